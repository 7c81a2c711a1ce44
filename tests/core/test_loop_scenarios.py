"""The closed loop on 20 machines it was not tuned to: a subset of benchmarks/bench_loop_suite.py.

Each scenario comes from tests/independent (its own error shapes, effects, laser and Renishaw-style
files; nothing of core/simulate.py or core/effects.py), is written to files, imported by volucal and
run through ``close_loop`` with the shipped defaults. Seeds 100–119 were not looked at while the
loop was developed: 5 clean machines, 10 with one to three catalogue effects, 5 with an effect
outside every catalogue.
"""

import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "independent"))

from loop_scenarios import (  # noqa: E402
    Outcome,
    effect_place,
    make_scenario,
    measure,
    on_line,
    run_scenario,
    write_session,
)

CATEGORIES = {
    **dict.fromkeys(range(100, 105), "clean"),
    **dict.fromkeys(range(105, 115), "effects"),
    **dict.fromkeys(range(115, 120), "outside"),
}


@pytest.fixture(scope="module")
def outcomes() -> dict[int, Outcome]:
    return {
        seed: run_scenario(make_scenario(seed, category)) for seed, category in CATEGORIES.items()
    }


def _of(outcomes: dict[int, Outcome], category: str) -> list[Outcome]:
    return [o for o in outcomes.values() if o.category == category]


def test_clean_machines_get_no_effect(outcomes) -> None:
    kept = {o.seed: o.kept for o in _of(outcomes, "clean") if o.kept}
    assert not kept


def test_every_visible_effect_is_found_or_reported(outcomes) -> None:
    """Visible: what the 21 errors leave of the effect reaches 4× the noise on some line. The loop
    refuses a drift, a defect or a surface that only one line shows beyond what the 21 errors
    absorb (one line cannot tell it from its own set-up), so a miss is allowed once in the ten
    (the suite measures 96 % right on what is visible), and never silently: what it leaves is
    reported as unexplained."""
    missed = {
        o.seed: sorted(o.visible_expected - o.kept)
        for o in _of(outcomes, "effects")
        if o.visible_expected - o.kept
    }
    assert len(missed) <= 1, missed
    assert all(outcomes[seed].unexplained > 0 for seed in missed), missed


def test_effects_that_are_not_there_are_not_kept(outcomes) -> None:
    """At most one scenario in 20 (5 %) keeps an effect it does not carry."""
    false = {o.seed: sorted(o.kept - o.expected) for o in outcomes.values() if o.kept - o.expected}
    assert len(false) <= 1, false


def test_effects_outside_the_catalogue_are_reported_and_not_fitted(outcomes) -> None:
    outside = _of(outcomes, "outside")
    assert all(o.unexplained > 0 for o in outside)
    assert not {o.seed: o.kept for o in outside if o.kept}


def test_no_kept_effect_has_implausible_parameters(outcomes) -> None:
    assert not {o.seed: o.implausible for o in outcomes.values() if o.implausible}


def test_errors_match_the_truth_where_the_effect_set_is_right(outcomes) -> None:
    """Every identified function within 0.35 µm / 2 µrad of the truth (RMS over the stroke,
    gauges removed) and squareness within 2 µrad (issue 12), and within 4 of its own stated
    standard uncertainty (RMS ratio): the bands are honest."""
    exact = [o for o in outcomes.values() if o.exact and o.category != "outside"]
    assert len(exact) >= 6
    for o in exact:
        lengths = {k: v for k, v in o.function_error.items() if k[1] in "XYZ"}
        angles = {k: v for k, v in o.function_error.items() if k[1] in "ABC"}
        assert max(lengths.values()) <= 0.35, (o.seed, lengths)
        assert max(angles.values()) <= 2.0, (o.seed, angles)
        assert max(o.squareness_error.values(), default=0.0) <= 2.0, (o.seed, o.squareness_error)
        assert o.band_ratio <= 4.0, (o.seed, o.band_ratio)


