"""Identification line by line (issues 14 and 17) against a straightforward dense reference.

Identification never forms anything of size lines × unknowns²: the design is stored sparse by
line, each line's own columns are eliminated line by line, and leave-one-line-out fits downdate
the reduced system. Here every piece is checked against the textbook dense computation on small
plans (the explicit design matrix, AᵀWA, its column-scaled eigen-decomposition), leave-one-line-out
against refitting without the line, and the storage against linear growth in the lines.
"""

from __future__ import annotations

import numpy as np
import pytest
from volucal.core import effects as fx
from volucal.core import plans
from volucal.core.cross_validation import RIDGE
from volucal.core.identify import (
    RANK_TOLERANCE,
    SEPARABILITY,
    Gauge,
    IdentifyOptions,
    cross_validate,
    identify,
    separable_reduction,
)
from volucal.core.identify_system import column_scale, eliminate
from volucal.core.machine import AXES, AXIS_INDEX, PAPER_MACHINE
from volucal.core.measurement import LineSpec, Measurement
from volucal.core.plans import PlannedLine
from volucal.core.readings import flatten
from volucal.core.simulate import (
    CyclicError,
    LaserSetup,
    Reversal,
    VirtualMachine,
    random_truth,
)

# --------------------------------------------------------------------------------------------
# The dense reference: explicit A, AᵀWA and its column-scaled eigen-decomposition
# --------------------------------------------------------------------------------------------


def _dense_normal(system):  # type: ignore[no-untyped-def]
    a = system.design_rows()
    w = system.weights
    return a, (a * w[:, None]).T @ a, (a * w[:, None]).T @ system.y


def _scaled_eigen(normal):  # type: ignore[no-untyped-def]
    scale = column_scale(normal)
    values, vectors = np.linalg.eigh(normal * scale[:, None] * scale[None, :])
    limit = RANK_TOLERANCE * max(values.max(), 1e-300)
    return scale, values, vectors, limit


def _dense_restricted(normal, rhs, own=()):  # type: ignore[no-untyped-def]
    """The solution and (AᵀWA)⁺ restricted to a complement of what the scaled normal matrix does
    not see: on the global columns, the unseen directions' parts are held at zero, the lines'
    ``own`` columns (offsets, slopes) left free to take what they can; an unseen direction with
    no global part (a line's own columns no reading tells apart) is held at zero."""
    scale, values, vectors, limit = _scaled_eigen(normal)
    null = vectors[:, values <= limit]
    is_own = np.zeros(len(normal), dtype=bool)
    is_own[np.asarray(own, dtype=np.int64)] = True
    _, singular, vt = np.linalg.svd(null[~is_own], full_matrices=True)
    rank = int(np.sum(singular > 1e-9))
    on_errors = null @ vt[:rank].T
    on_errors[is_own] = 0.0
    held = np.hstack([on_errors, null @ vt[rank:].T])
    q, _ = np.linalg.qr(held, mode="complete")
    t = q[:, held.shape[1] :] * scale[:, None]
    reduced = t.T @ normal @ t
    return t @ np.linalg.solve(reduced, t.T @ rhs), t @ np.linalg.inv(reduced) @ t.T


def _projector(basis):  # type: ignore[no-untyped-def]
    q, _ = np.linalg.qr(basis)
    return q @ q.T


def _measure(layout: str, seed: int, effects=(), step: float = 12.0):  # type: ignore[no-untyped-def]
    truth = random_truth(seed=seed)
    vm = VirtualMachine(truth, effects, seed=seed, laser=LaserSetup(noise_um=0.1, noise_urad=0.1))
    return vm.measure(plans.layout(layout, truth.machine, step))


def _relative(a, b) -> float:  # type: ignore[no-untyped-def]
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / np.max(np.abs(b)))


# --------------------------------------------------------------------------------------------
# The system and the solve
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("layout", ["direct", "nine-line", "full"])
def test_line_parts_add_up_to_the_dense_normal_equations(layout: str) -> None:
    measurement = _measure(layout, seed=31)
    result = identify(measurement, IdentifyOptions(refine=False, redundancy=False))
    system = result.system
    _, normal, rhs = _dense_normal(system)
    assert _relative(system.normal, normal) < 1e-12
    assert _relative(system.rhs, rhs) < 1e-12
    # every line's part lives on the columns its rows touch, and nothing else
    for index in range(system.lines):
        part = system.line_part(index)
        rows = system.design_rows(measurement_line_mask(result, index))
        touched = np.flatnonzero(np.any(rows != 0.0, axis=0))
        assert set(touched) <= set(part.columns)


