"""plan.toml: the machine and where each line was measured (DESIGN.md), read, validated and
written; and the import of every line's file into a :class:`Measurement`.

Validation errors are :class:`FormatError` naming the plan file, the line of the plan and, for a
``[[line]]`` entry, its number and name and the field (``[[line]] 2 ('x_y0_z0'), field
'direction': …``).

A plan names files, and a plan may come from anyone: ``file`` resolves inside the plan's folder
(relative paths, symbolic links and ``..`` all followed) unless the caller allows another folder
explicitly (``files_root``; ``--files-root`` on the command line). A file outside it, or whose name
does not end as a measurement file does (:data:`MEASUREMENT_EXTENSIONS`) and whose ``format`` is
not given, is refused before a byte of it is read, so that no error can quote another file's
content. FIFOs, devices and folders are refused by the readers before they block or stream.

**Units.** ``deviation_unit`` is the unit of a file that does not state its own. A file that states
it (a .rtl is µm and a .rta µrad by definition; a header ``Flat [mm]``; ``# unit: nm``; ``UNIT=``;
a capture's ``Units:``) needs none, and a ``deviation_unit`` that contradicts it is refused. A file
that does not state it and a plan without ``deviation_unit`` is refused with a message asking for
it: volucal assumes no unit. The same holds for the table options ``time_unit``, ``pressure_unit``
and ``temperature_unit``; positions are mm unless the file or ``position_unit`` says otherwise
(the plan's lengths are mm).

Fields volucal adds to the DESIGN.md ones (all optional; docs/formats.md describes them):

- ``[[line]]``: ``format`` (rtl, rta, table, iso230-2, capture; default from the file), ``columns``
  (column map of a table or CSV capture), ``position_unit``, ``time_unit``, ``pressure_unit``,
  ``temperature_unit``, ``delimiter``, ``data_marker``, ``target_tolerance_mm``,
  ``capture_step_mm``, ``capture_window_mm``, ``capture_step_s``, ``capture_rate_hz``,
  ``expansion_ppm_per_c`` (material expansion for ``env_corrected = false``; default the
  file's), ``assumed_air_index`` (the index an uncompensated laser assumed; default air at
  20 °C, 101.325 kPa, 50 %RH);
- ``[uncertainty]``: standard uncertainties of the measurement chain (keys in UNCERTAINTY_KEYS).
"""

from __future__ import annotations

import json
import math
import os
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..environment import correct_line_data
from ..machine import AXES, Machine, MachineError
from ..measurement import (
    Line,
    LineData,
    LineSpec,
    Measurement,
    Plan,
    PlanError,
    travel_axis,
)
from ..outliers import OutlierFlag, drop, screen
from ..progress import CancelToken, ProgressCallback, check, report
from ..userror import FormatError
from .capture import Capture, capture_line_data, read_capture
from .iso_table import is_iso_table, read_iso_table
from .limits import MIN_TARGET_SPACING_MM
from .rtl import read_rtl
from .source import SourceText
from .table import ColumnMap, TableFormat, read_table
from .units import (
    DEVIATION_FACTOR,
    POSITION_FACTOR,
    PRESSURE_FACTOR_KPA,
    TEMPERATURE_UNITS,
    TIME_FACTOR,
    choices,
    describe,
    is_angle,
    normalise_unit,
)

