"""Generic tables of readings (CSV, semicolon, tab or whitespace separated) with a column map.

One row is one reading. A :class:`ColumnMap` names the columns (by header name, or by 1-based
number for a file without a header row); :class:`TableFormat` declares the units and how to find
the data. Only position and deviation are required:

- position: the target (nominal position) along the line. Targets in :class:`LineData` are
  relative to the first row's position; rows within ``target_tolerance_mm`` are the same target.
- run: readings with the same run id form a run. Without a run column a new run starts whenever
  the travel reverses or a position repeats the previous row's.
- direction: +1/−1, ``+``/``-``, ``up``/``down``, ``fwd``/``bwd``, ``forward``/``backward``.
  Without it a run's direction is the way its positions go (a one-reading run needs the column).
- time: seconds (``time_unit``) or ISO 8601 date-times; without it readings are taken 1 s apart in
  row order (recorded in the metadata as ``time_source``).
- air_temp, material_temp (°C), pressure (``pressure_unit``), humidity (%RH): optional.

Header names match case-insensitively, ignoring a unit written as ``[mm]``, ``(mm)`` or a
``_mm`` suffix; such a unit is used when the format does not declare one (and must agree with it
when it does). A comment line ``# start_time: <ISO 8601>`` sets the time origin of relative times.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..measurement import Environment, LineData
from .source import SourceText, format_time_iso, parse_float
from .units import (
    DEVIATION_FACTOR,
    POSITION_FACTOR,
    PRESSURE_FACTOR_KPA,
    TIME_FACTOR,
    normalise_unit,
)

FloatArray = NDArray[np.float64]

ColumnRef = str | int | None

_DIRECTION_WORDS = {
    "+1": 1, "1": 1, "+": 1, "up": 1, "fwd": 1, "forward": 1, "f": 1, "pos": 1, "positive": 1,
    "-1": -1, "−1": -1, "-": -1, "down": -1, "bwd": -1, "backward": -1, "b": -1, "rev": -1,
    "reverse": -1, "neg": -1, "negative": -1,
}
_UNIT_IN_NAME = re.compile(r"^(?P<name>.*?)\s*(?:\[(?P<b>[^\]]*)\]|\((?P<p>[^)]*)\))\s*$")


@dataclass(frozen=True)
class ColumnMap:
    """Which column holds what: a header name, a 1-based column number, or None.

    None means "the column with the standard name (the field's name) if there is one"; a value
    given explicitly must exist in the file.
    """

    position: ColumnRef = None
    deviation: ColumnRef = None
    run: ColumnRef = None
    direction: ColumnRef = None
    time: ColumnRef = None
    air_temp: ColumnRef = None
    material_temp: ColumnRef = None
    pressure: ColumnRef = None
    humidity: ColumnRef = None

    @classmethod
    def from_mapping(cls, mapping: dict[str, object]) -> ColumnMap:
        """From a plan's ``columns = {position = "X", deviation = 2, ...}``; unknown keys raise
        ValueError naming them."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(mapping) - known)
        if unknown:
            raise ValueError(
                f"unknown column key(s) {', '.join(unknown)}; use {', '.join(sorted(known))}"
            )
        values: dict[str, ColumnRef] = {}
        for key, value in mapping.items():
            if isinstance(value, bool) or not isinstance(value, str | int):
                raise ValueError(f"column {key}: expected a header name or a column number")
            if isinstance(value, int) and value < 1:
                raise ValueError(f"column {key}: column numbers start at 1, got {value}")
            values[key] = value
        return cls(**values)  # type: ignore[arg-type]


@dataclass(frozen=True)
class TableFormat:
    """How to read a table: its columns, units and where the data start.

    ``deviation_unit`` None means the file does not say (the plan's ``deviation_unit`` applies)
    unless a header name carries a unit. ``delimiter`` None detects comma, semicolon, tab or
    whitespace from the first line. ``data_marker`` is a line after which the data start (e.g.
    ``":START"``); the header is then the last text line before it.
    """

    columns: ColumnMap = field(default_factory=ColumnMap)
    position_unit: str | None = None
    deviation_unit: str | None = None
    time_unit: str | None = None
    pressure_unit: str | None = None
    delimiter: str | None = None
    data_marker: str | None = None
    comment: str = "#"
    target_tolerance_mm: float = 1e-3

    def __post_init__(self) -> None:
        if not self.comment:
            raise ValueError("comment: the comment prefix cannot be empty")
        if not self.target_tolerance_mm > 0:
            raise ValueError("target_tolerance_mm must be positive")