def measurement_line_mask(result, index: int):  # type: ignore[no-untyped-def]
    return result.readings.line == index


@pytest.mark.parametrize("layout", ["direct", "nine-line", "twelve-line"])
def test_restricted_solution_and_inverse_equal_the_dense_eigen_solution(layout: str) -> None:
    """One linear solve at zero errors: the solution and (AᵀWA)⁺ on the identifiable subspace
    (nine-line and twelve-line leave many directions unseen) equal the dense computation, with
    what the plan cannot see held out of the errors (the lines' offsets and slopes take it)."""
    measurement = _measure(layout, seed=32)
    result = identify(measurement, IdentifyOptions(refine=False, redundancy=False))
    system = result.system
    a, normal, rhs = _dense_normal(system)
    x, inverse = _dense_restricted(normal, rhs, np.concatenate(system.own_columns()))
    gauge = Gauge.for_model(result.model)
    assert _relative(result.model.parameters, gauge.matrix @ x[: gauge.size]) < 1e-7
    assert _relative(result.residual, system.y - a @ x) < 1e-7
    assert _relative(result.normal_inverse, inverse) < 1e-7
    assert result.fitted_rank == int(np.linalg.matrix_rank(a * np.sqrt(system.weights)[:, None]))


def test_rank_null_space_and_redundant_lines_equal_the_dense_tests() -> None:
    measurement = _measure("direct", seed=33)
    result = identify(measurement, IdentifyOptions(refine=False))
    system = result.system
    _, normal, _ = _dense_normal(system)
    scale, values, vectors, limit = _scaled_eigen(normal)
    assert result.identifiability.rank == int(np.sum(values > limit))
    elimination, limit_blocks = eliminate(system)
    null = elimination.null_space(limit_blocks).orthonormal()
    dense_null = vectors[:, values <= limit]
    assert null.shape == dense_null.shape
    assert np.allclose(_projector(null), _projector(dense_null), atol=1e-8)
    # a line is redundant when the dense normal matrix without it keeps the other columns' rank
    redundant = []
    for index, line in enumerate(measurement.lines):
        own = system.line_columns(index)
        keep = np.setdiff1d(np.arange(system.size), own)
        mask = result.readings.line != index
        rows = system.design_rows(mask)
        without = (rows * system.weights[mask, None]).T @ rows
        m = (without * scale[:, None] * scale[None, :])[np.ix_(keep, keep)]
        if int(np.sum(np.linalg.eigvalsh(m) > limit)) == result.identifiability.rank - own.size:
            redundant.append(line.name)
    assert redundant and len(redundant) < len(measurement.lines)
    assert list(result.identifiability.redundant_lines) == redundant


def test_effects_reduced_to_their_separable_directions_as_the_dense_schur_complement() -> None:
    """Machine effects and set-up effects: a cosine error on a straightness line is the line's
    alignment slope (nothing separable); on one of four parallel linear lines, a reversal and a
    cycle are separable."""
    measurement = _measure(
        "full", seed=34, effects=(Reversal("X", 3.0), CyclicError("Y", 1.0, 16.0, 0.3))
    )
    names = [line.name for line in measurement.lines]
    far, straight = names.index("x_linear_far"), names.index("y_straight_x")
    effects = [
        fx.Reversal(axis_name="X", stroke_mm=(0.0, 400.0)),
        fx.Cyclic(axis_name="Y", period_mm=16.0),
        fx.Cosine(line=far, line_name=names[far]),
        fx.Cosine(line=straight, line_name=names[straight]),
    ]
    result = identify(
        measurement, IdentifyOptions(refine=False, redundancy=False), effects=effects
    )
    system = result.system
    _, normal, rhs = _dense_normal(system)
    reduction = separable_reduction(system)
    assert reduction is not None
    # dense: per effect, the Schur complement of its scaled columns against the rigid ones
    rigid = system.target_design.shape[1]
    scale = column_scale(normal)
    scaled = normal * scale[:, None] * scale[None, :]
    values, vectors = np.linalg.eigh(scaled[:rigid, :rigid])
    seen = values > RANK_TOLERANCE * values.max()
    vectors, values = vectors[:, seen], values[seen]
    widths = []
    for block, reduced_block in zip(
        [b for b in system.blocks if b.kind == "effect"], reduction.blocks, strict=True
    ):
        cols = np.arange(block.columns.start, block.columns.stop)
        projected = vectors.T @ scaled[:rigid, cols]
        schur = scaled[np.ix_(cols, cols)] - projected.T @ (projected / values[:, None])
        s_values, s_vectors = np.linalg.eigh(schur)
        kept = s_vectors[:, s_values > SEPARABILITY] * scale[cols][:, None]
        mine = reduction.matrix[cols, reduced_block.columns]
        assert kept.shape == mine.shape
        if kept.size:
            assert np.allclose(_projector(kept), _projector(mine), atol=1e-9)
        widths.append(kept.shape[1])
    assert widths == [1, 2, 1, 0]
    # and the fit in the reduced unknowns equals the dense one
    r = reduction.matrix
    _, values, _, limit = _scaled_eigen(r.T @ normal @ r)
    assert np.all(values > limit)  # the full plan sees everything: no gauge to choose
    x, inverse = _dense_restricted(r.T @ normal @ r, r.T @ rhs)
    assert _relative(result.residual, system.y - system.design_rows() @ (r @ x)) < 1e-7
    assert _relative(result.normal_inverse, r @ inverse @ r.T) < 1e-7


