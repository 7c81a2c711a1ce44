"""Renishaw LaserXL/CARTO linear (.rtl) and angular (.rta) logs: reader and writer.

There is no public specification; the layout below is the one four open parsers agree on
(REFERENCE.md §5). A file is a sequence of sections, each starting with a line ``NAME::``::

    HEADER::          key : value lines (File type, Owner, Version no)
    TARGET DATA::     Target-count: K, "Targets :" then K positions in mm (any number per line),
                      Flags: ...
    USER-TEXT::       Machine, Serial No, Date, By, Axis, Location, TITLE (free text)
    RUNS::            Run-count: R
    DEVIATIONS::      "Run Target Data:" then R·K rows "run target deviation" (µm; µrad in .rta)
    EQUIPMENT::       (.rta) key : value lines describing the optics
    ENVIRONMENT::     Air temp, Air press (kPa), Air humid (%RH), Mat temp 1..3 (°C, −10 = unused),
                      Env factor, Exp coeff (ppm/°C): "start end [flag]"; Date Time: "start" "end"
    EOF::

Conventions volucal applies, each checked against the file:

- Odd runs are forward (they visit targets 1 → K), even runs backward (K → 1). Rows are keyed on
  the target number, never on row order: backward rows may be stored in either order, but an odd
  run whose rows list the targets in descending order contradicts the convention and is rejected.
- Targets in :class:`LineData` are relative to the first target of the file (``target − target₁``,
  the laser is zeroed there), sorted ascending. A run's direction is +1 when it travels towards
  increasing relative target, so a file whose targets descend has forward runs with direction −1.
- ``sign`` declares the file's sign convention: +1 (default) reads deviations as
  ``measured − nominal``; −1 flips them.
- Only the start and end ``Date Time`` are recorded: runs are taken as equally spaced between them,
  and the readings of a run as evenly spread over its slot in the order the machine visited the
  targets, the first reading of the file at its start time. Air and material temperatures per
  reading are interpolated linearly in time between their start and end values.
- A missing section, counts that disagree with the rows, a repeated or missing (run, target) pair
  or a value that is not a number rejects the whole file, naming the file and the line.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..measurement import Environment, LineData
from .limits import (
    HUMIDITY_RANGE_PCT,
    MAX_ABS_DEVIATION,
    MAX_ABS_EXPANSION_PPM,
    MAX_ABS_POSITION_MM,
    MAX_READINGS,
    MAX_RUNS,
    MAX_TARGETS,
    MIN_TARGET_SPACING_MM,
    RTL_AIR_TEMP_RANGE_C,
    RTL_MATERIAL_TEMP_RANGE_C,
    RTL_PRESSURE_RANGE_KPA,
    size_text,
)
from .source import (
    SourceText,
    check_magnitude,
    check_range,
    format_number,
    format_time_rtl,
    is_number,
    parse_float,
    parse_int,
    parse_time,
    quote,
)

FloatArray = NDArray[np.float64]

REQUIRED_SECTIONS = ("HEADER", "TARGET DATA", "RUNS", "DEVIATIONS", "ENVIRONMENT", "EOF")
#: Mat temp values at or below this are sensors marked unused (the file writes −10).
UNUSED_SENSOR_C = -9.5

_SECTION = re.compile(r"^\s*([A-Za-z][A-Za-z \-]*?)\s*::\s*$")
_USER_TEXT_KEYS = {
    "machine": "machine",
    "serial no": "serial",
    "date": "date",
    "by": "operator",
    "axis": "axis",
    "location": "location",
    "title": "title",
}
_USER_TEXT_ORDER = ("Machine", "Serial No", "Date", "By", "Axis", "Location", "TITLE")


@dataclass(frozen=True, eq=False)
class RtlFile:
    """A .rtl/.rta file, read.

    ``data`` holds the readings (sign applied, units as in the file: µm, or µrad for .rta);
    ``targets_file_mm`` the targets as the file prints them; the sections' key/value text is kept
    in ``header``, ``target_data``, ``user_text``, ``equipment`` and ``environment_fields``.
    """

    path: Path
    data: LineData
    angular: bool
    sign: int
    targets_file_mm: FloatArray
    header: Mapping[str, str]
    target_data: Mapping[str, str]
    user_text: Mapping[str, str]
    equipment: Mapping[str, str]
    environment_fields: Mapping[str, str]
    start_time: float
    end_time: float
    text: str
    raw: bytes = field(repr=False)

    @property
    def environment(self) -> Environment:
        return self.data.environment

    @property
    def unit(self) -> str:
        return "urad" if self.angular else "um"


@dataclass
class _Section:
    name: str
    line: int  # line of the "NAME::" header
    body: list[tuple[int, str]] = field(default_factory=list)


def read_rtl(path: str | Path, sign: int = 1) -> RtlFile:
    """Read a Renishaw .rtl (linear) or .rta (angular) file.

    Parameters
    ----------
    path : file to read; ``.rta`` (or an ``EQUIPMENT::`` section) marks it angular.
    sign : +1 when the file's deviations are ``measured − nominal`` (the default), −1 to flip them.

    Raises
    ------
    FormatError
        For anything that is not a complete, consistent file; nothing is partly imported.
    """
    if sign not in (1, -1):
        raise ValueError(f"sign must be +1 or -1, got {sign!r}")
    source = SourceText.read(path)
    return _parse(source, sign)


def _parse(source: SourceText, sign: int) -> RtlFile:
    sections = _split_sections(source)
    for name in REQUIRED_SECTIONS:
        if name not in sections:
            raise source.error(
                f"the {name}:: section is missing: the file is incomplete or not a Renishaw "
                ".rtl/.rta log; export it again from the laser software",
                source.last_line,
            )
    header = _key_values(sections["HEADER"], source)
    targets, target_data = _targets(sections["TARGET DATA"], source)
    runs = _run_count(sections["RUNS"], source)
    deviations, row_order = _deviations(sections["DEVIATIONS"], source, runs, len(targets))
    user_text = _free_text(sections["USER-TEXT"]) if "USER-TEXT" in sections else {}
    equipment = _free_text(sections["EQUIPMENT"]) if "EQUIPMENT" in sections else {}
    environment_fields, environment, start, end = _environment(sections["ENVIRONMENT"], source)
    angular = source.path.suffix.lower() == ".rta" or "EQUIPMENT" in sections

    # Odd runs visit targets in file order; check the rows do not say otherwise.
    for run, (listed, line) in row_order.items():
        if run % 2 == 1 and listed == "descending":
            raise source.error(
                f"run {run} is odd, so forward by the .rtl convention (targets 1 → "
                f"{len(targets)}), but its rows list the targets in descending order; the file "
                "is inconsistent",
                line,
            )

    relative = targets - targets[0]
    order = np.argsort(relative, kind="stable")
    ascending_file = bool(relative[-1] > relative[0]) if len(relative) > 1 else True
    forward = 1 if ascending_file else -1
    run_direction = np.array([forward if r % 2 == 0 else -forward for r in range(runs)])
    deviation_sorted = sign * deviations[:, order]
    times = reading_times(runs, len(targets), end - start, run_direction)
    air, material = _temperatures_per_reading(environment, times, end - start)
    metadata = {
        _USER_TEXT_KEYS[k.lower()]: v
        for k, v in user_text.items()
        if k.lower() in _USER_TEXT_KEYS and v
    }
    data = LineData(
        origin_mm=float(targets[0]),
        targets_mm=relative[order],
        deviations=deviation_sorted,
        run_direction=run_direction,
        times_s=times,
        start_time=start,
        environment=environment,
        air_temp_c=air,
        material_temp_c=material,
        metadata=metadata,
    )
    return RtlFile(
        path=source.path,
        data=data,
        angular=angular,
        sign=sign,
        targets_file_mm=targets,
        header=header,
        target_data=target_data,
        user_text=user_text,
        equipment=equipment,
        environment_fields=environment_fields,
        start_time=start,
        end_time=end,
        text="\n".join(source.lines),
        raw=source.raw,
    )


def _split_sections(source: SourceText) -> dict[str, _Section]:
    sections: dict[str, _Section] = {}
    current: _Section | None = None
    for number, text in source.numbered():
        match = _SECTION.match(text)
        if match:
            name = " ".join(match.group(1).upper().split())
            if name in sections:
                raise source.error(f"the {name}:: section appears twice", number)
            if "EOF" in sections:
                raise source.error(f"the {name}:: section comes after EOF::", number)
            current = _Section(name, number)
            sections[name] = current
            continue
        if current is None:
            if text.strip():
                raise source.error(
                    "expected the first section (HEADER::) before any other text: this is not a "
                    "Renishaw .rtl/.rta log",
                    number,
                )
            continue
        if current.name == "EOF":
            if text.strip():
                raise source.error("unexpected text after EOF::", number)
            continue
        if text.strip():
            current.body.append((number, text))
    return sections


def _key_values(section: _Section, source: SourceText) -> dict[str, str]:
    values: dict[str, str] = {}
    for number, text in section.body:
        key, colon, value = text.partition(":")
        if not colon:
            raise source.error(
                f"{section.name}:: expected 'name : value', found {quote(text)}", number
            )
        values[key.strip()] = value.strip()
    return values


def _free_text(section: _Section) -> dict[str, str]:
    """Key/value text where a line without a colon continues the previous value (a long title)."""
    values: dict[str, str] = {}
    key = ""
    for _, text in section.body:
        name, colon, value = text.partition(":")
        if colon:
            key = name.strip()
            values[key] = value.strip()
        else:
            values[key] = (values.get(key, "") + " " + text.strip()).strip()
    return values


def _targets(section: _Section, source: SourceText) -> tuple[FloatArray, dict[str, str]]:
    count: int | None = None
    count_line = section.line
    values: list[float] = []
    fields: dict[str, str] = {}
    in_targets = False
    targets_line = None
    for number, text in section.body:
        stripped = text.strip()
        key, colon, rest = stripped.partition(":")
        key_norm = " ".join(key.lower().split())
        if colon and key_norm == "targets":
            in_targets = True
            targets_line = number
            for token in rest.split():
                values.append(_target(token, source, number))
            continue
        if colon and not is_number(key):
            in_targets = False
            fields[key.strip()] = rest.strip()
            if key_norm == "target-count":
                count = parse_int(rest.strip(), source, number, "Target-count")
                count_line = number
            continue
        if not in_targets:
            raise source.error(
                f"TARGET DATA:: unexpected line {quote(stripped)}; target positions follow "
                "'Targets :'",
                number,
            )
        for token in stripped.split():
            values.append(_target(token, source, number))
            if len(values) > MAX_TARGETS:
                raise source.error(
                    f"more than {size_text(MAX_TARGETS)} target positions "
                    "(docs/formats.md, Limits)",
                    number,
                )
    if count is None:
        raise source.error("TARGET DATA:: has no 'Target-count:' line", section.line)
    if targets_line is None:
        raise source.error("TARGET DATA:: has no 'Targets :' list", section.line)
    if not 1 <= count <= MAX_TARGETS:
        raise source.error(f"Target-count {count} is out of range 1…{MAX_TARGETS}", count_line)
    if len(values) != count:
        raise source.error(
            f"Target-count says {count} targets but {len(values)} positions are listed",
            count_line,
        )
    targets = np.asarray(values, dtype=float)
    steps = np.diff(targets)
    if count > 1 and not (np.all(steps > 0) or np.all(steps < 0)):
        raise source.error(
            "target positions must be strictly increasing or strictly decreasing", targets_line
        )
    if count > 1 and np.min(np.abs(steps)) < MIN_TARGET_SPACING_MM:
        raise source.error(
            f"two targets are {np.min(np.abs(steps)):g} mm apart; targets of a line are at least "
            f"{MIN_TARGET_SPACING_MM:g} mm apart (docs/formats.md, Limits)",
            targets_line,
        )
    return targets, fields


def _target(token: str, source: SourceText, number: int) -> float:
    value = parse_float(token, source, number, "target position (mm)")
    return check_magnitude(value, MAX_ABS_POSITION_MM, source, number, "target position (mm)")


def _run_count(section: _Section, source: SourceText) -> int:
    for number, text in section.body:
        key, colon, value = text.partition(":")
        if colon and " ".join(key.lower().split()) == "run-count":
            runs = parse_int(value.strip(), source, number, "Run-count")
            if not 1 <= runs <= MAX_RUNS:
                raise source.error(f"Run-count {runs} is out of range 1…{MAX_RUNS}", number)
            return runs
    raise source.error("RUNS:: has no 'Run-count:' line", section.line)


def _deviations(
    section: _Section, source: SourceText, runs: int, targets: int
) -> tuple[FloatArray, dict[int, tuple[str, int]]]:
    body = iter(section.body)
    for number, text in body:
        if " ".join(text.strip().lower().split()).startswith("run target data"):
            break
        raise source.error(f"DEVIATIONS:: expected 'Run Target Data:', found {quote(text)}", number)
    else:
        raise source.error("DEVIATIONS:: has no 'Run Target Data:' line", section.line)
    # the claimed size is checked before anything of that size exists
    expected = runs * targets
    if expected > MAX_READINGS:
        raise source.error(
            f"Run-count {runs} × Target-count {targets} = {size_text(expected)} readings, beyond "
            f"the {size_text(MAX_READINGS)} a line may hold (docs/formats.md, Limits)",
            section.line,
        )
    seen_at: dict[tuple[int, int], int] = {}
    values: list[float] = []
    cells: list[int] = []
    sequence: dict[int, list[tuple[int, int]]] = {}
    for number, text in body:
        tokens = text.split()
        if len(tokens) != 3:
            raise source.error(
                f"expected a row 'run target deviation', found {quote(text)}", number
            )
        run = parse_int(tokens[0], source, number, "run number")
        target = parse_int(tokens[1], source, number, "target number")
        value = parse_float(tokens[2], source, number, "deviation")
        check_magnitude(value, MAX_ABS_DEVIATION, source, number, "deviation")
        if not 1 <= run <= runs:
            raise source.error(f"run {run} is outside 1…{runs} (Run-count)", number)
        if not 1 <= target <= targets:
            raise source.error(f"target {target} is outside 1…{targets} (Target-count)", number)
        if (run, target) in seen_at:
            raise source.error(
                f"run {run}, target {target} appears twice (first at line "
                f"{seen_at[(run, target)]})",
                number,
            )
        seen_at[(run, target)] = number
        values.append(value)
        cells.append((run - 1) * targets + (target - 1))
        sequence.setdefault(run, []).append((target, number))
    if len(values) != expected:
        missing = next(
            (r, t)
            for r in range(1, runs + 1)
            for t in range(1, targets + 1)
            if (r, t) not in seen_at
        )
        last = section.body[-1][0]
        raise source.error(
            f"{len(values)} deviation rows for Run-count {runs} × Target-count {targets} = "
            f"{expected}; run {missing[0]}, target {missing[1]} is missing (the file may be cut "
            "short)",
            last,
        )
    grid = np.empty(expected)
    grid[np.asarray(cells, dtype=np.int64)] = values
    order: dict[int, tuple[str, int]] = {}
    for run, visits in sequence.items():
        numbers = [t for t, _ in visits]
        steps = np.diff(numbers)
        if len(numbers) > 2 and np.all(steps < 0):
            order[run] = ("descending", visits[0][1])
        else:
            order[run] = ("ascending" if np.all(steps > 0) else "mixed", visits[0][1])
    return grid.reshape(runs, targets), order


def _environment(
    section: _Section, source: SourceText
) -> tuple[dict[str, str], Environment, float, float]:
    fields: dict[str, str] = {}
    lines: dict[str, int] = {}
    for number, text in section.body:
        key, colon, value = text.partition(":")
        if not colon:
            raise source.error(
                f"ENVIRONMENT:: expected 'name : values', found {text.strip()!r}", number
            )
        name = " ".join(key.lower().split())
        fields[key.strip()] = value.strip()
        lines[name] = number
    by_name = {" ".join(k.lower().split()): v for k, v in fields.items()}

    def pair(
        name: str, what: str, bounds: tuple[float, float] | None = None
    ) -> tuple[float, float] | None:
        if name not in by_name:
            return None
        tokens = by_name[name].split()
        if len(tokens) < 2:
            raise source.error(f"{what}: expected 'start end [flag]'", lines[name])
        values = []
        for token, when in zip(tokens[:2], ("start", "end"), strict=True):
            value = parse_float(token, source, lines[name], f"{what} at {when}")
            if bounds is not None:
                check_range(value, *bounds, source, lines[name], f"{what} at {when}")
            values.append(value)
        return (values[0], values[1])

    if "date time" not in by_name:
        raise source.error(
            "ENVIRONMENT:: has no 'Date Time' line: the measurement cannot be placed in time",
            section.line,
        )
    stamps = re.findall(r'"([^"]*)"', by_name["date time"])
    if len(stamps) < 2:
        raise source.error(
            'Date Time: expected two quoted times, e.g. "10:46 Dec 12 2016" "11:01 Dec 12 2016"',
            lines["date time"],
        )
    start = parse_time(stamps[0], source, lines["date time"], "Date Time (start)")
    end = parse_time(stamps[1], source, lines["date time"], "Date Time (end)")
    if end < start:
        raise source.error("Date Time: the end is before the start", lines["date time"])
    materials = []
    for index in (1, 2, 3):
        values = pair(f"mat temp {index}", f"Mat temp {index}", RTL_MATERIAL_TEMP_RANGE_C)
        if values is not None and min(values) > UNUSED_SENSOR_C:
            materials.append(values)
    expansion = None
    if "exp coeff" in by_name:
        tokens = by_name["exp coeff"].split()
        if not tokens:
            raise source.error("Exp coeff: expected a value in ppm/°C", lines["exp coeff"])
        expansion = parse_float(tokens[0], source, lines["exp coeff"], "Exp coeff")
        check_magnitude(
            expansion, MAX_ABS_EXPANSION_PPM, source, lines["exp coeff"], "Exp coeff (ppm/°C)"
        )
    environment = Environment(
        air_temp_c=pair("air temp", "Air temp (°C)", RTL_AIR_TEMP_RANGE_C),
        air_pressure_kpa=pair("air press", "Air press (kPa)", RTL_PRESSURE_RANGE_KPA),
        air_humidity_pct=pair("air humid", "Air humid (%RH)", HUMIDITY_RANGE_PCT),
        material_temp_c=tuple(materials),
        expansion_ppm_per_c=expansion,
    )
    return fields, environment, start, end


def reading_times(
    runs: int, targets: int, duration_s: float, run_direction: NDArray[np.int64]
) -> FloatArray:
    """Times (runs, targets), s from the file start, of readings spread evenly over the file.

    Run r occupies the slot [r·T/R, (r+1)·T/R); its readings follow in the order the machine
    visited the (ascending) targets — increasing for direction +1, decreasing for −1 — each
    ``T/(R·K)`` after the previous one.
    """
    step = duration_s / (runs * targets)
    times = np.empty((runs, targets))
    visit = np.arange(targets)
    for run in range(runs):
        order = visit if run_direction[run] > 0 else visit[::-1]
        times[run, order] = (run * targets + visit) * step
    return times


def _temperatures_per_reading(
    environment: Environment, times: FloatArray, duration_s: float
) -> tuple[FloatArray | None, FloatArray | None]:
    fraction = times / duration_s if duration_s > 0 else np.zeros_like(times)

    def interpolate(pair: tuple[float, float]) -> FloatArray:
        return pair[0] + (pair[1] - pair[0]) * fraction

    air = interpolate(environment.air_temp_c) if environment.air_temp_c else None
    material = None
    if environment.material_temp_c:
        sensors = np.asarray(environment.material_temp_c)
        material = interpolate((float(sensors[:, 0].mean()), float(sensors[:, 1].mean())))
    return air, material


# --------------------------------------------------------------------------------------------
# Writer
# --------------------------------------------------------------------------------------------


def write_rtl(
    path: str | Path,
    data: LineData,
    *,
    angular: bool = False,
    user_text: Mapping[str, str] | None = None,
    first_target_mm: float = 0.0,
) -> None:
    """Write ``data`` as a .rtl (or, with ``angular=True``, .rta) file that :func:`read_rtl` reads
    back to the same values.

    Deviations are written with 4 decimals (µm or µrad), targets and environment values with 6
    decimals when exact and in full otherwise. Runs must alternate forward, backward, … starting
    forward (the .rtl convention); the start and end ``Date Time`` are chosen so that the reader's
    evenly spread reading times reproduce ``data.times_s`` (to the second) when the readings were
    evenly spaced in visit order. ``user_text`` defaults to the metadata keys machine, serial,
    date, operator, axis, location and title.

    Raises
    ------
    ValueError
        If the runs do not alternate starting forward or a reading is missing (NaN).
    """
    runs, count = data.deviations.shape
    expected = np.array([1 if r % 2 == 0 else -1 for r in range(runs)])
    if not np.array_equal(data.run_direction, expected):
        raise ValueError(
            "the .rtl format stores runs alternating forward, backward, … starting forward; "
            f"got directions {data.run_direction.tolist()}"
        )
    if not np.all(np.isfinite(data.deviations)):
        raise ValueError("the .rtl format has no way to store a missing reading (NaN)")
    targets = first_target_mm + data.targets_mm
    start, end = _file_times(data)
    lines = [
        "HEADER::",
        f"File type : {'Angular' if angular else 'Linear'}",
        "Owner     : volucal",
        "Version no: 1",
        "",
        "TARGET DATA::",
        "Filetype  : ISO",
        f"Target-count: {count}",
        "Targets :",
    ]
    for first in range(0, count, 5):
        lines.append(" ".join(f"{format_number(t):>12}" for t in targets[first : first + 5]))
    lines += ["Flags: 0 0 2 0", "", "USER-TEXT::"]
    text = dict(user_text) if user_text is not None else _user_text_from_metadata(data.metadata)
    for key in _USER_TEXT_ORDER:
        lines.append(f"{key}: {text.pop(key, '')}")
    lines += [f"{key}: {value}" for key, value in text.items()]
    lines += ["", "RUNS::", f"Run-count: {runs}", "", "DEVIATIONS::", "Run Target Data:"]
    visit = np.arange(count)
    for run in range(runs):
        order = visit if data.run_direction[run] > 0 else visit[::-1]
        for index in order:
            lines.append(f"{run + 1:>4} {index + 1:>4} {data.deviations[run, index]:12.4f}")
    if angular:
        lines += ["", "EQUIPMENT::", "Optics : angular"]
    lines += ["", "ENVIRONMENT::"]
    lines += _environment_lines(data.environment)
    lines.append(f'Date Time  : "{format_time_rtl(start)}" "{format_time_rtl(end)}"')
    lines += ["Final Data : 1 0", "", "EOF::", ""]
    Path(path).write_text("\r\n".join(lines), encoding="utf-8", newline="")


def _user_text_from_metadata(metadata: Mapping[str, str]) -> dict[str, str]:
    back = {v: k for k, v in _USER_TEXT_KEYS.items()}
    keys = {k.lower(): k for k in _USER_TEXT_ORDER}
    out = {}
    for name, value in metadata.items():
        if name in back:
            out[keys[back[name]]] = str(value)
    return out


def _file_times(data: LineData) -> tuple[float, float]:
    """File start and end that make :func:`reading_times` reproduce evenly spaced readings."""
    readings = data.times_s.size
    first = float(np.min(data.times_s))
    last = float(np.max(data.times_s))
    step = (last - first) / (readings - 1) if readings > 1 else 0.0
    start = data.start_time + first
    return start, start + step * readings


def _environment_lines(environment: Environment) -> list[str]:
    def pair(label: str, values: tuple[float, float] | None, flag: str | None) -> list[str]:
        if values is None:
            return []
        text = f"{label}: {format_number(values[0])} {format_number(values[1])}"
        return [text + (f" {flag}" if flag is not None else "")]

    out = pair("Air temp   ", environment.air_temp_c, "0")
    out += pair("Air press  ", environment.air_pressure_kpa, "0")
    out += pair("Air humid  ", environment.air_humidity_pct, None)
    sensors = list(environment.material_temp_c)[:3]
    if sensors:
        while len(sensors) < 3:
            sensors.append((-10.0, -10.0))
        for index, values in enumerate(sensors, start=1):
            out += pair(f"Mat temp {index} ", values, "0")
    if environment.expansion_ppm_per_c is not None:
        value = format_number(environment.expansion_ppm_per_c)
        out.append(f"Exp coeff  : {value} {value} 0")
    return out