def test_a_reflector_twitch_on_a_twelve_line_plan_is_not_kept_as_a_finer_function() -> None:
    """Seed 2000078 (a force-fit of the suite's block 2000000): reflector mounts that twitch on
    x_lin_3 and y_lin_2 of the twelve-line plan, every line of which is needed to identify the 21
    errors. A finer pitch of X took x_lin_3's twitch and the chain carried it to the other X
    lines, which showed it but were predicted worse with it where held out: it is not the
    machine's, and x_lin_3 is reported unexplained."""
    outcome = run_scenario(make_scenario(2000078))
    assert outcome.category == "outside" and outcome.plan == "twelve-line"
    assert outcome.kept == set(), outcome.kept
    assert any("x_lin_3" in where for where in outcome.unexplained_where), outcome.unexplained_where


def test_two_set_up_errors_that_hide_each_other_are_kept_together() -> None:
    """Seed 3300056 (block 3300000, demo plan, 0.08 µm noise): cosine errors of 7.5 and 9.4 ppm
    on body_pmp and diag_xy_pm_b beside a bump of Y. The 21 errors share each line's error
    between both: either cosine alone predicted the held-out lines no better, nothing was kept
    and 35 lines were reported. Held with the first, the second shows whole; together they
    predict the held-out lines 69 % better and the bump is found after them."""
    scenario = make_scenario(3300056)
    outcome = run_scenario(scenario)
    assert outcome.category == "effects"
    assert outcome.kept == outcome.expected, (outcome.kept, outcome.expected)
    assert outcome.unexplained == 0
    # a beam misaligned by θ reads every length short by 1 − cos θ
    truth = {
        s.line: 1e6 * (1.0 - np.cos(1e-6 * s.parameters["angle_urad"])) for s in scenario.setups
    }
    found = {
        e["parameters"]["line"]: -e["parameters"]["scale_ppm"]
        for e in outcome.effects_report
        if e["kind"] == "cosine"
    }
    assert found.keys() == truth.keys()
    for line, ppm in truth.items():
        assert found[line] == pytest.approx(ppm, abs=0.1), (line, found[line], ppm)


def test_a_first_lines_cosine_error_beside_a_drift_is_refitted_once_the_drift_is_kept() -> None:
    """Seed 3700091 (block 3700000, demo plan, 0.20 µm noise): a 3452 µrad cosine error of
    x_linear, the session's first line, beside a drift of X (12.1 ppm, τ 148 min) and a reversal
    of Z. Without the drift the cosine fitted 5856 µrad, past what alignment allows; with the
    drift kept, its τ fitted long enough to take part of the cosine, the diagnosis no longer
    found the cosine significant and it was never refitted. Refitted as owed, it is kept and the
    drift's τ moves back; the backward pass may not take the drift out, for without it the
    cosine is implausible again."""
    scenario = make_scenario(3700091)
    outcome = run_scenario(scenario)
    assert outcome.kept == outcome.expected, (outcome.kept, outcome.expected)
    assert outcome.unexplained == 0
    (setup,) = scenario.setups
    injected = 1e6 * (1.0 - np.cos(1e-6 * setup.parameters["angle_urad"]))
    (cosine,) = [e for e in outcome.effects_report if e["kind"] == "cosine"]
    p = cosine["parameters"]
    assert abs(-p["scale_ppm"] - injected) <= 3 * p["scale_std_ppm"], (p, injected)


def _loop_report(scenario) -> dict:  # type: ignore[no-untyped-def]
    """``close_loop``'s report.json on the scenario's files, as volucal imports them."""
    from volucal.core.io.plan import import_plan, load_plan
    from volucal.core.residuals import close_loop

    info, measured = measure(scenario, scenario.seed)
    with tempfile.TemporaryDirectory(prefix="volucal-scenario-") as tmp:
        measurement = import_plan(load_plan(write_session(Path(tmp), info, measured))).measurement
    return close_loop(measurement).to_report()


