"""Dynamic captures: a deviation sampled continuously (often 50 kHz, a million samples), against
time or against a position that moves, and how they become runs × targets.

Two file forms are read:

- the binary form (``.rtx``-like, REFERENCE.md §5)::

      HEADER::
      Sample rate: 50000                  (Hz; required unless a time_s channel is stored)
      Sample count: 1000000
      Channels: time_s position_mm deviation      (optional; default: deviation)
      Units: um                           (deviation unit; optional)
      Start time: 2026-01-01T00:00:00Z    (optional, ISO 8601)
      Data:
      <Sample count × channels float64, little-endian, sample-major>
      EOF::

- a large CSV/whitespace table with a header row (columns time, position, deviation, matched as
  in :mod:`volucal.core.io.table`), parsed in chunks of about ``chunk_bytes`` so that a million
  rows stay fast and memory stays bounded.

:func:`capture_line_data` bins a position capture onto regularly spaced targets (one run per
sweep) and a time-only capture into time windows at one target.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from io import StringIO
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..measurement import LineData
from ..userror import FormatError
from .limits import (
    MAX_ABS_DEVIATION,
    MAX_ABS_POSITION_MM,
    MAX_ABS_TIME_S,
    MAX_CAPTURE_BYTES,
    MAX_READINGS,
    MAX_SAMPLE_RATE_HZ,
    MAX_SAMPLES,
    MAX_TARGETS,
    MIN_TARGET_SPACING_MM,
    size_text,
)
from .source import (
    BLANKS,
    SourceText,
    check_magnitude,
    format_time_iso,
    parse_float,
    parse_int,
    parse_time,
    read_file_bytes,
)
from .table import TableFormat
from .table_layout import (
    Layout,
    find_layout,
    resolve_columns,
    row_fits,
    split_fields,
)
from .units import (
    ANGLE_UNITS,
    DEVIATION_FACTOR,
    POSITION_FACTOR,
    TIME_FACTOR,
    choices,
    normalise_unit,
)

FloatArray = NDArray[np.float64]

CHANNELS = ("time_s", "position_mm", "deviation")
_TRAILERS = (b"\nEOF::", b"\r\nEOF::")


@dataclass(frozen=True, eq=False)
class Capture:
    """Samples of a dynamic capture.

    time_s : (n,) seconds since ``start_time`` (POSIX s), never decreasing.
    deviation : (n,) in ``unit``.
    position_mm : (n,) or None for a time series at a fixed position.
    """

    path: Path
    time_s: FloatArray
    deviation: FloatArray
    position_mm: FloatArray | None
    unit: str | None
    start_time: float = 0.0
    sample_rate_hz: float | None = None
    header: Mapping[str, str] = field(default_factory=dict)
    raw: bytes = field(default=b"", repr=False)

    @property
    def samples(self) -> int:
        return int(self.deviation.size)


def read_capture(
    path: str | Path,
    table_format: TableFormat | None = None,
    *,
    sample_rate_hz: float | None = None,
    chunk_bytes: int = 8 << 20,
) -> Capture:
    """Read a binary capture (a file starting with ``HEADER::``) or a CSV/whitespace capture.

    ``table_format`` maps the CSV columns (position, deviation, time) and declares units (its
    ``deviation_unit`` must agree with a binary capture's ``Units:``); ``sample_rate_hz`` gives
    the times of a CSV capture without a time column; a CSV capture is parsed ``chunk_bytes`` at
    a time. The deviation unit must come from the file or ``table_format``.
    """
    path = Path(path)
    fmt = table_format or TableFormat()
    raw = read_file_bytes(path, MAX_CAPTURE_BYTES)
    if raw.lstrip().startswith(b"HEADER::"):
        return _read_binary(path, raw, fmt)
    if sample_rate_hz is not None and not 0 < sample_rate_hz <= MAX_SAMPLE_RATE_HZ:
        raise FormatError(
            path,
            f"the sample rate {sample_rate_hz!r} Hz is outside "
            f"0…{MAX_SAMPLE_RATE_HZ:g} Hz (capture_rate_hz)",
        )
    return _read_text(path, raw, fmt, sample_rate_hz, chunk_bytes)


# ---- binary ------------------------------------------------------------------------------


def _read_binary(path: Path, raw: bytes, fmt: TableFormat) -> Capture:
    marker = raw.find(b"\nData:")
    head = SourceText.from_bytes(path, raw[: marker if marker >= 0 else len(raw)])
    if marker < 0:
        raise head.error("no 'Data:' line: the file is cut short or not a capture", head.last_line)
    data_line = len(head.lines) + 1
    header: dict[str, str] = {}
    lines: dict[str, int] = {}
    for number, text in head.numbered():
        if text.strip(BLANKS) in ("", "HEADER::"):
            continue
        key, colon, value = text.partition(":")
        if not colon:
            raise head.error("expected 'name: value' in the header", number)
        header[key.strip(BLANKS)] = value.strip(BLANKS)
        lines[" ".join(key.lower().split())] = number
    by_name = {" ".join(k.lower().split()): v for k, v in header.items()}
    if "sample count" not in by_name:
        raise head.error("the header has no 'Sample count:'", head.last_line)
    count = parse_int(by_name["sample count"], head, lines["sample count"], "Sample count")
    if not 1 <= count <= MAX_SAMPLES:
        raise head.error(
            f"Sample count {count} is outside 1…{size_text(MAX_SAMPLES)} (docs/formats.md, Limits)",
            lines["sample count"],
        )
    channels = tuple(by_name.get("channels", "deviation").split())
    unknown = [c for c in channels if c not in CHANNELS]
    if unknown or len(set(channels)) != len(channels) or "deviation" not in channels:
        raise head.error(
            f"Channels: use {', '.join(CHANNELS)}, each at most once and deviation always",
            lines.get("channels", head.last_line),
        )
    rate = None
    if "sample rate" in by_name:
        rate = parse_float(by_name["sample rate"], head, lines["sample rate"], "Sample rate")
        if not 0 < rate <= MAX_SAMPLE_RATE_HZ:
            raise head.error(
                f"Sample rate must lie in 0…{MAX_SAMPLE_RATE_HZ:g} Hz", lines["sample rate"]
            )
    elif "time_s" not in channels:
        raise head.error("the header needs 'Sample rate:' (Hz) or a time_s channel", head.last_line)
    start = 0.0
    if "start time" in by_name:
        start = parse_time(by_name["start time"], head, lines["start time"], "Start time")

    # the size the header claims is checked against the bytes there before anything is read
    body = raw[marker + len(b"\nData:") :]
    body = body[2:] if body.startswith(b"\r\n") else body[1:] if body.startswith(b"\n") else body
    size = count * len(channels) * 8
    trailer = body[size:].rstrip(b" \t\r\n")
    if len(body) < size or trailer not in _TRAILERS:
        held = min(len(body), size)
        raise head.error(
            f"the data block should hold {count} samples × {len(channels)} channels × 8 bytes = "
            f"{size} bytes followed by a line break and EOF::; found {held} bytes"
            + (" and no EOF:: right after them" if trailer not in _TRAILERS else "")
            + ": the file is cut short or damaged",
            data_line,
        )
    unit = _binary_unit(head, by_name, lines, fmt)
    values = np.frombuffer(body, dtype="<f8", count=count * len(channels)).reshape(count, -1)
    finite = np.isfinite(values)
    if not finite.all():
        sample = int(np.argwhere(~finite)[0][0])
        raise head.error(
            f"sample {sample + 1} holds a value that is not a finite number", data_line
        )
    column = {name: values[:, i] for i, name in enumerate(channels)}
    if "time_s" in column:
        time = column["time_s"].copy()
    else:
        assert rate is not None  # checked with the header
        time = np.arange(count) / rate
    capture = Capture(
        path=path,
        time_s=time,
        deviation=column["deviation"].copy(),
        position_mm=column["position_mm"].copy() if "position_mm" in column else None,
        unit=unit,
        start_time=start,
        sample_rate_hz=rate,
        header=header,
        raw=raw,
    )
    _check_samples(
        head, capture, lambda _: data_line, lambda index, what: f"sample {index + 1}: {what}"
    )
    return capture


def _binary_unit(
    head: SourceText, by_name: dict[str, str], lines: dict[str, int], fmt: TableFormat
) -> str:
    declared = normalise_unit(fmt.deviation_unit) if fmt.deviation_unit else None
    if "units" not in by_name:
        if declared is None:
            raise head.error(
                "the header has no 'Units:' line and no deviation unit is given: "
                "give deviation_unit in the plan's [[line]] (um, nm, mm, urad, "
                "arcsec, …)",
                head.last_line,
            )
        if declared not in DEVIATION_FACTOR:
            raise head.error(f"deviation unit {declared!r} is not supported", head.last_line)
        return declared
    unit = normalise_unit(by_name["units"])
    if unit not in DEVIATION_FACTOR:
        raise head.error(
            f"Units: not a supported deviation unit; use one of {choices(tuple(DEVIATION_FACTOR))}",
            lines["units"],
        )
    if declared is not None and declared != unit:
        raise head.error(
            f"the file's Units: is {unit!r} but the deviation unit given is "
            f"{fmt.deviation_unit!r}; correct one of them",
            lines["units"],
        )
    return unit


def _check_samples(
    source: SourceText,
    capture: Capture,
    where: Callable[[int], int],
    label: Callable[[int, str], str],
) -> None:
    """Positions, deviations and times a laser can produce, and time that never goes back;
    ``where(i)`` is the line to name for sample i, ``label(i, what)`` how to call its value."""
    unit = capture.unit or "um"
    checks = [
        (
            "deviation",
            capture.deviation * DEVIATION_FACTOR[unit],
            MAX_ABS_DEVIATION,
            "µrad" if unit in ANGLE_UNITS else "µm",
        ),
        ("time", capture.time_s, MAX_ABS_TIME_S, "s"),
    ]
    if capture.position_mm is not None:
        checks.append(("position", capture.position_mm, MAX_ABS_POSITION_MM, "mm"))
    for what, values, limit, symbol in checks:
        with np.errstate(over="ignore", invalid="ignore"):
            bad = np.flatnonzero(~(np.abs(values) <= limit))
        if bad.size:
            index = int(bad[0])
            check_magnitude(
                float(values[index]),
                limit,
                source,
                where(index),
                label(index, f"{what} ({symbol})"),
            )
    back = np.flatnonzero(np.diff(capture.time_s) < 0)
    if back.size:
        index = int(back[0]) + 1
        raise source.error(
            f"{label(index, 'time')} goes back: the samples of a capture follow each other",
            where(index),
        )


# ---- text --------------------------------------------------------------------------------


def _read_text(
    path: Path, raw: bytes, fmt: TableFormat, sample_rate_hz: float | None, chunk_bytes: int
) -> Capture:
    # the header: found on the first 64 lines' text (a capture's preamble is short), then the
    # rows are parsed in chunks straight from the bytes
    head_end = 0
    for _ in range(64):
        cut = raw.find(b"\n", head_end)
        if cut < 0:
            head_end = len(raw)
            break
        head_end = cut + 1
    head = SourceText.from_bytes(path, raw[:head_end])
    layout = find_layout(
        head, delimiter=fmt.delimiter, data_marker=fmt.data_marker, comment=fmt.comment
    )
    if layout.header_line is None:
        raise head.error(
            "a CSV capture needs a header row naming its columns (time, position, deviation)",
            layout.first_data_line,
        )
    columns, header_units, shown = resolve_columns(
        head, layout, fmt.columns, ("time", "position", "deviation"), ("deviation",)
    )
    header_line = layout.header_line
    units: dict[str, str | None] = {}
    tables = {"time": TIME_FACTOR, "position": POSITION_FACTOR, "deviation": DEVIATION_FACTOR}
    for key in ("time", "position", "deviation"):
        if key not in columns:
            continue
        declared_raw = fmt.declared(key)
        declared = normalise_unit(declared_raw) if declared_raw else None
        from_header = header_units.get(key)
        if declared and from_header and declared != from_header:
            raise head.error(
                f"the {key} unit is declared as {declared_raw!r} but the header "
                f"{shown[key]} says {from_header!r}; correct one of them",
                header_line,
            )
        unit = declared or from_header
        if unit is None and key == "position":
            unit = fmt.position_unit_default
        if unit is None:
            example = {"time": "s", "position": "mm"}.get(key, "um")
            raise head.error(
                f"the {key} column {shown[key]} has no unit and volucal does not "
                f"assume one: give {key}_unit in the plan's [[line]] or write it "
                f"in the header, e.g. {key}_{example}",
                header_line,
            )
        if unit not in tables[key]:
            raise head.error(
                f"{key} unit {unit!r} is not supported; use one of {choices(tuple(tables[key]))}",
                header_line,
            )
        units[key] = unit
    if "time" not in columns and not sample_rate_hz:
        raise head.error(
            "a capture needs a time column or a sample rate (capture_rate_hz in the plan)",
            header_line,
        )

    order = sorted(columns, key=columns.get)  # type: ignore[arg-type]
    usecols = [columns[k] for k in order]
    delimiter = layout.delimiter
    blocks = []
    # chunks of whole lines, parsed by numpy's C reader: memory stays at the file's bytes plus
    # one chunk, and every error is traced back to its line
    position = _line_start(raw, layout.first_data_line)
    first_line = layout.first_data_line
    rows = 0
    while position < len(raw):
        cut = raw.find(b"\n", position + chunk_bytes)
        cut = len(raw) if cut < 0 else cut + 1
        chunk = raw[position:cut]
        text = chunk.decode("latin-1")
        if not chunk.isascii():
            # numpy takes a non-breaking space as a blank: find the line in strict terms
            found = _first_bad_line(head, text, first_line, layout, usecols, fmt.comment)
            if found is not None:
                raise found
        try:
            with warnings.catch_warnings():
                # a chunk of only blank or comment lines is fine (the file's tail)
                warnings.simplefilter("ignore", UserWarning)
                values = np.loadtxt(
                    StringIO(text),
                    delimiter=delimiter,
                    usecols=usecols,
                    comments=fmt.comment,
                    ndmin=2,
                    dtype=float,
                )
        except ValueError:
            raise _bad_line(head, text, first_line, layout, usecols, fmt.comment) from None
        if not np.isfinite(values).all():
            raise _bad_line(head, text, first_line, layout, usecols, fmt.comment)
        rows += values.shape[0]
        if rows > MAX_SAMPLES:
            raise head.error(
                f"more than {size_text(MAX_SAMPLES)} rows (docs/formats.md, Limits)", first_line
            )
        blocks.append(values)
        first_line += text.count("\n")
        position = cut
    values = np.concatenate(blocks) if blocks else np.empty((0, len(usecols)))
    if values.shape[0] == 0:
        raise head.error("the file holds no data rows", header_line)
    column = {key: values[:, i] for i, key in enumerate(order)}
    if "time" in column:
        time = column["time"] * TIME_FACTOR[units["time"] or "s"]
    else:
        time = np.arange(values.shape[0]) / float(sample_rate_hz)  # type: ignore[arg-type]
    position_mm = None
    if "position" in column:
        position_mm = column["position"] * POSITION_FACTOR[units["position"] or "mm"]
    capture = Capture(
        path=path,
        time_s=np.ascontiguousarray(time),
        deviation=np.ascontiguousarray(column["deviation"]),
        position_mm=None if position_mm is None else np.ascontiguousarray(position_mm),
        unit=units.get("deviation"),
        sample_rate_hz=sample_rate_hz,
        header={"columns": " ".join(layout.header)},
        raw=raw,
    )
    _check_samples(
        head,
        capture,
        lambda index: _line_of_row(raw, layout.first_data_line, index, fmt.comment),
        lambda _, what: what,
    )
    return capture


def _line_start(raw: bytes, line: int) -> int:
    """Byte offset where 1-based ``line`` starts."""
    offset = 0
    for _ in range(line - 1):
        cut = raw.find(b"\n", offset)
        if cut < 0:
            return len(raw)
        offset = cut + 1
    return offset


def _line_of_row(raw: bytes, first_line: int, row: int, comment: str) -> int:
    """Line number of data row ``row`` (0-based), counting from ``first_line`` and skipping
    blank and comment lines as the reader did. Only called for an error."""
    offset = _line_start(raw, first_line)
    number = first_line
    seen = -1
    marker = comment.encode("latin-1")
    while offset < len(raw):
        cut = raw.find(b"\n", offset)
        end = len(raw) if cut < 0 else cut
        text = raw[offset:end].strip()
        if text and not text.startswith(marker):
            seen += 1
            if seen == row:
                return number
        if cut < 0:
            break
        offset, number = cut + 1, number + 1
    return number


def _first_bad_line(
    source: SourceText,
    text: str,
    first_line: int,
    layout: Layout,
    usecols: list[int],
    comment: str,
) -> FormatError | None:
    """The error of the first line of a chunk that does not hold, in strict terms, as many
    fields as the header and numbers in the used columns; None if every line does."""
    for offset, line in enumerate(text.split("\n")):
        stripped = line.split(comment)[0].strip(BLANKS)
        if not stripped:
            continue
        fields_ = split_fields(stripped, layout.delimiter)
        number = first_line + offset
        if not row_fits(layout, len(fields_), max(usecols) + 1):
            return source.error(
                f"expected {layout.field_count} fields as in the header, found {len(fields_)}",
                number,
            )
        for index in usecols:
            try:
                parse_float(fields_[index], source, number, f"column {index + 1}")
            except FormatError as error:
                return error
    return None


def _bad_line(
    source: SourceText,
    text: str,
    first_line: int,
    layout: Layout,
    usecols: list[int],
    comment: str,
) -> FormatError:
    found = _first_bad_line(source, text, first_line, layout, usecols, comment)
    return found or source.error("a row could not be read as numbers", first_line)


# ---- writer ------------------------------------------------------------------------------


def write_capture(
    path: str | Path,
    deviation: FloatArray,
    *,
    sample_rate_hz: float | None = None,
    time_s: FloatArray | None = None,
    position_mm: FloatArray | None = None,
    unit: str = "um",
    start_time: float = 0.0,
    binary: bool = True,
) -> None:
    """Write a capture in the binary form (default) or as CSV with a header row.

    Either ``sample_rate_hz`` or ``time_s`` gives the sample times. Values round-trip exactly
    (float64 in the binary form, shortest exact decimal in CSV).
    """
    deviation = np.asarray(deviation, dtype=float)
    channels: list[tuple[str, FloatArray]] = []
    if time_s is not None:
        channels.append(("time_s", np.asarray(time_s, dtype=float)))
    elif sample_rate_hz is None:
        raise ValueError("give sample_rate_hz or time_s")
    if position_mm is not None:
        channels.append(("position_mm", np.asarray(position_mm, dtype=float)))
    channels.append(("deviation", deviation))
    if binary:
        head = ["HEADER::"]
        if sample_rate_hz is not None:
            head.append(f"Sample rate: {float(sample_rate_hz)!r}")
        head += [
            f"Sample count: {deviation.size}",
            f"Channels: {' '.join(name for name, _ in channels)}",
            f"Units: {unit}",
            f"Start time: {format_time_iso(start_time)}",
            "Data:",
        ]
        block = np.stack([values for _, values in channels], axis=1).astype("<f8")
        with open(path, "wb") as handle:
            handle.write(("\n".join(head) + "\n").encode("ascii"))
            handle.write(block.tobytes())
            handle.write(b"\nEOF::\n")
        return
    names = [name if name != "deviation" else f"deviation_{unit}" for name, _ in channels]
    if time_s is None:
        names.insert(0, "time_s")
        channels.insert(0, ("time_s", np.arange(deviation.size) / float(sample_rate_hz)))  # type: ignore[arg-type]
    block = np.stack([values for _, values in channels], axis=1)
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(",".join(names) + "\n")
        # 17 significant digits read back to the same float64
        np.savetxt(handle, block, delimiter=",", fmt="%.17g")


# ---- binning -----------------------------------------------------------------------------


def capture_line_data(
    capture: Capture,
    *,
    step_mm: float | None = None,
    window_mm: float | None = None,
    step_s: float = 1.0,
) -> LineData:
    """Runs × targets from a capture.

    A position capture is binned onto targets every ``step_mm`` from its first position: a sample
    counts for the nearest target when it lies within ±``window_mm``/2 of it (default window
    ``step_mm``/2, so that samples between targets are left out and jitter at a bin boundary
    cannot fake a reversal). Consecutive samples at one target form a visit, whose reading is the
    mean deviation and time of its samples; a run is a sequence of visits that move one way, and
    the visit where the travel turns belongs to the run that arrives there.

    A time-only capture becomes one target read once per window of ``step_s`` seconds (direction
    +1): a drift record at a fixed position.
    """
    if capture.position_mm is None:
        return _bin_times(capture, step_s)
    if step_mm is None or not (math.isfinite(step_mm) and step_mm >= MIN_TARGET_SPACING_MM):
        raise ValueError(
            f"a position capture needs a step_mm (capture_step_mm) of at least "
            f"{MIN_TARGET_SPACING_MM} mm"
        )
    if window_mm is not None and not (math.isfinite(window_mm) and window_mm > 0):
        raise ValueError("capture_window_mm must be a positive number")
    return _bin_positions(capture, step_mm, window_mm if window_mm is not None else step_mm / 2)


def _bin_positions(capture: Capture, step_mm: float, window_mm: float) -> LineData:
    assert capture.position_mm is not None
    relative = capture.position_mm - capture.position_mm[0]
    span = float(np.max(np.abs(relative))) / step_mm if relative.size else 0.0
    if not span < MAX_TARGETS:
        raise ValueError(
            f"the capture spans {float(np.ptp(relative)):g} mm, {span:.3g} steps of {step_mm:g} "
            f"mm: more than the {size_text(MAX_TARGETS)} targets a line may hold "
            "(docs/formats.md, Limits); check capture_step_mm and the position channel"
        )
    bins = np.rint(relative / step_mm).astype(np.int64)
    inside = np.flatnonzero(np.abs(relative - bins * step_mm) <= window_mm / 2)
    if inside.size == 0:
        raise ValueError("no sample lies within the window of a target")
    sample_bins = bins[inside]
    starts = np.flatnonzero(np.concatenate([[True], sample_bins[1:] != sample_bins[:-1]]))
    counts = np.diff(np.append(starts, inside.size))
    visit_bin = sample_bins[starts]
    visit_dev = np.add.reduceat(capture.deviation[inside], starts) / counts
    visit_time = np.add.reduceat(capture.time_s[inside], starts) / counts
    # a visit arrives by the step from the previous one; the visit where the travel turns still
    # arrives the old way, so it closes its run and the next visit opens a new one
    steps = np.sign(np.diff(visit_bin))
    arrival = np.concatenate([steps[:1], steps]) if steps.size else np.ones(1, dtype=np.int64)
    new_run = np.concatenate([[False], arrival[1:] != arrival[:-1]])
    run_of_visit = np.cumsum(new_run)
    run_direction = arrival[np.flatnonzero(np.concatenate([[True], new_run[1:]]))]
    runs = run_direction.size
    low, high = int(visit_bin.min()), int(visit_bin.max())
    if runs * (high - low + 1) > MAX_READINGS:
        raise ValueError(
            f"the capture makes {size_text(runs)} runs × {size_text(high - low + 1)} targets, "
            f"beyond the {size_text(MAX_READINGS)} readings a line may hold (docs/formats.md, "
            "Limits); check capture_step_mm and the position channel"
        )
    targets = np.arange(low, high + 1, dtype=float) * step_mm
    deviations = np.full((runs, targets.size), np.nan)
    times = np.full((runs, targets.size), np.nan)
    deviations[run_of_visit, visit_bin - low] = visit_dev
    times[run_of_visit, visit_bin - low] = visit_time
    return LineData(
        targets_mm=targets,
        deviations=deviations,
        run_direction=run_direction,
        times_s=times,
        start_time=capture.start_time,
        metadata={"capture_samples": str(capture.samples), "capture_step_mm": repr(step_mm)},
        origin_mm=float(capture.position_mm[0]),
    )


def _bin_times(capture: Capture, step_s: float) -> LineData:
    if not (math.isfinite(step_s) and step_s > 0):
        raise ValueError("step_s must be positive")
    duration = float(capture.time_s[-1] - capture.time_s[0])
    if duration / step_s >= MAX_READINGS:
        raise ValueError(
            f"{duration:g} s in windows of {step_s:g} s make more than {size_text(MAX_READINGS)} "
            "readings "
            "(docs/formats.md, Limits); give a longer capture_step_s"
        )
    window = np.floor((capture.time_s - capture.time_s[0]) / step_s).astype(np.int64)
    starts = np.flatnonzero(np.concatenate([[True], window[1:] != window[:-1]]))
    counts = np.diff(np.append(starts, window.size))
    mean_dev = np.add.reduceat(capture.deviation, starts) / counts
    mean_time = np.add.reduceat(capture.time_s, starts) / counts
    return LineData(
        targets_mm=np.zeros(1),
        deviations=mean_dev[:, None],
        run_direction=np.ones(starts.size, dtype=np.int64),
        times_s=mean_time[:, None],
        start_time=capture.start_time,
        metadata={"capture_samples": str(capture.samples), "capture_step_s": repr(step_s)},
    )