class _LeakyScale:
    """An effect declared to act on line 0 whose design also moves line 1: it cannot be
    eliminated with line 0's own columns and must stay a column of the whole system."""

    label = "scale of lines 0 and 1"
    line_index = 0

    def design(self, readings, model):  # type: ignore[no-untyped-def]
        return np.where(readings.line <= 1, readings.target_mm * 1e-3, 0.0)[:, None]


def test_an_effect_reaching_other_lines_stays_global() -> None:
    measurement = _measure("full", seed=38)
    result = identify(
        measurement, IdentifyOptions(refine=False, redundancy=False), effects=[_LeakyScale()]
    )
    system = result.system.reduced()
    assert all(c.size <= 2 for c in system.own_columns())  # offsets and slopes only
    a, normal, rhs = _dense_normal(system)
    x, _ = _dense_restricted(normal, rhs, np.concatenate(system.own_columns()))
    assert _relative(result.residual, system.y - a @ x) < 1e-7


# --------------------------------------------------------------------------------------------
# Cross-validation
# --------------------------------------------------------------------------------------------


def test_leave_one_line_out_equals_refitting_without_the_line() -> None:
    """The downdated fit predicts a line as a fit of the other lines does (one linear solve at
    zero errors, so that both linearise at the same point), after its own offset and slope are
    fitted to what is left."""
    measurement = _measure("full", seed=35)
    readings = flatten(measurement)
    options = IdentifyOptions(refine=False)
    result = identify(measurement, options, readings=readings)
    assert len(result.identifiability.redundant_lines) == len(measurement.lines)
    cv = cross_validate(result.system, readings, result.identifiability.redundant_lines)
    assert cv.method == "leave-one-line-out"
    system = result.system
    gauge = Gauge.for_model(result.model)
    for name in ("x_linear", "y_straight_x", "z_angle_y", "diag_xy_pp_b", "body_ppp"):
        index = readings.line_names.index(name)
        others = Measurement(
            measurement.machine, tuple(l for l in measurement.lines if l.name != name)
        )
        refit = identify(others, IdentifyOptions(refine=False, redundancy=False))
        theta = gauge.matrix.T @ refit.model.parameters
        mask = readings.line == index
        rows = system.design_rows(mask)
        r = system.y[mask] - rows[:, : gauge.size] @ theta
        own = rows[:, system.line_columns(index)]
        w = np.sqrt(system.weights[mask])
        coef, *_ = np.linalg.lstsq(own * w[:, None], r * w, rcond=None)
        expected = r - own @ coef
        # the refit has no ridge; RIDGE moves well-seen directions by ~RIDGE·condition
        assert np.max(np.abs(cv.residual[mask] - expected)) < 1e-4, name
        assert np.max(np.abs(expected)) > 0.05  # the line's noise, not nothing


