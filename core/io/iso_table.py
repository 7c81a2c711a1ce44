"""ISO 230-2 style target/run tables: targets, and per cycle the forward and backward readings.

Two forms are read (the first is detected by its ``TGT_DATA[`` entries):

- the key=value form of the ecmc motion-test tools (PSI/ESS), e.g.::

      UNIT=mm
      CYCLES=5
      POSITIONS=5
      TGT_DATA[1]=15
      REF_DATA_FWD[1,1]=15.00474806
      REF_DATA_BWD[1,1]=15.00071...

  ``TGT_DATA[i]`` is target i, ``REF_DATA_FWD[i,j]`` / ``REF_DATA_BWD[i,j]`` the position the
  reference system read at target i in cycle j; the deviation is ``reference − target``, in
  ``UNIT`` (the ecmc tools define mm when it is absent). Other keys (REF_PV, DEC, …) are kept
  in the header. Lines starting with ``#`` are comments.

- a column table (what :func:`write_iso_table` writes)::

      # unit: um
      target_mm  up_1  up_2  down_1  down_2
      0          0.0   0.2   -1.8    -2.0

  with deviations (``measured − target``) in ``unit`` (required: in the file, or given by the plan
  or the command line); columns ``up_j``/``down_j``
  (or ``fwd_j``/``bwd_j``) hold cycle j; an empty cell, ``nan`` or ``-`` is a missing reading.

Forward (``up``) means travel in the order of the targets' numbers (ecmc) or towards increasing
position (columns); the cycles become runs fwd₁, bwd₁, fwd₂, … The files carry no times: readings
are taken 1 s apart in the order the machine visits them (metadata ``time_source``).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..measurement import LineData
from .limits import (
    MAX_ABS_DEVIATION,
    MAX_ABS_POSITION_MM,
    MAX_READINGS,
    MAX_RUNS,
    MAX_TARGETS,
    MIN_TARGET_SPACING_MM,
    size_text,
)
from .rtl import reading_times
from .source import SourceText, check_magnitude, format_number, parse_float, parse_int, quote
from .table_layout import detect_delimiter, split_fields
from .units import ANGLE_UNITS, DEVIATION_FACTOR, choices, normalise_unit

FloatArray = NDArray[np.float64]

MAX_POSITIONS = MAX_TARGETS
MAX_CYCLES = MAX_RUNS // 2
_ENTRY = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*(?:\[\s*([^\]]*)\])?\s*=(.*)$")
_RUN_COLUMN = re.compile(r"^(up|down|fwd|bwd|forward|backward)[ _\-]?(\d+)$")
_TIME_SOURCE = "visit order (the file has no times): readings 1 s apart"


@dataclass(frozen=True, eq=False)
class IsoTable:
    """An ISO 230-2 table, read: ``data`` in the file's deviation unit ``unit``."""

    path: Path
    data: LineData
    unit: str
    form: str  # "ecmc" or "columns"
    targets_file_mm: FloatArray
    header: Mapping[str, str]
    raw: bytes = field(repr=False)


def read_iso_table(path: str | Path, unit: str | None = None) -> IsoTable:
    """Read an ISO 230-2 target/run table in either form.

    ``unit`` is the deviation unit the plan or the command line gives; it must agree with the
    file's (``UNIT=``, ``# unit:``) and is required for a column table that does not state one.

    Raises
    ------
    FormatError
        Naming file and line for a malformed entry, a missing or repeated reading, or counts that
        disagree with the entries.
    """
    source = SourceText.read(path)
    declared = normalise_unit(unit) if unit else None
    if declared is not None and declared not in DEVIATION_FACTOR:
        raise source.error(
            f"deviation unit {unit!r} is not supported; use one of "
            f"{choices(tuple(DEVIATION_FACTOR))}",
            1,
        )
    if any("TGT_DATA[" in line.upper() for line in source.lines):
        return _read_ecmc(source, declared)
    return _read_columns(source, declared)


def is_iso_table(source: SourceText) -> bool:
    """True for a file this module reads (ecmc entries, or a header with up/down columns)."""
    if any("TGT_DATA[" in line.upper() for line in source.lines):
        return True
    for text in source.lines:
        stripped = text.strip()
        if not stripped or stripped.startswith("#"):
            continue
        names = [n.lower() for n in split_fields(stripped, detect_delimiter(stripped))]
        return any(_RUN_COLUMN.match(n) for n in names)
    return False


