"""The backward pass: each kept effect removed in turn and dropped where its removal no longer
costs the margin, and the set-up errors tried in the place of kept surfaces."""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import numpy as np

from .effects import CrossAxis, Effect
from .identify import CrossValidation, Identification
from .loop_choice import complexity, effect_terms
from .loop_compare import (
    Fitter,
    Trial,
    cv_compared,
    kept_with,
    later_step,
    rows_compared,
    step_record,
)
from .loop_forward import try_finding
from .loop_judge import any_implausible, gain_where_it_acts, wald_statistic
from .loop_records import Finding, LoopOptions, Step
from .loop_search import diagnose
from .loop_unexplained import WIDESPREAD_MARGIN_FACTOR, WIDESPREAD_SHARE, unexplained_lines


def backward(
    fit: Fitter,
    current: Identification,
    cv: CrossValidation,
    kept: list[Effect],
    base: Identification,
    cv_base: CrossValidation,
    options: LoopOptions,
    steps: list[Step],
    number: int,
) -> tuple[Identification, CrossValidation, list[Effect]]:
    """Take out, one at a time, the kept effect whose removal costs least, while that cost is
    below the margin that earned it its place — never one without which the rest's refit has
    parameters no set-up allows: they explain the data only with it (indep. 3700091: without
    the drift of X, the first line's cosine error fits 5856 µrad and predicts the held-out lines
    1 % better; taken out, the audit took the cosine out after it and both were lost)."""
    while kept:
        costs = []
        left = len(unexplained_lines(current, cv, options.alpha))
        widespread = left >= WIDESPREAD_SHARE * len(current.readings.lines)
        needed = WIDESPREAD_MARGIN_FACTOR * options.margin if widespread else options.margin
        # Removing an effect raises the weighted sum of squares by its Wald statistic βᵀC⁻¹β
        # (in σ²); one that raises it far beyond what the margin allows needs no refit to
        # know it stays — unless structure spreads over the plan, which it may be taking in
        # sample far more than it predicts held out
        allowed = ((1.0 + options.margin) ** 2 - 1.0) * max(len(current.residual), 1)
        for effect in kept:
            index = list(current.effects).index(effect)
            if not widespread and wald_statistic(current, index) > 4.0 * allowed:
                continue
            rest = [e for e in kept if e is not effect]
            refit, cv_new = (base, cv_base) if not rest else fit(rest, current.model)
            if any_implausible(refit, options) is not None:
                continue  # the rest explains the data only with parameters no set-up allows
            with_it, without, _ = cv_compared(cv, cv_new, current, other_fit=refit)
            cost = without / with_it - 1.0
            # an effect that acts on few readings (a bump, a reversal's slope) is asked over
            # them, as when it was kept
            if 0.0 < cost < needed:
                rows, _ = rows_compared(cv, cv_new, current, refit)
                reach = gain_where_it_acts(effect, current, rows, cv, cv_new)
                if reach is not None:
                    cost = max(cost, -reach[0])
            costs.append((cost, effect, refit, cv_new, with_it, without))
        if not costs:
            break
        cost, effect, refit, cv_new, with_it, without = min(costs, key=lambda c: c[0])
        if cost >= needed:
            break
        reason = (
            f"removed in the backward pass: without it the cross-validated RMS is "
            f"{with_it:.4g} → {without:.4g} ({100 * cost:+.1f} %), "
        )
        if cost >= options.margin:  # widespread: beyond the margin, below twice it
            reason += (
                f"while {left} of {len(current.readings.lines)} lines stay unexplained beside "
                "it: so small a share of structure that spreads over the plan (less than "
                f"{100 * needed:.0f} %) is what any shape takes of it, not this effect"
            )
        else:
            reason += (
                f"less than the {100 * options.margin:.0f} % margin; a later effect explains "
                "what it did"
            )
        steps.append(
            later_step(
                number, effect, current, (refit, cv_new), False, reason, (current, cv), "backward"
            )
        )
        kept = [e for e in kept if e is not effect]
        current, cv = refit, cv_new
    return current, cv, kept


