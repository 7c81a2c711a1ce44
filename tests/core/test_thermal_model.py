"""Thermal models: the first-order lag, the fit and its uncertainty, the honest choice."""

import dataclasses
import json

import numpy as np
import pytest
from scipy.signal import lsim
from volucal.core.compensation.export_thermal import (
    ThermalExportOptions,
    check_points,
    export_thermal,
)
from volucal.core.project import Project
from volucal.core.thermal import thermal_measurement
from volucal.core.thermal_fit import (
    ThermalFitOptions,
    ThermalFitRequest,
    fit_thermal,
    rolling_origin_folds,
)
from volucal.core.thermal_model import (
    ThermalModel,
    ThermalTerm,
    first_order_response,
    fit_model,
    newey_west_covariance,
)
from volucal.core.thermal_sim import SimulatedThermalTest, simulate_thermal_test
from volucal.core.thermal_store import load_thermal, load_thermal_result, store_thermal
from volucal.core.userror import UserError

# ---- the lag ---------------------------------------------------------------------------------


def test_step_and_ramp_responses_are_analytic() -> None:
    t = np.linspace(0, 3000, 61)
    tau = 400.0
    step = np.where(t > 0, 5.0, 0.0)
    step[0] = 0.0
    # a step between samples 0 and 1 is a ramp over the first interval; after it the analytic
    # response of a ramp of duration h: 5·(1 − τ/h·(1 − e^(−h/τ))) at t = h, then decay
    h = t[1]
    after_ramp = 5.0 * (1 - tau / h * (1 - np.exp(-h / tau)))
    expected = 5.0 + (after_ramp - 5.0) * np.exp(-(t[1:] - h) / tau)
    np.testing.assert_allclose(first_order_response(t, step, tau)[1:], expected, rtol=1e-12)
    ramp = 0.01 * t
    exact = 0.01 * (t - tau * (1 - np.exp(-t / tau)))  # started at equilibrium, F(0) = 0
    np.testing.assert_allclose(first_order_response(t, ramp, tau), exact, atol=1e-12)


def test_lag_matches_a_continuous_simulation_and_irregular_sampling() -> None:
    t = np.linspace(0, 7200, 2001)
    signal = 20 + 3 * np.sin(2 * np.pi * t / 1800) + 0.001 * t
    tau = 600.0
    # scipy's continuous-time simulation of 1/(τs + 1) with the same first-order hold
    _, reference, _ = lsim(([1.0], [tau, 1.0]), signal - signal[0], t, interp=True)
    np.testing.assert_allclose(first_order_response(t, signal, tau), reference + signal[0],
                               atol=1e-9)
    # irregular sampling: a signal linear between its (irregular) samples gives the same
    # response whether it is sampled there only or on the fine regular grid
    rng = np.random.default_rng(3)
    keep = np.sort(np.concatenate([[0, t.size - 1],
                                   rng.choice(np.arange(1, t.size - 1), 300, replace=False)]))
    piecewise = np.interp(t, t[keep], signal[keep])
    np.testing.assert_allclose(first_order_response(t[keep], signal[keep], tau),
                               first_order_response(t, piecewise, tau)[keep], atol=1e-9)
    assert np.array_equal(first_order_response(t, signal, 0.0), signal)


# ---- fitting ---------------------------------------------------------------------------------


def test_newey_west_covers_autocorrelated_scatter() -> None:
    """Monte Carlo: with AR(1) noise (ρ = 0.95) the ordinary least-squares standard error of a
    slope is several times too small; the Newey–West one is right within 35 %."""
    rng = np.random.default_rng(7)
    n = 600
    x = np.sin(np.linspace(0, 6 * np.pi, n)) + np.linspace(0, 2, n)
    design = np.column_stack([np.ones(n), x])
    slopes, hac, ols = [], [], []
    for _ in range(300):
        e = np.empty(n)
        e[0] = rng.normal()
        for k in range(1, n):
            e[k] = 0.95 * e[k - 1] + rng.normal(0, np.sqrt(1 - 0.95**2))
        y = 1.0 + 2.0 * x + e
        coef, *_ = np.linalg.lstsq(design, y, rcond=None)
        r = y - design @ coef
        slopes.append(coef[1])
        hac.append(np.sqrt(newey_west_covariance(design, r)[1, 1]))
        ols.append(np.sqrt(np.linalg.inv(design.T @ design)[1, 1] * (r @ r) / (n - 2)))
    spread = np.std(slopes)
    assert np.mean(ols) < spread / 3
    assert 0.65 * spread < np.mean(hac) < 1.35 * spread


