"""Identification of the 21 geometric errors from any plan of laser lines.

A line with start P0, direction u and optics offset t reads (REFERENCE §2)

- linear:        m = u · E(P; t) + o_line
- straightness:  m = v · E(P; t) + o_line + s_line · target
- angular:       m = w · θ(P) + o_line

with E the exact volumetric error (kinematics), θ the rotation of the tool relative to the
workpiece, o a free zero offset per line (the laser is zeroed at its first target) and s a free
slope per straightness line (optics alignment). The error functions are linear combinations of
basis functions restricted to the gauge (zero at the reference; straightness with zero
least-squares slope, so that the squareness errors carry the angle between the axes).

The weighted least-squares problem is solved in normal-equation form with the geometric design
evaluated once per target (runs at one target share it), then refined by Gauss–Newton on the exact
chain until the update is far below the noise. Effects beyond the 21 errors (core/effects.py) add
columns per reading. Rank, unidentifiable combinations and redundant lines come from the
eigen-decomposition of the column-scaled normal matrix.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy import sparse
from scipy.linalg import cho_factor, cho_solve, cholesky, solve_triangular

from .errors import (
    AXIS_ERROR_IDS,
    ERROR_IDS,
    ERROR_INFO,
    SQUARENESS_IDS,
    Basis,
    BSplineBasis,
    ErrorModel,
    axis_error_ids,
    gauge_null_space,
)
from .identify_blocks import (
    ConstrainedSystem,
    Elimination,
    LinePart,
    NullSpace,
    largest_eigenvalue,
    largest_leverage,
    line_schur,
)
from .kinematics import VolumetricModel, error_value_jacobian, rotation_error
from .machine import AXES, AXIS_INDEX, Machine
from .measurement import Measurement
from .progress import CancelToken, ProgressCallback, check, report
from .readings import QUANTITY_CODE, Readings, flatten
from .userror import UserError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Eigenvalues of the column-scaled normal matrix below this fraction of the largest are taken as
#: zero: a direction whose singular value is 1e-6 of the strongest is not seen by the plan.
RANK_TOLERANCE = 1e-12


class IdentificationError(UserError):
    """The plan or the data cannot support an identification."""


# --------------------------------------------------------------------------------------------
# Uncertainty budget (ISO 230-9 manner)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class UncertaintyBudget:
    """Standard uncertainties of the measurement set-up, combined with the statistical band.

    Defaults are those of a typical laser set-up (stated in docs/identification.md); the plan's
    ``[uncertainty]`` table overrides them. Each contribution acts on the positioning errors as a
    scale error over the distance from the reference (ISO 230-9, annex on linear positioning).
    """

    laser_ppm: float = 0.5  # laser accuracy, ±0.5 ppm (XL-80 class), rectangular
    air_temp_sensor_c: float = 0.2  # air temperature sensor, ±0.2 °C, rectangular
    material_temp_sensor_c: float = 0.1  # material sensor, ±0.1 °C, rectangular
    expansion_coeff_ppm: float = 1.0  # uncertainty of α, ±1 ppm/°C, rectangular
    material_offset_c: float = 0.5  # typical |T_material − 20 °C| during the session
    dead_path_mm: float = 0.0  # dead path; an air-temperature change acts on it
    air_temp_change_c: float = 0.3  # air temperature change during a line
    cosine_urad: float = 100.0  # beam misalignment angle
    abbe_mm: float = 0.0  # Abbe offset of the optics not accounted for
    straightness_pct: float = 1.0  # straightness optics accuracy, % of the reading

    @classmethod
    def from_mapping(cls, values: Mapping[str, float]) -> UncertaintyBudget:
        unknown = sorted(set(values) - set(cls.__dataclass_fields__))
        if unknown:
            raise IdentificationError(
                f"[uncertainty]: unknown field(s) {', '.join(unknown)}; known: "
                + ", ".join(cls.__dataclass_fields__)
            )
        return cls(**{k: float(v) for k, v in values.items()})

    def scale_ppm(self) -> float:
        """Combined standard uncertainty of a length scale, ppm."""
        rect = 1 / np.sqrt(3)
        refractive_ppm_per_c = 0.93  # air refractive index sensitivity (Edlén), ppm/°C
        parts = [
            self.laser_ppm * rect,
            refractive_ppm_per_c * self.air_temp_sensor_c * rect,
            11.5 * self.material_temp_sensor_c * rect,  # steel expansion on the sensor error
            self.expansion_coeff_ppm * self.material_offset_c * rect,
            0.5 * (self.cosine_urad * 1e-6) ** 2 * 1e6,
        ]
        return float(np.sqrt(np.sum(np.square(parts))))

    def positioning_std_um(self, distance_mm: FloatArray, angle_urad: float = 0.0) -> FloatArray:
        """Standard uncertainty (µm) of a positioning error ``distance_mm`` from the reference."""
        scale = self.scale_ppm() * 1e-6 * np.abs(distance_mm) * 1e3
        dead = 0.93e-6 * self.dead_path_mm * self.air_temp_change_c * 1e3 / np.sqrt(3)
        abbe = self.abbe_mm * angle_urad * 1e-3 / np.sqrt(3)
        return np.asarray(np.sqrt(scale**2 + dead**2 + abbe**2))


# --------------------------------------------------------------------------------------------
# Options and results
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class IdentifyOptions:
    """How to identify.

    basis : per error id, the basis to use (others get B-splines every ``spacing_mm``).
    spacing_mm : breakpoint spacing of the default cubic B-spline basis.
    refine : Gauss–Newton on the exact chain after the linear solve.
    budget : the uncertainty budget.
    redundancy : compute which lines are redundant (one rank test per line).
    """

    basis: Mapping[str, Basis] = field(default_factory=dict)
    spacing_mm: float = 50.0
    refine: bool = True
    max_iterations: int = 6
    budget: UncertaintyBudget = field(default_factory=UncertaintyBudget)
    redundancy: bool = True


@dataclass(frozen=True)
class Unidentifiable:
    """Something the plan cannot see, in the metrologist's words."""

    ids: tuple[str, ...]  # error ids involved
    dimensions: int  # how many independent shapes are not determined
    message: str


@dataclass(frozen=True)
class Identifiability:
    rank: int
    unknowns: int
    unidentifiable: tuple[Unidentifiable, ...]
    redundant_lines: tuple[str, ...]
    identified_ids: tuple[str, ...]  # errors fully determined by the plan

    def to_json(self) -> dict[str, object]:
        return {
            "rank": self.rank,
            "unknowns": self.unknowns,
            "unidentifiable": [u.message for u in self.unidentifiable],
            "unidentifiable_ids": sorted({i for u in self.unidentifiable for i in u.ids}),
            "redundant_lines": list(self.redundant_lines),
        }


