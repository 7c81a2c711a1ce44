"""Generic 2-D grid tables (CSV, semicolon, tab or whitespace separated) with a column map.

One row is one reading at one grid node. A :class:`GridColumnMap` names the columns by header
name or 1-based number (as :mod:`volucal.core.io.table` does for lines):

- ``x``, ``y``: the commanded position (required);
- per direction either ``measured_x``/``measured_y`` (the measured position: the deviation is
  measured − commanded) or ``deviation_x``/``deviation_y`` (the deviation itself); at least one
  direction;
- ``air_temp``, ``material_temp``, ``pressure``, ``humidity``: optional, per reading.

Every quantity read needs a unit, from the header (``"x [mm]"``, ``"dX (µm)"``, ``"x_mm"``) or
declared in the :class:`GridFormat`; a column without one is an error that asks for it, never a
default. A Heidenhain KGM grid-encoder export (nominal X, Y and the deviations dX, dY) is such a
table; so is the Aerotech Accuracy2D file (:mod:`volucal.core.io.accuracy2d` is its preset).

Checks that catch cut-short or mixed-up files, each naming the file and line: every data row has
as many fields as the header; positions lie on a regular grid; every node of the grid's rectangle
has a reading (unless ``complete=False``); a deviation over ``max_deviation_mm`` or an
environment value outside what air can be (``PLAUSIBLE``) means a column is wrong.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from .grid2d import GridLayoutError, GridMeasurement, common_lattice, missing_nodes
from .io.source import SourceText, parse_float
from .io.table import detect_delimiter, split_fields
from .io.table_layout import ColumnRef, column_refs
from .io.units import DEVIATION_FACTOR, POSITION_FACTOR, PRESSURE_FACTOR_KPA, normalise_unit

#: Pressure units (to kPa). Aerotech's Accuracy2D files give mmHg.
PRESSURE_TO_KPA = {
    **PRESSURE_FACTOR_KPA,
    "mmhg": 0.1333223874,
    "torr": 0.1333223684,
    "inhg": 3.386389,
}
LENGTH_UNITS = ("um", "nm", "mm", "m", "in")
TEMPERATURE_UNITS = {"c": 0.0, "degc": 0.0, "°c": 0.0, "k": -273.15}
#: Values outside these ranges (in volucal's units) mean a wrong column or unit.
PLAUSIBLE = {
    "air_temp": (0.0, 50.0, "°C"),
    "material_temp": (0.0, 60.0, "°C"),
    "pressure": (50.0, 120.0, "kPa"),
    "humidity": (0.0, 100.0, "%RH"),
}
_SYMBOL = {
    "um": "µm",
    "c": "°C",
    "degc": "°C",
    "°c": "°C",
    "k": "K",
    "mmhg": "mmHg",
    "inhg": "inHg",
    "kpa": "kPa",
    "hpa": "hPa",
    "pa": "Pa",
    "torr": "Torr",
}
_UNIT_IN_NAME = re.compile(r"^(?P<name>.*?)\s*(?:\[(?P<b>[^\]]*)\]|\((?P<p>[^)]*)\))\s*$")
_KIND = {
    "x": "position",
    "y": "position",
    "measured_x": "position",
    "measured_y": "position",
    "deviation_x": "deviation",
    "deviation_y": "deviation",
    "air_temp": "temperature",
    "material_temp": "temperature",
    "pressure": "pressure",
    "humidity": "humidity",
}


@dataclass(frozen=True)
class GridColumnMap:
    """Which column holds what: a header name, a 1-based column number, or None (the column
    named like the field, if there is one)."""

    x: ColumnRef = None
    y: ColumnRef = None
    measured_x: ColumnRef = None
    measured_y: ColumnRef = None
    deviation_x: ColumnRef = None
    deviation_y: ColumnRef = None
    air_temp: ColumnRef = None
    material_temp: ColumnRef = None
    pressure: ColumnRef = None
    humidity: ColumnRef = None

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, object]) -> GridColumnMap:
        """From ``{"x": "X [mm]", "deviation_x": 3, …}``; unknown keys raise ValueError."""
        known = [f.name for f in fields(cls)]
        return cls(**column_refs(mapping, known, "grid column"))  # type: ignore[arg-type]


@dataclass(frozen=True)
class GridFormat:
    """How to read a grid table.

    ``position_unit`` is the unit of the commanded and measured positions, ``deviation_unit``
    that of deviation columns, ``temperature_unit`` of both temperatures; a unit in the header
    is used when none is declared and must agree with a declared one. ``sign`` −1 reads a file
    whose deviations are commanded − measured. ``data_marker``: the data start after this line
    (the header is the last text line before it); ``end_marker``: they end at this line.
    ``unit_notes`` says where declared units come from (shown with the grid).
    """

    columns: GridColumnMap = field(default_factory=GridColumnMap)
    position_unit: str | None = None
    deviation_unit: str | None = None
    temperature_unit: str | None = None
    pressure_unit: str | None = None
    delimiter: str | None = None
    data_marker: str | None = None
    end_marker: str | None = None
    comment: str = "#"
    sign: int = 1
    upper_axis: str | None = None
    node_tolerance_mm: float = 1e-3
    complete: bool = True
    max_deviation_mm: float = 1.0
    unit_notes: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.sign not in (1, -1):
            raise ValueError(f"sign must be +1 or -1, got {self.sign}")
        if not self.comment:
            raise ValueError("comment: the comment prefix cannot be empty")
        if not self.node_tolerance_mm > 0 or not self.max_deviation_mm > 0:
            raise ValueError("node_tolerance_mm and max_deviation_mm must be positive")


@dataclass
class _Layout:
    header: tuple[str, ...]
    header_line: int | None
    first_data_line: int
    delimiter: str | None


def read_grid_table(
    path: str | Path,
    grid_format: GridFormat | None = None,
    *,
    name: str | None = None,
    metadata: Mapping[str, str] | None = None,
    source: SourceText | None = None,
) -> GridMeasurement:
    """Read a grid table into a :class:`GridMeasurement` (µm, mm, °C, kPa, %RH).

    Raises
    ------
    FormatError
        Naming the file and line: a missing column or unit, a row with another field count
        than the header, a value that is not a number, a position off the grid, a node without
        a reading, an implausible deviation or environment value.
    """
    fmt = grid_format or GridFormat()
    text = source or SourceText.read(path)
    layout = _layout(text, fmt)
    columns = _resolve_columns(text, layout, fmt)
    units, notes = _resolve_units(text, layout, fmt, columns)
    lines, values = _rows(text, layout, fmt, columns)
    grid = _assemble(text, fmt, columns, units, notes, lines, values, name, metadata or {})
    check_grid(text, grid, fmt.node_tolerance_mm, complete=fmt.complete)
    return grid


# ---- layout ------------------------------------------------------------------------------


def _is_comment(text: str, fmt: GridFormat) -> bool:
    stripped = text.strip()
    return not stripped or stripped.startswith(fmt.comment) or stripped.startswith("//")


def _numeric(token: str) -> bool:
    try:
        float(token.replace(",", "."))
    except ValueError:
        return False
    return True


def _delimiter(fmt: GridFormat, probe: str) -> str | None:
    if fmt.delimiter is not None and fmt.delimiter.lower() in ("whitespace", "space", " "):
        return None
    return fmt.delimiter if fmt.delimiter is not None else detect_delimiter(probe)


def _layout(source: SourceText, fmt: GridFormat) -> _Layout:
    if fmt.data_marker is not None:
        marker = next((n for n, t in source.numbered() if t.strip() == fmt.data_marker), None)
        if marker is None:
            raise source.error(
                f"no {fmt.data_marker!r} line before the data: the file is cut short or is not "
                "in this layout",
                source.last_line,
            )
        header_line = next(
            (n for n in range(marker - 1, 0, -1) if not _is_comment(source.lines[n - 1], fmt)), None
        )
        first = marker + 1
        probe = source.lines[header_line - 1] if header_line else ""
        if header_line is not None and all(_numeric(t) for t in probe.split()):
            header_line = None
    else:
        first_text = next((n for n, t in source.numbered() if not _is_comment(t, fmt)), None)
        if first_text is None:
            raise source.error("the file holds no data rows", source.last_line)
        probe = source.lines[first_text - 1]
        tokens = split_fields(probe, _delimiter(fmt, probe))
        if all(_numeric(t) for t in tokens if t):
            header_line, first = None, first_text
        else:
            header_line, first = first_text, first_text + 1
    delimiter = _delimiter(fmt, probe)
    header: tuple[str, ...] = ()
    if header_line is not None:
        header = _merge_units(
            tuple(
                h.strip().strip('"').strip("'")
                for h in split_fields(source.lines[header_line - 1], delimiter)
            )
        )
    return _Layout(header, header_line, first, delimiter)


def _merge_units(tokens: tuple[str, ...]) -> tuple[str, ...]:
    """In a whitespace-separated header, ``x [mm]`` splits in two: join a token that is only a
    bracketed unit to the name before it."""
    out: list[str] = []
    for token in tokens:
        if out and re.fullmatch(r"\[[^\]]*\]|\([^)]*\)", token):
            out[-1] = f"{out[-1]} {token}"
        else:
            out.append(token)
    return tuple(out)


def _plain(name: str) -> str:
    return "_".join(name.strip().lower().split())


def header_name_unit(name: str) -> tuple[str, str | None]:
    """``"X [mm]"`` → ("x", "mm"); ``"dx_um"`` → ("dx", "um"); ``"AirTemp"`` → ("airtemp", None)."""
    text = name.strip()
    match = _UNIT_IN_NAME.match(text)
    if match:
        return _plain(match.group("name")), normalise_unit(match.group("b") or match.group("p"))
    plain = _plain(text)
    base, _, suffix = plain.rpartition("_")
    known = set(LENGTH_UNITS) | set(TEMPERATURE_UNITS) | set(PRESSURE_TO_KPA) | {"pct"}
    if base and normalise_unit(suffix) in known:
        return base, normalise_unit(suffix)
    return plain, None


def _resolve_columns(source: SourceText, layout: _Layout, fmt: GridFormat) -> dict[str, int]:
    names = [header_name_unit(h)[0] for h in layout.header]
    where = layout.header_line or layout.first_data_line
    columns: dict[str, int] = {}
    for f in fields(GridColumnMap):
        ref = getattr(fmt.columns, f.name)
        if isinstance(ref, int):
            if layout.header and ref > len(layout.header):
                raise source.error(
                    f"column {f.name} = {ref}, but the header has {len(layout.header)} columns",
                    where,
                )
            columns[f.name] = ref - 1
            continue
        wanted = _plain(ref) if isinstance(ref, str) else f.name
        found = [i for i, h in enumerate(layout.header) if _plain(h) == wanted]
        found = found or [i for i, plain in enumerate(names) if plain == wanted]
        if found:
            columns[f.name] = found[0]
        elif ref is not None or f.name in ("x", "y"):
            if not layout.header:
                raise source.error(
                    f"the file has no header row: map the {f.name} column by "
                    f"number (e.g. {f.name}=1)",
                    where,
                )
            raise source.error(
                f"no {f.name} column named {ref or f.name!r}; the header has "
                f"{', '.join(repr(h) for h in layout.header)}",
                where,
            )
    for axis in ("x", "y"):
        if f"measured_{axis}" in columns and f"deviation_{axis}" in columns:
            raise source.error(
                f"both measured_{axis} and deviation_{axis} are mapped: map one", where
            )
    if not any(k in columns for k in ("measured_x", "measured_y", "deviation_x", "deviation_y")):
        raise source.error(
            "no measured or deviation column is mapped: map measured_x/"
            "measured_y or deviation_x/deviation_y",
            where,
        )
    return columns


def _resolve_units(
    source: SourceText, layout: _Layout, fmt: GridFormat, columns: dict[str, int]
) -> tuple[dict[str, str], dict[str, str]]:
    """Unit of each quantity kind used (normalised) and where it came from."""
    where = layout.header_line or layout.first_data_line
    declared = {
        "position": fmt.position_unit,
        "deviation": fmt.deviation_unit,
        "temperature": fmt.temperature_unit,
        "pressure": fmt.pressure_unit,
        "humidity": "%",
    }
    option = {
        "position": "--position-unit mm",
        "deviation": "--deviation-unit um",
        "temperature": "--temperature-unit C",
        "pressure": "--pressure-unit hPa",
    }
    allowed = {
        "position": LENGTH_UNITS,
        "deviation": LENGTH_UNITS,
        "temperature": tuple(TEMPERATURE_UNITS),
        "pressure": tuple(PRESSURE_TO_KPA),
        "humidity": ("%", "pct", "%rh", "rh"),
    }
    units: dict[str, str] = {}
    notes: dict[str, str] = {}
    for key, index in columns.items():
        kind = _KIND[key]
        header_unit = header_name_unit(layout.header[index])[1] if layout.header else None
        unit = declared[kind]
        if (
            unit is not None
            and header_unit is not None
            and kind != "humidity"
            and normalise_unit(unit).lower() != header_unit.lower()
        ):
            raise source.error(
                f"column {layout.header[index]!r} ({key}) says {header_unit!r} but the "
                f"{kind} unit is declared as {unit!r}: correct one of them",
                where,
            )
        chosen = normalise_unit(unit) if unit is not None else header_unit
        label = layout.header[index] if layout.header else f"column {index + 1}"
        if chosen is None:
            raise source.error(
                f"no unit for {label!r} ({key}): the file does not state it; give it "
                f"({option[kind]}, or a unit in the header such as '{key} [mm]')",
                where,
            )
        chosen = chosen.lower()
        if chosen not in allowed[kind]:
            raise source.error(
                f"{kind} unit {chosen!r} of {label!r} is not supported; use one of "
                f"{', '.join(allowed[kind])}",
                where,
            )
        if kind in units and units[kind] != chosen:
            raise source.error(
                f"the {kind} columns disagree on their unit ({units[kind]!r} and {chosen!r})", where
            )
        units[kind] = chosen
        origin = fmt.unit_notes.get(kind) or (
            "declared" if unit is not None else f"header {label!r}"
        )
        notes[kind] = origin
    return units, notes


# ---- rows --------------------------------------------------------------------------------


def _rows(
    source: SourceText, layout: _Layout, fmt: GridFormat, columns: dict[str, int]
) -> tuple[list[int], dict[str, list[float]]]:
    values: dict[str, list[float]] = {k: [] for k in columns}
    lines: list[int] = []
    expected = len(layout.header) or None
    expected_from = layout.header_line
    decimal_comma = layout.delimiter == ";"
    for number in range(layout.first_data_line, len(source.lines) + 1):
        text = source.lines[number - 1]
        if fmt.end_marker is not None and text.strip() == fmt.end_marker:
            break
        if _is_comment(text, fmt):
            continue
        tokens = split_fields(text, layout.delimiter)
        if expected is None:
            expected, expected_from = len(tokens), number
        if len(tokens) != expected:
            what = (
                f"the header (line {expected_from})"
                if layout.header
                else f"the first data row (line {expected_from})"
            )
            raise source.error(
                f"{len(tokens)} fields where {what} has {expected}: the file is cut short or "
                "a value is missing or split; check this line",
                number,
            )
        for key, index in columns.items():
            token = tokens[index].replace(",", ".") if decimal_comma else tokens[index]
            label = layout.header[index] if layout.header else f"column {index + 1}"
            values[key].append(parse_float(token, source, number, f"{label} ({key})"))
        lines.append(number)
    if not lines:
        raise source.error("the file holds no data rows", source.last_line)
    return lines, values


def _assemble(
    source: SourceText,
    fmt: GridFormat,
    columns: dict[str, int],
    units: dict[str, str],
    notes: dict[str, str],
    lines: list[int],
    values: dict[str, list[float]],
    name: str | None,
    metadata: Mapping[str, str],
) -> GridMeasurement:
    count = len(lines)
    to_mm = POSITION_FACTOR[units["position"]]
    position = np.stack([np.asarray(values["x"]), np.asarray(values["y"])], axis=1) * to_mm
    deviation = np.full((count, 2), np.nan)
    for k, axis in enumerate(("x", "y")):
        if f"measured_{axis}" in values:
            measured = np.asarray(values[f"measured_{axis}"]) * to_mm
            deviation[:, k] = (measured - position[:, k]) * 1e3 * fmt.sign
        elif f"deviation_{axis}" in values:
            factor = DEVIATION_FACTOR[units["deviation"]]
            deviation[:, k] = np.asarray(values[f"deviation_{axis}"]) * factor * fmt.sign
    limit_um = fmt.max_deviation_mm * 1e3
    worst = np.nanargmax(np.where(np.isfinite(deviation), np.abs(deviation), -1.0).max(axis=1))
    if np.nanmax(np.abs(deviation[worst])) > limit_um:
        axis = "X" if abs(np.nan_to_num(deviation[worst, 0])) > limit_um else "Y"
        value = deviation[worst, 0 if axis == "X" else 1] / 1e3
        raise source.error(
            f"the {axis} deviation is {value:.6g} mm (more than {fmt.max_deviation_mm:g} mm): "
            "a column is wrong (commanded and measured swapped with another column?) or the "
            "unit is; check the column map",
            lines[int(worst)],
        )
    environment: dict[str, np.ndarray] = {}
    for key in ("air_temp", "material_temp", "pressure", "humidity"):
        if key not in values:
            continue
        raw = np.asarray(values[key])
        if key == "pressure":
            raw = raw * PRESSURE_TO_KPA[units["pressure"]]
        elif key in ("air_temp", "material_temp"):
            raw = raw + TEMPERATURE_UNITS[units["temperature"]]
        low, high, symbol = PLAUSIBLE[key]
        bad = np.flatnonzero((raw < low) | (raw > high))
        if bad.size:
            row = int(bad[0])
            raise source.error(
                f"{key.replace('_', ' ')} {values[key][row]:g} ({raw[row]:.4g} {symbol}) is "
                f"not plausible (expected {low:g} to {high:g} {symbol}): check the column map "
                "and the unit",
                lines[row],
            )
        environment[key] = raw
    unit_text: dict[str, str] = {
        kind: f"{_SYMBOL.get(units[kind], units[kind])} ({notes[kind]})"
        for kind in ("position", "deviation", "temperature", "pressure")
        if kind in units
    }
    unit_text["sign"] = "deviation = measured - commanded" + (
        " (the file's values negated)" if fmt.sign < 0 else ""
    )
    return GridMeasurement(
        name=name or source.path.stem,
        position_mm=position,
        deviation_um=deviation,
        air_temp_c=environment.get("air_temp"),
        material_temp_c=environment.get("material_temp"),
        pressure_kpa=environment.get("pressure"),
        humidity_pct=environment.get("humidity"),
        upper_axis=fmt.upper_axis,
        units=unit_text,
        metadata=dict(metadata),
        source_file=str(source.path),
        source_bytes=source.raw,
        file_lines=np.asarray(lines, dtype=np.int64),
    )


def check_grid(
    source: SourceText, grid: GridMeasurement, tolerance_mm: float, *, complete: bool
) -> None:
    """FormatError naming the line when the readings are off a regular grid or, if
    ``complete``, when a node of the grid's rectangle has no reading."""
    try:
        lattice = common_lattice([grid], tolerance_mm)
    except GridLayoutError as exc:
        line = (
            int(grid.file_lines[exc.index])
            if exc.index is not None and grid.file_lines is not None
            else grid_first_line(grid)
        )
        raise source.error(exc.reason, line) from None
    if complete:
        missing = missing_nodes(grid, lattice)
        if missing:
            x, y = missing[0]
            more = f" and {len(missing) - 1} other node(s)" if len(missing) > 1 else ""
            raise source.error(
                f"no reading at X = {x:g} mm, Y = {y:g} mm{more}: the file is cut short or "
                "rows are missing (a grid with gaps can be read with complete = False)",
                int(grid.file_lines[-1]) if grid.file_lines is not None else source.last_line,
            )


def grid_first_line(grid: GridMeasurement) -> int | None:
    return int(grid.file_lines[0]) if grid.file_lines is not None else None