def test_fit_recovers_a_known_model() -> None:
    m = simulate_thermal_test(SimulatedThermalTest(
        truth={"spindle": (2.0, 0.0), "column": (-1.2, 0.0)}, noise_um=0.2, seed=3))
    result = fit_thermal(ThermalFitRequest(m))
    assert set(result.model.sensors) >= {"spindle", "column"}
    coefficient = dict(zip([t.sensor for t in result.model.terms if t.power == 1],
                           result.model.coefficients, strict=False))
    assert coefficient["spindle"] == pytest.approx(2.0, abs=0.1)
    assert coefficient["column"] == pytest.approx(-1.2, abs=0.15)
    # the held-out error is the noise (0.2 µm RMS), far below the uncompensated drift
    assert result.test_rms < 0.35
    assert result.uncompensated_test_rms > 10


def test_a_lag_is_found_where_the_static_model_leaves_one() -> None:
    m = simulate_thermal_test(SimulatedThermalTest(
        truth={"spindle": (2.0, 1800.0)}, distractors=2, noise_um=0.05, seed=5))
    result = fit_thermal(ThermalFitRequest(m))
    lagged = [t for t in result.model.terms if t.sensor == "spindle"]
    assert lagged and lagged[0].tau_s == pytest.approx(1800.0, rel=0.2)
    assert any(d.startswith("lags: kept") for d in result.decisions)
    static = fit_thermal(ThermalFitRequest(m, options=ThermalFitOptions(dynamic=False)))
    assert result.test_rms < 0.5 * static.test_rms
    assert not static.model.dynamic


def test_the_test_part_never_influences_the_choice() -> None:
    """Honesty: whatever the held-out part holds, the chosen model and its coefficients are
    the same; only the reported test error changes."""
    m = simulate_thermal_test(SimulatedThermalTest(seed=2))
    a = fit_thermal(ThermalFitRequest(m))
    channel = m.errors[0]
    values = channel.values.copy()
    values[a.train_samples:] += 50.0 * np.sin(np.arange(values.size - a.train_samples))
    changed = dataclasses.replace(m, errors=(dataclasses.replace(channel, values=values),))
    b = fit_thermal(ThermalFitRequest(changed))
    assert a.model.terms == b.model.terms
    np.testing.assert_array_equal(a.model.coefficients, b.model.coefficients)
    assert a.decisions == b.decisions
    assert b.test_rms > 10 * a.test_rms


def test_folds_never_use_the_future() -> None:
    folds = rolling_origin_folds(100, blocks=10, initial_fraction=0.5)
    assert [v[0] for _, v in folds] == [50, 60, 70, 80, 90]
    for fit, validate in folds:
        assert fit.max() < validate.min() and np.all(np.diff(validate) == 1)


def test_bad_requests_are_user_errors() -> None:
    m = simulate_thermal_test(SimulatedThermalTest(hours=0.2, stuck_sensor=True))
    with pytest.raises(UserError, match="too few to choose a model"):
        fit_thermal(ThermalFitRequest(m, options=ThermalFitOptions(train_fraction=0.05)))
    full = simulate_thermal_test(SimulatedThermalTest(stuck_sensor=True))
    assert [e.name for e in full.excluded] == ["stuck"]
    with pytest.raises(UserError, match=r"'stuck' \(excluded: stuck\)"):
        fit_thermal(ThermalFitRequest(full, options=ThermalFitOptions(sensors=("stuck",))))
    with pytest.raises(UserError, match="training fraction"):
        ThermalFitOptions(train_fraction=0)


# ---- the model as a controller sees it -----------------------------------------------------


def _model() -> ThermalModel:
    t = np.arange(0, 4000.0, 60)
    temps = {"a": 20 + 5 * (1 - np.exp(-t / 900)), "b": 21 + 0.001 * t}
    y = 1.5 + 2.0 * (first_order_response(t, temps["a"], 300) - 20) - 0.5 * (temps["b"] - 21) \
        + 0.1 * (temps["b"] - 21) ** 2
    terms = [ThermalTerm("a", 300.0), ThermalTerm("b"), ThermalTerm("b", 0.0, 2)]
    return fit_model("Z drift", "um", t, y, temps, terms)