def test_an_effect_the_audit_took_out_does_not_win_the_same_step_again() -> None:
    """Seed 5000152 (block 5000000, demo plan): a 2.9 µm cycle of Y and a drift of Y (12.4 ppm,
    τ 199 min). Once the cycle was kept, a cosine error of y_linear, the session's first Y line,
    tied the drift (0.0994 µm against 0.0990 µm held out) and was kept for its one parameter;
    the audit took it out, y_linear still drifting in time, and the round after it, starting
    from the same model, kept the cosine again to take it out again: the drift was lost and four
    lines reported. The taken-out cosine now waits until another effect is kept: the drift is,
    and the cosine, tried beside it, is refused."""
    scenario = make_scenario(5000152)
    report = _loop_report(scenario)
    assert scenario.expected == {("cyclic", "Y"), ("thermal_drift", "Y")}
    assert {effect_place(e) for e in report["effects"]} == scenario.expected
    assert report["unexplained"] == []
    cosine = [s for s in report["loop"] if s["effect"]["kind"] == "cosine"]
    verdicts = [(s["stage"], s["verdict"]) for s in cosine]
    assert [v for v in verdicts if v[1] in ("kept", "taken out")] == [
        ("forward", "kept"),
        ("audit", "taken out"),
    ], verdicts
    (audit,) = [s["step"] for s in cosine if s["stage"] == "audit"]
    (drift,) = [
        s["step"]
        for s in report["loop"]
        if s["kept"] and s["stage"] == "forward" and s["effect"]["kind"] == "thermal_drift"
    ]
    assert drift > audit
    # owed once the drift is kept, refitted beside it and refused
    assert any(s["step"] > drift and not s["kept"] for s in cosine), verdicts


def test_a_scale_that_settled_before_a_line_was_measured_does_not_take_its_set_up_error() -> None:
    """Seed 5100126 (block 5100000, demo plan): a surface EX over X×Y, a drift of X (7.7 ppm,
    τ 20 min) and a cosine error of diag_xy_pp. Only x_linear, 0–23 min into the session, was
    measured while the X scale moved; diag_xy_pp was measured 631–663 min in. The backward pass
    took the drift out (no held-out line predicts x_linear's course), then the audit took the
    cosine error out for that course, and seven lines were reported. The X scale had settled
    long before diag_xy_pp's first reading: the cosine error stays, beside the surface, and the
    drift only x_linear's course shows is kept or reported there."""
    scenario = make_scenario(5100126)
    report = _loop_report(scenario)
    surface, drift = ("cross_axis", "X over X×Y"), ("thermal_drift", "X")
    cosine = ("cosine", "diag_xy_pp")
    assert scenario.expected == {surface, drift, cosine}
    kept = {effect_place(e) for e in report["effects"]}
    assert {surface, cosine} <= kept <= scenario.expected
    audited = [s for s in report["loop"] if s["stage"] == "audit"]
    assert not any(s["effect"]["kind"] == "cosine" for s in audited), audited
    # the fitted scale within 3 of its stated standard uncertainties (0.1 ppm) of the injected
    # beam's, 1 − cos θ
    (setup,) = scenario.setups
    injected = -1e6 * (1.0 - np.cos(setup.parameters["angle_urad"] * 1e-6))
    (fitted,) = [e["parameters"] for e in report["effects"] if e["kind"] == "cosine"]
    assert abs(fitted["scale_ppm"] - injected) < 3 * fitted["scale_std_ppm"]
    on_x_linear = [u for u in report["unexplained"] if u["where"].startswith("line x_linear at")]
    assert drift in kept or on_x_linear
    # seven lines were reported beside the surface alone; now x_linear and two others
    assert len(report["unexplained"]) <= 3


def test_a_surface_whose_order_the_lines_do_not_settle_states_the_spread_between_orders() -> None:
    """Seed 5200038 (block 5200000, demo plan): a surface EZ over X×Z, a product of sines,
    beside a cycle of X. Kept at order 8, it predicted 36 of the 46 held-out lines better than
    order 6, 3.97 % over all: beyond the 1 % tie, but within two standard errors line by line
    (paired t 1.57). Between the lines that measure EZ along X (z = 0 and 350 mm) the two differ:
    through the middle of the Z stroke EZX with the surface's slice is 5.2 µm RMS off the truth.
    It was stated at 0.9 µm (the function alone), 5.6 times too narrow. Order 6 now counts as a
    fit the plan does not rank below order 8: the 21 errors and the surface's own coefficients
    carry half the move to it, and the scoring folds the surface's uncertainty with the
    function's (tests/independent/loop_scenarios.py): 2.0 times, within the 3 the suite asks."""
    outcome = run_scenario(make_scenario(5200038))
    assert outcome.exact, (outcome.kept, outcome.expected)
    assert outcome.function_error["EZX"] > 3.0  # the swing the plan cannot see is still there
    assert outcome.band_ratio <= 3.0, outcome.band_ratio
    assert outcome.function_error["EZX"] <= 3.0 * outcome.expected_error["EZX"]
    (surface,) = [e["parameters"] for e in outcome.effects_report if e["kind"] == "cross_axis"]
    # order 8 and order 6 differ by 1.47 µm RMS over X×Z: half their outer product alone states
    # 1.04 µm (0.59 µm before, the coefficients' noise alone)
    assert surface["order"] == 8
    assert surface["rms_std_um"] >= 1.0, surface["rms_std_um"]


