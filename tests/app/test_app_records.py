"""The workbench's GUI-free pieces: evidence plots, stored records, the factor table, plan rows.

Each is checked against an answer worked out independently: a residual built with a known
period or reversal, a project written to HDF5 and read back, the standard deviations of the
uniform and triangular distributions, plan entries typed by hand.
"""

import math
from pathlib import Path

import numpy as np
import pytest
from volucal.app import evidence
from volucal.app.factors import SensitivitySetup
from volucal.app.plan_rows import LineRow, guess_spec, parse_vector
from volucal.app.records import (
    IdentificationRecord,
    LoopRecord,
    ReadingTable,
    effect_from_json,
    effect_to_json,
    identification_result_tree,
    loop_candidates,
)
from volucal.core.effects import Cyclic, Reversal
from volucal.core.io.plan import import_plan, load_plan
from volucal.core.machine import PAPER_MACHINE
from volucal.core.measurement import LineSpec, PlanError
from volucal.core.project import Project
from volucal.core.readings import flatten
from volucal.core.residuals import close_loop


def synthetic_readings(residual_of, runs=4, step=2.0):
    """Three Y lines (offset in X) read forward and backward; residual_of(q_y, approach)."""
    rows = {k: [] for k in ("line", "run", "target", "position", "target_mm", "approach")}
    targets = np.arange(0.0, 400.0 + step / 2, step)
    for line in range(3):
        for run in range(runs):
            sign = 1.0 if run % 2 == 0 else -1.0
            for index, t in enumerate(targets):
                rows["line"].append(line)
                rows["run"].append(run)
                rows["target"].append(index)
                rows["position"].append((100.0 * line, t, 0.0))
                rows["target_mm"].append(t)
                rows["approach"].append((1.0, sign, 1.0))
    position = np.array(rows["position"])
    approach = np.array(rows["approach"])
    residual = residual_of(position[:, 1], approach[:, 1])
    n = residual.size
    return ReadingTable(
        line_names=("y_a", "y_b", "y_c"), group=("Y", "Y", "Y"),
        direction=np.tile([0.0, 1.0, 0.0], (3, 1)), projection=np.tile([0.0, 1.0, 0.0], (3, 1)),
        line=np.array(rows["line"]), run=np.array(rows["run"]), target=np.array(rows["target"]),
        position_mm=position, target_mm=np.array(rows["target_mm"]), approach=approach,
        time_s=np.arange(n, dtype=float), material_temp_c=np.full(n, np.nan),
        value=residual.copy(), residual=residual, quantity=np.zeros(n, dtype=np.int64),
    )


def test_periodogram_peaks_at_the_period_put_in():
    readings = synthetic_readings(lambda q, a: 1.2 * np.sin(2 * np.pi * q / 16.0 + 0.6))
    result = evidence.periodogram(readings, "Y", PAPER_MACHINE)
    periods, power = result.series[0].x, result.series[0].y
    peak = periods[np.argmax(power)]
    assert peak == pytest.approx(16.0, rel=0.02)
    # a pure sinusoid: the fitted one explains all of the residual's variance
    assert power.max() == pytest.approx(1.0, abs=0.02)
    assert (16.0, "screw lead 16 mm") in result.markers


def test_reversal_difference_is_the_step_between_directions():
    reversal_um = 3.0
    readings = synthetic_readings(lambda q, a: 0.5 * reversal_um * a + 0.001 * q)
    result = evidence.reversal_difference(readings, "Y")
    assert len(result.series) == 3
    for series in result.series:
        np.testing.assert_allclose(series.y, reversal_um, atol=1e-12)


def test_departure_along_averages_runs_per_target():
    readings = synthetic_readings(lambda q, a: 0.01 * q + 0.2 * a)
    result = evidence.departure_along(readings, "Y")
    for series in result.series:
        # forward and backward cancel in the mean: 0.01·q is left
        np.testing.assert_allclose(series.y, 0.01 * series.x, atol=1e-12)


@pytest.fixture(scope="module")
def small_loop(small_plan):
    imported = import_plan(load_plan(small_plan))
    from volucal.core.identify import IdentifyOptions
    from volucal.core.residuals import LoopOptions

    options = LoopOptions(identify=IdentifyOptions(spacing_mm=100.0), max_steps=2)
    return imported, close_loop(imported.measurement, options), options


def test_identification_record_survives_the_project_file(small_loop, tmp_path):
    imported, loop, options = small_loop
    tree = identification_result_tree(loop.final, options.identify)
    project = Project.create(imported.measurement.machine)
    project.put_result("identifications", "loop", tree)
    project.save(tmp_path / "p.h5")
    stored = Project.open(tmp_path / "p.h5").result("identifications", "loop")
    live = IdentificationRecord.from_identification("loop", loop.final, options.identify)
    loaded = IdentificationRecord.from_tree("loop", stored)
    assert loaded.parameters == live.parameters
    assert loaded.identifiability == live.identifiability
    assert loaded.options == {"spacing_mm": 100.0, "refine": True, "max_iterations": 6}
    for name in ReadingTable._ARRAYS:
        np.testing.assert_array_equal(getattr(loaded.readings, name),
                                      getattr(live.readings, name))
    assert loaded.readings.line_names == live.readings.line_names
    # the residual RMS a reader computes is the core's
    r = loop.final.residual[~loop.final.readings.is_angular]
    assert loaded.residual_rms()[0] == pytest.approx(float(np.sqrt(np.mean(r**2))))
    assert [e["label"] for e in loaded.effects] == [e.label for e in loop.final.effects]


