"""Choosing what to compensate from S1 and the eq. 19 tolerances."""

from __future__ import annotations

import math

import pytest
from volucal.core.compensation import select_compensation
from volucal.core.userror import UserError


def test_eq19_as_published_reproduces_the_paper_table3() -> None:
    """Paper: S1(δx(x)) on ET = 0.23 (Fig. 3), T = 25 µm → Table 3 prints 0.97 µm."""
    selection = select_compensation({"EXX": 0.23, "EZZ": 0.24}, tolerance_um=25.0)
    by_id = {a.id: a for a in selection.allocations}
    assert by_id["EXX"].sigma_published == pytest.approx(math.sqrt(0.23 * 25 / 6))
    assert by_id["EXX"].sigma_published == pytest.approx(0.97, abs=0.01)
    assert by_id["EZZ"].sigma_published == pytest.approx(0.98, abs=0.03)  # printed 0.98


def test_selection_reaches_the_coverage_and_reports_the_residual() -> None:
    s1 = {"EXX": 0.5, "EZZ": 0.3, "EXZ": 0.15, "EYY": 0.04, "ECX": -0.01}
    selection = select_compensation(s1, tolerance_um=25.0, coverage=0.95, output_std_um=20.0)
    assert selection.selected == ("EXX", "EZZ", "EXZ")
    assert selection.residual_variance_fraction == pytest.approx(0.05)
    assert selection.residual_std_um == pytest.approx(math.sqrt(0.05) * 20.0)
    assert not selection.tolerance_met  # 6 × 4.47 µm > 25 µm
    assert select_compensation(s1, 25.0, 0.95, output_std_um=10.0).tolerance_met  # 6 × 2.24
    assert [a.id for a in selection.allocations][-1] == "ECX"  # negative estimate -> 0
    assert selection.allocations[-1].s1 == 0.0


def test_sound_form_divides_by_the_sensitivity_coefficient() -> None:
    selection = select_compensation(
        {"EXX": 0.25, "ECY": 0.75}, tolerance_um=24.0, coefficients={"EXX": 2.0}
    )
    by_id = {a.id: a for a in selection.allocations}
    assert by_id["EXX"].sigma_sound == pytest.approx(math.sqrt(0.25) * 24 / 6 / 2)
    assert by_id["ECY"].sigma_sound is None
    assert selection.output_std_um == 4.0  # T/6 when not given
    assert selection.to_json()["selected"] == ["ECY", "EXX"]


def test_bad_input_is_refused_with_a_clear_message() -> None:
    with pytest.raises(UserError, match="EQQ"):
        select_compensation({"EQQ": 0.5})
    with pytest.raises(UserError, match="coverage"):
        select_compensation({"EXX": 0.5}, coverage=1.5)
    with pytest.raises(UserError, match="tolerance"):
        select_compensation({"EXX": 0.5}, tolerance_um=0.0)
