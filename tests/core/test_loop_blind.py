"""The closed loop on machines of the blind generator (tests/blind, written by someone who did not
read the method), for behaviours its suite showed missing:

- a cycle shorter than twice the spacing of most lines is found at its period when one line's
  targets are fine enough to sample it (the coarser lines alias it; together they do not), and
  one shorter than twice every line's spacing where irregular targets tell it from its aliases,
  even one below half of it where no spacing of the targets repeats, and one whose own second
  harmonic is the next peak of the search (a harmonic is no alias);
- an error periodic in time, which only widens the run-to-run spread of the lines it acts on, is
  found as one sinusoid of the session, taken out of the readings before the loop searches,
  and reported with its axis, amplitude, period and lines: nothing is kept for it, and the 21
  errors are fitted as the machine has them; left in the readings (as where the search does
  not find it), it is reported as unexplained on each line it spoils, and nothing is kept for
  it, not even a set-up effect fitted to what it leaves in the means of a line that repeats
  far worse than its peers;
- a scale that oscillates in time, which a surface over two axes or a drift can mimic on the
  lines it crosses, is not kept as either: neither has one size on those lines or runs; nor as
  cosine errors of the lines that read short, while others along the same axes read long; nor
  as a warm-up its axis' first line alone shows where the later lines along the axis read the
  scale still changing in time, or, that line being a diagonal, the other axis' lines read
  theirs changing; nor as a drift that, with every kept effect in the model, leaves the lines
  along its axis reading their scale still changing (the final audit);
- a drift that only the first line shows before it settles is kept on what the angular lines
  say, and that line, which fixes the drift's size in sample and is predicted held out with the
  size later lines fix, is not asked to confirm it (rule (d));
- a set-up error (a cosine error) that, without an effect beside it, fits beyond what alignment
  allows, or falls short of the margin, is refitted once that effect is kept, and kept; one (an Abbe
  offset) that explains what its line alone shows as well as a surface does is refitted beside the
  surface's places, and kept for its fewer parameters, with the surfaces named as its rivals (and a
  drift that fits a first line's cosine error as well, likewise);
- a surface the plan cannot place (another direction or pair predicts the held-out data as well)
  is kept with a warning that names its rivals, and report.json lists them beside it, a rival
  place whose highest order swings beyond plausibility off the lines at a lower order;
- a bump whose only sight on a line is the block of targets held out, and the session's first
  line once a drift is in the model, are no predictions of either model compared: the comparison
  runs on the rest, and the effects are kept;
- a drift that one line alone shows is reported unexplained on that line, and nothing is kept,
  unless a logged material temperature drives it, even one the files log only at their two
  ends while the structure settles within the line; a drift a cosine error took is kept once the
  final audit takes the cosine out, and a cosine error a surface took once the audit takes the
  surface out (the forward steps run once more after it);
- a drift weaker than the variants of a bump that one line alone shows is kept once they are
  refused: a step's further batches take the strongest machine effect of each kind it has not
  tried (a set-up effect, which one line's artefact can fake, is refitted only among the
  strongest);
- candidates of one step are ranked over the readings every one of them predicts: one whose fit
  makes another held-out line a wild extrapolation is not excused the error there (a cosine
  error, not an Abbe offset of the same line), and when the two set-ups of a line predict as
  well, the report says the plan cannot tell them apart;
- bumps narrower than every line's target spacing are found at their places (the scan that
  places a bump tries widths below the spacing);
- a bump narrower than the spacing of most lines is found where the line that sees it best
  resolves it, not elsewhere with a finer function beside it;
- a bump whose free profile spans splines of its error function holds what they cannot, and is
  kept at its place (fitted as it came, bump and function traded tens of µm with opposite signs
  and the bump was refused as implausible); one narrower than the targets' spacing, whose free
  profile over three spacings each side its function's splines cancel, is kept as a Gaussian of
  one height at its place;
- a right effect is not refused for a change of size between runs that the 21 errors absorb
  almost whole, or that a reversal the model misfits brings between the two directions: a drift
  beside a reversal that grows along the stroke, an Abbe offset not taken by a surface;
- a held-out line that one model cannot predict (wild against its in-sample fit) but still
  predicts better than the other is compared, not left out: the session's first line with a
  drift in the model;
- a candidate refused for a size that changed between runs while another effect was missing is
  refitted once that effect is kept (a drift beside a reversal whose slope came later);
- a set-up error of one line (a cosine error) that takes only part of what its line shows, the
  line alone still drifting in time beyond its repeatability, is taken out by the audit and the
  line is reported unexplained (a column that bends as it warms); a right one whose line keeps
  a residual locked to position is kept;
- a beam cut and re-zeroed on a line's last two readings, diluted eightfold in the targets'
  means, is reported as a step in time on that line, at its run and target, and sized; a line
  whose reflector settles differently in each run, as stepping at more than one moment;
- a laser that wanders in time is not kept as a drift: between runs its size changes by more
  than the readings see of the drift itself;
- a surface term that reads on every line as the 21 errors do (a twist the plan sees as rolls
  and a squareness) is left to those errors, and the report says which errors carry it;
- a surface of another order at the kept one's place is kept before a second surface of the
  same direction that predicts as well with fewer terms: it makes no second claim;
- a surface kept at a step over its other family of as many terms that predicted as well (order
  6 and order 4 with lever-arm terms) is followed both ways to the end, and the route that ends
  better or as well with fewer parameters is the loop's: the one a step kept had taken a line's
  set-up error still missing;
- a round whose audit takes out everything it kept, back to where it started, is run again
  where an axis' scale still changes in time, everything the round kept held back until another
  effect is kept (a cosine error of the first line that stood in for a drift);
- a drift whose form leaves its axis' scale changing in time is read again by the audit in a
  form that does not (a course in time or a first-order response in place of a straight line
  between two temperature logs), before any set-up error is taken out for that change;
- a surface whose order the plan does not settle (another order predicts the held-out data as
  well and moves the errors fitted beside it) is kept with a warning naming the errors that
  move and a line the plan lacks on which the two read apart, and their stated uncertainties
  include the move; so do the errors beside a surface
  whose direction and pair the plan cannot tell, and beside a set-up effect (a cosine error)
  that the same effect on another line fits identically;
- a drift's time constant placed while a set-up error was still missing is estimated again
  with that error in the model, and both are kept, even one the search had placed at another
  of its peaks; a cycle kept at the screw lead moves off it to its own period where the data
  say so beyond the noise, and a drift beside it is kept;
- the errors' stated uncertainty holds what the plan leaves open beside them: their moves
  across a kept drift's time constant within its uncertainty, and to a basis spacing that
  predicts the lengths better than the one chosen; and what the chosen basis misses of their
  shape, the same in every re-measurement, against the finest spacing tried;
- held out, every fold fits the model the fit fitted, no freer: a cycle only the freer folds
  predicted is not kept, and a surface they had half taken is confirmed and kept at its place.

Each scenario is written to files by the generator, imported by volucal and run through
``close_loop`` with the shipped defaults; the truth comes from the generator's manifest.
"""

import re
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "independent"))

from loop_scenarios import one_line_refused  # noqa: E402
from score_blind import run_blind  # noqa: E402

from tests.blind.scenarios import write_scenario  # noqa: E402


def _loop_result(seed: int, noise_draw: int = 0):  # type: ignore[no-untyped-def]
    from volucal.core.io.plan import import_plan, load_plan
    from volucal.core.residuals import close_loop

    with tempfile.TemporaryDirectory(prefix="volucal-blind-") as tmp:
        plan, truth = write_scenario(seed, tmp, noise_draw=noise_draw)
        measurement = import_plan(load_plan(plan)).measurement
    return close_loop(measurement), truth


def _loop(seed: int, noise_draw: int = 0):  # type: ignore[no-untyped-def]
    result, truth = _loop_result(seed, noise_draw)
    return result.to_report(), truth


def _loop_left_in(seed: int, monkeypatch: pytest.MonkeyPatch):  # type: ignore[no-untyped-def]
    """The loop where an error periodic in time is not taken out of the readings before it
    searches, nor found by the judge or the report, as where the search does not find it (a
    period longer than half a line: 12 of the 62 such errors of the suite's blocks): the
    lines it acts on wander."""
    import volucal.core.loop_judge as loop_judge
    import volucal.core.loop_unexplained as loop_unexplained
    import volucal.core.residuals as residuals

    for module in (residuals, loop_judge, loop_unexplained):
        monkeypatch.setattr(module, "periodic_in_time", lambda identification, alpha: None)
    return _loop(seed)


def test_a_cycle_the_finest_line_samples_is_found_at_its_period() -> None:
    # lines along Z every 5.4, 4.0 and 3.0 mm, diagonals every 7 mm along Z; a 10.47 mm cycle
    # with its second harmonic: the old search started at twice the median spacing (10.8 mm),
    # kept an alias at 11.3 mm and the audit took it out again
    report, truth = _loop(1165)
    (cycle,) = [e for e in truth["effects"] if e["kind"] == "cyclic"]
    period = cycle["parameters"]["period_mm"]
    kept = [e for e in report["effects"] if e["kind"] == "cyclic" and e["axis"] == "Z"]
    assert kept, report["effects"]
    assert kept[0]["parameters"]["period_mm"] == pytest.approx(period, rel=0.002)
    assert {e["kind"] for e in report["effects"]} == {"cyclic"}


@pytest.mark.parametrize("seed", [1083, 1157])
def test_an_error_periodic_in_time_is_reported_on_every_line_it_acts_on(seed: int) -> None:
    # found as one sinusoid of the session, its entry lists the lines it acts on; a line it
    # leaves more on than the sinusoid takes out is reported on its own too
    report, truth = _loop(seed)
    (effect,) = truth["effects"]
    assert effect["kind"] == "outside:time_periodic"
    noise = truth["noise"]["sigma_um"]
    acting = {line for line, peak in effect["visibility"]["per_line"].items() if peak > 4 * noise}
    (periodic,) = [u["periodic"] for u in report["unexplained"] if "periodic" in u]
    assert periodic["axis"] == effect["axis"] and periodic["taken_out"]
    reported = set(periodic["run_to_run_rms_um"]) | {
        u["where"].split()[1] for u in report["unexplained"] if u["where"].startswith("line ")
    }
    assert acting and acting <= reported, (acting, report["unexplained"])
    assert not report["effects"]


@pytest.mark.parametrize(
    "seed",
    [
        # direct plan, 0.19 µm noise, a 1.4 µm Y error of period 95 s: an Abbe offset of
        # diag_yz_pp (53, 32, -28) mm, fitted to what the error left in its means, was kept at
        # 3.1 % better held out
        33105,
        # demo plan, 0.44 µm noise, a 1.1 µm Y error of period 75 s: an Abbe offset of y_linear
        # (90, 0, -22) mm was kept at 4.3 % better held out
        83031,
        # direct plan, 0.11 µm noise, a 0.6 µm Z error of period 176 s: a surface EX over X×Z
        # was kept at 3.2 % better held out, 75 % of it on the lines the error acts on
        83037,
        # twelve-line plan, 0.17 µm noise, a 4.2 µm X error of period 70 s
        1157,
        # the generator's own plan, 49 lines, 0.41 µm noise, a 3 µm Z error of period 102 s
        36049,
    ],
)
def test_an_error_periodic_in_time_is_taken_out_before_the_loop_searches_and_reported(
    seed: int,
) -> None:
    # what it leaves in the lines' means, a set-up of a line or a shape in position fits in
    # part; taken out of the readings, nothing is left for them, and the 21 errors are fitted
    # as the machine has them: every function within the 0.35 µm / 2 µrad the suite asks of an
    # exact effect set (before, their worst: 1.3 µm, 0.35 µm, 0.49 µm, 4.2 µrad, and 5.9 µrad
    # with a squareness 10 µrad off)
    from score_blind import _accuracy

    result, truth = _loop_result(seed)
    report = result.to_report()
    (effect,) = truth["effects"]
    assert effect["kind"] == "outside:time_periodic"
    assert report["effects"] == []
    assert not any(s["kept"] for s in report["loop"])
    (entry,) = [u for u in report["unexplained"] if "periodic" in u]
    assert entry["where"] == f"along {effect['axis']}, periodic in time"
    periodic = entry["periodic"]
    parameters = effect["parameters"]
    assert periodic["period_s"] == pytest.approx(parameters["period_s"], rel=0.002)
    assert periodic["amplitude_um"] == pytest.approx(abs(parameters["amplitude_um"]), rel=0.1)
    assert entry["magnitude_um"] == periodic["amplitude_um"]
    assert periodic["taken_out"]
    assert f"period {parameters['period_s']:.0f} s" in entry["description"]
    taken = "taken out of the readings before the loop searched its effects"
    assert taken in entry["description"]
    assert any("was taken out of the readings" in w for w in report["warnings"])
    functions, squareness, _ = _accuracy(seed, truth, result)
    angles = {f"E{c}{a}" for c in "ABC" for a in "XYZ"}
    assert max(v for k, v in functions.items() if k not in angles) < 0.35, functions
    assert max(v for k, v in functions.items() if k in angles) < 2.0, functions
    assert max(squareness.values(), default=0.0) < 2.0, squareness


def test_a_set_up_of_a_line_that_wanders_is_not_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    # direct plan, 0.19 µm noise: a 1.4 µm Y error periodic in time (95 s), each run timed
    # alike, so its means per target keep a shape on the lines it acts on. The diagonal
    # diag_yz_pp repeats 4.7 times worse than its steadiest peers; an Abbe offset of
    # (53, 32, -28) mm fitted to its means passed the 3 % margin (3.1 %) and was kept
    report, truth = _loop_left_in(33105, monkeypatch)
    (effect,) = truth["effects"]
    assert effect["kind"] == "outside:time_periodic"
    assert report["effects"] == []
    (refusal,) = [
        s
        for s in report["loop"]
        if s["effect"]["kind"] == "abbe_offset"
        and s["effect"]["parameters"]["line"] == "diag_yz_pp"
    ]
    assert refusal["verdict"] == "not repeatable", refusal
    assert "times its steadiest peers'" in refusal["reason"]
    assert "line diag_yz_pp, from run to run" in [u["where"] for u in report["unexplained"]]


