"""What the closed loop asks of its final model: the surfaces and time constants in doubt, the
other route a tied step could have taken, and the basis spacing chosen by cross-validation."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from .effects import CrossAxis, Effect, ThermalDrift
from .errors import AXIS_ERROR_IDS, ERROR_INFO, SQUARENESS_IDS, ErrorModel, gauge_null_space
from .identify import CrossValidation, Identification, cross_validate, identify
from .identify_system import Gauge
from .loop_backward import given_way
from .loop_choice import complexity, kept_instead, model_terms, nearly_as_strong, surface_place
from .loop_compare import Fitter, Trial, cv_compared, predicted_rows, rows_compared
from .loop_courses import on_common_rows
from .loop_forward import EVERY_PLACE, PER_PLACE, record_doubts, try_finding, untried_places
from .loop_judge import BOTH_WAYS, SHOWN_SIGMA2, earliest_along, judge
from .loop_records import EffectKey, Finding, FloatArray, LoopOptions, SpacingChoice, Step
from .loop_refine import fit_without, refine_kept
from .loop_search import diagnose
from .loop_state import Fork, State
from .loop_tester import Tester, rms_over
from .loop_unexplained import unexplained_lines
from .measurement import Measurement
from .progress import CancelToken, ProgressCallback, check, report
from .readings import Readings

#: Points over a stroke on which one function is compared with another or moved between bases.
STROKE_POINTS = 201


def surface_doubts_at_the_end(
    state: State,
    fit: Fitter,
    options: LoopOptions,
    base: Identification,
    cv_base: CrossValidation,
) -> None:
    """Ask what the plan leaves open about each kept surface (:func:`record_doubts`) again in the
    model the loop ends with: the surface judged against the rest without it, beside what
    predicted as well when it was kept and the other orders and places the diagnosis of that model
    gives nearly its gain (:func:`_variants_of_place`, :func:`untried_places`; at another
    place the same order and shape first, then the strongest, :data:`PER_PLACE`), each
    refitted only to be named.

    A step names the rivals of the model it keeps the surface in; the effects kept after it,
    and the backward pass, change what the surface has to explain, and a surface put in the
    place of another there was never asked (blind 51096, displacement-only plan: EY over X×Y
    kept at step 2 before the cosine error of diag_xy_offcentre, which the backward pass then
    kept beside it one order lower; in the final model the injected EY over Y×Z predicts the
    held-out data as well, 0.2838 against 0.2831 µm, with the same diagnosis gain, and was
    never named; at order 4, 0.2841). Other places that predict better than the kept surface
    by more than ``tie`` are not named: no refit of the loop ranked them against it. A place
    that predicts as well with fewer parameters than the kept one's is kept in its place
    (:func:`_leaner_place`)."""
    for key in [e.key for e in state.kept if isinstance(e, CrossAxis)]:
        surface = next((e for e in state.kept if e.key == key), None)
        if isinstance(surface, CrossAxis):  # an earlier surface's refit may have moved it
            _surface_asked_again(state, surface, fit, options, base, cv_base)


def _surface_asked_again(
    state: State,
    surface: CrossAxis,
    fit: Fitter,
    options: LoopOptions,
    base: Identification,
    cv_base: CrossValidation,
) -> None:
    """:func:`surface_doubts_at_the_end` for one kept surface."""
    rest = [e for e in state.kept if e is not surface]
    without, cv_without = (base, cv_base) if not rest else fit(rest, state.current.model)
    findings, _ = diagnose(without, [e.key for e in rest], options)
    own = next((f for f in findings if f.effect.key == surface.key), None)
    if own is None:  # the diagnosis proposes it at another order: its place's strongest
        place = surface_place(surface)
        strongest = max(
            (f.gain for f in findings if surface_place(f.effect) == place), default=0.0
        )
        own = Finding(surface, float("nan"), 0.0, 0, 0.0, 0.0, "final model", strongest)
    own = replace(own, effect=surface)
    chosen = judge(own, without, cv_without, state.current, state.cv, options, fit)
    # what predicted as well when it was kept, its other orders, then the other places
    tried: dict[EffectKey, Trial] = {surface.key: chosen}

    def ask(finding: Finding) -> Trial:
        key = finding.effect.key
        if key not in tried:
            tried[key] = try_finding(finding, fit, rest, without, cv_without, options)
        return tried[key]

    for finding in [*state.tied.get(surface.key, ()), *_variants_of_place(findings, own, options)]:
        ask(finding)
    for orders in untried_places(findings, [chosen], chosen, options, EVERY_PLACE):
        # the same shape at the other place and its strongest finding (often a higher order,
        # where the step's batch may have tried the same shape); the next order where one
        # swings implausibly
        orders.sort(key=lambda f: not _same_shape(f.effect, surface))
        plausible = 0
        for finding in orders:
            plausible += ask(finding).verdict != "implausible"
            if plausible == PER_PLACE:
                break
    trials = on_common_rows(list(tried.values()))
    chosen = trials[0]
    leaner, own = _leaner_place(chosen, trials, options.tie)
    if leaner is not chosen:
        _surface_swapped(state, chosen, leaner, own, without, cv_without)
        chosen = leaner
    place = surface_place(chosen.finding.effect)
    # another place that predicts better by more than the tie is not named (no refit of the
    # loop ranked the two); a richer order of its own place, refused for the margin, unsettles
    # its shape (:func:`unsettled`)
    better = chosen.score * (1.0 - options.tie)
    asked = [t for t in trials if t.score >= better or surface_place(t.finding.effect) == place]
    record_doubts(state, chosen, asked, options)


def _leaner_place(chosen: Trial, trials: list[Trial], tie: float) -> tuple[Trial, int]:
    """The surface kept in the final model in the place of the kept surface (``chosen``, judged
    there against the rest without it), and the fewest parameters of its own place's surfaces
    that predict the held-out data as well (within ``tie``): ``chosen``, unless a surface of
    another place that passes every rule and predicts as well has fewer parameters than every
    one of those; of several, the leanest, then the best.

    A step keeps what predicts best before the effects kept after it, with the fewest
    parameters among those that tie (:func:`simplest_best`); a surface of many terms may then
    hold what another effect, kept later, explains, and in the final model a leaner surface of
    another place predicts as well (blind 50099, direct plan: EY over Y×Z of order 8, 15 terms,
    kept at step 1 before the drift of X; in the final model the injected EX over X×Y with
    lever-arm terms, 6 terms, predicts 0.0810 µm against 0.0811 µm, and no order of Y×Z with
    fewer than 15 predicts as well). The tie rule asked again, on parameters only: where the
    kept place has as lean a variant that predicts as well, the plan tells the places apart no
    better than a step did, and the kept one stays (asked next for the smaller peak over the
    strokes, the machine's place was picked in 9 more blind and indep. scenarios and another
    in 6, among them for peaks 0.5 % apart). The other stays named (:func:`alike`)."""
    if not chosen.ok or not isinstance(chosen.finding.effect, CrossAxis):
        return chosen, 0
    place = surface_place(chosen.finding.effect)
    tied = [
        t
        for t in trials
        if t.ok
        and isinstance(t.finding.effect, CrossAxis)
        and t is not chosen
        and t.ties(chosen, tie)
    ]
    own = min(
        [complexity(chosen)]
        + [complexity(t) for t in tied if surface_place(t.finding.effect) == place]
    )
    leaner = [t for t in tied if surface_place(t.finding.effect) != place and complexity(t) < own]
    return min(leaner, key=lambda t: (complexity(t), t.score), default=chosen), own


def _surface_swapped(
    state: State,
    chosen: Trial,
    leaner: Trial,
    own: int,
    without: Identification,
    cv_without: CrossValidation,
) -> None:
    """Put ``leaner`` (:func:`_leaner_place`) in the place of the kept surface ``chosen`` in
    ``state``, with the two steps that say so."""
    surface, other = chosen.finding.effect, leaner.finding.effect
    reason = (
        f"in the final model {other.label} predicts the held-out data as well (cross-validated "
        f"RMS {leaner.score:.4g} against {chosen.score:.4g}) with {complexity(leaner)} "
        f"parameters, where no surface of its place that predicts as well has fewer than {own}"
    )
    state.current, state.cv, state.kept = given_way(
        state.steps,
        state.number,
        surface,
        (state.current, state.cv),
        leaner,
        reason,
        (without, cv_without),
    )


def _same_shape(effect: Effect, surface: CrossAxis) -> bool:
    """Whether ``effect`` is a surface of ``surface``'s order, with or without lever-arm terms
    as it is."""
    return (
        isinstance(effect, CrossAxis)
        and effect.order == surface.order
        and effect.lever_terms == surface.lever_terms
    )


def _variants_of_place(
    findings: list[Finding], own: Finding, options: LoopOptions
) -> list[Finding]:
    """The findings of a kept surface's direction and pair of axes at another order (or with or
    without lever-arm terms) with at least :data:`RIVAL_GAIN_SHARE` of its gain, strongest
    first, up to ``candidates_per_step``."""
    place = surface_place(own.effect)
    return [
        f
        for f in findings
        if surface_place(f.effect) == place
        and f.effect.key != own.effect.key
        and nearly_as_strong(f, own.gain, options)
    ][: options.candidates_per_step]


def other_route(
    state: State,
    rounds: Callable[[State, ProgressCallback | None], None],
    fit: Fitter,
    options: LoopOptions,
    progress: ProgressCallback | None,
    base: Identification,
) -> State:
    """The loop again from the first step that kept a surface over a line's set-up error that
    passed every rule too (:func:`_passing_set_up`), with the set-up error kept there instead,
    and from the first step that kept a surface over its other family of as many terms that
    predicted within ``tie`` (:func:`_tied_variant`), with that one kept there instead (a route
    that may itself fork once at a set-up error); the route that ends predicting the held-out
    data better by ``margin``, or as well (within ``tie``) with fewer parameters, is the loop's;
    ``rounds`` runs the loop's rounds (forward steps, backward passes, audits) on a state.

    Each step keeps what predicts best at that step, and a surface takes more of what is still
    missing than one line's set-up error does: the rest of the loop then builds on it. On a
    plan of diagonals a surface over the wrong plane took a misaligned line's scale, a second
    surface what the first bent, and the true surface never showed (blind 45017,
    displacement-only plan: EY over X×Y of order 4 kept at step 2 for 0.152 µm against 0.167 µm
    for a 3.3 mrad cosine error of body_ppp, then EY over X×Z of order 8; 0.0935 µm held out,
    25 parameters, 10 lines unexplained. With the cosine error kept at step 2, EY over Y×Z —
    the injected surface — and the cycle: 0.0836 µm, 8 parameters). Backward passes replace one
    effect at a time and cannot undo that."""

    def route(fork: Fork) -> State:
        """The loop's rounds run from ``fork``'s state with its other candidate kept at its
        step."""
        other, kept_there = fork.state, fork.other
        rows = other.steps[fork.first_row :]
        other.steps = other.steps[: fork.first_row] + [
            _swapped(row, fork, options.margin) for row in rows
        ]
        kept = [e for e in kept_there.refit.effects if isinstance(e, Effect)]
        other.current, other.cv, other.kept = refine_kept(
            fit,
            kept_there.refit,
            kept_there.cv,
            kept,
            base,
            other.steps,
            fork.number,
            options.alpha,
        )

        def onward(fraction: float, message: str) -> None:  # another route: 85–90 %
            said = f"another route from step {fork.number}: {message}"
            report(progress, 0.85 + 0.05 * fraction, said)

        rounds(other, onward)
        return other

    chosen = state
    if state.fork is not None:
        chosen = _route_taken(state, route(state.fork), state.fork, options)
    if state.variant_fork is not None:
        other = other_route(route(state.variant_fork), rounds, fit, options, progress, base)
        chosen = _route_taken(chosen, other, state.variant_fork, options)
    return chosen


def _route_taken(state: State, other: State, fork: Fork, options: LoopOptions) -> State:
    """Of ``state`` and ``other``, the route run from ``fork`` (:func:`other_route`), the one
    the loop takes: ``other`` where it ends predicting the held-out data better by ``margin``,
    or as well (within ``tie``) with fewer parameters; the rows of the fork's step say both
    ends."""
    ended, ended_other, _ = cv_compared(state.cv, other.cv, state.current, other_fit=other.current)
    terms, terms_other = model_terms(state.current), model_terms(other.current)
    taken = ended_other < ended * (1.0 - options.margin) or (
        ended_other <= ended * (1.0 + options.tie) and terms_other < terms
    )
    surface, kept_there = fork.surface.finding.effect, fork.other.finding.effect
    said = (
        f"{BOTH_WAYS}: with {surface.label} kept it ended at a cross-validated RMS of "
        f"{ended:.4g} with {terms} parameters, with {kept_there.label} kept at {ended_other:.4g} "
        f"with {terms_other}"
    )
    chosen = other if taken else state
    for at in range(fork.first_row, len(chosen.steps)):
        row = chosen.steps[at]
        if row.step != fork.number:
            break
        if row.finding.effect is surface or row.finding.effect is kept_there:
            chosen.steps[at] = replace(row, reason=f"{row.reason}; {said}")
    return chosen


def _swapped(row: Step, fork: Fork, margin: float) -> Step:
    """A row of the step another route forks at (:func:`other_route`), with the fork's other
    candidate kept there in the surface's place."""
    effect = row.finding.effect
    if effect is fork.other.finding.effect:
        return replace(row, kept=True, verdict="kept", reason=fork.other.reason)
    trial = next((t for t in fork.tried if t.finding.effect is effect), None)
    if trial is None or not trial.ok:
        return row
    return replace(
        row,
        kept=False,
        verdict="another kept",
        reason=f"{trial.reason}{kept_instead(fork.other, trial, margin)}",
    )


