"""A simulated thermal test with a known answer, for tests, examples and the workbench's demo.

A spindle runs a duty cycle (on, off, on at a lower speed, off) in a room whose temperature
drifts.
Heat reaches the sensors with first-order lags; the error channel is a known model of them::

    e = c0 + Σ_i c_i · F(T_i, τ_i) + noise,

so a fit can be checked against the truth: the sensors it should read, their time constants and
coefficients. Distractor sensors follow the same heat with other lags (correlated, as on a real
machine) but do not drive the error; one sensor can be stuck. Noise is AR(1) — a thermal error's
scatter is correlated from sample to sample — from a seeded ``numpy.random.Generator``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from .thermal import ThermalMeasurement, thermal_measurement
from .thermal_model import first_order_response


@dataclass(frozen=True)
class SimulatedThermalTest:
    """Settings of :func:`simulate_thermal_test`; ``truth`` maps a driving sensor to
    (coefficient µm/°C, time constant s)."""

    hours: float = 24.0
    interval_s: float = 60.0
    intercept_um: float = 0.0
    truth: Mapping[str, tuple[float, float]] = field(
        default_factory=lambda: {
            "spindle": (2.0, 1800.0),
            "column": (-1.2, 0.0),
        }
    )
    distractors: int = 4
    noise_um: float = 0.2
    noise_correlation: float = 0.9
    sensor_noise_c: float = 0.02
    stuck_sensor: bool = False
    seed: int = 1


def simulate_thermal_test(
    settings: SimulatedThermalTest | None = None, name: str = "simulated"
) -> ThermalMeasurement:
    """The simulated record (module notes), error channel ``"Z drift"`` in µm."""
    s = settings or SimulatedThermalTest()
    rng = np.random.default_rng(s.seed)
    time_s = np.arange(0.0, s.hours * 3600.0 + 1e-9, s.interval_s)
    hours = time_s / 3600.0
    # the heat source, a duty cycle in the manner of ISO 230-3: spindle on, off, on at a lower
    # speed, off (at 0, 20, 35 and 70 % of the test)
    fraction = hours / s.hours
    power = np.select([fraction < 0.2, fraction < 0.35, fraction < 0.7], [1.0, 0.0, 0.6], 0.0)
    room = 20.0 + 0.8 * np.sin(2 * np.pi * hours / 24.0) + 0.02 * hours
    heat = first_order_response(time_s, power, 2400.0)
    temperatures: dict[str, np.ndarray] = {}
    sources = {
        "spindle": room + 14.0 * heat,
        "column": room + 3.0 * first_order_response(time_s, power, 7200.0),
    }
    for k in range(s.distractors):
        lag = 600.0 * (k + 1)
        share = 0.3 + 0.15 * k
        sources[f"T{k + 1}"] = (
            room
            + 6.0 * share * first_order_response(time_s, power, lag)
            + 0.3 * k * np.sin(2 * np.pi * hours / (5.0 + k))
        )
    sources["room"] = room
    for sensor, values in sources.items():
        temperatures[sensor] = values + rng.normal(0.0, s.sensor_noise_c, time_s.size)
    error = np.full(time_s.size, s.intercept_um)
    for sensor, (coefficient, tau_s) in s.truth.items():
        exact = sources[sensor]
        error += coefficient * (first_order_response(time_s, exact, tau_s) - exact[0])
    innovation = rng.normal(0.0, s.noise_um * np.sqrt(1 - s.noise_correlation**2), time_s.size)
    noise = np.empty(time_s.size)
    noise[0] = rng.normal(0.0, s.noise_um)
    for k in range(1, time_s.size):
        noise[k] = s.noise_correlation * noise[k - 1] + innovation[k]
    if s.stuck_sensor:
        temperatures["stuck"] = np.full(time_s.size, 23.5)
    return thermal_measurement(name, time_s, {"Z drift": error + noise}, temperatures)
