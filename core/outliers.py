"""Outlier screening: readings or whole runs far outside the run-to-run spread of a line.

Screening only flags; it never drops. Each flag says which run and target, the value, why, and
the statistic, so that the user (or the ``--drop-outliers`` option of ``volucal import``) decides.

Method. For every reading x_ij (run j, target i) the reference is the median of the *other* runs
of the same direction at the same target (leave-one-out, so that the reading cannot hide itself);
the residual r_ij = x_ij − median. The run-to-run spread of the line is the robust standard
deviation σ = 1.4826·median|r| over all its residuals (floored at ``min_sigma``, so that
quantised or noiseless data do not turn rounding into outliers). A reading with |r| > k·σ is
flagged (k = ``threshold``, default 5: for Gaussian scatter one false flag in about 1.7 million
readings). A run with at least half of its readings flagged (and at least two) is flagged as a
whole run instead: it is shifted or broken, not one bad reading. Targets with fewer than three
runs in a direction are not screened (two readings cannot say which one is wrong).

A smooth transient is not an outlier. When a direction has many runs (at least
``MIN_TREND_RUNS``: a thermal test in the manner of ISO 230-3, the same targets measured again
and again while the machine warms up), the runs drift, and the median of the other runs is no
reference: every warm-up run would be flagged. There the reference of a reading is the smooth
trend of its target over time: a local straight line through the ``TREND_HALF_WINDOW`` runs on
either side in time, fitted without the reading itself (leave-one-out) and, in a second pass,
without the neighbours the first pass flagged (so that one bad reading does not hide the next).
A reading is then an outlier only if it leaves that trend. :func:`screen_series` applies the same
screen to one series over time (an error or temperature channel of a thermal record).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from .measurement import LineData

ROBUST_SIGMA = 1.4826  # σ of a Gaussian from its median absolute deviation
#: From this many runs in one direction the reference is the time trend, not the median.
MIN_TREND_RUNS = 8
#: Runs (or samples) on each side of a reading that its local trend line is fitted to.
TREND_HALF_WINDOW = 10


@dataclass(frozen=True)
class OutlierFlag:
    """One flagged reading (``target`` set) or one flagged run (``target`` None).

    run and target are 1-based indexes into the line's runs and (ascending) targets.
    """

    line: str
    run: int
    target: int | None
    target_mm: float | None
    value: float
    reason: str
    statistic: float

    def to_json(self) -> dict[str, object]:
        return {
            "line": self.line,
            "run": self.run,
            "target": self.target,
            "target_mm": self.target_mm,
            "value": self.value,
            "reason": self.reason,
            "statistic": self.statistic,
        }


def screen(
    data: LineData,
    *,
    line: str = "",
    threshold: float = 5.0,
    min_sigma: float = 0.05,
    unit: str = "um",
) -> list[OutlierFlag]:
    """Flag readings and runs far outside the run-to-run spread (see the module notes)."""
    x = data.deviations
    residual = np.full(x.shape, np.nan)
    trended: set[int] = set()
    for direction in (1, -1):
        rows = np.flatnonzero(data.run_direction == direction)
        if rows.size < 3:
            continue
        block = x[rows]
        if rows.size >= MIN_TREND_RUNS:
            times = _run_times(data, rows)
            for column in range(x.shape[1]):
                residual[rows, column] = trend_residual(times, block[:, column], min_sigma)
            trended.add(direction)
            continue
        for position, row in enumerate(rows):
            others = np.delete(block, position, axis=0)
            enough = np.sum(np.isfinite(others), axis=0) >= 2
            # columns with too few other readings get a dummy reference and no residual
            reference = np.nanmedian(np.where(enough, others, 0.0), axis=0)
            residual[row] = np.where(enough, x[row] - reference, np.nan)
    finite = np.isfinite(residual)
    if not finite.any():
        return []
    sigma = max(ROBUST_SIGMA * float(np.median(np.abs(residual[finite]))), min_sigma)
    score = np.abs(residual) / sigma
    flagged = finite & (score > threshold)
    symbol = "µrad" if unit == "urad" else "µm"
    flags: list[OutlierFlag] = []
    for run in range(x.shape[0]):
        sense = "forward" if data.run_direction[run] > 0 else "backward"
        hits = np.flatnonzero(flagged[run])
        screened = int(np.sum(finite[run]))
        if hits.size >= 2 and 2 * hits.size >= screened:
            offset = float(np.nanmedian(residual[run]))
            flags.append(
                OutlierFlag(
                    line,
                    run + 1,
                    None,
                    None,
                    offset,
                    f"run {run + 1} ({sense}) lies outside the run-to-run spread at {hits.size} "
                    f"of {screened} targets: median offset {offset:+.3f} {symbol}, "
                    f"{abs(offset) / sigma:.1f} σ (σ = {sigma:.3f} {symbol})",
                    float(np.nanmedian(score[run])),
                )
            )
            continue
        against = (
            f"the smooth trend over time of the other {sense} runs"
            if data.run_direction[run] in trended
            else f"the median of the other {sense} runs"
        )
        for target in hits:
            r = float(residual[run, target])
            flags.append(
                OutlierFlag(
                    line,
                    run + 1,
                    int(target) + 1,
                    float(data.targets_mm[target]),
                    float(x[run, target]),
                    f"reading at {data.targets_mm[target]:g} mm, run {run + 1} ({sense}) is "
                    f"{r:+.3f} {symbol} from {against}: "
                    f"{abs(r) / sigma:.1f} σ of the run-to-run spread (σ = {sigma:.3f} {symbol})",
                    float(score[run, target]),
                )
            )
    return flags


def drop(data: LineData, flags: Iterable[OutlierFlag]) -> LineData:
    """The line with every flagged reading (or whole flagged run) set to NaN (missing)."""
    deviations = data.deviations.copy()
    for flag in flags:
        if flag.target is None:
            deviations[flag.run - 1] = np.nan
        else:
            deviations[flag.run - 1, flag.target - 1] = np.nan
    return replace(data, deviations=deviations)


def _run_times(data: LineData, rows: np.ndarray) -> np.ndarray:
    """Each run's mean reading time; the run order where the times are unknown or equal."""
    with np.errstate(all="ignore"):
        times = np.nanmean(np.asarray(data.times_s, dtype=float)[rows], axis=1)
    if not np.all(np.isfinite(times)) or np.unique(times).size < times.size:
        return np.arange(rows.size, dtype=float)
    return times


