"""Aerotech Accuracy2D data files (the ``aerotech-accuracy2d`` preset of the grid reader).

Layout, as written by Aerotech's Linear Calibrator 2D software (Automation1):

- ``Key : value`` header lines (``JobName``, ``SerialNum``, ``TestType : Accuracy2D``,
  ``TestOrientation : Lower Axis ; Upper Axis``, ``AxisIndex : 6 ; 5``, ``StepSize : 5 ; 5``,
  ``TestLength : 350 ; 350``, …; two values separated by ``;`` are Axis 1 and Axis 2), sections
  ``DBase Info`` and ``Ignored``;
- the column header ``Position1 LaserData1 Position2 LaserData2 AirTemp MatTemp Pressure
  Humidity``, a line ``:START``, then one whitespace-separated row per grid point: commanded and
  laser-measured position of Axis 1 and Axis 2, air and material temperature, pressure, humidity.

Units. The data file does not state them. The position unit comes from the ``.set`` file saved
beside it (``PositionUnitName : mm``) or must be given; temperatures are °C, pressure mmHg and
humidity %RH in this layout (the vendor's .cal computed from the same data states "Average Air
Pressure (mmHg): 740.01" for a column of 740.01), and are checked for plausibility.

Axes. Which of Axis 1 and Axis 2 is X is given (``axes="XY"``: Axis 1 is X) or read from the
``SerialNum`` names when they end in X… and Y… (``643494-1-1-XWafer ; 643494-1-1-YWafer``); the
choice and its reason are recorded. ``TestOrientation`` says which axis is mounted on the other
(the upper axis).
"""

from __future__ import annotations

from pathlib import Path

from ..grid2d import GridMeasurement
from ..grid2d_table import GridColumnMap, GridFormat, check_grid, read_grid_table
from ..userror import FormatError
from .source import SourceText
from .units import POSITION_FACTOR, normalise_unit

PRESET = "aerotech-accuracy2d"
COLUMNS = (
    "Position1",
    "LaserData1",
    "Position2",
    "LaserData2",
    "AirTemp",
    "MatTemp",
    "Pressure",
    "Humidity",
)
DATA_MARKER = ":START"
#: Header keys kept as the grid's metadata.
KEPT = (
    "JobName",
    "SerialNum",
    "DateTime",
    "OperatorName",
    "LaserID",
    "StageLabel",
    "CoefficientOfThermalExpansion",
    "ControllerVerison",
    "BiDirectional",
    "CountsPerUnit",
    "TestType",
    "OpticLocation",
    "Payload",
    "TestOrientation",
    "MotionDirection",
    "AxisIndex",
    "HomeOffset",
    "StageSerialNumber",
    "StepSize",
    "TestLength",
)


def is_accuracy2d(source: SourceText) -> bool:
    """True when the file declares ``TestType : Accuracy2D`` before its data."""
    for _, text in source.numbered():
        if text.strip() == DATA_MARKER:
            return False
        key, colon, value = text.partition(":")
        if colon and key.strip() == "TestType":
            return value.strip() == "Accuracy2D"
    return False


def _header(source: SourceText) -> tuple[dict[str, tuple[str, int]], int]:
    """``{key: (value, line)}`` of the header and the line of ``:START``."""
    fields: dict[str, tuple[str, int]] = {}
    for number, text in source.numbered():
        stripped = text.strip()
        if stripped == DATA_MARKER:
            return fields, number
        key, colon, value = stripped.partition(" : ")
        if colon and key and " " not in key:
            fields.setdefault(key, (value.strip(), number))
    raise source.error(
        f"no {DATA_MARKER!r} line: the file is cut short before its data or is "
        "not an Accuracy2D data file",
        source.last_line,
    )


def _pair(value: str) -> list[str]:
    return [part.strip() for part in value.split(";")]


