"""Positioning accuracy and repeatability by ISO 230-2 (clause 2 definitions), and ISO 230-1
straightness against the least-squares, the minimum-zone and the end-point reference lines.

With x_ij = P_ij − P_i the deviation at target i in run j (``measured − target``), ↑ the runs that
approach in the positive direction (``run_direction`` +1) and ↓ the others:

- x̄↑_i, x̄↓_i: mean unidirectional deviations; x̄_i = (x̄↑_i + x̄↓_i)/2 the bidirectional mean;
- B_i = x̄↑_i − x̄↓_i the reversal value, B = max|B_i|, B̄ = mean B_i;
- s↑_i, s↓_i: sample standard deviations (n − 1); R↑_i = 4 s↑_i;
  R_i = max(2 s↑_i + 2 s↓_i + |B_i|, R↑_i, R↓_i); R↑ = max R↑_i, R = max R_i;
- E↑ = max x̄↑ − min x̄↑ (systematic positioning error); E = max(x̄↑, x̄↓) − min(x̄↑, x̄↓);
- M = max x̄ − min x̄ (mean bidirectional positioning error);
- A↑ = max(x̄↑ + 2s↑) − min(x̄↑ − 2s↑); A = max over both directions of (x̄ + 2s) − min over both of
  (x̄ − 2s) (accuracy).

Straightness (ISO 230-1, 3.4.8 and 3.4.9): the range of the deviations about a reference straight
line. The least-squares line minimises the sum of squared deviations; the minimum zone is the
narrowest pair of parallel lines that enclose the points (their separation measured along the
deviation, as ISO 230-1 does for a line), never more than the least-squares value; the end-point
line joins the first and last points. :func:`minimum_zone` is exact: the zone width
f(m) = max(y − m·x) − min(y − m·x) is convex and piecewise linear in the slope m with its breaks
at the slopes of the edges of the points' convex hull, so its minimum is at one of those slopes,
found by bisection over them in O(n log n).

Written from these definitions (REFERENCE.md §5 warns that an open implementation has bugs).
Values that cannot be computed (one run in a direction, no runs the other way) are NaN, and
``None`` in JSON.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .measurement import LineData

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Iso230Result:
    """ISO 230-2 values of one line. The ``_um`` fields hold the line's unit (µrad for an angular
    line; :meth:`to_json` then names the keys ``_urad``)."""

    unit: str
    targets_mm: FloatArray
    runs_up: int
    runs_down: int
    mean_up: FloatArray
    mean_down: FloatArray
    mean: FloatArray
    s_up: FloatArray
    s_down: FloatArray
    reversal: FloatArray
    repeatability: FloatArray
    repeatability_up: FloatArray
    repeatability_down: FloatArray
    A_um: float
    E_um: float
    R_um: float
    B_um: float
    M_um: float
    A_up_um: float
    A_down_um: float
    E_up_um: float
    E_down_um: float
    R_up_um: float
    R_down_um: float
    mean_reversal_um: float

    def to_json(self) -> dict[str, object]:
        """The DESIGN.md keys (``A_um``, ``E_um``, ``R_um``, ``B_um``, ``M_um``, ``A_up_um``, …)
        plus the per-target means and spreads; NaN becomes None."""
        u = self.unit
        out: dict[str, object] = {"unit": u, "runs_up": self.runs_up, "runs_down": self.runs_down}
        for key in (
            "A",
            "E",
            "R",
            "B",
            "M",
            "A_up",
            "A_down",
            "E_up",
            "E_down",
            "R_up",
            "R_down",
            "mean_reversal",
        ):
            out[f"{key}_{u}"] = _number(getattr(self, f"{key}_um"))
        out["targets_mm"] = _numbers(self.targets_mm)
        for key, values in (
            ("mean_up", self.mean_up),
            ("mean_down", self.mean_down),
            ("mean", self.mean),
            ("s_up", self.s_up),
            ("s_down", self.s_down),
            ("reversal", self.reversal),
            ("repeatability", self.repeatability),
            ("repeatability_up", self.repeatability_up),
            ("repeatability_down", self.repeatability_down),
        ):
            out[f"{key}_{u}"] = _numbers(values)
        return out


def _number(value: float) -> float | None:
    return None if not math.isfinite(value) else float(value)


def _numbers(values: FloatArray) -> list[float | None]:
    return [_number(float(v)) for v in values]


def _direction_stats(block: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Per-target mean and sample standard deviation over the runs of one direction."""
    count = np.sum(np.isfinite(block), axis=0)
    with warnings.catch_warnings():
        # a target no run of this direction reached (or reached once) has no mean (or no s)
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(block, axis=0) if block.shape[0] else np.full(block.shape[1], np.nan)
        s = np.nanstd(block, axis=0, ddof=1) if block.shape[0] else np.full(block.shape[1], np.nan)
    return mean, np.where(count >= 2, s, np.nan)