def set_up_for_surface(
    fit: Fitter,
    current: Identification,
    cv: CrossValidation,
    kept: list[Effect],
    base: Identification,
    cv_base: CrossValidation,
    options: LoopOptions,
    steps: list[Step],
    number: int,
) -> tuple[Identification, CrossValidation, list[Effect]]:
    """With every kept effect in the model, a kept surface that one line's set-up error explains
    as well (within ``tie``, with fewer parameters, passing every rule against the rest) gives
    way to it, one surface at a time.

    A step keeps what predicts best at that step, before the effects kept after it: a surface
    that reads one line's scale as depending on where the line lies takes the part of another
    machine effect still missing that falls on its axes, and beats that line's cosine error by
    it; once the other effect is kept, the two predict alike and the surface's extra terms
    explain nothing the cosine does not (blind 43187, displacement-only plan: EZ over X×Z kept at
    step 1 for 0.1164 µm against 0.1256 µm for a 4.1 mrad misalignment of z_lin_1; with EX over
    X×Y kept, 0.07514 against 0.07509). The strongest set-up finding of the model without the
    surface is refitted in its place; the tie rule of a step (:func:`simplest_best`) is asked
    again of the two. :func:`close_loop` then runs the backward pass once more: another kept
    effect may have taken what the set-up error now explains (blind 41008: a cosine error of
    body_mpp kept beside the surface that stood in for body_ppp's). Where no set-up error takes
    the surface's place whole, the surface one order lower beside one may
    (:func:`_lower_order_beside_set_up`)."""
    for surface in [e for e in kept if isinstance(e, CrossAxis)]:
        rest = [e for e in kept if e is not surface]
        without, cv_without = (base, cv_base) if not rest else fit(rest, current.model)
        findings, _ = diagnose(without, [e.key for e in rest], options)
        set_up = _strongest_set_up(findings, options)
        trial = (
            None if set_up is None else try_finding(set_up, fit, rest, without, cv_without, options)
        )
        if trial is not None and trial.ok:
            with_surface, with_set_up, _ = cv_compared(cv, trial.cv, current, other_fit=trial.refit)
        if (
            set_up is None
            or trial is None
            or not trial.ok
            or with_set_up > with_surface * (1.0 + options.tie)
            or complexity(trial) >= effect_terms(surface, current)
        ):
            # no set-up error takes the surface's place whole: one may take its highest order's
            lowered = _lower_order_beside_set_up(surface, rest, fit, current, cv, options)
            if lowered is not None:
                current, cv, kept = _lowered(lowered, surface, rest, current, cv, steps, number)
            continue
        reason = (
            f"{set_up.effect.label} explains what it did as well with fewer parameters: "
            f"cross-validated RMS {with_surface:.4g} with the surface, {with_set_up:.4g} with "
            "the set-up error in its place"
        )
        current, cv, kept = given_way(
            steps, number, surface, (current, cv), trial, reason, (without, cv_without)
        )
    return current, cv, kept


def _strongest_set_up(findings: list[Finding], options: LoopOptions) -> Finding | None:
    """The strongest finding of a line's set-up error (an Abbe offset, a cosine error) beyond
    the loop's false-alarm level, if any."""
    return next(
        (
            f
            for f in findings
            if f.effect.line_index is not None and f.log10_false_alarm < np.log10(options.alpha)
        ),
        None,
    )


def given_way(
    steps: list[Step],
    number: int,
    surface: Effect,
    before: tuple[Identification, CrossValidation],
    trial: Trial,
    reason: str,
    without: tuple[Identification, CrossValidation],
) -> tuple[Identification, CrossValidation, list[Effect]]:
    """A kept surface gives way to ``trial``'s effect, refitted in its place: the two backward
    steps that say so (``before`` the model with the surface, ``without`` the one without it),
    and the refit's model, cross-validation and kept effects."""
    steps.append(_surface_replaced(number, surface, *before, trial, reason))
    steps.append(
        step_record(
            number,
            trial,
            True,
            f"{trial.reason}; kept in the backward pass in the place of {surface.label}",
            *without,
            stage="backward",
        )
    )
    # the refit's own effects: a drift beside it may have been placed again (try_finding)
    kept = [e for e in trial.refit.effects if isinstance(e, Effect)]
    return trial.refit, trial.cv, kept