def _set_file_unit(path: Path) -> tuple[str, str] | None:
    """(unit, note) from the ``PositionUnitName`` of the .set file beside ``path``, if any."""
    set_path = path.with_suffix(".set")
    if not set_path.is_file():
        return None
    text = SourceText.read(set_path)
    for number, line in text.numbered():
        key, colon, value = line.partition(":")
        if colon and key.strip() == "PositionUnitName":
            unit = normalise_unit(value.strip()).lower()
            if unit not in POSITION_FACTOR:
                raise text.error(
                    f"PositionUnitName {value.strip()!r} is not a length unit "
                    f"volucal knows ({', '.join(POSITION_FACTOR)})",
                    number,
                )
            return unit, f"PositionUnitName in {set_path.name}, line {number}"
    return None


def _axis_names(
    source: SourceText, fields: dict[str, tuple[str, int]], axes: str | None
) -> tuple[tuple[str, str], str]:
    """Machine axis (X/Y) of Axis 1 and Axis 2, and why."""
    if axes is not None:
        choice = axes.strip().upper()
        if choice not in ("XY", "YX"):
            raise FormatError(source.path, f"axes must be XY (Axis 1 is X) or YX, got {axes!r}")
        return (choice[0], choice[1]), "given"
    serial, line = fields.get("SerialNum", ("", None))  # type: ignore[assignment]
    names = _pair(serial)
    letters = [name.rsplit("-", 1)[-1][:1].upper() for name in names]
    if len(letters) == 2 and sorted(letters) == ["X", "Y"]:
        return (letters[0], letters[1]), f"SerialNum {serial!r} (line {line})"
    raise source.error(
        f"cannot tell which of Axis 1 and Axis 2 is X: SerialNum {serial!r} does not end in "
        "X… and Y…; give the axes (--axes XY when Axis 1 is X, --axes YX otherwise)",
        line,
    )


def _upper_axis(fields: dict[str, tuple[str, int]], names: tuple[str, str]) -> str | None:
    orientation = _pair(fields.get("TestOrientation", ("", 0))[0])
    upper = [n for n, o in zip(names, orientation, strict=False) if o.lower() == "upper axis"]
    return upper[0] if len(upper) == 1 else None


def _expected_count(source: SourceText, fields: dict[str, tuple[str, int]]) -> int | None:
    """Points announced by StepSize and TestLength (one pass), or None if not stated."""
    if "StepSize" not in fields or "TestLength" not in fields:
        return None
    if fields.get("BiDirectional", ("0", 0))[0] not in ("0", ""):
        return None
    try:
        steps = [float(v) for v in _pair(fields["StepSize"][0])]
        lengths = [float(v) for v in _pair(fields["TestLength"][0])]
    except ValueError:
        raise source.error(
            "StepSize/TestLength: expected two numbers separated by ';'", fields["StepSize"][1]
        ) from None
    if len(steps) != 2 or len(lengths) != 2 or min(steps) <= 0:
        raise source.error(
            "StepSize/TestLength: expected two positive numbers separated by ';'",
            fields["StepSize"][1],
        )
    counts = [round(abs(length) / step) + 1 for length, step in zip(lengths, steps, strict=True)]
    return counts[0] * counts[1]


