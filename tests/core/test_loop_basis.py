"""The basis of the 21 errors is chosen by cross-validation (DESIGN: "Default basis … chosen by
cross-validation"), in the closed loop, once it has chosen the effects:

- where the noise dominates what bends between breakpoints, a coarser basis is kept and the 21
  errors come nearer the truth (a machine of the blind generator, tests/blind, written by
  someone who did not read the method);
- where the guideways bend at the default spacing's scale, the default is kept (the demo, with
  its reversal and screw cycle in the model);
- ``--spacing`` fixes it, and the project stores the spacing the errors were identified with;
- the report and the console say which spacing was kept and what each spacing tried scored.
"""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "independent"))

from score_blind import run_blind  # noqa: E402
from volucal.core.cli import main  # noqa: E402
from volucal.core.io.plan import import_plan, load_plan  # noqa: E402
from volucal.core.project import Project  # noqa: E402
from volucal.core.residuals import close_loop  # noqa: E402
from volucal.core.resources import demo_plan  # noqa: E402

ANGLES = {f"E{r}{a}" for r in "ABC" for a in "XYZ"}


def test_a_coarser_basis_is_kept_where_the_noise_dominates_and_the_errors_come_near_the_truth():
    # twelve-line plan, 0.47 µm of noise, no effect (blind 21101). With breakpoints every 50 mm
    # the functions followed the noise: EYY 0.40 µm and ECY 3.05 µrad from the truth, outside
    # issue 12's 0.35 µm / 2 µrad; the loop now keeps 150 mm (its error cross-validates lowest)
    outcome = run_blind(21101)
    assert outcome.kept == outcome.expected == set()
    assert outcome.basis_mm is not None and outcome.basis_mm > 50.0
    lengths = {k: v for k, v in outcome.function_error.items() if k not in ANGLES}
    angles = {k: v for k, v in outcome.function_error.items() if k in ANGLES}
    assert max(lengths.values()) <= 0.35, lengths  # µm
    assert max(angles.values()) <= 2.0, angles  # µrad
    assert max(outcome.squareness_error.values(), default=0.0) <= 2.0  # µrad
    assert outcome.band_ratio <= 3.0


def test_the_default_spacing_is_kept_where_a_coarser_one_predicts_worse() -> None:
    measurement = import_plan(load_plan(demo_plan())).measurement
    result = close_loop(measurement)
    basis = result.to_report()["basis"]
    assert basis["spacing_mm"] == 50.0
    assert basis["chosen_by"] == "cross-validation"
    tried = {t["spacing_mm"]: t for t in basis["tried"]}
    assert set(tried) >= {50.0, 75.0}
    assert tried[75.0]["cv_rms_all_lines"] > tried[50.0]["cv_rms_all_lines"]
    # the error rose at 75 mm: coarser spacings are not tried
    assert 150.0 not in tried
    assert {e.label.split()[0] for e in result.kept} == {"reversal", "cyclic"}