def _surface_replaced(
    number: int,
    surface: Effect,
    current: Identification,
    cv: CrossValidation,
    trial: Trial,
    reason: str,
) -> Step:
    """The backward step of a kept surface that gives way to ``trial``'s fit."""
    return later_step(
        number,
        surface,
        current,
        (trial.refit, trial.cv),
        False,
        f"replaced in the backward pass: {reason}",
        (current, cv),
        "backward",
    )


class _Lowered(NamedTuple):
    """A kept surface at one order lower, and a line's set-up error refitted beside it
    (:func:`_lower_order_beside_set_up`)."""

    lower: CrossAxis
    lower_fit: Identification
    cv_lower: CrossValidation
    trial: Trial
    with_surface: float
    with_both: float


def _lower_order_beside_set_up(
    surface: CrossAxis,
    rest: list[Effect],
    fit: Fitter,
    current: Identification,
    cv: CrossValidation,
    options: LoopOptions,
) -> _Lowered | None:
    """A kept surface whose highest order took one line's set-up error: the surface one order
    lower, beside the strongest set-up finding of the model with it, explains what the surface
    did as well (within ``tie``) with fewer parameters, the set-up passing every rule against
    the lower-order model. A surface over the plane of a line that is misaligned reads that
    line's scale as a shape of where the line lies; at step 1, before the set-up was ever
    refitted, its higher order predicts the line best (blind 46074, displacement-only plan:
    EY over X×Y, a pure product of the two positions, kept at order 4 for 0.0548 µm against
    0.0921 at order 3, the 3.4 mrad cosine error of diag_xy_offcentre taken up by the fourth
    order and never refitted)."""
    lowest = 2 if surface.lever_terms else 4
    if surface.order - 1 < lowest:
        return None
    machine = current.model.machine
    lower = replace(surface, order=surface.order - 1)
    lower_fit, cv_lower = fit(kept_with(rest, lower, machine), current.model)
    findings, _ = diagnose(lower_fit, [e.key for e in (*rest, lower)], options)
    set_up = _strongest_set_up(findings, options)
    if set_up is None:
        return None
    trial = try_finding(set_up, fit, [*rest, lower], lower_fit, cv_lower, options)
    if not trial.ok:
        return None
    with_surface, with_both, _ = cv_compared(cv, trial.cv, current, other_fit=trial.refit)
    fewer = effect_terms(lower, trial.refit) + complexity(trial) < effect_terms(surface, current)
    if with_both > with_surface * (1.0 + options.tie) or not fewer:
        return None
    return _Lowered(lower, lower_fit, cv_lower, trial, with_surface, with_both)


def _lowered(
    lowered: _Lowered,
    surface: CrossAxis,
    rest: list[Effect],
    current: Identification,
    cv: CrossValidation,
    steps: list[Step],
    number: int,
) -> tuple[Identification, CrossValidation, list[Effect]]:
    """The steps and the kept effects of a surface that gives way to itself one order lower
    beside a line's set-up error (:func:`_lower_order_beside_set_up`)."""
    lower, trial = lowered.lower, lowered.trial
    reason = (
        f"{lower.label} beside {trial.finding.effect.label} explains what it did as well with "
        f"fewer parameters: cross-validated RMS {lowered.with_surface:.4g} with the surface, "
        f"{lowered.with_both:.4g} with the two in its place"
    )
    steps.append(_surface_replaced(number, surface, current, cv, trial, reason))
    index = list(trial.refit.effects).index(lower)
    parameters = lower.parameters(
        trial.refit.effect_parameters[index], trial.refit.effect_covariances[index]
    )
    finding = Finding(lower, float("nan"), 0.0, 0, 0.0, 0.0, "backward pass")
    held = Trial(finding, trial.refit, trial.cv, True, reason, parameters)
    steps.append(
        step_record(
            number,
            held,
            True,
            f"kept in the backward pass in the place of {surface.label}, beside "
            f"{trial.finding.effect.label}",
            current,
            cv,
            stage="backward",
        )
    )
    steps.append(
        step_record(
            number,
            trial,
            True,
            f"{trial.reason}; kept in the backward pass beside {lower.label}, in the place of "
            f"{surface.label}",
            lowered.lower_fit,
            lowered.cv_lower,
            stage="backward",
        )
    )
    # the refit's own effects: a drift beside it may have been placed again (try_finding)
    kept = [e for e in trial.refit.effects if isinstance(e, Effect)]
    return trial.refit, trial.cv, kept
