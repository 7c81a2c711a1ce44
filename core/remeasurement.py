"""Before and after: the machine measured again once compensated, line by line beside the original.

An acceptance test ends with a re-measurement of the compensated machine along the same lines.
:func:`compare` pairs each line of the re-measurement with the original line measured at the
same place (same quantity, start and direction — the name need not be the same) and gives, per
pair, the ISO 230-2 values before and after (:func:`volucal.core.iso230_2.evaluate`) and, per
axis, the compensation rates of the measured lines (DESIGN.md, "Compensation rates"):

- RMS-based: 100·(1 − RMS after / RMS before) of the bidirectional mean deviation x̄ over the
  targets of every linear line along the axis;
- range-based: 100·(1 − range after / range before) of x̄ (the range of x̄ is ISO 230-2's M);
- the same ratio for the accuracy A.

Deviations are as the laser reads them (zeroed at the first target of each line). Only linear
lines along one machine axis enter the per-axis rates; every matched line has its ISO values.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .iso230_2 import Iso230Result, evaluate
from .machine import AXES
from .measurement import Line
from .tolerances import line_axis

#: Two lines are the same line when their starts agree within this (mm) and their directions
#: (and sensitive directions) within this cosine.
SAME_START_MM = 0.5
SAME_DIRECTION = 0.9999
KEYS = ("A", "E", "R", "B", "M")


@dataclass(frozen=True)
class LinePair:
    """One line measured before and after compensation."""

    name: str  # the original's name
    after_name: str
    quantity: str
    axis: str | None
    before: Iso230Result
    after: Iso230Result

    def value(self, key: str, which: str) -> float:
        result = self.before if which == "before" else self.after
        return float(getattr(result, f"{key}_um"))

    def improvement_percent(self, key: str) -> float:
        """100·(1 − after/before) of an ISO 230-2 value (NaN when undefined)."""
        return rate(self.value(key, "before"), self.value(key, "after"))


@dataclass(frozen=True)
class AxisRates:
    """Compensation rates of the measured lines of one axis (module notes), with the values
    they come from (µm)."""

    axis: str
    lines: tuple[str, ...]
    rms_before_um: float
    rms_after_um: float
    range_before_um: float
    range_after_um: float
    accuracy_before_um: float
    accuracy_after_um: float

    @property
    def rms_percent(self) -> float:
        return rate(self.rms_before_um, self.rms_after_um)

    @property
    def range_percent(self) -> float:
        return rate(self.range_before_um, self.range_after_um)

    @property
    def accuracy_percent(self) -> float:
        return rate(self.accuracy_before_um, self.accuracy_after_um)


@dataclass(frozen=True)
class Comparison:
    pairs: tuple[LinePair, ...]
    axes: tuple[AxisRates, ...]
    unmatched: tuple[str, ...]  # lines of the re-measurement with no original

    def pair(self, name: str) -> LinePair:
        for pair in self.pairs:
            if name in (pair.name, pair.after_name):
                return pair
        raise KeyError(name)


def rate(before: float, after: float) -> float:
    if not (math.isfinite(before) and math.isfinite(after)) or before <= 0:
        return math.nan
    return 100.0 * (1.0 - after / before)


def same_place(a: Line, b: Line) -> bool:
    """Same quantity, start, travel and sensitive direction."""
    sa, sb = a.spec, b.spec
    if sa.quantity != sb.quantity:
        return False
    if np.max(np.abs(np.subtract(sa.start_mm, sb.start_mm))) > SAME_START_MM:
        return False
    if float(np.dot(sa.direction, sb.direction)) < SAME_DIRECTION:
        return False
    if sa.sensitive is None or sb.sensitive is None:
        return sa.sensitive is None and sb.sensitive is None
    return float(np.dot(sa.sensitive, sb.sensitive)) >= SAME_DIRECTION


def match(before: Sequence[Line], after: Sequence[Line]) -> list[tuple[Line, Line]]:
    """Pairs (original, re-measured): the same name at the same place first, then the same
    place."""
    pairs: list[tuple[Line, Line]] = []
    free = list(before)
    for line in after:
        same_name = [b for b in free if b.name == line.name and same_place(b, line)]
        candidates = same_name or [b for b in free if same_place(b, line)]
        if candidates:
            pairs.append((candidates[0], line))
            free.remove(candidates[0])
    return pairs


def compare(before: Sequence[Line], after: Sequence[Line]) -> Comparison:
    """The re-measurement ``after`` beside the original ``before`` (module notes)."""
    pairs = []
    for original, again in match(before, after):
        pairs.append(
            LinePair(
                original.name,
                again.name,
                original.spec.quantity,
                line_axis(original),
                evaluate(original.data, original.spec.unit),
                evaluate(again.data, again.spec.unit),
            )
        )
    matched = {p.after_name for p in pairs}
    axes = []
    for axis in AXES:
        along = [p for p in pairs if p.axis == axis]
        if not along:
            continue
        mean_before = np.concatenate([p.before.mean for p in along])
        mean_after = np.concatenate([p.after.mean for p in along])
        axes.append(
            AxisRates(
                axis,
                tuple(p.name for p in along),
                _rms(mean_before),
                _rms(mean_after),
                max(p.before.M_um for p in along),
                max(p.after.M_um for p in along),
                max(p.before.A_um for p in along),
                max(p.after.A_um for p in along),
            )
        )
    unmatched = tuple(line.name for line in after if line.name not in matched)
    return Comparison(tuple(pairs), tuple(axes), unmatched)


def _rms(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(finite**2))) if finite.size else math.nan