@dataclass(frozen=True, eq=False)
class Identification:
    """The identified model and everything needed to judge it."""

    model: ErrorModel
    covariance: FloatArray  # (P, P) over model.parameters (statistical part)
    identifiability: Identifiability
    readings: Readings
    residual: FloatArray  # measured − predicted, per reading (µm or µrad)
    predicted: FloatArray
    offsets: dict[str, float]
    slopes: dict[str, float]
    effects: tuple[object, ...]
    effect_parameters: tuple[FloatArray, ...]
    effect_covariances: tuple[FloatArray, ...]
    sigma_scale: float  # a posteriori standard deviation of unit weight
    normal_inverse: FloatArray  # (AᵀWA)⁺ on the identifiable subspace, all columns
    iterations: int
    budget: UncertaintyBudget
    system: LinearSystem
    fitted_rank: int = 0  # independent unknowns fitted (21 errors, nuisances and effects)

    def band(
        self, eid: str, position_mm: FloatArray | None = None, count: int = 101
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(positions mm, value, standard uncertainty) of an error over its stroke.

        The standard uncertainty combines the statistical covariance with the budget (for the
        positioning errors). Squareness: one value (positions empty).
        """
        model = self.model
        sl = model.parameter_slices[eid]
        if eid in SQUARENESS_IDS:
            std = float(np.sqrt(max(self.covariance[sl, sl][0, 0], 0.0)))
            return np.empty(0), np.array([model.squareness_urad[eid]]), np.array([std])
        f = model.functions[eid]
        axis = ERROR_INFO[eid].axis
        assert axis is not None
        if position_mm is None:
            low, high = model.machine.stroke(axis)
            position_mm = np.linspace(low, high, count)
        design = f.basis.design(position_mm)
        cov = self.covariance[sl, sl]
        var = np.einsum("ij,jk,ik->i", design, cov, design)
        var = np.maximum(var, 0.0)
        if ERROR_INFO[eid].kind == "positioning":
            distance = position_mm - model.machine.reference(axis)
            var = var + self.budget.positioning_std_um(distance) ** 2
        return position_mm, f(position_mm), np.sqrt(var)

    def is_identified(self, eid: str) -> bool:
        return eid in self.identifiability.identified_ids


# --------------------------------------------------------------------------------------------
# The linear system
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ColumnBlock:
    kind: str  # "error", "offset", "slope", "effect"
    key: str  # error id, line name or effect label
    columns: slice
    line: int | None = None  # the only line this block acts on, if any


@dataclass(eq=False)
class LinearSystem:
    """Weighted least squares in normal-equation form, stored by line.

    ``normal`` = AᵀWA and ``rhs`` = AᵀWy over all readings (dense, unknowns × unknowns).
    ``target_design`` holds the rows of A shared by the readings at one target — the 21 errors'
    gauge coordinates, the lines' zero offsets and straightness slopes — as a sparse CSR matrix
    (T × p_target) in which every row of a line has the same columns: the errors that line moves
    and its own offset and slope. ``effect_design`` (readings × p_effect) holds the effects'
    columns. A line's contribution to the normal equations (:meth:`line_part`, for
    leave-one-line-out and the rank test of a line) is built from its rows when needed, on the
    columns it touches only: nothing of size lines × unknowns² is ever stored.

    ``line_targets`` (lines + 1) bounds each line's rows of ``target_design`` (targets are
    sorted by line); ``reading_order`` lists the readings line by line and ``reading_bounds``
    (lines + 1) bounds each line's readings in it.
    """

    blocks: list[ColumnBlock]
    normal: FloatArray
    rhs: FloatArray
    target_design: sparse.csr_matrix  # (T, p_target): geometric + nuisance columns per target
    target_of_reading: NDArray[np.int64]
    effect_design: FloatArray  # (n, p_effect)
    y: FloatArray  # the (pseudo-)observations of this linearisation
    weights: FloatArray
    line_targets: NDArray[np.int64]
    reading_order: NDArray[np.int64]
    reading_bounds: NDArray[np.int64]
    #: the effects' separable directions (see :func:`separable_reduction`), if restricted
    reduction: Reduction | None = None
    #: each line's part once built (:meth:`line_part`): a small dense block per line
    _parts: list[LinePart | None] = field(default_factory=list, init=False, repr=False)
    #: eliminations of the lines' own columns already made (see :func:`_eliminate`)
    _eliminations: dict[tuple[str, ...], tuple[Elimination, float]] = field(
        default_factory=dict, init=False, repr=False
    )

    def reduced(self) -> LinearSystem:
        """The same least-squares problem in the reduced unknowns (effects restricted to their
        separable directions); itself when unrestricted."""
        if self.reduction is None:
            return self
        r = self.reduction.matrix
        rigid = self.target_design.shape[1]
        blocks = [b for b in self.blocks if b.kind != "effect"] + list(self.reduction.blocks)
        return replace(
            self,
            blocks=blocks,
            normal=_expand_pair(self.normal, r, rigid, transpose=True),
            rhs=np.concatenate([self.rhs[:rigid], r[rigid:, rigid:].T @ self.rhs[rigid:]]),
            effect_design=self.effect_design @ r[rigid:, rigid:],
            reduction=None,
        )

    @property
    def size(self) -> int:
        return self.normal.shape[0]

    @property
    def lines(self) -> int:
        return len(self.line_targets) - 1

    def design_rows(self, mask: NDArray[np.bool_] | None = None) -> FloatArray:
        """Explicit (dense) rows of A for the readings in ``mask`` (all by default)."""
        idx = self.target_of_reading if mask is None else self.target_of_reading[mask]
        eff = self.effect_design if mask is None else self.effect_design[mask]
        return np.hstack([self.target_design[idx].toarray(), eff])

    def line_columns(self, line: int) -> NDArray[np.int64]:
        cols = [np.arange(b.columns.start, b.columns.stop) for b in self.blocks if b.line == line]
        return np.concatenate(cols) if cols else np.empty(0, dtype=np.int64)

    def own_columns(self, kinds: tuple[str, ...] = ("offset", "slope", "effect")) -> list[IntArray]:
        """Per line, the columns of the blocks of those ``kinds`` that act on that line only."""
        own: list[list[IntArray]] = [[] for _ in range(self.lines)]
        for b in self.blocks:
            if b.line is not None and b.kind in kinds:
                own[b.line].append(np.arange(b.columns.start, b.columns.stop))
        return [np.concatenate(c) if c else np.empty(0, dtype=np.int64) for c in own]

    def line_readings(self, line: int) -> IntArray:
        """Indices of the line's readings."""
        return self.reading_order[self.reading_bounds[line] : self.reading_bounds[line + 1]]

    def line_rows(self, line: int) -> tuple[IntArray, FloatArray]:
        """(columns, rows) of the line's targets in ``target_design``: the dense block
        (targets × columns) its rows hold on the columns they share."""
        a, z = self.line_targets[line], self.line_targets[line + 1]
        td = self.target_design
        start, stop = td.indptr[a], td.indptr[z]
        if z == a:
            return np.empty(0, dtype=np.int64), np.zeros((0, 0))
        k = (td.indptr[a + 1] - start) if z > a else 0
        return td.indices[start : start + k].astype(np.int64), td.data[start:stop].reshape(z - a, k)

    def line_part(self, line: int, keep: NDArray[np.bool_] | None = None) -> LinePart:
        """The line's contribution to the normal equations, on the columns it touches: from its
        readings (those in ``keep`` only, if given). Built once and kept (for all readings)."""
        if keep is not None:
            return self._build_part(line, keep)
        if not self._parts:
            self._parts = [None] * self.lines
        part = self._parts[line]
        if part is None:
            part = self._parts[line] = self._build_part(line, None)
        return part

    def _build_part(self, line: int, keep: NDArray[np.bool_] | None) -> LinePart:
        columns, block = self.line_rows(line)
        readings = self.line_readings(line)
        if keep is not None:
            readings = readings[keep[readings]]
        count = block.shape[0]
        local = self.target_of_reading[readings] - self.line_targets[line]
        w = self.weights[readings]
        y = self.y[readings]
        w_t = np.bincount(local, weights=w, minlength=count)
        wy_t = np.bincount(local, weights=w * y, minlength=count)
        normal = (block * w_t[:, None]).T @ block
        rhs = block.T @ wy_t
        if self.effect_design.shape[1] and readings.size:
            e = self.effect_design[readings]
            touched = np.flatnonzero(np.any(e != 0.0, axis=0))
            if touched.size:
                e = e[:, touched]
                we = e * w[:, None]
                agg = np.stack(
                    [np.bincount(local, weights=col, minlength=count) for col in we.T], axis=-1
                )
                cross = block.T @ agg
                normal = np.block([[normal, cross], [cross.T, e.T @ we]])
                rhs = np.concatenate([rhs, we.T @ y])
                columns = np.concatenate([columns, self.target_design.shape[1] + touched])
        return LinePart(columns, normal, rhs)

    def stored_nbytes(self) -> dict[str, int]:
        """Bytes held per kind of storage: what is stored by line (design rows, index arrays)
        and the dense unknowns × unknowns normal matrix."""
        td = self.target_design
        by_line = sum(
            a.nbytes
            for a in (
                td.data,
                td.indices,
                td.indptr,
                self.target_of_reading,
                self.effect_design,
                self.y,
                self.weights,
                self.line_targets,
                self.reading_order,
                self.reading_bounds,
            )
        )
        by_line += sum(
            p.columns.nbytes + p.normal.nbytes + p.rhs.nbytes for p in self._parts if p is not None
        )
        return {"lines": int(by_line), "normal": int(self.normal.nbytes + self.rhs.nbytes)}