# ---- ecmc key=value ------------------------------------------------------------------------


def _read_ecmc(source: SourceText, given_unit: str | None) -> IsoTable:
    header: dict[str, str] = {}
    declared: dict[str, tuple[int, int]] = {}
    targets: dict[int, tuple[float, int]] = {}
    readings: dict[str, dict[tuple[int, int], tuple[float, int]]] = {"FWD": {}, "BWD": {}}
    for number, text in source.numbered():
        stripped = text.strip()
        if not stripped or stripped.startswith("#"):
            continue
        match = _ENTRY.match(text)
        if not match:
            raise source.error(
                f"expected NAME=value or NAME[i]=value, found {quote(stripped)}", number
            )
        name, index, value = match.group(1).upper(), match.group(2), match.group(3).strip()
        if name in ("CYCLES", "POSITIONS"):
            count = parse_int(value, source, number, name)
            limit = MAX_CYCLES if name == "CYCLES" else MAX_POSITIONS
            if not 1 <= count <= limit:
                raise source.error(f"{name}={count} is out of range 1…{limit}", number)
            declared[name] = (count, number)
        elif name == "TGT_DATA":
            i = _indexes(index, 1, source, number, name)[0]
            if i in targets:
                raise source.error(f"TGT_DATA[{i}] is given twice", number)
            target = parse_float(value, source, number, f"TGT_DATA[{i}]")
            check_magnitude(target, MAX_ABS_POSITION_MM, source, number, f"TGT_DATA[{i}]")
            targets[i] = (target, number)
        elif name in ("REF_DATA_FWD", "REF_DATA_BWD"):
            i, j = _indexes(index, 2, source, number, name)
            table = readings[name[-3:]]
            if (i, j) in table:
                raise source.error(f"{name}[{i},{j}] is given twice", number)
            table[(i, j)] = (parse_float(value, source, number, f"{name}[{i},{j}]"), number)
        elif index is None:
            header[name] = value
    unit = normalise_unit(header["UNIT"]) if "UNIT" in header else (given_unit or "mm")
    if unit not in DEVIATION_FACTOR or unit in ANGLE_UNITS:
        raise source.error(
            f"UNIT={quote(header['UNIT'])} is not a supported length unit; use "
            "one of um, nm, mm, m, inch",
            _line_of(source, "UNIT"),
        )
    if given_unit is not None and given_unit != unit:
        raise source.error(
            f"the file's UNIT is {unit!r} but the unit given is {given_unit!r}; "
            "correct one of them",
            _line_of(source, "UNIT"),
        )
    if not targets:
        raise source.error("no TGT_DATA[i] entries", source.last_line)
    positions = declared.get("POSITIONS", (max(targets), source.last_line))
    cycles_seen = max((j for table in readings.values() for _, j in table), default=0)
    cycles = declared.get("CYCLES", (cycles_seen, source.last_line))
    if positions[0] * cycles[0] * 2 > MAX_READINGS:
        raise source.error(
            f"POSITIONS={positions[0]} × CYCLES={cycles[0]} × 2 directions is "
            f"beyond the {size_text(MAX_READINGS)} readings a line may hold "
            "(docs/formats.md, Limits)",
            positions[1],
        )
    for i, (_, number) in targets.items():
        if i > positions[0]:
            raise source.error(f"TGT_DATA[{i}] is beyond POSITIONS={positions[0]}", number)
    for kind, table in readings.items():
        for (i, j), (_, number) in table.items():
            if i > positions[0] or j > cycles[0]:
                raise source.error(
                    f"REF_DATA_{kind}[{i},{j}] is beyond POSITIONS={positions[0]}, "
                    f"CYCLES={cycles[0]}",
                    number,
                )
    if cycles[0] < 1 or not readings["FWD"]:
        raise source.error("no REF_DATA_FWD[i,j] readings", source.last_line)
    for i in range(1, positions[0] + 1):
        if i not in targets:
            raise source.error(
                f"TGT_DATA[{i}] is missing (POSITIONS={positions[0]})", source.last_line
            )
    kinds = ["FWD", "BWD"] if readings["BWD"] else ["FWD"]
    for kind in kinds:
        for j in range(1, cycles[0] + 1):
            for i in range(1, positions[0] + 1):
                if (i, j) not in readings[kind]:
                    raise source.error(
                        f"REF_DATA_{kind}[{i},{j}] is missing (POSITIONS={positions[0]}, "
                        f"CYCLES={cycles[0]}); the file may be cut short",
                        source.last_line,
                    )
    file_targets = np.array([targets[i][0] for i in range(1, positions[0] + 1)])
    _check_monotonic(source, file_targets, targets[1][1])
    factor = DEVIATION_FACTOR[unit]
    runs = []
    for j in range(1, cycles[0] + 1):
        for kind in kinds:
            run = []
            for i in range(1, positions[0] + 1):
                reading, number = readings[kind][(i, j)]
                deviation = reading - targets[i][0]
                check_magnitude(
                    deviation * factor,
                    MAX_ABS_DEVIATION,
                    source,
                    number,
                    f"REF_DATA_{kind}[{i},{j}] − TGT_DATA[{i}] (µm)",
                )
                run.append(deviation)
            runs.append(run)
    forward = 1 if positions[0] == 1 or file_targets[-1] > file_targets[0] else -1
    direction = [forward if kind == "FWD" else -forward for _ in range(cycles[0]) for kind in kinds]
    data = _line_data(file_targets, np.asarray(runs), np.asarray(direction))
    return IsoTable(source.path, data, unit, "ecmc", file_targets, header, source.raw)


