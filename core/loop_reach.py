"""What the structure nothing explains may have moved in the 21 errors.

The loop leaves the 21 errors as they were without an effect it cannot attribute: it never
force-fits. The lines it reports unexplained were fitted all the same, and what of their structure
the errors took up is not in the residual, so their stated uncertainties (made from the residual's
size) do not cover it. Each such line is left out of the final fit in turn (its readings' weight
taken to nothing; the effects, the basis and every other line as they are) and the errors fitted
without it are compared with those fitted with it:

- an error that moves by more than :data:`REACH_SIGMAS` times what its stated standard
  uncertainty and the line's own information allow is pulled by that line where the other lines do
  not follow: the move is named with the line, and the errors' covariance is widened by it in full
  (:func:`~volucal.core.loop_end.with_shape_doubt`), as the loop widens it for what a basis
  misses;
- an error the plan determines through that line alone (no longer identified without it, or its
  standard uncertainty :data:`RESTS_RATIO` times wider) cannot be checked against another line:
  it is named, nothing is added.

Structure spread over many lines can pull an error a little through each of them, and by much
through all: no line alone moves it beyond, and the moves add up. Over the unexplained lines, the
root sum of squares of an error's moves is set against :data:`REACH_SIGMAS` times
√(stated² + the sum of what each line's own information adds): the leave-one-line-out (jackknife)
spread of the error over the lines nothing explains. Beyond it, the error is named as moved by
those lines together, and its covariance widened by each of their moves in full
(:func:`moved_together`); with one line it is the rule above.

An outside effect that every line carries alike (a laser that wanders on every line) moves no
error when one line is left out: what the lines agree on cannot be told from the machine.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from .errors import SQUARENESS_IDS
from .identify import Identification
from .loop_records import FloatArray, Move, Unexplained
from .readings import Readings

#: An error moves beyond its stated uncertainty when leaving a line out moves it by more than this
#: many times √(stated² + what the line's own information adds to its variance).
REACH_SIGMAS = 3.0
#: An error rests on a line when, without it, its standard uncertainty is this many times wider.
RESTS_RATIO = 10.0
#: Left out: the line's readings keep their place, with their standard deviations this many times
#: wider (a weight of 1e-8: what they pull is below the fit's digits, the indices of the lines and
#: of their set-up effects unchanged).
LEFT_OUT_SIGMA = 1e4


@dataclass(frozen=True, eq=False)
class Reach:
    """What leaving one line out does to the errors: the moves beyond their stated uncertainty
    (largest ratio first), the errors that rest on the line alone, and the move of the model's
    parameters."""

    line: str
    moves: tuple[Move, ...]
    rests_on: tuple[str, ...]
    #: the parameters without the line minus with it, for the errors that do not rest on it:
    #: where an error moves beyond, it widens the errors' covariance in full
    change: FloatArray = field(repr=False)
    #: per error that does not rest on the line: how far it moves (as :attr:`Move.move`) and what
    #: the line's own information adds to its variance
    shifts: dict[str, tuple[float, float]] = field(default_factory=dict, repr=False)

    def sentence(self) -> str:
        """What the unexplained entry of the line adds to its description ("" for nothing)."""
        out = []
        if self.moves:
            out.append(
                "left out, it moves "
                + _listed([m.text() for m in self.moves])
                + ": the stated uncertainties include these moves"
            )
        if self.rests_on:
            verb = "rests" if len(self.rests_on) == 1 else "rest"
            out.append(
                f"{_listed(list(self.rests_on))} {verb} on this line alone, which no other line "
                "checks"
            )
        return "; ".join(out)


def _listed(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def reach_of_lines(
    final: Identification,
    lines: Sequence[str],
    refit: Callable[[Readings], Identification],
) -> dict[str, Reach]:
    """Per line of ``lines`` (names), what leaving it out of ``final`` moves; ``refit`` fits the
    final model's effects and basis to readings (``final.readings`` with other weights). The moves
    are measured between two refits (with the line and without it), so that they hold nothing of
    the loop's own route; the stated uncertainty is ``final``'s, with every doubt the loop
    added."""
    if not lines:
        return {}
    readings = final.readings
    names = [line.name for line in readings.lines]
    whole = refit(readings)
    ids = [eid for eid in final.identifiability.identified_ids if whole.is_identified(eid)]
    stated = {eid: rms_std(final, eid) for eid in ids}
    with_line = {eid: rms_std(whole, eid) for eid in ids}
    out = {}
    for name in dict.fromkeys(lines):
        index = names.index(name)
        sigma = np.where(readings.line == index, readings.sigma * LEFT_OUT_SIGMA, readings.sigma)
        without = refit(replace(readings, sigma=sigma))
        moves, rests, shifts = [], [], {}
        for eid in ids:
            if not without.is_identified(eid):
                rests.append(eid)
                continue
            alone = rms_std(without, eid)
            if alone > RESTS_RATIO * with_line[eid]:
                rests.append(eid)
                continue
            move = _rms_move(whole, without, eid)
            added = max(alone**2 - with_line[eid] ** 2, 0.0)
            shifts[eid] = (move, added)
            if move > REACH_SIGMAS * np.sqrt(stated[eid] ** 2 + added):
                moves.append(Move(eid, move, stated[eid]))
        moves.sort(key=lambda m: m.ratio, reverse=True)
        # an error the line alone determines is set anew (or left at zero) without it: its move
        # is no pull of the line's against the others'
        change = np.zeros_like(whole.model.parameters)
        for eid in shifts:
            at = whole.model.parameter_slices[eid]
            change[at] = without.model.parameters[at] - whole.model.parameters[at]
        out[name] = Reach(name, tuple(moves), tuple(rests), change, shifts)
    return out


@dataclass(frozen=True, eq=False)
class Together:
    """The errors the unexplained lines move beyond their stated uncertainty together and none
    alone (:attr:`Move.move` the root sum of squares of the lines' moves), the lines, and the
    moves that widen the errors' covariance (one per line, on those errors' parameters)."""

    lines: tuple[str, ...]
    moves: tuple[Move, ...]
    deltas: tuple[FloatArray, ...] = field(repr=False)

    def warning(self) -> str:
        """The sentence report.json's warnings and the console give."""
        them, its = ("it", "its") if len(self.moves) == 1 else ("them", "their")
        return (
            f"left out one at a time, the {len(self.lines)} lines whose systematic residual "
            f"nothing explains move {_listed([m.text() for m in self.moves])} together, as the "
            f"root sum of squares of their moves, though none alone moves {them} beyond {its} "
            f"stated uncertainty: their structure pulls {them} a little through each line; the "
            "stated uncertainties include these moves"
        )

    def to_json(self) -> dict[str, object]:
        return {"lines": list(self.lines), "moves": [m.to_json() for m in self.moves]}


