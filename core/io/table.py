"""Generic tables of readings (CSV, semicolon, tab or whitespace separated) with a column map.

One row is one reading. A :class:`ColumnMap` names the columns (by header name, or by 1-based
number for a file without a header row); :class:`TableFormat` declares the units and how to find
the data (:mod:`.table_layout` finds the header, splits the fields and matches the names). Only
position and deviation are required:

- position: the target (nominal position) along the line. Targets in :class:`LineData` are
  relative to the first row's position; rows within ``target_tolerance_mm`` are the same target.
- run: readings with the same run id form a run. Without a run column a new run starts whenever
  the travel reverses or a position repeats the previous row's.
- direction: +1/−1, ``+``/``-``, ``up``/``down``, ``fwd``/``bwd``, ``forward``/``backward``.
  Without it a run's direction is the way its positions go (a one-reading run needs the column).
- time: a number with a unit, or ISO 8601 date-times; without it readings are taken 1 s apart in
  row order (recorded in the metadata as ``time_source``). Within a run time never goes back.
- air_temp, material_temp, pressure, humidity (%RH): optional; converted to °C and kPa.

**Units.** Every quantity read has a unit: from the header (``Flat [mm]``, ``(mm)``, a ``_mm``
suffix) or declared by the format (the plan's ``deviation_unit``, ``pressure_unit``, …, or the
command line); both given must agree. A column without a unit is refused with a message asking
for one — except positions in a table a plan names: plan.toml states lengths in mm, so there they
are mm unless the header or ``position_unit`` says otherwise. A deviation
column named like an angle (yaw, pitch, roll) or a preamble ``TestType : Angular`` refuses a length
unit, and ``TestType : Flatness`` (or Linear, Straightness) refuses an angle.

**Values** must be numbers of the strict grammar of :mod:`.source` and lie within the bounds of
:mod:`.limits` once converted; a line's grid of runs × targets is checked against
``MAX_READINGS`` before it is allocated. A comment line ``# start_time: <ISO 8601>`` sets the time
origin of relative times.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..measurement import Environment, LineData
from .limits import (
    AIR_TEMP_RANGE_C,
    HUMIDITY_RANGE_PCT,
    MATERIAL_TEMP_RANGE_C,
    MAX_ABS_DEVIATION,
    MAX_ABS_POSITION_MM,
    MAX_ABS_TIME_S,
    MAX_READINGS,
    MIN_TARGET_SPACING_MM,
    PRESSURE_RANGE_KPA,
    size_text,
)
from .source import (
    BLANKS,
    SourceText,
    check_magnitude,
    check_range,
    format_time_iso,
    is_number,
    parse_float,
    quote,
)
from .table_layout import (
    ANGULAR_NAMES,
    DESCRIPTION,
    ENVIRONMENT_COLUMNS,
    HUMIDITY_UNITS,
    ColumnMap,
    Layout,
    detect_delimiter,
    find_layout,
    is_comment,
    name_key,
    resolve_columns,
    row_fits,
    split_fields,
    split_unit,
)
from .units import (
    ANGLE_UNITS,
    DEVIATION_FACTOR,
    POSITION_FACTOR,
    PRESSURE_FACTOR_KPA,
    TEMPERATURE_UNITS,
    TIME_FACTOR,
    choices,
    describe,
    normalise_unit,
)

__all__ = [
    "ColumnMap",
    "TableFile",
    "TableFormat",
    "cluster_targets",
    "detect_delimiter",
    "read_table",
    "split_fields",
    "split_unit",
    "write_table",
]

FloatArray = NDArray[np.float64]

_DIRECTION_WORDS = {
    "+1": 1,
    "1": 1,
    "+": 1,
    "up": 1,
    "fwd": 1,
    "forward": 1,
    "f": 1,
    "pos": 1,
    "positive": 1,
    "-1": -1,
    "−1": -1,
    "-": -1,
    "down": -1,
    "bwd": -1,
    "backward": -1,
    "b": -1,
    "rev": -1,
    "reverse": -1,
    "neg": -1,
    "negative": -1,
}
_REQUIRED = ("position", "deviation")
_UNIT_TABLES: dict[str, dict[str, object]] = {
    "position": POSITION_FACTOR,  # type: ignore[dict-item]
    "deviation": DEVIATION_FACTOR,  # type: ignore[dict-item]
    "time": TIME_FACTOR,  # type: ignore[dict-item]
    "pressure": PRESSURE_FACTOR_KPA,  # type: ignore[dict-item]
    "air_temp": TEMPERATURE_UNITS,  # type: ignore[dict-item]
    "material_temp": TEMPERATURE_UNITS,  # type: ignore[dict-item]
}
_UNIT_OPTION = {
    "position": "position_unit",
    "deviation": "deviation_unit",
    "time": "time_unit",
    "pressure": "pressure_unit",
    "air_temp": "temperature_unit",
    "material_temp": "temperature_unit",
}
_UNIT_FLAG = {"deviation": "--unit", "position": "--position-unit"}


@dataclass(frozen=True)
class TableFormat:
    """How to read a table: its columns, units and where the data start.

    A unit None means the format does not declare it: the header must then carry it.
    ``position_unit_default`` is the unit of positions when neither says: plan.toml states lengths
    in mm, so a table a plan names has mm there; a table read alone has none, and a position
    column without a unit is then refused like any other. ``delimiter`` None detects comma,
    semicolon, tab or whitespace from the header. ``data_marker`` is a line after which the data
    start (e.g. ``":START"``).
    ``environment`` False leaves the environment columns unread unless they are mapped (a
    command that does not use them need not ask for their units).
    """

    columns: ColumnMap = field(default_factory=ColumnMap)
    position_unit: str | None = None
    deviation_unit: str | None = None
    time_unit: str | None = None
    pressure_unit: str | None = None
    temperature_unit: str | None = None
    delimiter: str | None = None
    data_marker: str | None = None
    comment: str = "#"
    target_tolerance_mm: float = 1e-3
    environment: bool = True
    position_unit_default: str | None = None

    def __post_init__(self) -> None:
        if not self.comment:
            raise ValueError("comment: the comment prefix cannot be empty")
        if not (
            math.isfinite(self.target_tolerance_mm)
            and self.target_tolerance_mm >= MIN_TARGET_SPACING_MM
        ):
            raise ValueError(f"target_tolerance_mm must be at least {MIN_TARGET_SPACING_MM} mm")

    def declared(self, key: str) -> str | None:
        option = _UNIT_OPTION.get(key)
        value = getattr(self, option) if option else None
        return value if isinstance(value, str) else None


@dataclass(frozen=True, eq=False)
class TableFile:
    """A table, read: ``data`` in the file's deviation unit ``unit`` (temperatures in °C,
    pressure in kPa, positions in mm); ``units`` the unit of every column read."""

    path: Path
    data: LineData
    unit: str
    columns: dict[str, int]
    header: tuple[str, ...]
    raw: bytes = field(repr=False)
    units: dict[str, str | None] = field(default_factory=dict)


def read_table(path: str | Path, table_format: TableFormat | None = None) -> TableFile:
    """Read a table of readings into runs × targets.

    Raises
    ------
    FormatError
        Naming the file and line for a missing or ambiguous column, a header whose names do not
        match the rows' fields, a column without a unit, a value that is not a number or not
        possible, a run that goes back on itself, a target read twice in one run, mixed
        directions within a run, time going back, or more readings than a line may hold.
    """
    fmt = table_format or TableFormat()
    source = SourceText.read(path)
    layout = find_layout(
        source, delimiter=fmt.delimiter, data_marker=fmt.data_marker, comment=fmt.comment
    )
    wanted = ("position", "deviation", "run", "direction", "time") + (
        ENVIRONMENT_COLUMNS if fmt.environment else ()
    )
    columns, header_units, shown = resolve_columns(source, layout, fmt.columns, wanted, _REQUIRED)
    units = _units(source, layout, fmt, columns, header_units, shown)
    rows = _rows(source, layout, fmt, columns, units, shown)
    data = _assemble(source, fmt, columns, units, rows)
    return TableFile(
        source.path, data, units["deviation"] or "", columns, layout.header, source.raw, units
    )


# ---- units -------------------------------------------------------------------------------


def _units(
    source: SourceText,
    layout: Layout,
    fmt: TableFormat,
    columns: dict[str, int],
    header_units: dict[str, str | None],
    shown: dict[str, str],
) -> dict[str, str | None]:
    """The unit of every column read: declared and header units agree; a missing one is an
    error asking for it (positions: mm by the plan contract; times: checked per value, since
    ISO date-times need none)."""
    where = layout.header_line or layout.first_data_line
    units: dict[str, str | None] = {}
    for key in columns:
        from_header = header_units.get(key)
        declared_raw = fmt.declared(key)
        declared = normalise_unit(declared_raw) if declared_raw is not None else None
        if key == "humidity":
            if from_header is not None and from_header not in HUMIDITY_UNITS:
                raise source.error(
                    f"humidity column {shown[key]}: unit {from_header!r} is not %RH", where
                )
            continue
        if key not in _UNIT_TABLES:
            continue
        if declared is not None and from_header is not None and declared != from_header:
            raise source.error(
                f"the {DESCRIPTION[key]} unit is declared as {declared_raw!r} "
                f"({_UNIT_OPTION[key]}) but the header {shown[key]} says "
                f"{describe(from_header)!r}; correct one of them",
                where,
            )
        unit = declared or from_header
        if unit is None and key == "position":
            unit = fmt.position_unit_default
        if unit is not None and unit not in _UNIT_TABLES[key]:
            raise source.error(
                f"{DESCRIPTION[key]} unit {unit!r} of column {shown[key]} is not supported; use "
                f"one of {choices(tuple(_UNIT_TABLES[key]))}",
                where,
            )
        if unit is None and key != "time":
            raise source.error(_missing_unit(key, shown[key]), where)
        units[key] = unit
    _check_kind(source, layout, units.get("deviation"), shown, columns)
    return units


def _missing_unit(key: str, column: str) -> str:
    examples = {
        "position": "mm, um or inch",
        "deviation": "um, nm, mm or inch for lengths; urad, mrad, arcsec or deg for angles",
        "time": "s, ms, min or h",
        "pressure": "Pa, hPa, mbar, kPa, mmHg or inHg",
        "air_temp": "C, F or K",
        "material_temp": "C, F or K",
    }[key]
    flag = f", {_UNIT_FLAG[key]} on the command line" if key in _UNIT_FLAG else ""
    return (
        f"the {DESCRIPTION[key]} column {column} has no unit and volucal does not assume "
        f"one: give {_UNIT_OPTION[key]} ({examples}) in the plan's [[line]]{flag}, or write "
        f"it in the header, e.g. '{column.strip(chr(39))} [unit]'"
    )


def _check_kind(
    source: SourceText,
    layout: Layout,
    unit: str | None,
    shown: dict[str, str],
    columns: dict[str, int],
) -> None:
    """Refuse an angular file read with a length unit, and a length file with an angle unit."""
    if unit is None:
        return
    angle_unit = unit in ANGLE_UNITS
    name = layout.header[columns["deviation"]] if layout.header else ""
    base = name_key(split_unit(name)[0]) if name else ""
    if not angle_unit and any(base.startswith(word) for word in ANGULAR_NAMES):
        raise source.error(
            f"the deviation column {shown['deviation']} holds an angle, but its unit is "
            f"{describe(unit)} (a length): give its angular unit (urad, mrad, arcsec or deg) and "
            "read it as an angular line",
            layout.header_line or layout.first_data_line,
        )
    if layout.kind is not None:
        kind, line = layout.kind
        if kind == "angle" and not angle_unit:
            raise source.error(
                f"line {line} says this is an angular measurement, but the deviation unit is "
                f"{describe(unit)} (a length): give its angular unit (urad, mrad, arcsec or deg) "
                "and read it as an angular line",
                line,
            )
        if kind == "length" and angle_unit:
            raise source.error(
                f"line {line} says this is a length measurement, but the deviation unit is "
                f"{describe(unit)} (an angle): give its length unit (um, nm, mm or inch)",
                line,
            )


# ---- rows --------------------------------------------------------------------------------


@dataclass
class _Rows:
    lines: list[int] = field(default_factory=list)
    values: dict[str, list[float]] = field(default_factory=dict)
    absolute_time: bool | None = None
    run: list[str] = field(default_factory=list)
    direction: list[int] = field(default_factory=list)


def _iso_time(token: str, source: SourceText, line: int, what: str) -> float:
    text = token.strip(BLANKS)
    try:
        if not text.isascii():
            raise ValueError
        moment = datetime.fromisoformat(text.replace("Z", "+00:00"))
        if moment.tzinfo is None:
            moment = moment.replace(tzinfo=UTC)
        return moment.timestamp()
    except (ValueError, OverflowError, OSError):
        raise source.error(
            f"{what}: expected a number or an ISO 8601 date-time, found {quote(token)}", line
        ) from None


def _start_time(source: SourceText, fmt: TableFormat) -> float | None:
    start = None
    for number, text in source.numbered():
        stripped = text.strip(BLANKS)
        if stripped.startswith(fmt.comment):
            key, colon, value = stripped[len(fmt.comment) :].partition(":")
            if colon and key.strip(BLANKS).lower() == "start_time":
                start = _iso_time(value, source, number, "start_time")
    return start


def _rows(
    source: SourceText,
    layout: Layout,
    fmt: TableFormat,
    columns: dict[str, int],
    units: dict[str, str | None],
    shown: dict[str, str],
) -> _Rows:
    rows = _Rows(values={k: [] for k in columns if k not in ("run", "direction")})
    decimal_comma = layout.delimiter == ";"
    deviation_factor = DEVIATION_FACTOR[units["deviation"] or "um"]
    position_factor = POSITION_FACTOR[units["position"] or "mm"]
    needed = max(columns.values()) + 1
    for number in range(layout.first_data_line, len(source.lines) + 1):
        text = source.lines[number - 1]
        if is_comment(text, fmt.comment):
            continue
        tokens = split_fields(text, layout.delimiter)
        if not row_fits(layout, len(tokens), needed):
            against = (
                f"the header (line {layout.header_line})"
                if layout.header_line
                else f"the first row (line {layout.first_data_line})"
            )
            raise source.error(
                f"expected {layout.field_count} fields as in {against}, found {len(tokens)}",
                number,
            )
        rows.lines.append(number)
        for key, index in columns.items():
            token = tokens[index]
            if decimal_comma:
                token = token.replace(",", ".")
            if key == "run":
                rows.run.append(token.strip(BLANKS))
            elif key == "direction":
                word = token.strip(BLANKS).lower()
                if word not in _DIRECTION_WORDS:
                    raise source.error(
                        f"direction: expected +1/-1, up/down or fwd/bwd, found {quote(token)}",
                        number,
                    )
                rows.direction.append(_DIRECTION_WORDS[word])
            elif key == "time":
                rows.values[key].append(_time_value(token, source, number, rows, units, shown))
            else:
                value = parse_float(token, source, number, DESCRIPTION[key])
                rows.values[key].append(
                    _convert(key, value, source, number, units, deviation_factor, position_factor)
                )
    if not rows.lines:
        raise source.error("the file holds no data rows", source.last_line)
    return rows


def _time_value(
    token: str,
    source: SourceText,
    number: int,
    rows: _Rows,
    units: dict[str, str | None],
    shown: dict[str, str],
) -> float:
    absolute = not is_number(token)
    if rows.absolute_time is not None and absolute != rows.absolute_time:
        raise source.error("time: the column mixes numbers and date-times", number)
    rows.absolute_time = absolute
    if absolute:
        return _iso_time(token, source, number, "time")
    if units.get("time") is None:
        raise source.error(_missing_unit("time", shown["time"]), number)
    value = parse_float(token, source, number, "time") * TIME_FACTOR[units["time"] or "s"]
    return check_magnitude(value, MAX_ABS_TIME_S, source, number, "time (s)")


def _convert(
    key: str,
    value: float,
    source: SourceText,
    number: int,
    units: dict[str, str | None],
    deviation_factor: float,
    position_factor: float,
) -> float:
    """A row's value in volucal's unit (deviations stay in the file's unit), checked."""
    unit = units.get(key)
    if key == "position":
        return check_magnitude(
            value * position_factor, MAX_ABS_POSITION_MM, source, number, "position (mm)"
        )
    if key == "deviation":
        check_magnitude(
            value * deviation_factor,
            MAX_ABS_DEVIATION,
            source,
            number,
            f"deviation ({'µrad' if unit in ANGLE_UNITS else 'µm'})",
        )
        return value
    if key in ("air_temp", "material_temp"):
        factor, offset = TEMPERATURE_UNITS[unit or "c"]
        celsius = value * factor + offset
        low, high = AIR_TEMP_RANGE_C if key == "air_temp" else MATERIAL_TEMP_RANGE_C
        return check_range(
            celsius,
            low,
            high,
            source,
            number,
            f"{DESCRIPTION[key]} (°C)",
            f"check temperature_unit (read as {describe(unit or 'c')})",
        )
    if key == "pressure":
        kpa = value * PRESSURE_FACTOR_KPA[unit or "kpa"]
        return check_range(
            kpa,
            *PRESSURE_RANGE_KPA,
            source,
            number,
            "air pressure (kPa)",
            f"{value:g} {describe(unit or 'kpa')} cannot be air pressure; check "
            "pressure_unit (mmHg? hPa?)",
        )
    if key == "humidity":
        return check_range(value, *HUMIDITY_RANGE_PCT, source, number, "humidity (%RH)")
    return value


# ---- assembly ----------------------------------------------------------------------------


def _assemble(
    source: SourceText,
    fmt: TableFormat,
    columns: dict[str, int],
    units: dict[str, str | None],
    rows: _Rows,
) -> LineData:
    count = len(rows.lines)
    position = np.asarray(rows.values["position"])
    relative = position - position[0]
    run_index = _runs(rows, relative)
    targets, target_index = cluster_targets(relative, fmt.target_tolerance_mm)
    runs = int(run_index.max()) + 1
    cells = runs * len(targets)
    if cells > MAX_READINGS:
        raise source.error(
            f"{size_text(count)} rows make {size_text(runs)} runs × {size_text(len(targets))} "
            f"targets = {size_text(cells)} readings, beyond the {size_text(MAX_READINGS)} a line "
            "may hold (docs/formats.md, Limits): check the run column and the positions",
            rows.lines[-1],
        )
    first_line = np.zeros((runs, len(targets)), dtype=np.int64)
    for row, (r, k) in enumerate(zip(run_index, target_index, strict=True)):
        if first_line[r, k]:
            raise source.error(
                f"target {targets[k]:g} mm is read twice in one run (first at line "
                f"{first_line[r, k]}); add a run column or check the positions",
                rows.lines[row],
            )
        first_line[r, k] = rows.lines[row]
    direction = _directions(source, rows, run_index, relative, runs)

    time_source = "time column"
    start_time = _start_time(source, fmt)
    if "time" in columns:
        times_flat = np.asarray(rows.values["time"])
        if rows.absolute_time:
            # date-times are absolute: the origin is the start_time comment or the first row
            if start_time is None:
                start_time = float(times_flat[0])
            times_flat = times_flat - start_time
        _check_time_order(source, rows, run_index, times_flat)
    else:
        time_source = "row order (no time column): readings 1 s apart"
        times_flat = np.arange(count, dtype=float)

    def grid(values: Sequence[float] | FloatArray) -> FloatArray:
        out = np.full((runs, len(targets)), np.nan)
        out[run_index, target_index] = values
        return out

    air = grid(rows.values["air_temp"]) if "air_temp" in columns else None
    material = grid(rows.values["material_temp"]) if "material_temp" in columns else None

    def ends(key: str) -> tuple[float, float] | None:
        if key not in columns:
            return None
        values = rows.values[key]
        return (values[0], values[-1])

    material_ends = ends("material_temp")
    environment = Environment(
        air_temp_c=ends("air_temp"),
        air_pressure_kpa=ends("pressure"),
        air_humidity_pct=ends("humidity"),
        material_temp_c=(material_ends,) if material_ends else (),
    )
    metadata = {"time_source": time_source}
    if "pressure" in columns:
        metadata["pressure_unit_in_file"] = describe(units.get("pressure") or "kpa")
    for key in ("air_temp", "material_temp"):
        if key in columns:
            metadata["temperature_unit_in_file"] = describe(units.get(key) or "c")
    return LineData(
        targets_mm=targets,
        deviations=grid(rows.values["deviation"]),
        run_direction=direction,
        times_s=grid(times_flat),
        start_time=start_time or 0.0,
        environment=environment,
        air_temp_c=air,
        material_temp_c=material,
        metadata=metadata,
        origin_mm=float(position[0]),
    )


def _check_time_order(
    source: SourceText, rows: _Rows, run_index: NDArray[np.int64], times: FloatArray
) -> None:
    """Within a run, readings follow each other in time: a time that goes back is refused."""
    order = np.argsort(run_index, kind="stable")
    same_run = run_index[order][1:] == run_index[order][:-1]
    back = np.flatnonzero(same_run & (np.diff(times[order]) < 0))
    if back.size:
        row = int(order[back[0] + 1])
        raise source.error(
            "time goes back within a run here (readings of a run follow each "
            "other); check the time column",
            rows.lines[row],
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
    steps = np.diff(relative)
    sign = np.sign(steps)
    index = np.zeros(len(relative), dtype=np.int64)
    run = 0
    trend = 0.0
    for row in range(1, len(relative)):
        step_sign = sign[row - 1]
        if step_sign == 0 or (trend and step_sign != trend):
            run += 1
            trend = 0.0
        else:
            trend = step_sign
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
    order = np.argsort(run_index, kind="stable")
    bounds = np.searchsorted(run_index[order], np.arange(runs + 1))
    for run in range(runs):
        members = order[bounds[run] : bounds[run + 1]]
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
    extra = [
        (name, values)
        for name, values in (
            ("air_temp_c", data.air_temp_c),
            ("material_temp_c", data.material_temp_c),
        )
        if values is not None
    ]
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
