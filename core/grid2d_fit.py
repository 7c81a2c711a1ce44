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

Each error function is a degree-1 (node table) or cubic B-spline on the lattice nodes with a
difference penalty (P-splines, Eilers & Marx 1996); its degree and smoothing are chosen by K-fold
cross-validation over what the function interpolates: held-out lattice columns for functions of
x, held-out rows for functions of y. The surface's smoothing is chosen over held-out points.
Standard uncertainties come from the scatter of the readings about the rigid-body terms (taken as
independent; neighbouring readings are correlated, so they are a lower bound).
"""

from __future__ import annotations

import ctypes
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sparse
from numpy.typing import NDArray
from scipy.linalg import LinAlgError, cho_factor, cho_solve

from .errors import Basis, BSplineBasis, ErrorFunction, NodeTableBasis, gauge_null_space
from .grid2d import (
    GRID_AXES,
    UM_PER_MM_URAD,
    GridGauge,
    GridMeasurement,
    Lattice,
    common_lattice,
    rms,
)
from .grid2d_model import GridIdentification
from .grid2d_surface import SurfaceSolver
from .userror import UserError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Smoothing weights tried by cross-validation (per reading, relative to the data term).
SMOOTHING = tuple(10.0**k for k in range(-3, 1))
SURFACE_SMOOTHING = tuple(10.0**k for k in range(-3, 4))
DEGREES = (1, 3)


@dataclass(frozen=True)
class GridFitRequest:
    """How to identify the planar errors of one or more grids (one set of gauges per grid).

    upper_axis : "auto" (from the grids), "X", "Y" or None (no yaw lever-arm term).
    reference_mm : (x, y) where every error function is zero; the lattice's first node.
    surface : fit the cross-axis surface (the 2-D map beyond the rigid-body terms).
    folds : K of the K-fold cross-validation.
    degrees, smoothing : the candidates cross-validation chooses from for the error functions
        (smoothing weights up to 1: stronger smoothing biases a function more than its stated
        uncertainty says); surface_smoothing: those for the cross-axis surface.
    sweeps : passes over the error functions when choosing their smoothing.
    """

    upper_axis: str | None = "auto"
    reference_mm: tuple[float, float] | None = None
    surface: bool = True
    folds: int = 5
    degrees: tuple[int, ...] = DEGREES
    smoothing: tuple[float, ...] = SMOOTHING
    surface_smoothing: tuple[float, ...] = SURFACE_SMOOTHING
    sweeps: int = 2

    def __post_init__(self) -> None:
        if self.upper_axis not in ("auto", "X", "Y", None):
            raise UserError(f"upper axis must be X, Y, none or auto, got {self.upper_axis!r}")
        if self.folds < 2:
            raise UserError(f"cross-validation needs at least 2 folds, got {self.folds}")
        if not self.degrees or any(d not in (1, 3) for d in self.degrees):
            raise UserError("basis degrees must be 1 (node table) or 3 (cubic B-spline)")
        if not self.smoothing or any(not s > 0 for s in self.smoothing + self.surface_smoothing):
            raise UserError("smoothing weights must be positive")


@dataclass(frozen=True)
class _Term:
    """One error function: which coordinate it is a function of, which readings it enters and
    the lever arm that multiplies it there."""

    id: str
    argument: int  # 0: function of x, 1: function of y
    direction: int  # 0: enters the X readings, 1: the Y readings
    lever: str  # "", "x" (1e-3·x) or "-y" (−1e-3·y)
    straightness: bool


_TERMS = (
    _Term("EXX", 0, 0, "", False),
    _Term("EXY", 1, 0, "", True),
    _Term("EYX", 0, 1, "", True),
    _Term("EYY", 1, 1, "", False),
)
_YAW = {"Y": _Term("ECY", 1, 1, "x", False), "X": _Term("ECX", 0, 0, "-y", False)}


@dataclass
class _Readings:
    position: FloatArray  # (m, 2)
    value: FloatArray  # (m,)
    direction: IntArray  # (m,)
    grid: IntArray  # (m,)
    ix: IntArray
    iy: IntArray


def _readings(grids: Sequence[GridMeasurement], lattice: Lattice) -> _Readings:
    parts = []
    for g, grid in enumerate(grids):
        ix, iy = lattice.index(grid.position_mm)
        for k in range(2):
            ok = np.isfinite(grid.deviation_um[:, k])
            parts.append((grid.position_mm[ok], grid.deviation_um[ok, k], np.full(ok.sum(), k),
                          np.full(ok.sum(), g), ix[ok], iy[ok]))
    stacked = [np.concatenate([p[i] for p in parts]) for i in range(6)]
    return _Readings(stacked[0], stacked[1], stacked[2].astype(np.int64),
                     stacked[3].astype(np.int64), stacked[4].astype(np.int64),
                     stacked[5].astype(np.int64))


def _basis(nodes: FloatArray, degree: int) -> Basis:
    return NodeTableBasis(tuple(nodes)) if degree == 1 else BSplineBasis(tuple(nodes))


def _difference(size: int, degree: int) -> FloatArray:
    order = 1 if degree == 1 else 2
    return np.diff(np.eye(size), order, axis=0) if size > order else np.zeros((0, size))


class _Problem:
    """The linear system of the rigid-body model for one choice of bases."""

    def __init__(self, readings: _Readings, lattice: Lattice, terms: Sequence[_Term],
                 reference: tuple[float, float], grid_count: int, directions: set[int],
                 square: bool) -> None:
        self.readings = readings
        self.lattice = lattice
        self.terms = list(terms)
        self.reference = reference
        self.grid_count = grid_count
        self.directions = directions
        self.square = square
        self.nodes = (lattice.x_mm, lattice.y_mm)

    def build(self, degrees: dict[str, int]) -> _System:
        r = self.readings
        m = r.value.size
        blocks: list[sparse.csr_matrix] = []
        transforms: list[FloatArray] = []
        penalties: list[FloatArray] = []
        bases: dict[str, Basis] = {}
        for term in self.terms:
            basis = _basis(self.nodes[term.argument], degrees[term.id])
            bases[term.id] = basis
            rows = np.flatnonzero(r.direction == term.direction)
            design = basis.design(r.position[rows, term.argument])
            if term.lever == "x":
                design = design * (UM_PER_MM_URAD * r.position[rows, 0])[:, None]
            elif term.lever == "-y":
                design = design * (-UM_PER_MM_URAD * r.position[rows, 1])[:, None]
            block = np.zeros((m, basis.size))
            block[rows] = design
            blocks.append(sparse.csr_matrix(block))
            null = gauge_null_space(basis, self.reference[term.argument], term.straightness)
            transforms.append(null)
            difference = _difference(basis.size, degrees[term.id])
            penalties.append(null.T @ difference.T @ difference @ null)
        extra = []
        names = []
        x, y = r.position[:, 0], r.position[:, 1]
        if self.square:
            extra.append(np.where(r.direction == 0, -UM_PER_MM_URAD * y, 0.0))
            names.append("EC0Y")
        for g in range(self.grid_count):
            mine = r.grid == g
            if 0 in self.directions:
                extra.append(np.where(mine & (r.direction == 0), 1.0, 0.0))
                names.append(f"offset_x:{g}")
            if 1 in self.directions:
                extra.append(np.where(mine & (r.direction == 1), 1.0, 0.0))
                names.append(f"offset_y:{g}")
            extra.append(np.where(mine, np.where(r.direction == 0, -y, x) * UM_PER_MM_URAD, 0.0))
            names.append(f"rotation:{g}")
        blocks.append(sparse.csr_matrix(np.stack(extra, axis=1)))
        transforms.append(np.eye(len(extra)))
        penalties.append(np.zeros((len(extra), len(extra))))
        return _System(sparse.hstack(blocks).tocsr(), transforms, penalties, bases, names,
                       self.terms)


@dataclass
class _System:
    design: sparse.csr_matrix  # readings × original coefficients
    transforms: list[FloatArray]  # gauge null spaces per block (identity for the scalars)
    penalties: list[FloatArray]  # per block, in reduced coordinates, without λ
    bases: dict[str, Basis]
    scalar_names: list[str]
    terms: list[_Term]
    _fold_cache: dict[int, tuple[IntArray, list[tuple[FloatArray, FloatArray]]]] = field(
        default_factory=dict)

    @cached_property
    def transform(self) -> FloatArray:
        size_in = sum(t.shape[0] for t in self.transforms)
        size_out = sum(t.shape[1] for t in self.transforms)
        out = np.zeros((size_in, size_out))
        i = j = 0
        for t in self.transforms:
            out[i:i + t.shape[0], j:j + t.shape[1]] = t
            i += t.shape[0]
            j += t.shape[1]
        return out

    def penalty(self, smoothing: dict[str, float]) -> FloatArray:
        weights = [smoothing[t.id] for t in self.terms] + [0.0]
        size = sum(p.shape[0] for p in self.penalties)
        out = np.zeros((size, size))
        i = 0
        for p, w in zip(self.penalties, weights, strict=True):
            out[i:i + p.shape[0], i:i + p.shape[0]] = w * p
            i += p.shape[0]
        return out

    def gram(self, rows: NDArray[np.bool_] | None, values: FloatArray) -> tuple[FloatArray,
                                                                                  FloatArray]:
        """Reduced normal matrix and right-hand side of the given readings."""
        design = self.design if rows is None else self.design[rows]
        data = values if rows is None else values[rows]
        t = self.transform
        g = (design.T @ design).toarray()
        return t.T @ g @ t, t.T @ (design.T @ data)

    @cached_property
    def reduced_design(self) -> sparse.csr_matrix:
        """The design in the gauge-reduced coordinates."""
        return (self.design @ sparse.csr_matrix(self.transform)).tocsr()

    def fold_grams(self, folds: IntArray, count: int,
                   values: FloatArray) -> list[tuple[FloatArray, FloatArray]]:
        """Reduced normal matrix and right-hand side without each fold (cached per folds)."""
        key = id(folds)
        cached = self._fold_cache.get(key)
        if cached is None or cached[0] is not folds:
            t = self.transform
            total = (self.design.T @ self.design).toarray()
            total_rhs = self.design.T @ values
            grams = []
            for f in range(count):
                rows = self.design[folds == f]
                inner = (rows.T @ rows).toarray()
                grams.append((t.T @ (total - inner) @ t,
                              t.T @ (total_rhs - rows.T @ values[folds == f])))
            cached = (folds, grams)
            self._fold_cache[key] = cached
        return cached[1]

    def block_slices(self) -> list[slice]:
        out, start = [], 0
        for t in self.transforms:
            out.append(slice(start, start + t.shape[1]))
            start += t.shape[1]
        return out


def _solve(normal: FloatArray, rhs: FloatArray) -> FloatArray:
    scale = np.sqrt(np.maximum(np.diag(normal), 1e-300))
    scaled = normal / scale[:, None] / scale[None, :]
    try:
        factor = cho_factor(scaled + 1e-12 * np.eye(scaled.shape[0]))
    except LinAlgError:
        raise UserError(
            "the grid cannot separate the planar errors (a singular system): it needs at least "
            "two nodes along each axis in each measured direction"
        ) from None
    return np.asarray(cho_solve(factor, rhs / scale) / scale)


# --------------------------------------------------------------------------------------------
# Identification
# --------------------------------------------------------------------------------------------


def _upper_axis(grids: Sequence[GridMeasurement], request: GridFitRequest) -> str | None:
    if request.upper_axis != "auto":
        return request.upper_axis
    stated = {g.upper_axis for g in grids}
    if len(stated) > 1:
        raise UserError("the grids disagree on which axis is the upper one "
                        f"({', '.join(sorted(str(s) for s in stated))}); give it")
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
            paths = {line.split()[-1] for line in maps
                     if "openblas" in line.lower() and ".so" in line.split()[-1]}
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


def _identify(grids: GridMeasurement | Sequence[GridMeasurement],
              request: GridFitRequest) -> GridIdentification:
    grid_list = [grids] if isinstance(grids, GridMeasurement) else list(grids)
    names = [g.name for g in grid_list]
    if len(set(names)) != len(names):
        raise UserError(f"two grids are named alike ({', '.join(names)}): give them distinct "
                        "names")
    lattice = common_lattice(grid_list)
    reference = request.reference_mm or (float(lattice.x_mm[0]), float(lattice.y_mm[0]))
    for k, axis in enumerate(GRID_AXES):
        nodes = lattice.x_mm if k == 0 else lattice.y_mm
        if not nodes[0] - 1e-9 <= reference[k] <= nodes[-1] + 1e-9:
            raise UserError(f"the reference {axis} = {reference[k]:g} mm lies outside the grid "
                            f"({nodes[0]:g} to {nodes[-1]:g} mm)")
    readings = _readings(grid_list, lattice)
    directions = sorted({int(d) for d in np.unique(readings.direction)})
    upper = _upper_axis(grid_list, request)
    terms = [t for t in _TERMS if t.direction in directions]
    if upper is not None and _YAW[upper].direction in directions:
        terms.append(_YAW[upper])
    square = directions == [0, 1]
    problem = _Problem(readings, lattice, terms, reference, len(grid_list), set(directions),
                       square)
    solver = SurfaceSolver(lattice)
    model = _CrossValidation(readings, solver, request, directions)
    degrees, smoothing, surface_weight = model.choose(problem, terms)

    system = problem.build(degrees)
    normal, rhs = system.gram(None, readings.value)
    penalty = system.penalty(smoothing)
    reduced = _solve(normal + penalty, rhs)
    rigid_residual = readings.value - system.reduced_design @ reduced
    inverse = np.linalg.inv(normal + penalty)
    edf = float(np.trace(inverse @ normal))
    sigma = float(np.sqrt(np.sum(rigid_residual**2) / max(readings.value.size - edf, 1.0)))
    covariance = sigma**2 * inverse @ normal @ inverse

    functions: dict[str, ErrorFunction] = {}
    function_std: dict[str, FloatArray] = {}
    slices = system.block_slices()
    for index, term in enumerate(terms):
        null = system.transforms[index]
        basis = system.bases[term.id]
        block = slices[index]
        functions[term.id] = ErrorFunction(term.id, basis, null @ reduced[block])
        sample = basis.design(problem.nodes[term.argument]) @ null
        function_std[term.id] = np.sqrt(np.maximum(
            np.einsum("ij,jk,ik->i", sample, covariance[block, block], sample), 0.0))
    scalars = dict(zip(system.scalar_names, reduced[slices[-1]], strict=True))
    scalar_std = dict(zip(system.scalar_names,
                          np.sqrt(np.maximum(np.diag(covariance[slices[-1], slices[-1]]), 0)),
                          strict=True))

    residual = rigid_residual
    surface = None
    if request.surface:
        surface = np.zeros((2,) + lattice.shape)
        for k in directions:
            rows = readings.direction == k
            surface[k] = solver.as_grid(solver.fit(model.node[rows], rigid_residual[rows],
                                                   surface_weight[k]))
        on_node = np.where(readings.direction == 0, surface[0][readings.iy, readings.ix],
                           surface[1][readings.iy, readings.ix])
        residual = rigid_residual - on_node

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

    def by_direction(values: FloatArray) -> dict[str, float]:
        return {GRID_AXES[k]: rms(values[readings.direction == k]) for k in directions}

    cv_points = model.score(system, smoothing, surface_weight if request.surface else None,
                            model.point_folds)
    statistics = {
        "readings": int(readings.value.size),
        "grids": len(grid_list),
        "rms_um": {"rigid_body": by_direction(rigid_residual),
                   "with_surface": by_direction(residual)},
        "cv_rms_um": {**by_direction(cv_points),
                      "method": f"{request.folds}-fold cross-validation over held-out points "
                                "spread over the grid (the whole model refitted without them)"},
        "sigma_um": sigma,
        "effective_parameters": edf,
        "uncertainty": "standard uncertainties from the scatter of the readings about the "
                       "rigid-body terms, readings taken as independent",
    }
    choices: dict[str, dict[str, float]] = {
        eid: {"degree": degrees[eid], "smoothing": smoothing[eid]} for eid in degrees}
    if request.surface:
        choices["surface"] = {f"smoothing_{GRID_AXES[k].lower()}": surface_weight[k]
                              for k in directions}
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
        choices=choices,
        statistics=statistics,
        residual_um=_per_grid(grid_list, readings, residual),
    )


def _per_grid(grid_list: Sequence[GridMeasurement], readings: _Readings,
              residual: FloatArray) -> dict[str, FloatArray]:
    out = {}
    for g, grid in enumerate(grid_list):
        table = np.full((grid.count, 2), np.nan)
        for k in range(2):
            rows = np.flatnonzero((readings.grid == g) & (readings.direction == k))
            table[np.flatnonzero(np.isfinite(grid.deviation_um[:, k])), k] = residual[rows]
        out[grid.name] = table
    return out


class _CrossValidation:
    """K-fold cross-validation of the whole model (rigid-body terms and surface).

    A candidate is scored by refitting everything without the held-out readings and predicting
    them: held-out lattice columns for a function of x, rows for a function of y, points
    spread over the grid for the surface.
    """

    def __init__(self, readings: _Readings, solver: SurfaceSolver, request: GridFitRequest,
                 directions: list[int]) -> None:
        self.readings = readings
        self.solver = solver
        self.request = request
        self.directions = directions
        self.node = solver.node(readings.ix, readings.iy)
        k = request.folds
        self.line_folds = {0: readings.ix % k, 1: readings.iy % k}
        self.point_folds = (readings.ix + 2 * readings.iy) % k

    def choose(self, problem: _Problem, terms: list[_Term]
               ) -> tuple[dict[str, int], dict[str, float], dict[int, float]]:
        request = self.request
        degrees = {t.id: max(request.degrees) for t in terms}
        smoothing = {t.id: min(request.smoothing) for t in terms}
        weight = {k: min(request.surface_smoothing) for k in self.directions}
        surface = weight if request.surface else None
        for _ in range(request.sweeps):
            for term in terms:
                best: tuple[float, int, float] | None = None
                for degree in request.degrees:
                    system = problem.build({**degrees, term.id: degree})
                    folds = self.line_folds[term.argument]
                    for candidate in request.smoothing:
                        trial = {**smoothing, term.id: candidate}
                        score = float(np.mean(self.score(system, trial, surface, folds)**2))
                        if best is None or score < best[0]:
                            best = (score, degree, candidate)
                assert best is not None
                degrees[term.id], smoothing[term.id] = best[1], best[2]
            if surface is not None:
                system = problem.build(degrees)
                for k in self.directions:
                    rows = self.readings.direction == k
                    scores = [float(np.mean(self.score(system, smoothing, {**weight, k: w},
                                                       self.point_folds)[rows] ** 2))
                              for w in request.surface_smoothing]
                    weight[k] = request.surface_smoothing[int(np.argmin(scores))]
                surface = weight
        return degrees, smoothing, weight

    def score(self, system: _System, smoothing: dict[str, float],
              surface: dict[int, float] | None, folds: IntArray) -> FloatArray:
        """Prediction error of every reading when its fold is held out."""
        values = self.readings.value
        grams = system.fold_grams(folds, self.request.folds, values)
        penalty = system.penalty(smoothing)
        error = np.zeros_like(values)
        for f, (normal, rhs) in enumerate(grams):
            held = folds == f
            if not held.any():
                continue
            prediction = system.reduced_design @ _solve(normal + penalty, rhs)
            if surface is not None:
                kept = ~held
                for k in self.directions:
                    mine = self.readings.direction == k
                    fit = self.solver.fit(self.node[kept & mine],
                                          (values - prediction)[kept & mine], surface[k],
                                          key=(id(folds), f, k, surface[k]))
                    prediction[held & mine] += fit[self.node[held & mine]]
            error[held] = values[held] - prediction[held]
        return error


def sample_positions(lattice: Lattice) -> FloatArray:
    """Every lattice node as (n, 2) positions, rows of Y then columns of X."""
    xx, yy = np.meshgrid(lattice.x_mm, lattice.y_mm)
    return np.stack([xx.ravel(), yy.ravel()], axis=1)
