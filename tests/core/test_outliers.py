"""Outlier screening flags (never drops) readings and runs outside the run-to-run spread."""

import numpy as np
import pytest
from volucal.core.io.iso_table import read_iso_table
from volucal.core.measurement import LineData
from volucal.core.outliers import drop, screen, screen_series


def clean_line(seed: int = 4, runs: int = 10, count: int = 21, sigma: float = 0.5) -> LineData:
    rng = np.random.default_rng(seed)
    targets = np.linspace(0, 400, count)
    direction = np.tile([1, -1], runs // 2)
    deviations = 0.01 * targets + direction[:, None] * 1.0 + rng.normal(0, sigma, (runs, count))
    return LineData(targets, deviations, direction, np.zeros((runs, count)))


def test_clean_gaussian_data_is_not_flagged():
    for seed in range(20):
        assert screen(clean_line(seed)) == []


def test_a_single_bad_reading_is_flagged_with_its_reason():
    data = clean_line()
    bad = data.deviations.copy()
    bad[4, 7] += 8.0  # 16 σ
    flags = screen(LineData(data.targets_mm, bad, data.run_direction, data.times_s), line="x")
    assert len(flags) == 1
    flag = flags[0]
    assert (flag.line, flag.run, flag.target) == ("x", 5, 8)
    assert flag.target_mm == pytest.approx(140.0)
    assert flag.value == bad[4, 7]
    assert flag.statistic > 10
    assert "run 5 (forward)" in flag.reason and "140 mm" in flag.reason and "σ" in flag.reason
    assert flag.to_json()["run"] == 5


def test_a_shifted_run_is_flagged_as_a_run():
    data = clean_line()
    bad = data.deviations.copy()
    bad[3] += 6.0
    flags = screen(LineData(data.targets_mm, bad, data.run_direction, data.times_s))
    assert len(flags) == 1 and flags[0].target is None and flags[0].run == 4
    assert "backward" in flags[0].reason and "21 of 21 targets" in flags[0].reason


def test_drop_only_on_request():
    data = clean_line()
    bad = data.deviations.copy()
    bad[0, 0] += 9.0
    bad[3] += 6.0
    line = LineData(data.targets_mm, bad, data.run_direction, data.times_s)
    flags = screen(line)
    assert len(flags) == 2
    assert np.array_equal(line.deviations, bad)  # screening leaves the data alone
    dropped = drop(line, flags)
    assert np.isnan(dropped.deviations[0, 0]) and np.isnan(dropped.deviations[3]).all()
    assert np.isfinite(dropped.deviations).sum() == bad.size - 1 - 21


def test_too_few_runs_are_not_screened():
    data = clean_line(runs=4)  # two runs per direction
    bad = data.deviations.copy()
    bad[0, 0] += 50
    assert screen(LineData(data.targets_mm, bad, data.run_direction, data.times_s)) == []


def test_real_outlier_in_the_first_cycle(realdata):
    """The ESS mcu1025 acceptance data: REFERENCE §7 notes a +113 µm outlier in the first
    cycle (forward, first target) — and the second target of that cycle is off as well."""
    table = read_iso_table(realdata / "psi_ecmc_iso230_2" /
                           "ess_mcu1025_fat_sat_report.md_ISO230.dat")
    data = table.data
    microns = LineData(data.targets_mm, data.deviations * 1e3, data.run_direction, data.times_s)
    flags = screen(microns, line="mcu1025", unit="um")
    flagged = {(f.run, f.target) for f in flags}
    assert (1, 1) in flagged and (1, 2) in flagged
    first = next(f for f in flags if (f.run, f.target) == (1, 1))
    median_others = np.median(microns.deviations[[2, 4, 6, 8], 0])
    assert first.value - median_others == pytest.approx(113.9, abs=1.0)
    assert all(f.run == 1 for f in flags)


def drifting_line(seed: int = 2, runs: int = 24, count: int = 5) -> LineData:
    """A thermal test in the manner of ISO 230-3: the same five targets read again and again
    (forward runs only) while the axis grows by up to 15 µm with a warm-up time constant."""
    rng = np.random.default_rng(seed)
    targets = np.linspace(0, 400, count)
    minutes = np.arange(runs)[:, None] * 10.0 + np.arange(count)[None, :] * 0.5
    growth = 15.0 * (1 - np.exp(-minutes / 60.0)) * (targets / 400.0)
    deviations = growth + rng.normal(0, 0.3, (runs, count))
    return LineData(targets, deviations, np.ones(runs, dtype=np.int64), minutes * 60.0)


def test_a_warm_up_over_many_runs_is_a_trend_not_outliers():
    """With the median of the other runs as the reference, the first runs of the warm-up sit
    far below the rest and are flagged; against the smooth trend over time they are not."""
    for seed in range(10):
        assert screen(drifting_line(seed)) == []
    data = drifting_line()
    bad = data.deviations.copy()
    bad[9, 3] += 3.0  # 10 σ off the trend, well inside the range the warm-up spans
    flags = screen(LineData(data.targets_mm, bad, data.run_direction, data.times_s), line="z")
    assert [(f.run, f.target) for f in flags] == [(10, 4)]
    assert flags[0].statistic > 6


def test_two_neighbouring_bad_readings_do_not_hide_each_other():
    data = drifting_line(runs=40)
    bad = data.deviations.copy()
    bad[20, 2] += 4.0
    bad[21, 2] += 4.0
    flags = screen(LineData(data.targets_mm, bad, data.run_direction, data.times_s))
    assert {(f.run, f.target) for f in flags} == {(21, 3), (22, 3)}


def test_series_screen_flags_a_spike_in_a_transient():
    t = np.arange(0, 600.0) * 60
    rng = np.random.default_rng(1)
    y = 20 * (1 - np.exp(-t / 7200)) + rng.normal(0, 0.1, t.size)
    assert screen_series(t, y) == []
    y[123] += 1.5
    flags = screen_series(t, y, name="Z", unit="um")
    assert [f.sample for f in flags] == [124]
    assert "Z at sample 124" in flags[0].reason and "smooth trend" in flags[0].reason
