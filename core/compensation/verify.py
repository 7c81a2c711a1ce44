"""Verification: apply a compensation to a (virtual) machine and measure what is left.

The machine is an :class:`ErrorSource` taken as the truth (the virtual machine, or the model
itself for a prediction). A compensation is anything that turns nominal positions into commands
(``command_mm(nominal, approach)``): the controller simulations of :mod:`.controller`, the
volumetric grid with trilinear interpolation, or the exact inverse that NC-program rewriting
applies at every target point. The residual at a nominal point n is ``c + E(c) − n``.

Compensation rates (DESIGN.md, "Conventions"), per axis direction d over a regular grid of the
workspace: RMS-based ``100·(1 − RMS(E_d after)/RMS(E_d before))`` and range-based
``100·(1 − range after/range before)``. The grid used here is the regular grid (25 mm unless set)
plus the centres of its cells, so that a compensation grid with the same spacing is also judged
between its nodes. Where the machine has reversal every point is evaluated approached from below
and from above (all axes), and both are pooled.

ISO 230-2 figures are given along each axis' reference line, approached from below (↑) and from
above (↓), for the component along the axis: E↑, E↓, E (bidirectional systematic positioning
error), M (mean bidirectional positioning error), B (reversal, max |x̄↑ − x̄↓|) and the mean
reversal, ISO 230-2 §3 definitions with one deterministic run per direction (a model has no
repeatability: A = E and R = B here).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import RegularGridInterpolator

from ..machine import AXES, AXIS_INDEX
from ..progress import CancelToken, ProgressCallback, check, report
from .controller import axis_compensation, reversal_compensation
from .inverse import invert
from .limits import check_sizes
from .source import ErrorSource, table_extents
from .tables import CompensationTables, VolumetricGrid, even_nodes

FloatArray = NDArray[np.float64]
UM_PER_MM = 1e3

RATE_DEFINITION = (
    "per axis direction d over a regular grid of the workspace (spacing {spacing:g} mm, plus the "
    "centres of its cells): RMS-based 100*(1 - RMS(E_d after)/RMS(E_d before)), range-based "
    "100*(1 - range(E_d after)/range(E_d before)); E is the volumetric error of the machine, "
    "before = uncompensated, after = with the compensation applied as the controller applies it"
)


class Compensation(Protocol):
    """Anything that turns nominal positions into the commands that compensate them."""

    def command_mm(self, nominal_mm: ArrayLike, approach: ArrayLike) -> FloatArray: ...


class GridCompensation:
    """Volumetric grid applied with trilinear interpolation, end values held (3-D grid
    compensation as Fanuc's 3D error compensation and ISG apply it)."""

    def __init__(self, grid: VolumetricGrid) -> None:
        self.grid = grid
        self._interpolators = [
            RegularGridInterpolator(grid.axes_mm, grid.correction_um[..., k], method="linear")
            for k in range(3)
        ]

    def command_mm(self, nominal_mm: ArrayLike, approach: ArrayLike) -> FloatArray:
        n = np.atleast_2d(np.asarray(nominal_mm, dtype=float))
        inside = n.copy()
        for k, nodes in enumerate(self.grid.axes_mm):
            inside[:, k] = np.clip(inside[:, k], nodes[0], nodes[-1])
        correction = np.stack([f(inside) for f in self._interpolators], axis=-1)
        return n + correction / UM_PER_MM


class SumCompensation:
    """Several compensations active at once: their corrections add (e.g. a volumetric grid plus
    bidirectional reversal tables, as Beckhoff/ISG load them together)."""

    def __init__(self, *parts: Compensation) -> None:
        self.parts = parts

    def command_mm(self, nominal_mm: ArrayLike, approach: ArrayLike) -> FloatArray:
        n = np.atleast_2d(np.asarray(nominal_mm, dtype=float))
        command = n.copy()
        for part in self.parts:
            command += part.command_mm(n, approach) - n
        return command


class ExactCompensation:
    """The exact inverse of a source at each point: what NC-program rewriting commands at every
    target point (between points it follows the split segments; see :mod:`.ncprogram`)."""

    def __init__(self, source: ErrorSource, tool_offset_mm: ArrayLike | None = None) -> None:
        self.source = source
        self.tool_offset_mm = tool_offset_mm

    def command_mm(self, nominal_mm: ArrayLike, approach: ArrayLike) -> FloatArray:
        return invert(self.source, nominal_mm, approach, self.tool_offset_mm).commanded_mm


@dataclass(frozen=True)
class Rates:
    """Compensation rates per axis direction (percent) and the statistics behind them (µm)."""

    rms_percent: Mapping[str, float]
    range_percent: Mapping[str, float]
    rms_before_um: Mapping[str, float]
    rms_after_um: Mapping[str, float]
    range_before_um: Mapping[str, float]
    range_after_um: Mapping[str, float]
    max_after_um: Mapping[str, float]

    def to_json(self) -> dict[str, object]:
        """Plain JSON: a rate that is not defined (no error to compensate) is None."""
        return {
            "rms_percent": defined(self.rms_percent),
            "range_percent": defined(self.range_percent),
            "rms_before_um": dict(self.rms_before_um),
            "rms_after_um": dict(self.rms_after_um),
            "range_before_um": dict(self.range_before_um),
            "range_after_um": dict(self.range_after_um),
            "max_abs_after_um": dict(self.max_after_um),
        }


def defined(rates: Mapping[str, float]) -> dict[str, float | None]:
    """Rates per axis direction with None where a rate is not defined (NaN)."""
    return {axis: value if math.isfinite(value) else None for axis, value in rates.items()}


def rate_text(value: float | None) -> str:
    """A rate (%) in a 5-character column; "—" where it is not defined (None or NaN)."""
    if value is None or not math.isfinite(value):
        return f"{'—':>5}"
    return f"{value:5.1f}"


#: Below this (µm: a nanometre, a laser interferometer's resolution) a direction has no error to
#: compensate, and a rate would divide rounding by rounding: a plan that measures X alone leaves
#: the model's Ey at 10⁻¹⁴ µm, which "compensates" by 100 % or by −0.003 % alike.
RATE_FLOOR_UM = 1e-3


def compensation_rates(before_um: ArrayLike, after_um: ArrayLike) -> Rates:
    """Rates per direction from residuals before and after (each (n, 3), µm); NaN (null in
    report.json) for a direction whose error before is below :data:`RATE_FLOOR_UM`."""
    b = np.asarray(before_um, dtype=float).reshape(-1, 3)
    a = np.asarray(after_um, dtype=float).reshape(-1, 3)
    rms_b = np.sqrt(np.mean(b**2, axis=0))
    rms_a = np.sqrt(np.mean(a**2, axis=0))
    range_b = np.ptp(b, axis=0)
    range_a = np.ptp(a, axis=0)

    def rate(after: FloatArray, before: FloatArray) -> dict[str, float]:
        with np.errstate(divide="ignore", invalid="ignore"):
            values = np.where(before >= RATE_FLOOR_UM, 100.0 * (1.0 - after / before), np.nan)
        return {axis: float(values[k]) for k, axis in enumerate(AXES)}

    def per_axis(values: FloatArray) -> dict[str, float]:
        return {axis: float(values[k]) for k, axis in enumerate(AXES)}

    return Rates(
        rms_percent=rate(rms_a, rms_b),
        range_percent=rate(range_a, range_b),
        rms_before_um=per_axis(rms_b),
        rms_after_um=per_axis(rms_a),
        range_before_um=per_axis(range_b),
        range_after_um=per_axis(range_a),
        max_after_um=per_axis(np.max(np.abs(a), axis=0)),
    )


@dataclass(frozen=True)
class PositioningFigures:
    """ISO 230-2 systematic figures of one axis line (µm); one deterministic run each way."""

    E_up_um: float
    E_down_um: float
    E_um: float
    M_um: float
    B_um: float
    mean_reversal_um: float

    def to_json(self) -> dict[str, float]:
        return {
            "E_up_um": self.E_up_um,
            "E_down_um": self.E_down_um,
            "E_um": self.E_um,
            "M_um": self.M_um,
            "B_um": self.B_um,
            "mean_reversal_um": self.mean_reversal_um,
        }


def positioning_figures(up_um: ArrayLike, down_um: ArrayLike) -> PositioningFigures:
    """ISO 230-2 E↑, E↓, E, M, B and mean reversal from the mean deviations per target."""
    up = np.asarray(up_um, dtype=float)
    down = np.asarray(down_um, dtype=float)
    both = np.concatenate([up, down])
    mean = (up + down) / 2.0
    reversal = up - down
    return PositioningFigures(
        E_up_um=float(np.ptp(up)),
        E_down_um=float(np.ptp(down)),
        E_um=float(np.ptp(both)),
        M_um=float(np.ptp(mean)),
        B_um=float(np.max(np.abs(reversal))),
        mean_reversal_um=float(np.mean(reversal)),
    )


@dataclass(frozen=True)
class MethodResult:
    """One compensation method verified: rates, ISO 230-2 figures before/after per axis."""

    method: str
    description: str
    rates: Rates
    iso230_2: Mapping[str, Mapping[str, PositioningFigures]]

    def to_json(self) -> dict[str, object]:
        return {
            "method": self.method,
            "description": self.description,
            "rates": self.rates.to_json(),
            "iso230_2": {
                axis: {when: figures.to_json() for when, figures in by_when.items()}
                for axis, by_when in self.iso230_2.items()
            },
        }


@dataclass(frozen=True)
class VerificationResult:
    """All methods verified on the same points of the same machine."""

    methods: Mapping[str, MethodResult]
    grid_spacing_mm: float
    points: int
    approaches: tuple[int, ...]
    tool_offset_mm: tuple[float, float, float]
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def rate_definition(self) -> str:
        return RATE_DEFINITION.format(spacing=self.grid_spacing_mm)

    def to_json(self) -> dict[str, object]:
        return {
            "rate_definition": self.rate_definition,
            "grid_spacing_mm": self.grid_spacing_mm,
            "points": self.points,
            "approaches": list(self.approaches),
            "tool_offset_mm": list(self.tool_offset_mm),
            "methods": {name: m.to_json() for name, m in self.methods.items()},
            "notes": list(self.notes),
        }


@dataclass(frozen=True)
class VerifyRequest:
    """Where to verify: grid spacing (mm), tool offset (machine's by default), extent per axis
    (the truth's measured range by default)."""

    grid_spacing_mm: float = 25.0
    tool_offset_mm: tuple[float, float, float] | None = None
    range_mm: Mapping[str, tuple[float, float]] | None = None


def verification_points(
    extents: Mapping[str, tuple[float, float]], spacing_mm: float
) -> FloatArray:
    """The regular grid at ``spacing_mm`` plus the centres of its cells, (n, 3) mm."""
    check_sizes({a: extents[a] for a in AXES}, None, spacing_mm)
    nodes = [even_nodes(*extents[a], spacing_mm) for a in AXES]
    centres = [(v[:-1] + v[1:]) / 2.0 for v in nodes]
    sets = []
    for axes in (nodes, centres):
        mesh = np.meshgrid(*axes, indexing="ij")
        sets.append(np.stack([m.ravel() for m in mesh], axis=-1))
    return np.concatenate(sets)


def verify(
    truth: ErrorSource,
    compensations: Mapping[str, tuple[str, Compensation]],
    request: VerifyRequest | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
) -> VerificationResult:
    """Residual error of ``truth`` under each compensation.

    Parameters
    ----------
    truth : ErrorSource
        The machine the compensation is applied to (the virtual machine).
    compensations : mapping name -> (description, compensation)
        Each turns nominal positions into commands (``command_mm(nominal, approach)``).
    request : VerifyRequest, optional
        Grid spacing, tool offset, extent.
    """
    request = request or VerifyRequest()
    machine = truth.machine
    tool = tuple(float(v) for v in (request.tool_offset_mm or machine.tool_offset_mm))
    extents = table_extents(truth, request.range_mm)
    points = verification_points(extents, request.grid_spacing_mm)
    probe = points[:: max(1, len(points) // 200)]
    gap = truth.error_um(probe, np.ones(3), tool) - truth.error_um(probe, -np.ones(3), tool)
    has_reversal = bool(np.max(np.abs(gap)) > 1e-9)
    approaches = (1, -1) if has_reversal else (1,)
    lines = _axis_lines(machine.reference_mm, extents, request.grid_spacing_mm)

    def residuals(compensation: Compensation | None, nominal: FloatArray, sign: int) -> FloatArray:
        approach = np.full((len(nominal), 3), float(sign))
        command = nominal if compensation is None else compensation.command_mm(nominal, approach)
        return (command - nominal) * UM_PER_MM + truth.error_um(command, approach, tool)

    before = np.concatenate([residuals(None, points, s) for s in approaches])
    before_lines = {
        axis: {s: residuals(None, pts, s)[:, AXIS_INDEX[axis]] for s in (1, -1)}
        for axis, pts in lines.items()
    }
    results: dict[str, MethodResult] = {}
    for step, (name, (description, compensation)) in enumerate(compensations.items()):
        check(cancel)
        report(progress, step / max(1, len(compensations)), f"verifying {name}")
        after = np.concatenate([residuals(compensation, points, s) for s in approaches])
        iso = {}
        for axis, pts in lines.items():
            k = AXIS_INDEX[axis]
            after_line = {s: residuals(compensation, pts, s)[:, k] for s in (1, -1)}
            iso[axis] = {
                "before": positioning_figures(before_lines[axis][1], before_lines[axis][-1]),
                "after": positioning_figures(after_line[1], after_line[-1]),
            }
        results[name] = MethodResult(name, description, compensation_rates(before, after), iso)
    report(progress, 1.0, "verification done")
    return VerificationResult(
        methods=results,
        grid_spacing_mm=float(request.grid_spacing_mm),
        points=len(points),
        approaches=approaches,
        tool_offset_mm=(tool[0], tool[1], tool[2]),
    )


def _axis_lines(
    reference: tuple[float, float, float] | None,
    extents: Mapping[str, tuple[float, float]],
    spacing_mm: float,
) -> dict[str, FloatArray]:
    assert reference is not None
    lines = {}
    for axis in AXES:
        nodes = even_nodes(*extents[axis], spacing_mm)
        points = np.tile(np.asarray(reference, dtype=float), (len(nodes), 1))
        points[:, AXIS_INDEX[axis]] = nodes
        lines[axis] = points
    return lines


def standard_compensations(
    identified: ErrorSource, tables: CompensationTables
) -> dict[str, tuple[str, Compensation]]:
    """The methods volucal reports, computed from the identified source and its tables.

    - ``volumetric_grid``: the grid with trilinear interpolation (direction free: it leaves
      reversal);
    - ``volumetric_grid_and_reversal`` (only where there is reversal): the grid plus per-axis
      reversal tables, each direction's table minus the mean of both;
    - ``nc_rewriting``: the exact inverse at each target point, with the approach direction
      known from the program (it corrects reversal too);
    - ``axis_tables``: each axis' own positioning table (bidirectional where there is reversal),
      linear interpolation, end values held;
    - ``axis_and_cross_tables``: plus the cross-axis tables (straightness, squareness along the
      axis lines, sag); what is left is the non-additive part (angles times other axes' lever
      arms).
    """
    out: dict[str, tuple[str, Compensation]] = {}
    if tables.grid is not None:
        grid = GridCompensation(tables.grid)
        out["volumetric_grid"] = (
            f"volumetric grid, {tables.grid.spacing_mm:g} mm, trilinear interpolation",
            grid,
        )
        if any(t.bidirectional for t in tables.axis.values()):
            out["volumetric_grid_and_reversal"] = (
                "volumetric grid plus bidirectional reversal tables (forward/backward minus "
                "their mean)",
                SumCompensation(grid, reversal_compensation(tables)),
            )
    out["nc_rewriting"] = (
        "NC program rewriting: exact inverse at every target point",
        ExactCompensation(identified, tables.tool_offset_mm),
    )
    out["axis_tables"] = (
        "per-axis positioning tables only, linear interpolation, end values held",
        axis_compensation(tables, include_cross=False),
    )
    out["axis_and_cross_tables"] = (
        "per-axis plus cross-axis tables, linear interpolation, end values held",
        axis_compensation(tables, include_cross=True),
    )
    return out
