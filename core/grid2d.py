"""2-D grid measurements: the XY positioning errors measured at the nodes of a grid.

A grid is measured with one set-up: an interferometer reading X and Y against a flat (or
L-shaped) mirror, as Aerotech's Accuracy2D test does, or a grid encoder plate (Heidenhain KGM)
read by a scanning head. Every reading carries the commanded position and the deviation
``measured − commanded`` in X and/or Y. One set-up means one zero per direction (the laser zero,
or the plate's origin) and one alignment of the reference (the mirror's or the plate's rotation
about Z): these are the gauge terms of the grid (:class:`GridGauge`), not errors of the machine.

Units (volucal's): positions mm, deviations µm, temperatures °C, pressure kPa, humidity %RH.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .userror import UserError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
UM_PER_MM_URAD = 1e-3  # µrad × mm → µm

#: The two in-plane axes of a grid, in column order of ``position_mm`` and ``deviation_um``.
GRID_AXES = ("X", "Y")
UPPER_AXIS_CHOICES = ("X", "Y")


def _readonly(values: object, shape: tuple[int, ...] | None, what: str) -> FloatArray:
    array = np.array(values, dtype=float)
    if shape is not None and array.shape != shape:
        raise ValueError(f"{what}: expected shape {shape}, got {array.shape}")
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class GridMeasurement:
    """One grid as imported: commanded positions, deviations and the environment per reading.

    Parameters
    ----------
    name : str
        Name of the grid (the file's stem by default); one set of gauge terms per name.
    position_mm : (n, 2) array
        Commanded X and Y of every reading.
    deviation_um : (n, 2) array
        ``measured − commanded`` in X and in Y (µm); NaN where a direction was not measured.
    air_temp_c, material_temp_c, pressure_kpa, humidity_pct : (n,) arrays or None
        The environment recorded with each reading, where the file has it.
    upper_axis : "X", "Y" or None
        The axis mounted on the other one (nearer the measured point in the kinematic chain):
        its yaw turns the other axis' travel, so it shows with the other axis' position as lever
        arm (``ECY(y)·x`` in the Y readings when Y is the upper axis). None: not known; the
        identification then leaves that term out.
    units : mapping
        For every quantity read, ``"<unit> (<where it came from>)"``, e.g. ``"mm (.set file)"``.
    metadata : mapping
        What the file says about the test (serial numbers, date, axis numbers, …), as text.
    source_file, source_bytes
        The file the grid was read from and its bytes, kept unchanged.
    file_lines : (n,) array of int
        The 1-based line of every reading in the source file (for messages).
    """

    name: str
    position_mm: FloatArray
    deviation_um: FloatArray
    air_temp_c: FloatArray | None = None
    material_temp_c: FloatArray | None = None
    pressure_kpa: FloatArray | None = None
    humidity_pct: FloatArray | None = None
    upper_axis: str | None = None
    units: Mapping[str, str] = field(default_factory=dict)
    metadata: Mapping[str, str] = field(default_factory=dict)
    source_file: str = ""
    source_bytes: bytes = field(default=b"", repr=False)
    file_lines: IntArray | None = None

    def __post_init__(self) -> None:
        position = _readonly(self.position_mm, None, "position_mm")
        if position.ndim != 2 or position.shape[1] != 2 or position.shape[0] == 0:
            raise ValueError(f"position_mm: expected shape (n, 2), got {position.shape}")
        n = position.shape[0]
        object.__setattr__(self, "position_mm", position)
        object.__setattr__(
            self, "deviation_um", _readonly(self.deviation_um, (n, 2), "deviation_um")
        )
        for key in ("air_temp_c", "material_temp_c", "pressure_kpa", "humidity_pct"):
            value = getattr(self, key)
            if value is not None:
                object.__setattr__(self, key, _readonly(value, (n,), key))
        if self.upper_axis is not None and self.upper_axis not in UPPER_AXIS_CHOICES:
            raise ValueError(f"upper_axis must be X, Y or None, got {self.upper_axis!r}")
        if not np.all(np.isfinite(position)):
            raise ValueError("position_mm: every commanded position must be a finite number")
        if self.file_lines is not None:
            lines = np.array(self.file_lines, dtype=np.int64)
            if lines.shape != (n,):
                raise ValueError(f"file_lines: expected shape ({n},), got {lines.shape}")
            lines.setflags(write=False)
            object.__setattr__(self, "file_lines", lines)
        object.__setattr__(self, "units", MappingProxyType(dict(self.units)))
        object.__setattr__(self, "metadata", MappingProxyType(dict(self.metadata)))

    @property
    def count(self) -> int:
        return int(self.position_mm.shape[0])

    @property
    def measured_directions(self) -> tuple[str, ...]:
        """The directions with at least one reading (``("X", "Y")`` for an Accuracy2D grid)."""
        return tuple(
            a for k, a in enumerate(GRID_AXES) if np.any(np.isfinite(self.deviation_um[:, k]))
        )

    def environment_summary(self) -> dict[str, dict[str, float]]:
        """Mean, min and max of each environment quantity the grid carries."""
        out: dict[str, dict[str, float]] = {}
        for key in ("air_temp_c", "material_temp_c", "pressure_kpa", "humidity_pct"):
            value = getattr(self, key)
            if value is not None and value.size:
                out[key] = {
                    "mean": float(np.mean(value)),
                    "min": float(np.min(value)),
                    "max": float(np.max(value)),
                }
        return out


@dataclass(frozen=True, eq=False)
class Lattice:
    """The regular nodes a set of grids lies on: ``x_mm[i], y_mm[j]`` with one step per axis."""

    x_mm: FloatArray
    y_mm: FloatArray

    @property
    def step_mm(self) -> tuple[float, float]:
        return (_step(self.x_mm), _step(self.y_mm))

    @property
    def shape(self) -> tuple[int, int]:
        """(number of Y nodes, number of X nodes): tables are indexed [row j (Y), column i (X)]."""
        return (int(self.y_mm.size), int(self.x_mm.size))

    def index(self, position_mm: FloatArray) -> tuple[IntArray, IntArray]:
        """Column (X) and row (Y) index of each position's nearest node."""
        ix = np.rint((position_mm[:, 0] - self.x_mm[0]) / self.step_mm[0]).astype(np.int64)
        iy = np.rint((position_mm[:, 1] - self.y_mm[0]) / self.step_mm[1]).astype(np.int64)
        return ix, iy


def _step(nodes: FloatArray) -> float:
    return float((nodes[-1] - nodes[0]) / (nodes.size - 1)) if nodes.size > 1 else 0.0


def grid_nodes(values_mm: FloatArray, tolerance_mm: float) -> tuple[FloatArray, float, int]:
    """The regular nodes that ``values_mm`` lie on: (nodes, step, index of the worst value).

    Returns the nodes from the smallest to the largest value with the most common spacing, and
    the index of the value farthest from its node (so that a caller can name its line).
    """
    distinct = np.unique(np.round(values_mm / tolerance_mm)) * tolerance_mm
    if distinct.size == 1:
        return distinct, 0.0, 0
    gaps = np.diff(distinct)
    gaps = np.round(gaps[gaps > tolerance_mm] / tolerance_mm) * tolerance_mm
    step = 0.0
    if gaps.size:
        # the most common spacing (the larger on a tie): one odd value cannot move the step
        values, counts = np.unique(gaps, return_counts=True)
        step = float(values[counts == counts.max()].max())
    low, high = float(values_mm.min()), float(values_mm.max())
    count = int(round((high - low) / step)) + 1 if step > 0 else 1
    nodes = np.asarray(low + step * np.arange(count), dtype=float)
    nearest = np.clip(np.rint((values_mm - low) / step), 0, count - 1) if step > 0 else 0
    off = np.abs(values_mm - (low + step * nearest))
    return nodes, step, int(np.argmax(off))


class GridLayoutError(UserError):
    """Readings that do not lie on one regular lattice; ``index`` is the reading at fault."""

    def __init__(self, grid: GridMeasurement, index: int | None, reason: str) -> None:
        self.grid = grid
        self.index = index
        self.reason = reason
        super().__init__(f"{_where(grid, index)}: {reason}")


def common_lattice(grids: list[GridMeasurement], tolerance_mm: float = 1e-3) -> Lattice:
    """The regular lattice every grid's nodes lie on (one step per axis shared by all grids).

    Raises
    ------
    UserError
        When a grid's positions are off its regular nodes or the grids' steps or node origins
        differ, naming the grid, the file line and what to check.
    """
    if not grids:
        raise UserError("no grid given")
    steps: list[tuple[float, float]] = []
    for grid in grids:
        pair = []
        for k, axis in enumerate(GRID_AXES):
            nodes, step, worst = grid_nodes(grid.position_mm[:, k], tolerance_mm)
            if nodes.size < 2:
                raise GridLayoutError(
                    grid,
                    None,
                    f"every reading has the same commanded {axis} ({nodes[0]:g} "
                    f"mm): a grid needs at least two {axis} positions; check the column map",
                )
            distinct = np.unique(np.round(grid.position_mm[:, k] / tolerance_mm))
            if nodes.size > max(2 * distinct.size, 16) or nodes.size > 4 * grid.count:
                # a spacing far below the values' spread: measured values, not commanded nodes
                gaps = np.diff(np.sort(grid.position_mm[:, k]))
                index = int(
                    np.argsort(grid.position_mm[:, k])[
                        1 + int(np.argmin(np.where(gaps > tolerance_mm, gaps, np.inf)))
                    ]
                )
                raise GridLayoutError(
                    grid,
                    index,
                    f"the commanded {axis} values ({distinct.size} distinct, some "
                    f"{step:.4g} mm apart) do not lie on a regular grid: check the column map "
                    "(are the commanded and measured columns swapped?)",
                )
            offset = abs(
                grid.position_mm[worst, k]
                - (nodes[0] + step * round((grid.position_mm[worst, k] - nodes[0]) / step))
            )
            if offset > tolerance_mm:
                raise GridLayoutError(
                    grid,
                    worst,
                    f"commanded {axis} = {grid.position_mm[worst, k]:.6g} mm is "
                    f"{offset:.4g} mm off the grid's {step:g} mm nodes: check this line (are "
                    "the commanded and measured columns swapped?)",
                )
            pair.append(step)
        steps.append((pair[0], pair[1]))
    step_x = steps[0][0]
    step_y = steps[0][1]
    for grid, (sx, sy) in zip(grids, steps, strict=True):
        if abs(sx - step_x) > tolerance_mm or abs(sy - step_y) > tolerance_mm:
            raise GridLayoutError(
                grid,
                None,
                f"its node step ({sx:g} × {sy:g} mm) differs from the first "
                f"grid's ({step_x:g} × {step_y:g} mm); grids fitted together must share one "
                "step",
            )
    low = grids[0].position_mm.min(axis=0)
    high = grids[0].position_mm.max(axis=0)
    for grid in grids[1:]:
        low = np.minimum(low, grid.position_mm.min(axis=0))
        high = np.maximum(high, grid.position_mm.max(axis=0))
    axes_nodes = []
    for k, step in enumerate((step_x, step_y)):
        count = int(round((high[k] - low[k]) / step)) + 1
        nodes = low[k] + step * np.arange(count)
        for grid in grids:
            shift = (grid.position_mm[:, k] - low[k]) / step
            if np.max(np.abs(shift - np.rint(shift))) * step > tolerance_mm:
                raise GridLayoutError(
                    grid,
                    None,
                    f"its {GRID_AXES[k]} nodes are not on the {step:g} mm lattice "
                    "of the other grids (offset origin); grids fitted together must share "
                    "their nodes",
                )
        axes_nodes.append(nodes)
    return Lattice(axes_nodes[0], axes_nodes[1])


def _where(grid: GridMeasurement, index: int | None) -> str:
    source = grid.source_file or grid.name
    if index is not None and grid.file_lines is not None:
        return f"{source}, line {int(grid.file_lines[index])}"
    return source


def missing_nodes(grid: GridMeasurement, lattice: Lattice) -> list[tuple[float, float]]:
    """Nodes of the grid's own rectangle that have no reading (sorted by Y, then X)."""
    ix, iy = lattice.index(grid.position_mm)
    seen = np.zeros((int(iy.max()) + 1, int(ix.max()) + 1), dtype=bool)
    seen[iy, ix] = True
    rows, cols = np.nonzero(~seen[iy.min() :, ix.min() :])
    return [
        (float(lattice.x_mm[ix.min() + c]), float(lattice.y_mm[iy.min() + r]))
        for r, c in zip(rows, cols, strict=True)
    ]


# --------------------------------------------------------------------------------------------
# Gauge terms
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class GridGauge:
    """The terms one set-up adds to every reading of a grid, and nothing of the machine.

    ``offset_x_um``/``offset_y_um``: the zero of each direction (where the laser was zeroed);
    ``rotation_urad``: the rotation of the reference (mirror or plate) about +Z, which adds
    ``−rotation·y`` to the X readings and ``+rotation·x`` to the Y readings (a rigid turn of an
    orthogonal reference; its squareness is the reference for the machine's).
    """

    offset_x_um: float = 0.0
    offset_y_um: float = 0.0
    rotation_urad: float = 0.0

    def evaluate(self, position_mm: FloatArray) -> FloatArray:
        """(n, 2) values of the gauge terms at the given positions (µm)."""
        x = position_mm[:, 0]
        y = position_mm[:, 1]
        turn = self.rotation_urad * UM_PER_MM_URAD
        return np.stack([self.offset_x_um - turn * y, self.offset_y_um + turn * x], axis=1)

    def to_json(self) -> dict[str, float]:
        return {
            "offset_x_um": self.offset_x_um,
            "offset_y_um": self.offset_y_um,
            "rotation_urad": self.rotation_urad,
        }


def gauge_design(position_mm: FloatArray) -> FloatArray:
    """Columns (offset X, offset Y, rotation) of the gauge terms for stacked X then Y values."""
    n = position_mm.shape[0]
    design = np.zeros((2 * n, 3))
    design[:n, 0] = 1.0
    design[n:, 1] = 1.0
    design[:n, 2] = -position_mm[:, 1] * UM_PER_MM_URAD
    design[n:, 2] = position_mm[:, 0] * UM_PER_MM_URAD
    return design


def remove_gauge_terms(
    position_mm: FloatArray, values_um: FloatArray
) -> tuple[FloatArray, GridGauge]:
    """``values_um`` (n, 2; X and Y) less the least-squares gauge terms, and those terms.

    Used to compare two maps of the same grid that differ by their set-up conventions (where
    each zeroes the map and how each removes the reference's rotation); NaN values are ignored.
    """
    design = gauge_design(position_mm)
    stacked = np.concatenate([values_um[:, 0], values_um[:, 1]])
    usable = np.isfinite(stacked)
    coefficients, *_ = np.linalg.lstsq(design[usable], stacked[usable], rcond=None)
    gauge = GridGauge(*(float(c) for c in coefficients))
    return values_um - gauge.evaluate(position_mm), gauge


def rms(values: FloatArray) -> float:
    """Root mean square of the finite values (NaN when there are none)."""
    finite = np.asarray(values, dtype=float)
    finite = finite[np.isfinite(finite)]
    return float(np.sqrt(np.mean(finite**2))) if finite.size else float("nan")


def describe_grid(grid: GridMeasurement, lattice: Lattice | None = None) -> dict[str, Any]:
    """A JSON-friendly summary of a grid (counts, nodes, units, environment, metadata)."""
    lattice = lattice or common_lattice([grid])
    low = grid.position_mm.min(axis=0)
    high = grid.position_mm.max(axis=0)
    return {
        "name": grid.name,
        "file": grid.source_file,
        "readings": grid.count,
        "measured_directions": list(grid.measured_directions),
        "nodes": {
            "x": int(round((high[0] - low[0]) / lattice.step_mm[0])) + 1,
            "y": int(round((high[1] - low[1]) / lattice.step_mm[1])) + 1,
        },
        "step_mm": {"x": lattice.step_mm[0], "y": lattice.step_mm[1]},
        "range_mm": {"x": [float(low[0]), float(high[0])], "y": [float(low[1]), float(high[1])]},
        "upper_axis": grid.upper_axis,
        "units": dict(grid.units),
        "environment": grid.environment_summary(),
        "metadata": dict(grid.metadata),
    }