def test_loop_record_keeps_every_candidate_and_round_trips(small_loop):
    _, loop, _ = small_loop
    record = LoopRecord.from_loop("main", loop)
    labels = {c["label"] for c in record.candidates}
    assert labels >= {s.finding.effect.label for s in loop.steps}
    assert {c["label"] for c in record.candidates if c["kept"]} == {
        e.label for e in loop.final.effects}
    again = LoopRecord.from_tree("main", record.to_tree())
    assert again.report == record.report
    assert again.candidates == record.candidates


def test_effects_rebuilt_from_json_have_the_same_design(small_loop):
    imported, loop, _ = small_loop
    measurement = imported.measurement
    readings = flatten(measurement)
    for entry in loop_candidates(loop):
        original = next(s.finding.effect for s in loop.steps
                        if s.finding.effect.label == entry["label"]) if not entry["kept"] else \
            next(e for e in loop.final.effects if e.label == entry["label"])
        rebuilt = effect_from_json(entry["effect"], measurement)
        assert type(rebuilt) is type(original)
        assert rebuilt.label == original.label
        np.testing.assert_array_equal(rebuilt.design(readings, loop.base.model),
                                      original.design(readings, loop.base.model))


def test_effect_json_has_the_constructor_fields():
    effect = Cyclic(axis_name="Y", period_mm=16.0, harmonics=(1, 2), reference_mm=0.0)
    entry = effect_to_json(effect)
    assert entry["class"] == "Cyclic"
    assert entry["fields"] == {"axis_name": "Y", "period_mm": 16.0, "harmonics": [1, 2],
                               "reference_mm": 0.0, "period_searched": False}
    reversal = effect_to_json(Reversal(axis_name="X", order=1, stroke_mm=(0.0, 400.0)))
    assert reversal["fields"]["stroke_mm"] == [0.0, 400.0]


def test_uniform_and_triangular_factors_have_the_spread_as_standard_deviation():
    setup = SensitivitySetup.paper_table2(n=200)
    factor = setup.factor("EXX")
    uniform = setup.with_factor("EXX", distribution="uniform").factor("EXX").to_distribution()
    # a uniform distribution on [a, b] has standard deviation (b − a)/√12
    assert (uniform.high - uniform.low) / math.sqrt(12) == pytest.approx(factor.spread)
    assert (uniform.high + uniform.low) / 2 == pytest.approx(factor.mean)
    triangular = setup.with_factor("EXX", distribution="triangular").factor(
        "EXX").to_distribution()
    samples = triangular.ppf(np.random.default_rng(1).random(400_000))
    assert samples.std() == pytest.approx(factor.spread, rel=5e-3)
    assert samples.mean() == pytest.approx(factor.mean, abs=5e-3 * factor.spread)


def test_identified_setup_spreads_come_from_the_covariance(small_loop):
    _, loop, _ = small_loop
    final = loop.final
    setup = SensitivitySetup.identified(final.model, final.covariance, n=200)
    sl = final.model.parameter_slices["EC0Y"]
    expected = max(math.sqrt(final.covariance[sl, sl][0, 0]), 0.1)  # at least the µrad floor
    assert setup.factor("EC0Y").spread == pytest.approx(expected)
    assert setup.factor("EC0Y").mean == pytest.approx(final.model.squareness_urad["EC0Y"])
    with pytest.raises(Exception, match="only its spread"):
        setup.with_factor("EXX", mean=3.0)
    edited = setup.with_factor("EXX", spread=5.0)
    assert edited.spread_overrides() == {"EXX": 5.0}
    assert SensitivitySetup.from_json(edited.to_json()) == edited


def test_guess_reads_the_line_from_the_file_name():
    spec = guess_spec(Path("/logs/x_straight_y.rtl"), PAPER_MACHINE)
    assert (spec.name, spec.quantity, spec.direction, spec.sensitive) == (
        "x_straight_y", "straightness", (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    assert spec.reflector_mm == PAPER_MACHINE.tool_offset_mm
    angular = guess_spec(Path("/logs/z_angle_x.rta"), PAPER_MACHINE)
    assert (angular.quantity, angular.direction, angular.sensitive) == (
        "angular", (0.0, 0.0, 1.0), (1.0, 0.0, 0.0))
    assert guess_spec(Path("/logs/y_linear.rtl"), PAPER_MACHINE).quantity == "linear"


def test_a_row_gives_back_its_spec_exactly():
    spec = LineSpec("diag", "linear", (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (0.0, 0.0, 200.0),
                    file="/logs/diag.rtl")
    assert LineRow.from_spec(spec).to_spec() == spec


def test_row_errors_name_the_line_and_the_field():
    row = LineRow.from_spec(LineSpec("x", "linear", (0, 0, 0), (1, 0, 0), (0, 0, 0)))
    row.start = "1, 2"
    with pytest.raises(PlanError, match=r"line 'x': start: expected three numbers"):
        row.to_spec()
    with pytest.raises(PlanError, match="not a number"):
        parse_vector("1, two, 3", "line 'x': start")
    row.start = "0, 0, 0"
    row.quantity = "straightness"
    with pytest.raises(PlanError, match="sensitive is required"):
        row.to_spec()