def _indexes(text: str | None, count: int, source: SourceText, line: int, name: str) -> list[int]:
    parts = [] if text is None else [p.strip() for p in text.split(",")]
    if len(parts) != count:
        shape = "[i]" if count == 1 else "[i,j]"
        raise source.error(f"{name}: expected an index {shape}", line)
    values = [parse_int(p, source, line, f"{name} index") for p in parts]
    if not all(1 <= v <= MAX_POSITIONS for v in values):
        raise source.error(f"{name}: indexes run from 1 to at most {MAX_POSITIONS}", line)
    return values


def _line_of(source: SourceText, key: str) -> int:
    for number, text in source.numbered():
        if text.strip().upper().startswith(key):
            return number
    return source.last_line


def _check_monotonic(source: SourceText, targets: FloatArray, line: int) -> None:
    steps = np.diff(targets)
    if targets.size > 1 and not (np.all(steps > 0) or np.all(steps < 0)):
        raise source.error("targets must be strictly increasing or strictly decreasing", line)
    if targets.size > 1 and np.min(np.abs(steps)) < MIN_TARGET_SPACING_MM:
        raise source.error(
            f"two targets are {np.min(np.abs(steps)):g} mm apart; targets of a "
            f"line are at least {MIN_TARGET_SPACING_MM:g} mm apart "
            "(docs/formats.md, Limits)",
            line,
        )


def _line_data(
    file_targets: FloatArray, runs: FloatArray, direction: NDArray[np.int64]
) -> LineData:
    """Runs (in file target order) → LineData with ascending relative targets and visit times."""
    relative = file_targets - file_targets[0]
    order = np.argsort(relative, kind="stable")
    count = relative.size
    times = reading_times(direction.size, count, float(direction.size * count), direction)
    return LineData(
        targets_mm=relative[order],
        deviations=runs[:, order],
        run_direction=direction,
        times_s=times,
        metadata={"time_source": _TIME_SOURCE},
        origin_mm=float(file_targets[0]),
    )


# ---- column form ----------------------------------------------------------------------------


