"""Identification on simulated machines with known ground truth and no extra effects."""

import numpy as np
import pytest
from volucal.core import plans
from volucal.core.errors import ERROR_IDS, SQUARENESS_IDS
from volucal.core.identify import IdentificationError, IdentifyOptions, identify
from volucal.core.machine import Machine
from volucal.core.measurement import Measurement
from volucal.core.simulate import LaserSetup, VirtualMachine, random_truth

STRAIGHTNESS = {"EYX", "EZX", "EXY", "EZY", "EXZ", "EYZ"}
ROLL = {"EAX", "EBY", "ECZ"}
SQUARENESS = set(SQUARENESS_IDS)


def _measure(
    layout: str, seed: int, machine: Machine | None = None, step: float = 12.0, noise: float = 0.1
) -> tuple[VirtualMachine, Measurement]:
    truth = random_truth(machine, seed) if machine else random_truth(seed=seed)
    vm = VirtualMachine(truth, seed=seed, laser=LaserSetup(noise_um=noise, noise_urad=noise))
    return vm, vm.measure(plans.layout(layout, truth.machine, step))


def _errors(result, truth) -> dict[str, tuple[float, float]]:  # type: ignore[no-untyped-def]
    """Per identified error: (max |identified − truth|, max standard uncertainty)."""
    out = {}
    for eid in ERROR_IDS:
        if not result.is_identified(eid):
            continue
        q, value, std = result.band(eid)
        true = (
            np.array([truth.squareness_urad[eid]])
            if eid in SQUARENESS_IDS
            else truth.functions[eid](q)
        )
        out[eid] = (float(np.max(np.abs(value - true))), float(np.max(std)))
    return out


def test_full_plan_recovers_every_error_within_absolute_limits() -> None:
    vm, measurement = _measure("full", seed=21, step=6.0)
    result = identify(measurement)
    assert result.identifiability.rank == result.identifiability.unknowns
    assert not result.identifiability.unidentifiable
    for eid, (error, _) in _errors(result, vm.truth).items():
        limit = 1.0 if result.model.machine and eid[1] in "ABC" or eid in SQUARENESS_IDS else 0.2
        assert error < limit, (eid, error)
    assert result.sigma_scale == pytest.approx(1.0, abs=0.05)


def test_full_plan_on_another_chain() -> None:
    machine = Machine(name="gantry", chain="WFXYZT", tool_offset_mm=(0.0, 0.0, 150.0))
    vm, measurement = _measure("full", seed=4, machine=machine)
    result = identify(measurement)
    assert not result.identifiability.unidentifiable
    for eid, (error, std) in _errors(result, vm.truth).items():
        assert error < max(4 * std, 0.05), eid


def test_coverage_of_the_95_percent_band_over_many_seeds() -> None:
    inside, total = 0, 0
    for seed in range(12):
        vm, measurement = _measure("direct" if seed % 2 else "full", seed=100 + seed)
        result = identify(measurement, IdentifyOptions(redundancy=False))
        for eid in ERROR_IDS:
            if not result.is_identified(eid) or eid in ("EXX", "EYY", "EZZ"):
                # the positioning bands include the (systematic) budget: tested separately
                continue
            q, value, std = result.band(eid, count=11)
            true = (
                np.array([vm.truth.squareness_urad[eid]])
                if eid in SQUARENESS_IDS
                else vm.truth.functions[eid](q)
            )
            keep = std > 0
            inside += int(np.sum(np.abs(value - true)[keep] < 1.96 * std[keep]))
            total += int(keep.sum())
    coverage = inside / total
    assert 0.92 < coverage < 0.985, coverage


def test_positioning_band_includes_the_uncertainty_budget() -> None:
    vm, measurement = _measure("direct", seed=3)
    result = identify(measurement)
    q, _, std = result.band("EXX")
    budget = result.budget.positioning_std_um(q - q[0])
    assert np.all(std >= budget - 1e-12)
    assert std[-1] > std[0]


def test_nine_line_plan_reports_straightness_roll_and_squareness() -> None:
    _, measurement = _measure("nine-line", seed=2)
    result = identify(measurement)
    missing = {u.ids[0] for u in result.identifiability.unidentifiable}
    assert missing == STRAIGHTNESS | ROLL | SQUARENESS
    messages = " ".join(u.message for u in result.identifiability.unidentifiable)
    assert "roll of X (EAX) is not seen by this plan" in messages
    # what it does see, it gets right
    assert result.is_identified("EXX") and result.is_identified("ECY")


def test_displacement_only_plan_identifies_all_21_errors() -> None:
    _, measurement = _measure("displacement-only", seed=5)
    result = identify(measurement)
    assert result.identifiability.rank == result.identifiability.unknowns
    assert len(measurement.lines) == 25


def test_redundant_lines_are_those_that_can_be_left_out() -> None:
    _, measurement = _measure("direct", seed=6)
    result = identify(measurement)
    redundant = set(result.identifiability.redundant_lines)
    names = [line.name for line in measurement.lines]
    essential = [n for n in names if n not in redundant]
    assert essential and redundant
    # leaving out an essential line loses rank; leaving out a redundant one does not
    for name, should_lose in ((essential[0], True), (sorted(redundant)[0], False)):
        reduced = Measurement(
            measurement.machine, tuple(l for l in measurement.lines if l.name != name)
        )
        sub = identify(reduced, IdentifyOptions(redundancy=False))
        lost = sub.identifiability.rank - (
            result.identifiability.rank - _own_columns(measurement, name)
        )
        assert (lost < 0) == should_lose, name


def _own_columns(measurement: Measurement, name: str) -> int:
    line = measurement.line(name)
    return 2 if line.spec.quantity == "straightness" else 1


def test_empty_measurement_is_a_clear_error() -> None:
    with pytest.raises(IdentificationError, match="no lines"):
        identify(Measurement(random_truth().machine, ()))