def test_leave_one_line_out_equals_the_dense_ridged_solve() -> None:
    """Every line of the demo-like plan: the downdated solve equals solving the dense normal
    equations without the line (ridge RIDGE on the scaled diagonal), as the definition reads."""
    measurement = _measure("full", seed=36, effects=(Reversal("X", 3.0),))
    readings = flatten(measurement)
    result = identify(
        measurement,
        IdentifyOptions(redundancy=False, max_iterations=1),
        effects=[fx.Reversal(axis_name="X", stroke_mm=(0.0, 400.0))],
        readings=readings,
    )
    system = result.system.reduced()
    cv = cross_validate(result.system, readings)
    a, normal, rhs = _dense_normal(system)
    for index in range(system.lines):
        own = system.line_columns(index)
        keep = np.setdiff1d(np.arange(system.size), own)
        mask = readings.line == index
        rows = a[mask]
        m = normal - (rows * system.weights[mask, None]).T @ rows
        b = rhs - (rows * system.weights[mask, None]).T @ system.y[mask]
        m, b = m[np.ix_(keep, keep)], b[keep]
        scale = column_scale(m)
        scaled = m * scale[:, None] * scale[None, :] + RIDGE * np.eye(keep.size)
        x = np.zeros(system.size)
        x[keep] = np.linalg.solve(scaled, b * scale) * scale
        r = system.y[mask] - rows @ x
        w = np.sqrt(system.weights[mask])
        coef, *_ = np.linalg.lstsq(rows[:, own] * w[:, None], r * w, rcond=None)
        expected = r - rows[:, own] @ coef
        assert np.max(np.abs(cv.residual[mask] - expected)) < 1e-7 * max(
            1.0, float(np.max(np.abs(expected)))
        ), index


# --------------------------------------------------------------------------------------------
# Storage grows with the lines, not with lines × unknowns²
# --------------------------------------------------------------------------------------------


def _grid(count: int) -> Measurement:
    """``count`` axis-parallel linear and straightness lines along X and Y across a plane."""
    machine = PAPER_MACHINE
    lines = []
    per_axis = count // 4
    for axis, across in (("X", "Y"), ("Y", "X")):
        u = tuple(float(a == axis) for a in AXES)
        v = tuple(float(a == across) for a in AXES)
        for k, fixed in enumerate(np.linspace(0.0, 400.0, per_axis)):
            start = [0.0, 0.0, 100.0]
            start[AXIS_INDEX[across]] = float(fixed)
            for quantity in ("linear", "straightness"):
                spec = LineSpec(
                    name=f"{axis}{k}{quantity[0]}",
                    quantity=quantity,
                    start_mm=tuple(start),  # type: ignore[arg-type]
                    direction=u,  # type: ignore[arg-type]
                    reflector_mm=machine.tool_offset_mm,
                    sensitive=v if quantity == "straightness" else None,  # type: ignore[arg-type]
                )
                lines.append(PlannedLine(spec, plans.targets(400.0, 20.0)))
    vm = VirtualMachine(random_truth(seed=37), seed=37, laser=LaserSetup(runs_per_direction=1))
    return vm.measure(lines)


def test_storage_by_line_grows_linearly_with_the_lines() -> None:
    """Doubling the lines doubles what the system stores by line (sparse design rows and each
    line's part on the columns it touches); the old per-line dense normal matrices (lines ×
    unknowns², which issue 17 measured at 12 GB for 1,000 lines) would grow more than threefold
    here, the unknowns growing with the lines' offsets and slopes."""
    small, large = (
        identify(_grid(count), IdentifyOptions(refine=False, redundancy=False)).system
        for count in (40, 80)
    )
    ratio = large.stored_nbytes()["lines"] / small.stored_nbytes()["lines"]
    assert 1.9 < ratio < 2.1, ratio
    assert large.lines * large.size**2 > 3 * small.lines * small.size**2
    # a line's part is as large as the columns it touches, whatever the number of lines
    widths = [
        [system.line_part(i).columns.size for i in range(system.lines)] for system in (small, large)
    ]
    assert max(widths[0]) == max(widths[1]) < small.size / 2
    # nothing the system holds is larger than the normal matrix or the per-line storage
    for system in (small, large):
        held = [v for v in vars(system).values() if isinstance(v, np.ndarray)]
        held += [system.target_design.data, system.target_design.indices]
        assert max(v.nbytes for v in held) <= max(
            system.size**2 * 8, system.stored_nbytes()["lines"]
        )
