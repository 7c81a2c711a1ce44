"""Every reading of a measurement flattened into arrays: the context identification, effects and
the closed loop work on (position, approach direction, time, temperature, line)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from .measurement import Line, LineData, Measurement

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

QUANTITY_CODE = {"linear": 0, "straightness": 1, "angular": 2}
#: Repeatability floor (µm or µrad): weights never exceed 1/floor².
SIGMA_FLOOR = 0.01


@dataclass(frozen=True, eq=False)
class Readings:
    """One entry per valid reading (NaN readings are left out).

    line : index of the line in ``lines``; run, target : indices into the line's data.
    position_mm : NC position of the target; target_mm : distance from the line start.
    approach : (n, 3) sign of the last motion of each axis (+1 from below, −1 from above).
    time_s : seconds since the session's first reading; material_temp_c : per reading (NaN if
    not logged). material_ends_s, material_ends_c : (n, 2) session times of the file's first and
    last reading and the material temperatures logged there, where the file logs the temperature
    only at its two ends (material_temp_c is then interpolated linearly between them); NaN where
    it logs one per reading or none. value : the reading (µm or µrad); sigma : its
    repeatability (same unit).
    projection : (n, 3) beam direction (linear), deviation direction (straightness) or rotation
    axis (angular). reflector_mm : (n, 3) optics offset used for that line.
    """

    lines: tuple[Line, ...]
    line: IntArray
    run: IntArray
    target: IntArray
    position_mm: FloatArray
    target_mm: FloatArray
    approach: FloatArray
    time_s: FloatArray
    material_temp_c: FloatArray
    material_ends_s: FloatArray
    material_ends_c: FloatArray
    value: FloatArray
    sigma: FloatArray
    quantity: IntArray
    projection: FloatArray
    reflector_mm: FloatArray

    def __len__(self) -> int:
        return int(self.value.size)

    @property
    def line_names(self) -> list[str]:
        return [line.name for line in self.lines]

    @cached_property
    def is_angular(self) -> NDArray[np.bool_]:
        return self.quantity == QUANTITY_CODE["angular"]

    def line_mask(self, index: int) -> NDArray[np.bool_]:
        return self.line == index


_ARRAY_FIELDS = (
    "line",
    "run",
    "target",
    "position_mm",
    "target_mm",
    "approach",
    "time_s",
    "material_temp_c",
    "material_ends_s",
    "material_ends_c",
    "value",
    "sigma",
    "quantity",
    "projection",
    "reflector_mm",
)


def repeatability(line: Line) -> float:
    """Pooled run-to-run standard deviation of a line (µm or µrad), per target and direction.

    The spread of repeated readings at one target in one direction is what the instrument and the
    machine repeat to; it sets the weight of the line in identification.
    """
    d = line.data
    squares = 0.0
    dof = 0
    for sign in (1, -1):
        block = d.deviations[d.run_direction == sign]
        if len(block) < 2:
            continue
        centred = block - np.nanmean(block, axis=0)
        valid = np.isfinite(centred)
        squares += float(np.sum(centred[valid] ** 2))
        dof += int(valid.sum() - np.sum(valid.any(axis=0)))
    if dof <= 0:
        return float("nan")
    return max(float(np.sqrt(squares / dof)), SIGMA_FLOOR)


#: Per-reading temperatures within this of a straight line in time (°C) were interpolated
#: between the file's two logs, not logged at every reading.
STRAIGHT_LINE_C = 1e-9


def _sensor_means(data: LineData) -> FloatArray | None:
    """The material temperature a file logs at its start and at its end (°C): the mean of its
    sensors, as the Renishaw reader interpolates between them; None where it logs none."""
    sensors = np.asarray(data.environment.material_temp_c, dtype=float)
    return sensors.reshape(-1, 2).mean(axis=0) if sensors.size else None


def _logged_ends(
    data: LineData, times: FloatArray, material: FloatArray
) -> tuple[FloatArray, FloatArray] | None:
    """The times (s from the file's start) and temperatures of a file's two material logs, when
    its per-reading temperatures are the straight line between them (as a file that logs the
    environment at its start and end is read); None when they were logged at every reading."""
    ends_c = _sensor_means(data)
    if ends_c is None or times.size < 2 or not np.all(np.isfinite(material)):
        return None
    slope, offset = np.polyfit(times, material, 1)
    straight = np.max(np.abs(offset + slope * times - material)) <= STRAIGHT_LINE_C
    if not straight or abs(ends_c[1] - ends_c[0]) <= STRAIGHT_LINE_C or slope == 0.0:
        return None
    ends_s = (ends_c - offset) / slope
    span = float(np.ptp(times))
    if ends_s[0] > times.min() + 1e-6 * span or ends_s[1] < times.max() - 1e-6 * span:
        return None
    return ends_s, ends_c


def flatten(measurement: Measurement, default_sigma: float = 0.5) -> Readings:
    """All readings of a measurement, with repeatability-based sigmas."""
    origin = measurement.session_start
    parts: dict[str, list[np.ndarray]] = {name: [] for name in _ARRAY_FIELDS}
    for index, line in enumerate(measurement.lines):
        d = line.data
        spec = line.spec
        runs, count = d.deviations.shape
        run, target = np.meshgrid(np.arange(runs), np.arange(count), indexing="ij")
        valid = np.isfinite(d.deviations)
        run, target = run[valid], target[valid]
        n = run.size
        direction = np.asarray(spec.direction)
        moving = np.abs(direction) > 1e-12
        approach = np.ones((n, 3))
        approach[:, moving] = np.sign(direction[moving]) * d.run_direction[run][:, None]
        sigma = repeatability(line)
        if not np.isfinite(sigma):
            sigma = default_sigma
        material = np.full(n, np.nan)
        ends_s = np.full((n, 2), np.nan)
        ends_c = np.full((n, 2), np.nan)
        if d.material_temp_c is not None:
            material = np.asarray(d.material_temp_c, float)[run, target]
            ends = _logged_ends(d, d.times_s[run, target], material)
            if ends is not None:
                ends_s[:], ends_c[:] = ends[0] + d.start_time - origin, ends[1]
        elif (means := _sensor_means(d)) is not None:
            start, end = means
            first, last = float(np.nanmin(d.times_s)), float(np.nanmax(d.times_s))
            fraction = (d.times_s[run, target] - first) / ((last - first) or 1.0)
            material = start + (end - start) * fraction
            ends_s[:] = (d.start_time + first - origin, d.start_time + last - origin)
            ends_c[:] = (start, end)
        if spec.quantity == "linear":
            projection = direction
        else:
            assert spec.sensitive is not None
            projection = np.asarray(spec.sensitive)
        parts["line"].append(np.full(n, index))
        parts["run"].append(run)
        parts["target"].append(target)
        parts["position_mm"].append(spec.positions(d.targets_mm)[target])
        parts["target_mm"].append(d.targets_mm[target])
        parts["approach"].append(approach)
        parts["time_s"].append(d.start_time + d.times_s[run, target] - origin)
        parts["material_temp_c"].append(material)
        parts["material_ends_s"].append(ends_s)
        parts["material_ends_c"].append(ends_c)
        parts["value"].append(d.deviations[run, target])
        parts["sigma"].append(np.full(n, sigma))
        parts["quantity"].append(np.full(n, QUANTITY_CODE[spec.quantity]))
        parts["projection"].append(np.broadcast_to(projection, (n, 3)))
        parts["reflector_mm"].append(np.broadcast_to(np.asarray(spec.reflector_mm), (n, 3)))
    arrays = {k: np.concatenate(v) if v else np.empty(0) for k, v in parts.items()}
    for key in ("line", "run", "target", "quantity"):
        arrays[key] = arrays[key].astype(np.int64)
    return Readings(measurement.lines, **arrays)