def _span(high: FloatArray, low: FloatArray) -> float:
    if not (np.isfinite(high).all() and np.isfinite(low).all()) or high.size == 0:
        return math.nan
    return float(np.max(high) - np.min(low))


def evaluate(data: LineData, unit: str = "um") -> Iso230Result:
    """ISO 230-2 positioning values of a line (module notes give the definitions)."""
    up = data.deviations[data.run_direction > 0]
    down = data.deviations[data.run_direction < 0]
    mean_up, s_up = _direction_stats(up)
    mean_down, s_down = _direction_stats(down)
    mean = (mean_up + mean_down) / 2.0
    reversal = mean_up - mean_down
    r_up = 4.0 * s_up
    r_down = 4.0 * s_down
    repeatability = np.maximum(np.maximum(2 * s_up + 2 * s_down + np.abs(reversal), r_up), r_down)

    def max_or_nan(values: FloatArray) -> float:
        return float(np.max(values)) if values.size and np.isfinite(values).all() else math.nan

    both_means = np.concatenate([mean_up, mean_down])
    both_high = np.concatenate([mean_up + 2 * s_up, mean_down + 2 * s_down])
    both_low = np.concatenate([mean_up - 2 * s_up, mean_down - 2 * s_down])
    return Iso230Result(
        unit=unit,
        targets_mm=data.targets_mm,
        runs_up=int(up.shape[0]),
        runs_down=int(down.shape[0]),
        mean_up=mean_up,
        mean_down=mean_down,
        mean=mean,
        s_up=s_up,
        s_down=s_down,
        reversal=reversal,
        repeatability=repeatability,
        repeatability_up=r_up,
        repeatability_down=r_down,
        A_um=_span(both_high, both_low),
        E_um=_span(both_means, both_means),
        R_um=max_or_nan(repeatability),
        B_um=max_or_nan(np.abs(reversal)),
        M_um=_span(mean, mean),
        A_up_um=_span(mean_up + 2 * s_up, mean_up - 2 * s_up),
        A_down_um=_span(mean_down + 2 * s_down, mean_down - 2 * s_down),
        E_up_um=_span(mean_up, mean_up),
        E_down_um=_span(mean_down, mean_down),
        R_up_um=max_or_nan(r_up),
        R_down_um=max_or_nan(r_down),
        mean_reversal_um=float(np.mean(reversal)) if np.isfinite(reversal).all() else math.nan,
    )


#: How each straightness value is named in outputs.
STRAIGHTNESS_METHODS = {
    "least_squares": "least-squares reference line (ISO 230-1)",
    "minimum_zone": "minimum zone (ISO 230-1)",
    "end_point": "end-point reference line (ISO 230-1)",
}


@dataclass(frozen=True)
class Straightness:
    """Straightness of one profile in its deviations' unit, by each reference line, with the
    slope (unit per mm) of the least-squares and minimum-zone lines."""

    least_squares: float
    minimum_zone: float
    end_point: float
    slope_least_squares: float
    slope_minimum_zone: float

    def to_json(self, unit: str) -> dict[str, object]:
        return {
            f"least_squares_{unit}": self.least_squares,
            f"minimum_zone_{unit}": self.minimum_zone,
            f"end_point_{unit}": self.end_point,
            "methods": dict(STRAIGHTNESS_METHODS),
        }