#: [uncertainty] keys: standard uncertainties of the measurement chain.
UNCERTAINTY_KEYS = {
    "laser_ppm": "laser wavelength and its compensation, ppm of the displacement",
    "air_temp_sensor_c": "air temperature sensor, °C",
    "air_pressure_sensor_pa": "air pressure sensor, Pa",
    "humidity_sensor_pct": "humidity sensor, %RH",
    "material_temp_sensor_c": "material temperature sensor, °C",
    "expansion_coeff_ppm": "material expansion coefficient, ppm/°C",
    "dead_path_mm": "laser dead path, mm",
    "cosine_urad": "beam alignment (cosine error), µrad",
    "abbe_mm": "Abbe offset of the optics, mm",
    "straightness_optics_um": "straightness optics, µm",
    "angular_optics_urad": "angular optics, µrad",
}
MACHINE_KEYS = ("name", "chain", "stroke", "screw_lead", "tool_offset", "reference")
LINE_KEYS = (
    "name",
    "file",
    "quantity",
    "start",
    "direction",
    "sensitive",
    "reflector",
    "deviation_unit",
    "sign",
    "env_corrected",
)
#: Reader options of a [[line]] (kept in LineSpec.reader) and their TOML types.
READER_KEYS: dict[str, tuple[type, ...]] = {
    "format": (str,),
    "columns": (dict,),
    "position_unit": (str,),
    "time_unit": (str,),
    "pressure_unit": (str,),
    "temperature_unit": (str,),
    "delimiter": (str,),
    "data_marker": (str,),
    "target_tolerance_mm": (int, float),
    "capture_step_mm": (int, float),
    "capture_window_mm": (int, float),
    "capture_step_s": (int, float),
    "capture_rate_hz": (int, float),
    "expansion_ppm_per_c": (int, float),
    "assumed_air_index": (int, float),
}
FORMATS = ("rtl", "rta", "table", "iso230-2", "capture")
_EXTENSION_FORMAT = {".rtl": "rtl", ".rta": "rta", ".rtx": "capture"}
_TEXT_EXTENSIONS = (".csv", ".txt", ".dat", ".tsv", ".prn", ".iso")
#: File names a plan may list without a ``format``: what laser software and volucal write.
MEASUREMENT_EXTENSIONS = tuple(_EXTENSION_FORMAT) + _TEXT_EXTENSIONS
_POSITION = re.compile(r"\(at (?:line (\d+), column \d+|end of document)\)")


# --------------------------------------------------------------------------------------------
# Reading plan.toml
# --------------------------------------------------------------------------------------------


class _Locator:
    """Line numbers of tables, ``[[line]]`` entries and fields in a plan's text (for messages)."""

    def __init__(self, text: str) -> None:
        self.lines = text.splitlines()
        self.entries: list[int] = []
        self.tables: dict[str, int] = {}
        for number, line in enumerate(self.lines, start=1):
            match = re.match(r"^\s*\[(\[?)\s*([^\]\s]+)\s*\]", line)
            if not match:
                continue
            if match.group(1) and match.group(2) == "line":
                self.entries.append(number)
            self.tables.setdefault(match.group(2), number)

    def _block_end(self, start: int) -> int:
        for number in range(start + 1, len(self.lines) + 1):
            if self.lines[number - 1].lstrip().startswith("["):
                return number
        return len(self.lines) + 1

    def field(self, start: int | None, key: str) -> int | None:
        """Line of ``key = …`` in the table starting at line ``start`` (0: before any table);
        the table's own line when the key is not written there."""
        if start is None:
            return None
        pattern = re.compile(rf"^\s*{re.escape(key)}\s*=")
        for number in range(start + 1, self._block_end(start)):
            if pattern.match(self.lines[number - 1]):
                return number
        return start or None

    def entry(self, index: int) -> int | None:
        return self.entries[index] if index < len(self.entries) else None


def _entry_label(index: int, name: object) -> str:
    label = f"[[line]] {index + 1}"
    return f"{label} ({name!r})" if isinstance(name, str) and name else label


def load_plan(path: str | Path, files_root: str | Path | None = None) -> Plan:
    """Read and validate a plan.toml.

    Returns a :class:`Plan` whose LineSpec ``file`` paths are absolute (resolved against the
    plan's folder) and whose ``reader`` mappings hold the reader options given.

    Parameters
    ----------
    path : the plan file.
    files_root : the folder the plan's files must lie in (after following symbolic links and
        ``..``); default the plan's own folder. Giving it is the user's explicit permission to read
        files elsewhere.

    Raises
    ------
    FormatError
        For TOML syntax (with its line), an unknown table or key, or any value that cannot be
        right — naming the ``[[line]]`` entry and the field.
    """
    path = Path(path)
    source = SourceText.read(path)
    text = "\n".join(source.lines)
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        message = str(exc)
        match = _POSITION.search(message)
        line = int(match.group(1)) if match and match.group(1) else max(len(source.lines), 1)
        raise FormatError(
            path, f"TOML syntax: {_POSITION.sub('', message).strip()}", line
        ) from None
    locate = _Locator(text)
    end = source.last_line  # where a plan that lacks a table ended
    unknown = sorted(set(document) - {"machine", "line", "uncertainty"})
    if unknown:
        raise FormatError(
            path,
            f"unknown table or key {', '.join(unknown)}; a plan has [machine], [[line]] and "
            "an optional [uncertainty]",
            locate.tables.get(unknown[0]) or locate.field(0, unknown[0]) or end,
        )
    machine = _machine(path, document.get("machine"), locate, end)
    entries = document.get("line", [])
    if not isinstance(entries, list) or not entries:
        raise FormatError(
            path,
            "the plan has no [[line]] entries (each line is a [[line]] table)",
            locate.tables.get("line", end),
        )
    try:
        folder = Path(os.path.realpath(path.parent))
        root = Path(os.path.realpath(files_root)) if files_root is not None else folder
    except (OSError, RuntimeError, ValueError):
        raise FormatError(path, "its folder cannot be resolved") from None
    specs = [
        _line(path, index, entry, machine, locate, root, files_root is not None)
        for index, entry in enumerate(entries)
    ]
    seen: dict[str, int] = {}
    for index, spec in enumerate(specs):
        if spec.name in seen:
            raise FormatError(
                path,
                f"{_entry_label(index, spec.name)}, field 'name': the name is already used by "
                f"[[line]] {seen[spec.name] + 1}; names must be unique",
                locate.field(locate.entry(index), "name"),
            )
        seen[spec.name] = index
    uncertainty = _uncertainty(path, document.get("uncertainty", {}), locate)
    return Plan(
        machine=machine,
        lines=tuple(specs),
        path=Path(os.path.realpath(path)),
        uncertainty=uncertainty,
    )


