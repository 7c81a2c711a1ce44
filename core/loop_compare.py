"""Refits of the closed loop and how two fits predict the held-out readings: the readings both
predict, their cross-validated RMS, and the rows a step records."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from .effects import CrossAxis, Cyclic, Effect, Reversal
from .errors import ErrorModel
from .identify import (
    BLOCK_MM,
    CrossValidation,
    Identification,
    IdentificationError,
    cross_validate,
    identify,
    residual_rms,
)
from .loop_periodic import PeriodicInTime, less
from .loop_records import ESTIMATED_AGAIN, Finding, IntArray, LoopOptions, Step, group_rms
from .loop_tester import rms_over
from .machine import Machine
from .measurement import Measurement
from .progress import CancelToken, check
from .readings import Readings, flatten

#: A held-out block whose cross-validated mean square exceeds this many times what the fit leaves
#: there in-sample (or the median block's, if more) is an extrapolation the plan leaves
#: ill-posed, not a prediction: a twelve-line plan holding out a line's end leaves a spline there
#: almost unseen. Structure the model lacks is as large in-sample as held out, and stays.
WILD_BLOCK_FACTOR = 25.0


def predicted_rows(
    reference: CrossValidation, fit: Identification
) -> tuple[NDArray[np.bool_], int]:
    """Per reading, whether its cross-validated residual is a prediction, and how many held-out
    blocks (or lines) are not. Held out in blocks, a line's end targets never are. A held-out
    block or line whose cross-validated mean square exceeds :data:`WILD_BLOCK_FACTOR` times what
    the fit ``fit`` leaves there in-sample (or the median block's or line's of its quantity, if
    more) is a wild extrapolation (judged on ``fit`` and its cross-validation ``reference``).
    For a linear fit the held-out residual of a line is (I − H)⁻¹ times its in-sample residual,
    H the line's leverage: a ratio of 25 in mean square is a leverage of 0.8 or more, a line
    the rest of the plan barely determines (an angular line that alone reads its error, or the
    session's first line once a drift in time is in the model: the later lines cannot tell the
    drift from the positioning error without it)."""
    out = np.isfinite(reference.residual)
    readings = fit.readings
    blocks = reference.method.startswith("held-out blocks")
    wild = 0
    angular = readings.is_angular
    for quantity in (~angular, angular):
        rows = np.flatnonzero(quantity & out)
        if rows.size == 0:
            continue
        _, group = np.unique(held_out_group(readings, rows, blocks), return_inverse=True)
        count = np.bincount(group).astype(float)
        held = np.bincount(group, reference.residual[rows] ** 2) / count
        in_sample = np.bincount(group, fit.residual[rows] ** 2) / count
        tame = held <= WILD_BLOCK_FACTOR * np.maximum(in_sample, float(np.median(in_sample)))
        out[rows] = tame[group]
        wild += int(np.count_nonzero(~tame))
    return out, wild


def cv_compared(
    reference: CrossValidation,
    other: CrossValidation,
    fit: Identification,
    um: bool = False,
    other_fit: Identification | None = None,
) -> tuple[float, float, int]:
    """The cross-validated error of two fits over the same predicted readings
    (:func:`predicted_rows`), and how many held-out blocks or lines were left out as wild. Each
    block or line is judged on both fits (``fit`` that of ``reference``, ``other_fit`` that of
    ``other``): one that either model needs to fix its own parameters, so that held out it is
    barely determined, is no prediction of either (a bump whose only sight on a line is the block
    held out, the session's first line once a drift in time is in the model). With ``um``, over
    the displacement readings alone (µm, as report.json states it)."""
    readings = fit.readings
    rows, wild = rows_compared(reference, other, fit, other_fit)
    if um:
        rows &= ~readings.is_angular
    return (
        rms_over(reference.residual, readings, rows),
        rms_over(other.residual, readings, rows),
        wild,
    )


def rows_compared(
    reference: CrossValidation,
    other: CrossValidation,
    fit: Identification,
    other_fit: Identification | None,
) -> tuple[NDArray[np.bool_], int]:
    """The readings :func:`cv_compared` compares two fits over, and how many held-out blocks or
    lines it leaves out.

    A block or line wild under one fit alone, whose held-out error there is still below the
    other's, stays: the fit that goes wild is the one the exclusion is fair to, and it predicts
    that block better than the other even barely determined (blind 24020: held out, the
    session's first line, x_linear, is predicted to 0.67 µm RMS with a drift of X in the model
    and to 2.05 µm without it; left out, the drift earned 1.2 % and was refused)."""
    rows, wild = predicted_rows(reference, fit)
    if other_fit is None:
        return rows, wild
    theirs, _ = predicted_rows(other, other_fit)
    both = np.flatnonzero(np.isfinite(reference.residual) & np.isfinite(other.residual))
    blocks = reference.method.startswith("held-out blocks")
    _, group = np.unique(held_out_group(fit.readings, both, blocks), return_inverse=True)
    ours_tame = np.bincount(group, rows[both]) > 0
    theirs_tame = np.bincount(group, theirs[both]) > 0
    ours_ms = np.bincount(group, reference.residual[both] ** 2)
    theirs_ms = np.bincount(group, other.residual[both] ** 2)
    # wild under one fit alone: compared when that fit's held-out error is still the lower
    wins = np.where(ours_tame, theirs_ms < ours_ms, ours_ms < theirs_ms)
    compared = (ours_tame & theirs_tame) | ((ours_tame != theirs_tame) & wins)
    out = np.zeros_like(rows)
    out[both] = compared[group]
    return out, int(np.count_nonzero(~compared))


def held_out_group(readings: Readings, rows: NDArray[np.generic], blocks: bool) -> IntArray:
    """For the readings ``rows`` (a mask or indices), a key of what cross-validation held out
    together: the line, and with held-out blocks the block of targets."""
    key = readings.line[rows].astype(np.int64) * 1_000_000
    if blocks:
        key = key + np.floor(readings.target_mm[rows] / BLOCK_MM).astype(np.int64)
    return key


@dataclass(frozen=True, eq=False)
class Trial:
    finding: Finding
    refit: Identification
    cv: CrossValidation
    ok: bool
    reason: str
    parameters: dict[str, object]
    uncorroborated: bool = False  # refused only because one line alone shows it
    #: its cross-validated error over the readings the comparison with the current model runs
    #: on (:func:`cv_compared`, wild blocks left out); among the candidates of a step, over the
    #: readings every one of them predicts (:func:`on_common_rows`)
    score: float = float("nan")
    #: the rule that refused it (:data:`VERDICTS`), "kept" when it passed them all
    verdict: str = "kept"
    #: the readings its comparison with the current model ran on
    rows: NDArray[np.bool_] | None = None
    #: for a surface refused as the disagreement of lines it leaves systematic
    #: (:func:`gained_through_lines_it_leaves`): those lines
    left: frozenset[str] = frozenset()
    #: for a machine effect refused as one line alone shows it: that line
    alone_on: str = ""
    #: the share by which it bettered the held-out error of the model it was tried against, as
    #: the margin judges it (:func:`~volucal.core.loop_judge._margin_gain`), and where: "" over
    #: the plan, else the readings it acts on
    improvement: float = float("nan")
    improvement_over: str = ""

    def ties(self, other: Trial, tie: float) -> bool:
        """Whether it predicts the held-out data as well as ``other``: its score within ``tie``
        (a share) above ``other``'s."""
        return self.score <= other.score * (1.0 + tie)


class Fitter:
    """Refits of one measurement with a set of effects, from the current model.

    ``readings`` are the measurement's, less the error periodic in time ``periodic`` where
    one was taken out of them (:func:`~volucal.core.loop_periodic.taken_out`): the readings
    of fewer lines are taken the same way."""

    def __init__(
        self,
        measurement: Measurement,
        readings: Readings,
        options: LoopOptions,
        redundant: Sequence[str],
        cancel: CancelToken | None,
        periodic: PeriodicInTime | None = None,
    ) -> None:
        self.measurement = measurement
        self.readings = readings
        self.periodic = periodic
        self.options = replace(options.identify, redundancy=False)
        self.iterations = options.identify.max_iterations
        self.redundant = redundant
        self.cancel = cancel
        self.loop_options = options
        self._reduced: dict[frozenset[str], Fitter | None] = {}
        self._last: tuple[tuple[Effect, ...], tuple[Identification, CrossValidation]] | None = None
        self._moved: dict[Effect, Effect] = {}

    def __call__(
        self, effects: Sequence[Effect], initial: ErrorModel
    ) -> tuple[Identification, CrossValidation]:
        refit = self.identify(effects, initial)
        return refit, cross_validate(refit.system, self.readings, self.redundant)

    def converged(
        self, effects: Sequence[Effect], initial: ErrorModel
    ) -> tuple[Identification, CrossValidation]:
        """The refit iterated until the 21 errors settle, with its cross-validation.

        A refit of the loop is one linear solve from the model it starts from, and an Abbe
        offset acts through the angles of that model, identified while the offset was missing:
        its lever arm then takes what those angles lack (blind 38111: (3.5, −3.5, 61.7) mm
        fitted against the injected (0, 0, 56.4) mm, 12 of its standard uncertainties out).
        Iterated, offset and angles agree ((1.0, −1.0, 57.0) ± (0.7, 0.7, 0.4) mm)."""
        refit = self.identify(effects, initial, self.iterations)
        return refit, cross_validate(refit.system, self.readings, self.redundant)

    def identify(
        self, effects: Sequence[Effect], initial: ErrorModel, iterations: int = 1
    ) -> Identification:
        """The refit alone, without cross-validation: ``iterations`` linear solves at most."""
        check(self.cancel)
        return identify(
            self.measurement,
            replace(self.options, max_iterations=iterations),
            effects=effects,  # type: ignore[arg-type]
            readings=self.readings,
            cancel=self.cancel,
            initial=initial,
        )

    def once(
        self, effects: Sequence[Effect], initial: ErrorModel
    ) -> tuple[Identification, CrossValidation]:
        """:meth:`__call__`, the last one kept for the same effect objects: the current model
        of a step is refitted once whatever number of candidates asks for it."""
        key = tuple(effects)
        if self._last is None or self._last[0] != key:
            self._last = (key, self(effects, initial))
        return self._last[1]

    def without(self, names: frozenset[str]) -> Fitter | None:
        """A fitter of the same session without the lines ``names`` (time still counted from
        the whole session's first reading); None where what is left cannot be cross-validated
        or identified."""
        if names not in self._reduced:
            self._reduced[names] = self._without(names)
        return self._reduced[names]

    def _without(self, names: frozenset[str]) -> Fitter | None:
        whole = self.measurement
        left = Measurement(
            whole.machine,
            tuple(line for line in whole.lines if line.name not in names),
            whole.uncertainty,
        )
        readings = flatten(left)
        shift = left.session_start - whole.session_start
        readings = replace(
            readings,
            time_s=readings.time_s + shift,
            material_ends_s=readings.material_ends_s + shift,
        )
        if self.periodic is not None:  # not remembered: its lines are the whole session's
            readings = less(readings, self.periodic.reading(readings))
        try:
            base = identify(left, self.loop_options.identify, readings=readings, cancel=self.cancel)
        except IdentificationError:
            return None
        redundant = base.identifiability.redundant_lines
        if can_cross_validate(readings, cross_validate(base.system, readings, redundant)):
            return None
        return Fitter(left, readings, self.loop_options, redundant, self.cancel, self.periodic)

    def moved(self, effects: Sequence[Effect]) -> list[Effect]:
        """``effects`` of the whole session for this fitter's lines: a set-up effect follows its
        line to its index here and is left out with it."""
        index = {line.name: i for i, line in enumerate(self.measurement.lines)}
        out: list[Effect] = []
        for effect in effects:
            name = getattr(effect, "line_name", None)
            if effect.line_index is None:
                out.append(effect)
            elif name in index:  # the same object each time: :meth:`once` knows it again
                out.append(self._moved.setdefault(effect, replace(effect, line=index[name])))  # type: ignore[call-arg]
        return out


def can_cross_validate(readings: Readings, cv: CrossValidation) -> str | None:
    """Why the plan is too small to cross-validate, or None."""
    if cv.method == "leave-one-line-out":
        return None if len(readings.lines) >= 3 else "fewer than three lines"
    blocks = [len(np.unique(np.floor(line.data.targets_mm / BLOCK_MM))) for line in readings.lines]
    if max(blocks, default=0) < 3:
        return (
            f"every line is shorter than three blocks of {BLOCK_MM:g} mm of targets and not "
            "every line is redundant"
        )
    return None


def later_step(
    number: int,
    effect: Effect,
    fitted: Identification,
    trial_fit: tuple[Identification, CrossValidation],
    kept: bool,
    reason: str,
    before: tuple[Identification, CrossValidation],
    stage: str,
) -> Step:
    """A step of the refine, backward or audit stage: ``effect`` with its parameters as fitted in
    ``fitted``, the fit tried (``trial_fit``) and the model it was compared with (``before``)."""
    index = list(fitted.effects).index(effect)
    parameters = effect.parameters(
        fitted.effect_parameters[index], fitted.effect_covariances[index]
    )
    where, verdict = {
        "refine": ("estimated again", ESTIMATED_AGAIN),
        "backward": ("backward pass", "taken out"),
        "audit": ("final audit", "taken out"),
    }[stage]
    finding = Finding(effect, float("nan"), 0.0, 0, 0.0, 0.0, where)
    trial = Trial(finding, *trial_fit, kept, reason, parameters)
    return step_record(number, trial, kept, reason, *before, stage=stage, verdict=verdict)


def step_record(
    number: int,
    trial: Trial,
    kept: bool,
    reason: str,
    current: Identification,
    cv: CrossValidation,
    stage: str = "forward",
    verdict: str = "kept",
) -> Step:
    return Step(
        number,
        trial.finding,
        kept,
        reason,
        residual_rms(current)[0],
        residual_rms(trial.refit)[0],
        *cv_compared(cv, trial.cv, current, um=True, other_fit=trial.refit)[:2],
        trial.parameters,
        group_rms(current),
        group_rms(trial.refit),
        stage,
        verdict,
        trial.alone_on,
        trial.improvement,
        trial.improvement_over,
    )


def kept_with(kept: list[Effect], effect: Effect, machine: Machine) -> list[Effect]:
    """Kept effects plus a new one. The new one replaces a kept effect that describes the same
    structure: a position-dependent reversal the constant one, a cross-axis surface of another
    order or family the one kept for the same direction and axes, and a cycle the one kept on the
    same axis whose frequency is within the resolution of the stroke (1/stroke): two such cycles
    cannot be told apart, so the new period is a refinement of the old."""

    def replaced(e: Effect) -> bool:
        if isinstance(effect, Reversal) and isinstance(e, Reversal):
            return e.axis == effect.axis
        if isinstance(effect, CrossAxis) and isinstance(e, CrossAxis):
            return e.direction == effect.direction and {e.along, e.across} == {
                effect.along,
                effect.across,
            }
        if isinstance(effect, Cyclic) and isinstance(e, Cyclic) and e.axis == effect.axis:
            low, high = machine.stroke(effect.axis)
            return abs(1.0 / e.period_mm - 1.0 / effect.period_mm) < 1.0 / (high - low)
        return False

    return [e for e in kept if not replaced(e)] + [effect]