def _expand_pair(
    matrix: FloatArray, r: FloatArray, rigid: int, transpose: bool = False
) -> FloatArray:
    """r·M·rᵀ (or rᵀ·M·r with ``transpose``) for a reduction matrix r that is the identity on the
    first ``rigid`` columns and block-structured after: computed by blocks (r is P × P')."""
    e = r[rigid:, rigid:]
    if transpose:
        e = e.T
    n_out = rigid + e.shape[0]
    out = np.empty((n_out, n_out))
    out[:rigid, :rigid] = matrix[:rigid, :rigid]
    cross = matrix[:rigid, rigid:] @ e.T
    out[:rigid, rigid:] = cross
    out[rigid:, :rigid] = cross.T
    out[rigid:, rigid:] = e @ matrix[rigid:, rigid:] @ e.T
    return out


def _column_scale(normal: FloatArray) -> FloatArray:
    """1/‖column‖ for the columns of A (from AᵀA's diagonal); columns whose norm is below 1e-12
    of the largest are rounding noise of an unseen parameter and are left unscaled, so that
    they stay (numerically) zero instead of being blown up to unit size."""
    diag = np.diag(normal).copy()
    seen = diag > 1e-24 * max(float(diag.max(initial=0.0)), 1e-300)
    return np.where(seen, 1.0 / np.sqrt(np.where(seen, diag, 1.0)), 1.0)


def _rank_limit(normal: FloatArray, scale: FloatArray) -> float:
    """Eigenvalues of the column-scaled normal matrix at or below this are taken as zero."""
    largest = largest_eigenvalue(normal * scale[:, None] * scale[None, :])
    return RANK_TOLERANCE * max(largest, 1e-300)


def _eliminate(
    system: LinearSystem, kinds: tuple[str, ...] = ("offset", "slope", "effect")
) -> tuple[Elimination, float]:
    """The system with every line's own columns eliminated, and the rank limit (made once per
    system: the subspace, the rank analysis and the first solve share it)."""
    if kinds not in system._eliminations:
        scale = _column_scale(system.normal)
        limit = _rank_limit(system.normal, scale)
        elimination = Elimination.of(
            system.line_part, system.own_columns(kinds), system.size, scale, limit
        )
        system._eliminations[kinds] = (elimination, limit)
    return system._eliminations[kinds]