def _machine(path: Path, table: object, locate: _Locator, end: int) -> Machine:
    where = locate.tables.get("machine")
    if not isinstance(table, dict):
        raise FormatError(path, "the [machine] table is missing", where or end)
    unknown = sorted(set(table) - set(MACHINE_KEYS))
    if unknown:
        raise FormatError(
            path,
            f"[machine]: unknown field {unknown[0]!r}; fields are {', '.join(MACHINE_KEYS)}",
            locate.field(where, unknown[0]),
        )
    if "stroke" not in table:
        raise FormatError(
            path,
            "[machine]: field 'stroke' is required, e.g. stroke = "
            "{ X = [0, 400], Y = [0, 400], Z = [0, 350] }",
            where,
        )
    for key in ("stroke", "screw_lead"):
        if key in table and not isinstance(table[key], dict):
            raise FormatError(
                path,
                f"[machine], field {key!r}: expected a table such as {{ X = …, Y = …, Z = … }}",
                locate.field(where, key),
            )
    for key in ("name", "chain"):
        if key in table and not isinstance(table[key], str):
            raise FormatError(
                path, f"[machine], field {key!r}: expected a string", locate.field(where, key)
            )
    try:
        return Machine(
            name=table.get("name", "machine"),
            chain=table.get("chain", "WXYFZT"),
            stroke_mm=table["stroke"],
            screw_lead_mm=table.get("screw_lead", {}),
            tool_offset_mm=table.get("tool_offset", (0.0, 0.0, 0.0)),
            reference_mm=table.get("reference"),
        )
    except MachineError as exc:
        match = re.match(r"machine\.([a-z_]+)", str(exc))
        key = match.group(1) if match else "stroke"
        raise FormatError(
            path, f"[machine], field {key!r}: {exc}", locate.field(where, key)
        ) from None


