"""Identification of the planar errors from 2-D grid measurements.

Model of a reading of grid g at the commanded position (x, y), in volucal's ISO 230-1 ids and
signs (DESIGN.md "Conventions"; µm, µrad, mm; 1e-3 turns µrad·mm into µm)::

    X readings:  EXX(x) + EXY(y) − 1e-3·y·EC0Y  [− 1e-3·y·ECX(x)]  + Sx(x, y)  + ox_g − 1e-3·θ_g·y
    Y readings:  EYX(x) + EYY(y)                 [+ 1e-3·x·ECY(y)]  + Sy(x, y)  + oy_g + 1e-3·θ_g·x

- EXX, EYY: positioning of X and Y; EYX: straightness of X in Y; EXY: straightness of Y in X;
  EC0Y: squareness of Y to X. All are seen at the measured point (at its height and optics
  offset: pitch and yaw times those offsets are part of them).
- The yaw of the upper axis (the one mounted on the other) turns the lower axis' travel, so it
  shows with the lower axis' position as lever arm: ``ECY(y)·x`` when Y is the upper axis (chain
  W-Y-X…), ``−ECX(x)·y`` when X is. A grid identifies it; lines cut from the grid cannot.
- Sx, Sy: the cross-axis surface, what the map holds beyond the rigid-body terms (sag, twist,
  the mirror's or plate's unflatness, local defects): node values on the measured lattice,
  interpolated bilinearly, fitted to what the rigid-body terms leave (zero mean over the readings).
- Gauges of grid g (one set-up): the zero of each direction ox_g, oy_g and one rotation θ_g of
  the reference (mirror or plate). Every error function is zero at the reference position (the
  lattice's first node unless given); straightness functions have zero least-squares slope over
  their stroke, so EC0Y carries the angle between the axes at the reference, as everywhere in
  volucal. The rotation gauge leaves squareness observable: a turned reference adds −θ·y to X and
  +θ·x to Y, a squareness error only −EC0Y·y to X.

Fitting, in three steps:

1. The rigid-body terms as node tables, one value per lattice line, by least squares with the
   gauges (:mod:`volucal.core.grid2d_system`): each node value is what its line's readings say.
   What no function of one coordinate can hold is left to the surface, which therefore never
   holds a line's offset.
2. The surface fitted to what the node tables leave, its smoothing chosen by K-fold
   cross-validation over held-out points (:mod:`volucal.core.grid2d_cv`).
3. Each error function between its nodes: a smooth part (node table or cubic P-spline) plus the
   departures of its measured nodes from it, carried part-way to the next node
   (:mod:`volucal.core.grid2d_departures`). Degree, smoothing and carry are chosen by K-fold
   cross-validation over held-out lattice lines (columns for functions of x, rows for functions
   of y), which is what predicting the error between measured nodes asks of the model.

At the measured nodes the model is the node tables plus the surface, so it reproduces the
measured map; between them it is the cross-validated prediction. Standard uncertainties of the
node values come from the scatter of the readings about the rigid-body terms (taken as
independent; neighbouring readings are correlated, so they are a lower bound).
"""

from __future__ import annotations

import ctypes
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .errors import ErrorFunction, NodeTableBasis
from .grid2d import GRID_AXES, GridGauge, GridMeasurement, Lattice, common_lattice, rms
from .grid2d_cv import CrossValidation, FunctionChoice
from .grid2d_departures import NodeDepartureBasis, fit_smooth_part, smooth_basis
from .grid2d_model import GridIdentification
from .grid2d_surface import SurfaceSolver
from .grid2d_system import (
    TERMS,
    YAW,
    Readings,
    Term,
    build_system,
    solve,
    stack_readings,
)
from .userror import UserError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Smoothing weights of an error function's smooth part tried by cross-validation (relative to
#: one node value; a node value holds a whole line's readings), from nearly through the node
#: values to nearly a straight line (cubic) or a constant (node table).
SMOOTHING = tuple(10.0**k for k in range(-2, 6))
SURFACE_SMOOTHING = tuple(10.0**k for k in range(-3, 4))
DEGREES = (1, 3)


