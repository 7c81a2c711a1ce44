"""The refinement of kept effects: a cycle's period and a drift's time constant estimated again
with the other kept effects in the model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import stats
from scipy.optimize import minimize_scalar

from .effects import Cyclic, Effect, ThermalDrift
from .errors import ErrorModel
from .identify import CrossValidation, Identification
from .loop_compare import Fitter, cv_compared, later_step
from .loop_records import Step
from .loop_tester import Tester, noise_variance
from .machine import Machine


def refine_kept(
    fit: Fitter,
    current: Identification,
    cv: CrossValidation,
    kept: list[Effect],
    base: Identification,
    steps: list[Step],
    number: int,
    alpha: float,
) -> tuple[Identification, CrossValidation, list[Effect]]:
    """Estimate again the searched quantity of every kept effect (a cycle's period, a drift's
    time constant) with all the others in the model. Each was estimated when the model still
    lacked the effects kept after it: two cycles of near periods on axes that share lines, or a
    cycle next to a drift, bias each other's estimate, and a cycle whose period is off by a
    fraction of the stroke's resolution slips its phase over the stroke and leaves structure a
    finer function would then be kept for. The re-estimate stays within the resolution of the
    first (it is the same effect, placed better) and replaces it only when the cross-validated
    error says it is better."""
    for effect in list(kept):
        # a cycle at the screw lead too (:func:`re_estimate`)
        if not (
            isinstance(effect, Cyclic) or (isinstance(effect, ThermalDrift) and effect.searched)
        ):
            continue
        without = fit_without(effect, kept, fit, current.model, base)
        better = re_estimate(
            effect, without, current.model.machine, alpha, noise_variance(current)
        )
        if better is None:
            continue
        trial_kept = [better if e is effect else e for e in kept]
        refit, cv_new = fit(trial_kept, current.model)
        before, after, _ = cv_compared(cv, cv_new, current, other_fit=refit)
        if not after < before:
            continue
        reason = (
            f"{effect.label} estimated again with the other kept effects in the model: "
            f"{searched_value(effect)} → {searched_value(better)}; cross-validated RMS "
            f"{before:.4g} → {after:.4g}"
        )
        steps.append(
            later_step(
                number, better, refit, (refit, cv_new), True, reason, (current, cv), "refine"
            )
        )
        kept, current, cv = trial_kept, refit, cv_new
    return current, cv, kept


def fit_without(
    effect: Effect,
    effects: list[Effect],
    fit: Fitter,
    initial: ErrorModel,
    base: Identification | None,
) -> Tester:
    """A tester of what the refit with ``effects`` less ``effect`` leaves (``base``, the fit of
    the 21 errors alone, when nothing else is left), to place ``effect``'s searched quantity in."""
    rest = [e for e in effects if e is not effect]
    return Tester(fit.identify(rest, initial) if rest or base is None else base)


def searched_value(effect: Effect) -> str:
    if isinstance(effect, Cyclic):
        return f"period {effect.period_mm:.5g} mm"
    assert isinstance(effect, ThermalDrift)
    return f"τ {effect.time_constant_s / 60:.4g} min"


def re_estimate(
    effect: Effect, tester: Tester, machine: Machine, alpha: float, sigma2: float
) -> Effect | None:
    """The effect with its searched quantity placed where it removes most of what the model
    without it leaves, within one resolution step of its present value; None when that is no
    better than the present value beyond the noise: the χ² it removes must grow past the
    ``alpha`` level of one degree of freedom, counted in the σ² of the fit with every effect in
    (``sigma2``, :func:`noise_variance`). ``tester``'s σ² holds what the effect leaves while
    it is out of the model and can be a hundred times the noise, so a move worth hundreds of
    the noise's σ² reads as a fraction of a per cent of the effect's own χ² (blind 56101, plan
    of the demo: a 4.4 µm cycle of X kept at 23.509 mm beside a drift of X; at 23.533 mm (truth
    23.535) the held-out error fell 0.3242 → 0.3175 µm, where a false bump of X at 26 mm had
    taken up the phase the period lost over the stroke). The caller keeps the move only when
    the held-out error says it is better.

    A cycle at the screw lead moves off it the same way, its period then a parameter more: it
    is another cycle, near the lead, that the lead's candidate took (blind 38058: a cycle of
    15.84 mm on Z kept at the 16 mm lead, a quarter of a period out of phase over the stroke,
    the drift of X then below the margin), and its period is a searched one."""

    def gain(candidate: Effect) -> float:
        return tester.drop(candidate.design(tester.ident.readings, tester.ident.model))

    if isinstance(effect, Cyclic):
        low, high = machine.stroke(effect.axis)
        frequency = 1.0 / effect.period_mm
        resolution = 1.0 / (high - low)
        bounds = (max(frequency - resolution, 0.5 * frequency), frequency + resolution)

        def make(x: float) -> Effect:
            return replace(effect, period_mm=1.0 / x)

        tolerance = 1e-3 * resolution
    elif isinstance(effect, ThermalDrift):
        log_tau = float(np.log(effect.time_constant_s))
        bounds = (log_tau - 1.0, log_tau + 1.0)
        tolerance = 1e-3

        def make(x: float) -> Effect:
            return replace(effect, time_constant_s=float(np.exp(x)))

    else:
        return None
    now = gain(effect)
    found = minimize_scalar(
        lambda x: -gain(make(x)), bounds=bounds, method="bounded", options={"xatol": tolerance}
    )
    if not np.isfinite(found.fun):
        return None
    gained = (-found.fun - now) * tester.sigma2 / sigma2
    if gained < stats.chi2.isf(alpha, 1):
        return None
    if isinstance(effect, Cyclic) and not effect.searched:
        return replace(effect, period_mm=1.0 / float(found.x), period_searched=True)
    return make(float(found.x))