def _line(
    path: Path,
    index: int,
    entry: object,
    machine: Machine,
    locate: _Locator,
    root: Path,
    root_given: bool,
) -> LineSpec:
    start_line = locate.entry(index)
    if not isinstance(entry, dict):
        raise FormatError(path, f"{_entry_label(index, None)}: expected a table", start_line or 1)
    label = _entry_label(index, entry.get("name"))

    def fail(key: str, message: str) -> FormatError:
        return FormatError(
            path, f"{label}, field {key!r}: {message}", locate.field(start_line, key)
        )

    unknown = sorted(set(entry) - set(LINE_KEYS) - set(READER_KEYS))
    if unknown:
        raise fail(
            unknown[0],
            f"unknown field; fields are {', '.join(LINE_KEYS)} and the "
            f"reader options {', '.join(READER_KEYS)}",
        )
    for key in ("file", "quantity", "start", "direction"):
        if key not in entry:
            raise FormatError(path, f"{label}: field {key!r} is required", start_line)
    if not isinstance(entry["file"], str) or not entry["file"].strip() or "\x00" in entry["file"]:
        raise fail("file", "expected a path string")
    reader = _reader_options(entry, fail)
    file_path = _data_file(path, entry["file"], root, root_given, "format" in reader, fail)
    name = entry.get("name", Path(entry["file"]).stem)
    if not isinstance(name, str) or not name.strip():
        raise fail("name", "expected a non-empty string")
    if "/" in name or name.startswith("."):
        raise fail(
            "name",
            "a name cannot contain '/' or start with '.' (it names a group in the project file)",
        )
    for key in ("quantity", "deviation_unit"):
        if key in entry and not isinstance(entry[key], str):
            raise fail(key, "expected a string")
    for key in ("start", "direction", "sensitive", "reflector"):
        if key in entry:
            _check_vector(entry[key], fail, key)
    sign = entry.get("sign", 1)
    if isinstance(sign, bool) or sign not in (1, -1):
        raise fail("sign", f"expected +1 (deviation = measured − nominal) or -1, got {sign!r}")
    env = entry.get("env_corrected", True)
    if not isinstance(env, bool):
        raise fail("env_corrected", f"expected true or false, got {env!r}")
    quantity = entry["quantity"]
    stated = "deviation_unit" in entry
    unit = (
        normalise_unit(entry["deviation_unit"])
        if stated
        else ("urad" if quantity == "angular" else "um")
    )
    try:
        return LineSpec(
            name=name,
            quantity=quantity,
            start_mm=tuple(entry["start"]),  # type: ignore[arg-type]
            direction=tuple(entry["direction"]),  # type: ignore[arg-type]
            reflector_mm=tuple(entry.get("reflector", machine.tool_offset_mm)),  # type: ignore[arg-type]
            sensitive=tuple(entry["sensitive"]) if "sensitive" in entry else None,  # type: ignore[arg-type]
            file=str(file_path),
            deviation_unit=unit,
            sign=sign,
            env_corrected=env,
            reader=reader,
            deviation_unit_stated=stated,
        )
    except PlanError as exc:
        # LineSpec's messages read "line 'name': <field> …"
        message = str(exc).split(": ", 1)[-1]
        match = re.match(
            r"(quantity|start|direction|reflector|sensitive|deviation_unit|sign)\b", message
        )
        key = match.group(1) if match else "quantity"
        raise fail(key, message.removeprefix(f"{key}: ")) from None


def _data_file(
    plan: Path, name: str, root: Path, root_given: bool, format_given: bool, fail: Any
) -> Path:
    """The real path of a plan's ``file``, inside ``root`` and named as a measurement file (module
    notes); nothing of the file is read here."""
    candidate = Path(name)
    if not candidate.is_absolute():
        candidate = plan.parent / candidate
    try:
        real = Path(os.path.realpath(candidate))
    except (OSError, RuntimeError, ValueError):
        raise fail("file", f"{name!r} cannot be resolved (a loop of symbolic links?)") from None
    if not real.is_relative_to(root):
        where = "the allowed folder" if root_given else "the plan's folder"
        error = fail(
            "file",
            f"{name!r} resolves to {str(real)!r}, outside {where} "
            f"{str(root)!r}; volucal reads a plan's files only from there. Move the file "
            "into that folder, or allow its folder explicitly (--files-root DIR on the "
            "command line, files_root= in load_plan)",
        )
        raise OutsideFolderError(error.path, error.reason, error.line, real)
    if real.suffix.lower() not in MEASUREMENT_EXTENSIONS and not format_given:
        raise fail(
            "file",
            f"{name!r} is not named as a measurement file "
            f"({', '.join(MEASUREMENT_EXTENSIONS)}); if it is one, say how to read it with "
            'format = "table" (or rtl, rta, iso230-2, capture)',
        )
    return real


def _check_vector(value: object, fail: Any, key: str) -> None:
    if (
        not isinstance(value, list)
        or len(value) != 3
        or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in value
        )
    ):
        raise fail(key, f"expected three numbers [x, y, z], got {value!r}")


def _reader_options(entry: dict[str, Any], fail: Any) -> dict[str, object]:
    reader: dict[str, object] = {}
    for key, types in READER_KEYS.items():
        if key not in entry:
            continue
        value = entry[key]
        if isinstance(value, bool) or not isinstance(value, types):
            raise fail(key, f"expected {' or '.join(t.__name__ for t in types)}, got {value!r}")
        if isinstance(value, int | float) and not (math.isfinite(value) and value > 0):
            raise fail(key, f"expected a positive number, got {value!r}")
        reader[key] = value
    if "format" in reader and reader["format"] not in FORMATS:
        raise fail("format", f"{reader['format']!r} is not one of {', '.join(FORMATS)}")
    if "columns" in reader:
        try:
            ColumnMap.from_mapping(reader["columns"])  # type: ignore[arg-type]
        except ValueError as exc:
            raise fail("columns", str(exc)) from None
    for key, known in (
        ("position_unit", POSITION_FACTOR),
        ("time_unit", TIME_FACTOR),
        ("pressure_unit", PRESSURE_FACTOR_KPA),
        ("temperature_unit", TEMPERATURE_UNITS),
    ):
        if key in reader and normalise_unit(str(reader[key])) not in known:
            raise fail(key, f"{reader[key]!r} is not one of {choices(tuple(known))}")
    for key in ("target_tolerance_mm", "capture_step_mm"):
        if key in reader and float(reader[key]) < MIN_TARGET_SPACING_MM:  # type: ignore[arg-type]
            raise fail(key, f"expected at least {MIN_TARGET_SPACING_MM} mm, got {reader[key]!r}")
    if reader.get("delimiter") == "":
        raise fail("delimiter", "use ',', ';', a tab or \"whitespace\"")
    return reader