@dataclass(frozen=True)
class GridFitRequest:
    """How to identify the planar errors of one or more grids (one set of gauges per grid).

    upper_axis : "auto" (from the grids), "X", "Y" or None (no yaw lever-arm term).
    reference_mm : (x, y) where every error function is zero; the lattice's first node.
    surface : fit the cross-axis surface (the 2-D map beyond the rigid-body terms).
    folds : K of the K-fold cross-validations.
    degrees, smoothing : the candidates cross-validation chooses from for the smooth part of
        each error function (module notes, step 3); surface_smoothing: those for the
        cross-axis surface.
    sweeps : passes over the functions of one coordinate when choosing them.
    significance : how many standard errors of its cross-validated gain a function's smooth
        part and carry must beat the linear interpolation of its node values by (the lookup
        table a controller makes of them) to be chosen; 0 takes the least cross-validated
        error.
    """

    upper_axis: str | None = "auto"
    reference_mm: tuple[float, float] | None = None
    surface: bool = True
    folds: int = 5
    degrees: tuple[int, ...] = DEGREES
    smoothing: tuple[float, ...] = SMOOTHING
    surface_smoothing: tuple[float, ...] = SURFACE_SMOOTHING
    sweeps: int = 2
    significance: float = 1.0

    def __post_init__(self) -> None:
        if self.upper_axis not in ("auto", "X", "Y", None):
            raise UserError(f"upper axis must be X, Y, none or auto, got {self.upper_axis!r}")
        if self.folds < 2:
            raise UserError(f"cross-validation needs at least 2 folds, got {self.folds}")
        if not self.degrees or any(d not in (1, 3) for d in self.degrees):
            raise UserError("basis degrees must be 1 (node table) or 3 (cubic B-spline)")
        if not self.smoothing or any(not s > 0 for s in self.smoothing + self.surface_smoothing):
            raise UserError("smoothing weights must be positive")
        if not self.significance >= 0:
            raise UserError(
                f"significance must be a number of standard errors >= 0, got {self.significance}"
            )


def _upper_axis(grids: Sequence[GridMeasurement], request: GridFitRequest) -> str | None:
    if request.upper_axis != "auto":
        return request.upper_axis
    stated = {g.upper_axis for g in grids}
    if len(stated) > 1:
        raise UserError(
            "the grids disagree on which axis is the upper one "
            f"({', '.join(sorted(str(s) for s in stated))}); give it"
        )
    return stated.pop()


@contextmanager
def _one_blas_thread() -> Iterator[None]:
    """Run the enclosed linear algebra on one BLAS thread (this thread only).

    The identification solves thousands of systems of a few hundred unknowns; OpenBLAS gains
    nothing from threads at that size and, on a busy machine, loses up to 20× to them. OpenBLAS'
    ``openblas_set_num_threads_local`` sets the count for the calling thread and returns the old
    one; where the library or the symbol is absent this does nothing.
    """
    setters = []
    for library in _openblas_libraries():
        function = getattr(library, "openblas_set_num_threads_local", None)
        if function is not None:
            function.argtypes = [ctypes.c_int]
            function.restype = ctypes.c_int
            setters.append((function, function(1)))
    try:
        yield
    finally:
        for function, previous in setters:
            function(previous)


def _openblas_libraries() -> list[ctypes.CDLL]:
    libraries = []
    try:
        with open("/proc/self/maps", encoding="ascii", errors="replace") as maps:
            paths = {
                line.split()[-1]
                for line in maps
                if "openblas" in line.lower() and ".so" in line.split()[-1]
            }
    except OSError:
        return []
    for path in sorted(paths):
        try:
            libraries.append(ctypes.CDLL(path))
        except OSError:
            continue
    return libraries


def identify_grid(
    grids: GridMeasurement | Sequence[GridMeasurement],
    request: GridFitRequest | None = None,
) -> GridIdentification:
    """Identify the planar errors (module notes) from one grid or several overlapping grids.

    Several grids (zones of a stitched calibration) are fitted together: they share the
    machine's errors and each keeps its own gauge terms, so their overlaps tie them together
    (least-squares stitching).

    Raises
    ------
    UserError
        For grids off a common lattice, with fewer than two nodes along an axis, or that do not
        separate the terms.
    """
    with _one_blas_thread():
        return _identify(grids, request or GridFitRequest())