def time_constant_doubts(
    fit: Fitter,
    current: Identification,
    kept: list[Effect],
    base: Identification,
    options: LoopOptions,
) -> tuple[list[FloatArray], dict[tuple[str, str | None, str], dict[str, object]], list[str]]:
    """Per kept drift whose time constant the loop searched: the moves of the 21 errors to the
    refits at either end of τ's standard uncertainty, one per row (:func:`with_shape_doubt`);
    by the drift's key, those ends and the drift's size there (for report.json); and a warning
    for each drift in time that one line alone shows.

    A refit holds τ fixed, so the errors' covariance says nothing of how they move with it, and
    τ trades against the drift's scale and the static scale of its axis: the machine at the
    first reading is what the drift is not (blind 38021: τ 240 min against 192 injected; the Y
    positioning 0.52 µm off, 6.5 of its stated standard uncertainties). Nor does the drift's
    own standard uncertainty, taken at the kept τ: a drift that one line shows (the earliest
    along its axis, :func:`_uncorroborated`) reaches nearly the same course with a larger scale
    and a slower τ (blind 4047: 54 ± 5.7 ppm at τ 99 min for 25 ppm at 41 min). The ends are
    where the χ² the drift removes, over the model without it, falls one σ² of the final fit
    below its best, searched outward from the kept τ within the range the options allow; an
    end at that range's limit means the data bound τ no closer on that side."""
    rows: list[FloatArray] = []
    ranges: dict[tuple[str, str | None, str], dict[str, object]] = {}
    warnings: list[str] = []
    low, high = (float(np.log(t)) for t in options.time_constants_s)
    for effect in kept:
        if not isinstance(effect, ThermalDrift) or not effect.searched:
            continue
        tester = fit_without(effect, kept, fit, current.model, base)

        def gain(log_tau: float, effect: ThermalDrift = effect, tester: Tester = tester) -> float:
            candidate = replace(effect, time_constant_s=float(np.exp(log_tau)))
            return tester.drop(candidate.design(tester.ident.readings, tester.ident.model))

        start = float(np.log(effect.time_constant_s))
        # one σ² of the final fit, in the units of the model without the drift
        level = gain(start) - Tester(current).sigma2 / max(tester.sigma2, 1e-300)
        index = next(i for i, e in enumerate(current.effects) if e is effect)
        taus, sizes = [], []
        for limit in (low, high):
            end = _where_below(gain, level, start, limit)
            taus.append(float(np.exp(end)))
            if end == start:
                sizes.append(float(current.effect_parameters[index][0]))
                continue
            moved = replace(effect, time_constant_s=float(np.exp(end)))
            refit = fit.identify([moved if e is effect else e for e in kept], current.model)
            rows.append(refit.model.parameters - current.model.parameters)
            moved_at = next(i for i, e in enumerate(refit.effects) if e is moved)
            sizes.append(float(refit.effect_parameters[moved_at][0]))
        size = "scale" if effect.mode == "time" else "expansion"
        unit = "ppm" if effect.mode == "time" else "ppm_per_c"
        ranges[effect.key] = {
            "time_constant_range_s": taus,
            f"{size}_at_range_{unit}": sizes,
        }
        if effect.mode == "time":
            values = current.effect_parameters[index]
            warning = _one_line_drift(effect, values, tester, taus, sizes, options)
            warnings += [warning] if warning else []
    return rows, ranges, warnings