def test_a_cycle_is_placed_with_the_harmonic_it_is_fitted_with_and_leaves_no_bump() -> None:
    """Seed 5300140 (block 5300000, demo plan): a pure 51.5 mm cycle of X, 4.6 µm. Fitted with a
    second harmonic (the stronger finding), its period came from the search's pure sine: the
    phase slipped over the stroke and a bump of X was kept beside it. Placed with its harmonic,
    the cycle is all that is kept."""
    scenario = make_scenario(5300140)
    assert scenario.expected == {("cyclic", "X")}
    report = _loop_report(scenario)
    (kept,) = report["effects"]
    assert (kept["kind"], kept["axis"]) == ("cyclic", "X"), report["effects"]
    (truth,) = scenario.effects
    assert kept["parameters"]["period_mm"] == pytest.approx(truth.parameters["period"], rel=2e-4)


def test_a_cycle_fitted_a_hair_long_is_placed_again_and_leaves_no_bump() -> None:
    """Seed 5400167 (demo plan): cycles of X (35.3 mm) and Z, a reversal of X. The cycle of X,
    kept first at 35.352 mm while the reversal and Z's cycle were missing, left 0.2 µm fitted
    that long; a bump of X over 351 ± 100 mm took it at 30.4 µm against as much of EXX and was
    refused as implausible. Its re-estimate beside them gained past the noise in the σ² of the
    whole fit, not 0.1 % of the cycle's own χ² in the σ² of the fit without it: it is placed
    again, and no bump is tried."""
    scenario = make_scenario(5400167)
    report = _loop_report(scenario)
    kept = {(e["kind"], e["axis"]) for e in report["effects"]}
    assert kept == {("cyclic", "X"), ("cyclic", "Z"), ("reversal", "X")}
    (first,) = [
        s["effect"]["parameters"]["period_mm"]
        for s in report["loop"]
        if s["kept"]
        and s["stage"] == "forward"
        and s["effect"]["kind"] == "cyclic"
        and s["effect"]["axis"] == "X"
    ]
    (final,) = [
        e["parameters"]["period_mm"]
        for e in report["effects"]
        if e["kind"] == "cyclic" and e["axis"] == "X"
    ]
    (truth,) = [
        e.parameters["period"] for e in scenario.effects if (e.kind, e.target) == ("cyclic", "X")
    ]
    assert abs(final - truth) < abs(first - truth) / 10
    assert not [s for s in report["loop"] if s["effect"]["kind"] == "local"]


@pytest.mark.parametrize(("seed", "line"), [(3500036, "x_linear"), (3500071, "z_linear_far")])
def test_a_set_up_error_fitted_within_its_uncertainty_of_nothing_is_not_kept(
    seed: int, line: str
) -> None:
    """Block 3500000, demo plan: refitted after the effect it had been refused beside was kept,
    a set-up error of one line fitted as nothing (a cosine error of −0.04 ± 0.42 ppm, 3500036;
    an Abbe offset of (−8 ± 13, 26 ± 26) mm, 3500071), yet predicted the held-out lines 3–5 %
    better: the comparison, not the effect, had changed. Nothing was injected on that line; the
    step that tried it says why it was refused."""
    scenario = make_scenario(seed)
    report = _loop_report(scenario)
    assert {effect_place(e) for e in report["effects"]} == scenario.expected
    refusals = [
        step
        for step in report["loop"]
        if step["effect"]["parameters"].get("line") == line and step["verdict"] == "not confirmed"
    ]
    assert refusals, [s["verdict"] for s in report["loop"]]
    assert all("within its stated uncertainty of nothing" in s["reason"] for s in refusals)


