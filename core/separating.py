"""Which lines, not in the plan, would tell fits of the same measurement apart.

When the loop keeps a surface and surfaces of other places (another direction or pair of axes)
predict the held-out data as well, the plan cannot say which of them the machine has: every fit
reads the measured lines alike. Away from those lines they differ. This module evaluates each fit
(the 21 errors with the machine effects it kept, :class:`~volucal.core.loop_source.LoopSource`)
on the lines a laser interferometer could measure next — a positioning line along each axis the
plan moves, and straightness lines where the plan has straightness optics, at the low end, the
middle and the high end of the other two strokes, the optics where the plan's lines along that
axis have them — and picks the fewest of those lines on which every two fits read apart.

A line is compared after what its own set-up takes is removed: the least-squares constant and
slope of the difference of two fits' readings (the datum, and a cosine error's scale or a
straightness optic's alignment). Two fits read apart on a line when the peak of what is left is
at least :data:`APART_NOISES` times the noise of one reading of the measurement (the median of
the displacement readings' stated standard deviations, scaled by the fit's a-posteriori
factor). The lines are picked greedily, each the one that tells the most pairs still together
apart (then the one with the largest smallest difference among them).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .identify import Identification
from .loop_source import LoopSource
from .machine import AXES, AXIS_INDEX
from .measurement import LineSpec

FloatArray = NDArray[np.float64]

#: Points sampled along each candidate line.
SAMPLES = 41

#: Two fits read apart on a line when their difference (datum and scale removed) peaks at this
#: many times the noise of one reading.
APART_NOISES = 5.0


@dataclass(frozen=True)
class CandidateLine:
    """A line the plan could add: moving along ``along``, reading the displacement along
    ``reads`` (``along`` itself for a positioning line), the other two axes at ``at_mm``."""

    along: str
    reads: str
    at_mm: dict[str, float]

    @property
    def quantity(self) -> str:
        return "linear" if self.reads == self.along else "straightness"

    def words(self) -> str:
        at = ", ".join(f"{axis} = {value:.0f} mm" for axis, value in self.at_mm.items())
        if self.quantity == "linear":
            return f"a positioning line along {self.along} at {at}"
        return f"a straightness line along {self.along} reading {self.reads} at {at}"

    def to_report(self) -> dict[str, object]:
        return {
            "quantity": self.quantity,
            "along": self.along,
            "reads": self.reads,
            "at_mm": dict(self.at_mm),
        }


@dataclass(frozen=True)
class Separation:
    """The lines that would tell the fits apart, and how far apart they read there."""

    lines: tuple[CandidateLine, ...]
    #: over every two fits the lines tell apart, the largest difference on one of the lines
    #: (peak, datum and scale removed), at its smallest
    least_difference_um: float
    noise_um: float
    #: the pairs of fits (by their labels) that no candidate line tells apart
    together: tuple[tuple[str, str], ...]
    fits: int

    def sentence(self) -> str:
        """The advice in words, as a sentence of a warning."""
        ratio = self.least_difference_um / self.noise_um if self.noise_um > 0 else float("inf")
        if len(self.lines) == 1:
            words = self.lines[0].words()
            lines = f"{words[0].upper()}{words[1:]} would tell them apart: on it"
        else:
            listed = "; ".join(f"({i}) {line.words()}" for i, line in enumerate(self.lines, 1))
            lines = f"{len(self.lines)} lines would tell them apart, {listed}: on one of these"
        alike = "; ".join(f"{a} and {b}" for a, b in self.together)
        but = f", but {alike}, which read alike on every line tried" if alike else ""
        which = "the two" if self.fits == 2 else "every two"
        return (
            f"{lines} {which} read at least {self.least_difference_um:.3g} µm apart (peak, the "
            f"line's datum and scale removed), {ratio:.3g} times the noise of one reading{but}"
        )

    def to_report(self) -> dict[str, object]:
        return {
            "lines": [line.to_report() for line in self.lines],
            "least_difference_um": self.least_difference_um,
            "noise_um": self.noise_um,
            "not_told_apart": [list(pair) for pair in self.together],
        }


def separating_lines(fits: Sequence[Identification], labels: Sequence[str]) -> Separation | None:
    """The fewest candidate lines (module docstring) on which every two of ``fits`` (named by
    ``labels``) read apart, picked greedily; None for fewer than two fits or when no line tells
    any two apart."""
    if len(fits) < 2:
        return None
    lines, differences = _differences(fits)
    readings = fits[0].readings
    displacement = readings.sigma[~readings.is_angular]
    noise = float(np.median(displacement)) * float(fits[0].sigma_scale)
    apart = differences >= APART_NOISES * noise  # (lines, pairs)
    pairs = [(i, j) for i in range(len(fits)) for j in range(i + 1, len(fits))]
    left = np.ones(len(pairs), dtype=bool)
    chosen: list[int] = []
    while left.any():
        told = (apart & left).sum(axis=1)
        if told.max() == 0:
            break
        least = np.where(apart & left, differences, np.inf).min(axis=1)
        best = int(np.lexsort((-least, -told))[0])
        chosen.append(best)
        left &= ~apart[best]
    if not chosen:
        return None
    covered = ~left
    reach = differences[chosen].max(axis=0)
    return Separation(
        tuple(lines[i] for i in chosen),
        float(reach[covered].min()),
        noise,
        tuple((labels[i], labels[j]) for (i, j), still in zip(pairs, left, strict=True) if still),
        len(fits),
    )


def _differences(fits: Sequence[Identification]) -> tuple[list[CandidateLine], FloatArray]:
    """The candidate lines and, per line and pair of fits, the peak of the difference of the
    two fits' readings there, datum and scale removed (µm)."""
    readings = fits[0].readings
    specs = [line.spec for line in readings.lines]
    machine = fits[0].model.machine
    sources = [LoopSource(fit) for fit in fits]
    straightness = any(spec.quantity == "straightness" for spec in specs)
    n = len(fits)
    lines: list[CandidateLine] = []
    rows: list[list[float]] = []
    for along in AXES:
        k = AXIS_INDEX[along]
        if not any(abs(spec.direction[k]) > 1e-6 for spec in specs):
            continue  # the plan never moves this axis
        travel = np.linspace(*machine.stroke(along), SAMPLES)
        others = [axis for axis in AXES if axis != along]
        reflector = _reflector(specs, k)
        for a in _three(machine.stroke(others[0])):
            for b in _three(machine.stroke(others[1])):
                q = np.zeros((SAMPLES, 3))
                q[:, k] = travel
                q[:, AXIS_INDEX[others[0]]] = a
                q[:, AXIS_INDEX[others[1]]] = b
                errors = [source.error_um(q, None, reflector) for source in sources]
                for reads in [along, *others] if straightness else [along]:
                    j = AXIS_INDEX[reads]
                    lines.append(CandidateLine(along, reads, {others[0]: a, others[1]: b}))
                    rows.append(
                        [
                            _peak(errors[i][:, j] - errors[m][:, j], travel)
                            for i in range(n)
                            for m in range(i + 1, n)
                        ]
                    )
    return lines, np.array(rows).reshape(len(lines), n * (n - 1) // 2)


def _three(stroke: tuple[float, float]) -> tuple[float, float, float]:
    low, high = stroke
    return (float(low), 0.5 * (low + high), float(high))


def _reflector(specs: Sequence[LineSpec], k: int) -> FloatArray:
    """The optics offset of the plan's first line along axis ``k`` (else of its first line):
    where a new line's optics would sit."""
    along = [spec for spec in specs if abs(spec.direction[k]) > 1 - 1e-6]
    return np.asarray((along or list(specs))[0].reflector_mm, dtype=float)


def _peak(difference: FloatArray, travel: FloatArray) -> float:
    """The peak of a difference of readings along a line once what the line's set-up takes is
    removed: its least-squares constant and slope."""
    design = np.stack([np.ones_like(travel), travel - travel.mean()], axis=1)
    coefficients, *_ = np.linalg.lstsq(design, difference, rcond=None)
    return float(np.max(np.abs(difference - design @ coefficients)))