def _one_line_drift(
    effect: ThermalDrift,
    values: FloatArray,
    tester: Tester,
    taus: Sequence[float],
    sizes: Sequence[float],
    options: LoopOptions,
) -> str | None:
    """The warning for a kept drift in time (``values`` its fitted scale) that one line alone
    shows beyond what the model without it (``tester``) absorbs, with τ's standard-uncertainty
    range (``taus``) and the scale at its ends (``sizes``); None when it shows on more lines."""
    readings = tester.ident.readings
    energy = tester.line_energy(effect.design(readings, tester.ident.model) @ values)
    showing = np.flatnonzero(energy >= SHOWN_SIGMA2)
    if showing.size != 1:
        return None
    line = int(showing[0])
    shortest, longest = options.time_constants_s
    low = " (the shortest tried)" if np.isclose(taus[0], shortest) else ""
    high = " (the longest tried)" if np.isclose(taus[1], longest) else ""
    first = (
        f", the first along {effect.axis}" if line == earliest_along(effect.axis, readings) else ""
    )
    return (
        f"the {effect.label} is shown by line {readings.lines[line].name} alone{first}: the axis "
        "warming while that line was measured, settled for the later lines, reads there as a "
        f"beam drifting during it would; τ is between {taus[0] / 60:.3g} min{low} and "
        f"{taus[1] / 60:.3g} min{high} and the scale between {min(sizes):.3g} and "
        f"{max(sizes):.3g} ppm (one standard uncertainty); a second line along the axis early in "
        "the session tells them apart"
    )


