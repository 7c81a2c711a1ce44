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
column-scaled normal matrix's spectrum.

Dense plans (hundreds of lines): the system is stored by line (core/identify_system.py), each
line's own offset, slope and set-up effects are eliminated line by line, and everything is solved
on the reduced system of the errors' columns (core/identify_blocks.py): time grows linearly with
the lines and memory with the unknowns, never with lines × unknowns².
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from .cross_validation import BLOCK_MM, CrossValidation, cross_validate
from .errors import (
    AXIS_ERROR_IDS,
    ERROR_IDS,
    ERROR_INFO,
    SQUARENESS_IDS,
    Basis,
    BSplineBasis,
    ErrorModel,
)
from .identify_blocks import ConstrainedSystem, Elimination, NullSpace, largest_leverage, line_schur
from .identify_system import (
    RANK_TOLERANCE,
    SHARE_NAMED,
    SHARED_SEEN,
    ColumnBlock,
    EffectTerm,
    Gauge,
    GeometricDesign,
    LinearSystem,
    Reduction,
    SharedPart,
    build_system,
    column_scale,
    eliminate,
    expand_pair,
    predict_geometric,
    rank_limit,
    unique_targets,
    without_effects,
)
from .machine import Machine
from .measurement import Measurement
from .progress import CancelToken, ProgressCallback, check, report
from .readings import Readings, flatten
from .userror import UserError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


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

    @property
    def unidentifiable_ids(self) -> list[str]:
        """The errors the plan leaves (partly) undetermined, sorted."""
        return sorted({i for u in self.unidentifiable for i in u.ids})

    def to_json(self) -> dict[str, object]:
        return {
            "rank": self.rank,
            "unknowns": self.unknowns,
            "unidentifiable": [u.message for u in self.unidentifiable],
            "unidentifiable_ids": self.unidentifiable_ids,
            "redundant_lines": list(self.redundant_lines),
        }


@dataclass(frozen=True, eq=False)
class Identification:
    """The identified model and everything needed to judge it."""

    model: ErrorModel
    covariance: FloatArray  # (P, P) over model.parameters (statistical; a loop adds shape doubt)
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
# What the plan separates: effects' directions, the identifiable subspace
# --------------------------------------------------------------------------------------------


#: An effect direction is fitted only where more than this share of its signal (column-scaled)
#: is not also a combination of the 21 errors and the lines' nuisances: what the plan cannot tell
#: apart from a rigid body at all stays with the rigid body (a sag's bilinear part that a roll
#: produces as well stays a roll) instead of being split between them by a minimum norm.
SEPARABILITY = 1e-6


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
    scale = column_scale(system.normal)
    limit = rank_limit(system.normal[:rigid, :rigid], scale[:rigid])
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
    shared: list[SharedPart] = []
    start = rigid
    carriers = _error_names(system, elimination.glob[errors])
    for position, block in enumerate(effects):
        columns = np.arange(block.columns.start, block.columns.stop)
        local = columns - rigid
        s_values, s_vectors = np.linalg.eigh(schur_all[np.ix_(local, local)])
        kept = s_vectors[:, s_values > SEPARABILITY] * scale[columns][:, None]
        pieces.append((columns, kept))
        blocks.append(replace(block, columns=slice(start, start + kept.shape[1])))
        start += kept.shape[1]
        for w in s_vectors[:, s_values <= SEPARABILITY].T:
            # the errors' change that reproduces the direction's readings
            along = projected[:, local] @ w
            if float(along @ (along / values)) <= SHARED_SEEN:
                continue  # not seen at all (or only by the lines' zeros and slopes)
            change = (vectors @ (along / values)) * scale[elimination.glob[errors]]
            shares = {
                name: float(np.linalg.norm(change[positions]))
                for name, positions in carriers.items()
            }
            largest = max(shares.values())
            names = sorted(
                (n for n, v in shares.items() if v >= SHARE_NAMED * largest),
                key=lambda n: -shares[n],
            )
            shared.append(SharedPart(position, w, tuple(names)))
    matrix = np.zeros((system.size, start))
    matrix[:rigid, :rigid] = np.eye(rigid)
    for (columns, kept), block in zip(pieces, blocks, strict=True):
        matrix[columns, block.columns] = kept
    return Reduction(matrix, tuple(blocks), tuple(shared))


def _error_names(system: LinearSystem, glob: IntArray) -> dict[str, IntArray]:
    """Per error id, the positions in ``glob`` (global columns) of its columns."""
    out = {}
    for block in system.blocks:
        if block.kind == "error":
            inside = (glob >= block.columns.start) & (glob < block.columns.stop)
            if np.any(inside):
                out[block.key] = np.flatnonzero(inside)
    return out


@dataclass(frozen=True, eq=False)
class _Subspace:
    """The identifiable subspace of a system, fixed in the column scaling of its first
    linearisation: the complement (in scaled coordinates) of its null space."""

    scale: FloatArray
    null: NullSpace  # in the scaled coordinates of ``scale``
    rank: int

    @classmethod
    def of(cls, system: LinearSystem) -> _Subspace:
        elimination, limit = eliminate(system)
        null = elimination.null_space(limit)
        return cls(elimination.scale, null.held_on_errors(), system.size - null.dimensions)

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


def model_with_bases(machine: Machine, options: IdentifyOptions) -> ErrorModel:
    """A zero model with the bases identification uses."""

    def basis_for(axis: str, eid: str) -> Basis:
        if eid in options.basis:
            return options.basis[eid]
        low, high = machine.stroke(axis)
        return BSplineBasis.uniform(low, high, options.spacing_mm)

    return ErrorModel.zero(machine, basis_for)


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
    elimination, limit = eliminate(system)
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
    targets = unique_targets(readings)
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
    reduced: LinearSystem | None = None
    max_iterations = options.max_iterations if options.refine else 1
    noise = float(np.median(readings.sigma))
    for iterations in range(1, max_iterations + 1):
        check(cancel)
        report(
            progress, 0.1 + 0.7 * (iterations - 1) / max_iterations, f"linear solve {iterations}"
        )
        current = model.with_parameters(gauge.matrix @ theta)
        # the previous linearisation is not needed any more: free it before building the next
        system = reduced = None
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
                without_effects(structural),
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
    # what was kept for the solves is not part of the result
    system.unseen = (subspace.scale, subspace.null.vectors)
    system._parts = None
    system._eliminations.clear()
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
        normal_inverse = expand_pair(normal_inverse, reduction.matrix, rigid)
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
# Reports
# --------------------------------------------------------------------------------------------


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
    "BLOCK_MM",
    "ColumnBlock",
    "CrossValidation",
    "EffectTerm",
    "Gauge",
    "LinearSystem",
    "RANK_TOLERANCE",
    "cross_validate",
    "identify",
    "parameters_report",
]
