"""2-D correction tables from a grid identification: a generic CSV grid and an Aerotech .cal.

Sign convention (stated in every file): ``error = measured − commanded`` of the machine at a
node, with the gauge terms of the measurement set-up removed (the laser zero of each direction
and the rotation of the mirror) and zero at the reference node; ``correction = −error``, the
value to add to the commanded position. The 2-D table corrects X and Y as functions of both
commanded positions; the controller interpolates between the nodes (bilinearly, for Aerotech).

- CSV (comma separated, ``#`` comment lines first): ``x_mm, y_mm, error_x_um, error_y_um,
  correction_x_um, correction_y_um, beyond_measured``, one row per node, Y rows then X columns.
- Aerotech 2-D calibration file, the layout of the vendor's own .cal files: ``;`` comment lines,
  ``:START2D <row axis> <column axis> <output axis 1> <output axis 2> <row step> <column step>
  <columns>``, ``:START2D POSUNIT=PRIMARY CORUNIT=PRIMARY/1000`` (plus ``OFFSETROW = …
  OFFSETCOL = …`` when the table does not start at 0: minus the first node's position), one
  line per row of ``<column-axis correction> <row-axis correction>`` pairs, ``:END``. Values are
  corrections in µm (primary units mm / 1000): Aerotech's Accuracy2D software wrote the grid
  643494's table with exactly this sign (volucal reproduces it to the last digit from the same
  data by the vendor's method). Check the sign on the controller before use: the table Aerotech's
  MATLAB stitching wrote for the grids 642583 has the opposite sign relative to its raw data.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..grid2d import GRID_AXES, Lattice
from ..grid2d_model import GridIdentification
from ..io.source import SourceText, parse_float
from ..userror import FormatError, UserError
from .export_common import write_text

FloatArray = NDArray[np.float64]
SIGN_CONVENTION = (
    "error = measured - commanded (um) with the set-up's gauge terms removed (laser zero per "
    "direction, mirror rotation), zero at the reference node; correction = -error, the value "
    "to add to the commanded position"
)
DECIMALS = 4  # µm: 0.1 nm, as the vendor's tables


@dataclass(frozen=True, eq=False)
class Grid2DTable:
    """Machine error and correction at the nodes of a regular 2-D table.

    ``error_um`` is indexed [direction (X, Y), row (Y), column (X)]; ``beyond_measured`` flags
    nodes outside the measured area (the identification holds its end values there).
    """

    x_mm: FloatArray
    y_mm: FloatArray
    error_um: FloatArray
    reference_mm: tuple[float, float]
    beyond_measured: NDArray[np.bool_]

    @property
    def correction_um(self) -> FloatArray:
        return -self.error_um + 0.0

    @property
    def lattice(self) -> Lattice:
        return Lattice(self.x_mm, self.y_mm)


def _nodes(low: float, high: float, spacing: float | None, default: FloatArray) -> FloatArray:
    if spacing is None:
        return np.asarray(default, dtype=float)
    if not spacing > 0:
        raise UserError(f"table spacing must be a positive number of mm, got {spacing}")
    count = max(1, int(np.ceil((high - low) / spacing - 1e-9)))
    return np.linspace(low, high, count + 1)


def grid_table(
    identification: GridIdentification,
    spacing_mm: float | tuple[float, float] | None = None,
    *,
    surface: bool = True,
) -> Grid2DTable:
    """The 2-D table at the measured lattice nodes, or at nodes dividing its range evenly with at
    most ``spacing_mm`` between them (one value, or X and Y)."""
    lattice = identification.lattice
    pair = (spacing_mm, spacing_mm) if not isinstance(spacing_mm, tuple) else spacing_mm
    x = _nodes(float(lattice.x_mm[0]), float(lattice.x_mm[-1]), pair[0], lattice.x_mm)
    y = _nodes(float(lattice.y_mm[0]), float(lattice.y_mm[-1]), pair[1], lattice.y_mm)
    xx, yy = np.meshgrid(x, y)
    positions = np.stack([xx.ravel(), yy.ravel()], axis=1)
    reference = np.array([identification.reference_mm])
    values = identification.error(positions, surface=surface) - identification.error(
        reference, surface=surface
    )
    error = np.stack([values[:, k].reshape(xx.shape) for k in range(2)])
    beyond = identification.beyond_measured(positions).reshape(xx.shape)
    return Grid2DTable(x, y, error, identification.reference_mm, beyond)


def _f(value: float) -> str:
    return f"{round(float(value), DECIMALS) + 0.0:.{DECIMALS}f}"


def write_grid_csv(path: str | Path, table: Grid2DTable, comments: Sequence[str] = ()) -> Path:
    """Write the generic CSV grid (module notes) atomically."""
    lines = [f"# {c}" for c in comments]
    lines += [
        f"# sign: {SIGN_CONVENTION}",
        f"# reference (zero) at X = {table.reference_mm[0]:g} mm, Y = {table.reference_mm[1]:g} mm",
        "x_mm,y_mm,error_x_um,error_y_um,correction_x_um,correction_y_um,beyond_measured",
    ]
    correction = table.correction_um
    for j, y in enumerate(table.y_mm):
        for i, x in enumerate(table.x_mm):
            lines.append(
                ",".join(
                    [
                        f"{x:.6f}",
                        f"{y:.6f}",
                        _f(table.error_um[0, j, i]),
                        _f(table.error_um[1, j, i]),
                        _f(correction[0, j, i]),
                        _f(correction[1, j, i]),
                        str(int(table.beyond_measured[j, i])),
                    ]
                )
            )
    return write_text(Path(path), "\n".join(lines) + "\n")


def _uniform_step(nodes: FloatArray, axis: str) -> float:
    if nodes.size < 2:
        raise UserError(f"a 2-D table needs at least two {axis} nodes")
    steps = np.diff(nodes)
    if np.ptp(steps) > 1e-6:
        raise UserError(f"the {axis} nodes are not evenly spaced: a .cal table needs one step")
    return float(steps.mean())


def write_aerotech_cal(
    path: str | Path,
    table: Grid2DTable,
    axis_numbers: Mapping[str, int],
    *,
    column_axis: str = "X",
    comments: Sequence[str] = (),
) -> Path:
    """Write an Aerotech 2-D calibration file (module notes) with CRLF line ends, atomically.

    ``axis_numbers`` gives the controller's axis number (AxisIndex) of X and Y; the columns run
    along ``column_axis`` (the scan axis of the measurement), the rows along the other.
    """
    if column_axis not in GRID_AXES:
        raise UserError(f"the column axis must be X or Y, got {column_axis!r}")
    row_axis = "Y" if column_axis == "X" else "X"
    for axis in GRID_AXES:
        number = axis_numbers.get(axis)
        if not isinstance(number, int) or isinstance(number, bool) or number < 0:
            raise UserError(
                f"the .cal table needs the controller's axis number of {axis} "
                "(e.g. --cal-axes X=6,Y=5)"
            )
    col_nodes = table.x_mm if column_axis == "X" else table.y_mm
    row_nodes = table.y_mm if column_axis == "X" else table.x_mm
    col_step = _uniform_step(col_nodes, column_axis)
    row_step = _uniform_step(row_nodes, row_axis)
    correction = table.correction_um
    col_k, row_k = GRID_AXES.index(column_axis), GRID_AXES.index(row_axis)
    if column_axis == "Y":  # tables are [row (Y), column (X)]: make rows follow X
        correction = correction.transpose(0, 2, 1)
    lines = [f"; {c}" for c in comments]
    lines += [
        "; volucal 2-D correction table in the layout of Aerotech's 2-D calibration files",
        f"; sign: {SIGN_CONVENTION}",
        f"; values: {column_axis} correction then {row_axis} correction per node, um "
        "(CORUNIT=PRIMARY/1000 with mm primary units)",
        f"; rows: {row_axis} (axis {axis_numbers[row_axis]}) from {row_nodes[0]:g} to "
        f"{row_nodes[-1]:g} mm; columns: {column_axis} (axis {axis_numbers[column_axis]}) from "
        f"{col_nodes[0]:g} to {col_nodes[-1]:g} mm",
        f"; zero at X = {table.reference_mm[0]:g} mm, Y = {table.reference_mm[1]:g} mm",
        f":START2D {axis_numbers[row_axis]} {axis_numbers[column_axis]} "
        f"{axis_numbers[column_axis]} {axis_numbers[row_axis]} {row_step:.3f} {col_step:.3f} "
        f"{col_nodes.size} ",
    ]
    units = ":START2D POSUNIT=PRIMARY CORUNIT=PRIMARY/1000"
    if abs(row_nodes[0]) > 1e-9 or abs(col_nodes[0]) > 1e-9:
        units += f" OFFSETROW = {-row_nodes[0]:.3f} OFFSETCOL = {-col_nodes[0]:.3f}"
    lines.append(units)
    for j in range(row_nodes.size):
        lines.append(
            "".join(
                f"{_f(correction[col_k, j, i])}  {_f(correction[row_k, j, i])}  \t"
                for i in range(col_nodes.size)
            )
        )
    lines.append(":END")
    return write_text(Path(path), "\n".join(lines) + "\n", newline="\r\n")


@dataclass(frozen=True, eq=False)
class AerotechCal:
    """A 2-D calibration file as read: the table in the file's own values (µm for
    ``CORUNIT=…/1000``), ``values`` indexed [output (1, 2), row, column]."""

    row_axis: int
    column_axis: int
    output_axes: tuple[int, int]
    row_step_mm: float
    column_step_mm: float
    offset_row_mm: float
    offset_column_mm: float
    options: dict[str, str]
    values: FloatArray

    @property
    def row_mm(self) -> FloatArray:
        return np.asarray(
            -self.offset_row_mm + self.row_step_mm * np.arange(self.values.shape[1]), dtype=float
        )

    @property
    def column_mm(self) -> FloatArray:
        return np.asarray(
            -self.offset_column_mm + self.column_step_mm * np.arange(self.values.shape[2]),
            dtype=float,
        )


_OPTION = re.compile(r"(\w+)\s*=\s*(\S+)")


def read_aerotech_cal(path: str | Path) -> AerotechCal:
    """Read an Aerotech 2-D calibration file (module notes; vendor's or volucal's).

    Raises
    ------
    FormatError
        Naming the file and line for a missing or malformed ``:START2D`` line, a row with
        another number of values than the header announces, a value that is not a number.
    """
    source = SourceText.read(path)
    header: list[str] | None = None
    options: dict[str, str] = {}
    rows: list[list[float]] = []
    expected = 0
    for number, text in source.numbered():
        stripped = text.strip()
        if not stripped or stripped.startswith(";"):
            continue
        if stripped.startswith(":START2D"):
            tokens = stripped.split()[1:]
            if header is None:
                if len(tokens) != 7:
                    raise source.error(
                        ":START2D: expected row axis, column axis, two output "
                        "axes, row step, column step and column count",
                        number,
                    )
                header = tokens
                try:
                    expected = 2 * int(tokens[6])
                except ValueError:
                    raise source.error(
                        f":START2D: the column count {tokens[6]!r} is not a whole number", number
                    ) from None
            else:
                options.update({k.upper(): v for k, v in _OPTION.findall(stripped)})
                if "OUTAXIS3" in options:
                    expected = expected // 2 * 3
            continue
        if stripped.startswith(":END"):
            break
        if header is None:
            raise source.error("a table row before the :START2D line", number)
        tokens = stripped.split()
        if len(tokens) != expected:
            raise source.error(
                f"{len(tokens)} values where :START2D announces {expected}: the "
                "file is cut short or a value is missing",
                number,
            )
        rows.append([parse_float(t, source, number, "correction") for t in tokens])
    if header is None:
        raise source.error("no :START2D line: not a 2-D calibration file", source.last_line)
    if not rows:
        raise source.error("the table has no rows", source.last_line)
    values = np.asarray(rows)
    per_node = 3 if "OUTAXIS3" in options else 2
    table = np.stack([values[:, k::per_node] for k in range(2)])
    try:
        axes = [int(t) for t in header[:4]]
        steps = [float(t) for t in header[4:6]]
        offsets = [float(options.get(k, "0")) for k in ("OFFSETROW", "OFFSETCOL")]
    except ValueError as exc:
        raise FormatError(source.path, f":START2D: {exc}") from None
    return AerotechCal(
        axes[0],
        axes[1],
        (axes[2], axes[3]),
        steps[0],
        steps[1],
        offsets[0],
        offsets[1],
        options,
        table,
    )


def cal_as_table(cal: AerotechCal, axis_numbers: Mapping[str, int]) -> tuple[Lattice, FloatArray]:
    """A read .cal as a lattice and correction (µm) indexed [direction (X, Y), row (Y),
    column (X)], given the controller's axis number of X and Y."""
    names = {v: k for k, v in axis_numbers.items()}
    try:
        row_axis, column_axis = names[cal.row_axis], names[cal.column_axis]
        outputs = [names[a] for a in cal.output_axes]
    except KeyError as exc:
        raise UserError(
            f"the .cal's axis {exc.args[0]} is neither X ({axis_numbers.get('X')}) "
            f"nor Y ({axis_numbers.get('Y')})"
        ) from None
    correction = np.zeros_like(cal.values)
    for k, axis in enumerate(outputs):
        correction[GRID_AXES.index(axis)] = cal.values[k]
    if row_axis == "X" and column_axis == "Y":
        correction = correction.transpose(0, 2, 1)
        return Lattice(cal.row_mm, cal.column_mm), correction
    return Lattice(cal.column_mm, cal.row_mm), correction