def _where_below(gain: Callable[[float], float], level: float, start: float, limit: float) -> float:
    """Where ``gain`` first falls below ``level`` going from ``start`` towards ``limit`` (steps
    doubling from 0.05, then a root between the last two), ``limit`` when it never does."""
    from scipy.optimize import brentq

    x, step = start, 0.05 * float(np.sign(limit - start))
    while step and (x + step - limit) * np.sign(step) < 0:
        if gain(x + step) < level:
            return float(brentq(lambda t: gain(t) - level, x, x + step, xtol=1e-3))
        x, step = x + step, 2.0 * step
    return limit


def choose_spacing(
    measurement: Measurement,
    readings: Readings,
    options: LoopOptions,
    redundant: Sequence[str],
    fit: Identification,
    cv: CrossValidation,
    cancel: CancelToken | None = None,
) -> tuple[Identification, CrossValidation, SpacingChoice]:
    """The basis spacing of ``options.spacings_mm`` whose 21 errors, fitted with the effects the
    loop kept, predict the held-out readings best (DESIGN: the default basis is chosen by
    cross-validation), with its fit and cross-validation. ``fit`` and ``cv`` are the loop's
    final fit, at the identification's own spacing: the reference every other is compared with
    over the readings both predict (:func:`cv_compared`), the same lines or blocks held out (the
    plan's ``redundant`` lines decide which).

    A finer basis follows the guideways' shape more closely and the noise more; a coarser one
    averages the noise over more targets and misses what bends between its breakpoints: which
    costs more depends on the machine and the noise. The choice comes after the effects, so that
    a screw cycle or a drift the model does not hold yet is not taken for noise to be averaged
    (the effects themselves are chosen at the identification's spacing, whose shapes the loop's
    thresholds were set on). From the reference the spacings are tried coarser, then finer,
    each way while the error keeps falling. A trial is a first-order fit (the nonlinear
    refinement moves the prediction at second order of the errors, far below what tells two
    spacings apart). The best is identified again in full and kept unless it leaves a line
    with a systematic residual (:func:`unexplained`) that the reference explains: held-out
    readings weigh the noise of every run, that test the mean of the runs, and a basis that
    averages the noise away while it misses a bend the runs agree on is not kept for the
    first (the next best is tried instead).
    """
    reference = options.identify.spacing_mm
    effects = list(fit.effects)
    identify_options = replace(options.identify, redundancy=False)
    displacement = ~readings.is_angular
    rows, _ = predicted_rows(cv, fit)
    um = {reference: rms_over(cv.residual, readings, rows & displacement)}
    rms = {reference: rms_over(cv.residual, readings, rows)}
    ratio = {reference: 1.0}
    fits = {reference: fit}
    coarser = sorted(s for s in set(options.spacings_mm) if s > reference)
    finer = sorted((s for s in set(options.spacings_mm) if s < reference), reverse=True)
    for way in (coarser, finer):
        best = 1.0
        for spacing_mm in way:
            check(cancel)
            first_order = replace(identify_options, spacing_mm=spacing_mm, refine=False)
            trial = identify(
                measurement, first_order, effects=effects, readings=readings, cancel=cancel
            )
            trial_cv = cross_validate(trial.system, readings, redundant)
            fits[spacing_mm] = trial
            # over the readings both predict (:func:`cv_compared`), on both scales
            rows, _ = rows_compared(cv, trial_cv, fit, trial)
            mine = rms_over(cv.residual, readings, rows)
            rms[spacing_mm] = rms_over(trial_cv.residual, readings, rows)
            um[spacing_mm] = rms_over(trial_cv.residual, readings, rows & displacement)
            ratio[spacing_mm] = rms[spacing_mm] / mine if mine > 0 else np.inf
            if ratio[spacing_mm] >= best:
                break
            best = ratio[spacing_mm]
    chosen, refused = reference, {}
    better = sorted((s for s in ratio if ratio[s] < 1.0), key=lambda s: ratio[s])
    clean = unexplained_lines(fit, cv, options.alpha) if better else set()
    for spacing_mm in better:
        check(cancel)
        trial = identify(
            measurement,
            replace(identify_options, spacing_mm=spacing_mm),
            effects=effects,
            readings=readings,
            cancel=cancel,
        )
        trial_cv = cross_validate(trial.system, readings, redundant)
        left = unexplained_lines(trial, trial_cv, options.alpha) - clean
        if not left:
            fit, cv, chosen = trial, trial_cv, spacing_mm
            break
        refused[spacing_mm] = tuple(sorted(left))
    # spacings that predict as well (within the tie) are fits the plan cannot rank below the
    # chosen one: their moves of the 21 errors widen its covariance (:func:`with_shape_doubt`);
    # the finest spacing tried, where coarser than the chosen one, by what the chosen basis
    # misses of each function's shape against it (:func:`_shape_missed`) instead, not twice
    finest = min(fits)
    rivals = [
        fits[s]
        for s in ratio
        if s not in (chosen, finest)
        and s not in refused
        and (ratio[s] <= ratio[chosen] * (1.0 + options.tie) or um[s] < um[chosen])
    ]
    moves = [in_basis(r.model.parameters[None, :], r.model, fit.model)[0] for r in rivals]
    doubt = np.reshape([m - fit.model.parameters for m in moves], (-1, fit.model.parameter_count))
    missed, missed_rms = (
        _shape_missed(fit, fits[finest]) if finest != chosen else (np.zeros((0, 0)), {})
    )
    return fit, cv, SpacingChoice(
        chosen, reference, um, rms, cv.method, refused, doubt, missed, missed_rms, finest
    )