@dataclass(frozen=True, eq=False)
class TableFile:
    """A table, read: ``data`` in the file's deviation unit ``unit`` (None if not stated)."""

    path: Path
    data: LineData
    unit: str | None
    columns: dict[str, int]
    header: tuple[str, ...]
    raw: bytes = field(repr=False)


@dataclass
class _Layout:
    header: tuple[str, ...]
    header_line: int | None
    first_data_line: int
    delimiter: str | None
    start_time: float | None


def read_table(path: str | Path, table_format: TableFormat | None = None) -> TableFile:
    """Read a table of readings into runs × targets.

    Raises
    ------
    FormatError
        Naming the file and line for a missing column, a value that is not a number, a run that
        goes back on itself, a target read twice in one run, or mixed directions within a run.
    """
    fmt = table_format or TableFormat()
    source = SourceText.read(path)
    layout = _layout(source, fmt)
    columns, units = _resolve_columns(source, layout, fmt)
    rows = _rows(source, layout, fmt, columns)
    data = _assemble(source, fmt, columns, units, rows, layout)
    return TableFile(source.path, data, units["deviation"], columns, layout.header, source.raw)


# ---- layout ------------------------------------------------------------------------------


def _is_comment(text: str, fmt: TableFormat) -> bool:
    stripped = text.strip()
    return not stripped or stripped.startswith(fmt.comment) or stripped.startswith("//")


def split_fields(text: str, delimiter: str | None) -> list[str]:
    if delimiter is None:
        return text.split()
    return [part.strip() for part in text.split(delimiter)]


def detect_delimiter(text: str) -> str | None:
    for candidate in (",", ";", "\t"):
        if candidate in text:
            return candidate
    return None


def _numeric(token: str) -> bool:
    try:
        float(token.replace(",", "."))
    except ValueError:
        return False
    return True


def _layout(source: SourceText, fmt: TableFormat) -> _Layout:
    start_time = None
    for number, text in source.numbered():
        stripped = text.strip()
        if stripped.startswith(fmt.comment):
            key, colon, value = stripped[len(fmt.comment):].partition(":")
            if colon and key.strip().lower() == "start_time":
                start_time = _iso_time(value.strip(), source, number, "start_time")
    whitespace = fmt.delimiter is not None and fmt.delimiter.lower() in ("whitespace", "space", " ")
    fixed = None if whitespace else fmt.delimiter
    if fmt.data_marker is not None:
        marker = next(
            (n for n, text in source.numbered() if text.strip() == fmt.data_marker), None
        )
        if marker is None:
            raise source.error(
                f"the data marker line {fmt.data_marker!r} was not found", source.last_line
            )
        header_line = next(
            (n for n in range(marker - 1, 0, -1) if not _is_comment(source.lines[n - 1], fmt)),
            None,
        )
        first_data = marker + 1
        probe = source.lines[header_line - 1] if header_line else ""
        delimiter = fixed if (whitespace or fixed) else detect_delimiter(probe)
    else:
        first = next((n for n, text in source.numbered() if not _is_comment(text, fmt)), None)
        if first is None:
            raise source.error("the file holds no data rows", source.last_line)
        delimiter = fixed if (whitespace or fixed) else detect_delimiter(source.lines[first - 1])
        tokens = split_fields(source.lines[first - 1], delimiter)
        if all(_numeric(t) for t in tokens if t):
            header_line, first_data = None, first
        else:
            header_line, first_data = first, first + 1
    header: tuple[str, ...] = ()
    if header_line is not None:
        header = tuple(split_fields(source.lines[header_line - 1], delimiter))
    return _Layout(header, header_line, first_data, delimiter, start_time)