def trend_residual(
    time_s: np.ndarray,
    values: np.ndarray,
    min_sigma: float = 0.05,
    threshold: float = 5.0,
    half_window: int = TREND_HALF_WINDOW,
) -> np.ndarray:
    """Each value's standardised distance from its leave-one-out local trend, in the values'
    unit (module notes); NaN where a value is missing or has too few neighbours. Values need
    not be in time order.

    The trend is a local quadratic through the neighbours (a line would cut the corner of a
    warm-up's early curvature); its prediction at the left-out sample is less certain at the
    ends of a record, where the neighbours lie on one side only, so each residual is divided by
    √(1 + h), h the prediction's leverage (its variance in units of the scatter), which makes
    all residuals comparable with one σ.
    """
    out = np.full(values.shape, np.nan)
    finite = np.flatnonzero(np.isfinite(values) & np.isfinite(time_s))
    if finite.size < 5:
        return out
    order = finite[np.argsort(time_s[finite], kind="stable")]
    t = np.asarray(time_s, dtype=float)[order]
    x = np.asarray(values, dtype=float)[order]
    # time in units of the median step keeps the window sums well conditioned
    step = float(np.median(np.diff(t))) or 1.0
    t = (t - t[0]) / step
    weights = np.ones(x.size)
    residual = _local_trend_residual(t, x, weights, half_window)
    finite_residual = residual[np.isfinite(residual)]
    if finite_residual.size:
        sigma = max(ROBUST_SIGMA * float(np.median(np.abs(finite_residual))), min_sigma)
        suspect = np.abs(residual) > threshold * sigma
        if suspect.any():
            weights[suspect] = 0.0
            residual = _local_trend_residual(t, x, weights, half_window)
    out[order] = residual
    return out


