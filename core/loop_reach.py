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
    parameters (the widening, zero where nothing moves beyond)."""

    line: str
    moves: tuple[Move, ...]
    rests_on: tuple[str, ...]
    delta: FloatArray = field(repr=False)

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
        moves, rests = [], []
        for eid in ids:
            if not without.is_identified(eid):
                rests.append(eid)
                continue
            alone = rms_std(without, eid)
            if alone > RESTS_RATIO * with_line[eid]:
                rests.append(eid)
                continue
            move = _rms_move(whole, without, eid)
            allowed = np.sqrt(stated[eid] ** 2 + max(alone**2 - with_line[eid] ** 2, 0.0))
            if move > REACH_SIGMAS * allowed:
                moves.append(Move(eid, move, stated[eid]))
        moves.sort(key=lambda m: m.ratio, reverse=True)
        delta = np.zeros_like(whole.model.parameters)
        if moves:
            # an error the line alone determines is set anew (or left at zero) without it: its
            # move is no pull of the line's against the others'
            for eid in set(ids) - set(rests):
                at = whole.model.parameter_slices[eid]
                delta[at] = without.model.parameters[at] - whole.model.parameters[at]
        out[name] = Reach(name, tuple(moves), tuple(rests), delta)
    return out


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
