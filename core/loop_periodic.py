"""An error periodic in time along one machine direction (docs/method.md §3, "An error
periodic in time, found as such").

A hydraulic unit, a coolant chiller or an air conditioning that cycles moves the tool against
the workpiece with a period of minutes, whatever the axes' positions. No effect of the
catalogue is such an error: it is reported unexplained, never kept. But it changes every
line that reads its direction from run to run, and what it leaves in a line's per-target means
is a shape the line's timing gives it, which a set-up of that line or a shape in position fits
as well as anything (blind 83031: a 1.1 µm Y error of period 75 s kept as a 90 mm Abbe offset
of y_linear). Found, the lines it acts on are treated as lines that repeat far worse than
their peers (:func:`~volucal.core.loop_judge.judge`), and it is taken out of the readings
before the loop searches its effects (:func:`taken_out`): what it leaves in the lines it acts
on, no effect is then fitted to, and the 21 errors are fitted as the machine has them (blind
83035: a 3.4 µm Y error of period 237 s had moved a squareness by 21 µrad).

The search uses what the model leaves about each line's per-target, per-direction means, less
a smooth course in time of each line (an offset and a scale, linear and quadratic in the
line's time: a drift the model lacks, or a settling set-up): no effect in position or of the
approach direction, nor a slow drift, takes part in it. A sinusoid in the session's time along
direction d reads ``p_d (a cos ωt + b sin ωt)`` on a displacement reading whose beam or
deviation direction is p; its fit over every line that reads d (one amplitude and phase for
the session) is held to an F test against what is left, Bonferroni over the independent
periods searched and the three directions. A wandering laser or reflector, a beam re-zeroed,
also leave run-to-run changes, which line by line a sinusoid fits in part; they fit no one
sinusoid of the session, line after line: the session's sinusoid must take
:data:`COHERENT_SHARE` or more of what each line's own sinusoid (its own amplitude and phase, the
same period) takes together, and the lines it acts on must move in :data:`MOVING_APART`
directions or more.
"""

from __future__ import annotations

import weakref
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import sparse, special

from .identify import Identification
from .loop_records import FloatArray, IntArray
from .loop_tester import cell_key
from .machine import AXES
from .readings import Readings

#: The session's sinusoid must take this share of what each line's own sinusoid takes.
COHERENT_SHARE = 0.9
#: The shortest period searched, in median intervals between a line's readings.
SHORTEST_IN_INTERVALS = 3.0
#: The longest period searched, as a share of the median line's duration: longer, a period
#: is a course in time within a line, which the smooth course takes.
LONGEST_IN_LINES = 0.5
#: A line it acts on shows it with this energy (σ²) or more, what it changes from run to run.
SHOWN_SIGMA2 = 16.0
#: An error of the machine along one direction reads on every line that reads that direction,
#: whichever way it moves: the lines it acts on move in this many directions or more (a laser
#: that wanders on each line, three parallel lines of the twelve-line plan measured at other
#: times, can line up with one sinusoid by chance; blind 53079: 92 % at 287 s on y_lin_1–3, the
#: diagonals that read Y showing nothing of it).
MOVING_APART = 2
#: Periods of the coarse search (each line's own sinusoid) refined for the session's one.
REFINED = 3
#: Frequencies per chunk of the search (memory).
CHUNK = 256


