"""The virtual machine measures the way a laser does."""

import numpy as np
import pytest
from volucal.core import plans
from volucal.core.io.plan import import_plan, load_plan
from volucal.core.iso230_2 import evaluate
from volucal.core.simulate import (
    LaserSetup,
    Reversal,
    ThermalDrift,
    VirtualMachine,
    random_truth,
    write_session,
)


@pytest.fixture(scope="module")
def session():  # type: ignore[no-untyped-def]
    truth = random_truth(seed=8)
    vm = VirtualMachine(truth, (Reversal("X", 3.0), ThermalDrift("Y", 11.5, 1.5, 3600.0)), seed=8)
    lines = plans.direct(truth.machine, 20.0, 3.0)
    return vm, lines, vm.measure(lines)


def test_bidirectional_runs_zeroed_at_the_first_target(session) -> None:  # type: ignore[no-untyped-def]
    _, lines, measurement = session
    for line in measurement.lines:
        d = line.data
        assert d.runs == 10
        assert list(d.run_direction[:4]) == [1, -1, 1, -1]
        assert d.deviations[0, 0] == 0.0
    times = [line.data.start_time for line in measurement.lines]
    assert times == sorted(times) and len(set(times)) == len(times)


def test_reversal_shows_as_the_iso_230_2_reversal(session) -> None:  # type: ignore[no-untyped-def]
    _, _, measurement = session
    result = evaluate(measurement.line("x_linear").data)
    assert result.B_um == pytest.approx(3.0, abs=0.3)
    assert evaluate(measurement.line("z_linear").data).B_um < 0.5


def test_thermal_drift_raises_the_logged_material_temperature(session) -> None:  # type: ignore[no-untyped-def]
    _, _, measurement = session
    first = measurement.lines[0].data.environment.material_temp_c[0][0]
    last = measurement.lines[-1].data.environment.material_temp_c[0][1]
    assert last - first == pytest.approx(1.5, abs=0.1)


def test_straightness_optics_carry_a_random_slope() -> None:
    truth = random_truth(seed=9)
    slopes = []
    for seed in range(6):
        vm = VirtualMachine(truth, seed=seed, laser=LaserSetup(noise_um=0.0))
        line = vm.measure(plans.direct(truth.machine, 20.0)[1:2]).lines[0]
        slopes.append(np.polyfit(line.data.targets_mm, line.data.deviations[0], 1)[0])
    assert np.std(slopes) > 0.01  # µm per mm: tens of µrad of alignment


def test_written_session_reads_back_through_the_plan(tmp_path, session) -> None:  # type: ignore[no-untyped-def]
    _, _, measurement = session
    plan_path = write_session(measurement, tmp_path)
    imported = import_plan(load_plan(plan_path)).measurement
    assert [l.name for l in imported.lines] == [l.name for l in measurement.lines]
    for a, b in zip(imported.lines, measurement.lines, strict=True):
        assert a.spec.quantity == b.spec.quantity
        assert np.allclose(a.data.targets_mm, b.data.targets_mm, atol=1e-6)
        assert np.allclose(a.data.deviations, b.data.deviations, atol=1e-4)
        assert a.data.start_time == pytest.approx(b.data.start_time, abs=1.0)