def _identify(
    grids: GridMeasurement | Sequence[GridMeasurement], request: GridFitRequest
) -> GridIdentification:
    grid_list = [grids] if isinstance(grids, GridMeasurement) else list(grids)
    names = [g.name for g in grid_list]
    if len(set(names)) != len(names):
        raise UserError(f"two grids are named alike ({', '.join(names)}): give them distinct names")
    lattice = common_lattice(grid_list)
    reference = request.reference_mm or (float(lattice.x_mm[0]), float(lattice.y_mm[0]))
    nodes = (lattice.x_mm, lattice.y_mm)
    for k, name in enumerate(GRID_AXES):
        if not nodes[k][0] - 1e-9 <= reference[k] <= nodes[k][-1] + 1e-9:
            raise UserError(
                f"the reference {name} = {reference[k]:g} mm lies outside the grid "
                f"({nodes[k][0]:g} to {nodes[k][-1]:g} mm)"
            )
    readings = stack_readings(grid_list, lattice)
    directions = sorted({int(d) for d in np.unique(readings.direction)})
    upper = _upper_axis(grid_list, request)
    terms = [t for t in TERMS if t.direction in directions]
    if upper is not None and YAW[upper].direction in directions:
        terms.append(YAW[upper])
    square = directions == [0, 1]
    system = build_system(
        readings, lattice, terms, reference, len(grid_list), set(directions), square
    )
    solver = SurfaceSolver(lattice)
    cv = CrossValidation(readings, system, solver, nodes, reference, request.folds, directions)

    # 1. node tables and gauges
    normal, rhs = system.gram(readings.value)
    reduced = solve(normal + system.penalty, rhs)
    rigid_residual = readings.value - system.reduced_design @ reduced
    inverse = np.linalg.inv(normal + system.penalty)
    edf = float(np.trace(inverse @ normal))
    sigma = float(np.sqrt(np.sum(rigid_residual**2) / max(readings.value.size - edf, 1.0)))
    covariance = sigma**2 * inverse @ normal @ inverse
    slices = system.block_slices()
    scalars = dict(zip(system.scalar_names, reduced[slices[-1]], strict=True))
    scalar_std = dict(
        zip(
            system.scalar_names,
            np.sqrt(np.maximum(np.diag(covariance[slices[-1], slices[-1]]), 0)),
            strict=True,
        )
    )

    # 2. the surface on what they leave
    weights = cv.choose_surface(request.surface_smoothing) if request.surface else None
    residual = rigid_residual
    surface = None
    if weights is not None:
        surface = np.zeros((2,) + lattice.shape)
        for k in directions:
            rows = readings.direction == k
            surface[k] = solver.as_grid(solver.fit(cv.node[rows], rigid_residual[rows], weights[k]))
        on_node = np.where(
            readings.direction == 0,
            surface[0][readings.iy, readings.ix],
            surface[1][readings.iy, readings.ix],
        )
        residual = rigid_residual - on_node

    # 3. each function between its nodes
    choices = cv.choose_functions(
        terms, request.degrees, request.smoothing, weights, request.sweeps, request.significance
    )
    functions: dict[str, ErrorFunction] = {}
    function_std: dict[str, FloatArray] = {}
    for index, term in enumerate(terms):
        values = system.node_values(reduced, index)
        functions[term.id] = _function(
            term,
            choices[term.id],
            nodes[term.argument],
            values,
            _measured(readings, term, nodes[term.argument].size),
            reference[term.argument],
        )
        null = system.transforms[index]
        block = slices[index]
        function_std[term.id] = np.sqrt(
            np.maximum(np.einsum("ij,jk,ik->i", null, covariance[block, block], null), 0.0)
        )

    gauges = {
        grid.name: GridGauge(
            offset_x_um=float(scalars.get(f"offset_x:{g}", 0.0)),
            offset_y_um=float(scalars.get(f"offset_y:{g}", 0.0)),
            rotation_urad=float(scalars[f"rotation:{g}"]),
        )
        for g, grid in enumerate(grid_list)
    }
    measured = np.zeros(lattice.shape, dtype=bool)
    measured[readings.iy, readings.ix] = True

    def by_direction(values: FloatArray, rows: NDArray[np.bool_] | None = None) -> dict[str, float]:
        mask = np.ones(values.size, dtype=bool) if rows is None else rows
        return {GRID_AXES[k]: rms(values[mask & (readings.direction == k)]) for k in directions}

    between: dict[str, object] = {}
    for line_axis, label in ((1, "rows"), (0, "columns")):
        if any(t.argument == line_axis for t in terms):
            ours, held = cv.line_errors(terms, choices, weights, line_axis)
            if not held.any():
                continue
            table = {t.id: FunctionChoice(1, min(request.smoothing), 1.0) for t in terms}
            lookup, _ = cv.line_errors(terms, table, weights, line_axis)
            between[label] = {
                "model": by_direction(ours, held),
                "node_values_interpolated": by_direction(lookup, held),
            }
    statistics = {
        "readings": int(readings.value.size),
        "grids": len(grid_list),
        "rms_um": {
            "rigid_body": by_direction(rigid_residual),
            "with_surface": by_direction(residual),
        },
        "cv_rms_um": {
            **by_direction(cv.surface_errors(weights, cv.point_folds)),
            "method": f"{request.folds}-fold cross-validation over held-out points "
            "spread over the grid (the whole model refitted without them)",
        },
        "cv_between_lines_rms_um": {
            **between,
            "method": f"{request.folds}-fold cross-validation over held-out lattice lines "
            "(rows, columns; the whole model refitted without them): the model's "
            "prediction halfway between measured lines, and the linear "
            "interpolation of the node values (a lookup table) for comparison",
        },
        "sigma_um": sigma,
        "effective_parameters": edf,
        "uncertainty": "standard uncertainties of the node values from the scatter of the "
        "readings about the rigid-body terms, readings taken as independent",
    }
    choice_table: dict[str, dict[str, float]] = {
        eid: {"degree": c.degree, "smoothing": c.smoothing, "carry": c.carry}
        for eid, c in choices.items()
    }
    if weights is not None:
        choice_table["surface"] = {
            f"smoothing_{GRID_AXES[k].lower()}": weights[k] for k in directions
        }
    return GridIdentification(
        lattice=lattice,
        reference_mm=(float(reference[0]), float(reference[1])),
        upper_axis=upper if any(t.id in ("ECX", "ECY") for t in terms) else None,
        functions=functions,
        function_std=function_std,
        squareness_urad=float(scalars["EC0Y"]) if square else None,
        squareness_std_urad=float(scalar_std["EC0Y"]) if square else None,
        gauges=gauges,
        surface_um=surface,
        measured_nodes=measured,
        choices=choice_table,
        statistics=statistics,
        residual_um=_per_grid(grid_list, readings, residual),
    )