def test_an_error_periodic_in_time_is_not_kept_as_a_reversal(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # twelve-line plan, 0.32 µm noise: a 2.3 µm Y error periodic in time (264 s). Read forward
    # and backward at different times, it leaves a difference between the approach directions
    # on every Y line: nothing at both ends, 3.5 µm at mid-stroke. A constant reversal of Y took
    # 9.6 % of the held-out error and its size, fitted line by line, differed only 17 %
    # (found and taken out, it leaves no reversal to judge: 0.1 % worse held out)
    report, truth = _loop_left_in(49199, monkeypatch)
    (effect,) = truth["effects"]
    assert (effect["kind"], effect["axis"]) == ("outside:time_periodic", "Y")
    assert report["effects"] == []
    (refusal,) = [s for s in report["loop"] if s["effect"]["kind"] == "reversal"]
    assert refusal["effect"]["axis"] == "Y"
    assert refusal["verdict"] == "uneven along its line", refusal
    assert "let change linearly over the stroke" in refusal["reason"]
    # every Y line reported, placed and sized by forward less backward (the hump's top); the
    # targets' means pool both directions, and y_lin_1 was not reported at all
    on_y = {u["where"].split()[1]: u for u in report["unexplained"] if " y_lin_" in u["where"]}
    assert sorted(on_y) == ["y_lin_1", "y_lin_2", "y_lin_3"], report["unexplained"]
    for u in on_y.values():
        assert "follows mostly the approach direction" in u["description"], u
        assert "forward − backward" in u["description"]
        assert 2.5 < u["magnitude_um"] < 5.0, u


def test_a_reversal_that_changes_over_the_stroke_is_kept_with_its_slope() -> None:
    # twelve-line plan, 0.13 µm noise: a drift of X and a reversal of Z that goes from −1.81 µm
    # at the stroke's start (its low end on this plan) to −2.33 µm at its end. Its slope betters
    # the held-out error by 2.0 % over the twelve lines and was refused for the 3 % margin, four
    # of the five lines moving Z then reported for the 0.37 µm it left between their
    # directions; over the lines that move Z, which alone it acts on, it earns 5 %
    report, truth = _loop(50073)
    (injected,) = [e["parameters"] for e in truth["effects"] if e["kind"] == "reversal"]
    start, end = injected["B_at_stroke_start_um"], injected["B_at_stroke_end_um"]
    assert {(e["kind"], e["axis"]) for e in report["effects"]} == {
        ("reversal", "Z"),
        ("thermal_drift", "X"),
    }
    (kept,) = [e for e in report["effects"] if e["kind"] == "reversal"]
    assert kept["label"] == "reversal Z (position-dependent)"
    p = kept["parameters"]
    assert abs(p["value_um"] - (start + end) / 2) <= 3.0 * p["value_std_um"]
    assert abs(p["slope_um_per_stroke"] - (end - start)) <= 3.0 * p["slope_std_um_per_stroke"]
    (row,) = [
        s for s in report["loop"] if s["kept"] and "position-dependent" in s["effect"]["label"]
    ]
    assert "over the lines that move Z, the only ones its slope acts on" in row["reason"]
    assert report["unexplained"] == []


def test_a_narrow_bump_two_lines_show_is_kept_for_what_it_gains_within_its_reach() -> None:
    # direct plan, 0.47 µm noise: a 3.9 µm bump of Y along X, 6.7 mm wide, and a bump of Z along
    # Y. The narrow one shows on x_straight_y and diag_xy_pp, 2.9 and 2.3 µm; over the plan it
    # earned 2.4 % held out and was refused for the 3 % margin, and the two lines were reported;
    # over the readings within its reach it earns 62 %, and the backward pass asks it the same
    report, truth = _loop(51019)
    injected = {(e["axis"], e["direction"]) for e in truth["effects"]}
    assert injected == {("X", "Y"), ("Y", "Z")}
    kept = {(e["axis"], e["parameters"]["direction"]) for e in report["effects"]}
    assert kept == injected and {e["kind"] for e in report["effects"]} == {"local"}
    (row,) = [s for s in report["loop"] if s["kept"] and s["effect"]["axis"] == "X"]
    assert "over the readings within its reach" in row["reason"]
    assert report["unexplained"] == []


def test_lines_a_reversal_leaves_between_its_directions_do_not_take_a_surface_out() -> None:
    # direct plan, 0.19 µm noise: a surface EX over X×Z, a bump of Y in X and a reversal of X
    # from 3.79 to 2.93 µm over the stroke. Kept constant (before its slope could earn the margin
    # over the lines that move X), it left a difference between x_linear's and diag_xz_pp's
    # directions; held against the surface as lines it leaves systematic, that had the audit
    # take the surface out (a difference between the directions is no shape a surface could
    # take: test_loop.py pins that the loop's own judgements do not count it)
    outcome = run_blind(48142)
    assert outcome.kept == outcome.expected
    assert ("cross_axis", "X over X×Z") in outcome.kept


@pytest.mark.parametrize("seed", [1005, 1067, 5028])
def test_a_scale_oscillating_in_time_is_not_kept_as_a_surface_or_a_drift(seed: int) -> None:
    # 1005, 1067: a surface fits some lines at twice its size and others at none; 5028
    # (twelve-line plan, 56 min period): a drift in time takes 8 % of the held-out error and is
    # refused: fitted run by run, its size varies far beyond the noise
    outcome = run_blind(seed)
    assert outcome.category == "outside"
    assert not outcome.kept
    assert outcome.unexplained > 0


def test_a_scale_swinging_back_within_a_line_is_not_kept_as_a_drift() -> None:
    # direct plan, 0.12 µm noise: the Y scale oscillates over 110 min; y_linear (44 min) sees it
    # swing through 0.4 of a period, two diagonals see one level each. A drift of Y (τ 375 min)
    # took it to 0.127 µm held out, every run split passed: the line's file repeatability
    # (0.77 µm) holds the swing itself. Within y_linear the readings follow the drift's shape
    # times a course in time no exponential takes; the drift is refused and the lines reported
    report, truth = _loop(40148)
    assert truth["category"] == "outside"
    assert not report["effects"], report["effects"]
    drift = [s for s in report["loop"] if s["effect"]["kind"] == "thermal_drift"]
    assert drift and all(s["verdict"] == "not repeatable" for s in drift)
    assert "on line y_linear" in drift[0]["reason"]
    assert "off its course in time" in drift[0]["reason"]
    assert any("y_linear" in u["where"] for u in report["unexplained"])


def test_a_course_in_time_in_the_first_line_of_an_axis_is_no_warm_up_unless_it_settled() -> None:
    # direct plan, 0.18 µm noise: the X scale oscillates over 99 min; x_linear (0-25 min), the
    # first line along X, reads a quarter period of it and alone shows it. Kept as a warm-up
    # (τ 365 min, -87 ppm) that later lines would read as a settled scale — but the next line
    # along X starts at 420 min, 1.2 of those time constants: the drift as fitted had not
    # settled, so nothing bears it out. Refused as one line's and reported on x_linear; a
    # warm-up that settles before the next line (test above) is still kept
    report, truth = _loop(61139)
    assert truth["category"] == "outside"
    assert not report["effects"], report["effects"]
    drift = [s for s in report["loop"] if s["effect"]["kind"] == "thermal_drift"]
    assert drift and drift[0]["verdict"] == "one line only"
    assert "only line x_linear shows it" in drift[0]["reason"]
    (line,) = [u for u in report["unexplained"] if "x_linear" in u["where"]]
    assert line["strongest"] == "time"


def test_a_scale_swinging_over_the_session_is_no_warm_up_where_later_lines_read_it_changing() -> (
    None
):
    # direct plan, 0.12 µm noise: the Y scale oscillates over 118 min (4.2 µm at the stroke's
    # end). y_linear, the first line along Y, reads a rise of it and alone shows it beyond what
    # the 21 errors absorb: kept as a warm-up of 146 ppm, τ 105 min, settled by the time the
    # next line along Y starts. The diagonals through Y, measured later, read the scale still
    # swinging (reported unexplained, following time) with the drift in the model: nothing bears
    # the warm-up out, so it is refused as one line's and the three lines are reported
    report, truth = _loop(81144)
    assert [e["kind"] for e in truth["effects"]] == ["outside:scale_oscillation"]
    assert report["effects"] == []
    (drift,) = [s for s in report["loop"] if s["effect"]["kind"] == "thermal_drift"]
    assert drift["verdict"] == "one line only"
    assert "only line y_linear shows it" in drift["reason"]
    assert "nor is it a warm-up that settled" in drift["reason"]
    assert "diag_xy_pp and diag_yz_pp, still read the scale changing in time" in drift["reason"]
    reported = {u["where"].split(" at ")[0]: u for u in report["unexplained"]}
    assert {"line y_linear", "line diag_xy_pp", "line diag_yz_pp"} <= set(reported)
    for name in ("line diag_xy_pp", "line diag_yz_pp"):
        assert reported[name]["strongest"] == "time"


def test_a_warm_up_a_diagonal_alone_shows_is_not_kept_where_the_other_axis_scale_changes() -> None:
    # direct plan, 0.17 µm noise: the X scale oscillates over 103 min (3.4 times the noise).
    # diag_xz_pp, the first line along Z, alone shows it beyond what the 21 errors absorb, and it
    # was kept as a warm-up of Z of -63 ppm, τ 39 min: along the diagonal X and Z move in step,
    # and a drift of either scale reads alike there. x_linear and diag_xy_pp, the other lines
    # along X, read the X scale changing in time: the drift is refused as one line's, and both
    # diagonals are reported
    report, truth = _loop(81051)
    assert [e["kind"] for e in truth["effects"]] == ["outside:scale_oscillation"]
    assert truth["effects"][0]["axis"] == "X"
    assert report["effects"] == []
    drift = [s for s in report["loop"] if s["effect"]["label"] == "thermal drift Z (time)"]
    assert drift and drift[0]["verdict"] == "one line only"
    assert "only line diag_xz_pp shows it" in drift[0]["reason"]
    assert "nor can it be told from a change of X's scale" in drift[0]["reason"]
    assert "on lines x_linear and diag_xy_pp, the other lines along X" in drift[0]["reason"]
    reported = {u["where"].split(" at ")[0] for u in report["unexplained"]}
    assert {"line diag_xz_pp", "line diag_xy_pp"} <= reported


def test_a_drift_that_leaves_its_lines_reading_the_scale_still_changing_is_taken_out() -> None:
    # direct plan, 0.23 µm noise: the Z scale oscillates over 54 min (4.3 µm at the stroke's
    # end, 3.0 times the noise). Kept as a drift of Z of 121 ppm, τ 76 min, that diag_yz_pp and
    # z_linear both show, nothing reported: each line's own settling course beside the drift
    # took what it left. With the drift in the model the two still read the Z scale changing
    # in time; the audit takes it out, and both lines are reported, following time
    report, truth = _loop(61026)
    assert [e["kind"] for e in truth["effects"]] == ["outside:scale_oscillation"]
    assert truth["effects"][0]["axis"] == "Z"
    assert report["effects"] == []
    (audited,) = [s for s in report["loop"] if s["stage"] == "audit"]
    assert audited["effect"]["label"] == "thermal drift Z (time)"
    assert (
        "the scale of Z still changes in time on lines diag_yz_pp and z_linear"
        in (audited["reason"])
    )
    reported = {u["where"].split(" at ")[0]: u for u in report["unexplained"]}
    assert {"line diag_yz_pp", "line z_linear"} <= set(reported)
    assert reported["line z_linear"]["strongest"] == "time"


def test_a_set_up_read_while_the_axis_scale_swung_is_not_kept() -> None:
    # displacement-only plan, 0.39 µm noise: the Y scale oscillates over 94 min. Cosine errors of
    # body_ppp and diag_yz_offcentre, each a scale of its line read while the Y scale stood
    # off its mean, were kept. With them in the model, y_lin_2, which moves Y alone, still
    # follows its distance times a course in time: the Y scale changes, and a set-up that is a
    # scale of a line moving Y cannot be told from it. The audit takes them out
    report, truth = _loop(41072)
    assert truth["category"] == "outside"
    assert not report["effects"], report["effects"]
    audited = [
        s["effect"]["parameters"]["line"]
        for s in report["loop"]
        if s["stage"] == "audit"
        and s["effect"]["kind"] == "cosine"
        and "the Y scale changes in time: line y_lin_2" in s["reason"]
    ]
    assert audited == ["body_ppp", "diag_yz_offcentre"], audited
    assert len(report["unexplained"]) >= 10


def test_set_ups_read_while_the_axis_scale_swung_are_taken_out_where_others_read_long() -> None:
    # demo plan, 0.17 µm noise: the X scale oscillates over 65 min. Cosine errors of
    # diag_xz_pp_b and body_mpp (measured while the scale stood off its mean) were kept at steps
    # 2 and 3; body_ppp, along the same axes, reads longer than the model's scale beside them,
    # which no misalignment does: the audit takes both out, nothing is kept and the lines are
    # reported
    report, truth = _loop(40118)
    assert truth["category"] == "outside"
    assert not report["effects"], report["effects"]
    audited = {
        s["effect"]["parameters"]["line"]
        for s in report["loop"]
        if s["stage"] == "audit" and s["effect"]["kind"] in ("cosine", "abbe_offset")
    }
    assert audited >= {"body_mpp"}, report["loop"]
    assert len(report["unexplained"]) >= 10


def test_a_shape_fitted_to_lines_that_change_between_runs_is_not_kept() -> None:
    # direct plan, 0.24 µm noise: a 2.5 µm Z error periodic in time (107 s) spoils every line
    # that moves Z; seven of them repeat 3–8 times worse than their peers, and what each run's
    # timing leaves in their per-target means differs from line to line. A surface EX over X×Z
    # of order 8 took it at 9.6 % better held out, 92 % of that on those seven lines. It is
    # refused as not repeatable and the lines are reported; so is the error itself, found as
    # one sinusoid of the session at its period. Taken out of the readings, it leaves
    # x_straight_z_offset repeating 2.1 times worse than its peers, and surfaces over X×Z, X×Y
    # and Y×Z take 5–7 % of the held-out error, all of it there
    report, truth = _loop(42119)
    assert (truth["category"], report["effects"]) == ("outside", [])
    surfaces = {
        s["effect"]["label"]: s for s in report["loop"] if s["effect"]["kind"] == "cross_axis"
    }
    assert any(label.startswith("cross-axis EX over X×Z") for label in surfaces), surfaces
    for step in surfaces.values():
        assert step["verdict"] == "not repeatable"
        assert "on lines that repeat far worse than their peers" in step["reason"]
        assert "an error periodic in time (2.3 µm along Z, period 107 s" in step["reason"]
    where = [u["where"] for u in report["unexplained"]]
    assert "line x_straight_z_offset, from run to run" in where
    assert "along Z, periodic in time" in where


def test_a_surface_is_judged_without_the_line_a_missing_drift_spoils() -> None:
    # demo plan, 0.39 µm noise: a surface EX over X×Y and a drift of X (τ 30 min) that only
    # x_linear, the session's first line, shows. The surface was kept at 39 % better held out,
    # then taken out by the audit at 33 % spread between lines, all of it x_linear's (95 % more
    # of the surface there, beside the drift it lacks); nothing was kept and 25 lines reported.
    # x_linear's scale settles in time: it may take a size of its own, the surface stays and
    # x_linear is reported
    report, truth = _loop(42166)
    assert truth["category"] == "effects"
    assert [
        (e["kind"], e["axis"], sorted(e["parameters"]["depends_on"])) for e in report["effects"]
    ] == [("cross_axis", "X", ["X", "Y"])]
    assert not [s for s in report["loop"] if s["stage"] == "audit"]
    assert any(u["where"].startswith("line x_linear ") for u in report["unexplained"])


def _kept_places(report: dict) -> list[tuple[str, str]]:  # type: ignore[type-arg]
    """The kept effects by kind and place: a set-up error's line, any other's axis."""
    return sorted(
        (
            e["kind"],
            e["parameters"]["line"] if e["kind"] in ("cosine", "abbe_offset") else e["axis"],
        )
        for e in report["effects"]
    )


def test_a_set_up_error_short_of_the_margin_is_refitted_once_another_is_kept() -> None:
    # demo plan, 0.12 µm noise: a 7.8 mm cycle of Y and cosine errors of diag_yz_pm_b (-5.95 ppm)
    # and z_linear_side (-7.57 ppm). Step 2 kept diag_yz_pm_b's; z_linear_side's, refitted in the
    # same batch while the other was still missing, predicted the held-out lines 2.2 % better
    # and was refused; its F statistic never doubled, so it was not refitted again, and
    # z_linear_side stayed unexplained with 1.4 µm. Beside the other cosine error: 16.7 %
    report, truth = _loop(48121)
    rows = [
        s
        for s in report["loop"]
        if s["effect"]["kind"] == "cosine" and s["effect"]["parameters"]["line"] == "z_linear_side"
    ]
    # refused beside the other line's missing error, kept at a later step beside it
    refused = [s["step"] for s in rows if s["verdict"] == "below margin"]
    (kept,) = [s["step"] for s in rows if s["kept"]]
    assert refused and min(refused) < kept, rows
    assert _kept_places(report) == [
        ("cosine", "diag_yz_pm_b"),
        ("cosine", "z_linear_side"),
        ("cyclic", "Y"),
    ], report["effects"]
    for line in ("diag_yz_pm_b", "z_linear_side"):
        (injected,) = [e for e in truth["effects"] if e.get("line") == line]
        (fitted,) = [e for e in report["effects"] if e["parameters"].get("line") == line]
        assert fitted["parameters"]["scale_ppm"] == pytest.approx(
            injected["parameters"]["scale_ppm"], abs=0.5
        )
    assert not report["unexplained"], report["unexplained"]


def test_a_surface_gives_way_to_the_set_up_error_that_explains_it_as_well() -> None:
    # displacement-only plan, 0.07 µm noise: a 4.1 mrad misalignment of z_lin_1 beside a surface
    # EX over X×Y. Step 1 kept a surface EZ over X×Z (0.1164 µm held out against 0.1256 µm for
    # the cosine error): it took part of the EX surface still missing. With EX over X×Y kept at
    # step 2 both predict alike (0.07514 against 0.07509 µm) and the surface stayed, its six
    # terms for the cosine's one. The backward pass puts the cosine error in its place
    report, truth = _loop(43187)
    assert truth["category"] == "effects"
    assert _kept_places(report) == [("cosine", "z_lin_1"), ("cross_axis", "X")]
    (replaced,) = [
        s
        for s in report["loop"]
        if s["stage"] == "backward" and s["effect"]["kind"] == "cross_axis" and not s["kept"]
    ]
    assert "cosine misalignment of line z_lin_1 explains what it did as well" in replaced["reason"]
    (cosine,) = [e for e in truth["effects"] if e["kind"] == "cosine"]
    (fitted,) = [e for e in report["effects"] if e["kind"] == "cosine"]
    # the line's scale, −θ²/2: within 0.5 ppm of the injected −8.34 ppm (fitted −8.60)
    assert fitted["parameters"]["scale_ppm"] == pytest.approx(
        cosine["parameters"]["scale_ppm"], abs=0.5
    )


def test_a_surface_whose_highest_order_took_a_set_up_error_gives_way_one_order_lower() -> None:
    # blind 46074 (displacement-only plan, 0.053 µm noise): EY over X×Y, a product of the two
    # positions (3.0 µm peak), and a 3.4 mrad misalignment of diag_xy_offcentre (−5.8 ppm), a
    # line in the surface's plane. Step 1 kept the surface at order 4 (0.0548 µm held out
    # against 0.0921 at order 3): its fourth order took the cosine error, never refitted. The
    # backward pass puts the surface one order lower beside the cosine error in its place
    report, truth = _loop(46074)
    assert truth["category"] == "effects"
    assert _kept_places(report) == [("cosine", "diag_xy_offcentre"), ("cross_axis", "Y")]
    (surface,) = [e for e in report["effects"] if e["kind"] == "cross_axis"]
    assert sorted(surface["parameters"]["depends_on"]) == ["X", "Y"]
    (replaced,) = [
        s
        for s in report["loop"]
        if s["stage"] == "backward" and s["effect"]["kind"] == "cross_axis" and not s["kept"]
    ]
    assert "(order 4, with lever-arm terms)" in replaced["effect"]["label"]
    assert "beside cosine misalignment of line diag_xy_offcentre" in replaced["reason"]
    (cosine,) = [e for e in truth["effects"] if e["kind"] == "cosine"]
    (fitted,) = [e for e in report["effects"] if e["kind"] == "cosine"]
    # the line's scale, −θ²/2, is what the plan reads of a misalignment
    assert fitted["parameters"]["scale_ppm"] == pytest.approx(
        cosine["parameters"]["scale_ppm"], abs=0.5
    )


def test_a_set_up_error_second_to_a_surface_is_followed_to_the_end_of_a_second_route() -> None:
    # blind 45017 (displacement-only plan, 0.082 µm noise): a 16 mm cycle of Z, EY over Y×Z
    # (1.5 µm peak) and a 3.3 mrad misalignment of body_ppp (−5.3 ppm). Step 2 kept EY over X×Y
    # (0.152 µm held out) over the cosine error (0.167 µm), step 3 a second surface EY over
    # X×Z: 0.0935 µm, 25 parameters, 10 lines reported. The loop runs on from step 2 with the
    # cosine error kept instead, finds EY over Y×Z at step 3 and ends at 0.0836 µm with 8
    report, truth = _loop(45017)
    assert truth["category"] == "effects"
    assert _kept_places(report) == [("cosine", "body_ppp"), ("cross_axis", "Y"), ("cyclic", "Z")]
    (surface,) = [e for e in report["effects"] if e["kind"] == "cross_axis"]
    assert sorted(surface["parameters"]["depends_on"]) == ["Y", "Z"]
    assert report["unexplained"] == []
    (forked,) = [
        s for s in report["loop"] if s["step"] == 2 and s["kept"] and s["stage"] == "forward"
    ]
    assert forked["effect"]["kind"] == "cosine"
    assert "the loop ran on from this step both ways" in forked["reason"]
    (cosine,) = [e for e in truth["effects"] if e["kind"] == "cosine"]
    (fitted,) = [e for e in report["effects"] if e["kind"] == "cosine"]
    assert fitted["parameters"]["scale_ppm"] == pytest.approx(
        cosine["parameters"]["scale_ppm"], abs=0.5
    )


def test_a_surface_kept_over_its_other_family_of_as_many_terms_is_followed_both_ways() -> None:
    # blind 55024 (displacement-only plan, 0.051 µm noise): EY over X×Y (30× the noise), a
    # 4.4 mrad misalignment of y_lin_3 (−9.6 ppm) and a 79 mm Abbe offset of z_lin_1. Step 1
    # kept EY over X×Y at order 6 (0.0949 µm held out) over order 4 with lever-arm terms
    # (0.0953 µm), six terms each; the Abbe offset then read 110 mm, implausible, EZ over Y×Z
    # was kept at step 2 and the cosine error never showed: 0.0522 µm, 15 parameters. The loop
    # runs on from step 1 with the other family kept and ends with the three at 0.0519 µm, 10.
    report, truth = _loop(55024)
    assert truth["category"] == "effects"
    assert _kept_places(report) == [
        ("abbe_offset", "z_lin_1"),
        ("cosine", "y_lin_3"),
        ("cross_axis", "Y"),
    ]
    (surface,) = [e for e in report["effects"] if e["kind"] == "cross_axis"]
    assert sorted(surface["parameters"]["depends_on"]) == ["X", "Y"]
    (forked,) = [
        s for s in report["loop"] if s["step"] == 1 and s["kept"] and s["stage"] == "forward"
    ]
    assert forked["effect"]["kind"] == "cross_axis"
    assert "the loop ran on from this step both ways" in forked["reason"]
    (cosine,) = [e for e in truth["effects"] if e["kind"] == "cosine"]
    (fitted,) = [e for e in report["effects"] if e["kind"] == "cosine"]
    assert fitted["parameters"]["scale_ppm"] == pytest.approx(
        cosine["parameters"]["scale_ppm"], abs=0.5
    )


def test_a_round_the_audit_brings_back_to_its_start_runs_again_without_what_it_took_out() -> None:
    # blind 57197 (demo plan, 0.23 µm noise): a drift of X (12.0 ppm/°C, logged material
    # temperature) and misalignments of diag_xy_pm_b (-5.31 ppm) and diag_xy_pp_b (-4.79 ppm).
    # The first round kept a cosine error of x_linear in the drift's place (tied with it held
    # out, one parameter fewer) and the two diagonals' beside it; the audit took all three out
    # (x_linear still drifting, the X scale changing in time), back to the round's empty start,
    # and the loop stopped there with 20 lines reported. Run again with those three held back
    # until another effect is kept, the drift comes first and the two misalignments after it.
    report, truth = _loop(57197)
    assert truth["category"] == "effects"
    assert _kept_places(report) == [
        ("cosine", "diag_xy_pm_b"),
        ("cosine", "diag_xy_pp_b"),
        ("thermal_drift", "X"),
    ]
    audited = {s["effect"]["label"] for s in report["loop"] if s["stage"] == "audit"}
    assert "cosine misalignment of line x_linear" in audited
    (drift,) = [e for e in truth["effects"] if e["kind"] == "thermal_drift"]
    (fitted,) = [e for e in report["effects"] if e["kind"] == "thermal_drift"]
    assert fitted["parameters"]["expansion_ppm_per_c"] == pytest.approx(
        drift["parameters"]["alpha_ppm_per_K"], abs=0.5
    )
    for cosine in (e for e in truth["effects"] if e["kind"] == "cosine"):
        (fitted,) = [
            e for e in report["effects"] if e.get("parameters", {}).get("line") == cosine["line"]
        ]
        assert fitted["parameters"]["scale_ppm"] == pytest.approx(
            cosine["parameters"]["scale_ppm"], abs=0.3
        )


def test_a_drift_that_leaves_its_axis_scale_changing_is_read_again_in_another_form() -> None:
    # blind 57093 (displacement-only plan, 0.11 µm noise): a drift of X, τ 169 min, whose
    # temperature the files log at their two ends only, and a 78 mm Abbe offset of diag_xz_pp.
    # The drift was kept read as a straight line in temperature between the logs (a richer form
    # did not better it by the margin); x_lin_1 still followed a course in time (0.02 µm RMS,
    # 10⁻⁹ false alarm), the audit took diag_xz_pp's set-up error out for it, then the drift for
    # the sizes that left unequal, and 22 lines were reported. The audit reads the drift again in
    # the form with which the X scale stands still, and both stay: the set-up error as a cosine
    # error, the Abbe offset named as its rival (the plan cannot tell them apart).
    report, truth = _loop(57093)
    assert truth["category"] == "effects"
    assert _kept_places(report) == [("cosine", "diag_xz_pp"), ("thermal_drift", "X")]
    (cosine,) = [e for e in report["effects"] if e["kind"] == "cosine"]
    rivals = {(r["kind"], r["parameters"]["line"]) for r in cosine["rivals"]["effects"]}
    assert ("abbe_offset", "diag_xz_pp") in rivals
    (read_again,) = [
        s for s in report["loop"] if s["stage"] == "refine" and "in the final audit" in s["reason"]
    ]
    assert read_again["effect"]["kind"] == "thermal_drift"
    assert read_again["reason"].startswith("thermal drift X (material temperature) read again")
    (drift,) = [e for e in truth["effects"] if e["kind"] == "thermal_drift"]
    (fitted,) = [e for e in report["effects"] if e["kind"] == "thermal_drift"]
    p = drift["parameters"]
    assert fitted["parameters"]["time_constant_s"] == pytest.approx(60 * p["tau_min"], rel=0.1)
    assert fitted["parameters"]["scale_ppm"] == pytest.approx(
        p["alpha_ppm_per_K"] * p["delta_T_inf_K"], abs=0.5
    )


def test_a_surface_refused_for_a_line_it_leaves_gives_way_to_that_lines_set_up_error() -> None:
    # displacement-only plan, 0.41 µm noise: misalignments of body_ppp and diag_yz_pm and a
    # drift of X. A surface EY over X×Z stood in for body_ppp's cosine error (a cosine error of
    # another body diagonal beside it, the audit took both out, 11 lines reported; later the
    # surface gave way to it in the backward pass, asked twice). Judged without body_ppp, which
    # it leaves systematic, the surface is refused at step 3; body_ppp's cosine error, short of
    # the margin at step 2 while the drift was missing, is refitted in step 3 and kept there,
    # the surface's other order compared and not kept
    report, truth = _loop(41008)
    assert truth["category"] == "effects"
    assert _kept_places(report) == [
        ("cosine", "body_ppp"),
        ("cosine", "diag_yz_pm"),
        ("thermal_drift", "X"),
    ]
    (handed,) = [
        s
        for s in report["loop"]
        if s["kept"] and s["effect"]["label"] == "cosine misalignment of line body_ppp"
    ]
    assert handed["stage"] == "forward" and handed["verdict"] == "kept"
    earlier = [
        s
        for s in report["loop"]
        if s["effect"]["label"] == "cosine misalignment of line body_ppp"
        and s["step"] < handed["step"]
    ]
    assert [s["verdict"] for s in earlier] == ["below margin"], earlier
    carried = [
        s
        for s in report["loop"]
        if s["step"] == handed["step"] and "leaves systematic (body_ppp)" in s["reason"]
    ]
    assert carried and all(s["verdict"] == "not confirmed" for s in carried), carried
    refused = [
        s
        for s in report["loop"]
        if s["step"] == handed["step"] and s["effect"]["kind"] == "cross_axis"
    ]
    assert refused and all(not s["kept"] for s in refused)
    assert not any(s["stage"] in ("backward", "audit") for s in report["loop"])
    assert not report["unexplained"], report["unexplained"]


def test_a_surface_refused_while_another_effect_is_missing_is_tried_again_beside_it() -> None:
    # demo plan, 0.45 µm noise: surfaces EX over X×Z and EY over Y×Z and a local defect of Z in
    # X. At step 3 the surface EX over X×Z of order 4 was refused: beside it five lines the
    # local defect, still missing, spoils stayed systematic and took half its gain. The defect
    # was kept instead; refitted beside it at step 4, the surface of order 4 is kept, and
    # nothing is left unexplained (without the second try, order 3 was kept at a later step and
    # z_straight_x and z_straight_x_far were reported)
    report, truth = _loop(45093)
    assert truth["category"] == "effects"
    assert [(e["kind"], e["axis"]) for e in report["effects"]] == [
        ("cross_axis", "Y"),
        ("local", "Z"),
        ("cross_axis", "X"),
    ]
    *_, first, again = [
        s
        for s in report["loop"]
        if s["effect"]["label"] == "cross-axis EX over X×Z (order 4, with lever-arm terms)"
    ]
    assert not first["kept"] and "on lines it leaves systematic" in first["reason"]
    assert again["kept"] and again["step"] > first["step"]
    assert not report["unexplained"], report["unexplained"]


@pytest.mark.parametrize("seed", [21142, 26046, 26062])
def test_a_scale_oscillating_in_time_is_not_kept_as_cosine_errors_of_the_lines_that_read_short(
    seed: int,
) -> None:
    # demo plan, X (26046) or Y (21142, 26062) scale oscillating over 32-107 min: the lines
    # measured while it was short were kept as cosine errors; others along the same axes read
    # 1.4-5.8 ppm long beside them, which no misaligned beam does. The audit takes them out,
    # or, where the line repeats far worse than its peers (21142's body_mmp, 2.2 times), they
    # are refused at once: a set-up of a line that wanders is not kept
    report, truth = _loop(seed)
    assert truth["category"] == "outside"
    assert not report["effects"], report["effects"]
    assert report["unexplained"]
    audited = [
        s for s in report["loop"] if s["stage"] == "audit" and s["effect"]["kind"] == "cosine"
    ]
    wandering = [
        s
        for s in report["loop"]
        if s["effect"]["kind"] == "cosine"
        and s["verdict"] == "not repeatable"
        and "times its steadiest peers'" in s["reason"]
    ]
    assert audited or wandering
    assert all("longer than the model's scale" in s["reason"] for s in audited)
    # with nothing left kept, another round would repeat the first step for step
    kept = [s["effect"]["label"] for s in report["loop"] if s["stage"] == "forward" and s["kept"]]
    assert len(kept) == len(set(kept)), kept


def test_a_cycle_shorter_than_twice_the_spacing_is_found_where_irregular_targets_tell_it() -> None:
    # every line along Y has targets about every 10.7 mm, irregularly; the cycle is 9.94 mm with
    # its second harmonic: below two samples a period, but the irregular targets sample it at
    # phases its aliases do not fit, and the search holds it to twice every alias' gain
    report, truth = _loop(1061)
    (cycle,) = [e for e in truth["effects"] if e["kind"] == "cyclic"]
    kept = [e for e in report["effects"] if e["kind"] == "cyclic" and e["axis"] == "Y"]
    assert len(kept) == 1, report["effects"]
    parameters = kept[0]["parameters"]
    assert parameters["period_mm"] == pytest.approx(cycle["parameters"]["period_mm"], rel=0.002)
    h2 = cycle["parameters"]["harmonic2_amplitude_um"]
    assert parameters["amplitude_um_h2"] == pytest.approx(h2, rel=0.1)


def test_a_cycle_shorter_than_half_the_spacing_is_found_where_irregular_targets_tell_it() -> None:
    # twelve-line plan, targets 10-27 mm apart; a 6.0 mm cycle of Y, 1.4 µm, at 0.44 µm noise:
    # the search started at half the finest spacing (6.5 mm), nothing was kept and three lines
    # were reported with 1.3 µm each. No spacing of these targets repeats (their spectral window
    # stays below 0.5), so the search runs down to 2 mm and the alias guard holds
    report, truth = _loop(26083)
    (cycle,) = [e for e in truth["effects"] if e["kind"] == "cyclic"]
    kept = [e for e in report["effects"] if e["kind"] == "cyclic" and e["axis"] == "Y"]
    assert len(kept) == 1 and len(report["effects"]) == 1, report["effects"]
    period = cycle["parameters"]["period_mm"]
    assert kept[0]["parameters"]["period_mm"] == pytest.approx(period, rel=0.002)
    assert not report["unexplained"], report["unexplained"]
    assert not any("none shorter than" in w for w in report["warnings"]), report["warnings"]


def test_a_cycle_whose_second_harmonic_peaks_beside_it_is_found_at_its_own_period() -> None:
    # twelve-line plan, targets about every 15 mm (irregularly), 0.43 µm noise: a 15.4 mm cycle
    # of X, 2.4 µm with a 1.3 µm second harmonic. The search's alias guard held the 15.4 mm
    # peak to twice every other peak's gain, its own harmonic at 7.7 mm among them: it lost to
    # a 36 mm peak, a cycle of Y at 15.4 mm was kept for the diagonal and the audit took it out
    report, truth = _loop(48041)
    (cycle,) = truth["effects"]
    assert (cycle["kind"], cycle["axis"]) == ("cyclic", "X")
    (kept,) = report["effects"]
    assert (kept["kind"], kept["axis"]) == ("cyclic", "X"), report["effects"]
    parameters = kept["parameters"]
    assert parameters["period_mm"] == pytest.approx(cycle["parameters"]["period_mm"], rel=0.002)
    assert parameters["amplitude_um_h2"] == pytest.approx(
        cycle["parameters"]["harmonic2_amplitude_um"], rel=0.15
    )
    assert not report["unexplained"], report["unexplained"]


def test_a_cycle_whose_alias_fits_part_of_it_wins_by_what_noise_cannot_make() -> None:
    # blind 57023, twelve-line plan, targets 14-25 mm apart along Z, 0.11 µm noise: an 11.2 mm
    # cycle of Z, 1.0 µm with a 0.33 µm second harmonic. Its alias at 7.41 mm fits 877 σ² of
    # the cycle's 1460: 1.7 times, short of the guard's ratio of 2, and the search fell back to
    # a 36.4 mm peak of 141 σ²; two bumps of Z of 12.7 and 8.2 µm were kept and five lines
    # reported. 583 σ² apart is 7.6 spreads of the cycle's gain: no noise makes that
    report, truth = _loop(57023)
    (cycle,) = truth["effects"]
    assert (cycle["kind"], cycle["axis"]) == ("cyclic", "Z")
    assert _kept_places(report) == [("cyclic", "Z")], report["effects"]
    (kept,) = report["effects"]
    parameters, p = kept["parameters"], cycle["parameters"]
    assert parameters["period_mm"] == pytest.approx(p["period_mm"], rel=0.002)
    assert parameters["amplitude_um"] == pytest.approx(p["amplitude_um"], abs=0.03)
    assert parameters["amplitude_um_h2"] == pytest.approx(p["harmonic2_amplitude_um"], abs=0.03)
    assert not report["unexplained"], report["unexplained"]


def test_a_cycle_with_its_second_harmonic_is_placed_with_it_and_leaves_no_bump() -> None:
    # demo plan, 0.086 µm noise: a 33.671 mm cycle of X (1.9 µm, second harmonic 0.73 µm), 20
    # periods over the stroke. Its period was refined as a pure sine and kept, with its harmonic,
    # at 33.691 mm: over the far periods the phase slipped and a bump of X at 366 mm was kept for
    # it (8.8 % better over the readings within its reach). Refined with its harmonic, the cycle
    # leaves nothing
    report, truth = _loop(53117)
    (cycle,) = truth["effects"]
    assert (cycle["kind"], cycle["axis"]) == ("cyclic", "X")
    (kept,) = report["effects"]
    assert (kept["kind"], kept["axis"]) == ("cyclic", "X"), report["effects"]
    # 20 periods: 0.02 mm off slips the phase by 0.07 rad at the stroke's end
    assert kept["parameters"]["period_mm"] == pytest.approx(
        cycle["parameters"]["period_mm"], rel=2e-4
    )
    assert not report["unexplained"], report["unexplained"]


def test_a_bump_diagonals_put_on_either_axis_is_kept_on_the_one_no_line_contradicts() -> None:
    # demo plan, 0.055 µm noise: a triangular bump of X in X (4.5 µm, 37 mm wide at half height,
    # at 318 mm). The free profile left its foot at 282 mm, which three XZ diagonals cross at
    # Z = 247 mm: a bump of Z in X there fitted it 0.2 % better than one of X and was kept, though
    # the diagonal descending in Z crosses Z = 247 mm at X = 118 mm, showed it with 17.4 σ² and
    # lost 14.7 σ² held out. A line that shows a shape and is predicted worse with it refuses it.
    # (Since no bump is proposed where a kept one of its function spans, the foot is no longer
    # fitted by bumps of X beside the first; what it leaves, diag_xz_pm_b alone shows.)
    report, truth = _loop(54062)
    (bump,) = truth["effects"]
    assert (bump["kind"], bump["axis"], bump["parameters"]["direction"]) == ("local", "X", "X")
    assert {(e["kind"], e["axis"], e["parameters"]["direction"]) for e in report["effects"]} == {
        ("local", "X", "X")
    }, report["effects"]
    refused = [
        s
        for s in report["loop"]
        if s["effect"]["label"].startswith("local defect Z in X") and not s["kept"]
    ]
    assert refused and all("diag_xz_pm_b" in s["reason"] for s in refused)


def test_a_line_that_shows_a_bump_and_is_predicted_worse_with_it_refuses_it() -> None:
    # the rule of blind 54062 above, on the numbers it met there: diag_xz_pm_b showed the bump of
    # Z with 17.4 σ² and lost 14.7 σ² held out; the XZ diagonals that gained are not asked
    from types import SimpleNamespace

    from volucal.core.loop_judge import contradicted_by_a_line

    names = ("diag_xz_pp", "diag_xz_pp_b", "diag_xz_pm_b", "x_linear")
    readings = SimpleNamespace(lines=[SimpleNamespace(name=n) for n in names])
    energy = np.array([40.0, 35.0, 17.4, 3.0])
    why = contradicted_by_a_line(energy, np.array([30.0, 28.0, -14.7, -2.5]), readings)
    assert why is not None and why.startswith("line diag_xz_pm_b shows it (17.4 σ²")
    # predicted worse by less than half of what it shows, or shown by less than 16 σ²: not asked
    assert contradicted_by_a_line(energy, np.array([30.0, 28.0, -8.0, -2.5]), readings) is None
    assert contradicted_by_a_line(energy, np.array([30.0, 28.0, 5.0, -2.9]), readings) is None


def test_a_bump_held_out_blocks_of_its_line_predict_worse_is_kept_beside_a_missing_cycle() -> None:
    # twelve-line plan, held-out blocks: a 4.8 µm bump of Z at 71 mm beside a 25 mm cycle of Z
    # and a faint bump of X. At step 1, with the cycle still missing, z_lin_2's held-out blocks
    # are predicted 40 σ² worse with the bump (25 σ² shown): predicted with the rest of their
    # own line, they carry what it lacks. Only held-out lines contradict a bump; all three kept
    report, truth = _loop(53121)
    injected = {(e["kind"], e["axis"]) for e in truth["effects"]}
    assert injected == {("local", "Z"), ("cyclic", "Z"), ("local", "X")}
    assert {(e["kind"], e["axis"]) for e in report["effects"]} == injected, report["effects"]
    assert not any("contradict" in s["reason"] for s in report["loop"])


def test_a_surface_a_held_out_body_diagonal_is_predicted_worse_with_is_kept() -> None:
    # demo plan, 0.14 µm noise: a surface EY over X×Y (2.8 µm) and a 72 mm Abbe offset of
    # diag_yz_pm_b. Held out, body_pmp (which separates the surface from the squareness errors)
    # is predicted 426 σ² worse with the surface, though it shows 184 σ² of it: a surface is not
    # refused as contradicted by a line, as a local defect is, and both effects are kept
    report, truth = _loop(54099)
    assert {(e["kind"], e.get("line") or e["axis"]) for e in truth["effects"]} == {
        ("cross_axis", "Y"),
        ("abbe_offset", "diag_yz_pm_b"),
    }
    kept = {(e["kind"], e["axis"]) for e in report["effects"]}
    assert ("cross_axis", "Y") in kept and len(report["effects"]) == 2, report["effects"]
    (offset,) = [e for e in report["effects"] if e["kind"] == "abbe_offset"]
    assert offset["parameters"]["line"] == "diag_yz_pm_b"
    assert not report["unexplained"], report["unexplained"]


def test_a_surface_the_plan_cannot_place_is_kept_with_a_warning_naming_its_rival() -> None:
    # the direct plan measures each function on one line: EY over X×Z (the truth) and EY over Y×Z
    # predict the held-out blocks alike (0.0995 and 0.0996 µm); the loop keeps one and says so
    report, truth = _loop(1097)
    (surface,) = truth["effects"]
    assert surface["kind"] == "cross_axis" and surface["axis"] == "Y"
    kept = [e for e in report["effects"] if e["kind"] == "cross_axis"]
    assert len(kept) == 1 and kept[0]["axis"] == "Y"
    alike = [w for w in report["warnings"] if "cannot tell which direction and pair" in w]
    assert len(alike) == 1
    # report.json names the rivals beside the kept surface: the truth is one of the two
    places = {
        (e["axis"], tuple(sorted(e["parameters"]["depends_on"])))
        for e in [kept[0], *kept[0]["rivals"]["effects"]]
    }
    assert ("Y", tuple(sorted(surface["depends_on"]))) in places
    scores = [r["cv_rms_all_lines"] for r in kept[0]["rivals"]["effects"]]
    assert max(scores) <= kept[0]["rivals"]["kept_cv_rms_all_lines"] * 1.01
    assert "EY over X×Z" in alike[0] and "EY over Y×Z" in alike[0]


def test_two_abbe_offsets_that_hide_each_other_are_kept_together() -> None:
    # full plan, 0.25 µm noise: y_linear and y_linear_side both read 41 mm off the beam beside a
    # 16 mm cycle of Y. Either offset alone predicted the held-out lines no better (the 21
    # errors share both between the two lines); a surface EY over X×Y stood in for them and
    # three lines were reported. A surface that leaves both lines systematic is refused now and
    # hands on their set-up errors, tried together in the same step: kept together, nothing is
    # left unexplained
    report, truth = _loop(27006)
    offsets = {e["line"]: e["parameters"] for e in truth["effects"] if e["kind"] == "abbe_offset"}
    kept = {e["parameters"]["line"]: e["parameters"] for e in report["effects"] if not e["axis"]}
    assert kept.keys() == offsets.keys() == {"y_linear", "y_linear_side"}
    assert {e["kind"] for e in report["effects"]} == {"cyclic", "abbe_offset"}
    together = [s["effect"]["label"] for s in report["loop"] if s["verdict"] == "kept together"]
    assert sorted(together) == [f"Abbe offset of line {line}" for line in sorted(offsets)]
    for line, injected in offsets.items():
        fitted = np.array(kept[line]["offset_mm"])
        std = np.array(kept[line]["offset_std_mm"])
        moved = std > 1e-9  # the offset along the beam reads nothing on the line (round-off)
        assert np.all(abs(fitted - injected["offset_mm"])[moved] <= 3.0 * std[moved]), line
    assert not report["unexplained"], report["unexplained"]


def test_an_abbe_offset_and_a_cosine_error_of_one_line_are_kept_together() -> None:
    # the generator's plan, 0.14 µm noise: diag_xy_pp reads 80 mm off the beam (in Z) and the
    # beam is tilted 3.4 mrad (−5.9 ppm). Alone, the offset took the tilt's scale and grew to
    # 146 mm (beyond the 100 mm a set-up can be off), the cosine error took the lever arm's term
    # and changed along the line: both were refused and five lines were reported. Refitted
    # together, each passes every rule and nothing is left unexplained
    report, truth = _loop(37156)
    injected = {e["kind"]: e["parameters"] for e in truth["effects"]}
    assert injected.keys() == {"abbe_offset", "cosine"}
    kept = {e["kind"]: e["parameters"] for e in report["effects"]}
    assert kept.keys() == {"abbe_offset", "cosine"}
    assert {p["line"] for p in kept.values()} == {"diag_xy_pp"}
    together = [s["effect"]["kind"] for s in report["loop"] if s["verdict"] == "kept together"]
    assert sorted(together) == ["abbe_offset", "cosine"]
    fitted = np.array(kept["abbe_offset"]["offset_mm"])
    std = np.array(kept["abbe_offset"]["offset_std_mm"])
    assert np.all(abs(fitted - injected["abbe_offset"]["offset_mm"]) <= 3.0 * std)
    scale = kept["cosine"]
    assert abs(scale["scale_ppm"] - injected["cosine"]["scale_ppm"]) <= 3.0 * scale["scale_std_ppm"]
    assert not report["unexplained"], report["unexplained"]


def test_a_drift_is_placed_again_beside_an_offset_it_held_and_both_are_kept() -> None:
    # demo plan, 0.053 µm noise: a drift of X (τ 195 min) and diag_xy_pp_b read 56 mm off the
    # beam in Z. The drift kept first placed its τ at 346 min, taking part of the offset's
    # structure; fixed there, the offset predicted the held-out lines 16 % worse and was
    # refused, then the audit took the drift out (its size differed on the offset's line) and
    # nothing was kept, 21 lines reported. With τ estimated again beside it, the offset passes
    report, truth = _loop(38111)
    injected = {e["kind"]: e["parameters"] for e in truth["effects"]}
    assert injected.keys() == {"abbe_offset", "thermal_drift"}
    kept = {e["kind"]: e["parameters"] for e in report["effects"]}
    assert kept.keys() == {"abbe_offset", "thermal_drift"}
    offset = kept["abbe_offset"]
    assert offset["line"] == "diag_xy_pp_b"
    # the lever arm acts through the identified angles: iterated with them, it settles within
    # its stated uncertainty (one solve from the angles fitted without it left (3.5, −3.5,
    # 61.7) mm, 12 σ out)
    fitted, std = np.array(offset["offset_mm"]), np.array(offset["offset_std_mm"])
    moved = std > 1e-9  # the offset along the beam reads nothing on the line
    assert np.all(abs(fitted - injected["abbe_offset"]["offset_mm"])[moved] <= 3.0 * std[moved])
    # the time constant settles within 5 % of the injected one (346 min before)
    tau = kept["thermal_drift"]["time_constant_s"] / 60.0
    assert tau == pytest.approx(injected["thermal_drift"]["tau_min"], rel=0.05)
    moves = [s for s in report["loop"] if s["stage"] == "refine" and s["kept"]]
    assert any(s["effect"]["kind"] == "thermal_drift" for s in moves)
    assert not report["unexplained"], report["unexplained"]


def test_a_drift_at_another_peak_of_its_time_constant_is_placed_again_beside_a_set_up() -> None:
    # demo plan, 0.33 µm noise: a 16 mm cycle of X, a drift of X (τ 35 min) and a cosine error
    # of diag_xy_pp (-7.25 ppm). τ's search has two peaks; without the cosine error the long
    # one won (339 min: a line's scale reads as the straight course of a long τ). Held there,
    # the cosine error predicted the held-out lines 10 % worse; the audit took the drift out
    # and only the cycle was kept, nine lines reported. Each refit beside a drift now places
    # its τ again over the whole range, and says so in the row
    report, truth = _loop(49090)
    injected = {e["kind"]: e["parameters"] for e in truth["effects"]}
    assert _kept_places(report) == [
        ("cosine", "diag_xy_pp"),
        ("cyclic", "X"),
        ("thermal_drift", "X"),
    ]
    kept = {e["kind"]: e["parameters"] for e in report["effects"]}
    tau = kept["thermal_drift"]["time_constant_s"] / 60.0
    assert tau == pytest.approx(injected["thermal_drift"]["tau_min"], rel=0.1)
    assert kept["cosine"]["scale_ppm"] == pytest.approx(injected["cosine"]["scale_ppm"], abs=0.5)
    (row,) = [
        s
        for s in report["loop"]
        if s["kept"] and s["stage"] == "forward" and s["effect"]["kind"] == "cosine"
    ]
    moved = re.search(
        r"thermal drift X \(time\) placed again with it: τ (\S+) min → τ (\S+) min", row["reason"]
    )
    assert moved, row["reason"]
    before, after = float(moved.group(1)), float(moved.group(2))
    assert before > np.e * after  # from the other peak, not the refinement's factor e
    assert after == pytest.approx(injected["thermal_drift"]["tau_min"], rel=0.1)
    assert not report["unexplained"], report["unexplained"]


def test_a_cycle_near_the_screw_lead_is_placed_at_its_own_period() -> None:
    # twelve-line plan, 0.08 µm noise: a cycle of X at the 16 mm lead, one of Z at 15.84 mm
    # (not the lead) and a drift of X. Z's cycle was kept at the 16 mm lead, a quarter period
    # out of phase over the stroke; the drift then earned 2.5 % and was refused, eight lines
    # reported. The lead's cycle moves off the lead where the data say so beyond the noise
    report, truth = _loop(38058)
    (z_cycle,) = [e for e in truth["effects"] if e["kind"] == "cyclic" and e["axis"] == "Z"]
    assert not z_cycle["parameters"]["at_screw_lead"]
    assert {(e["kind"], e["axis"]) for e in report["effects"]} == {
        ("cyclic", "X"),
        ("cyclic", "Z"),
        ("thermal_drift", "X"),
    }
    periods = {
        e["axis"]: e["parameters"]["period_mm"] for e in report["effects"] if e["kind"] == "cyclic"
    }
    assert periods["X"] == 16.0  # the lead's cycle stays at the lead
    assert periods["Z"] == pytest.approx(z_cycle["parameters"]["period_mm"], rel=0.002)
    assert not report["unexplained"], report["unexplained"]


def test_the_errors_beside_a_drift_state_what_its_time_constant_leaves_open() -> None:
    # demo plan, 0.25 µm noise: Y warms (τ 192 min) and body_mpp reads 55 mm off the beam. Both
    # are kept, τ at 240 min; the static Y scale takes what the drift's shape misses and the Y
    # positioning came out 0.52 µm off, 6.5 of its stated standard uncertainties (a refit holds
    # τ fixed). The errors' uncertainty now holds their moves across τ's own
    outcome = run_blind(38021)
    assert outcome.kept == outcome.expected
    assert outcome.band_ratio <= 3.0, outcome.function_error


@pytest.mark.parametrize(
    ("seed", "axis", "line", "change_c"),
    [
        # demo plan: Y warms by 2.4 °C (τ 80 min) and its first line is measured at 190 min;
        # two Abbe offsets of Y lines beside it, and the audit takes the drift out. EYY was
        # 5.9 µm from the machine at the first reading, 11 times its stated uncertainty, and
        # nothing named it
        (54085, "Y", "y_linear", 2.2),
        # the paper's twelve-line plan: X warms by 1.6 °C and no drift is kept (a bump on Z
        # is); EXX was 4.3 µm from the machine at the first reading, 39 times its stated
        # uncertainty
        (54026, "X", "x_lin_3", 1.6),
    ],
)
def test_a_scale_no_line_read_near_the_first_readings_temperature_is_in_its_uncertainty(
    seed: int, axis: str, line: str, change_c: float
) -> None:
    from score_blind import _accuracy

    result, truth = _loop_result(seed)
    report = result.to_report()
    (drift,) = [e for e in truth["effects"] if e["kind"] == "thermal_drift"]
    assert drift["axis"] == axis
    assert axis not in {e.axis for e in result.kept if e.kind == "thermal_drift"}
    doubt = {d["axis"]: d for d in report["temperature_doubts"]}[axis]
    assert doubt["error"] == f"E{axis}{axis}" and doubt["line"] == line
    assert doubt["material_change_c"] == pytest.approx(change_c, abs=0.1)
    # the generator's files state 11.5 ppm/°C
    assert doubt["half_width_ppm"] == pytest.approx(11.5 * doubt["material_change_c"], rel=1e-3)
    assert any(f"refers the {axis} scale back" in w for w in report["warnings"])
    functions, _, ratios = _accuracy(seed, truth, result)
    # the doubt widens the error's uncertainty; it does not move the error
    assert functions[f"E{axis}{axis}"] > 4.0, functions
    assert ratios[f"E{axis}{axis}"] < 3.0, ratios


def test_an_axis_whose_lines_read_no_change_with_the_temperature_has_no_doubt_from_it() -> None:
    # blind 54085: x_linear was measured 0.43 °C above the first reading, the other X lines
    # 2.4 °C above it, and they read one X scale (|κ| + 2u(κ) = 0.15 ppm/°C): the X scale did
    # not follow the temperature, and 0.43 °C at 11.5 ppm/°C (0.66 µm RMS, 3.6 times EXX's
    # stated uncertainty) is not added
    result, _ = _loop_result(54085)
    doubts = {d.axis: d for d in result.temperature_doubts}
    assert "X" not in doubts
    # Z's lines, at 2.37 to 2.41 °C, bound its following only loosely (above α): α bounds it
    z = doubts["Z"]
    assert z.half_width_ppm == pytest.approx(abs(z.change_c) * z.expansion_ppm_per_c)
    # where the first reading logs no temperature, nothing says how far it changed since; where
    # a Y line logs none, that line may have read the Y scale at the first reading's
    from dataclasses import replace

    from volucal.core.loop_scale import temperature_doubts

    base = result.base
    readings = base.readings
    assert {d.axis for d in temperature_doubts(base, base)} == {"Y", "Z"}

    def without(rows: np.ndarray) -> list:  # type: ignore[type-arg]
        temperature = readings.material_temp_c.copy()
        temperature[rows] = np.nan
        unlogged = replace(base, readings=replace(readings, material_temp_c=temperature))
        return temperature_doubts(unlogged, unlogged)

    assert without(np.array([int(np.argmin(readings.time_s))])) == []
    # nor does the bound, with a reading without a temperature: X is given α's doubt again
    y_linear = readings.line_names.index("y_linear")
    assert {d.axis for d in without(readings.line == y_linear)} == {"X", "Z"}


def test_a_kept_drift_refers_its_axis_scale_back_and_leaves_it_no_temperature_doubt() -> None:
    # twelve-line plan: X warms (material temperature logged) and the drift is kept
    result, _ = _loop_result(61080)
    assert "X" in {e.axis for e in result.kept if e.kind == "thermal_drift"}
    assert "X" not in {d.axis for d in result.temperature_doubts}


def test_a_material_temperature_that_does_not_change_puts_no_doubt_on_the_scales() -> None:
    # a clean machine (the paper's twelve-line plan) whose files log the material temperature,
    # steady over the session
    result, truth = _loop_result(53001)
    assert truth["effects"] == []
    temperature = result.final.readings.material_temp_c
    assert np.isfinite(temperature).all() and np.ptp(temperature) < 0.05
    assert result.temperature_doubts == ()
    assert "temperature_doubts" not in result.to_report()


def test_a_basis_that_predicts_the_lengths_better_widens_the_errors_uncertainty() -> None:
    # demo plan, 0.40 µm noise: the 150 mm basis predicts the held-out readings best over all
    # (1.3 % better than 100 mm, beyond the 1 % tie) but the lengths worse than 100 mm; at 150
    # mm the straightness EXZ came out 0.50 µm off, 7.9 of its stated standard uncertainties.
    # A spacing that predicts the lengths better is a rival the plan cannot rank below it
    outcome = run_blind(39087)
    assert outcome.kept == outcome.expected
    assert outcome.basis_mm == 150.0
    assert outcome.band_ratio <= 3.0, outcome.function_error


def test_the_errors_stated_uncertainty_holds_what_a_coarser_basis_misses_of_their_shape() -> None:
    # demo plan, a clean machine, 0.18 µm noise, measured again with fresh noise: the loop keeps
    # 150 mm in some re-measurements (every line predicted 0.14 % better than at 100 mm, the
    # lengths 1.1 % worse), 100 or 75 mm in others, and the coarser basis misses the bend of the
    # Z positioning the same way every time: EZZ came out 0.13 µm off at 150 mm, and over draws
    # 1 to 8 3.0 times the RMS error its band stated (mean square 9.3; 0.7 with the basis held at
    # 50 mm). The band now holds what the basis misses against the finest spacing tried
    ratios = []
    for draw in (1, 3, 4, 5, 6, 7, 8):
        outcome = run_blind(590005, noise_draw=draw)
        assert not outcome.kept  # a clean machine
        ratios.append(outcome.function_error["EZZ"] / outcome.expected_error["EZZ"])
    assert np.mean(np.square(ratios)) < 2.5, ratios

    report, _ = _loop(590005, noise_draw=2)
    basis = report["basis"]
    assert basis["spacing_mm"] == 150.0
    missed = basis["shape_missed"]
    assert missed["against_spacing_mm"] == 50.0
    # the EZZ miss estimated from the data alone, against 0.127 µm from the truth in that draw
    assert 0.06 < missed["rms"]["EZZ"] < 0.25
    from volucal.core.calibrate import summary_table

    table = summary_table(
        {
            **report,
            "lines": 0,
            "readings": 0,
            "identifiability": {"rank": 0, "unknowns": 0, "unidentifiable": []},
        }
    )
    (line,) = [row for row in table.splitlines() if "misses of the errors' shape" in row]
    assert "against 50 mm" in line and f"EZZ {missed['rms']['EZZ']:.3f} µm" in line


def test_a_cosine_error_too_large_beside_a_missing_surface_is_kept_once_the_surface_is() -> None:
    # demo plan; y_linear_side's beam is tilted by 4051 µrad beside a surface EY over X×Y
    # (0.17 µm noise). Without the surface the cosine fitted 6702 µrad, past the 5000 µrad
    # alignment allows, and was refused as implausible; the surface kept, its F statistic stayed
    # below the retry factor and it was never refitted: nine lines were reported unexplained. A
    # set-up effect refused as implausible is refitted after another keep, whatever its F
    report, truth = _loop(28048)
    (tilt,) = [e for e in truth["effects"] if e["kind"] == "cosine"]
    assert {(e["kind"], e["axis"]) for e in report["effects"]} == {
        ("cross_axis", "Y"),
        ("cosine", None),
    }
    (cosine,) = [e["parameters"] for e in report["effects"] if e["kind"] == "cosine"]
    assert cosine["line"] == tilt["line"]
    assert (
        abs(cosine["scale_ppm"] - tilt["parameters"]["scale_ppm"]) <= 3.0 * cosine["scale_std_ppm"]
    )
    refused = [s for s in report["loop"] if s["verdict"] == "implausible"]
    assert any(
        s["effect"]["label"] == f"cosine misalignment of line {tilt['line']}" for s in refused
    )
    assert not report["unexplained"], report["unexplained"]


def test_an_abbe_offset_a_surface_fits_as_well_on_its_one_line_is_kept_not_the_surface() -> None:
    # direct plan, 0.06 µm noise: a reversal of Z, a bump of X in Y and a 71 mm Abbe offset
    # (along X) of diag_yz_pp, the one line that moves Y and Z together. At the third step what
    # is left is that line's: six places of a surface of order 8 fit it with the same gain to
    # three figures and filled the batch, and the Abbe offset, with that gain, was never refitted:
    # a surface EZ over Y×Z was kept for it. A set-up effect whose gain ties the strongest's is
    # refitted beside them, and the tie rule keeps it for its three parameters; the surfaces
    # that predict as well are named beside it
    report, truth = _loop(29039)
    (offset,) = [e for e in truth["effects"] if e["kind"] == "abbe_offset"]
    assert {(e["kind"], e["axis"]) for e in report["effects"]} == {
        ("reversal", "Z"),
        ("local", "X"),
        ("abbe_offset", None),
    }
    (kept,) = [e["parameters"] for e in report["effects"] if e["kind"] == "abbe_offset"]
    assert kept["line"] == offset["line"]
    # the plan reads the offset along X through the diagonal's angles, part of which the 21
    # errors take: 62 of the 71 mm injected are fitted
    injected = np.array(offset["parameters"]["offset_mm"])
    assert np.linalg.norm(np.array(kept["offset_mm"]) - injected) <= 0.2 * np.linalg.norm(injected)
    # the reversal of Z changes from 2.35 to 2.14 µm over the stroke: its slope earns 0.6 % held
    # out over the plan, 3.1 % over the lines that move Z, and is kept; nothing is left
    (injected,) = [e["parameters"] for e in truth["effects"] if e["kind"] == "reversal"]
    change = injected["B_at_stroke_end_um"] - injected["B_at_stroke_start_um"]
    (reversal,) = [e for e in report["effects"] if e["kind"] == "reversal"]
    assert reversal["label"] == "reversal Z (position-dependent)"
    p = reversal["parameters"]
    assert abs(p["slope_um_per_stroke"] - change) <= 3.0 * p["slope_std_um_per_stroke"]
    assert report["unexplained"] == []
    (entry,) = [e for e in report["effects"] if e["kind"] == "abbe_offset"]
    assert {r["kind"] for r in entry["rivals"]["effects"]} == {"cross_axis"}
    assert any(
        "cannot tell line diag_yz_pp's set-up from an error" in w for w in report["warnings"]
    )


def test_the_lines_whose_set_up_error_fits_alike_are_named_beside_the_one_kept() -> None:
    # displacement-only plan, 0.12 µm noise: a cycle of X and cosine errors of diag_xz_pp and
    # diag_yz_pp_offset. The 21 errors tie the three offset diagonals: a cosine error of any of
    # them fits the readings alike, and the first, diag_xy_pp_offset's, was kept; the injected
    # line was never refitted, so never named. Each such line is refitted to be named, and the
    # errors' bands take in what the choice moves
    report, truth = _loop(50091)
    injected = {e["line"] for e in truth["effects"] if e["kind"] == "cosine"}
    assert injected == {"diag_xz_pp", "diag_yz_pp_offset"}
    cosines = [e for e in report["effects"] if e["kind"] == "cosine"]
    kept = {e["parameters"]["line"] for e in cosines}
    assert "diag_xz_pp" in kept
    (tied,) = [e for e in cosines if e["parameters"]["line"] != "diag_xz_pp"]
    named = {
        r["label"].removeprefix("cosine misalignment of line ")
        for r in tied["rivals"]["effects"]
        if r["kind"] == "cosine"
    }
    offsets = {"diag_xy_pp_offset", "diag_xz_pp_offset", "diag_yz_pp_offset"}
    assert named | {tied["parameters"]["line"]} == offsets
    assert any("this plan cannot tell which line's set-up it is" in w for w in report["warnings"])


def test_a_first_line_s_cosine_error_a_drift_fits_as_well_is_stated_with_that_doubt() -> None:
    # demo plan, 0.22 µm noise: X expands by 5.5 ppm over the session (τ 61 min) and only
    # x_linear, the first line, sees it before it settles; there it reads as the line's short
    # scale, and a cosine error of x_linear (one parameter) ties the drift (two): it is kept.
    # The report must not claim the plan settled it: the drift is named as its rival and the
    # errors' bands take in the move to it
    report, _ = _loop(30100)
    (entry,) = [e for e in report["effects"] if e["kind"] == "cosine"]
    assert {r["kind"] for r in entry["rivals"]["effects"]} == {"thermal_drift"}
    (warning,) = [w for w in report["warnings"] if "cannot tell line x_linear's set-up" in w]
    assert "thermal drift X" in warning


def test_a_drift_a_cosine_error_predicts_better_on_its_one_line_alone_is_named_its_rival() -> None:
    # demo plan, 0.15 µm noise: X expands by 11.4 ppm/K over 0.35 K (τ 3.9 h) and only x_linear
    # shows it beyond the 21 errors. A cosine error of x_linear is kept; the drift predicts the
    # held-out data 1.7 % worse over all, more than the 1 % tie, but not line by line: held out
    # x_linear, it is estimated from lines it barely reaches. The plan cannot rank it below the
    # cosine error, and the report names it, fitted where the machine has it
    report, truth = _loop(55102)
    (drift,) = truth["effects"]
    assert drift["kind"] == "thermal_drift" and drift["axis"] == "X"
    (entry,) = [e for e in report["effects"] if e["kind"] == "cosine"]
    (rival,) = entry["rivals"]["effects"]
    assert rival["label"] == "thermal drift X (time)"
    assert entry["rivals"]["kept_cv_rms_all_lines"] < rival["cv_rms_all_lines"]
    p = drift["parameters"]
    scale = p["alpha_ppm_per_K"] * p["delta_T_inf_K"]
    assert rival["parameters"]["scale_ppm"] == pytest.approx(scale, abs=0.2)
    assert rival["parameters"]["time_constant_s"] / 60 == pytest.approx(p["tau_min"], rel=0.1)
    (warning,) = [w for w in report["warnings"] if "cannot tell line x_linear's set-up" in w]
    assert "not significantly worse (paired t below 2)" in warning


def test_a_line_s_abbe_offset_as_strong_as_its_kept_cosine_error_is_refitted_and_named() -> None:
    # demo plan, 0.17 µm noise: diag_xy_pp_b's reflector sits 58 mm below where the plan puts
    # it. The diagnosis gives that offset 1892 σ² and a cosine error of the line 1900; the step
    # refitted the cosine error and two surfaces, kept the cosine error and never named the
    # offset. The offset is refitted after the keep, named as the cosine error's rival and found
    # where the reflector is
    report, truth = _loop(53140)
    (abbe,) = [e for e in truth["effects"] if e["kind"] == "abbe_offset"]
    (entry,) = [e for e in report["effects"] if e["kind"] == "cosine"]
    assert entry["parameters"]["line"] == abbe["line"] == "diag_xy_pp_b"
    (rival,) = [r for r in entry["rivals"]["effects"] if r["kind"] == "abbe_offset"]
    assert rival["label"] == "Abbe offset of line diag_xy_pp_b"
    offset = np.array(rival["parameters"]["offset_mm"])
    assert np.abs(offset - np.array(abbe["parameters"]["offset_mm"])).max() < 6.0
    assert any(
        w.startswith(
            "cosine misalignment of line diag_xy_pp_b was kept, but Abbe offset of line "
            "diag_xy_pp_b predicts the held-out data as well"
        )
        and "optics sit off the beam or its beam is tilted" in w
        for w in report["warnings"]
    )


def test_a_drift_only_a_line_moving_two_axes_shows_names_the_other_axis_its_rival() -> None:
    # demo plan, 0.46 µm noise: Y expands by 11.1 ppm/K over 1.9 K (τ 57 min) and only
    # diag_xy_pp, which moves X and Y alike, shows it beyond the 21 errors. A drift of X is
    # kept (21 ppm, τ 56 min); the drift of Y predicts the held-out data 2.8 % worse over all
    # but not line by line. The report must not say the plan chose the axis
    report, truth = _loop(50193)
    assert [(e["kind"], e["axis"]) for e in truth["effects"] if e["kind"] == "thermal_drift"] == [
        ("thermal_drift", "Y")
    ]
    (entry,) = [e for e in report["effects"] if e["kind"] == "thermal_drift"]
    assert entry["axis"] == "X"
    assert [r["label"] for r in entry["rivals"]["effects"]] == ["thermal drift Y (time)"]
    (warning,) = [w for w in report["warnings"] if "which axis' scale drifts" in w]
    assert warning.startswith("thermal drift X (time) was kept, but thermal drift Y (time)")
    assert "Lines along X and Y alone" in warning


@pytest.mark.parametrize("seed", [26162, 27068])
def test_a_surface_the_plan_sees_alike_at_every_place_is_named_among_the_rivals(seed: int) -> None:
    # direct plan, one surface seen on one diagonal: every direction and pair of axes fits it
    # within 1 % of the diagnosis' gain; the step refits its three strongest and the injected
    # one was fourth (EY over Y×Z, 27068) or sixth (EZ over X×Y, 26162): kept on another place,
    # it was not named. Every place the diagnosis gives nearly the same gain is now refitted
    report, truth = _loop(seed)
    (surface,) = [e for e in truth["effects"] if e["kind"] == "cross_axis"]
    (kept,) = [e for e in report["effects"] if e["kind"] == "cross_axis"]
    places = {
        (e["axis"], tuple(sorted(e["parameters"]["depends_on"])))
        for e in [kept, *kept["rivals"]["effects"]]
    }
    assert (surface["axis"], tuple(sorted(surface["depends_on"]))) in places
    scores = [r["cv_rms_all_lines"] for r in kept["rivals"]["effects"]]
    assert max(scores) <= kept["rivals"]["kept_cv_rms_all_lines"] * 1.01
    assert any("cannot tell which direction and pair" in w for w in report["warnings"])


def test_a_bump_one_line_alone_shows_is_reported_with_the_effects_that_would_explain_it() -> None:
    # twelve-line plan: a 1.0 µm bump of EYX at X 319 mm that only diag_xy_pp shows. A local
    # defect of Y along X or of X along Y fits it alike at step 1, 14.4 % better held out, and is
    # refused as one line cannot tell it from its own set-up; the report said "no effect of the
    # catalogue explains it" of the line. It names both now, and what would tell
    report, truth = _loop(53046)
    (bump,) = truth["effects"]
    assert report["effects"] == []
    (item,) = report["unexplained"]
    assert item["where"].startswith("line diag_xy_pp at ")
    named = item["one_line_effects"]
    assert {(e["kind"], e["axis"], e["parameters"]["direction"]) for e in named} == {
        ("local", "X", "Y"),
        ("local", "Y", "X"),
    }
    for effect in named:
        assert effect["step"] == 1
        assert effect["held_out_gain_percent"] == pytest.approx(14.4, abs=1.5)
        assert "held_out_over" not in effect  # the gain is over the plan
        assert effect["parameters"]["peak_mm"] == pytest.approx(
            bump["parameters"]["centre_mm"], abs=15.0
        )
        assert effect["label"] in item["description"]
    assert "no effect of the catalogue explains it" not in item["description"]
    assert "only this line shows it" in item["description"]
    assert "a second line that reads the same error there would tell" in item["description"]
    # the suite counts them as the loop would have kept them without the one-line rule
    assert one_line_refused(report) == {("local", "X in Y"), ("local", "Y in X")}


def test_a_surface_that_explains_its_one_line_but_a_remainder_stays_is_kept() -> None:
    # direct plan: a 4.6 µm surface EZ over Y×Z that only diag_yz_pp shows, beside a triangular
    # bump of EYZ whose tip the free profile rounds (a 0.17 µm wiggle stays on diag_yz_pp). The
    # surface takes 91 % of the line's mean square, yet the line stayed systematic, and refitted
    # without it the surface had nothing left to gain: the audit took it out, 14 lines reported
    report, truth = _loop(56144)
    (surface,) = [e for e in truth["effects"] if e["kind"] == "cross_axis"]
    (kept,) = [e for e in report["effects"] if e["kind"] == "cross_axis"]
    assert {e["kind"] for e in report["effects"]} == {"cross_axis", "cyclic", "local"}
    places = {
        (e["axis"], tuple(sorted(e["parameters"]["depends_on"])))
        for e in [kept, *kept["rivals"]["effects"]]
    }
    assert (surface["axis"], tuple(sorted(surface["depends_on"]))) in places
    assert any("cannot tell which direction and pair" in w for w in report["warnings"])
    assert [u["where"].split(" at ")[0] for u in report["unexplained"]] == ["line diag_yz_pp"]
    assert report["cv_rms_um"]["after_loop"] < 1.1 * truth["noise"]["sigma_um"]


def test_a_rival_place_whose_highest_order_swings_off_the_lines_is_named_at_a_lower_one() -> None:
    # direct plan, two surfaces and a cycle: the second kept surface (EZ over Y×Z, order 4) is
    # predicted as well by EZ over X×Z and over X×Y, but their strongest findings (order 8)
    # swing to 69 and 83 µm off the lines that measure them and were refused as implausible:
    # nothing was named. Each place's next order is now refitted, and named
    report, _ = _loop(47031)
    (kept,) = [e for e in report["effects"] if e["kind"] == "cross_axis" and e["axis"] == "Z"]
    assert kept["parameters"]["depends_on"] == ["Y", "Z"]
    places = {tuple(r["parameters"]["depends_on"]) for r in kept["rivals"]["effects"]}
    assert {("X", "Y"), ("X", "Z")} <= places
    for rival in kept["rivals"]["effects"]:
        assert rival["cv_rms_all_lines"] <= kept["rivals"]["kept_cv_rms_all_lines"] * 1.01
        assert rival["parameters"]["peak_um"] <= 50.0  # within what the loop holds plausible
    assert any(
        w.startswith("cross-axis EZ over Y×Z (order 4) was kept, but") for w in report["warnings"]
    )


def test_a_surface_the_backward_pass_placed_is_asked_its_rivals_in_the_final_model() -> None:
    # displacement-only plan (blind 51096): surfaces EY and EZ over Y×Z and a cosine error of
    # diag_xy_offcentre. EY over X×Y was kept at step 2, before the cosine; the backward pass
    # kept it one order lower beside the cosine, and in that model EY over Y×Z (the truth)
    # predicts the held-out blocks as well (0.2841 against 0.2831 µm). No step had asked: it
    # was not named, and the errors beside it were stated 18 times too sure of themselves
    report, truth = _loop(51096)
    (kept,) = [e for e in report["effects"] if e["kind"] == "cross_axis" and e["axis"] == "Y"]
    places = {tuple(r["parameters"]["depends_on"]) for r in kept["rivals"]["effects"]}
    assert ("Y", "Z") in places, kept["rivals"]
    for rival in kept["rivals"]["effects"]:
        assert rival["cv_rms_all_lines"] <= kept["rivals"]["kept_cv_rms_all_lines"] * 1.01
    assert any(
        w.startswith(f"{kept['label']} was kept, but") and "EY over Y×Z" in w
        for w in report["warnings"]
    )
    outcome = run_blind(51096)
    assert outcome.exact_up_to_named_rivals
    assert outcome.band_ratio <= 3.0


def test_an_abbe_offset_that_grows_past_the_optics_reach_once_settled_is_not_kept() -> None:
    # direct plan, a surface EZ over X×Y: an Abbe offset of z_straight_y fits it there, (−52,
    # 0, 93) mm in the step's one solve and (−68, 0, 123) mm once offset and angles agree in
    # the final model, beyond the 100 mm a set-up can be off: it was kept, implausible in the
    # report. Judged settled, it is refused, and a surface is kept with the injected place
    # among its named rivals. (Asked again once the surface is in, the offset reaches 157 mm in
    # one solve: refused as it stands.)
    report, truth = _loop(48071)
    assert "abbe_offset" not in {e["kind"] for e in report["effects"]}
    row, *again = [
        s for s in report["loop"] if s["effect"]["label"] == "Abbe offset of line z_straight_y"
    ]
    assert row["verdict"] == "implausible"
    assert "once its lever arm and the angles agree" in row["reason"]
    assert all(s["verdict"] == "implausible" for s in again)
    (kept,) = [e for e in report["effects"] if e["kind"] == "cross_axis"]
    places = {
        (e["axis"], tuple(sorted(e["parameters"]["depends_on"])))
        for e in [kept, *kept["rivals"]["effects"]]
    }
    assert ("Z", ("X", "Y")) in places


def test_a_drift_the_angular_lines_confirm_is_kept() -> None:
    # full plan; X expands over the session (τ ≈ 2 h) and the first line, x_linear, sees it
    # before it settles; the later displacement lines cannot tell it from EXX, but the angular
    # lines along X, which the fit bent towards the drifting line, can: judged on displacement
    # lines alone the drift was refused and eight lines were reported unexplained. Once the drift
    # is in the model the later lines cannot predict x_linear without it (a leverage near 1):
    # that line is no prediction of either model and the comparison runs on the others
    report, truth = _loop(1099)
    (effect,) = truth["effects"]
    assert effect["kind"] == "thermal_drift" and effect["axis"] == "X"
    assert [(e["kind"], e["axis"]) for e in report["effects"]] == [("thermal_drift", "X")]
    (kept,) = report["effects"]
    # the files log the material temperature of the drifting axis: the drift follows it at the
    # axis' expansion coefficient
    assert kept["parameters"]["mode"] == "temperature"
    alpha = effect["parameters"]["alpha_ppm_per_K"]
    assert kept["parameters"]["expansion_ppm_per_c"] == pytest.approx(alpha, rel=0.05)
    judged = report["cv_rms_um"]["all_lines"]
    assert judged["after_loop"] < 0.95 * judged["before_loop"]
    assert not report["unexplained"], report["unexplained"]


def test_bumps_a_held_out_block_alone_shows_are_judged_on_the_rest() -> None:
    # twelve-line plan (linear lines only, held-out blocks): a 16.8 mm cycle of Z, a bump of EZZ
    # and one of EXX. Held out, the block holding a bump leaves its free profile barely
    # determined: judged on the model without it only, those blocks counted against the bump
    # (−18.5 %, 79 % better where it acts) and a finer EBX was kept for it
    report, truth = _loop(4012)
    expected = sorted(
        ("local", f"{e['axis']} in {e['direction']}")
        if e["kind"] == "local"
        else (e["kind"], e["axis"])
        for e in truth["effects"]
    )
    kept = sorted(
        ("local", f"{e['axis']} in {e['parameters']['direction']}")
        if e["kind"] == "local"
        else (e["kind"], e["axis"])
        for e in report["effects"]
    )
    assert kept == expected == [("cyclic", "Z"), ("local", "X in X"), ("local", "Z in Z")]
    centres = {
        e["axis"]: e["parameters"]["centre_mm"] for e in truth["effects"] if e["kind"] == "local"
    }
    for e in report["effects"]:
        if e["kind"] == "local":  # the free profile spans the truth's centre
            p = e["parameters"]
            assert abs(p["center_mm"] - centres[e["axis"]]) < p["width_mm"]


def test_a_drift_the_first_line_settles_is_kept_with_the_other_effects() -> None:
    # full plan, left out line by line; Z warms (the files log its material temperature), X has a
    # reversal and EX a surface over Y×Z. With the drift in the model the later lines cannot
    # predict the first Z line: its "prediction" is no test of either model, and before that
    # rule nothing was kept and 29 lines were reported unexplained
    report, truth = _loop(4124)
    expected = {(e["kind"], e["axis"]) for e in truth["effects"]}
    assert {(e["kind"], e["axis"]) for e in report["effects"]} == expected
    (surface,) = [e for e in report["effects"] if e["kind"] == "cross_axis"]
    assert sorted(surface["parameters"]["depends_on"]) == ["Y", "Z"]


def _one_line_drift(seed: int) -> tuple[dict, dict, list[str]]:  # type: ignore[type-arg]
    """The kept drift in time, its injected truth and the loop's warnings about it."""
    report, truth = _loop(seed)
    (drift,) = [e for e in report["effects"] if e["kind"] == "thermal_drift"]
    (injected,) = [e["parameters"] for e in truth["effects"] if e["kind"] == "thermal_drift"]
    warned = [w for w in report["warnings"] if w.startswith(f"the {drift['label']} is shown")]
    return drift, injected, warned


@pytest.mark.parametrize("seed", [4047, 50121])
def test_a_warm_up_the_earliest_line_of_its_axis_alone_shows_is_kept_with_its_doubt(
    seed: int,
) -> None:
    # direct plan, X warms with nothing logging a temperature (4047: 25.1 ppm, τ 41 min; 50121:
    # 24.9 ppm, τ 24 min) and only x_linear, the first line along X, sees it beyond what the 21
    # errors absorb: the later lines read the settled scale. It was refused as one line's; a
    # warm-up shows nowhere else, so the drift is kept. On one line the scale trades against τ
    # (4047: 54 ppm at τ 99 min): report.json gives τ's range and the scale at its ends, and
    # both cover the truth; a warning names the line and what it cannot tell apart
    drift, injected, warned = _one_line_drift(seed)
    assert drift["axis"] == "X" and drift["parameters"]["mode"] == "time"
    true_tau = injected["tau_min"] * 60.0
    true_scale = injected["alpha_ppm_per_K"] * injected["delta_T_inf_K"]
    low, high = drift["parameters"]["time_constant_range_s"]
    assert low < drift["parameters"]["time_constant_s"] < high
    assert low < true_tau < high
    scales = drift["parameters"]["scale_at_range_ppm"]
    assert min(scales) < true_scale < max(scales)
    (text,) = warned
    assert "x_linear alone, the first along X" in text


def test_a_drift_one_line_shows_is_kept_when_the_logged_temperature_drives_it() -> None:
    # direct plan: a reversal and a 16 mm cycle of Y, and X warming by 2.6 K (τ 66 min) with its
    # material temperature in the files. Only x_linear, measured first, sees the drift beyond
    # what the 21 errors absorb (0.004 % of its contribution escapes them): the candidate driven
    # by the temperature was dropped as absorbed whole, and the one driven by time was refused
    # for showing on one line. A logged driver pins it on one line: it is kept
    outcome = run_blind(7190)
    assert outcome.kept == outcome.expected
    (drift,) = [e for e in outcome.effects_report if e["kind"] == "thermal_drift"]
    assert drift["parameters"]["mode"] == "temperature"


def test_a_drift_behind_variants_of_a_bump_one_line_alone_shows_is_kept() -> None:
    # twelve-line plan: X warms by 1.4 K (τ 26 min; the files log the material temperature at
    # their ends) and EZY has a 5 µm bump that only diag_yz_pp shows. The bump's variants (local
    # defects, finer functions) are the strongest proposals, refused as one line's; the drift
    # removes a quarter of their χ², just short of a batch, and the step's second batch held
    # more variants. Refitted as the strongest of a kind the step had not tried, the drift is
    # kept and the bump is reported on its line (before: a finer roll of Z, ECZ, was kept)
    outcome = run_blind(16018)
    assert outcome.kept == {("thermal_drift", "X")}
    assert outcome.one_line_handling == {("local", "Y in Z"): "unexplained"}


def test_candidates_of_a_step_are_ranked_over_the_readings_all_of_them_predict() -> None:
    # demo plan: a cosine error of 4.8 ppm on y_linear_mid, an Abbe offset of 44 mm on z_linear
    # and a bump of EXZ. On y_linear_mid the Abbe offset and the cosine error both pass step 1;
    # the Abbe offset's fit makes one more held-out line a wild extrapolation, and ranked each
    # on its own readings it came first (RMS 0.1275 against 0.1346) though the cosine error
    # predicts every reading better. Over the readings both predict, the cosine error is kept
    # (the two within 1 %: the one with fewer parameters)
    report, truth = _loop(17124)
    step = [s for s in report["loop"] if s["step"] == 1]
    kept = {s["effect"]["label"] for s in report["loop"] if s["verdict"] == "kept"}
    assert "cosine misalignment of line y_linear_mid" in kept
    assert "Abbe offset of line y_linear_mid" not in kept
    rival = next(s for s in step if s["effect"]["label"] == "Abbe offset of line y_linear_mid")
    assert rival["verdict"] == "another kept"
    assert "over the readings every candidate of the step predicts" in rival["reason"]
    # over those readings the two set-ups of the line are within 1 %: the report says the plan
    # cannot tell them apart
    assert any(
        w.startswith(
            "cosine misalignment of line y_linear_mid was kept, but Abbe offset of line "
            "y_linear_mid predicts the held-out data as well"
        )
        and "optics sit off the beam or its beam is tilted" in w
        for w in report["warnings"]
    )
    labels = sorted(e["label"] for e in report["effects"])
    assert labels[:2] == [
        "Abbe offset of line z_linear",
        "cosine misalignment of line y_linear_mid",
    ]
    assert len(labels) == 3 and labels[2].startswith("local defect Z in X")
    assert {e["kind"] for e in truth["effects"]} == {"cosine", "abbe_offset", "local"}


def test_a_drift_that_settles_between_two_temperature_logs_is_kept_at_its_time_constant() -> None:
    # direct plan: X warms by 1.46 K with τ 15.2 min while x_linear, measured first, lasts 75
    # min; the file logs the material temperature at its start and end only. Read as a straight
    # line between the two logs, the temperature-driven drift changed size from run to run and
    # was refused. Read as a first-order response between the logs, it passes every rule; so
    # does the same drift in time, which only x_linear, the first line along X, shows: the two
    # are one course here (0.1332 µm held out both) and either is kept, at the truth's size and
    # time constant
    report, truth = _loop(8028)
    (true_drift,) = truth["effects"]
    true = true_drift["parameters"]
    first_order = "thermal drift X (material temperature, first order)"
    (row,) = [s for s in report["loop"] if s["step"] == 1 and s["effect"]["label"] == first_order]
    assert row["verdict"] in ("kept", "another kept")
    (drift,) = report["effects"]
    found = drift["parameters"]
    if drift["label"] == first_order:
        assert found["between_logs"] == "first order"
        # within 3 stated σ (0.35 ppm/°C here) of the truth's 11.26 ppm/K
        error = abs(found["expansion_ppm_per_c"] - true["alpha_ppm_per_K"])
        assert error < 3 * found["expansion_std_ppm_per_c"]
    else:
        assert drift["label"] == "thermal drift X (time)"
        error = abs(found["scale_ppm"] - true["alpha_ppm_per_K"] * true["delta_T_inf_K"])
        assert error < 3 * found["scale_std_ppm"]
    assert found["time_constant_s"] / 60 == pytest.approx(true["tau_min"], rel=0.05)
    assert not report["unexplained"]


def test_a_drift_a_cosine_error_took_is_kept_once_the_audit_takes_the_cosine_out() -> None:
    # demo plan: X drifting, and cosine errors on x_linear and body_pmp. A cosine of x_linear
    # took the drift's place first; with the other effects in, it grew past what a beam can be
    # misaligned by and the final audit took it out, leaving the drift's structure unexplained
    # on seven lines. The forward steps now run again after the audit. Since bumps are scanned
    # down to the finest line's spacing (more candidates share the step's false-alarm budget),
    # the drift wins the first step outright; either way it is kept, and the cosine is not
    report, truth = _loop(7010)
    kinds = {(e["kind"], e["axis"]) for e in report["effects"]}
    assert ("thermal_drift", "X") in kinds
    assert kinds <= {(e["kind"], e.get("axis")) for e in truth["effects"]}
    kept = [e["label"] for e in report["effects"]]
    assert "cosine misalignment of line x_linear" not in kept
    audited = [s for s in report["loop"] if s["stage"] == "audit"]
    drift = [s for s in report["loop"] if s["kept"] and s["effect"]["kind"] == "thermal_drift"]
    assert drift
    if audited:  # a drift the audit freed is found in the round after it
        assert drift[-1]["step"] > audited[0]["step"]
    assert not report["unexplained"]


def test_a_set_up_error_a_surface_took_is_kept_in_the_step_the_surface_was_tried() -> None:
    # demo plan, noise 0.23 µm: cosine errors on y_linear_mid, diag_xz_pp_b and z_linear_side. A
    # surface EZ over X×Z took z_linear_side's cosine at step 3: that cosine, refused below the
    # margin at step 2 while diag_xz_pp_b's was still missing, was not refitted there, and the
    # backward pass later put it in the surface's place. Owed a refit once another effect is
    # kept, it is now refitted at step 3 beside the surface and kept there: it predicts the
    # held-out lines better (0.2478 against 0.2696 µm); no backward pass or audit has to undo it
    report, truth = _loop(8027)
    expected = {f"cosine misalignment of line {e['line']}" for e in truth["effects"]}
    assert {e["label"] for e in report["effects"]} == expected
    rows = [
        s
        for s in report["loop"]
        if s["effect"]["label"] == "cosine misalignment of line z_linear_side"
    ]
    assert [(s["step"], s["verdict"]) for s in rows] == [(2, "below margin"), (3, "kept")], rows
    surfaces = [s for s in report["loop"] if s["step"] == 3 and s["effect"]["kind"] == "cross_axis"]
    assert surfaces and not any(s["kept"] for s in surfaces)
    assert not [s for s in report["loop"] if s["stage"] in ("backward", "audit")]
    assert not report["unexplained"]


def test_a_bump_a_finer_function_follows_as_well_is_kept_as_a_bump() -> None:
    # full plan: an Abbe offset of z_linear and a 2 µm bump of EYZ (27 mm wide); the bump and a
    # finer EYZ predict the held-out lines within 0.2 % of each other: the named physical effect
    # is kept (short structure is the loop's to name), not a finer spline. What of the bump the
    # smooth EYZ can take is EYZ's: the two together follow the truth's EYZ and its bump
    outcome = run_blind(4043)
    assert outcome.kept == outcome.expected == {("abbe_offset", "z_linear"), ("local", "Z in Y")}
    assert outcome.function_error["EYZ"] < 0.35


def test_a_bump_spanning_splines_of_its_function_holds_what_they_cannot_and_is_kept() -> None:
    # twelve-line plan: a reversal of X that shrinks along the stroke and a −3.0 µm bump of EXX at
    # 288 mm (FWHM 36 mm). The free profile that removes the most spans 323 ± 121 mm, over
    # splines of the 50 mm EXX: fitted as it came, bump and function traded +51.7 µm against
    # −48 µm, the bump was refused as implausible and a finer EXX and a 49 mm cycle took its
    # place. Held to what no spline of EXX within its span can hold, it is kept, its peak where
    # the bump is; EXX takes the rest of it
    report, truth = _loop(54086)
    kept = {(e["kind"], e["axis"]) for e in report["effects"]}
    assert kept == {("reversal", "X"), ("local", "X")}
    (bump,) = [e["parameters"] for e in report["effects"] if e["kind"] == "local"]
    (true_bump,) = [e["parameters"] for e in truth["effects"] if e["kind"] == "local"]
    assert bump["direction"] == "X"
    assert bump["peak_mm"] == pytest.approx(true_bump["centre_mm"], abs=5.0)
    # what EXX's splines within the span take of the bump is not the bump's: less, same sign
    assert 0.5 < bump["amplitude_um"] / true_bump["amplitude_um"] < 1.0
    assert not report["unexplained"]


def test_a_bump_narrower_than_the_spacing_whose_free_profile_is_cancelled_is_kept_narrow() -> None:
    # direct plan, targets every 17.4 mm, 0.21 µm noise: a 3.2 µm bump of EYX at 293 mm, 7.4 mm
    # (1 σ) wide, beside a bump of EXY and a reversal of X. The free profile spanning three
    # spacings each side was fitted at 49.6 µm over ± 77 mm, which EYX's splines cancelled:
    # refused as implausible, both bumps were missed. Its Gaussian of one height, below the
    # spacing, is refitted in its place and kept where the bump is, at its size
    report, truth = _loop(57085)
    kept = {(e["kind"], e["axis"], e["parameters"].get("direction")) for e in report["effects"]}
    assert kept == {("local", "X", "Y"), ("local", "Y", "X"), ("reversal", "X", None)}
    (narrow,) = [
        e["parameters"]
        for e in report["effects"]
        if e["kind"] == "local" and e["parameters"]["profile"] == "gaussian"
    ]
    (true_bump,) = [
        e["parameters"]
        for e in truth["effects"]
        if e["kind"] == "local" and e["parameters"]["direction"] == "Y"
    ]
    assert narrow["direction"] == "Y"
    assert narrow["center_mm"] == pytest.approx(true_bump["centre_mm"], abs=3.0)
    assert narrow["amplitude_um"] == pytest.approx(true_bump["amplitude_um"], rel=0.15)
    # 1 σ against the FWHM's 7.35 mm: the readings fix it to a couple of mm
    assert narrow["width_mm"] == pytest.approx(true_bump["width_fwhm_mm"] / 2.3548, abs=2.5)
    assert not report["unexplained"]


def test_bumps_narrower_than_the_target_spacing_are_found_at_their_places() -> None:
    # twelve-line plan: bumps of EYY at 291 mm (FWHM 14 mm, −3.3 µm) and of EZZ at 253 mm
    # (FWHM 12 mm, −4.9 µm), the diagonals' targets every 16 mm. Scanned only with Gaussians as
    # wide as that spacing, the bump of Y was placed at 323 mm, its free profile fitted to
    # 414 µm and refused as implausible: the bump was missed. Scanned with narrower ones too,
    # both are found where they are
    report, truth = _loop(18110)
    locals_ = {
        (e["parameters"]["direction"], e["axis"]): e["parameters"]["center_mm"]
        for e in report["effects"]
        if e["kind"] == "local"
    }
    assert len(report["effects"]) == 2
    true = {
        (e["parameters"]["direction"], e["axis"]): e["parameters"]["centre_mm"]
        for e in truth["effects"]
    }
    assert set(locals_) == set(true) == {("Y", "Y"), ("Z", "Z")}
    for key, centre in true.items():
        assert abs(locals_[key] - centre) < 5.0


def test_a_bump_the_linear_line_resolves_is_found_at_its_place() -> None:
    # demo plan: a 3.6 µm bump of EZZ at 294 mm, 20 mm wide (FWHM). z_linear's targets are 3.5
    # mm apart, most lines' 15 mm along Z: scanned no narrower than the typical 15 mm, the bump
    # was kept at 237 mm with a finer EZZ beside it. The narrowest width scanned is now the
    # spacing of the lines that read the bump's direction
    report, truth = _loop(8054)
    (true_bump,) = truth["effects"]
    (bump,) = report["effects"]
    assert (bump["kind"], bump["axis"], bump["parameters"]["direction"]) == ("local", "Z", "Z")
    assert bump["parameters"]["center_mm"] == pytest.approx(
        true_bump["parameters"]["centre_mm"], abs=5.0
    )
    amplitude, std = bump["parameters"]["amplitude_um"], bump["parameters"]["amplitude_std_um"]
    assert abs(amplitude - true_bump["parameters"]["amplitude_um"]) < max(3 * std, 0.35)
    assert not report["unexplained"]


def test_a_drift_beside_a_reversal_whose_size_changes_along_the_stroke_is_kept() -> None:
    # twelve-line plan, noise 0.45 µm: a reversal of X that grows along the stroke, X drifting
    # with its material temperature and a bump of EZZ. The constant reversal misfits each
    # direction differently, so the drift's size, fitted run by run, differs between the runs of
    # the two directions (78 %); within one direction it holds (10 %). Compared with its line
    # alone, and sized along patterns the 21 errors absorb almost whole, the drift was refused
    outcome = run_blind(5142)
    assert outcome.kept == outcome.expected
    assert ("thermal_drift", "X") in outcome.kept


def test_a_drift_refused_before_the_reversal_s_slope_was_in_the_model_is_kept_after_it() -> None:
    # twelve-line plan: X warms (τ 58 min, 18.7 ppm) beside a reversal of Y that shrinks along
    # the stroke. At step 2 the drift was refused as unrepeatable (its size, run by run, varied
    # by 34 %) while the reversal's slope, kept at the same step, was still missing; with it in
    # the model the drift's F had grown by less than the retry factor, so it was never refitted
    # and three X lines were reported unexplained
    outcome = run_blind(22167)
    assert outcome.kept == outcome.expected == {("reversal", "Y"), ("thermal_drift", "X")}
    (drift,) = [e for e in outcome.effects_report if e["kind"] == "thermal_drift"]
    assert drift["parameters"]["time_constant_s"] == pytest.approx(58 * 60, rel=0.25)
    assert not outcome.unexplained


def test_a_first_line_a_drift_predicts_better_even_barely_determined_is_compared() -> None:
    # demo plan: X warms by 1.9 K (τ 71 min, the files log its material temperature) beside a
    # 21.7 mm cycle of Y; x_linear, measured first, shows the drift 33 times the noise. Held
    # out, x_linear is predicted to 0.67 µm RMS with a drift in the model (wild against 0.10 µm
    # in-sample) and to 2.05 µm without: it was left out of the comparison, the drift earned
    # 1.2 % there and was refused, and x_linear was reported unexplained
    report, truth = _loop(24020)
    expected = {(e["kind"], e["axis"]) for e in truth["effects"]}
    assert {(e["kind"], e["axis"]) for e in report["effects"]} == expected
    assert expected == {("cyclic", "Y"), ("thermal_drift", "X")}
    assert not report["unexplained"]
    step = next(s for s in report["loop"] if s["kept"] and s["effect"]["kind"] == "thermal_drift")
    assert "wild" not in step["reason"]


def test_a_set_up_error_that_leaves_its_line_structured_is_taken_out() -> None:
    # displacement-only plan: the column bends in X as it warms (EX ∝ g(t)·z², outside every
    # catalogue); only diag_xz_pm shows it, 4.7× the noise. That line's cosine error took its
    # linear part (20 % of the held-out error) and nothing was reported: with it in the model
    # the line's runs still drift apart beyond its repeatability, and no other line's do. The
    # audit takes it out and the line is reported unexplained
    report, truth = _loop(22103)
    assert truth["category"] == "outside"
    assert not report["effects"]
    audits = [s for s in report["loop"] if s["stage"] == "audit"]
    assert audits
    assert all("diag_xz_pm keeps a residual that changes in time" in s["reason"] for s in audits)
    assert any(u["where"].startswith("line diag_xz_pm ") for u in report["unexplained"])


def test_an_abbe_offset_is_kept_not_a_surface_in_its_place() -> None:
    # direct plan: a reversal of Y, a bump of EX along Y and an Abbe offset of −70 mm on
    # diag_yz_pp. Sized run by run along a pattern the model absorbs almost whole, the offset's
    # size "varied by 265 %" and a surface EY over Y×Z was kept in its place, with nothing left
    # unexplained
    outcome = run_blind(6176)
    assert outcome.kept == outcome.expected
    assert ("abbe_offset", "diag_yz_pp") in outcome.kept


@pytest.mark.parametrize("seed", [6010, 6166])
def test_a_laser_that_wanders_is_not_kept_as_a_drift(seed: int) -> None:
    # direct plan: the laser's reading wanders in time (a random walk). A drift in time takes a
    # trace of it that the 21 errors do not absorb (0.002 % of its contribution in 6010); fitted
    # run by run, its size changes by more than the readings see of the drift itself
    outcome = run_blind(seed)
    assert outcome.category == "outside"
    assert not outcome.kept
    assert outcome.unexplained > 0


def test_a_beam_cut_on_the_last_readings_of_a_line_is_reported_at_its_moment() -> None:
    # displacement-only plan: the beam was cut on body_ppp at the second-last reading of its
    # eighth and last run and re-zeroed, 2.3 µm off (5.2 times the noise) on two readings of
    # 592; the target means and the line's spread left it unreported
    report, truth = _loop(51109)
    (effect,) = truth["effects"]
    assert effect["kind"] == "outside:beam_interruption"
    line, step = effect["line"], effect["parameters"]["step_um"]
    assert report["effects"] == []
    (hit,) = [u for u in report["unexplained"] if u["where"].startswith(f"line {line}, run 8 ")]
    sigma = truth["noise"]["sigma_um"]
    # two readings less their cells' means (four runs each way): standard error σ/√2 · √(4/3)
    standard_error = sigma / np.sqrt(2) * np.sqrt(4 / 3)
    assert hit["magnitude_um"] == pytest.approx(abs(step), abs=3 * standard_error)


def test_lines_whose_reflector_settles_anew_each_run_are_said_to_step_more_than_once() -> None:
    # direct plan: every line's reflector settles 1.4 µm (σ) differently in each run, 5 times
    # the noise; each line's spread is alike, so none repeats worse than its peers. Lines the
    # other tests leave are reported by their strongest step, and where the line, that step
    # taken out, still steps, said to step at other moments too; nothing is kept
    report, truth = _loop(51143)
    (effect,) = truth["effects"]
    assert effect["kind"] == "outside:reflector_twitch"
    twitched = set(effect["parameters"]["lines"])
    assert report["effects"] == []
    names = [u["where"].split()[1].rstrip(",") for u in report["unexplained"]]
    assert len(names) == len(set(names)) and set(names) <= twitched
    steps = [u for u in report["unexplained"] if "steps by" in u["description"]]
    assert any("at other moments too" in u["description"] for u in steps), steps


def test_a_twist_the_plan_reads_as_angles_is_left_to_them_and_said_so() -> None:
    # demo plan: a surface EX over Y×Z with a twist u·v among its terms. On these lines the twist
    # reads exactly as EBY, EAX, ECZ and EB0Z together do (no line reads Y's roll directly): the
    # fit leaves it to them. Scored against the truth with the twist in the surface, those
    # errors were 5 µrad and the squareness 9 µrad off, 35 times their stated uncertainty
    from score_blind import rigid_share

    from tests.blind.scenarios import build_scenario

    scenario = build_scenario(8156)
    (surface,) = [e for e in scenario.effects if e.kind == "cross_axis"]
    assert surface.coefficients["1,1"] != 0.0
    _, functions, squareness, (remaining,) = rigid_share(scenario)
    assert remaining.coefficients.get("1,1", 0.0) == pytest.approx(0.0, abs=1e-12)
    assert remaining.coefficients["1,2"] == surface.coefficients["1,2"]  # not rigid: stays
    # the generator's own fit puts the twist into these angles and the squareness
    assert min(np.max(np.abs(functions[eid])) for eid in ("EBY", "EAX", "ECZ")) > 1.0  # µrad
    assert abs(squareness["EB0Z"]) > 1.0

    report, _ = _loop(8156)
    (kept,) = report["effects"]
    assert kept["kind"] == "cross_axis"
    shared = kept["shared_with_errors"]
    assert shared["terms"] == ["P1(Y)·P1(Z)"]
    assert {"EBY", "EB0Z"} <= set(shared["errors"])
    assert any("P1(Y)·P1(Z)" in w and "EBY" in w for w in report["warnings"])

    outcome = run_blind(8156)
    assert outcome.kept == outcome.expected
    angles = {k: v for k, v in outcome.function_error.items() if k[1] in "ABC"}
    assert max(angles.values()) < 2.0, angles  # µrad, the issue's bound
    assert max(outcome.squareness_error.values()) < 2.0, outcome.squareness_error
    assert outcome.band_ratio <= 3.0


def test_errors_a_surface_of_unsettled_order_moves_are_stated_with_that_doubt() -> None:
    # direct plan: a surface EZ over X×Z with a u³·v term, two bumps. Surfaces of order 3 and 4
    # (with lever-arm terms) predict the held-out blocks alike (0.2737 and 0.2729 µm); the
    # simpler one is kept, and EZX, EZZ and the squareness EA0Z fitted beside it were 3 µm,
    # 7 µm and 29 µrad off the truth with stated uncertainties 12 times smaller. Asked again in
    # the final model (the bumps in it), order 8 predicts as well too and moves EZX most
    report, _ = _loop(9086)
    assert {e["kind"] for e in report["effects"]} == {"cross_axis", "local"}
    (warning,) = [w for w in report["warnings"] if "does not settle the surface's shape" in w]
    assert "EZ over X×Z (order" in warning and "EZX" in warning
    # and it names a line the plan lacks on which the two orders read apart
    assert re.search(r"line along [XYZ].* would tell them apart: on it the two read", warning)
    outcome = run_blind(9086)
    assert outcome.kept == outcome.expected
    assert outcome.function_error["EZZ"] > 3.0  # the truth is still not what was fitted ...
    assert outcome.band_ratio <= 3.0  # ... but the stated uncertainty now says how far it may be


def test_a_cosine_error_the_plan_reads_alike_on_three_lines_is_stated_with_that_doubt() -> None:
    # the paper's plan (blind seed 15043): a cosine misalignment of diag_yz_pp_offset beside a
    # cycle of Y and a surface EX over Y×Z. The same scale on diag_xy_pp_offset or
    # diag_xz_pp_offset fits the readings identically (the 21 errors take up any of the three
    # offset diagonals' scales alike), and the cross-validated error kept diag_xy_pp_offset; the
    # squareness EC0Y fitted beside it was 31 µrad off the truth with a stated uncertainty 100
    # times smaller, and nothing said the line was a guess
    report, _ = _loop(15043)
    (warning,) = [w for w in report["warnings"] if "cannot tell which line's set-up" in w]
    assert all(f"diag_{pair}_pp_offset" in warning for pair in ("xy", "xz", "yz")), warning
    assert "EC0Y" in warning
    outcome = run_blind(15043)
    assert ("cosine", "diag_yz_pp_offset") in outcome.expected
    assert outcome.squareness_error["EC0Y"] > 20.0  # the truth is still not what was fitted ...
    assert outcome.band_ratio <= 3.0  # ... but the stated uncertainty now says how far it may be


def test_errors_beside_a_surface_the_plan_cannot_place_are_stated_with_that_doubt() -> None:
    # direct plan (blind 15175): a surface EX over Y×Z. EX over X×Z, EZ over X×Z and EZ over X×Y
    # predict the held-out blocks alike (0.2246, 0.2247, 0.2248 µm); the loop kept EX over X×Z,
    # and EXX fitted beside it was 24 µm off the truth with a stated uncertainty 50 times
    # smaller. Each rival moves the errors fitted beside it: the bands now include those moves
    report, _ = _loop(15175)
    (warning,) = [w for w in report["warnings"] if "cannot tell which direction and pair" in w]
    assert "EZ over X×Z" in warning and "EZ over X×Y" in warning, warning
    assert "stated uncertainties of the errors include the differences" in warning
    outcome = run_blind(15175)
    assert outcome.function_error["EXX"] > 10.0  # µm: the truth is not what was fitted ...
    assert outcome.band_ratio <= 3.0  # ... but the stated uncertainty says how far it may be


def test_a_richer_surface_is_kept_only_when_its_extra_terms_earn_the_margin() -> None:
    # displacement-only plan (blind 19167): a surface EY over X×Y (u·v and u·v² terms) beside an
    # Abbe offset of diag_xz_pm. The surface of order 4 with lever-arm terms predicted the
    # held-out data 1.6 % better than that of order 3 (0.3172 and 0.3224 µm) and was kept: its
    # extra terms took 10 µrad of the squareness EC0Y, 12 times its stated uncertainty
    outcome = run_blind(19167)
    assert outcome.kept == outcome.expected
    (surface,) = [e for e in outcome.effects_report if e["kind"] == "cross_axis"]
    assert "order 3" in surface["label"], surface["label"]
    assert max(outcome.squareness_error.values()) < 2.0, outcome.squareness_error  # µrad
    assert outcome.band_ratio <= 3.0


def test_a_surface_of_another_order_is_kept_before_a_second_surface_that_ties_it() -> None:
    # demo plan (blind 51162): a bump on Z and a surface EZ over Y×Z (u·v … u³·v and u²·v²
    # terms). The surface of order 3 with lever-arm terms was kept first; a step later its order
    # 4 (0.2085 µm) and a second surface EZ over X×Y of which the plan sees one term (0.2088 µm)
    # tied, and the one adding fewer parameters was kept beside the first: two claims on Z where
    # the machine had one
    outcome = run_blind(51162)
    assert outcome.kept == outcome.expected, (outcome.kept, outcome.expected)
    (surface,) = [e for e in outcome.effects_report if e["kind"] == "cross_axis"]
    assert "Y×Z (order 4" in surface["label"], surface["label"]


def test_a_drift_the_first_line_fixes_is_not_asked_to_be_confirmed_there() -> None:
    # the generator's own plan, 0.16 µm noise: X expands 27 ppm over the session (τ 92 min),
    # the first line, x_linear, sees it before it settles; the logged material temperature
    # drives it. Held out, x_linear is predicted with the expansion fixed by later lines and
    # confirmed 42 % of what the drift removes there, the other lines ten times what it removes
    # from them: judged on every line, rule (d) refused it at 43 % and x_linear was reported
    report, truth = _loop(32107)
    (effect,) = truth["effects"]
    assert effect["kind"] == "thermal_drift" and effect["axis"] == "X"
    (kept,) = report["effects"]
    assert (kept["kind"], kept["axis"]) == ("thermal_drift", "X")
    p = kept["parameters"]
    assert p["mode"] == "temperature"
    alpha = effect["parameters"]["alpha_ppm_per_K"]
    assert abs(p["expansion_ppm_per_c"] - alpha) <= 3 * p["expansion_std_ppm_per_c"], (p, alpha)
    assert report["unexplained"] == []


def test_what_a_freer_fold_fitted_is_not_held_out_evidence() -> None:
    # each held-out fold once fitted directions of the 21 errors that the fit leaves unseen
    # (its rank limit set by its own largest eigenvalue): the held-out error measured a freer
    # model than the one identified. Twelve-line plan (31076): a 0.06 µm cycle of X, 3.5 %
    # better held out from a few blocks of the diagonals where its in-sample gain is nil, was
    # kept beside a reversal and two bumps. Direct plan (32115): a surface EZ over Y×Z the fit
    # needed, and the folds had half taken, was confirmed at 40 % by rule (d) and refused, and
    # 17 lines were reported unexplained
    outcome = run_blind(31076)
    assert outcome.kept == outcome.expected
    outcome = run_blind(32115)
    assert ("cross_axis", "Z over Y×Z") in outcome.kept
    assert outcome.kept <= outcome.expected
    assert outcome.unexplained == 0


def test_a_scale_that_swings_on_every_line_of_its_axis_takes_out_the_set_ups_it_hid_in() -> None:
    # blind 45141 (demo plan, 0.46 µm noise): the Y scale swings over 98 min, 2.2 µm at the end
    # of the stroke (2.9 times the noise), outside the catalogue. Each of the four lines moving
    # Y alone follows its distance times a course in time at 10⁻³ to 10⁻⁴, none past the
    # Bonferroni level over the twelve such lines, and two Abbe offsets (diag_yz_pp_b,
    # diag_xy_pp_b, each 96 % a scale of its diagonal) were kept with eight lines reported.
    # Together the Y lines say the scale changes (Fisher's combination), and the audit takes
    # the offsets out: nothing is kept and the lines are reported
    report, truth = _loop(45141)
    assert truth["category"] == "outside"
    assert report["effects"] == []
    assert len(report["unexplained"]) >= 8
    audits = [
        s for s in report["loop"] if s["stage"] == "audit" and s["effect"]["kind"] == "abbe_offset"
    ]
    assert {s["effect"]["label"] for s in audits} == {
        "Abbe offset of line diag_yz_pp_b",
        "Abbe offset of line diag_xy_pp_b",
    }
    for step in audits:
        assert "the Y scale changes in time" in step["reason"]
        assert "lines moving Y alone, together (Fisher)" in step["reason"]


def test_a_surface_that_is_only_the_scales_of_lines_measured_at_other_times_is_taken_out() -> None:
    # blind 45003 (demo plan, 0.097 µm noise): the Z scale swings over 80 min, 2.5 µm at the end
    # of the stroke, outside the catalogue. A surface EZ over X×Z (order 3) was kept at 11 %
    # better held out: the Z lines, measured hours apart, read the scale of their time, and the
    # surface gave each the scale of where it lies. Each Z line follows a course in time
    # (10⁻⁸ to 10⁻³⁸); beside a scale of its own on every linear line moving Z the surface adds
    # nothing, so the audit takes it out: nothing is kept and the lines are reported
    report, truth = _loop(45003)
    assert truth["category"] == "outside"
    assert report["effects"] == []
    assert len(report["unexplained"]) >= 15
    audits = [
        s for s in report["loop"] if s["stage"] == "audit" and s["effect"]["kind"] == "cross_axis"
    ]
    assert audits
    for step in audits:
        assert "the scale of Z" in step["reason"]
        assert "the surface explains nothing beyond the noise" in step["reason"]
    # each Z line alone follows its target position; the report says, across them, that the
    # scale moved between the times they were measured at: the scales it lists follow the
    # generator's swing, A·sin(2πt/T + φ) over the 350 mm stroke, at each line's mid-time
    (across,) = [u for u in report["unexplained"] if "moving Z alone" in u["where"]]
    listed = re.findall(r"(z_linear\w*) ([+-][\d.]+) ppm at (\d+) min", across["description"])
    assert {name for name, _, _ in listed} == {
        "z_linear",
        "z_linear_far",
        "z_linear_mid",
        "z_linear_side",
    }
    (swing,) = truth["effects"]
    parameters = swing["parameters"]
    minutes = np.array([float(t) for _, _, t in listed])
    read = np.array([float(ppm) for _, ppm, _ in listed])
    truth_ppm = (
        1000.0
        * parameters["amplitude_at_stroke_end_um"]
        / 350.0
        * np.sin(2 * np.pi * minutes / parameters["period_min"] + parameters["phase_rad"])
    )
    # relative to the model's scale, which holds their mean: compare them about their means (a
    # line's minutes hold a stretch of the swing, its slope their mean: 0.5 ppm of 7.3)
    assert np.abs((read - read.mean()) - (truth_ppm - truth_ppm.mean())).max() < 0.5


def test_a_sliver_of_structure_that_spreads_over_the_plan_is_not_kept(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # blind 36049 (the generator's own plan, 49 lines): a 3 µm Z error periodic in time (102 s),
    # outside every catalogue. A surface EZ over Y×Z took 3.7 % of the held-out error, above the
    # 3 % margin, while 22 of the 49 lines stayed unexplained beside it: a share of structure that
    # spreads over the plan as small as that is what any flexible shape takes of it. Nothing is
    # kept now, and the lines are reported (the error left in the readings, as where the search
    # does not find it; found and taken out, the surface is 3.3 % worse held out)
    report, _ = _loop_left_in(36049, monkeypatch)
    assert report["effects"] == []
    assert len(report["unexplained"]) >= 20
    # the surface is refused in the forward steps, most of its gain on the Z lines it leaves
    # systematic (before that rule, the backward pass took it out: "lines stay unexplained
    # beside it")
    surfaces = [s for s in report["loop"] if s["effect"]["kind"] == "cross_axis"]
    assert surfaces and not any(s["kept"] for s in surfaces)
    assert any("on lines it leaves systematic" in s["reason"] for s in surfaces)


def test_a_surface_kept_before_the_rest_gives_way_to_a_leaner_one_that_predicts_as_well() -> None:
    # direct plan, 0.077 µm noise: a surface EX over X×Y (4.1 µm) and a thermal drift of X. With
    # the drift still missing, step 1 kept EY over Y×Z of order 8 (15 terms); once the drift was
    # kept, EX over X×Y with lever-arm terms (6 terms) predicted the held-out data as well, 0.0810
    # against 0.0811 µm, and no order of Y×Z with fewer terms predicted as well. Asked again in
    # the final model, the step's tie rule keeps the leaner surface, and the other stays named
    # as a rival the plan cannot tell from it
    report, truth = _loop(50099)
    assert {(e["kind"], e["axis"]) for e in truth["effects"]} == {
        ("cross_axis", "X"),
        ("thermal_drift", "X"),
    }
    (surface,) = [e for e in report["effects"] if e["kind"] == "cross_axis"]
    assert (surface["axis"], surface["parameters"]["depends_on"]) == ("X", ["X", "Y"])
    assert len(report["effects"]) == 2, report["effects"]
    swapped = [
        s
        for s in report["loop"]
        if s["stage"] == "backward"
        and "in the final model cross-axis EX over X×Y" in s["reason"]
        and "where no surface of its place that predicts as well has fewer than 15" in s["reason"]
    ]
    assert swapped and swapped[0]["effect"]["label"].startswith("cross-axis EY over Y×Z")
    rivals = [r["label"] for r in surface["rivals"]["effects"]]
    assert any(label.startswith("cross-axis EY over Y×Z") for label in rivals), rivals
    assert any("cannot tell which direction" in w for w in report["warnings"])


def test_a_cycle_placed_again_beside_a_drift_leaves_no_bump_at_the_stroke_end() -> None:
    # plan of the demo, 0.29 µm noise: a 4.4 µm cycle of X at 23.535 mm and a drift of X. The
    # cycle, kept first, was placed at 23.509 mm while the drift was missing; its estimate
    # beside the drift (23.533 mm) gained hundreds of the noise's σ² but under 0.1 % of the
    # cycle's own χ², counted in the σ² of the fit without the cycle, and was not taken. A
    # bump of X at 26 mm took up the phase the period lost over the stroke
    report, truth = _loop(56101)
    (cycle,) = [e for e in truth["effects"] if e["kind"] == "cyclic"]
    assert {(e["kind"], e["axis"]) for e in report["effects"]} == {
        ("cyclic", "X"),
        ("thermal_drift", "X"),
    }
    (kept,) = [e for e in report["effects"] if e["kind"] == "cyclic"]
    assert kept["parameters"]["period_mm"] == pytest.approx(
        cycle["parameters"]["period_mm"], rel=3e-4
    )
    assert any(s["stage"] == "refine" and s["effect"]["kind"] == "cyclic" for s in report["loop"])


def test_a_finer_function_the_lines_it_reaches_do_not_confirm_is_not_kept() -> None:
    # twelve-line plan, 0.08 µm noise: a 4.8 µm bump of Y over X that only diag_xy_pp shows,
    # and a reversal of X. A finer roll of X took the bump: it reached diag_xz_pp too (16.2 σ²)
    # and lost 44.6 σ² held out there, while the Y positioning lines, which it does not reach,
    # gained 724 σ², the bump no longer pulling the Y positioning error through diag_xy_pp
    report, truth = _loop(57193)
    assert {(e["kind"], e["axis"]) for e in truth["effects"]} == {("local", "X"), ("reversal", "X")}
    assert [(e["kind"], e["axis"]) for e in report["effects"]] == [("reversal", "X")]
    finer = [s for s in report["loop"] if s["effect"]["kind"] == "higher_order"]
    assert finer and not any(s["kept"] for s in finer)
    assert any("diag_xy_pp" in u["where"] for u in report["unexplained"]), report["unexplained"]


def test_a_bump_its_function_cancels_is_no_defect_of_its_size() -> None:
    # direct plan, 0.21 µm noise, targets every 17.4 mm: a 3.2 µm bump of Y over X at 293 mm,
    # 17 mm wide, one of X over Y, a reversal of X. The bump of Y over X, placed at 295 mm over
    # ± 77 mm, took 49.6 µm against as much of EYX, no reading changing by more than 1.04 µm.
    # A bump whose profile the readings see less than a tenth of is refused as implausible
    report, truth = _loop(57085)
    assert ("reversal", "X") in {(e["kind"], e["axis"]) for e in report["effects"]}
    assert not [
        e
        for e in report["effects"]
        if e["kind"] == "local" and abs(e["parameters"]["amplitude_um"]) > 10
    ]
    cancelled = [
        s
        for s in report["loop"]
        if s["effect"]["kind"] == "local" and "its error function cancels it" in s["reason"]
    ]
    assert cancelled and all(s["verdict"] == "implausible" for s in cancelled)
    assert all(abs(s["effect"]["parameters"]["amplitude_um"]) > 10.0 for s in cancelled)


def test_the_final_audit_takes_out_a_bump_its_function_cancels() -> None:
    # the same machine (blind 57085): the bump its step refused, put in the model beside the
    # effect the loop kept before it (the reversal; the narrow bump kept at its place would
    # share its readings), is taken out by the final audit for the same reason. What the
    # readings see of a kept bump can shrink as later effects come in; the audit, with every
    # kept effect in the model, asks it against the fit without it, as its step did
    from volucal.core.identify import cross_validate, identify
    from volucal.core.io.plan import import_plan, load_plan
    from volucal.core.loop_audit import audit
    from volucal.core.loop_compare import Fitter
    from volucal.core.readings import flatten
    from volucal.core.residuals import LoopOptions, close_loop

    with tempfile.TemporaryDirectory(prefix="volucal-blind-") as tmp:
        plan, _ = write_scenario(57085, tmp)
        measurement = import_plan(load_plan(plan)).measurement
    result = close_loop(measurement)
    kept = [e for e in result.final.effects if e.kind != "local"]
    bump = next(
        s.finding.effect
        for s in result.steps
        if s.finding.effect.kind == "local" and "its error function cancels it" in s.reason
    )
    options = LoopOptions()
    readings = flatten(measurement)
    base = identify(measurement, options.identify, readings=readings)
    redundant = base.identifiability.redundant_lines
    cv_base = cross_validate(base.system, readings, redundant)
    fit = Fitter(measurement, readings, options, redundant, None)
    before, _ = fit(kept, base.model)
    current, cv = fit([*kept, bump], before.model)
    steps: list = []
    *_, left = audit(fit, current, cv, [*kept, bump], base, cv_base, options, steps, 9)
    assert left == kept
    assert [s.finding.effect for s in steps] == [bump]
    assert steps[0].stage == "audit" and "its error function cancels it" in steps[0].reason
