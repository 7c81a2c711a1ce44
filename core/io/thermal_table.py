"""Thermal test tables: one row per sample, error and temperature channels in columns.

A CSV, semicolon, tab or whitespace table (the same layouts :mod:`volucal.core.io.table` reads,
with its delimiter detection and field splitting) whose rows are samples in time order. A
:class:`ThermalTableFormat` is the column map:

- ``errors``: one :class:`ErrorColumn` per error channel (spindle drift X/Y/Z, a tilt, the
  positioning error at a target…): the column (header name or 1-based number), its unit and an
  optional sign. Required.
- ``temperatures``: the temperature columns; None takes every column that is neither time nor
  error. ``temperature_unit`` (°C, K or °F) applies to all of them.
- ``time``: the time column (numbers in ``time_unit``, or ISO 8601 date-times); None uses a column
  named ``time`` when there is one, else ``sample_interval_s`` must say how far apart the rows are.

Units are declared, as everywhere in volucal: in the format or in the header (``"delta L [um]"``,
``"T1 (°C)"``, ``"drift_um"``). A unit that is neither is an error asking for one, never a default;
a unit declared in both places must agree.

Bad input is a :class:`~volucal.core.userror.FormatError` naming the file, the line, and the column:
an empty cell or NaN in a channel (a gap), a value that is not a number, a row cut short, a time
that does not increase. A temperature sensor that reads one value for the whole record (stuck) is
not an error: it is excluded with a warning (:func:`volucal.core.thermal.split_stuck_sensors`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from ..thermal import (
    ErrorChannel,
    TemperatureChannel,
    ThermalMeasurement,
    split_stuck_sensors,
    time_gaps,
)
from ..userror import FormatError
from .source import SourceText
from .table import detect_delimiter, split_fields
from .units import ANGLE_UNITS, DEVIATION_FACTOR, TIME_FACTOR, normalise_unit

ColumnRef = str | int

#: Spellings of the temperature units (lower case) → "c", "k" or "f".
TEMPERATURE_UNITS = {
    "c": "c",
    "°c": "c",
    "degc": "c",
    "deg c": "c",
    "deg_c": "c",
    "celsius": "c",
    "℃": "c",
    "k": "k",
    "kelvin": "k",
    "f": "f",
    "°f": "f",
    "degf": "f",
    "deg f": "f",
    "fahrenheit": "f",
}
#: Cell texts that mean "no value" (a gap) rather than a malformed number.
MISSING = {"", "nan", "na", "n/a", "-", "--", "null", "none", "?"}
_UNIT_IN_NAME = re.compile(r"^(?P<name>.*?)\s*(?:\[(?P<b>[^\]]*)\]|\((?P<p>[^)]*)\))\s*$")
_TIME_NAMES = ("time", "t", "timestamp", "date_time", "datetime")


@dataclass(frozen=True)
class ErrorColumn:
    """An error channel: which column, its unit (None: the header's), its name and sign.

    ``sign`` -1 flips the file's values so that the channel holds ``measured − nominal``.
    """

    column: ColumnRef
    unit: str | None = None
    name: str | None = None
    sign: int = 1

    def __post_init__(self) -> None:
        if self.sign not in (1, -1):
            raise ValueError(f"error column {self.column!r}: sign must be +1 or -1")
        if isinstance(self.column, int) and (isinstance(self.column, bool) or self.column < 1):
            raise ValueError(f"error column {self.column!r}: column numbers start at 1")


@dataclass(frozen=True)
class ThermalTableFormat:
    """How to read a thermal table (module notes)."""

    errors: tuple[ErrorColumn, ...]
    temperatures: tuple[ColumnRef, ...] | None = None
    temperature_unit: str | None = None
    time: ColumnRef | None = None
    time_unit: str | None = None
    sample_interval_s: float | None = None
    delimiter: str | None = None
    comment: str = "#"
    stuck_span_c: float = field(default=1e-9)

    def __post_init__(self) -> None:
        if not self.errors:
            raise ValueError("name at least one error column")
        if self.sample_interval_s is not None and not (
            math.isfinite(self.sample_interval_s) and self.sample_interval_s > 0
        ):
            raise ValueError("the sample interval must be a positive number of seconds")
        if self.time is not None and self.sample_interval_s is not None:
            raise ValueError("give a time column or a sample interval, not both")
        if self.temperature_unit is not None:
            temperature_unit_key(self.temperature_unit)  # raises ValueError when unknown


def temperature_unit_key(unit: str) -> str:
    """``"°C"`` → ``"c"``, ``"K"`` → ``"k"``, ``"degF"`` → ``"f"``; ValueError otherwise."""
    key = TEMPERATURE_UNITS.get(unit.strip().lower())
    if key is None:
        raise ValueError(f"temperature unit {unit!r} is not known; use °C (C, degC), K or °F")
    return key


def to_celsius(values: np.ndarray, key: str) -> np.ndarray:
    if key == "k":
        return values - 273.15
    if key == "f":
        return (values - 32.0) * (5.0 / 9.0)
    return values


def read_thermal_table(
    path: str | Path, table_format: ThermalTableFormat, name: str | None = None
) -> ThermalMeasurement:
    """Read a thermal table into a :class:`~volucal.core.thermal.ThermalMeasurement`.

    Raises
    ------
    FormatError
        Naming the file, line and column, for the problems listed in the module notes.
    """
    fmt = table_format
    source = SourceText.read(path)
    header_line, delimiter, header = _layout(source, fmt)
    where = header_line or 1
    names = [_split_unit(h) for h in header]
    error_cols = [_column(source, header, names, e.column, "error", where) for e in fmt.errors]
    time_col = _time_column(source, header, names, fmt, where)
    used = set(error_cols) | ({time_col} if time_col is not None else set())
    notes: list[str] = []
    if time_col is None and fmt.temperatures is None:
        # a time column beside a declared interval is not a temperature
        for index, (plain, _) in enumerate(names):
            if _plain(plain) in _TIME_NAMES and index not in used:
                used.add(index)
                notes.append(
                    f"column {_label(header, index)} is not used: the declared sample "
                    f"interval of {fmt.sample_interval_s:g} s gives the time"
                )
    if fmt.temperatures is None:
        width = len(header) if header else _width(source, fmt, delimiter, where)
        temp_cols = [k for k in range(width) if k not in used]
    else:
        temp_cols = [
            _column(source, header, names, ref, "temperature", where) for ref in fmt.temperatures
        ]
    clash = sorted(set(temp_cols) & used)
    if clash:
        raise source.error(
            f"column {_label(header, clash[0])} is mapped as a temperature and as time or an error",
            where,
        )
    if len(set(error_cols)) != len(error_cols):
        raise source.error("the same column is mapped to two error channels", where)

    error_units = [
        _error_unit(source, e, names, k, header, where)
        for e, k in zip(fmt.errors, error_cols, strict=True)
    ]
    temp_keys = _temperature_units(source, fmt, names, temp_cols, header, where)
    time_factor = _time_factor(source, fmt, names, time_col, header, where)

    columns = error_cols + temp_cols + ([time_col] if time_col is not None else [])
    labels = [_label(header, k) for k in columns]
    rows, lines, absolute = _rows(source, fmt, delimiter, header_line, columns, labels, time_col)
    count = len(lines)
    if count < 2:
        raise source.error("a thermal record needs at least two samples (rows)", source.last_line)

    start_time = None
    if time_col is not None:
        raw_time = rows[:, -1]
        _check_time(source, raw_time, lines, _label(header, time_col))
        if absolute:
            start_time = float(raw_time[0])
            time_s = raw_time - raw_time[0]
        elif time_factor is None:
            raise source.error(
                f"time column {_label(header, time_col)} has no unit: declare it (e.g. "
                "--time-unit s; s, min, h or ms)",
                where,
            )
        else:
            time_s = (raw_time - raw_time[0]) * time_factor
        time_source = f"time column {_label(header, time_col)}"
    else:
        assert fmt.sample_interval_s is not None
        time_s = np.arange(count, dtype=float) * fmt.sample_interval_s
        time_source = f"no time column, declared sample interval {fmt.sample_interval_s:g} s"

    errors = []
    for j, (spec, col, unit) in enumerate(zip(fmt.errors, error_cols, error_units, strict=True)):
        factor = DEVIATION_FACTOR[unit]
        kept = "urad" if unit in ANGLE_UNITS else "um"
        channel_name = spec.name or (names[col][0] if header else f"error{j + 1}")
        errors.append(
            ErrorChannel(channel_name, kept, rows[:, j] * factor * spec.sign, unit, spec.sign)
        )
    temperatures = []
    offset = len(error_cols)
    for j, col in enumerate(temp_cols):
        label = names[col][0] if header else f"T{col + 1}"
        temperatures.append(
            TemperatureChannel(label, to_celsius(rows[:, offset + j], temp_keys[j]))
        )
    usable, excluded = split_stuck_sensors(temperatures, fmt.stuck_span_c)
    warnings = tuple(notes) + tuple(e.reason for e in excluded) + tuple(time_gaps(time_s))
    source_path = Path(source.path)
    try:
        return ThermalMeasurement(
            name=name or source_path.stem,
            time_s=time_s,
            errors=tuple(errors),
            temperatures=usable,
            excluded=excluded,
            warnings=warnings,
            time_source=time_source,
            start_time=start_time,
            source=source_path,
            source_bytes=source.raw,
        )
    except FormatError:
        raise
    except Exception as exc:  # a check the reader did not anticipate: still name the file
        raise FormatError(source.path, str(exc)) from None


# ---- layout and columns ------------------------------------------------------------------


def _is_comment(text: str, fmt: ThermalTableFormat) -> bool:
    stripped = text.strip()
    return not stripped or stripped.startswith(fmt.comment) or stripped.startswith("//")


def _numeric(token: str) -> bool:
    try:
        float(token.replace(",", "."))
    except ValueError:
        return token.strip().lower() in MISSING - {""}
    return True


def _layout(
    source: SourceText, fmt: ThermalTableFormat
) -> tuple[int | None, str | None, tuple[str, ...]]:
    first = next((n for n, text in source.numbered() if not _is_comment(text, fmt)), None)
    if first is None:
        raise source.error("the file holds no data rows", source.last_line)
    text = source.lines[first - 1]
    whitespace = fmt.delimiter is not None and fmt.delimiter.lower() in ("whitespace", "space", " ")
    delimiter = None if whitespace else (fmt.delimiter or detect_delimiter(text))
    tokens = split_fields(text, delimiter)
    if all(_numeric(t) for t in tokens if t):
        return None, delimiter, ()
    return first, delimiter, tuple(tokens)


def _plain(name: str) -> str:
    return "_".join(name.strip().lower().split())


def _split_unit(name: str) -> tuple[str, str | None]:
    """``"delta L [um]"`` → ("delta L", "um"); ``"drift_um"`` → ("drift", "um"); the name keeps
    its spelling (it names the channel)."""
    text = name.strip()
    match = _UNIT_IN_NAME.match(text)
    if match:
        unit = match.group("b") if match.group("b") is not None else match.group("p")
        return match.group("name").strip(), unit.strip()
    base, underscore, suffix = text.rpartition("_")
    if (
        underscore
        and base
        and (
            normalise_unit(suffix) in DEVIATION_FACTOR
            or normalise_unit(suffix) in TIME_FACTOR
            or suffix.lower() in TEMPERATURE_UNITS
        )
    ):
        return base, suffix
    return text, None


def _label(header: tuple[str, ...], index: int) -> str:
    return repr(header[index]) if header else f"{index + 1}"


def _column(
    source: SourceText,
    header: tuple[str, ...],
    names: list[tuple[str, str | None]],
    ref: ColumnRef,
    role: str,
    where: int,
) -> int:
    if isinstance(ref, int):
        if header and ref > len(header):
            raise source.error(f"{role} column {ref}: the header has {len(header)} columns", where)
        return ref - 1
    if not header:
        raise source.error(
            f"the file has no header row: give the {role} column {ref!r} by "
            "number (1 is the first column)",
            where,
        )
    wanted = _plain(ref)
    for index, text in enumerate(header):
        if _plain(text) == wanted or _plain(names[index][0]) == wanted:
            return index
    raise source.error(
        f"no {role} column named {ref!r}; the header has {', '.join(repr(h) for h in header)}",
        where,
    )


def _time_column(
    source: SourceText,
    header: tuple[str, ...],
    names: list[tuple[str, str | None]],
    fmt: ThermalTableFormat,
    where: int,
) -> int | None:
    if fmt.time is not None:
        return _column(source, header, names, fmt.time, "time", where)
    if fmt.sample_interval_s is not None:
        return None
    for index, (plain, _) in enumerate(names):
        if _plain(plain) in _TIME_NAMES:
            return index
    raise source.error(
        "no time column: name it (e.g. --time Time) or declare how far apart the rows are "
        "(e.g. --interval 60s for one sample a minute)",
        where,
    )


def _width(source: SourceText, fmt: ThermalTableFormat, delimiter: str | None, where: int) -> int:
    for number, text in source.numbered():
        if number >= where and not _is_comment(text, fmt):
            return len(split_fields(text, delimiter))
    return 0


def _error_unit(
    source: SourceText,
    spec: ErrorColumn,
    names: list[tuple[str, str | None]],
    index: int,
    header: tuple[str, ...],
    where: int,
) -> str:
    declared = normalise_unit(spec.unit) if spec.unit is not None else None
    header_unit = names[index][1] if header else None
    from_header = normalise_unit(header_unit) if header_unit else None
    label = _label(header, index)
    if declared and from_header and declared != from_header:
        raise source.error(
            f"error column {label}: the unit is declared as {spec.unit!r} but the "
            f"header says {names[index][1]!r}",
            where,
        )
    unit = declared or from_header
    if unit is None:
        raise source.error(
            f"error column {label} has no unit: declare it (e.g. --error "
            f'"{names[index][0] if header else index + 1}=um"; µm, mm, nm, µrad, arcsec…)',
            where,
        )
    if unit not in DEVIATION_FACTOR:
        raise source.error(
            f"error column {label}: unit {unit!r} is not supported; use one of "
            f"{', '.join(DEVIATION_FACTOR)}",
            where,
        )
    return unit


def _temperature_units(
    source: SourceText,
    fmt: ThermalTableFormat,
    names: list[tuple[str, str | None]],
    columns: list[int],
    header: tuple[str, ...],
    where: int,
) -> list[str]:
    """The unit key ("c", "k", "f") of every temperature column: the declared one, or the
    header's; a column with neither is an error asking for one."""
    declared = temperature_unit_key(fmt.temperature_unit) if fmt.temperature_unit else None
    keys = []
    for index in columns:
        text = names[index][1] if header else None
        key = TEMPERATURE_UNITS.get(text.strip().lower()) if text else None
        label = _label(header, index)
        if text and key is None:
            raise source.error(
                f"temperature column {label}: unit {text!r} is not a "
                "temperature unit (°C, K or °F)",
                where,
            )
        if declared is not None and key is not None and key != declared:
            raise source.error(
                f"temperature column {label}: the unit is declared as "
                f"{fmt.temperature_unit!r} but the header says {text!r}",
                where,
            )
        if key is None and declared is None:
            raise source.error(
                f"temperature column {label} has no unit: declare it (e.g. "
                "--temperature-unit C for °C; K and °F are converted)",
                where,
            )
        keys.append(key or declared)
    return keys  # type: ignore[return-value]


def _time_factor(
    source: SourceText,
    fmt: ThermalTableFormat,
    names: list[tuple[str, str | None]],
    index: int | None,
    header: tuple[str, ...],
    where: int,
) -> float | None:
    """Seconds per unit of a numeric time column; None when no unit is known (date-times need
    none; numbers then raise once the rows show them)."""
    if index is None:
        return 1.0
    declared = normalise_unit(fmt.time_unit) if fmt.time_unit else None
    header_unit = names[index][1] if header else None
    from_header = normalise_unit(header_unit) if header_unit else None
    if declared and from_header and declared != from_header:
        raise source.error(
            f"time column {_label(header, index)}: the unit is declared as "
            f"{fmt.time_unit!r} but the header says {names[index][1]!r}",
            where,
        )
    unit = declared or from_header
    if unit is None:
        return None
    if unit not in TIME_FACTOR:
        raise source.error(
            f"time unit {unit!r} is not supported; use one of {', '.join(TIME_FACTOR)}", where
        )
    return TIME_FACTOR[unit]


# ---- rows --------------------------------------------------------------------------------


def _rows(
    source: SourceText,
    fmt: ThermalTableFormat,
    delimiter: str | None,
    header_line: int | None,
    columns: list[int],
    labels: list[str],
    time_col: int | None,
) -> tuple[np.ndarray, list[int], bool]:
    """Values (rows × mapped columns, time last when mapped), their line numbers, and whether
    the times are date-times."""
    decimal_comma = delimiter == ";"
    needed = max(columns) + 1
    start = (header_line or 0) + 1
    values: list[list[float]] = []
    lines: list[int] = []
    absolute: bool | None = None
    roles = ["error"] * len(fmt.errors) + ["temperature"] * (
        len(columns) - len(fmt.errors) - (1 if time_col is not None else 0)
    )
    if time_col is not None:
        roles.append("time")
    for number in range(start, len(source.lines) + 1):
        text = source.lines[number - 1]
        if _is_comment(text, fmt):
            continue
        tokens = split_fields(text, delimiter)
        if len(tokens) < needed:
            short = next(k for k, c in enumerate(columns) if c >= len(tokens))
            raise source.error(
                f"column {labels[short]} ({roles[short]}) has no value: the row has "
                f"{len(tokens)} fields, {needed} are needed (a gap or a row cut short)",
                number,
            )
        row: list[float] = []
        for k, column in enumerate(columns):
            token = tokens[column].strip()
            if decimal_comma:
                token = token.replace(",", ".")
            if roles[k] == "time":
                value, is_date = _time_value(source, token, number, labels[k])
                if absolute is None:
                    absolute = is_date
                elif absolute != is_date:
                    raise source.error(
                        f"time column {labels[k]}: mixes numbers and date-times", number
                    )
                row.append(value)
                continue
            row.append(_channel_value(source, token, number, labels[k], roles[k]))
        values.append(row)
        lines.append(number)
    if not lines:
        raise source.error("the file holds no data rows", source.last_line)
    return np.asarray(values, dtype=float), lines, bool(absolute)


def _channel_value(source: SourceText, token: str, line: int, label: str, role: str) -> float:
    if token.lower() in MISSING:
        what = "a gap" if token == "" or token.lower() not in ("nan",) else "NaN"
        raise source.error(
            f"column {label} ({role}) has no value ({what}): fill the gap (e.g. interpolate) "
            f"or leave the column out",
            line,
        )
    try:
        value = float(token)
    except ValueError:
        raise source.error(
            f"column {label} ({role}): expected a number, found {token!r}", line
        ) from None
    if not math.isfinite(value):
        raise source.error(
            f"column {label} ({role}): expected a finite number, found {token!r}", line
        )
    return value


def _time_value(source: SourceText, token: str, line: int, label: str) -> tuple[float, bool]:
    if token.lower() in MISSING:
        raise source.error(f"time column {label} has no value", line)
    try:
        value = float(token)
    except ValueError:
        pass
    else:
        if not math.isfinite(value):
            raise source.error(
                f"time column {label}: expected a finite number, found {token!r}", line
            )
        return value, False
    try:
        moment = datetime.fromisoformat(token.strip('"').replace("Z", "+00:00"))
    except ValueError:
        raise source.error(
            f"time column {label}: expected a number or an ISO 8601 date-time, found {token!r}",
            line,
        ) from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return moment.timestamp(), True


def _check_time(source: SourceText, time: np.ndarray, lines: list[int], label: str) -> None:
    steps = np.diff(time)
    back = np.flatnonzero(steps <= 0)
    if back.size:
        k = int(back[0]) + 1
        word = "repeats" if steps[k - 1] == 0 else "goes back"
        raise source.error(
            f"time column {label} {word} ({time[k]:g} after {time[k - 1]:g} on line "
            f"{lines[k - 1]}): the samples must be in time order, one per time",
            lines[k],
        )