def _shape_missed(
    fit: Identification, finest: Identification
) -> tuple[FloatArray, dict[str, float]]:
    """What ``fit``'s coarser basis misses of each error function's shape, measured against the
    fit at the finest spacing tried (``finest``): moves of ``fit``'s parameters (rows), one per
    function whose two fits differ beyond what their noise explains, and per such function the
    RMS of the miss (µm or µrad over the stroke).

    A coarser basis wins the cross-validation where what it averages of the noise outweighs
    what it misses of a bend: the miss stays, the same in every re-measurement, and the fit's
    covariance, which holds the noise alone, does not cover it (blind 590005, demo plan, clean,
    0.18 µm noise, measured again with fresh noise: 150 mm kept in some draws, and over eight
    the Z positioning missed the truth by 3.0 times the RMS its band stated; with the basis held
    at 50 mm, 0.8 times). The two fits differ by that miss and by the noise the finer basis
    follows and the coarser one averages. A finer basis holds nearly every shape of a coarser
    one, so that noise's covariance over the stroke is about the difference of the two fits'
    (both at the finest fit's σ: the coarser fit's own σ holds some of the miss), and its mean
    square is about that difference's trace: what the mean square difference exceeds it by
    estimates the miss's square, unbiased before it is clamped at zero. A function counts where
    it exceeds it by more than twice what that noise alone spreads it by (the standard
    deviation of a Gaussian vector's mean square, √(2 Σ λ²) over the eigenvalues λ of its
    covariance), so that a basis missing nothing widens few bands. Its move towards the finest
    fit, least-squares in ``fit``'s basis and gauge, is scaled to that RMS: added to the
    covariance as its outer product, it widens the band by the RMS of the miss.

    ``finest`` is the loop's own fit where the identification's spacing is the finest of the
    loop's spacings (the default), else a first-order trial at that spacing (what the
    nonlinear refinement adds is second order, far below a band); its covariance is statistical
    either way."""
    model = fit.model
    at_finest_sigma = (finest.sigma_scale / fit.sigma_scale) ** 2 if fit.sigma_scale > 0 else 1.0
    rows: list[FloatArray] = []
    sizes: dict[str, float] = {}
    for eid in AXIS_ERROR_IDS:
        axis = str(ERROR_INFO[eid].axis)
        low, high = model.machine.stroke(axis)
        q = np.linspace(low, high, STROKE_POINTS)
        values, covariances = [], []
        for f, scale in ((fit, at_finest_sigma), (finest, 1.0)):
            sl = f.model.parameter_slices[eid]
            design = f.model.functions[eid].basis.design(q)
            values.append(design @ f.model.parameters[sl])
            covariances.append(scale * design @ f.covariance[sl, sl] @ design.T)
        difference = values[1] - values[0]
        between = covariances[1] - covariances[0]
        expected = float(np.trace(between)) / len(q)
        spread = float(np.sqrt(2.0 * np.sum(np.linalg.eigvalsh(between) ** 2))) / len(q)
        square = float(np.mean(difference**2)) - expected
        if square <= 2.0 * spread:
            continue
        coefficients = fit_in_gauge(model, eid, q, difference)
        shown = float(np.sqrt(np.mean((model.functions[eid].basis.design(q) @ coefficients) ** 2)))
        if shown <= 0.0:
            continue
        row = np.zeros(model.parameter_count)
        row[model.parameter_slices[eid]] = coefficients * np.sqrt(square) / shown
        rows.append(row)
        sizes[eid] = float(np.sqrt(square))
    return np.reshape(rows, (-1, model.parameter_count)), sizes