def _uncertainty(path: Path, table: object, locate: _Locator) -> dict[str, float]:
    where = locate.tables.get("uncertainty")
    if not isinstance(table, dict):
        raise FormatError(path, "[uncertainty]: expected a table of numbers", where)
    out: dict[str, float] = {}
    for key, value in table.items():
        if key not in UNCERTAINTY_KEYS:
            raise FormatError(
                path,
                f"[uncertainty], field {key!r}: unknown; fields are {', '.join(UNCERTAINTY_KEYS)}",
                locate.field(where, key),
            )
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not (math.isfinite(value) and value >= 0)
        ):
            raise FormatError(
                path,
                f"[uncertainty], field {key!r}: expected a number ≥ 0, got {value!r}",
                locate.field(where, key),
            )
        out[key] = float(value)
    return out


# --------------------------------------------------------------------------------------------
# Writing plan.toml
# --------------------------------------------------------------------------------------------


def _toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        items = ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items())
        return "{ " + items + " }"
    raise TypeError(f"cannot write {value!r} to TOML")


def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def plan_text(plan: Plan, folder: str | Path | None = None) -> str:
    """The plan.toml text of ``plan`` with file paths relative to ``folder`` (the plan's)."""
    base = (
        Path(folder)
        if folder is not None
        else (plan.path.parent if plan.path is not None else Path.cwd())
    )
    m = plan.machine
    lines = [
        "[machine]",
        f"name = {_toml_value(m.name)}",
        f"chain = {_toml_value(m.chain)}",
        f"stroke = {_toml_value({a: list(m.stroke(a)) for a in AXES})}",
    ]
    if m.screw_lead_mm:
        lines.append(f"screw_lead = {_toml_value(dict(m.screw_lead_mm))}")
    lines.append(f"tool_offset = {_toml_value(list(m.tool_offset_mm))}")
    default_reference = tuple(m.stroke(a)[0] for a in AXES)
    if m.reference_mm != default_reference:
        lines.append(f"reference = {_toml_value(list(m.reference_mm or ()))}")
    if plan.uncertainty:
        lines += ["", "[uncertainty]"]
        lines += [f"{k} = {_toml_value(float(v))}" for k, v in plan.uncertainty.items()]
    for spec in plan.lines:
        lines += ["", "[[line]]", f"name = {_toml_value(spec.name)}"]
        if spec.file is not None:
            relative = os.path.relpath(Path(spec.file).resolve(), base.resolve())
            lines.append(f"file = {_toml_value(Path(relative).as_posix())}")
        lines += [
            f"quantity = {_toml_value(spec.quantity)}",
            f"start = {_toml_value(list(spec.start_mm))}",
            f"direction = {_toml_value(list(spec.direction))}",
        ]
        if spec.sensitive is not None:
            lines.append(f"sensitive = {_toml_value(list(spec.sensitive))}")
        lines.append(f"reflector = {_toml_value(list(spec.reflector_mm))}")
        if spec.deviation_unit_stated:
            lines.append(f"deviation_unit = {_toml_value(spec.deviation_unit)}")
        lines += [
            f"sign = {spec.sign}",
            f"env_corrected = {_toml_value(spec.env_corrected)}",
        ]
        lines += [f"{key} = {_toml_value(value)}" for key, value in spec.reader.items()]
    return "\n".join(lines) + "\n"


def write_plan(path: str | Path, plan: Plan) -> None:
    """Write ``plan`` as plan.toml in the DESIGN.md shape; ``file`` paths relative to its folder."""
    path = Path(path)
    path.write_text(plan_text(plan, path.parent), encoding="utf-8")


# --------------------------------------------------------------------------------------------
# Importing the lines
# --------------------------------------------------------------------------------------------


