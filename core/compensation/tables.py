"""Compensation tables computed from an error source.

Three kinds of table, each stating the tool offset it assumes and flagging positions beyond the
measured range (where a source holds its end values instead of extrapolating):

- :class:`AxisTable` — per axis, along the axis' reference line (the other axes at the machine
  reference): the component of E along the axis, approached from below (forward) and from above
  (backward). The two directions differ only where the source has reversal.
- :class:`CrossAxisTable` — the other two components of E along the same line (straightness,
  squareness seen along the axis, sag, tool offset times the axis' angles). They are made zero at
  the input axis' reference position, so that the tables of the three axes add up without
  counting E at the reference more than once.
- :class:`VolumetricGrid` — E on a regular grid of the workspace (25 mm by default), direction
  free.

Every table carries both the *error* E at its nodes (what a controller that indexes its table by
the measured axis position needs, e.g. Siemens leadscrew error compensation) and the
*correction* ``commanded − nominal`` from the iterated inverse (:mod:`.inverse`; what a
controller that indexes by the commanded position adds, e.g. LinuxCNC). The two differ by E times
its slope: nanometres, but the inverse is the exact one.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..machine import AXES, AXIS_INDEX
from ..progress import CancelToken, ProgressCallback, check, report
from ..userror import UserError
from .inverse import invert
from .limits import MAX_TABLE_NODES, check_sizes, node_count
from .source import ErrorSource, measured_range, table_extents, unmoved_axes

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Two directions differing by less than this (µm) are one table.
REVERSAL_NEGLIGIBLE_UM = 1e-6


@dataclass(frozen=True)
class TableRequest:
    """What tables to compute.

    spacing_mm : node spacing of the axis and cross-axis tables (one value or per axis); the
        nodes divide the range evenly, so the spacing used is at most the one asked for.
    nodes_mm : explicit nodes per axis (ascending), overriding ``spacing_mm`` for that axis
        (e.g. Fanuc's points at the reference position plus whole intervals).
    tool_offset_mm : tool point the tables are for; the machine's tool offset by default.
    line_mm : the point the per-axis lines pass through; the machine reference by default.
    range_mm : table extent per axis; the measured range by default. Nodes beyond the measured
        range are flagged (the source holds its end values there).
    grid_spacing_mm : spacing of the volumetric grid (25 mm, DESIGN.md "Conventions"); None
        skips the grid.
    """

    spacing_mm: float | Mapping[str, float] = 10.0
    nodes_mm: Mapping[str, tuple[float, ...]] | None = None
    tool_offset_mm: tuple[float, float, float] | None = None
    line_mm: tuple[float, float, float] | None = None
    range_mm: Mapping[str, tuple[float, float]] | None = None
    grid_spacing_mm: float | None = 25.0

    def spacing_for(self, axis: str) -> float:
        value = self.spacing_mm[axis] if isinstance(self.spacing_mm, Mapping) else self.spacing_mm
        spacing = float(value)
        if not math.isfinite(spacing) or spacing <= 0:
            raise UserError(
                f"table spacing for {axis} must be a positive number of mm, got {value}"
            )
        return spacing


@dataclass(frozen=True, eq=False)
class AxisTable:
    """Positioning compensation of one axis along its reference line (µm, mm).

    ``error_*_um`` is the component of E along the axis at the node (approached from below:
    forward; from above: backward); ``correction_*_um`` is ``commanded − nominal`` along the axis
    from the inverse, with the nominal at the node.
    """

    axis: str
    position_mm: FloatArray
    error_forward_um: FloatArray
    error_backward_um: FloatArray
    correction_forward_um: FloatArray
    correction_backward_um: FloatArray
    line_mm: tuple[float, float, float]
    tool_offset_mm: tuple[float, float, float]
    measured_range_mm: tuple[float, float]
    beyond_range: BoolArray

    @property
    def bidirectional(self) -> bool:
        """True when forward and backward differ (the source has reversal on this axis)."""
        gap = np.abs(self.error_forward_um - self.error_backward_um)
        return bool(np.max(gap, initial=0.0) > REVERSAL_NEGLIGIBLE_UM)

    @property
    def error_mean_um(self) -> FloatArray:
        return (self.error_forward_um + self.error_backward_um) / 2.0

    @property
    def correction_mean_um(self) -> FloatArray:
        return (self.correction_forward_um + self.correction_backward_um) / 2.0

    @property
    def reversal_um(self) -> FloatArray:
        """Forward minus backward error (ISO 230-2 sign, B_i = x̄↑ − x̄↓)."""
        return self.error_forward_um - self.error_backward_um

    @property
    def spacing_mm(self) -> float | None:
        """The node spacing when the nodes are equidistant, else None."""
        return equidistant_spacing(self.position_mm)


@dataclass(frozen=True, eq=False)
class CrossAxisTable:
    """Error of ``output_axis`` as a function of ``input_axis`` along the input's reference line.

    Zero at the input axis' reference position (see the module docstring). Direction free: the
    mean of both approach directions.
    """

    input_axis: str
    output_axis: str
    position_mm: FloatArray
    error_um: FloatArray
    correction_um: FloatArray
    line_mm: tuple[float, float, float]
    tool_offset_mm: tuple[float, float, float]
    measured_range_mm: tuple[float, float]
    beyond_range: BoolArray

    @property
    def spacing_mm(self) -> float | None:
        return equidistant_spacing(self.position_mm)


@dataclass(frozen=True, eq=False)
class VolumetricGrid:
    """E and the compensating correction on a regular grid (µm), direction free.

    ``error_um`` and ``correction_um`` have shape (nx, ny, nz, 3), indexed by the X, Y, Z node
    positions.
    """

    x_mm: FloatArray
    y_mm: FloatArray
    z_mm: FloatArray
    error_um: FloatArray
    correction_um: FloatArray
    tool_offset_mm: tuple[float, float, float]
    spacing_mm: float

    @property
    def axes_mm(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        return (self.x_mm, self.y_mm, self.z_mm)

    @property
    def points_mm(self) -> FloatArray:
        """Node positions (nx·ny·nz, 3) in C order (X slowest)."""
        grid = np.meshgrid(self.x_mm, self.y_mm, self.z_mm, indexing="ij")
        return np.stack([g.ravel() for g in grid], axis=-1)


@dataclass(frozen=True, eq=False)
class CompensationTables:
    """Everything a compensation export needs, computed from one source."""

    axis: Mapping[str, AxisTable]
    cross: tuple[CrossAxisTable, ...]
    grid: VolumetricGrid | None
    tool_offset_mm: tuple[float, float, float]
    line_mm: tuple[float, float, float]
    flags: tuple[str, ...] = field(default_factory=tuple)

    def cross_table(self, input_axis: str, output_axis: str) -> CrossAxisTable:
        for table in self.cross:
            if table.input_axis == input_axis and table.output_axis == output_axis:
                return table
        raise KeyError((input_axis, output_axis))


def equidistant_spacing(position_mm: FloatArray) -> float | None:
    steps = np.diff(position_mm)
    if len(steps) == 0:
        return None
    if np.max(np.abs(steps - steps[0])) <= 1e-9 * max(1.0, abs(float(steps[0]))):
        return float(steps[0])
    return None


def even_nodes(low: float, high: float, spacing_mm: float) -> FloatArray:
    """Nodes dividing [low, high] into equal intervals no longer than ``spacing_mm`` (at most
    :data:`~.limits.MAX_TABLE_NODES`, checked before they are made)."""
    count = node_count(low, high, spacing_mm, "spacing")
    if count > MAX_TABLE_NODES:
        raise UserError(
            f"a spacing of {spacing_mm:g} mm gives {count:,} nodes over [{low:g}, {high:g}] mm; "
            f"volucal computes at most {MAX_TABLE_NODES:,}: use a larger spacing"
        )
    return np.linspace(low, high, count)


def build_tables(
    source: ErrorSource,
    request: TableRequest | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
) -> CompensationTables:
    """Per-axis, cross-axis and volumetric tables of ``source``.

    Parameters
    ----------
    source : ErrorSource
        The machine's errors (model, or the closed loop's extended model).
    request : TableRequest, optional
        Spacing, tool offset, reference line, extent and grid spacing.

    Returns
    -------
    CompensationTables
        With ``flags`` naming every table node beyond the measured range.
    """
    request = request or TableRequest()
    machine = source.machine
    tool = _vector(request.tool_offset_mm or machine.tool_offset_mm)
    assert machine.reference_mm is not None
    line = _vector(request.line_mm or machine.reference_mm)
    measured = measured_range(source)
    extents = table_extents(source, request.range_mm)
    unmoved = unmoved_axes(source)
    flags: list[str] = []
    axis_tables: dict[str, AxisTable] = {}
    cross_tables: list[CrossAxisTable] = []
    for step, axis in enumerate(AXES):
        check(cancel)
        report(progress, step / 4, f"axis table {axis}")
        nodes = _nodes(request, axis, extents[axis])
        own, cross = _line_tables(source, axis, nodes, line, tool, measured[axis])
        axis_tables[axis] = own
        cross_tables.extend(cross)
        if axis in unmoved:
            flags.append(
                f"{axis} table: no measured line moved {axis} (every reading at {axis} = "
                f"{unmoved[axis]:g} mm); its {nodes.size} nodes span [{nodes[0]:g}, "
                f"{nodes[-1]:g}] mm, along which nothing was measured"
            )
        elif np.any(own.beyond_range):
            outside = own.position_mm[own.beyond_range]
            low, high = measured[axis]
            flags.append(
                f"{axis} table: {outside.size} node(s) beyond the measured range "
                f"[{low:g}, {high:g}] mm (from {outside.min():g} to {outside.max():g} mm); "
                "their values are the end values held, not extrapolated"
            )
    grid = None
    if request.grid_spacing_mm is not None:
        check(cancel)
        report(progress, 0.75, "volumetric grid")
        grid = _grid(source, extents, float(request.grid_spacing_mm), tool)
    report(progress, 1.0, "tables done")
    return CompensationTables(
        axis=axis_tables,
        cross=tuple(cross_tables),
        grid=grid,
        tool_offset_mm=tool,
        line_mm=line,
        flags=tuple(flags),
    )


def _nodes(request: TableRequest, axis: str, extent: tuple[float, float]) -> FloatArray:
    if request.nodes_mm and axis in request.nodes_mm:
        nodes = np.asarray(request.nodes_mm[axis], dtype=float)
        if nodes.ndim != 1 or nodes.size < 2 or np.any(np.diff(nodes) <= 0):
            raise UserError(f"table nodes for {axis} must be at least two ascending positions")
        return nodes
    if not extent[1] > extent[0]:
        raise UserError(
            f"the {axis} table would span [{extent[0]:g}, {extent[1]:g}] mm, a single position: "
            "give an extent (range_mm) from a lower to a higher position"
        )
    return even_nodes(extent[0], extent[1], request.spacing_for(axis))


def _line_tables(
    source: ErrorSource,
    axis: str,
    nodes: FloatArray,
    line: tuple[float, float, float],
    tool: tuple[float, float, float],
    measured: tuple[float, float],
) -> tuple[AxisTable, list[CrossAxisTable]]:
    k = AXIS_INDEX[axis]
    # The reference point is appended so that the cross tables can be zeroed there exactly.
    positions = np.tile(np.asarray(line, dtype=float), (len(nodes) + 1, 1))
    positions[:-1, k] = nodes
    results = {}
    for sign in (1.0, -1.0):
        approach = np.full(3, sign)
        error = source.error_um(positions, approach, tool)
        inverse = invert(source, positions, approach, tool)
        results[sign] = (error, inverse.correction_um)
    (e_fwd, c_fwd), (e_bwd, c_bwd) = results[1.0], results[-1.0]
    low, high = measured
    tolerance = 1e-9 * max(1.0, abs(low), abs(high))
    beyond = (nodes < low - tolerance) | (nodes > high + tolerance)
    own = AxisTable(
        axis=axis,
        position_mm=nodes.copy(),
        error_forward_um=e_fwd[:-1, k].copy(),
        error_backward_um=e_bwd[:-1, k].copy(),
        correction_forward_um=c_fwd[:-1, k].copy(),
        correction_backward_um=c_bwd[:-1, k].copy(),
        line_mm=line,
        tool_offset_mm=tool,
        measured_range_mm=measured,
        beyond_range=beyond,
    )
    e_mean = (e_fwd + e_bwd) / 2.0
    c_mean = (c_fwd + c_bwd) / 2.0
    cross = []
    for output in AXES:
        j = AXIS_INDEX[output]
        if j == k:
            continue
        cross.append(
            CrossAxisTable(
                input_axis=axis,
                output_axis=output,
                position_mm=nodes.copy(),
                error_um=e_mean[:-1, j] - e_mean[-1, j],
                correction_um=c_mean[:-1, j] - c_mean[-1, j],
                line_mm=line,
                tool_offset_mm=tool,
                measured_range_mm=measured,
                beyond_range=beyond.copy(),
            )
        )
    return own, cross


def _grid(
    source: ErrorSource,
    extents: Mapping[str, tuple[float, float]],
    spacing_mm: float,
    tool: tuple[float, float, float],
) -> VolumetricGrid:
    if not math.isfinite(spacing_mm) or spacing_mm <= 0:
        raise UserError(f"grid spacing must be a positive number of mm, got {spacing_mm}")
    check_sizes({a: extents[a] for a in AXES}, None, spacing_mm)
    axes = [even_nodes(*extents[a], spacing_mm) for a in AXES]
    mesh = np.meshgrid(*axes, indexing="ij")
    points = np.stack([m.ravel() for m in mesh], axis=-1)
    error = source.error_um(points, None, tool)
    correction = invert(source, points, None, tool).correction_um
    shape = tuple(len(a) for a in axes) + (3,)
    return VolumetricGrid(
        x_mm=axes[0],
        y_mm=axes[1],
        z_mm=axes[2],
        error_um=error.reshape(shape),
        correction_um=correction.reshape(shape),
        tool_offset_mm=tool,
        spacing_mm=spacing_mm,
    )


def _vector(values: ArrayLike) -> tuple[float, float, float]:
    v = np.asarray(values, dtype=float).reshape(-1)
    if v.size != 3 or not np.all(np.isfinite(v)):
        raise UserError(f"expected three finite numbers [x, y, z] in mm, got {values!r}")
    return (float(v[0]), float(v[1]), float(v[2]))
