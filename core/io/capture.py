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

import io
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..measurement import LineData
from ..userror import FormatError
from .source import SourceText, decode_text, format_time_iso, parse_float, parse_int, parse_time
from .table import TableFormat, _split_unit, detect_delimiter, split_fields
from .units import DEVIATION_FACTOR, POSITION_FACTOR, TIME_FACTOR, normalise_unit

FloatArray = NDArray[np.float64]

MAX_SAMPLES = 1_000_000_000
CHANNELS = ("time_s", "position_mm", "deviation")


@dataclass(frozen=True, eq=False)
class Capture:
    """Samples of a dynamic capture.

    time_s : (n,) seconds since ``start_time`` (POSIX s).
    deviation : (n,) in ``unit`` (None when the file does not say).
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

    ``table_format`` maps the CSV columns (position, deviation, time) and their units;
    ``sample_rate_hz`` gives the times of a CSV capture without a time column; a CSV capture is
    parsed ``chunk_bytes`` at a time.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise FormatError(path, "file not found; check the path") from None
    except OSError as exc:
        raise FormatError(path, f"cannot be read: {exc.strerror or exc}") from None
    if raw.lstrip().startswith(b"HEADER::"):
        return _read_binary(path, raw)
    return _read_text(path, raw, table_format or TableFormat(), sample_rate_hz, chunk_bytes)


# ---- binary ------------------------------------------------------------------------------


def _read_binary(path: Path, raw: bytes) -> Capture:
    marker = raw.find(b"\nData:")
    head = SourceText.from_bytes(path, raw[: marker if marker >= 0 else len(raw)])
    if marker < 0:
        raise head.error("no 'Data:' line: the file is cut short or not a capture", head.last_line)
    data_line = len(head.lines) + 1
    header: dict[str, str] = {}
    lines: dict[str, int] = {}
    for number, text in head.numbered():
        if text.strip() in ("", "HEADER::"):
            continue
        key, colon, value = text.partition(":")
        if not colon:
            raise head.error(f"expected 'name: value' in the header, found {text.strip()!r}",
                             number)
        header[key.strip()] = value.strip()
        lines[" ".join(key.lower().split())] = number
    by_name = {" ".join(k.lower().split()): v for k, v in header.items()}
    if "sample count" not in by_name:
        raise head.error("the header has no 'Sample count:'", head.last_line)
    count = parse_int(by_name["sample count"], head, lines["sample count"], "Sample count")
    if not 1 <= count <= MAX_SAMPLES:
        raise head.error(f"Sample count {count} is out of range", lines["sample count"])
    channels = tuple(by_name.get("channels", "deviation").split())
    unknown = [c for c in channels if c not in CHANNELS]
    if unknown or len(set(channels)) != len(channels) or "deviation" not in channels:
        raise head.error(
            f"Channels {' '.join(channels)!r}: use {', '.join(CHANNELS)}, each at most once and "
            "deviation always",
            lines.get("channels", head.last_line),
        )
    rate = None
    if "sample rate" in by_name:
        rate = parse_float(by_name["sample rate"], head, lines["sample rate"], "Sample rate")
        if rate <= 0:
            raise head.error("Sample rate must be positive (Hz)", lines["sample rate"])
    elif "time_s" not in channels:
        raise head.error("the header needs 'Sample rate:' (Hz) or a time_s channel",
                         head.last_line)
    start = 0.0
    if "start time" in by_name:
        start = parse_time(by_name["start time"], head, lines["start time"], "Start time")
    unit = None
    if "units" in by_name:
        unit = normalise_unit(by_name["units"])
        if unit not in DEVIATION_FACTOR:
            raise head.error(f"Units {by_name['units']!r} is not a supported deviation unit",
                             lines["units"])

    body = raw[marker + len(b"\nData:"):]
    body = body[2:] if body.startswith(b"\r\n") else body[1:] if body.startswith(b"\n") else body
    size = count * len(channels) * 8
    tail = body[size:].strip()
    if len(body) < size or tail != b"EOF::":
        held = min(len(body), size)
        raise head.error(
            f"the data block should hold {count} samples × {len(channels)} channels × 8 bytes = "
            f"{size} bytes followed by EOF::; found {held} bytes"
            + (" and no EOF::" if tail != b"EOF::" else "")
            + ": the file is cut short or damaged",
            data_line,
        )
    values = np.frombuffer(body, dtype="<f8", count=count * len(channels)).reshape(count, -1)
    finite = np.isfinite(values)
    if not finite.all():
        sample = int(np.argwhere(~finite)[0][0])
        raise head.error(f"sample {sample + 1} holds a value that is not a finite number",
                         data_line)
    column = {name: values[:, i] for i, name in enumerate(channels)}
    if "time_s" in column:
        time = column["time_s"].copy()
    else:
        assert rate is not None  # checked with the header
        time = np.arange(count) / rate
    return Capture(
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


# ---- text --------------------------------------------------------------------------------


def _read_text(
    path: Path, raw: bytes, fmt: TableFormat, sample_rate_hz: float | None, chunk_bytes: int
) -> Capture:
    source = SourceText(path, b"", ())
    # the header row: the first line that is neither blank nor a comment
    offset, number = 0, 1
    while True:
        end = raw.find(b"\n", offset)
        stop = len(raw) if end < 0 else end
        line = decode_text(raw[offset:stop])
        if line.strip() and not line.lstrip().startswith("#"):
            break
        if end < 0:
            raise source.error("the file holds no header row and no data", number)
        offset, number = end + 1, number + 1
    header_line = number
    header_text = line.strip()
    delimiter = fmt.delimiter if fmt.delimiter not in (None, "whitespace", "space", " ") else (
        None if fmt.delimiter else detect_delimiter(header_text)
    )
    header = split_fields(header_text, delimiter)
    names = [_split_unit(h) for h in header]
    columns: dict[str, int] = {}
    units: dict[str, str | None] = {}
    for key in ("time", "position", "deviation"):
        ref = getattr(fmt.columns, key)
        if isinstance(ref, int):
            index = ref - 1 if ref <= len(header) else None
        else:
            wanted = "_".join((ref or key).lower().split())
            index = next((i for i, (plain, _) in enumerate(names)
                          if plain == wanted or "_".join(header[i].lower().split()) == wanted),
                         None)
        if index is None:
            if ref is not None or key == "deviation":
                raise source.error(
                    f"no {key} column {ref or key!r}; the header has "
                    f"{', '.join(repr(h) for h in header)}",
                    header_line,
                )
            continue
        columns[key] = index
        units[key] = names[index][1]
    if "time" not in columns and not sample_rate_hz:
        raise source.error(
            "a capture needs a time column or a sample rate (capture_rate_hz in the plan)",
            header_line,
        )
    declared = {"time": fmt.time_unit, "position": fmt.position_unit,
                "deviation": fmt.deviation_unit}
    for key, unit in declared.items():
        if unit is not None:
            if units.get(key) not in (None, normalise_unit(unit)):
                raise source.error(
                    f"the {key} unit is declared as {unit!r} but the header says {units[key]!r}",
                    header_line,
                )
            units[key] = normalise_unit(unit)
    tables = {"time": TIME_FACTOR, "position": POSITION_FACTOR, "deviation": DEVIATION_FACTOR}
    for key, unit in units.items():
        if unit is not None and unit not in tables[key]:
            raise source.error(f"{key} unit {unit!r} is not supported", header_line)

    order = sorted(columns, key=columns.get)  # type: ignore[arg-type]
    usecols = [columns[k] for k in order]
    blocks = []
    # chunks of whole lines, parsed by numpy's C reader: memory stays at the file's bytes plus
    # one chunk, and every error is traced back to its line
    position = len(raw) if end < 0 else end + 1
    first_line = header_line + 1
    while position < len(raw):
        cut = raw.find(b"\n", position + chunk_bytes)
        cut = len(raw) if cut < 0 else cut + 1
        text = raw[position:cut].decode("latin-1")
        try:
            with warnings.catch_warnings():
                # a chunk of only blank or comment lines is fine (the file's tail)
                warnings.simplefilter("ignore", UserWarning)
                values = np.loadtxt(io.StringIO(text), delimiter=delimiter, usecols=usecols,
                                    comments="#", ndmin=2, dtype=float)
        except ValueError:
            raise _bad_line(source, text, first_line, delimiter, usecols) from None
        if not np.isfinite(values).all():
            raise _bad_line(source, text, first_line, delimiter, usecols)
        blocks.append(values)
        first_line += text.count("\n")
        position = cut
    values = np.concatenate(blocks) if blocks else np.empty((0, len(usecols)))
    if values.shape[0] == 0:
        raise source.error("the file holds no data rows", header_line)
    column = {key: values[:, i] for i, key in enumerate(order)}
    if "time" in column:
        time = column["time"] * TIME_FACTOR[units["time"] or "s"]
    else:
        time = np.arange(values.shape[0]) / float(sample_rate_hz)  # type: ignore[arg-type]
    position_mm = None
    if "position" in column:
        position_mm = column["position"] * POSITION_FACTOR[units["position"] or "mm"]
    return Capture(
        path=path,
        time_s=np.ascontiguousarray(time),
        deviation=np.ascontiguousarray(column["deviation"]),
        position_mm=None if position_mm is None else np.ascontiguousarray(position_mm),
        unit=units.get("deviation"),
        sample_rate_hz=sample_rate_hz,
        header={"columns": " ".join(header)},
        raw=raw,
    )


def _bad_line(
    source: SourceText, text: str, first_line: int, delimiter: str | None, usecols: list[int]
) -> FormatError:
    """The first line of a chunk that does not hold finite numbers in the used columns."""
    for offset, line in enumerate(text.split("\n")):
        stripped = line.split("#")[0].strip()
        if not stripped:
            continue
        fields_ = split_fields(stripped, delimiter)
        number = first_line + offset
        if len(fields_) <= max(usecols):
            return source.error(
                f"expected at least {max(usecols) + 1} fields, found {len(fields_)}", number
            )
        for index in usecols:
            parse_float(fields_[index], source, number, f"column {index + 1}")
    return source.error("a row could not be read as numbers", first_line)


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
    if step_mm is None or not step_mm > 0:
        raise ValueError("a position capture needs a positive step_mm (capture_step_mm)")
    return _bin_positions(capture, step_mm, window_mm if window_mm is not None else step_mm / 2)


def _bin_positions(capture: Capture, step_mm: float, window_mm: float) -> LineData:
    assert capture.position_mm is not None
    relative = capture.position_mm - capture.position_mm[0]
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
    )


def _bin_times(capture: Capture, step_s: float) -> LineData:
    if not step_s > 0:
        raise ValueError("step_s must be positive")
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