class OutsideFolderError(FormatError):
    """A plan's file that lies outside the folder the plan may read from; ``real`` is where it
    is, so that a program can ask its user whether to allow that folder."""

    def __init__(self, path: object, message: str, line: int | None, real: Path) -> None:
        super().__init__(path, message, line)
        self.real = real


class LineFieldError(PlanError):
    """A line's plan field that does not fit its file; ``key`` names the field."""

    def __init__(self, name: str, key: str, message: str) -> None:
        self.key = key
        self.reason = message
        super().__init__(f"line {name!r}, field {key!r}: {message}")


@dataclass(frozen=True, eq=False)
class LineImport:
    """One line, imported: the file's values as read (``raw``, in ``raw_unit``, file sign) and
    volucal's (``corrected``: µm/µrad, ``measured − nominal``, environment re-corrected where the
    plan asks), the file's bytes and what was done."""

    spec: LineSpec
    format: str
    raw: LineData
    raw_unit: str
    corrected: LineData
    source_bytes: bytes
    sign_convention: str
    corrections: tuple[str, ...]
    notes: tuple[str, ...]
    flags: tuple[OutlierFlag, ...]
    capture: Capture | None = None

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def readings(self) -> int:
        return int(np.isfinite(self.corrected.deviations).sum())

    def provenance(self) -> dict[str, object]:
        """What the project file records about where these values came from."""
        return {
            "source_file": Path(self.spec.file or "").name,
            "format": self.format,
            "raw_unit": self.raw_unit,
            "sign_convention": self.sign_convention,
            "corrections": list(self.corrections),
            "notes": list(self.notes),
        }


@dataclass(frozen=True, eq=False)
class ImportResult:
    """Every line of a plan, imported, and the measurement they make (lines in session order)."""

    plan: Plan
    measurement: Measurement
    lines: tuple[LineImport, ...]
    outliers_dropped: bool

    @property
    def flags(self) -> list[OutlierFlag]:
        return [flag for line in self.lines for flag in line.flags]

    @property
    def raw(self) -> dict[str, LineData]:
        return {line.name: line.raw for line in self.lines}

    @property
    def source_bytes(self) -> dict[str, bytes]:
        return {line.name: line.source_bytes for line in self.lines}


def sign_convention(sign: int) -> str:
    if sign > 0:
        return "sign +1: deviation = measured − nominal, as written in the file"
    return "sign −1: the file's deviations are flipped to measured − nominal"


def detect_format(spec: LineSpec) -> str:
    """The reader for a line: the plan's ``format``, else by extension (.rtl, .rta, .rtx), else
    by content (an ISO 230-2 table or a generic table)."""
    explicit = spec.reader.get("format")
    if isinstance(explicit, str):
        return explicit
    file = Path(spec.file or "")
    suffix = file.suffix.lower()
    if suffix in _EXTENSION_FORMAT:
        return _EXTENSION_FORMAT[suffix]
    if suffix in _TEXT_EXTENSIONS and file.is_file():
        return "iso230-2" if is_iso_table(SourceText.read(file)) else "table"
    return "table"


def _table_format(reader: Mapping[str, object], deviation_unit: str | None) -> TableFormat:
    columns = reader.get("columns")
    return TableFormat(
        columns=ColumnMap.from_mapping(columns) if isinstance(columns, dict) else ColumnMap(),
        position_unit=reader.get("position_unit"),  # type: ignore[arg-type]
        # plan.toml states lengths in mm: a position column without a unit is in mm by the plan
        position_unit_default="mm",
        deviation_unit=deviation_unit,
        time_unit=reader.get("time_unit"),  # type: ignore[arg-type]
        pressure_unit=reader.get("pressure_unit"),  # type: ignore[arg-type]
        temperature_unit=reader.get("temperature_unit"),  # type: ignore[arg-type]
        delimiter=reader.get("delimiter"),  # type: ignore[arg-type]
        data_marker=reader.get("data_marker"),  # type: ignore[arg-type]
        target_tolerance_mm=float(reader.get("target_tolerance_mm", 1e-3)),  # type: ignore[arg-type]
    )