def test_the_spacing_can_be_fixed_and_the_project_stores_what_the_errors_used(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    report_path, project_path = tmp_path / "r.json", tmp_path / "p.h5"
    code = main(
        [
            "calibrate",
            str(demo_plan()),
            "--spacing",
            "100",
            "--report",
            str(report_path),
            "--project",
            str(project_path),
            "--no-sensitivity",
            "--quiet",
        ]
    )
    out = capsys.readouterr().out
    assert code == 0
    basis = json.loads(report_path.read_text())["basis"]
    assert (basis["spacing_mm"], basis["chosen_by"]) == (100.0, "set")
    assert "cubic B-splines every 100 mm, as set" in out
    project = Project.open(project_path)
    for name in ("main", "loop"):
        options = json.loads(str(project.result("identifications", name)["options_json"]))
        assert options["spacing_mm"] == 100.0, name


@pytest.mark.parametrize("value", ["0", "-5", "abc", "nan"])
def test_a_spacing_that_is_no_length_is_one_clear_error(
    value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["calibrate", str(demo_plan()), "--spacing", value])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "--spacing" in err and "Traceback" not in err


def test_a_shape_doubt_moves_to_the_chosen_basis_unchanged_where_both_bases_hold_it() -> None:
    # the loop's doubts on a surface's shape are moves of the 21 errors found at the effects'
    # spacing (gauged, as every fit is); once a coarser basis is kept they widen its covariance.
    # A move both bases hold (a gauged cubic along each stroke, a squareness) must arrive
    # unchanged; one the coarser basis cannot follow arrives as its nearest move within the
    # coarser gauge (zero at the reference position, a straightness with no least-squares
    # slope): not a move no fit of that basis could make. The nearest gauged move is solved
    # here from the gauge's constraints directly (Lagrange multipliers), not from its null space
    from volucal.core.errors import (
        AXIS_ERROR_IDS,
        ERROR_INFO,
        SQUARENESS_IDS,
        ErrorModel,
        gauge_constraints,
    )
    from volucal.core.errors import default_basis as basis
    from volucal.core.loop_end import STROKE_POINTS, in_basis
    from volucal.core.machine import PAPER_MACHINE

    fine = ErrorModel.zero(PAPER_MACHINE, lambda axis, _: basis(PAPER_MACHINE, axis, 50.0))
    coarse = ErrorModel.zero(PAPER_MACHINE, lambda axis, _: basis(PAPER_MACHINE, axis, 150.0))
    assert coarse.parameter_count < fine.parameter_count
    rng = np.random.default_rng(5)

    def nearest_gauged(model: ErrorModel, eid: str, q: np.ndarray, values: np.ndarray):  # type: ignore[no-untyped-def]
        # least squares of ``values`` at q in the function's basis under the gauge constraints
        f = model.functions[eid].basis
        axis = str(ERROR_INFO[eid].axis)
        rows = gauge_constraints(f, PAPER_MACHINE.reference(axis), ERROR_INFO[eid].is_straightness)
        design = f.design(q)
        n, m = design.shape[1], len(rows)
        kkt = np.block([[design.T @ design, rows.T], [rows, np.zeros((m, m))]])
        right = np.concatenate([design.T @ values, np.zeros(m)])
        return np.linalg.solve(kkt, right)[:n]

    def gauged_cubic(eid: str, q: np.ndarray) -> np.ndarray:
        # a random cubic less the constant and the line (both bases hold all three) that put
        # it in the gauge: fine-basis coefficients
        f = fine.functions[eid].basis
        axis = str(ERROR_INFO[eid].axis)
        reference = PAPER_MACHINE.reference(axis)
        rows = gauge_constraints(f, reference, ERROR_INFO[eid].is_straightness)
        low, high = PAPER_MACHINE.stroke(axis)
        exact = [np.polyval(rng.normal(size=4), (q - low) / (high - low)), np.ones_like(q), q]
        cubic, *gauges = (np.linalg.lstsq(f.design(q), v, rcond=None)[0] for v in exact)
        gauges = np.stack(gauges[: len(rows)], axis=1)
        return cubic - gauges @ np.linalg.solve(rows @ gauges, rows @ cubic)

    for wiggle in (0.0, 1.0):
        move = np.zeros(fine.parameter_count)
        for eid in AXIS_ERROR_IDS:
            low, high = PAPER_MACHINE.stroke(str(ERROR_INFO[eid].axis))
            q = np.linspace(low, high, 57)
            cubic = gauged_cubic(eid, q)
            shape = fine.functions[eid].basis.design(q) @ cubic
            shape += wiggle * np.sin(2 * np.pi * q / 60.0 + rng.uniform(0, 2 * np.pi))
            move[fine.parameter_slices[eid]] = nearest_gauged(fine, eid, q, shape)
        for eid in SQUARENESS_IDS:
            move[fine.parameter_slices[eid]] = rng.normal()
        moved = in_basis(move[None, :], fine, coarse)[0]
        for eid in AXIS_ERROR_IDS:
            low, high = PAPER_MACHINE.stroke(str(ERROR_INFO[eid].axis))
            q = np.linspace(low, high, STROKE_POINTS)
            change = fine.functions[eid].basis.design(q) @ move[fine.parameter_slices[eid]]
            expected = nearest_gauged(coarse, eid, q, change)
            got = moved[coarse.parameter_slices[eid]]
            assert got == pytest.approx(expected, abs=1e-9), eid
            if wiggle == 0.0:  # a gauged cubic: both bases hold it, it arrives unchanged
                values = coarse.functions[eid].basis.design(q) @ got
                assert values == pytest.approx(change, abs=1e-9), eid
        for eid in SQUARENESS_IDS:
            assert moved[coarse.parameter_slices[eid]] == pytest.approx(
                move[fine.parameter_slices[eid]]
            )


def test_a_coarser_basis_that_leaves_a_bend_the_runs_agree_on_is_refused_and_said(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # clean machine, plan preset, 0.31 µm noise (blind 22053): 150 mm predicts the held-out
    # readings best, but leaves a line a systematic residual that 50 mm explains (its errors
    # were 9.9 times their stated uncertainty); 100 mm leaves none and is kept
    from tests.blind.scenarios import write_scenario

    plan, _ = write_scenario(22053, tmp_path)
    report_path = tmp_path / "r.json"
    code = main(["calibrate", str(plan), "--report", str(report_path), "--no-sensitivity"])
    out = capsys.readouterr().out
    assert code == 0
    report = json.loads(report_path.read_text())
    assert report["effects"] == [] and report["unexplained"] == []
    basis = report["basis"]
    tried = {t["spacing_mm"]: t for t in basis["tried"]}
    assert tried[150.0]["cv_rms_all_lines"] < tried[100.0]["cv_rms_all_lines"]
    assert tried[150.0]["leaves_structure_on"]
    assert basis["spacing_mm"] == 100.0
    assert "150 mm refused: it leaves a systematic residual on" in out
    # each spacing's figures are over the readings it and the identification's own spacing
    # both predict, not the loop table's (those the fits before and after the loop predict):
    # the console says which
    assert basis["reference_spacing_mm"] == 50.0
    assert "over the readings each and the 50 mm basis both predict" in out