def _scaled_pinv(normal: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Pseudo-inverse of a normal matrix via the column-scaled eigen-decomposition.

    Returns (pinv, scale, eigenvalues, eigenvectors) in scaled coordinates. Dense (unknowns³):
    for small matrices only; identification itself works line by line (core/identify_blocks.py).
    """
    scale = _column_scale(normal)
    scaled = normal * scale[:, None] * scale[None, :]
    values, vectors = np.linalg.eigh(scaled)
    keep = values > RANK_TOLERANCE * max(values.max(initial=0.0), 1e-300)
    inv_values = np.where(keep, 1.0 / np.where(keep, values, 1.0), 0.0)
    pinv_scaled = (vectors * inv_values) @ vectors.T
    return pinv_scaled * scale[:, None] * scale[None, :], scale, values, vectors


#: An effect direction is fitted only where more than this share of its signal (column-scaled)
#: is not also a combination of the 21 errors and the lines' nuisances: what the plan cannot tell
#: apart from a rigid body at all stays with the rigid body (a sag's bilinear part that a roll
#: produces as well stays a roll) instead of being split between them by a minimum norm.
SEPARABILITY = 1e-6


@dataclass(frozen=True, eq=False)
class Reduction:
    """The effects' unknowns restricted to what the plan tells apart from a rigid body.

    ``matrix`` (P × P') maps the reduced unknowns to all of them: the identity on the 21 errors'
    and the lines' columns (which come first), and for each effect the separable directions of
    its columns. ``blocks`` are the effects' column blocks in the reduced unknowns.
    """

    matrix: FloatArray
    blocks: tuple[ColumnBlock, ...]


def separable_reduction(system: LinearSystem) -> Reduction | None:
    """Per effect, the eigenvectors of its Schur complement against the other columns (the
    information it does not share with the 21 errors and the nuisances), column-scaled, whose
    eigenvalue reaches :data:`SEPARABILITY`; None without effects.

    The lines' offsets and slopes are eliminated line by line; the Schur complement against the
    21 errors is then taken on the (small) reduced system.
    """
    effects = [b for b in system.blocks if b.kind == "effect"]
    if not effects:
        return None
    rigid = effects[0].columns.start  # effect columns come last
    scale = _column_scale(system.normal)
    limit = _rank_limit(system.normal[:rigid, :rigid], scale[:rigid])
    elimination = Elimination.of(
        system.line_part, system.own_columns(("offset", "slope")), system.size, scale, limit
    )
    reduced = elimination.reduced
    errors = np.flatnonzero(elimination.glob < rigid)
    effect_positions = np.flatnonzero(elimination.glob >= rigid)  # every effect column, in order
    values, vectors = np.linalg.eigh(reduced[np.ix_(errors, errors)])
    seen = values > limit
    vectors, values = vectors[:, seen], values[seen]
    projected = vectors.T @ reduced[np.ix_(errors, effect_positions)]
    schur_all = reduced[np.ix_(effect_positions, effect_positions)] - projected.T @ (
        projected / values[:, None]
    )
    pieces = []
    blocks = []
    start = rigid
    for block in effects:
        columns = np.arange(block.columns.start, block.columns.stop)
        local = columns - rigid
        s_values, s_vectors = np.linalg.eigh(schur_all[np.ix_(local, local)])
        kept = s_vectors[:, s_values > SEPARABILITY] * scale[columns][:, None]
        pieces.append((columns, kept))
        blocks.append(replace(block, columns=slice(start, start + kept.shape[1])))
        start += kept.shape[1]
    matrix = np.zeros((system.size, start))
    matrix[:rigid, :rigid] = np.eye(rigid)
    for (columns, kept), block in zip(pieces, blocks, strict=True):
        matrix[columns, block.columns] = kept
    return Reduction(matrix, tuple(blocks))


@dataclass(frozen=True, eq=False)
class _Subspace:
    """The identifiable subspace of a system, fixed in the column scaling of its first
    linearisation: the complement (in scaled coordinates) of its null space."""

    scale: FloatArray
    null: NullSpace  # in the scaled coordinates of ``scale``
    rank: int

    @classmethod
    def of(cls, system: LinearSystem) -> _Subspace:
        elimination, limit = _eliminate(system)
        null = elimination.null_space(limit)
        return cls(elimination.scale, null, system.size - null.dimensions)

    def restrict(self, system: LinearSystem) -> ConstrainedSystem:
        """The least-squares problem of ``system`` restricted to the subspace."""
        made = system._eliminations.get(("offset", "slope", "effect"))
        if (
            made is not None
            and np.array_equal(made[0].scale, self.scale)
            and not any(u.shape[1] for u in self.null.own)
            and not any(b.null.shape[1] for b in made[0].lines)
        ):
            # the system the subspace was found on: its elimination is this one
            return ConstrainedSystem.of(made[0], self.null.vectors)
        elimination = Elimination.of(
            system.line_part,
            system.own_columns(),
            system.size,
            self.scale,
            0.0,
            own_null=self.null.own,
        )
        return ConstrainedSystem.of(elimination, self.null.vectors)

    def solve(self, system: LinearSystem) -> FloatArray:
        return np.asarray(self.restrict(system).solve() * self.scale)

    def inverse(self, system: LinearSystem) -> FloatArray:
        """Covariance factor (AᵀWA)⁺ restricted to the identifiable subspace."""
        return np.asarray(self.restrict(system).inverse() * self.scale[:, None] * self.scale)


#: Ridge added to the column-scaled normal matrix of a leave-one-line-out fit.
RIDGE = 1e-11


def _spd_solve(matrix: FloatArray, rhs: FloatArray) -> FloatArray:
    """Solve with a (ridged) symmetric positive definite matrix by Cholesky; by its
    pseudo-inverse if rounding left it indefinite (as :func:`solve_normal` does)."""
    try:
        factor = cho_factor(matrix, lower=True, check_finite=False, overwrite_a=True)
        return np.asarray(cho_solve(factor, rhs, check_finite=False))
    except np.linalg.LinAlgError:
        return np.asarray(np.linalg.pinv(matrix, hermitian=True) @ rhs)


def solve_normal(normal: FloatArray, rhs: FloatArray) -> FloatArray:
    """Minimum-norm (in scaled coordinates) solution of the normal equations; fast path by a
    Cholesky factorisation with a tiny ridge for rank-deficient systems."""
    scale = _column_scale(normal)
    scaled = normal * scale[:, None] * scale[None, :]
    scaled[np.diag_indices_from(scaled)] += RIDGE
    try:
        factor = cho_factor(scaled, lower=True, check_finite=False)
        return np.asarray(cho_solve(factor, rhs * scale, check_finite=False) * scale)
    except np.linalg.LinAlgError:
        pinv, *_ = _scaled_pinv(normal)
        return np.asarray(pinv @ rhs)


# --------------------------------------------------------------------------------------------
# Building the system
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _Targets:
    """Unique (line, target) points of a measurement, sorted by line."""

    line: NDArray[np.int64]
    position_mm: FloatArray
    reflector_mm: FloatArray
    projection: FloatArray
    quantity: NDArray[np.int64]
    target_mm: FloatArray
    of_reading: NDArray[np.int64]

    def rows(self, start: int, stop: int) -> _Targets:
        """The targets start … stop − 1 (``of_reading`` is left as is)."""
        return _Targets(
            self.line[start:stop],
            self.position_mm[start:stop],
            self.reflector_mm[start:stop],
            self.projection[start:stop],
            self.quantity[start:stop],
            self.target_mm[start:stop],
            self.of_reading,
        )

    def bounds(self, lines: int) -> NDArray[np.int64]:
        """(lines + 1) bounds of each line's targets."""
        return np.searchsorted(self.line, np.arange(lines + 1)).astype(np.int64)


def _unique_targets(readings: Readings) -> _Targets:
    key = readings.line * 1_000_000 + readings.target
    unique, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    return _Targets(
        readings.line[first],
        readings.position_mm[first],
        readings.reflector_mm[first],
        readings.projection[first],
        readings.quantity[first],
        readings.target_mm[first],
        inverse.astype(np.int64),
    )


def model_with_bases(machine: Machine, options: IdentifyOptions) -> ErrorModel:
    """A zero model with the bases identification uses."""

    def basis_for(axis: str, eid: str) -> Basis:
        if eid in options.basis:
            return options.basis[eid]
        low, high = machine.stroke(axis)
        return BSplineBasis.uniform(low, high, options.spacing_mm)

    return ErrorModel.zero(machine, basis_for)


@dataclass(frozen=True, eq=False)
class Gauge:
    """Block-diagonal map from free gauge coordinates θ to model parameters: p = N θ."""

    matrix: FloatArray  # (P, G)
    blocks: dict[str, slice]  # error id -> columns of θ

    @classmethod
    def for_model(cls, model: ErrorModel) -> Gauge:
        columns = []
        blocks: dict[str, slice] = {}
        start = 0
        for eid in AXIS_ERROR_IDS:
            f = model.functions[eid]
            axis = ERROR_INFO[eid].axis
            assert axis is not None
            null = gauge_null_space(
                f.basis, model.machine.reference(axis), ERROR_INFO[eid].is_straightness
            )
            columns.append(null)
            blocks[eid] = slice(start, start + null.shape[1])
            start += null.shape[1]
        for eid in SQUARENESS_IDS:
            columns.append(np.ones((1, 1)))
            blocks[eid] = slice(start, start + 1)
            start += 1
        rows = sum(c.shape[0] for c in columns)
        matrix = np.zeros((rows, start))
        r = 0
        for c, eid in zip(columns, ERROR_IDS, strict=True):
            matrix[r : r + c.shape[0], blocks[eid]] = c
            r += c.shape[0]
        return cls(matrix, blocks)

    @property
    def size(self) -> int:
        return self.matrix.shape[1]


def _geometric_rows(model: ErrorModel, targets: _Targets) -> FloatArray:
    """d(reading)/d(model parameters) per target (T, P): exact chain for displacement optics,
    the first-order sum of the axes' angles for angular optics.

    The chain's derivatives with respect to each error's *value* (T × 3 × 6 per axis) are
    projected on the optics first and then spread over the error's basis functions, so nothing
    of size T × 3 × P is formed."""
    rows = np.zeros((len(targets.line), model.parameter_count))
    angular = targets.quantity == QUANTITY_CODE["angular"]
    disp = ~angular
    slices = model.parameter_slices
    if disp.any():
        q = targets.position_mm[disp]
        w = targets.projection[disp]
        per_axis, squareness = error_value_jacobian(model, q, targets.reflector_mm[disp])
        block = np.zeros((len(q), model.parameter_count))
        for axis in AXES:
            k = AXIS_INDEX[axis]
            along = np.einsum("nc,ncj->nj", w, per_axis[axis])  # d(reading)/d(error value)
            for j, eid in enumerate(axis_error_ids(axis)):
                design = model.functions[eid].basis.design(q[:, k])
                block[:, slices[eid]] = along[:, j, None] * design
        for sid in SQUARENESS_IDS:
            block[:, slices[sid].start] = np.einsum("nc,nc->n", w, squareness[sid])
        rows[disp] = block
    if angular.any():
        q = targets.position_mm[angular]
        w = targets.projection[angular]
        block = np.zeros((int(angular.sum()), model.parameter_count))
        for axis in AXES:
            for j, component in enumerate("ABC"):
                eid = f"E{component}{axis}"
                design = model.functions[eid].basis.design(q[:, AXIS_INDEX[axis]])
                block[:, slices[eid]] += w[:, j, None] * design
        rows[angular] = block
    return rows


def _gauge_rows(rows: FloatArray, model: ErrorModel, gauge: Gauge) -> FloatArray:
    """rows · N (T × G) by the gauge map's diagonal blocks (one per error), skipping the errors
    these rows do not move."""
    out = np.zeros((rows.shape[0], gauge.size))
    slices = model.parameter_slices
    for eid in ERROR_IDS:
        part = rows[:, slices[eid]]
        if np.any(part):
            out[:, gauge.blocks[eid]] = part @ gauge.matrix[slices[eid], gauge.blocks[eid]]
    return out


def predict_geometric(model: ErrorModel, targets: _Targets) -> FloatArray:
    """Exact prediction of each target's reading from the 21 errors (without nuisances)."""
    out = np.zeros(len(targets.line))
    angular = targets.quantity == QUANTITY_CODE["angular"]
    disp = ~angular
    if disp.any():
        e = VolumetricModel(model).error(targets.position_mm[disp], targets.reflector_mm[disp])
        out[disp] = np.einsum("nc,nc->n", e, targets.projection[disp])
    if angular.any():
        rot = rotation_error(model, targets.position_mm[angular])
        out[angular] = np.einsum("nc,nc->n", rot, targets.projection[angular])
    return out


class EffectTerm:
    """What identification needs of an effect (core/effects.py implements it)."""

    label: str
    line_index: int | None  # the only line it acts on (a set-up effect), or None

    def design(self, readings: Readings, model: ErrorModel) -> FloatArray:  # (n, k)
        raise NotImplementedError


#: Target rows (targets × parameters) built at once: about 32 MB of them.
_ROW_ENTRIES = 4_000_000


@dataclass(frozen=True, eq=False)
class GeometricDesign:
    """d(reading)/dθ of every target in the gauge coordinates, line by line: ``columns[l]`` are
    the gauge coordinates line l moves, ``rows[l]`` (its targets × those columns) the values."""

    columns: list[IntArray]
    rows: list[FloatArray]

    @classmethod
    def of(
        cls, model: ErrorModel, targets: _Targets, gauge: Gauge, bounds: IntArray
    ) -> GeometricDesign:
        budget = max(1, _ROW_ENTRIES // max(model.parameter_count, 1))
        lines = len(bounds) - 1
        columns: list[IntArray] = []
        rows: list[FloatArray] = []
        first = 0
        while first < lines:
            last = first + 1
            while last < lines and bounds[last + 1] - bounds[first] <= budget:
                last += 1
            a = bounds[first]
            geo = _gauge_rows(_geometric_rows(model, targets.rows(a, bounds[last])), model, gauge)
            for line in range(first, last):
                sub = geo[bounds[line] - a : bounds[line + 1] - a]
                touched = np.flatnonzero(np.any(sub != 0.0, axis=0))
                columns.append(touched)
                rows.append(np.ascontiguousarray(sub[:, touched]))
            first = last
        return cls(columns, rows)

    def apply(self, theta: FloatArray) -> FloatArray:
        """rows · θ for every target."""
        parts = [r @ theta[c] for c, r in zip(self.columns, self.rows, strict=True)]
        return np.concatenate(parts) if parts else np.zeros(0)


def build_system(
    readings: Readings,
    targets: _Targets,
    model: ErrorModel,
    gauge: Gauge,
    effects: Sequence[EffectTerm],
    pseudo_y: FloatArray,
    effect_model: ErrorModel | None = None,
    geometric: GeometricDesign | None = None,
) -> LinearSystem:
    """Assemble the normal equations for one linearisation (effects designed with
    ``effect_model``, by default the linearisation point itself; the geometric rows given or
    computed at ``model``)."""
    n_lines = len(readings.lines)
    bounds = targets.bounds(n_lines)
    if geometric is None:
        geometric = GeometricDesign.of(model, targets, gauge, bounds)
    blocks: list[ColumnBlock] = [ColumnBlock("error", eid, gauge.blocks[eid]) for eid in ERROR_IDS]
    start = gauge.size
    for index, line in enumerate(readings.lines):
        blocks.append(
            ColumnBlock("offset", line.name, slice(start + index, start + index + 1), index)
        )
    offset_of = start + np.arange(n_lines)
    start += n_lines
    straight_lines = [
        i for i, line in enumerate(readings.lines) if line.spec.quantity == "straightness"
    ]
    slope_of: dict[int, int] = {}
    for k, index in enumerate(straight_lines):
        blocks.append(
            ColumnBlock("slope", readings.lines[index].name, slice(start + k, start + k + 1), index)
        )
        slope_of[index] = start + k
    start += len(straight_lines)
    p_t = start
    # target rows line by line: the line's error columns, then its offset (and slope) column
    data, indices, row_length = [], [], []
    for index in range(n_lines):
        a, z = bounds[index], bounds[index + 1]
        columns = [geometric.columns[index], [offset_of[index]]]
        pieces = [geometric.rows[index], np.ones((z - a, 1))]
        if index in slope_of:
            columns.append([slope_of[index]])
            # slope per metre of travel keeps the columns on the scale of the others
            pieces.append(targets.target_mm[a:z, None] / 1000.0)
        columns_l = np.concatenate(columns).astype(np.int32)
        data.append(np.hstack(pieces).ravel())
        indices.append(np.tile(columns_l, z - a))
        row_length.append(np.full(z - a, columns_l.size))
    indptr = np.concatenate([[0], np.cumsum(np.concatenate(row_length))]) if n_lines else [0]
    target_design = sparse.csr_matrix(
        (
            np.concatenate(data) if data else np.zeros(0),
            np.concatenate(indices) if indices else np.zeros(0, np.int32),
            np.asarray(indptr, dtype=np.int64),
        ),
        shape=(len(targets.line), p_t),
    )
    del data, indices
    effect_parts = []
    for effect in effects:
        d = effect.design(readings, effect_model or model)
        effect_parts.append(d)
        blocks.append(
            ColumnBlock("effect", effect.label, slice(start, start + d.shape[1]), effect.line_index)
        )
        start += d.shape[1]
    effect_design = np.hstack(effect_parts) if effect_parts else np.zeros((len(readings), 0))
    order = np.argsort(readings.line, kind="stable").astype(np.int64)
    system = LinearSystem(
        blocks,
        np.zeros((start, start)),
        np.zeros(start),
        target_design,
        targets.of_reading,
        effect_design,
        pseudo_y,
        1.0 / readings.sigma**2,
        bounds,
        order,
        np.searchsorted(readings.line[order], np.arange(n_lines + 1)).astype(np.int64),
    )
    for index in range(n_lines):
        part = system.line_part(index)
        system.normal[np.ix_(part.columns, part.columns)] += part.normal
        system.rhs[part.columns] += part.rhs
    return system


# --------------------------------------------------------------------------------------------
# Identifiability
# --------------------------------------------------------------------------------------------

_KIND_WORDS = {
    "positioning": "positioning",
    "straightness": "straightness",
    "roll": "roll",
    "pitch": "pitch",
    "yaw": "yaw",
    "tilt": "tilt",
    "squareness": "squareness",
}


def _describe(eid: str) -> str:
    info = ERROR_INFO[eid]
    if info.axis is None:
        return f"{info.description} ({eid})"
    if info.kind == "straightness":
        return f"straightness of {info.axis} in {info.component} ({eid})"
    return f"{_KIND_WORDS[info.kind]} of {info.axis} ({eid})"


def identifiability(
    system: LinearSystem, gauge: Gauge, lines: Sequence[str], redundancy: bool = True
) -> Identifiability:
    """Rank, what the plan cannot see (named), and which lines are redundant."""
    elimination, limit = _eliminate(system)
    nulls = elimination.null_space(limit)
    null = nulls.orthonormal()  # scaled coordinates
    rank = system.size - null.shape[1]
    messages: list[Unidentifiable] = []
    unidentified: set[str] = set()
    block_of = {b.key: b for b in system.blocks if b.kind == "error"}
    if null.shape[1]:
        for eid in ERROR_IDS:
            cols = block_of[eid].columns
            part = null[cols]
            if part.size == 0:
                continue
            s = np.linalg.svd(part, compute_uv=False)
            dims = int(np.sum(s > 1e-6))
            if dims == 0:
                continue
            unidentified.add(eid)
            total = cols.stop - cols.start
            # partners: other errors moving together with this one in the null space
            u, s_full, vt = np.linalg.svd(part, full_matrices=False)
            combos = null @ vt[:dims].T
            partners = []
            for other in ERROR_IDS:
                if other == eid:
                    continue
                share = np.linalg.norm(combos[block_of[other].columns], axis=0)
                if np.any(share > 0.1):
                    partners.append(other)
            nuisance = [b for b in system.blocks if b.kind in ("offset", "slope")]
            absorbed = any(
                np.any(np.linalg.norm(combos[b.columns], axis=0) > 0.1) for b in nuisance
            )
            if dims == total and not partners:
                text = f"{_describe(eid)} is not seen by this plan"
            elif dims == total:
                text = (
                    f"{_describe(eid)} is not determined: only its combination with "
                    f"{', '.join(partners)} is seen"
                )
            else:
                text = f"{_describe(eid)}: {dims} of {total} shape functions are not determined"
                if partners:
                    text += f" (confounded with {', '.join(partners)})"
            if absorbed and not partners:
                text += " (absorbed by the lines' zero offsets and alignment slopes)"
            messages.append(Unidentifiable((eid, *partners), dims, text))
    redundant: list[str] = []
    if redundancy:
        redundant = [
            name
            for index, name in enumerate(lines)
            if _is_redundant(system, elimination, index, limit)
        ]
    identified = tuple(e for e in ERROR_IDS if e not in unidentified)
    return Identifiability(rank, system.size, tuple(messages), tuple(redundant), identified)


def _is_redundant(system: LinearSystem, elimination: Elimination, line: int, limit: float) -> bool:
    """Whether leaving the line out keeps the rank of every other column (its own columns go
    with it): its largest leverage on the reduced system stays below 1.

    With R the reduced matrix and S the line's Schur part, R − S keeps R's rank when the
    eigenvalues h of S against R (the line's leverages) are below 1; an eigenvalue of R − S
    then lies between (1 − h)·λmin(R) and (1 − h)·λmax(R), compared with the rank limit as the
    whole matrix's eigenvalues are. In between, R − S's eigenvalues are counted directly.
    """
    block = elimination.lines[line]
    values, _ = elimination.eigen
    kept = values[values > limit]
    if block.null.shape[1]:
        return _keeps_rank(elimination, system, line, limit, block.null.shape[1])
    if kept.size == 0:
        return True
    pinv = elimination.reduced_pinv(limit)
    touched = block.touched
    rows = _projected_rows(system, elimination, line)
    h = largest_leverage(rows, pinv[np.ix_(touched, touched)])
    gap = 1.0 - h
    if gap * kept[0] > limit:
        return True
    if gap * kept[-1] <= limit:
        return False
    return _keeps_rank(elimination, system, line, limit, 0)


def _projected_rows(system: LinearSystem, elimination: Elimination, line: int) -> FloatArray:
    """A factor F (·× touched) of the line's Schur part S = FᵀF, scaled: its weighted target
    rows with its own columns projected out, or (when effects act on the line, whose rows differ
    from reading to reading) the square root of S."""
    block = elimination.lines[line]
    scale = elimination.scale
    part = system.line_part(line)
    own = np.isin(part.columns, block.columns)
    target_columns, rows = system.line_rows(line)
    if target_columns.size != part.columns.size:
        schur, _ = line_schur(block, part, scale)
        values, vectors = np.linalg.eigh(schur)
        return np.asarray((vectors * np.sqrt(np.maximum(values, 0.0))).T)
    readings = system.line_readings(line)
    local = system.target_of_reading[readings] - system.line_targets[line]
    w_t = np.bincount(local, weights=system.weights[readings], minlength=rows.shape[0])
    x = rows * scale[target_columns]
    # own columns in the order of block.columns
    where = np.searchsorted(target_columns, block.columns)
    projected = x[:, ~own] - x[:, where] @ (block.inverse @ block.coupling)
    return np.asarray(projected * np.sqrt(w_t)[:, None])


def _keeps_rank(
    elimination: Elimination, system: LinearSystem, line: int, limit: float, lost_own: int
) -> bool:
    """R − S has R's rank less the line's undetermined own directions (eigenvalues counted)."""
    block = elimination.lines[line]
    values, _ = elimination.eigen
    schur, _ = line_schur(block, system.line_part(line), elimination.scale)
    reduced = elimination.reduced.copy()
    reduced[np.ix_(block.touched, block.touched)] -= schur
    left = np.linalg.eigvalsh(reduced)
    return int(np.sum(left > limit)) == int(np.sum(values > limit)) - lost_own


# --------------------------------------------------------------------------------------------
# Identification
# --------------------------------------------------------------------------------------------


def _without_effects(system: LinearSystem) -> LinearSystem:
    """The system restricted to the 21 errors and the lines' nuisances (effect columns, which
    come last, left out)."""
    size = min((b.columns.start for b in system.blocks if b.kind == "effect"), default=system.size)
    if size == system.size:
        return system
    out = replace(
        system,
        blocks=[b for b in system.blocks if b.kind != "effect"],
        normal=system.normal[:size, :size],
        rhs=system.rhs[:size],
        effect_design=np.zeros((len(system.target_of_reading), 0)),
        reduction=None,
    )
    # the parts without the effects' columns (which come last)
    out._parts = [
        None
        if p is None
        else LinePart(
            p.columns[p.columns < size],
            p.normal[np.ix_(p.columns < size, p.columns < size)],
            p.rhs[p.columns < size],
        )
        for p in system._parts
    ]
    return out


def identify(
    measurement: Measurement,
    options: IdentifyOptions | None = None,
    effects: Sequence[EffectTerm] = (),
    readings: Readings | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
    initial: ErrorModel | None = None,
) -> Identification:
    """Identify the 21 errors (and the given effects' parameters) from a measurement.

    ``initial`` (a model with the same bases, e.g. a previous identification) is the first
    linearisation point; effects whose design depends on the model (an Abbe offset acts through
    the identified angles) need it.
    """
    options = options or IdentifyOptions()
    if not measurement.lines:
        raise IdentificationError("the measurement has no lines to identify from")
    readings = readings if readings is not None else flatten(measurement)
    if len(readings) == 0:
        raise IdentificationError("the measurement has no valid readings")
    targets = _unique_targets(readings)
    bounds = targets.bounds(len(readings.lines))
    model = model_with_bases(measurement.machine, options)
    gauge = Gauge.for_model(model)
    theta = np.zeros(gauge.size) if initial is None else gauge.matrix.T @ initial.parameters
    iterations = 0
    system: LinearSystem | None = None
    subspace: _Subspace | None = None
    rank_info: Identifiability | None = None
    solution = np.zeros(0)
    reduction: Reduction | None = None
    restricted: ConstrainedSystem | None = None
    max_iterations = options.max_iterations if options.refine else 1
    noise = float(np.median(readings.sigma))
    for iterations in range(1, max_iterations + 1):
        check(cancel)
        report(
            progress, 0.1 + 0.7 * (iterations - 1) / max_iterations, f"linear solve {iterations}"
        )
        current = model.with_parameters(gauge.matrix @ theta)
        geometric = GeometricDesign.of(current, targets, gauge, bounds)
        base = predict_geometric(current, targets) - geometric.apply(theta)
        pseudo_y = readings.value - base[targets.of_reading]
        system = build_system(
            readings, targets, current, gauge, effects, pseudo_y, geometric=geometric
        )
        del geometric
        if subspace is None:
            # What the plan can see is decided once, on the first-order system (the Jacobian at
            # zero errors): nonlinear refinement must not turn second-order couplings into
            # "identified" directions.
            structural = system
            if initial is not None:
                zero = model.with_parameters(np.zeros(model.parameter_count))
                structural = build_system(
                    readings, targets, zero, gauge, effects, pseudo_y, effect_model=current
                )
            reduction = separable_reduction(structural)
            structural.reduction = reduction
            subspace = _Subspace.of(structural.reduced())
            # What the plan sees of the 21 errors is judged without the effects: what an effect
            # shares with a rigid body is left to the rigid body (separable_reduction).
            rank_info = identifiability(
                _without_effects(structural),
                gauge,
                [line.name for line in readings.lines],
                options.redundancy,
            )
            del structural
        system.reduction = reduction
        reduced = system.reduced()
        restricted = subspace.restrict(reduced)
        solution = _expand(
            reduction,
            _refined_solve(reduced, restricted, subspace.scale),
            reduced.target_design.shape[1],
        )
        new_theta = solution[: gauge.size]
        change = _max_value_change(model, gauge, theta, new_theta)
        theta = new_theta
        if change < 1e-2 * noise:
            break
    assert system is not None and subspace is not None and rank_info is not None
    assert restricted is not None
    model = model.with_parameters(gauge.matrix @ theta)
    check(cancel)
    report(progress, 0.85, "uncertainty")
    design_residual = system.y - _apply(system, solution)
    final_pred = readings.value - design_residual
    fitted_rank = subspace.rank
    dof = max(len(readings) - fitted_rank, 1)
    chi2 = float(np.sum(system.weights * design_residual**2))
    sigma_scale = float(np.sqrt(chi2 / dof))
    scale = subspace.scale
    rigid = system.target_design.shape[1]
    normal_inverse = restricted.inverse() * scale[:, None] * scale[None, :]
    if reduction is not None:
        normal_inverse = _expand_pair(normal_inverse, reduction.matrix, rigid)
    del restricted
    cov_all = normal_inverse * sigma_scale**2
    g = gauge.size
    covariance = gauge.matrix @ cov_all[:g, :g] @ gauge.matrix.T
    offsets, slopes, eff_params, eff_cov = {}, {}, [], []
    for block in system.blocks:
        if block.kind == "offset":
            offsets[block.key] = float(solution[block.columns][0])
        elif block.kind == "slope":
            slopes[block.key] = float(solution[block.columns][0]) / 1000.0  # µm per mm
        elif block.kind == "effect":
            eff_params.append(solution[block.columns].copy())
            eff_cov.append(cov_all[block.columns, block.columns].copy())
    report(progress, 1.0, "identified")
    return Identification(
        model=model,
        covariance=covariance,
        identifiability=rank_info,
        readings=readings,
        residual=design_residual,
        predicted=final_pred,
        offsets=offsets,
        slopes=slopes,
        effects=tuple(effects),
        effect_parameters=tuple(eff_params),
        effect_covariances=tuple(eff_cov),
        sigma_scale=sigma_scale,
        normal_inverse=normal_inverse,
        iterations=iterations,
        budget=options.budget,
        system=system,
        fitted_rank=fitted_rank,
    )


def _refined_solve(
    system: LinearSystem, restricted: ConstrainedSystem, scale: FloatArray
) -> FloatArray:
    """The restricted least-squares solution, refined once with the residual of the design
    itself (corrected semi-normal equations): the normal equations square the design's
    condition number, the residual y − Ax does not, so the step recovers the digits an
    ill-conditioned plan (a few diagonals) loses in AᵀWA."""
    x = restricted.solve()
    residual = system.y - _apply(system, x * scale)
    correction = restricted.solve(_apply_transpose(system, system.weights * residual) * scale)
    return np.asarray((x + correction) * scale)


def _apply_transpose(system: LinearSystem, values: FloatArray) -> FloatArray:
    """Aᵀ·v for a value per reading."""
    per_target = np.bincount(
        system.target_of_reading, weights=values, minlength=system.target_design.shape[0]
    )
    out = system.target_design.T @ per_target
    if system.effect_design.shape[1]:
        out = np.concatenate([out, system.effect_design.T @ values])
    return np.asarray(out)


def _expand(reduction: Reduction | None, reduced: FloatArray, rigid: int) -> FloatArray:
    """The solution in all unknowns from the reduced unknowns (effects follow the ``rigid``
    columns)."""
    if reduction is None:
        return reduced
    r = reduction.matrix
    return np.concatenate([reduced[:rigid], r[rigid:, rigid:] @ reduced[rigid:]])


def _apply(system: LinearSystem, solution: FloatArray) -> FloatArray:
    """A·x for every reading."""
    p_t = system.target_design.shape[1]
    out = (system.target_design @ solution[:p_t])[system.target_of_reading]
    if system.effect_design.shape[1]:
        out = out + system.effect_design @ solution[p_t:]
    return out


def _max_value_change(model: ErrorModel, gauge: Gauge, old: FloatArray, new: FloatArray) -> float:
    """Largest change of any error value over its stroke (µm or µrad) between two solutions."""
    delta = model.with_parameters(gauge.matrix @ (new - old))
    worst = max(abs(v) for v in delta.squareness_urad.values())
    for eid in AXIS_ERROR_IDS:
        _, values = delta.sampled(eid, 41)
        worst = max(worst, float(np.max(np.abs(values))))
    return worst


# --------------------------------------------------------------------------------------------
# Cross-validation
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CrossValidation:
    """Cross-validated error of a fit."""

    method: str  # "leave-one-line-out" or "held-out blocks"
    rms_um: float  # over displacement readings
    rms_urad: float  # over angular readings (nan if none)
    per_line_rms: dict[str, float]
    residual: FloatArray  # cross-validated residual per reading


def cross_validate(
    system: LinearSystem, readings: Readings, redundant: Sequence[str] | None = None
) -> CrossValidation:
    """Leave-one-line-out cross-validated residuals from the normal equations.

    For each line: fit without it, predict it, then fit only that line's own columns (its zero
    offset, straightness slope and set-up effects) to what is left — the laser's zero and
    alignment are unknown for a line never seen. When some lines are not redundant (leaving them
    out loses rank), held-out contiguous blocks of targets are used instead.

    The fit without a line is the reduced system (every line's own columns eliminated) less
    the line's part, condensed on the columns the line touches: no refit of the whole system per
    line.
    """
    system = system.reduced()
    names = [line.name for line in readings.lines]
    if redundant is not None and set(names) - set(redundant):
        return _cross_validate_blocks(system, readings)
    # The fit without a line is solve_normal's: the normal equations without the line (its own
    # columns left out) with a ridge of RIDGE on the column-scaled diagonal. The ridge scales
    # with the diagonal *without* the line, which on the columns the line touches is the full
    # diagonal less the line's. With every line's own columns eliminated (ridge included), that
    # is the reduced matrix R less the line's Schur part S on the columns t the line touches,
    # solved by Cholesky as solve_normal does: the columns f it does not touch are eliminated
    # first, once for all the lines that touch the same columns (lines of one direction and
    # kind), leaving (Σ_t − S) x_t = c_t − c_l with Σ_t = R_tt − R_tf R_ff⁻¹ R_ft. (Forming R⁻¹
    # for a Woodbury update instead would lose the digits of the directions that only the ridge
    # holds, which plans that leave errors unseen have.)
    scale = _column_scale(system.normal)
    elimination = Elimination.of(
        system.line_part, system.own_columns(), system.size, scale, 0.0, ridge=RIDGE
    )
    # lines are grouped by the blocks (errors, effects) they touch; a group is condensed once on
    # the union of its lines' columns
    block_of = np.zeros(system.size, dtype=np.int64)
    for number, b in enumerate(system.blocks):
        block_of[b.columns] = number
    groups: dict[bytes, list[int]] = {}
    for index, block in enumerate(elimination.lines):
        signature = np.unique(block_of[elimination.glob[block.touched]]).tobytes()
        groups.setdefault(signature, []).append(index)
    residual = np.empty(len(readings))
    for members in groups.values():
        union = np.unique(np.concatenate([elimination.lines[i].touched for i in members]))
        sigma, c_t = _condensed(elimination, union)
        for index in members:
            _leave_out(system, elimination, index, union, sigma, c_t, residual)
    return _summarise("leave-one-line-out", residual, readings)


def _condensed(elimination: Elimination, touched: IntArray) -> tuple[FloatArray, FloatArray]:
    """The reduced system condensed on the columns ``touched`` (the others eliminated by
    Cholesky): Σ_t = R_tt − R_tf R_ff⁻¹ R_ft and c_t − R_tf R_ff⁻¹ c_f."""
    reduced, rhs = elimination.reduced, elimination.reduced_rhs
    free = np.setdiff1d(np.arange(reduced.shape[0]), touched)
    sigma = reduced[np.ix_(touched, touched)]
    c_t = rhs[touched]
    if free.size == 0:
        return sigma, c_t
    try:
        factor = cholesky(reduced[np.ix_(free, free)], lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        pinv = np.linalg.pinv(reduced[np.ix_(free, free)], hermitian=True)
        cross = reduced[np.ix_(free, touched)]
        return sigma - cross.T @ pinv @ cross, c_t - cross.T @ (pinv @ rhs[free])
    w = solve_triangular(factor, reduced[np.ix_(free, touched)], lower=True, check_finite=False)
    z = solve_triangular(factor, rhs[free], lower=True, check_finite=False)
    return sigma - w.T @ w, c_t - w.T @ z


def _leave_out(
    system: LinearSystem,
    elimination: Elimination,
    index: int,
    union: IntArray,
    sigma: FloatArray,
    c_t: FloatArray,
    residual: FloatArray,
) -> None:
    """The cross-validated residual of one line, from the system condensed on ``union`` (the
    columns it touches and perhaps others)."""
    scale = elimination.scale
    block = elimination.lines[index]
    touched = block.touched
    part = system.line_part(index)
    schur, rhs = line_schur(block, part, scale)
    global_part = ~np.isin(part.columns, block.columns)
    diagonal = np.diag(part.normal)[global_part] * scale[part.columns[global_part]] ** 2
    schur[np.diag_indices_from(schur)] += RIDGE * diagonal
    where = np.searchsorted(union, touched)
    matrix = sigma.copy()
    matrix[np.ix_(where, where)] -= schur
    right = c_t.copy()
    right[where] -= rhs
    without = _spd_solve(matrix, right)
    columns = elimination.glob[union]
    solution = np.zeros(system.size)
    solution[columns] = without * scale[columns]
    rows = system.line_readings(index)
    r = system.y[rows] - _apply_rows(system, rows, solution)
    if block.columns.size:
        local = _columns_at(system, rows, block.columns)
        w = np.sqrt(system.weights[rows])
        coef, *_ = np.linalg.lstsq(local * w[:, None], r * w, rcond=None)
        r = r - local @ coef
    residual[rows] = r


def _apply_rows(system: LinearSystem, rows: IntArray, solution: FloatArray) -> FloatArray:
    """A·x for the readings ``rows``."""
    p_t = system.target_design.shape[1]
    targets = system.target_of_reading[rows]
    out = system.target_design[targets] @ solution[:p_t]
    if system.effect_design.shape[1]:
        out = out + system.effect_design[rows] @ solution[p_t:]
    return np.asarray(out)


def _columns_at(system: LinearSystem, rows: IntArray, columns: IntArray) -> FloatArray:
    """Dense values of the design ``columns`` at the readings ``rows``."""
    p_t = system.target_design.shape[1]
    target = columns[columns < p_t]
    effect = columns[columns >= p_t] - p_t
    parts = []
    if target.size:
        parts.append(system.target_design[system.target_of_reading[rows]][:, target].toarray())
    if effect.size:
        parts.append(system.effect_design[np.ix_(rows, effect)])
    out = np.hstack(parts)
    # back to the order of ``columns``
    stacked = np.concatenate([np.flatnonzero(columns < p_t), np.flatnonzero(columns >= p_t)])
    order = np.argsort(stacked)
    return np.asarray(out[:, order])


#: Length of travel held out together in block cross-validation (a third of the default
#: 50 mm basis spacing, so every basis function keeps data on both sides).
BLOCK_MM = 15.0


def _cross_validate_blocks(
    system: LinearSystem, readings: Readings, folds: int = 5
) -> CrossValidation:
    """Held-out contiguous blocks of targets within every line (all lines stay in the fit).

    Blocks are short (the targets within ``BLOCK_MM`` of travel) and dealt to the folds in turn,
    shifted from line to line: a fold never empties a region of the stroke that only one line
    sees (which would leave local basis functions undetermined), while a structure spanning a
    block still has to be predicted from its neighbours and the other lines.

    Each fold is the minimum-norm (column-scaled) least-squares fit of the readings it keeps,
    solved line by line like identification.
    """
    residual = np.empty(len(readings))
    fold_of = np.zeros(len(readings), dtype=int)
    for index in range(len(readings.lines)):
        mask = readings.line == index
        block = np.floor(readings.target_mm[mask] / BLOCK_MM).astype(int)
        fold_of[mask] = (block + index) % folds
    own = system.own_columns()
    for k in range(folds):
        held = fold_of == k
        keep = ~held

        def part(index: int, keep: NDArray[np.bool_] = keep) -> LinePart:
            return system.line_part(index, keep)

        normal = np.zeros_like(system.normal)
        for index in range(system.lines):
            p = part(index)
            normal[np.ix_(p.columns, p.columns)] += p.normal
        scale = _column_scale(normal)
        limit = _rank_limit(normal, scale)
        del normal
        elimination = Elimination.of(part, own, system.size, scale, limit)
        null = elimination.null_space(limit)
        x = ConstrainedSystem.of(elimination, null.vectors).solve() * scale
        rows = np.flatnonzero(held)
        residual[held] = system.y[held] - _apply_rows(system, rows, x)
    return _summarise("held-out blocks of targets", residual, readings)


def _summarise(method: str, residual: FloatArray, readings: Readings) -> CrossValidation:
    angular = readings.is_angular
    disp = ~angular
    rms_um = float(np.sqrt(np.mean(residual[disp] ** 2))) if disp.any() else float("nan")
    rms_urad = float(np.sqrt(np.mean(residual[angular] ** 2))) if angular.any() else float("nan")
    per_line = {
        line.name: float(np.sqrt(np.mean(residual[readings.line == i] ** 2)))
        for i, line in enumerate(readings.lines)
    }
    return CrossValidation(method, rms_um, rms_urad, per_line, residual)


def residual_rms(identification: Identification) -> tuple[float, float]:
    """RMS residual (µm over displacement readings, µrad over angular readings)."""
    r = identification.residual
    angular = identification.readings.is_angular
    um = float(np.sqrt(np.mean(r[~angular] ** 2))) if (~angular).any() else float("nan")
    urad = float(np.sqrt(np.mean(r[angular] ** 2))) if angular.any() else float("nan")
    return um, urad


def parameters_report(
    identification: Identification, count: int = 41
) -> dict[str, dict[str, object]]:
    """The report.json ``parameters`` block: basis, coefficients and sampled values with std."""
    out: dict[str, dict[str, object]] = {}
    model = identification.model
    for eid in ERROR_IDS:
        positions, values, std = identification.band(eid, count=count)
        entry: dict[str, object] = {
            "unit": ERROR_INFO[eid].unit,
            "identified": identification.is_identified(eid),
            "position_mm": positions.tolist(),
            "value": values.tolist(),
            "std": std.tolist(),
        }
        if eid in SQUARENESS_IDS:
            entry["basis"] = {"kind": "constant"}
            entry["coefficients"] = [model.squareness_urad[eid]]
        else:
            f = model.functions[eid]
            entry["basis"] = f.basis.describe()
            entry["coefficients"] = f.coefficients.tolist()
        out[eid] = entry
    return out


__all__ = [
    "Identification",
    "IdentifyOptions",
    "UncertaintyBudget",
    "cross_validate",
    "identify",
    "parameters_report",
]