def test_a_surface_implausible_at_its_highest_order_is_refitted_at_lower_ones() -> None:
    """Seed 4300180 (block 4300000, sparse plan, 0.08 µm noise): a cycle and a bump of Z and a
    surface EX over X×Z. At order 8 the surface predicted the held-out blocks best (52.6 %
    better) but swung to a 150 µm peak where the plan reads nothing, and was refused; EX over
    Y×Z was kept in its place and X×Z never refitted at a lower order. Its lower orders are now
    refitted in the same step: order 6 is kept, the other places named as rivals that fit as
    well."""
    outcome = run_scenario(make_scenario(4300180))
    assert outcome.kept == outcome.expected, (outcome.kept, outcome.expected)
    (surface,) = [e for e in outcome.effects_report if e["kind"] == "cross_axis"]
    assert surface["label"].startswith("cross-axis EX over X×Z (order 6")
    assert outcome.unexplained == 0
    assert not outcome.implausible


@pytest.mark.parametrize(
    ("seed", "plan", "lines"),
    [
        (4500087, "sparse", {"y_straight_z", "z_straight_y"}),
        (4500143, "sparse", {"x_linear", "x_straight_y"}),
        (4700074, "twelve-line", {"diag_xz_pp", "x_lin_2", "z_lin_1"}),
        (5000106, "sparse", {"x_linear", "x_straight_z_offset", "y_linear", "z_straight_x"}),
    ],
)
def test_a_surface_is_not_kept_for_the_disagreement_of_lines_it_leaves_systematic(
    seed: int, plan: str, lines: set[str]
) -> None:
    """Seeds 4500087 and 4500143 (force-fits of block 4500000, sparse plan, 0.20 µm noise):
    reflector mounts that twitch (38 mm bumps of 3.9 and 2.5 µm) on two and three lines, outside
    the catalogue. A surface EY over X×Y of order 8 was kept, 11.7 % and 4.0 % better held out:
    the twitching lines pull the 21 errors away from the other lines, the surface's many terms
    relieve the pull, and the twitching lines stay systematic beside it. Without those lines
    it predicts the held-out readings no better (−0.2 % and 1.6 %): nothing is kept, and the
    twitching lines are reported unexplained. Seed 4700074 (twelve-line plan, 0.12 µm noise):
    3.8 µm twitches of three lines, a quarter of the plan; a finer ECX was kept, 7.8 % better
    held out, all of it on two of them, which it left systematic — a finer function relieves the
    pull as a surface does. Seed 5000106 (sparse plan, 0.14 µm noise): 2.2 µm twitches of four
    lines pull two more, six of 21 systematic, too many for the test when the surface EX over
    X×Z of order 8 was kept (6.9 % better held out); beside it the four twitching lines alone
    stay systematic, and the final audit asks it then: without them it is 0.1 % worse."""
    outcome = run_scenario(make_scenario(seed))
    assert outcome.category == "outside" and outcome.plan == plan
    assert outcome.kept == set(), outcome.kept
    for name in lines:
        assert any(on_line(where, name) for where in outcome.unexplained_where), name


@pytest.mark.parametrize(("seed", "axis"), [(4700004, "Z"), (4700054, None)])
def test_an_axis_scale_that_moves_between_lines_is_reported_across_them(
    seed: int, axis: str | None
) -> None:
    """Seed 4700004 (demo plan): the Z scale oscillates in time, 8 ppm over 90 min, each Z
    line 33 min long; each Z line alone follows its target position and time. The report says,
    across the four lines moving Z alone, that they read different scales at different times.
    Seed 4700054: a laser that wanders on x_linear_far alone (and x_straight_z_far) makes that
    line's scale 1.75 ppm off three X lines that agree: it is the line's, reported on it, not a
    scale of X."""
    scenario = make_scenario(seed)
    assert scenario.category == "outside"
    outcome = run_scenario(scenario)
    assert outcome.kept == set(), outcome.kept
    across = [w for w in outcome.unexplained_where if w.startswith("the linear lines moving")]
    if axis is None:
        assert across == []
        assert any(on_line(w, "x_linear_far") for w in outcome.unexplained_where)
    else:
        assert across == [f"the linear lines moving {axis} alone, over the session"]