def _measured(readings: Readings, term: Term, size: int) -> NDArray[np.bool_]:
    """The lattice nodes along ``term``'s argument with a reading in its direction."""
    seen = np.zeros(size, dtype=bool)
    seen[readings.node(term)[readings.direction == term.direction]] = True
    return seen


def _function(
    term: Term,
    choice: FunctionChoice,
    nodes: FloatArray,
    values: FloatArray,
    measured: NDArray[np.bool_],
    reference: float,
) -> ErrorFunction:
    """The error function: its smooth part plus its measured nodes' departures (step 3).

    The function is its node values at the measured nodes. A reference between lattice nodes
    is one more node, where the node table is zero by the gauge, so the function stays zero
    there too.
    """
    basis = smooth_basis(nodes, choice.degree)
    coefficients = fit_smooth_part(basis, nodes[measured], values[measured], choice.smoothing)
    at = nodes[measured]
    value = values[measured]
    if np.min(np.abs(nodes - reference)) > 1e-9:
        order = np.searchsorted(at, reference)
        at = np.insert(at, order, reference)
        value = np.insert(
            value, order, float(NodeTableBasis(tuple(nodes)).evaluate(reference, values))
        )
    departures = value - basis.design(at) @ coefficients
    return ErrorFunction(
        term.id,
        NodeDepartureBasis(basis, tuple(at), choice.carry),
        np.concatenate([coefficients, departures]),
    )


def _per_grid(
    grid_list: Sequence[GridMeasurement], readings: Readings, residual: FloatArray
) -> dict[str, FloatArray]:
    out = {}
    for g, grid in enumerate(grid_list):
        table = np.full((grid.count, 2), np.nan)
        for k in range(2):
            rows = np.flatnonzero((readings.grid == g) & (readings.direction == k))
            table[np.flatnonzero(np.isfinite(grid.deviation_um[:, k])), k] = residual[rows]
        out[grid.name] = table
    return out


def sample_positions(lattice: Lattice) -> FloatArray:
    """Every lattice node as (n, 2) positions, rows of Y then columns of X."""
    xx, yy = np.meshgrid(lattice.x_mm, lattice.y_mm)
    return np.stack([xx.ravel(), yy.ravel()], axis=1)