@dataclass(frozen=True)
class PeriodicInTime:
    """An error periodic in time along one machine direction (:func:`periodic_in_time`)."""

    axis: str
    period_s: float
    #: its amplitude (µm) along the axis
    amplitude_um: float
    #: false-alarm level, Bonferroni over the periods and the directions searched
    p: float
    #: what the session's sinusoid takes of what each line's own sinusoid takes together
    coherent: float
    #: the periods searched (s)
    searched_s: tuple[float, float]
    #: what it takes of what the lines along its axis leave about their cells' means and
    #: smooth courses
    share: float
    #: per line it acts on (by index): what it changes there from run to run (RMS, µm)
    lines: dict[int, float]
    #: per line whose readings it changes (by index), over the line's runs or within them: what
    #: it adds there (RMS, µm); a period long beside a line's runs is mostly a course in time
    #: within each, which it changes from run to run little (blind 83141: 1.3 µm along Z,
    #: 584 s; z_linear_far, 0.89 µm RMS, not among the lines it changes from run to run)
    reads: dict[int, float]
    #: its phase (rad): along the axis it reads ``amplitude_um · cos(2π t / period_s − phase_rad)``
    #: at ``t`` seconds of the session's time
    phase_rad: float

    def to_json(self, names: list[str], taken: bool) -> dict[str, object]:
        """Its report entry (docs/report_json.md, ``unexplained[].periodic``), the lines
        named by ``names``; ``taken``: whether the loop took it out of the readings."""
        return {
            "axis": self.axis,
            "amplitude_um": self.amplitude_um,
            "period_s": self.period_s,
            "phase_rad": self.phase_rad,
            "form": "amplitude_um · cos(2π t / period_s − phase_rad), t in s from the "
            "session's first reading, along +axis",
            "log10_false_alarm": float(np.log10(max(self.p, 1e-300))),
            "searched_s": list(self.searched_s),
            "run_to_run_rms_um": {names[i]: self.lines[i] for i in sorted(self.lines)},
            "added_rms_um": {names[i]: self.reads[i] for i in sorted(self.reads)},
            "taken_out": taken,
        }

    def reading(self, readings: Readings) -> FloatArray:
        """What it adds to each of ``readings`` (µm; nothing to an angular reading)."""
        return _added(readings, self.axis, self.amplitude_um, self.period_s, self.phase_rad)


def _added(
    readings: Readings, axis: str, amplitude_um: float, period_s: float, phase_rad: float
) -> FloatArray:
    """What ``amplitude_um · cos(2π t / period_s − phase_rad)`` along ``axis`` adds to each of
    ``readings``, read through each displacement reading's direction (µm)."""
    course = amplitude_um * np.cos(2.0 * np.pi * readings.time_s / period_s - phase_rad)
    added = readings.projection[:, AXES.index(axis)] * course
    return np.where(readings.is_angular, 0.0, added)


@dataclass(frozen=True)
class _Line:
    """One line's readings along a direction, and the projector that takes out its cells'
    means and its smooth course in time."""

    rows: IntArray
    #: per reading, its cell (target and approach direction)
    cells: IntArray
    #: (cells × readings) the cells' means of a column of the line's readings
    means: sparse.csr_matrix
    #: orthonormal columns: the smooth course in time, its cells' means taken out
    course: FloatArray
    weight: float  # 1/σ² of its readings

    @property
    def free(self) -> int:
        """The readings' degrees of freedom beside the cells' means and the course."""
        return int(self.rows.size - self.means.shape[0] - self.course.shape[1])

    def project(self, values: FloatArray) -> FloatArray:
        """``values`` (rows × k) less their part in the line's cells and course (the course
        columns are centred in the cells, so the two parts are orthogonal)."""
        centred = _centred(self.means, self.cells, values)
        return centred - self.course @ (self.course.T @ centred)


def _centred(means: sparse.csr_matrix, cells: IntArray, values: FloatArray) -> FloatArray:
    """``values`` (rows × k) less their means over each cell."""
    return values - np.asarray(means @ values)[cells]


def _lines_along(readings: Readings, k: int, usable: NDArray[np.bool_]) -> list[_Line]:
    """The lines that read direction ``k`` (their usable displacement readings)."""
    out = []
    for index in range(len(readings.lines)):
        rows = np.flatnonzero((readings.line == index) & usable)
        if rows.size < 8 or abs(float(readings.projection[rows[0], k])) <= 1e-6:
            continue
        time = readings.time_s[rows]
        if np.ptp(time) <= 0:
            continue
        of_line = usable[readings.line == index]
        _, cells = np.unique(cell_key(readings, index)[of_line], return_inverse=True)
        counts = np.bincount(cells).astype(float)
        means = sparse.csr_matrix(
            (1.0 / counts[cells], (cells, np.arange(cells.size))), shape=(counts.size, cells.size)
        )
        t = (time - time.mean()) / np.ptp(time)
        s = readings.target_mm[rows]
        s = (s - s.mean()) / (np.ptp(s) or 1.0)
        course = _centred(means, cells, np.column_stack([t, t * t, t * s, t * t * s]))
        u, singular, _ = np.linalg.svd(course, full_matrices=False)
        if singular.size == 0 or singular.max() <= 0:
            continue
        sigma = float(np.median(readings.sigma[rows]))
        line = _Line(rows, cells, means, u[:, singular > 1e-9 * singular.max()], 1.0 / sigma**2)
        if line.free > 2:
            out.append(line)
    return out