def _profile(targets_mm: ArrayLike, deviation: ArrayLike) -> tuple[FloatArray, FloatArray]:
    x = np.asarray(targets_mm, dtype=float)
    y = np.asarray(deviation, dtype=float)
    keep = np.isfinite(x) & np.isfinite(y)
    x, y = x[keep], y[keep]
    if x.size < 2 or np.ptp(x) == 0:
        raise ValueError("straightness needs at least two readings at different targets")
    return x, y


def straightness(targets_mm: ArrayLike, deviation_um: ArrayLike) -> tuple[float, float]:
    """ISO 230-1 straightness: the range of the deviations about the least-squares reference
    line and about the end-point reference line (through the first and last points), in the
    deviations' unit. Missing readings (NaN) are left out. :func:`evaluate_straightness` adds
    the minimum zone.
    """
    result = evaluate_straightness(targets_mm, deviation_um)
    return result.least_squares, result.end_point


def evaluate_straightness(targets_mm: ArrayLike, deviation: ArrayLike) -> Straightness:
    """Straightness of a profile by the least-squares, minimum-zone and end-point reference
    lines (module notes). Missing readings (NaN) are left out.

    Raises
    ------
    ValueError
        With fewer than two readings at different targets.
    """
    x, y = _profile(targets_mm, deviation)
    # centred for conditioning: positions of hundreds of mm, deviations of µm
    centre = float(np.mean(x))
    slope, intercept = np.polyfit(x - centre, y, 1)
    about_ls = y - (slope * (x - centre) + intercept)
    order = np.argsort(x, kind="stable")
    x0, x1 = x[order[0]], x[order[-1]]
    y0, y1 = y[order[0]], y[order[-1]]
    about_ep = y - (y0 + (y1 - y0) * (x - x0) / (x1 - x0))
    zone, zone_slope, _ = minimum_zone(x, y)
    return Straightness(
        least_squares=float(np.ptp(about_ls)),
        minimum_zone=zone,
        end_point=float(np.ptp(about_ep)),
        slope_least_squares=float(slope),
        slope_minimum_zone=zone_slope,
    )


def minimum_zone(targets_mm: ArrayLike, deviation: ArrayLike) -> tuple[float, float, float]:
    """The minimum-zone straightness of a profile: (width, slope, intercept) of the narrowest
    band ``m·x + c ≤ y ≤ m·x + c + width`` that holds every point (module notes).

    Raises
    ------
    ValueError
        With fewer than two readings at different targets.
    """
    x, y = _profile(targets_mm, deviation)
    centre = float(np.mean(x))
    xc = x - centre
    candidates = np.unique(
        np.concatenate([_hull_slopes(xc, y, upper=True), _hull_slopes(xc, y, upper=False)])
    )

    def width(m: float) -> float:
        r = y - m * xc
        return float(np.max(r) - np.min(r))

    # f is convex over the sorted candidate slopes: bisect on its discrete slope
    low, high = 0, candidates.size - 1
    while low < high:
        mid = (low + high) // 2
        if width(candidates[mid]) <= width(candidates[mid + 1]):
            high = mid
        else:
            low = mid + 1
    m = float(candidates[low])
    r = y - m * xc
    return float(np.max(r) - np.min(r)), m, float(np.min(r)) - m * centre


def _hull_slopes(x: FloatArray, y: FloatArray, *, upper: bool) -> FloatArray:
    """Slopes of the edges of the upper (or lower) convex hull of the points (monotone chain)."""
    order = np.lexsort((y, x))
    xs, ys = x[order], y[order]
    sign = 1.0 if upper else -1.0
    hull: list[int] = []
    for i in range(xs.size):
        while len(hull) >= 2:
            a, b = hull[-2], hull[-1]
            cross = (xs[b] - xs[a]) * (ys[i] - ys[a]) - (ys[b] - ys[a]) * (xs[i] - xs[a])
            if sign * cross >= 0:  # b is not strictly outside the chord a–i
                hull.pop()
            else:
                break
        hull.append(i)
    index = np.asarray(hull)
    dx = np.diff(xs[index])
    keep = dx > 0
    return np.diff(ys[index])[keep] / dx[keep]