def _read_columns(source: SourceText, declared: str | None) -> IsoTable:
    header: dict[str, str] = {}
    names: list[str] | None = None
    delimiter: str | None = None
    header_line = 0
    rows: list[tuple[int, list[str]]] = []
    for number, text in source.numbered():
        stripped = text.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            key, colon, value = stripped[1:].partition(":")
            if colon:
                header[key.strip().lower()] = value.strip()
            continue
        if names is None:
            delimiter = detect_delimiter(stripped)
            names = [n.lower() for n in split_fields(stripped, delimiter)]
            header_line = number
            continue
        rows.append((number, split_fields(stripped, delimiter)))
    if names is None:
        raise source.error("no header row (target_mm up_1 … down_1 …)", source.last_line)
    target_names = [
        i for i, n in enumerate(names) if n in ("target", "target_mm", "position", "position_mm")
    ]
    if len(target_names) != 1:
        raise source.error("the header needs one target column (target_mm)", header_line)
    run_columns: dict[tuple[int, int], int] = {}
    for index, name in enumerate(names):
        match = _RUN_COLUMN.match(name)
        if match:
            kind = 1 if match.group(1) in ("up", "fwd", "forward") else -1
            cycle = int(match.group(2))
            if cycle < 1 or (kind, cycle) in run_columns:
                raise source.error(
                    f"column {name!r} is repeated or its cycle is not ≥ 1", header_line
                )
            run_columns[(kind, cycle)] = index
        elif index != target_names[0]:
            raise source.error(
                f"column {name!r} is not understood; use target_mm, up_1, up_2, …, down_1, …",
                header_line,
            )
    if not run_columns:
        raise source.error("no up_j / down_j columns", header_line)
    if not rows:
        raise source.error("the table has no rows", source.last_line)
    unit_line = next(
        (n for n, text in source.numbered() if re.match(r"^\s*#\s*unit\s*:", text, re.IGNORECASE)),
        1,
    )
    if "unit" in header:
        unit = normalise_unit(header["unit"])
        if unit not in DEVIATION_FACTOR:
            raise source.error(
                f"unit {quote(header['unit'])} is not supported; use one of "
                f"{choices(tuple(DEVIATION_FACTOR))}",
                unit_line,
            )
        if declared is not None and declared != unit:
            raise source.error(
                f"the file's unit is {unit!r} but the unit given is "
                f"{declared!r}; correct one of them",
                unit_line,
            )
    elif declared is not None:
        unit = declared
    else:
        raise source.error(
            "the table does not state its deviation unit and volucal does not assume one: add a "
            "line '# unit: um' (or nm, mm, urad, arcsec, …), or give deviation_unit in the plan "
            "(--unit on the command line)",
            header_line,
        )
    if len(rows) * len(run_columns) > MAX_READINGS:
        raise source.error(
            f"{len(rows)} targets × {len(run_columns)} runs is beyond the "
            f"{size_text(MAX_READINGS)} readings a line may hold",
            header_line,
        )
    factor = DEVIATION_FACTOR[unit]
    targets = []
    values = np.full((len(rows), len(run_columns)), np.nan)
    keys = sorted(run_columns, key=run_columns.__getitem__)  # runs in column order
    for row, (number, cells) in enumerate(rows):
        if len(cells) != len(names):
            raise source.error(f"expected {len(names)} fields, found {len(cells)}", number)
        target = parse_float(cells[target_names[0]], source, number, "target")
        targets.append(check_magnitude(target, MAX_ABS_POSITION_MM, source, number, "target (mm)"))
        for col, run_key in enumerate(keys):
            cell = cells[run_columns[run_key]]
            if cell.lower() in ("", "nan", "-"):
                continue
            what = names[run_columns[run_key]]
            reading = parse_float(cell, source, number, what)
            check_magnitude(reading * factor, MAX_ABS_DEVIATION, source, number, what)
            values[row, col] = reading
    file_targets = np.asarray(targets)
    _check_monotonic(source, file_targets, rows[0][0])
    if file_targets.size > 1 and file_targets[-1] < file_targets[0]:
        # rows listed from the high end: "up" still means towards increasing position
        file_targets, values = file_targets[::-1], values[::-1]
    direction = np.array([kind for kind, _ in keys], dtype=np.int64)
    data = _line_data(file_targets, values.T.copy(), direction)
    return IsoTable(source.path, data, unit, "columns", file_targets, header, source.raw)


def write_iso_table(
    path: str | Path, data: LineData, *, unit: str = "um", first_target_mm: float = 0.0
) -> None:
    """Write the column form: one row per target, one column per run (``up_j``/``down_j`` in
    run order per direction). Values round-trip exactly; times and environment are not kept."""
    counters = {1: 0, -1: 0}
    names = []
    for direction in data.run_direction:
        counters[int(direction)] += 1
        names.append(f"{'up' if direction > 0 else 'down'}_{counters[int(direction)]}")
    lines = [f"# unit: {unit}", "  ".join(["target_mm", *names])]
    for k, target in enumerate(data.targets_mm):
        cells = [format_number(first_target_mm + float(target))]
        for run in range(data.runs):
            value = data.deviations[run, k]
            cells.append(repr(float(value)) if np.isfinite(value) else "nan")
        lines.append("  ".join(cells))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
