"""The closed loop: find structure in the residual, trace it to an effect, add it, refit, report.

1. Identify the 21 errors; the residual is measured − model, per reading.
2. Diagnose: every effect of the catalogue (core/effects.py) that the plan could reveal is tested
   against the residual with an F-test of its columns *after* projecting out what the current model
   can already absorb (so an effect the model mimics scores nothing). Searched quantities (the
   period of a cyclic error, the place of a local defect, the time constant of a drift) are
   estimated continuously and their false-alarm level corrected for the number of independent
   trials (Bonferroni).
3. Trace: each finding names the effect, the axis and its evidence (F, false-alarm level,
   magnitude, where it shows most).
4. Add: the strongest findings are refitted. One is kept only when
   - its parameters are physically plausible for the set-up (:class:`~volucal.core.effects.
     Plausibility`): an Abbe offset a third of a metre off explains nothing;
   - the cross-validated error (leave-one-line-out when every line is redundant, held-out blocks
     of targets otherwise) improves by at least ``margin``;
   - the held-out data confirm what the fit gained: the drop of the cross-validated mean square
     is at least ``generalisation`` of the drop of the fitted mean square. A real effect predicts
     lines it was not fitted to; a flexible term bent towards structure it does not describe
     (a time-varying scale read as a cross-axis coupling) removes much from the fit and little
     from held-out lines.
   Every candidate is scored again at every step against the current model: a real effect that
   ranked second is tried again once the first is in the model. A candidate refused before is
   refitted again only once its evidence has grown (``retry_factor``), or, when it was refused
   for a size that varied between runs or along a line, or is a set-up error refused as
   implausible or short of the margin, once another effect has been kept: what the model lacked
   spoiled that size, or the held-out lines, as much as the candidate's own misfit could. In
   each refit of a candidate beside a kept drift in time, the drift's τ is searched again over
   its whole range with the candidate in the model.
5. Refine and backward pass: after each keep, every kept cycle's period and drift's τ is
   estimated again with the others in the model (kept when the cross-validated error drops). At
   the end each kept effect is removed in turn; an effect whose removal no longer costs
   ``margin`` of the cross-validated error is dropped (it was superseded by a later one).
6. Report before/after, the effects kept and refused with the reason, and what is still
   unexplained — located, sized and decomposed into what it follows (position, approach
   direction, time), never force-fitted; with the errors each unexplained line moves beyond
   their stated uncertainty when it is left out (their uncertainty widened by the move), and
   those it alone determines.

Stopping rule: the loop stops when no candidate reaches the family-wise false-alarm level
``alpha`` (Bonferroni over every trial of a step), or when every proposal of a step is refused.
Its false-alarm rate on clean machines is measured by ``benchmarks/bench_loop_suite.py``.

Residuals along a line are autocorrelated, so the F-test only proposes; cross-validation decides.

The loop's parts, each in its own module (this one runs them and keeps the public names):

- ``loop_records``: what the loop is asked (:class:`LoopOptions`) and what it records
  (:class:`Finding`, :class:`Step`, :class:`SpacingChoice`, :class:`Unexplained`);
- ``loop_tester``: the F tests of a candidate's columns against what the model leaves;
- ``loop_search``: the diagnosis, with the searched periods, time constants and bump places;
- ``loop_compare``: refits and how two fits predict the held-out readings;
- ``loop_courses``: the scales of lines that follow a course in time;
- ``loop_unexplained``: what nothing explains, located and decomposed;
- ``loop_reach``: what the lines nothing explains moved in the 21 errors;
- ``loop_judge``: the rules a refitted candidate must pass to be kept;
- ``loop_state``, ``loop_choice``, ``loop_forward``: the forward steps and how a step chooses
  among the candidates that pass, with their rivals and doubts;
- ``loop_refine``, ``loop_backward``, ``loop_audit``, ``loop_end``: the refinement of kept
  effects, the backward pass, the final audit and what is asked of the final model.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from threadpoolctl import threadpool_limits

from .effects import AbbeOffset, Cyclic, Effect
from .identify import (
    BLOCK_MM,
    CrossValidation,
    Identification,
    IdentifyOptions,
    cross_validate,
    identify,
    residual_rms,
)
from .loop_audit import audit
from .loop_backward import backward, set_up_for_surface
from .loop_choice import Shared, shared_of, shared_warnings, with_surface_doubt
from .loop_compare import Fitter, can_cross_validate, cv_compared
from .loop_courses import scales_in_time
from .loop_end import (
    choose_spacing,
    in_basis,
    other_route,
    surface_doubts_at_the_end,
    time_constant_doubts,
    with_shape_doubt,
)
from .loop_forward import AUDIT_ROUNDS, forward, prune
from .loop_judge import BOTH_WAYS, PLACED_AGAIN, TOGETHER
from .loop_periodic import periodic_in_time, taken_out
from .loop_reach import Together, moved_together, reach_of_lines, with_reach
from .loop_records import (
    ESTIMATED_AGAIN,
    EffectKey,
    Finding,
    LoopOptions,
    SpacingChoice,
    Step,
    TemperatureDoubt,
    Unexplained,
    effect_entry,
    group_rms,
    line_group,
)
from .loop_scale import temperature_warning, with_scale_doubts, with_temperature_doubts
from .loop_search import diagnose, periods_text
from .loop_state import State
from .loop_unexplained import unexplained, with_one_line_effects
from .measurement import Measurement
from .progress import CancelToken, ProgressCallback, report
from .readings import Readings, flatten


def _one_line_effect(step: Step) -> dict[str, object]:
    """A machine effect refused only because one line alone shows it, as report.json's
    ``unexplained[].one_line_effects`` gives it."""
    return {
        **effect_entry(step.finding.effect, step.parameters),
        "step": step.step,
        "held_out_gain_percent": 100.0 * step.improvement,
        **({"held_out_over": step.improvement_over} if step.improvement_over else {}),
    }


@dataclass(frozen=True, eq=False)
class LoopResult:
    base: Identification
    final: Identification
    cv_before: CrossValidation
    cv_after: CrossValidation
    steps: tuple[Step, ...]
    unexplained: tuple[Unexplained, ...]
    warnings: tuple[str, ...]
    #: per kept effect (as ``final.effects``): what of it the plan reads exactly as a change of
    #: the 21 errors (:class:`Shared`)
    shared: tuple[Shared, ...]
    #: the basis spacing the 21 errors were identified with, and how it was chosen
    spacing: SpacingChoice | None = None
    #: per kept effect (as ``final.effects``): its rivals of another place that fit as well
    #: (empty when it has none); each may be the effect the machine has
    rivals: tuple[dict[str, object], ...] = ()
    #: per kept effect (as ``final.effects``): for a drift whose time constant the loop searched,
    #: τ's standard-uncertainty range and the drift's size at either end (empty otherwise)
    searched_ranges: tuple[dict[str, object], ...] = ()
    #: the errors the unexplained lines move beyond their stated uncertainty together and none
    #: alone (:func:`~volucal.core.loop_reach.moved_together`)
    together: Together | None = None
    #: the doubts the material's change of temperature puts on the axes' positioning errors
    #: where no kept drift refers their scale back to the session's first reading
    #: (:func:`~volucal.core.loop_scale.temperature_doubts`)
    temperature_doubts: tuple[TemperatureDoubt, ...] = ()

    @property
    def kept(self) -> tuple[Effect, ...]:
        return tuple(self.final.effects)  # type: ignore[arg-type]

    def identify_options(self, asked: IdentifyOptions) -> IdentifyOptions:
        """``asked`` with the basis spacing the loop identified the 21 errors with."""
        if self.spacing is None:
            return asked
        return replace(asked, spacing_mm=self.spacing.spacing_mm)

    def effects_report(self) -> list[dict[str, object]]:
        out: list[dict[str, object]] = []
        rivals = self.rivals or ({},) * len(self.shared)
        ranges = self.searched_ranges or ({},) * len(self.shared)
        for effect, values, cov, part, rival, searched in zip(
            self.final.effects,
            self.final.effect_parameters,
            self.final.effect_covariances,
            self.shared,
            rivals,
            ranges,
            strict=True,
        ):
            assert isinstance(effect, Effect)
            entry = effect_entry(effect, {**effect.parameters(values, cov), **searched})
            if part.count:
                entry["shared_with_errors"] = {
                    "terms": list(part.terms),
                    "errors": list(part.errors),
                }
            if rival:
                entry["rivals"] = rival
            out.append(entry)
        return out

    def _cv_report(self) -> dict[str, object]:
        """Cross-validated RMS (µm, displacement lines) before and after the loop, over the
        readings the loop compares: those both the base and the final model predict (wild
        extrapolations are counted, not averaged in)."""
        before, after, wild = cv_compared(
            self.cv_before, self.cv_after, self.base, um=True, other_fit=self.final
        )
        judged = cv_compared(self.cv_before, self.cv_after, self.base, other_fit=self.final)
        out: dict[str, object] = {
            "before_loop": before,
            "after_loop": after,
            "method": self.cv_after.method,
            # what the loop judges by: every line, angular readings on the displacement scale
            "all_lines": {"before_loop": judged[0], "after_loop": judged[1]},
        }
        if self.cv_after.method.startswith("held-out blocks"):
            out["blocks_left_out"] = wild
        else:
            out["lines_left_out"] = wild
        return out

    def to_report(self) -> dict[str, object]:
        """The ``loop``, ``effects``, ``residual_rms_um``, ``cv_rms_um`` and ``unexplained``
        blocks of report.json (DESIGN.md)."""
        steps = []
        for s in self.steps:
            effect = s.finding.effect
            steps.append(
                {
                    "step": s.step,
                    "stage": s.stage,
                    "effect": {
                        **effect_entry(effect, s.parameters),
                        "evidence": s.finding.evidence(),
                    },
                    "kept": s.kept,
                    "verdict": s.verdict,
                    "reason": s.reason,
                    "rms_um": {"before": s.rms_before, "after": s.rms_after},
                    "cv_rms_um": {"before": s.cv_before, "after": s.cv_after},
                    "rms_um_by_group": {"before": s.per_group_before, "after": s.per_group_after},
                }
            )
        return {
            "loop": steps,
            "effects": self.effects_report(),
            "residual_rms_um": {
                "before_loop": residual_rms(self.base)[0],
                "after_loop": residual_rms(self.final)[0],
            },
            "residual_rms_urad": {
                "before_loop": residual_rms(self.base)[1],
                "after_loop": residual_rms(self.final)[1],
            },
            "cv_rms_um": self._cv_report(),
            "unexplained": [
                {
                    "where": u.where,
                    "description": u.description,
                    "magnitude_um": u.magnitude_um,
                    "correlates_with": dict(u.correlates_with),
                    "strongest": u.strongest,
                    **(
                        {"one_line_effects": [_one_line_effect(s) for s in u.one_line_effects]}
                        if u.one_line_effects
                        else {}
                    ),
                    **({"moves": [m.to_json() for m in u.moves]} if u.moves else {}),
                    **({"rests_on": list(u.rests_on)} if u.rests_on else {}),
                    **({"scale": u.scale.to_json()} if u.scale is not None else {}),
                    **({"periodic": dict(u.periodic)} if u.periodic else {}),
                }
                for u in self.unexplained
            ],
            **({"moved_together": self.together.to_json()} if self.together else {}),
            **(
                {"temperature_doubts": [d.to_json() for d in self.temperature_doubts]}
                if self.temperature_doubts
                else {}
            ),
            "warnings": list(self.warnings),
            **({"basis": self.spacing.report()} if self.spacing is not None else {}),
        }


def _with_reach(
    measurement: Measurement,
    options: LoopOptions,
    spacing: SpacingChoice,
    final: Identification,
    leftover: list[Unexplained],
    cancel: CancelToken | None,
) -> tuple[Identification, list[Unexplained], Together | None]:
    """The final fit with the errors' covariance widened by what each unexplained line pulls
    and by what they pull together, the unexplained entries saying the former
    (:func:`~volucal.core.loop_reach.reach_of_lines`), and the latter
    (:func:`~volucal.core.loop_reach.moved_together`)."""
    fit_options = replace(options.identify, redundancy=False, spacing_mm=spacing.spacing_mm)

    def refit(weighted: Readings) -> Identification:
        return identify(
            measurement,
            fit_options,
            effects=list(final.effects),  # type: ignore[arg-type]
            readings=weighted,
            cancel=cancel,
            initial=final.model,
        )

    reach = reach_of_lines(final, [u.line for u in leftover if u.line], refit)
    together = moved_together(final, reach)
    pulls = [r.change for r in reach.values() if r.moves]
    pulls += list(together.deltas) if together else []
    return with_shape_doubt(final, pulls, share=1.0), with_reach(leftover, reach), together


def _cv_warnings(readings: Readings, cv: CrossValidation, redundant: Sequence[str]) -> list[str]:
    """What the plan allows the loop to cross-validate, said once."""
    out = []
    not_redundant = [line.name for line in readings.lines if line.name not in redundant]
    if not_redundant and cv.method != "leave-one-line-out":
        names = ", ".join(not_redundant[:5]) + (" …" if len(not_redundant) > 5 else "")
        out.append(
            f"{len(not_redundant)} of {len(readings.lines)} lines are not redundant for this plan "
            f"({names}): leaving one out loses what only it sees, so the loop cross-validates on "
            f"held-out blocks of {BLOCK_MM:g} mm of targets; an effect is kept only where the "
            "rest of each line predicts the held-out block"
        )
    return out


def close_loop(
    measurement: Measurement,
    options: LoopOptions | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
) -> LoopResult:
    """Identify, then add effects from the catalogue while cross-validation says they help,
    then take out any that a later one made unnecessary.

    The loop's linear algebra is thousands of small products and solves, for which BLAS threads
    cost more in hand-over than they gain: it runs on one (the demo's loop, five runs of each
    alternated in one process on two cores: median 10.6 s on one thread, 12.1 s on two)."""
    with threadpool_limits(limits=1, user_api="blas"):
        return _close_loop(measurement, options or LoopOptions(), progress, cancel)


def _close_loop(
    measurement: Measurement,
    options: LoopOptions,
    progress: ProgressCallback | None,
    cancel: CancelToken | None,
) -> LoopResult:
    readings = flatten(measurement)
    report(progress, 0.0, "identifying the 21 errors")
    base = identify(measurement, options.identify, readings=readings, cancel=cancel)
    redundant = base.identifiability.redundant_lines
    cv_base = cross_validate(base.system, readings, redundant)
    warnings = _cv_warnings(readings, cv_base, redundant)
    why_not = can_cross_validate(readings, cv_base)
    spacing = SpacingChoice(
        options.identify.spacing_mm, options.identify.spacing_mm, {}, {}, cv_base.method
    )
    if why_not is not None:
        warnings.append(
            f"the loop cannot cross-validate this plan ({why_not}): no effect is tested; measure "
            "more lines or longer lines to close the loop"
        )
        leftover = unexplained(base, cv_base, options.alpha)
        final, temperature = with_temperature_doubts(base, base)
        warnings += [temperature_warning(d) for d in temperature]
        return LoopResult(
            base,
            final,
            cv_base,
            cv_base,
            (),
            tuple(leftover),
            tuple(warnings),
            (),
            spacing,
            temperature_doubts=tuple(temperature),
        )
    # an error periodic in time is no effect of the catalogue, and what it leaves in the lines
    # it acts on a shape in position or a set-up fits in part (blind 83037: a 0.6 µm Z error of
    # period 176 s kept as a surface EX over X×Z, 3.2 % better held out); taken out of the
    # readings, the loop searches and fits its effects without it, and reports it unexplained
    periodic = periodic_in_time(base, options.alpha)
    start, cv_start = base, cv_base
    if periodic is not None:
        readings = taken_out(readings, periodic, options.alpha)
        start = identify(measurement, options.identify, readings=readings, cancel=cancel)
        cv_start = cross_validate(start.system, readings, redundant)
        warnings.append(
            f"an error periodic in time ({periodic.amplitude_um:.2g} µm along {periodic.axis}, "
            f"period {periodic.period_s:.0f} s) was taken out of the readings before the loop "
            "searched its effects: the errors after the loop, and its 21 errors, are without "
            "it; it is listed under unexplained, as no effect of the catalogue, and no "
            "compensation table, holds an error in time"
        )
    fit = Fitter(measurement, readings, options, redundant, cancel, periodic)
    state = State(start, cv_start)

    def rounds(state: State, progress: ProgressCallback | None) -> None:
        """The forward steps, the backward pass, the set-up errors in the place of surfaces and
        the audit, in rounds while the audit takes an effect out."""
        # the kept sets the rounds started from: where the audit leaves one of them, another
        # round would keep what that one kept over again (blind 26062: a surface the backward
        # pass took out, and beside it the cosine the audit took out, owed a refit once the
        # surface was back), and the loop stops there; unless an axis' scale still changes in
        # time there, which what the round kept may have stood in for: the round runs again
        # with everything it kept held back until another effect is kept (blind 57197: a
        # cosine error of x_linear kept where a drift of X tied it, the diagonals' cosine
        # errors beside it; the audit took the three out, back to the empty start, 20 lines
        # reported; run again, the drift comes first and the two cosine errors after it)
        starts: list[frozenset[EffectKey]] = []
        for _ in range(AUDIT_ROUNDS):
            starts.append(frozenset(e.key for e in state.kept))
            first_row = len(state.steps)
            forward(state, fit, options, progress, cancel, start)
            prune(backward, state, fit, start, cv_start, options)
            placed = frozenset(e.key for e in state.kept)
            prune(set_up_for_surface, state, fit, start, cv_start, options)
            if frozenset(e.key for e in state.kept) != placed:  # a surface gave way: ask again
                prune(backward, state, fit, start, cv_start, options)
            before = frozenset(e.key for e in state.kept)
            if not prune(audit, state, fit, start, cv_start, options):
                break
            left = frozenset(e.key for e in state.kept)
            if state.number >= options.max_steps:
                break
            again = left in starts
            if again and not scales_in_time(state.current, options.alpha):
                break
            # what the taken-out effect held is the others' again: every candidate is scored
            # anew, but the taken-out one (its key: a cycle at another period, a surface of
            # another order is another candidate) is not proposed until another is kept
            # (:func:`owed_refit`): from the same model it would win the same step again, to be
            # taken out again (indep. 5000152: a cosine error of y_linear tied a drift of Y,
            # kept for its one parameter, was taken out as its line still drifted, and kept
            # again a round later)
            state.refused.clear()
            state.refused_beside.clear()
            held = before - left
            if again:
                held |= {
                    row.finding.effect.key
                    for row in state.steps[first_row:]
                    if row.stage == "forward" and row.kept
                } - left
            for key in held:
                state.refused[key] = np.inf
                state.refused_beside[key] = left

    rounds(state, progress)
    state = other_route(state, rounds, fit, options, progress, start)
    surface_doubts_at_the_end(state, fit, options, start, cv_start)
    current, cv, kept = state.current, state.cv, state.kept
    if any(isinstance(e, AbbeOffset) for e in kept):
        current, cv = fit.converged(kept, current.model)
    time_doubts, time_ranges, time_warnings = time_constant_doubts(
        fit, current, kept, start, options
    )
    warnings += time_warnings
    report(progress, 0.9, "choosing the basis spacing by cross-validation")
    current, cv, spacing = choose_spacing(
        measurement, readings, options, redundant, current, cv, cancel
    )
    # the fit before any doubt widens its covariance, which the temperature doubts' F test
    # projects with
    fitted = current
    warnings += state.warnings
    ambiguous, aliased, steps = state.ambiguous, state.aliased, state.steps
    # said only of surfaces and cycles the final model holds
    warnings += [text for e in kept for text in ambiguous.get(e.key, ())]
    warnings += [
        f"the cycle of {e.axis} kept at {e.period_mm:.4g} mm fits the readings about as well at "
        f"{periods_text(aliased[e.axis])}: the targets along {e.axis} are too regular to tell "
        "a cycle from its aliases, and between the targets they differ; targets spaced irregularly "
        "(as ISO 230-2 advises) tell them apart"
        for e in kept
        if isinstance(e, Cyclic) and e.searched and e.axis in aliased
    ]
    shared = tuple(shared_of(current, index) for index in range(len(current.effects)))
    warnings += shared_warnings(current, shared)
    report(progress, 0.95, "looking for what is still unexplained")
    leftover = with_one_line_effects(
        unexplained(current, cv, options.alpha), steps, {e.key for e in kept}, options.margin
    )
    doubts = [state.shape_doubt[e.key] for e in kept if e.key in state.shape_doubt]
    doubts += time_doubts
    if spacing.spacing_mm != spacing.reference_mm:
        doubts = [in_basis(np.atleast_2d(d), state.current.model, current.model) for d in doubts]
    current = with_shape_doubt(current, [*doubts, spacing.doubt])
    current = with_shape_doubt(current, [spacing.shape_missed], share=1.0)
    current = with_surface_doubt(current, state.surface_doubt)
    report(progress, 0.97, "leaving each unexplained line out")
    current, leftover, together = _with_reach(
        measurement, options, spacing, current, leftover, cancel
    )
    warnings += [together.warning()] if together else []
    current, leftover = with_scale_doubts(current, leftover, options.alpha)
    current, temperature = with_temperature_doubts(current, fitted)
    warnings += [temperature_warning(d) for d in temperature]
    report(progress, 1.0, "loop closed")
    rivals = tuple(state.rivals.get(e.key, {}) for e in current.effects)  # type: ignore[attr-defined]
    ranges = tuple(time_ranges.get(e.key, {}) for e in current.effects)  # type: ignore[attr-defined]
    return LoopResult(
        base,
        current,
        cv_base,
        cv,
        tuple(steps),
        tuple(leftover),
        tuple(warnings),
        shared,
        spacing,
        rivals,
        ranges,
        together,
        tuple(temperature),
    )


__all__ = [
    "BOTH_WAYS",
    "ESTIMATED_AGAIN",
    "PLACED_AGAIN",
    "TOGETHER",
    "Finding",
    "LoopOptions",
    "LoopResult",
    "SpacingChoice",
    "Step",
    "Unexplained",
    "close_loop",
    "diagnose",
    "group_rms",
    "line_group",
    "unexplained",
]