def _local_trend_residual(
    t: np.ndarray, x: np.ndarray, w: np.ndarray, half_window: int
) -> np.ndarray:
    """(x_i − q_i(t_i)) / √(1 + h_i): q_i the weighted least-squares quadratic through the
    neighbours j ≠ i, |i − j| ≤ half_window, h_i its leverage at t_i (vectorised over i: one
    pass per offset, then one batched 3 × 3 solve)."""
    n = x.size
    moments = np.zeros((n, 5))  # Σ w·dt^k, k = 0…4
    rhs = np.zeros((n, 3))  # Σ w·dt^k·x, k = 0…2
    for offset in range(-half_window, half_window + 1):
        if offset == 0:
            continue
        lo, hi = max(0, -offset), min(n, n - offset)
        if lo >= hi:
            continue
        i = np.arange(lo, hi)
        j = i + offset
        dt = t[j] - t[i]
        powers = w[j][:, None] * dt[:, None] ** np.arange(5)
        moments[i] += powers
        rhs[i] += powers[:, :3] * x[j][:, None]
    normal = np.stack([moments[:, k : k + 3] for k in range(3)], axis=1)
    usable = moments[:, 0] >= 5
    normal[~usable] = np.eye(3)
    scale = np.sqrt(np.abs(np.diagonal(normal, axis1=1, axis2=2)))  # equilibrate, then solve
    scale[scale == 0] = 1.0
    balanced = normal / scale[:, :, None] / scale[:, None, :]
    well_posed = usable & (np.linalg.cond(balanced) < 1e10)
    balanced[~well_posed] = np.eye(3)
    inverse = np.linalg.inv(balanced) / scale[:, :, None] / scale[:, None, :]
    level = np.einsum("ij,ij->i", inverse[:, 0, :], rhs)
    leverage = inverse[:, 0, 0]
    return np.where(well_posed, (x - level) / np.sqrt(1.0 + leverage), np.nan)


@dataclass(frozen=True)
class SeriesFlag:
    """One sample of a time series that leaves its smooth trend (``sample`` is 1-based)."""

    channel: str
    sample: int
    time_s: float
    value: float
    reason: str
    statistic: float

    def to_json(self) -> dict[str, object]:
        return {
            "channel": self.channel,
            "sample": self.sample,
            "time_s": self.time_s,
            "value": self.value,
            "reason": self.reason,
            "statistic": self.statistic,
        }


def screen_series(
    time_s: np.ndarray,
    values: np.ndarray,
    *,
    name: str = "",
    unit: str = "um",
    threshold: float = 5.0,
    min_sigma: float = 0.05,
) -> list[SeriesFlag]:
    """Flag the samples of a series over time that leave its smooth local trend by more than
    ``threshold`` robust σ of the residuals (module notes); a warm-up or cool-down is a trend,
    not a set of outliers. Flags only; never drops."""
    time = np.asarray(time_s, dtype=float)
    x = np.asarray(values, dtype=float)
    residual = trend_residual(time, x, min_sigma, threshold)
    finite = np.isfinite(residual)
    if not finite.any():
        return []
    sigma = max(ROBUST_SIGMA * float(np.median(np.abs(residual[finite]))), min_sigma)
    symbol = {"um": "µm", "urad": "µrad", "c": "°C"}.get(unit, unit)
    flags = []
    for k in np.flatnonzero(finite & (np.abs(residual) > threshold * sigma)):
        r = float(residual[k])
        flags.append(
            SeriesFlag(
                name,
                int(k) + 1,
                float(time[k]),
                float(x[k]),
                f"{name or 'value'} at sample {k + 1} ({time[k]:g} s) is {r:+.3f} {symbol} from "
                f"the smooth trend of its neighbours: {abs(r) / sigma:.1f} σ of the scatter about "
                f"the trend (σ = {sigma:.3f} {symbol})",
                abs(r) / sigma,
            )
        )
    return flags