def _split_unit(name: str) -> tuple[str, str | None]:
    """``"Position [mm]"`` → ("position", "mm"); ``"deviation_um"`` → ("deviation", "um")."""
    text = name.strip()
    match = _UNIT_IN_NAME.match(text)
    if match:
        return _plain(match.group("name")), normalise_unit(match.group("b") or match.group("p"))
    plain = _plain(text)
    base, _, suffix = plain.rpartition("_")
    if base and suffix in _KNOWN_SUFFIXES:
        return base, normalise_unit(suffix)
    return plain, None


def _plain(name: str) -> str:
    return "_".join(name.strip().lower().split())


_KNOWN_SUFFIXES = (
    set(DEVIATION_FACTOR) | set(POSITION_FACTOR) | set(TIME_FACTOR) | set(PRESSURE_FACTOR_KPA)
    | {"c", "pct"}
)
_REQUIRED = ("position", "deviation")


def _resolve_columns(
    source: SourceText, layout: _Layout, fmt: TableFormat
) -> tuple[dict[str, int], dict[str, str | None]]:
    """0-based indexes of the mapped columns and the unit of each (declared or from the header)."""
    names = [_split_unit(h) for h in layout.header]
    where = layout.header_line or layout.first_data_line
    columns: dict[str, int] = {}
    header_units: dict[str, str | None] = {}
    for f in fields(ColumnMap):
        ref = getattr(fmt.columns, f.name)
        if isinstance(ref, int):
            if layout.header and ref > len(layout.header):
                raise source.error(
                    f"column {f.name} = {ref}, but the header has {len(layout.header)} columns",
                    where,
                )
            columns[f.name] = ref - 1
            header_units[f.name] = names[ref - 1][1] if names else None
            continue
        wanted = _plain(ref) if isinstance(ref, str) else f.name
        found = [i for i, h in enumerate(layout.header) if _plain(h) == wanted]
        if not found:
            found = [i for i, (plain, _) in enumerate(names) if plain == wanted]
        if found:
            columns[f.name] = found[0]
            header_units[f.name] = names[found[0]][1]
        elif ref is not None or f.name in _REQUIRED:
            if not layout.header:
                raise source.error(
                    f"the file has no header row: map the {f.name} column by number "
                    f"(e.g. columns = {{ {f.name} = 2 }})",
                    where,
                )
            raise source.error(
                f"no {f.name} column named {ref or f.name!r}; the header has "
                f"{', '.join(repr(h) for h in layout.header)}",
                where,
            )
    declared = {
        "position": fmt.position_unit,
        "deviation": fmt.deviation_unit,
        "time": fmt.time_unit,
        "pressure": fmt.pressure_unit,
    }
    units: dict[str, str | None] = {}
    for key, unit in declared.items():
        from_header = header_units.get(key)
        if unit is not None and from_header is not None and normalise_unit(unit) != from_header:
            raise source.error(
                f"the {key} unit is declared as {unit!r} but the header says {from_header!r}",
                where,
            )
        units[key] = normalise_unit(unit) if unit is not None else from_header
    tables = {"position": POSITION_FACTOR, "deviation": DEVIATION_FACTOR, "time": TIME_FACTOR,
              "pressure": PRESSURE_FACTOR_KPA}
    for key, unit in units.items():
        if unit is not None and unit not in tables[key]:
            raise source.error(
                f"{key} unit {unit!r} is not supported; use one of {', '.join(tables[key])}", where
            )
    return columns, units


# ---- rows --------------------------------------------------------------------------------


@dataclass
class _Rows:
    lines: list[int] = field(default_factory=list)
    values: dict[str, list[float]] = field(default_factory=dict)
    absolute_time: bool = False
    run: list[str] = field(default_factory=list)
    direction: list[int] = field(default_factory=list)


def _iso_time(token: str, source: SourceText, line: int, what: str) -> float:
    try:
        moment = datetime.fromisoformat(token.strip().replace("Z", "+00:00"))
    except ValueError:
        raise source.error(
            f"{what}: expected a number or an ISO 8601 date-time, found {token!r}", line
        ) from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return moment.timestamp()