def moved_together(final: Identification, reach: dict[str, Reach]) -> Together | None:
    """Over two or more lines left out (:func:`reach_of_lines`), the errors no line moves beyond
    and none rests on, whose moves' root sum of squares is beyond :data:`REACH_SIGMAS` times
    √(stated² + what the lines' own information adds, summed): what a jackknife over those lines
    reads. None when there is none."""
    if len(reach) < 2:
        return None
    named = {m.error_id for r in reach.values() for m in r.moves}
    named |= {eid for r in reach.values() for eid in r.rests_on}
    candidates = set().union(*(r.shifts for r in reach.values())) - named
    moves = []
    for eid in sorted(candidates):
        shifts = [r.shifts[eid] for r in reach.values()]
        stated = rms_std(final, eid)
        spread = float(np.sqrt(sum(move**2 for move, _ in shifts)))
        if spread > REACH_SIGMAS * np.sqrt(stated**2 + sum(added for _, added in shifts)):
            moves.append(Move(eid, spread, stated))
    if not moves:
        return None
    moves.sort(key=lambda m: m.ratio, reverse=True)
    deltas = []
    for r in reach.values():
        if r.moves:
            continue  # its whole move widens the covariance already
        delta = np.zeros_like(r.change)
        for move in moves:
            at = final.model.parameter_slices[move.error_id]
            delta[at] = r.change[at]
        deltas.append(delta)
    return Together(tuple(reach), tuple(moves), tuple(deltas))


def with_reach(unexplained: Sequence[Unexplained], reach: dict[str, Reach]) -> list[Unexplained]:
    """The unexplained entries with what leaving their line out moves, said once per line (on its
    first entry)."""
    out, said = [], set()
    for item in unexplained:
        found = reach.get(item.line) if item.line else None
        if found is None or item.line in said or not (found.moves or found.rests_on):
            out.append(item)
            continue
        said.add(item.line)
        description = item.description.rstrip(". ") + "; " + found.sentence()
        out.append(
            replace(item, description=description, moves=found.moves, rests_on=found.rests_on)
        )
    return out


def rms_std(fit: Identification, eid: str) -> float:
    """The error's standard uncertainty, RMS over its stroke for a function."""
    _, _, std = fit.band(eid)
    return float(np.sqrt(np.mean(std**2)))


def _rms_move(a: Identification, b: Identification, eid: str) -> float:
    """How far the error is from one fit to the other: RMS over its stroke for a function."""
    if eid in SQUARENESS_IDS:
        return abs(float(b.model.squareness_urad[eid] - a.model.squareness_urad[eid]))
    q, value, _ = a.band(eid)
    _, other, _ = b.band(eid, q)
    return float(np.sqrt(np.mean((other - value) ** 2)))