def _sums(
    lines: list[_Line], readings: Readings, k: int, rest: list[FloatArray], frequencies: FloatArray
) -> FloatArray:
    """Per line and frequency, the weighted normal sums of the cosine and sine columns and of
    their products with the rest: (lines, 5, frequencies) as cc, ss, cs, cr, sr."""
    out = np.empty((len(lines), 5, frequencies.size))
    for j, line in enumerate(lines):
        phase = 2.0 * np.pi * np.outer(readings.time_s[line.rows], frequencies)
        p = readings.projection[line.rows, k][:, None]
        c = line.project(p * np.cos(phase))
        s = line.project(p * np.sin(phase))
        r = rest[j]
        out[j] = line.weight * np.stack(
            [np.sum(c * c, 0), np.sum(s * s, 0), np.sum(c * s, 0), r @ c, r @ s]
        )
    return out


def _gain(sums: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """From normal sums (…, 5, f): the sum of squares a sinusoid takes, and its a and b."""
    cc, ss, cs, cr, sr = (sums[..., i, :] for i in range(5))
    det = cc * ss - cs * cs
    ok = det > 1e-9 * np.maximum(cc * ss, 1e-300)
    safe = np.where(ok, det, 1.0)
    a = np.where(ok, (ss * cr - cs * sr) / safe, 0.0)
    b = np.where(ok, (cc * sr - cs * cr) / safe, 0.0)
    return a * cr + b * sr, a, b


#: per readings (by id) and false-alarm level: the readings, the error found in them, and
#: whether it was taken out of them (:func:`taken_out`)
_FOUND: dict[tuple[int, float], tuple[weakref.ref[Readings], PeriodicInTime | None, bool]] = {}


def periodic_in_time(identification: Identification, alpha: float) -> PeriodicInTime | None:
    """The strongest error periodic in time along one machine direction that ``identification``
    leaves, where its false-alarm level is below ``alpha`` and it is one sinusoid of the
    session (:data:`COHERENT_SHARE`); else None.

    Searched once per set of readings, on the first fit that asks (the loop's 21-error fit):
    what it is searched in, the readings about their cells' means less each line's smooth
    course in time, no effect of the catalogue changes (a shape in position, a reversal, a
    set-up's scale or lever arm are the same in every run; a drift is a smooth course)."""
    key = (id(identification.readings), alpha)
    known = _FOUND.get(key)
    if known is not None and known[0]() is identification.readings:
        return known[1]
    found = _search(identification, alpha)
    _remember(identification.readings, alpha, found)
    return found


def taken_out(readings: Readings, found: PeriodicInTime, alpha: float) -> Readings:
    """``readings`` less what ``found`` adds to them (:func:`less`), remembered as readings
    ``found`` was taken out of.

    The error is what the readings of the whole session leave (:func:`periodic_in_time` on
    them, at false-alarm level ``alpha``), and no effect of the catalogue is one: the loop
    searches and fits its effects on the readings without it. The search on these answers
    ``found``, the error they were taken out of: what its estimate misses stays on the lines
    it changes, which the judge treats as before (:func:`~volucal.core.loop_judge.judge`), and
    it is reported unexplained."""
    out = less(readings, found.reading(readings))
    _remember(out, alpha, found, taken=True)
    return out


def less(readings: Readings, added: FloatArray) -> Readings:
    """``readings`` less ``added`` (µm, per reading).

    Each line keeps the weight its logs give it, the spread it repeats to with the error in
    it: weighted by the spread without it (blind 83031: z_straight_y 0.94 µm with it, 0.39 µm
    without, against 0.44 µm of noise drawn), the lines the error changes weigh up to six
    times more, and what its estimate misses on them took a surface (blind 42119: EX over X×Z
    of order 8 kept, 6.0 % better held out, beside a 2.3 µm Z error of period 107 s)."""
    return replace(readings, value=readings.value - added)


def reported_taken_out(readings: Readings, entry: Mapping[str, Any]) -> Readings:
    """``readings`` less the error periodic in time of a report's entry
    (``unexplained[].periodic``, docs/report_json.md), as the loop that took it out fitted
    them: a refit of the loop's effects by hand is of the same readings."""
    added = _added(
        readings,
        str(entry["axis"]),
        float(entry["amplitude_um"]),
        float(entry["period_s"]),
        float(entry["phase_rad"]),
    )
    return less(readings, added)


def is_taken_out(readings: Readings, alpha: float) -> bool:
    """Whether ``readings`` are readings an error periodic in time was taken out of
    (:func:`taken_out`)."""
    known = _FOUND.get((id(readings), alpha))
    return known is not None and known[0]() is readings and known[2]


def _remember(
    readings: Readings, alpha: float, found: PeriodicInTime | None, taken: bool = False
) -> None:
    """What the search answers on ``readings``, while they are alive."""
    for stale in [k for k, (ref, *_) in _FOUND.items() if ref() is None]:
        del _FOUND[stale]
    _FOUND[(id(readings), alpha)] = (weakref.ref(readings), found, taken)


def _search(identification: Identification, alpha: float) -> PeriodicInTime | None:
    """The search of :func:`periodic_in_time`, without remembering it."""
    readings = identification.readings
    residual = identification.residual
    usable = ~readings.is_angular & np.isfinite(residual)
    spacing, duration = [], []
    for index in range(len(readings.lines)):
        time = np.sort(readings.time_s[readings.line == index])
        if time.size > 2:
            spacing.append(float(np.median(np.diff(time))))
            duration.append(float(time[-1] - time[0]))
    if not duration:
        return None
    shortest = SHORTEST_IN_INTERVALS * float(np.median(spacing))
    longest = LONGEST_IN_LINES * float(np.median(duration))
    session = float(np.ptp(readings.time_s))
    if not np.isfinite([shortest, longest, session]).all():
        return None
    if shortest <= 0 or longest <= 2 * shortest or session <= 0:
        return None
    coarse = np.arange(1.0 / longest, 1.0 / shortest, 1.0 / (4.0 * float(np.median(duration))))
    independent = len(AXES) * session * (1.0 / shortest - 1.0 / longest)
    best: PeriodicInTime | None = None
    best_f = 0.0
    for k, axis in enumerate(AXES):
        lines = _lines_along(readings, k, usable)
        if len(lines) < 2:
            continue
        rest = [line.project(residual[line.rows][:, None])[:, 0] for line in lines]
        chi0 = sum(line.weight * float(r @ r) for line, r in zip(lines, rest, strict=True))
        dof = sum(line.free for line in lines) - 2
        if dof <= 2 * len(lines):
            continue  # too few readings beside the cells' means to hold any period to
        own = np.concatenate(
            [
                _gain(_sums(lines, readings, k, rest, coarse[i : i + CHUNK]))[0].sum(0)
                for i in range(0, coarse.size, CHUNK)
            ]
        )
        step = coarse[1] - coarse[0] if coarse.size > 1 else coarse[0]
        for i in np.argsort(own)[::-1][:REFINED]:
            fine = np.arange(coarse[i] - step, coarse[i] + step, 1.0 / (4.0 * session))
            fine = fine[fine > 0]
            sums = _sums(lines, readings, k, rest, fine)
            together, a, b = _gain(sums.sum(0))
            j = int(np.argmax(together))
            f = (together[j] / 2.0) / max((chi0 - together[j]) / dof, 1e-300)
            if f <= best_f:
                continue
            p = float(special.fdtrc(2, dof, f)) * independent
            apart = float(_gain(sums[:, :, j : j + 1])[0].sum())
            coherent = float(together[j]) / apart if apart > 0 else 0.0
            if p >= alpha or coherent < COHERENT_SHARE:
                continue
            shown, reads = {}, {}
            for line in lines:
                phase = 2.0 * np.pi * fine[j] * readings.time_s[line.rows]
                p_k = readings.projection[line.rows, k]
                added = p_k * (a[j] * np.cos(phase) + b[j] * np.sin(phase))
                fitted = line.project(added[:, None])[:, 0]
                index = int(readings.line[line.rows[0]])
                if line.weight * float(fitted @ fitted) >= SHOWN_SIGMA2:
                    shown[index] = float(np.sqrt(np.mean(fitted**2)))
                if line.weight * float(added @ added) >= SHOWN_SIGMA2:
                    reads[index] = float(np.sqrt(np.mean(added**2)))
            travels = {tuple(np.round(readings.lines[i].spec.direction, 6)) for i in shown}
            if len(travels) < MOVING_APART:
                continue
            best_f = f
            best = PeriodicInTime(
                axis,
                1.0 / float(fine[j]),
                float(np.hypot(a[j], b[j])),
                p,
                coherent,
                (shortest, longest),
                float(together[j]) / chi0 if chi0 > 0 else 0.0,
                shown,
                reads,
                float(np.arctan2(b[j], a[j])),
            )
    return best