def in_basis(moves: FloatArray, old: ErrorModel, new: ErrorModel) -> FloatArray:
    """Moves (rows) of ``old``'s parameters as the nearest moves of ``new``'s, whose functions
    have other bases: each function's change least-squares on a fine grid of its stroke within
    ``new``'s gauge, the squareness errors as they are. A move of a gauged fit is gauged, but
    where a coarser basis cannot follow its shape, the free least-squares fit leaves it a value
    at the reference position (blind 21101, a 75 mm rival fit's EZY carried to the kept 150 mm:
    3.8 µm there, 2.1 µm RMS), a move no fit of ``new`` can make, which would widen a band where
    the gauge holds it at zero."""
    out = np.zeros((len(moves), new.parameter_count))
    was, now = old.parameter_slices, new.parameter_slices
    for eid in AXIS_ERROR_IDS:
        low, high = old.machine.stroke(str(ERROR_INFO[eid].axis))
        q = np.linspace(low, high, STROKE_POINTS)
        change = old.functions[eid].basis.design(q) @ moves[:, was[eid]].T
        out[:, now[eid]] = fit_in_gauge(new, eid, q, change).T
    for eid in SQUARENESS_IDS:
        out[:, now[eid]] = moves[:, was[eid]]
    return out


def fit_in_gauge(model: ErrorModel, eid: str, q: FloatArray, values: FloatArray) -> FloatArray:
    """The coefficients of ``model``'s function ``eid`` nearest ``values`` at q (least squares;
    one column per column of ``values``) among those its gauge admits: zero at the reference
    position and, for a straightness, no least-squares slope over the stroke."""
    basis = model.functions[eid].basis
    axis = str(ERROR_INFO[eid].axis)
    null = gauge_null_space(basis, model.machine.reference(axis), ERROR_INFO[eid].is_straightness)
    return null @ np.linalg.lstsq(basis.design(q) @ null, values, rcond=None)[0]


def with_shape_doubt(
    fit: Identification, deltas: Sequence[FloatArray], share: float = 0.5
) -> Identification:
    """``fit`` with the errors' covariance widened by ``share`` of the outer product of each
    move (one per row): by half, of a kept surface or set-up effect to a rival that fits as well
    (:func:`unsettled`, :func:`alike`, :func:`interchangeable`); in full, of a function by
    what its basis misses (:func:`_shape_missed`). In the model's parameters and in the fit's
    normal inverse alike (a refined function's covariance is made from the latter)."""
    moves = [move for d in deltas for move in np.atleast_2d(d) if np.any(move)]
    if not moves:
        return fit
    widening = sum(share * np.outer(d, d) for d in moves)
    gauge = Gauge.for_model(fit.model).matrix  # orthonormal columns: parameters = gauge @ θ
    size = gauge.shape[1]
    normal_inverse = fit.normal_inverse.copy()
    normal_inverse[:size, :size] += gauge.T @ widening @ gauge / max(fit.sigma_scale, 1e-300) ** 2
    return replace(fit, covariance=fit.covariance + widening, normal_inverse=normal_inverse)