def _rows(
    source: SourceText, layout: _Layout, fmt: TableFormat, columns: dict[str, int]
) -> _Rows:
    rows = _Rows(values={k: [] for k in columns if k not in ("run", "direction")})
    decimal_comma = layout.delimiter == ";"
    needed = max(columns.values()) + 1
    for number in range(layout.first_data_line, len(source.lines) + 1):
        text = source.lines[number - 1]
        if _is_comment(text, fmt):
            continue
        tokens = split_fields(text, layout.delimiter)
        if len(tokens) < needed:
            raise source.error(
                f"expected at least {needed} fields, found {len(tokens)}", number
            )
        rows.lines.append(number)
        for key, index in columns.items():
            token = tokens[index]
            if decimal_comma:
                token = token.replace(",", ".")
            if key == "run":
                rows.run.append(token.strip())
            elif key == "direction":
                word = token.strip().lower()
                if word not in _DIRECTION_WORDS:
                    raise source.error(
                        f"direction: expected +1/-1, up/down or fwd/bwd, found {token!r}", number
                    )
                rows.direction.append(_DIRECTION_WORDS[word])
            elif key == "time" and not _numeric(token):
                rows.values[key].append(_iso_time(token, source, number, "time"))
                rows.absolute_time = True
            else:
                rows.values[key].append(parse_float(token, source, number, key))
    if not rows.lines:
        raise source.error("the file holds no data rows", source.last_line)
    return rows


def _assemble(
    source: SourceText,
    fmt: TableFormat,
    columns: dict[str, int],
    units: dict[str, str | None],
    rows: _Rows,
    layout: _Layout,
) -> LineData:
    count = len(rows.lines)
    position = np.asarray(rows.values["position"]) * POSITION_FACTOR[units["position"] or "mm"]
    relative = position - position[0]
    run_index = _runs(rows, relative)
    targets, target_index = cluster_targets(relative, fmt.target_tolerance_mm)
    runs = int(run_index.max()) + 1
    occupied = np.zeros((runs, len(targets)), dtype=np.int64)
    for row, (r, k) in enumerate(zip(run_index, target_index, strict=True)):
        if occupied[r, k]:
            raise source.error(
                f"target {targets[k]:g} mm is read twice in one run (first at line "
                f"{occupied[r, k]}); add a run column or check the positions",
                rows.lines[row],
            )
        occupied[r, k] = rows.lines[row]
    direction = _directions(source, rows, run_index, relative, runs)

    time_source = "time column"
    start_time = layout.start_time or 0.0
    if "time" in columns:
        raw_time = np.asarray(rows.values["time"])
        if rows.absolute_time:
            # date-times are absolute: the origin is the start_time comment or the first row
            if layout.start_time is None:
                start_time = float(raw_time[0])
            times_flat = raw_time - start_time
        else:
            times_flat = raw_time * TIME_FACTOR[units["time"] or "s"]
    else:
        time_source = "row order (no time column): readings 1 s apart"
        times_flat = np.arange(count, dtype=float)

    def grid(values: Sequence[float] | FloatArray) -> FloatArray:
        out = np.full((runs, len(targets)), np.nan)
        out[run_index, target_index] = values
        return out

    air = grid(rows.values["air_temp"]) if "air_temp" in columns else None
    material = grid(rows.values["material_temp"]) if "material_temp" in columns else None

    def ends(key: str, factor: float = 1.0) -> tuple[float, float] | None:
        if key not in columns:
            return None
        values = rows.values[key]
        return (values[0] * factor, values[-1] * factor)

    pressure_factor = PRESSURE_FACTOR_KPA[units["pressure"] or "kpa"]
    material_ends = ends("material_temp")
    environment = Environment(
        air_temp_c=ends("air_temp"),
        air_pressure_kpa=ends("pressure", pressure_factor),
        air_humidity_pct=ends("humidity"),
        material_temp_c=(material_ends,) if material_ends else (),
    )
    return LineData(
        targets_mm=targets,
        deviations=grid(rows.values["deviation"]),
        run_direction=direction,
        times_s=grid(times_flat),
        start_time=start_time,
        environment=environment,
        air_temp_c=air,
        material_temp_c=material,
        metadata={"time_source": time_source},
    )