def read_line_file(spec: LineSpec) -> tuple[str, LineData, str, bytes, Capture | None]:
    """(format, raw data as in the file, the file's deviation unit, bytes, capture).

    The unit is the file's own, or the plan's ``deviation_unit`` for a file that states none
    (module notes); a contradiction or no unit at all is refused.
    """
    fmt = detect_format(spec)
    path = Path(spec.file or "")
    stated = spec.deviation_unit if spec.deviation_unit_stated else None
    if fmt in ("rtl", "rta"):
        rtl = read_rtl(path)
        if rtl.angular and spec.quantity != "angular":
            raise FormatError(
                path,
                f"this is an angular log (.rta) but the plan's line "
                f"{spec.name!r} has quantity = {spec.quantity!r}",
                1,
            )
        if stated is not None and stated != rtl.unit:
            raise LineFieldError(
                spec.name,
                "deviation_unit",
                f"the file is a Renishaw {'.rta' if rtl.angular else '.rtl'} log, whose "
                f"deviations are in {describe(rtl.unit)} by definition, but the plan says "
                f"{describe(stated)}; remove deviation_unit or correct it",
            )
        return fmt, rtl.data, rtl.unit, rtl.raw, None
    if fmt == "iso230-2":
        table = read_iso_table(path, stated)
        return fmt, table.data, table.unit, table.raw, None
    if fmt == "capture":
        capture = read_capture(
            path,
            _table_format(spec.reader, stated),
            sample_rate_hz=spec.reader.get("capture_rate_hz"),
        )  # type: ignore[arg-type]
        try:
            data = capture_line_data(
                capture,
                step_mm=spec.reader.get("capture_step_mm"),  # type: ignore[arg-type]
                window_mm=spec.reader.get("capture_window_mm"),  # type: ignore[arg-type]
                step_s=float(spec.reader.get("capture_step_s", 1.0)),  # type: ignore[arg-type]
            )
        except ValueError as exc:
            raise LineFieldError(spec.name, "capture_step_mm", str(exc)) from None
        if capture.unit is None:
            raise LineFieldError(
                spec.name,
                "deviation_unit",
                "the capture does not state its deviation unit: give deviation_unit",
            )
        return fmt, data, capture.unit, capture.raw, capture
    table_file = read_table(path, _table_format(spec.reader, stated))
    return fmt, table_file.data, table_file.unit, table_file.raw, None


def import_line(spec: LineSpec, *, drop_outliers: bool = False) -> LineImport:
    """Read one line's file and convert it to volucal's units and sign (module notes)."""
    fmt, raw, unit, source_bytes, capture = read_line_file(spec)
    if is_angle(unit) != (spec.quantity == "angular"):
        kind = "an angle" if is_angle(unit) else "a length"
        raise LineFieldError(
            spec.name,
            "deviation_unit",
            f"the file's deviations are in {unit} "
            f"({kind}), which does not fit a {spec.quantity} line",
        )
    factor = DEVIATION_FACTOR[unit] * spec.sign
    corrected = replace(raw, deviations=raw.deviations * factor)
    corrections: list[str] = []
    notes: list[str] = []
    if unit not in ("um", "urad"):
        corrections.append(f"deviations converted from {unit} to {spec.unit}")
    # a table's environment is converted as it is read; say so
    pressure_unit = raw.metadata.get("pressure_unit_in_file")
    if pressure_unit not in (None, "kPa"):
        corrections.append(f"air pressure converted from {pressure_unit} to kPa")
    temperature_unit = raw.metadata.get("temperature_unit_in_file")
    if temperature_unit not in (None, "°C"):
        corrections.append(f"temperatures converted from {temperature_unit} to °C")
    if not spec.env_corrected:
        if spec.quantity == "linear":
            assumed = spec.reader.get("assumed_air_index")
            try:
                corrected, applied = correct_line_data(
                    corrected,
                    expansion_ppm_per_c=spec.reader.get("expansion_ppm_per_c"),  # type: ignore[arg-type]
                    assumed_index=float(assumed) if assumed is not None else None,  # type: ignore[arg-type]
                )
            except ValueError as exc:
                raise LineFieldError(spec.name, "env_corrected", str(exc)) from None
            corrections += applied
        else:
            notes.append(
                f"env_corrected = false has no effect on a {spec.quantity} line "
                "(its optics do not depend on the air's refractive index)"
            )
    flags = screen(corrected, line=spec.name, unit=spec.unit)
    if drop_outliers and flags:
        corrected = drop(corrected, flags)
        notes.append(f"{len(flags)} outlier flag(s) applied: flagged readings set missing")
    return LineImport(
        spec=spec,
        format=fmt,
        raw=raw,
        raw_unit=unit,
        corrected=corrected,
        source_bytes=source_bytes,
        sign_convention=sign_convention(spec.sign),
        corrections=tuple(corrections),
        notes=tuple(notes),
        flags=tuple(flags),
        capture=capture,
    )


