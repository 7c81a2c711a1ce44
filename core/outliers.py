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
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from .measurement import LineData

ROBUST_SIGMA = 1.4826  # σ of a Gaussian from its median absolute deviation


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
    for direction in (1, -1):
        rows = np.flatnonzero(data.run_direction == direction)
        if rows.size < 3:
            continue
        block = x[rows]
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
            flags.append(OutlierFlag(
                line, run + 1, None, None, offset,
                f"run {run + 1} ({sense}) lies outside the run-to-run spread at {hits.size} "
                f"of {screened} targets: median offset {offset:+.3f} {symbol}, "
                f"{abs(offset) / sigma:.1f} σ (σ = {sigma:.3f} {symbol})",
                float(np.nanmedian(score[run])),
            ))
            continue
        for target in hits:
            r = float(residual[run, target])
            flags.append(OutlierFlag(
                line, run + 1, int(target) + 1, float(data.targets_mm[target]),
                float(x[run, target]),
                f"reading at {data.targets_mm[target]:g} mm, run {run + 1} ({sense}) is "
                f"{r:+.3f} {symbol} from the median of the other {sense} runs: "
                f"{abs(r) / sigma:.1f} σ of the run-to-run spread (σ = {sigma:.3f} {symbol})",
                float(score[run, target]),
            ))
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