def cluster_targets(
    relative_mm: FloatArray, tolerance_mm: float
) -> tuple[FloatArray, NDArray[np.int64]]:
    """Distinct targets (ascending) and each value's target index; values closer than the
    tolerance to their neighbour are one target (its mean)."""
    order = np.argsort(relative_mm, kind="stable")
    ordered = relative_mm[order]
    new_group = np.concatenate([[True], np.diff(ordered) > tolerance_mm])
    group_sorted = np.cumsum(new_group) - 1
    sums = np.bincount(group_sorted, weights=ordered)
    counts = np.bincount(group_sorted)
    targets = sums / counts
    index = np.empty_like(group_sorted)
    index[order] = group_sorted
    return targets, index.astype(np.int64)


def _runs(rows: _Rows, relative: FloatArray) -> NDArray[np.int64]:
    if rows.run:
        ids: dict[str, int] = {}
        return np.array([ids.setdefault(r, len(ids)) for r in rows.run], dtype=np.int64)
    index = np.zeros(len(relative), dtype=np.int64)
    run = 0
    trend = 0.0
    for row in range(1, len(relative)):
        step = relative[row] - relative[row - 1]
        if step == 0 or (trend and math.copysign(1.0, step) != trend):
            run += 1
            trend = 0.0
        else:
            trend = math.copysign(1.0, step)
        index[row] = run
    return index


def _directions(
    source: SourceText,
    rows: _Rows,
    run_index: NDArray[np.int64],
    relative: FloatArray,
    runs: int,
) -> NDArray[np.int64]:
    direction = np.zeros(runs, dtype=np.int64)
    for run in range(runs):
        members = np.flatnonzero(run_index == run)
        first_line = rows.lines[members[0]]
        if rows.direction:
            values = {rows.direction[m] for m in members}
            if len(values) > 1:
                raise source.error(
                    "one run holds readings of both directions; check the run and direction "
                    "columns",
                    first_line,
                )
            direction[run] = values.pop()
            continue
        steps = np.diff(relative[members])
        if len(members) < 2:
            raise source.error(
                "a run with a single reading has no direction of travel: add a direction column",
                first_line,
            )
        if np.all(steps > 0):
            direction[run] = 1
        elif np.all(steps < 0):
            direction[run] = -1
        else:
            bad = members[1 + int(np.argmax(np.sign(steps) != np.sign(steps[0])))]
            raise source.error(
                "the run goes back on itself here: add a direction column (or a run column "
                "that separates the runs)",
                rows.lines[bad],
            )
    return direction


# ---- writer ------------------------------------------------------------------------------


def write_table(
    path: str | Path,
    data: LineData,
    *,
    deviation_unit: str = "um",
    delimiter: str = ",",
    first_target_mm: float = 0.0,
) -> None:
    """Write one row per reading (runs in order, targets in visit order) that :func:`read_table`
    reads back exactly with the default :class:`TableFormat`.

    Columns: run, direction, position_mm, deviation_<unit>, time_s and, when present,
    air_temp_c and material_temp_c; a ``# start_time:`` comment keeps the time origin. Missing
    readings (NaN) are left out.
    """
    header = ["run", "direction", "position_mm", f"deviation_{deviation_unit}", "time_s"]
    extra = [(name, values) for name, values in (("air_temp_c", data.air_temp_c),
                                                ("material_temp_c", data.material_temp_c))
             if values is not None]
    header += [name for name, _ in extra]
    lines = [f"# start_time: {format_time_iso(data.start_time)}", delimiter.join(header)]
    visit = np.arange(data.targets_mm.size)
    for run in range(data.runs):
        order = visit if data.run_direction[run] > 0 else visit[::-1]
        for k in order:
            value = data.deviations[run, k]
            if not np.isfinite(value):
                continue
            cells = [
                str(run + 1),
                "+1" if data.run_direction[run] > 0 else "-1",
                repr(float(first_target_mm + data.targets_mm[k])),
                repr(float(value)),
                repr(float(data.times_s[run, k])),
            ]
            cells += [repr(float(values[run, k])) for _, values in extra]
            lines.append(delimiter.join(cells))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
