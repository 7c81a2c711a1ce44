"""Outlier screening flags (never drops) readings and runs outside the run-to-run spread."""

import numpy as np
import pytest
from volucal.core.io.iso_table import read_iso_table
from volucal.core.measurement import LineData
from volucal.core.outliers import drop, screen


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
