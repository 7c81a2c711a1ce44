"""A material temperature logged only at a file's two ends: the readings keep where and what the
two logs were, and the drift candidate that reads the temperature between them as a first-order
response meets both logs, follows a structure that settles exactly for the right time constant
and is the straight line for a long one."""

from dataclasses import replace

import numpy as np
import pytest
from volucal.core import plans
from volucal.core import simulate as sim
from volucal.core.effects import ThermalDrift, first_order_temperature
from volucal.core.io.rtl import read_rtl, write_rtl
from volucal.core.measurement import Environment, Line, Measurement
from volucal.core.readings import flatten


def _measurement() -> Measurement:
    truth = sim.random_truth(seed=3)
    vm = sim.VirtualMachine(truth, (), seed=3, laser=sim.LaserSetup(noise_um=0.1))
    return vm.measure(plans.layout("full", truth.machine, 25.0, 0.0))


def _through_rtl(line: Line, tmp_path, temperature, origin: float) -> Line:
    """The line as a Renishaw file that logs the material temperature at its start and end
    (``temperature`` of the session time, s) reads back: per-reading temperatures on the
    straight line between the two logs."""
    path = tmp_path / f"{line.name}.rtl"
    write_rtl(path, line.data)
    log = read_rtl(path)  # where the file's start and end fall
    ends = (temperature(log.start_time - origin), temperature(log.end_time - origin))
    environment = Environment(material_temp_c=(ends,), expansion_ppm_per_c=11.5)
    write_rtl(path, replace(line.data, environment=environment))
    return Line(line.spec, read_rtl(path).data)


def test_a_renishaw_file_is_known_to_log_the_temperature_at_its_ends(tmp_path) -> None:
    measurement = _measurement()
    lines = list(measurement.lines)
    origin = measurement.session_start
    lines[0] = _through_rtl(lines[0], tmp_path, lambda t: 20.20 if t <= 0.0 else 21.10, origin)
    # the second line's temperatures were logged at every reading: a sensor's scatter
    data = lines[1].data
    logged = 20.5 + np.random.default_rng(1).normal(0.0, 0.02, data.deviations.shape)
    lines[1] = Line(lines[1].spec, replace(data, material_temp_c=logged))
    readings = flatten(replace(measurement, lines=tuple(lines)))

    first = readings.line == 0
    np.testing.assert_allclose(readings.material_ends_c[first], [[20.20, 21.10]] * first.sum())
    # the logs are the file's start and end: the readings lie between them
    start, end = readings.material_ends_s[first][0]
    assert start <= readings.time_s[first].min() and readings.time_s[first].max() < end
    assert start == pytest.approx(lines[0].data.start_time - origin, abs=1e-6)
    # the interpolated temperatures meet both logs along the straight line
    straight = 20.20 + 0.90 * (readings.time_s[first] - start) / (end - start)
    np.testing.assert_allclose(readings.material_temp_c[first], straight, atol=1e-9)

    assert np.isnan(readings.material_ends_c[readings.line == 1]).all()
    np.testing.assert_allclose(
        readings.material_temp_c[readings.line == 1],
        logged[readings.run[readings.line == 1], readings.target[readings.line == 1]],
    )


def test_the_first_order_reading_follows_a_structure_that_settles(tmp_path) -> None:
    measurement = _measurement()
    tau, rise = 400.0, 1.5
    origin = measurement.session_start

    def settling(t):  # °C: 20 + rise·(1 − exp(−t/τ)), t from the session's start
        return 20.0 + rise * -np.expm1(-np.asarray(t) / tau)

    lines = list(measurement.lines)
    lines[0] = _through_rtl(lines[0], tmp_path, lambda t: float(settling(t)), origin)
    readings = flatten(replace(measurement, lines=tuple(lines)))
    first = readings.line == 0
    t0, t1 = readings.material_ends_s[first][0]
    ends = settling(np.array([t0, t1]))
    np.testing.assert_allclose(readings.material_ends_c[first][0], ends, atol=1e-12)

    # the right time constant gives the structure's temperature at every reading in the file
    between = first_order_temperature(readings, tau)[first]
    np.testing.assert_allclose(between, settling(readings.time_s[first]), atol=1e-9)
    # the straight line misses it by a tenth of the rise and more
    assert np.max(np.abs(readings.material_temp_c[first] - between)) > 0.1 * rise
    # a time constant far beyond the file is the straight line between the logs
    np.testing.assert_allclose(
        first_order_temperature(readings, 1e9)[first], readings.material_temp_c[first], atol=1e-5
    )
    # readings of other files keep their temperature
    np.testing.assert_array_equal(
        first_order_temperature(readings, tau)[~first], readings.material_temp_c[~first]
    )

    drift = ThermalDrift("X", "temperature", tau, 0.0, first_order=True)
    assert drift.searched == 1
    assert drift.parameters(np.array([11.5]), np.array([[0.04]])) == {
        "mode": "temperature",
        "expansion_ppm_per_c": 11.5,
        "expansion_std_ppm_per_c": pytest.approx(0.2),
        "between_logs": "first order",
        "time_constant_s": tau,
    }
