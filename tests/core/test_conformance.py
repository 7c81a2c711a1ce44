"""ISO 14253-1 decisions against hand-worked values (volucal.core.conformance)."""

import math

import numpy as np
import pytest
from volucal.core.conformance import (
    CONFORMS,
    DOES_NOT_CONFORM,
    NO_DECISION,
    accuracy_conformance,
    combine,
    decide,
    volumetric_conformance,
)
from volucal.core.errors import ErrorModel
from volucal.core.identify import UncertaintyBudget
from volucal.core.machine import PAPER_MACHINE
from volucal.core.measurement import Line, LineData, LineSpec
from volucal.core.userror import UserError

#: A budget with nothing but the laser's ±1 ppm (rectangular): u = 1/√3 ppm of the distance.
LASER_ONLY = UncertaintyBudget(laser_ppm=1.0, air_temp_sensor_c=0.0, material_temp_sensor_c=0.0,
                               expansion_coeff_ppm=0.0, material_offset_c=0.0, dead_path_mm=0.0,
                               air_temp_change_c=0.0, cosine_urad=0.0, abbe_mm=0.0)
NO_SETUP = UncertaintyBudget(laser_ppm=0.0, air_temp_sensor_c=0.0, material_temp_sensor_c=0.0,
                             expansion_coeff_ppm=0.0, material_offset_c=0.0, dead_path_mm=0.0,
                             air_temp_change_c=0.0, cosine_urad=0.0, abbe_mm=0.0)


@pytest.mark.parametrize(
    ("value", "u", "tolerance", "verdict"),
    [
        (8.0, 1.0, 10.0, CONFORMS),  # 8 + 1 ≤ 10
        (9.0, 1.0, 10.0, CONFORMS),  # on the conformance limit: y + U = T
        (9.5, 1.0, 10.0, NO_DECISION),  # 10.5 > T but 8.5 ≤ T
        (10.5, 1.0, 10.0, NO_DECISION),
        (11.0, 1.0, 10.0, NO_DECISION),  # y − U = T is not beyond T
        (11.5, 1.0, 10.0, DOES_NOT_CONFORM),
        (math.nan, 1.0, 10.0, NO_DECISION),
    ],
)
def test_decision_zones_of_iso_14253_1(value, u, tolerance, verdict):
    assert decide(value, u, tolerance) == verdict


def test_one_failing_item_fails_the_whole_and_one_undecided_leaves_no_decision():
    assert combine([CONFORMS, CONFORMS]) == CONFORMS
    assert combine([CONFORMS, NO_DECISION]) == NO_DECISION
    assert combine([NO_DECISION, DOES_NOT_CONFORM, CONFORMS]) == DOES_NOT_CONFORM
    assert combine([]) == NO_DECISION


def _line(name: str, quantity: str, deviations, directions, targets) -> Line:
    sensitive = None if quantity == "linear" else (0.0, 1.0, 0.0)
    spec = LineSpec(name, quantity, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 200.0),
                    sensitive=sensitive)
    deviations = np.asarray(deviations, dtype=float)
    times = np.arange(deviations.size, dtype=float).reshape(deviations.shape)
    return Line(spec, LineData(np.asarray(targets, float), deviations, np.asarray(directions),
                               times))


def test_accuracy_decision_uses_iso_230_2_a_and_the_laser_budget():
    # two runs each way over 0…400 mm. Up: x̄↑ = (0, 3), s↑ = (0.5·√2, 0) … worked by hand:
    # up runs (0, 3) and (1, 3): x̄↑ = (0.5, 3), s↑ = (0.7071, 0)
    # down runs (−1, 2) and (−1, 2): x̄↓ = (−1, 2), s↓ = (0, 0)
    # A = max(x̄ + 2s) − min(x̄ − 2s) = max(1.914, 3, −1, 2) − min(−0.914, 3, −1, 2) = 4
    line = _line("x", "linear", [[0, 3], [-1, 2], [1, 3], [-1, 2]], [1, -1, 1, -1], [0, 400])
    straight = _line("s", "straightness", [[0, 9], [0, 9]], [1, -1], [0, 400])
    expected_u = 400.0 * 1e3 * 1e-6 / math.sqrt(3)  # 400 mm at 1/√3 ppm, in µm
    result = accuracy_conformance([line, straight], LASER_ONLY, tolerance_um=4.2)
    (item,) = result.items  # the straightness line is not a positioning line
    assert item.value_um == pytest.approx(4.0, abs=1e-12)
    assert item.expanded_uncertainty_um == pytest.approx(2 * expected_u, rel=1e-12)
    assert item.verdict == NO_DECISION  # 4 + 0.46 > 4.2 > 4 − 0.46
    assert accuracy_conformance([line], LASER_ONLY, 5.0).verdict == CONFORMS
    assert accuracy_conformance([line], LASER_ONLY, 3.0).verdict == DOES_NOT_CONFORM


def test_accuracy_needs_a_linear_line_and_a_positive_tolerance():
    straight = _line("s", "straightness", [[0, 9], [0, 9]], [1, -1], [0, 400])
    with pytest.raises(UserError, match="no linear line"):
        accuracy_conformance([straight], LASER_ONLY, 5.0)
    with pytest.raises(UserError, match="positive"):
        accuracy_conformance([straight], LASER_ONLY, -1.0)


def test_volumetric_decision_on_a_squareness_error_alone():
    # EC0Y = 50 µrad tilts Y towards X: |E| = 50e-6 · y, largest at y = 400 mm: 20 µm.
    # With σ(EC0Y) = 1 µrad and no set-up budget, u = 1e-6 · 400 mm = 0.4 µm.
    model = ErrorModel(PAPER_MACHINE, ErrorModel.zero(PAPER_MACHINE).functions,
                       {"EC0Y": 50.0, "EB0Z": 0.0, "EA0Z": 0.0})
    covariance = np.zeros((model.parameter_count, model.parameter_count))
    index = model.parameter_slices["EC0Y"].start
    covariance[index, index] = 1.0
    result = volumetric_conformance(model, covariance, NO_SETUP, tolerance_um=21.0)
    (item,) = result.items
    assert item.value_um == pytest.approx(20.0, rel=1e-6)
    assert item.expanded_uncertainty_um == pytest.approx(0.8, rel=1e-6)
    assert "Y 400" in item.where
    assert item.verdict == CONFORMS  # 20 + 0.8 ≤ 21
    assert volumetric_conformance(model, covariance, NO_SETUP, 20.5).verdict == NO_DECISION
    assert volumetric_conformance(model, covariance, NO_SETUP, 19.0).verdict == DOES_NOT_CONFORM
    with pytest.raises(UserError, match="covariance"):
        volumetric_conformance(model, covariance[:-1, :-1], NO_SETUP, 20.0)