def read_accuracy2d(
    path: str | Path,
    *,
    axes: str | None = None,
    position_unit: str | None = None,
    upper_axis: str | None = "auto",
    name: str | None = None,
) -> GridMeasurement:
    """Read an Aerotech Accuracy2D data file (module notes) into a :class:`GridMeasurement`.

    Parameters
    ----------
    axes : "XY", "YX" or None
        Which machine axis Axis 1 and Axis 2 are; None reads it from ``SerialNum``.
    position_unit : str or None
        Unit of the positions; needed when the ``.set`` file is not beside the data file (and
        must agree with it when it is).
    upper_axis : "auto", "X", "Y" or None
        The axis mounted on the other; "auto" reads ``TestOrientation``.

    Raises
    ------
    FormatError
        Naming the file and line: not an Accuracy2D file, other columns, a missing unit, a file
        cut short (fewer rows than StepSize and TestLength announce), and every check of
        :func:`volucal.core.grid2d_table.read_grid_table`.
    """
    path = Path(path)
    source = SourceText.read(path)
    fields, start = _header(source)
    test_type = fields.get("TestType")
    if test_type is None or test_type[0] != "Accuracy2D":
        raise source.error(
            f"TestType is {test_type[0]!r}, not 'Accuracy2D': read this file with a column map"
            if test_type
            else "no 'TestType : Accuracy2D' line: not an Accuracy2D data file",
            test_type[1] if test_type else 1,
        )
    header_line = next((n for n in range(start - 1, 0, -1) if source.lines[n - 1].strip()), 1)
    found = tuple(source.lines[header_line - 1].split())
    if found != COLUMNS:
        raise source.error(
            f"expected the columns {' '.join(COLUMNS)}, found {' '.join(found) or 'nothing'}",
            header_line,
        )

    from_set = _set_file_unit(path)
    if from_set and position_unit and normalise_unit(position_unit).lower() != from_set[0]:
        raise FormatError(
            path,
            f"the position unit is given as {position_unit!r} but "
            f"{from_set[1]} says {from_set[0]!r}",
        )
    if from_set:
        unit, unit_note = from_set
    elif position_unit:
        unit, unit_note = normalise_unit(position_unit).lower(), "given"
    else:
        raise FormatError(
            path,
            f"no unit for the positions: the data file does not state it and its .set "
            f"file ({path.with_suffix('.set').name}) is not beside it; give it (--position-unit "
            "mm)",
        )

    names, axes_note = _axis_names(source, fields, axes)
    upper = _upper_axis(fields, names) if upper_axis == "auto" else upper_axis
    first, second = ("x", "y") if names == ("X", "Y") else ("y", "x")
    columns = GridColumnMap(
        **{
            first: "Position1",
            f"measured_{first}": "LaserData1",
            second: "Position2",
            f"measured_{second}": "LaserData2",
            "air_temp": "AirTemp",
            "material_temp": "MatTemp",
            "pressure": "Pressure",
            "humidity": "Humidity",
        }
    )
    layout_note = "Aerotech Accuracy2D layout"
    fmt = GridFormat(
        columns=columns,
        position_unit=unit,
        temperature_unit="C",
        pressure_unit="mmHg",
        delimiter="whitespace",
        data_marker=DATA_MARKER,
        end_marker=":END",
        upper_axis=upper,
        complete=False,
        unit_notes={
            "position": unit_note,
            "temperature": layout_note,
            "pressure": f"{layout_note}; the vendor's .cal header states mmHg",
        },
    )
    metadata = {key: fields[key][0] for key in KEPT if key in fields}
    metadata["preset"] = PRESET
    metadata["axes"] = f"Axis 1 = {names[0]}, Axis 2 = {names[1]} ({axes_note})"
    metadata["upper_axis"] = (
        f"{upper} (TestOrientation)"
        if upper_axis == "auto" and upper
        else "not stated (TestOrientation)"
        if upper_axis == "auto"
        else f"{upper} (given)"
    )
    axis_index = _pair(fields.get("AxisIndex", ("", 0))[0])
    if len(axis_index) == 2 and all(v.isdigit() for v in axis_index):
        metadata[f"axis_number_{names[0]}"] = axis_index[0]
        metadata[f"axis_number_{names[1]}"] = axis_index[1]
    grid = read_grid_table(path, fmt, name=name, metadata=metadata, source=source)

    expected = _expected_count(source, fields)
    if expected is not None and grid.count != expected:
        where = f"lines {fields['StepSize'][1]} and {fields['TestLength'][1]}"
        raise source.error(
            f"{grid.count} readings where StepSize and TestLength ({where}) announce "
            f"{expected}: "
            + (
                "the file is cut short here"
                if grid.count < expected
                else "rows are repeated or the header is wrong"
            ),
            int(grid.file_lines[-1]) if grid.file_lines is not None else source.last_line,
        )
    # With the count right, every node must still be there (a repeated row hides a gap).
    check_grid(source, grid, fmt.node_tolerance_mm, complete=True)
    return grid