def test_steady_state_and_json_round_trip() -> None:
    model = _model()
    again = ThermalModel.from_json(json.loads(json.dumps(model.to_json())))
    assert again.terms == model.terms
    np.testing.assert_allclose(again.coefficients, model.coefficients)
    state = {"a": 24.0, "b": 22.5}
    t = np.array([0.0, 1e6])
    record = {k: np.full(2, v) for k, v in state.items()}
    assert model.predict_steady(state) == pytest.approx(model.predict(t, record)[-1])
    assert "Z drift [µm] =" in model.formula() and "F(a, τ=5 min)" in model.formula()


def test_export_states_units_signs_and_check_points(tmp_path) -> None:
    model = _model()
    export = export_thermal(model, tmp_path, ThermalExportOptions(period_s=0.002))
    names = sorted(p.name for p in export.files)
    assert names == ["thermal-z-drift-check.csv", "thermal-z-drift.csv", "thermal-z-drift.hal",
                     "thermal-z-drift.json"]
    hal = (tmp_path / "thermal-z-drift.hal").read_text(encoding="ascii")
    assert "compensation = -error" in hal and "degC" in hal and "um" in hal
    gain = float(-np.expm1(-0.002 / 300.0))
    assert f"setp thermal-z-drift-lag0.gain {gain!r}" in hal
    data = json.loads((tmp_path / "thermal-z-drift.json").read_text())
    assert data["units"] == {"error": "um", "temperature": "degC", "time_constant": "s",
                             "compensation": "mm"}
    assert "compensation = -error" in data["sign_convention"]
    for point in data["check_points"]:
        expected = model.predict_steady(point["temperatures_degC"])
        assert point["error_um"] == pytest.approx(expected)
        assert point["compensation_mm"] == pytest.approx(-expected / 1000)
    assert len(check_points(model)) == 1 + 2 * 2
    table = (tmp_path / "thermal-z-drift.csv").read_text().splitlines()
    rows = [line.split(",") for line in table if not line.startswith("#")]
    assert rows[0][0] == "term" and rows[1][0] == "intercept"
    assert float(rows[1][5]) == pytest.approx(model.intercept)
    assert [r[1] for r in rows[2:]] == ["a", "b", "b"]
    angular = dataclasses.replace(model, unit="urad")
    with pytest.raises(UserError, match="only translation errors"):
        export_thermal(angular, tmp_path / "x")


def test_project_round_trip(tmp_path) -> None:
    m = simulate_thermal_test(SimulatedThermalTest(hours=6, stuck_sensor=True), name="warmup")
    result = fit_thermal(ThermalFitRequest(m))
    project = Project.create()
    assert store_thermal(project, "warmup", m, [result]) == "/thermal/warmup"
    project.save(tmp_path / "p.h5")
    stored = load_thermal(Project.open(tmp_path / "p.h5"), "warmup")
    back = stored.measurement
    np.testing.assert_array_equal(back.time_s, m.time_s)
    np.testing.assert_array_equal(back.errors[0].values, m.errors[0].values)
    assert back.sensor_names == m.sensor_names and [e.name for e in back.excluded] == ["stuck"]
    model = stored.models["Z drift"]
    np.testing.assert_allclose(model.predict(back.time_s, back.temperature_map()),
                               result.predicted)
    assert stored.results["Z drift"]["test_rms_um"] == pytest.approx(result.test_rms)
    with pytest.raises(UserError, match="no thermal record 'x'"):
        load_thermal(Project.open(tmp_path / "p.h5"), "x")
    again = load_thermal_result(Project.open(tmp_path / "p.h5"), "warmup")
    assert again.model.terms == result.model.terms and again.decisions == result.decisions
    assert again.test_rms == pytest.approx(result.test_rms)
    assert again.baselines == result.baselines and again.subsets == result.subsets
    assert again.term_spread == pytest.approx(result.term_spread)
    np.testing.assert_array_equal(again.predicted, result.predicted)
    assert again.outliers == result.outliers


def test_measurement_from_arrays_excludes_stuck() -> None:
    m = thermal_measurement("m", [0, 1, 2], {"e": [0, 1, 2]}, {"T1": [1, 2, 3], "T2": [5, 5, 5]})
    assert m.sensor_names == ("T1",) and m.excluded[0].name == "T2"