#: A plan places a line's targets where its file puts them when they agree within this (mm):
#: beyond a capture's first sample, an inch table's rounding or a target tolerance, and far
#: below a start copied from another line (tens of mm), which is what the note is for.
PLACED_TOLERANCE_MM = 0.1


def placed_apart(spec: LineSpec, raw: LineData) -> str | None:
    """A note where a plan's line along one axis is placed elsewhere than its file puts its
    targets, or None. The plan's ``start`` and ``direction`` place the readings for the model;
    a file's positions may be the laser's own (from its zero) and the note is no error, but a
    start copied from another line shifts every error function read from it, and nothing else
    would tell. The file's positions are distances along the beam: a direction a little off the
    axis is compared by its sign alone."""
    axis = travel_axis(spec.direction)
    if axis is None or raw.origin_mm is None or raw.targets_mm.size == 0:
        return None
    k = AXES.index(axis)
    by_plan = spec.start_mm[k] + np.sign(spec.direction[k]) * raw.targets_mm
    by_file = raw.origin_mm + raw.targets_mm
    if np.max(np.abs(by_plan - by_file)) <= PLACED_TOLERANCE_MM:
        return None
    # the lowest and the highest of the file's positions, each where the plan puts it, so that
    # a line the plan runs the other way shows
    return (
        f"the file puts its targets at {by_file[0]:g} … {by_file[-1]:g} mm and the plan's start "
        f"and direction at {axis} {by_plan[0]:g} … {by_plan[-1]:g} mm (volucal uses the plan's). "
        "Where the file's positions are the machine's, check start and direction"
    )


def session_order(lines: list[Line]) -> list[Line]:
    """Lines by the time of their first reading (ties keep plan order): the session order."""

    def first_reading(line: Line) -> float:
        times = line.data.times_s
        offset = float(np.nanmin(times)) if np.isfinite(times).any() else 0.0
        return line.data.start_time + offset

    return sorted(lines, key=first_reading)


def import_plan(
    plan: Plan,
    *,
    drop_outliers: bool = False,
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
) -> ImportResult:
    """Import every line of ``plan``; nothing is returned unless every line reads.

    Errors name the data file and its line (FormatError from the readers) or the plan file, the
    ``[[line]]`` entry and the field (a missing file, options that do not fit the file).
    """
    text = (
        plan.path.read_text(encoding="utf-8", errors="replace")
        if (plan.path is not None and plan.path.is_file())
        else ""
    )
    locate = _Locator(text)
    imported: list[LineImport] = []
    for index, spec in enumerate(plan.lines):
        check(cancel)
        report(progress, index / len(plan.lines), f"reading {spec.name}")

        def fail(key: str, message: str, index: int = index, spec: LineSpec = spec) -> FormatError:
            where = plan.path if plan.path is not None else Path("plan.toml")
            return FormatError(
                where,
                f"{_entry_label(index, spec.name)}, field {key!r}: {message}",
                locate.field(locate.entry(index), key) if text else None,
            )

        if spec.file is None:
            raise fail("file", "the line has no file")
        if not os.path.lexists(spec.file):
            raise fail("file", f"{spec.file} does not exist")
        try:
            line = import_line(spec, drop_outliers=drop_outliers)
        except LineFieldError as exc:
            raise fail(exc.key, exc.reason) from None
        # against the plan's entry, not a proposed one (the import wizard's preview)
        placed = placed_apart(spec, line.raw)
        imported.append(line if placed is None else replace(line, notes=(*line.notes, placed)))
    report(progress, 1.0, "imported")
    lines = session_order([Line(item.spec, item.corrected) for item in imported])
    measurement = Measurement(plan.machine, tuple(lines), dict(plan.uncertainty))
    return ImportResult(plan, measurement, tuple(imported), drop_outliers)


def load_measurement(plan: Plan, screen_outliers: str = "keep") -> Measurement:
    """The measurement of ``plan``: every line's file read, sign and units applied and, where
    ``env_corrected = false``, the environment correction; lines ordered by start time.

    ``screen_outliers``: ``"keep"`` returns every reading (flags are available through
    :func:`import_plan`); ``"drop"`` sets readings and runs flagged by
    :func:`volucal.core.outliers.screen` to NaN (missing).
    """
    if screen_outliers not in ("keep", "drop"):
        raise ValueError(f"screen_outliers must be 'keep' or 'drop', got {screen_outliers!r}")
    return import_plan(plan, drop_outliers=screen_outliers == "drop").measurement
