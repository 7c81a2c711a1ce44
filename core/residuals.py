"""The closed loop: find structure in the residual, trace it to an effect, add it, refit, report.

1. Identify the 21 errors; the residual is measured − model, per reading.
2. Diagnose: every effect of the catalogue (core/effects.py) that the plan could reveal is tested
   against the residual with an F-test of its columns *after* projecting out what the current model
   can already absorb (so an effect the model mimics scores nothing). Searched quantities (the
   period of a cyclic error, the place of a local defect, the time constant of a drift) are
   scanned and their false-alarm level corrected for the number of trials (Bonferroni).
3. Trace: each finding names the effect, the axis and its evidence (F, false-alarm level,
   magnitude, where it shows most).
4. Add: the strongest findings are refitted; one is kept only if the cross-validated error
   (leave-one-line-out when every line is redundant, held-out blocks of targets otherwise)
   improves by a clear margin. Repeat until nothing more is found.
5. Report before/after, the effects kept and rejected, and what is still unexplained — located and
   sized, never force-fitted.

Residuals along a line are autocorrelated, so the F-test only proposes; cross-validation decides.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy import sparse

from .effects import (
    AbbeOffset,
    Cosine,
    CrossAxis,
    Cyclic,
    Effect,
    HigherOrder,
    LocalDefect,
    Reversal,
    ThermalDrift,
)
from .errors import AXIS_ERROR_IDS, ErrorModel
from .identify import (
    CrossValidation,
    Identification,
    IdentifyOptions,
    cross_validate,
    identify,
    residual_rms,
)
from .machine import AXES, AXIS_INDEX
from .measurement import Measurement
from .progress import CancelToken, ProgressCallback, check, report
from .readings import Readings, flatten

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class LoopOptions:
    """Thresholds of the loop.

    alpha : family-wise false-alarm level for proposing an effect (Bonferroni over all tests).
    margin : relative improvement of the cross-validated RMS an effect must bring to be kept.
    candidates_per_step : how many of the strongest findings are refitted and cross-validated.
    """

    alpha: float = 1e-4
    margin: float = 0.03
    candidates_per_step: int = 3
    max_steps: int = 8
    identify: IdentifyOptions = field(default_factory=IdentifyOptions)


@dataclass(frozen=True, eq=False)
class Finding:
    """A diagnostic result: an effect that would explain part of the residual."""

    effect: Effect
    f_statistic: float
    log10_false_alarm: float  # log10 of the false-alarm level, corrected for the trials
    trials: int
    magnitude_um: float
    detectability: float  # share of the effect's signal the current model cannot absorb
    where: str

    def evidence(self) -> dict[str, object]:
        return {
            "statistic": "F",
            "F": round(self.f_statistic, 3),
            "log10_false_alarm": round(self.log10_false_alarm, 2),
            "trials": self.trials,
            "magnitude_um": round(self.magnitude_um, 4),
            "detectability": round(self.detectability, 3),
            "where": self.where,
        }


@dataclass(frozen=True)
class Step:
    step: int
    finding: Finding
    kept: bool
    reason: str
    rms_before: float
    rms_after: float
    cv_before: float
    cv_after: float
    parameters: dict[str, object]
    per_group_before: dict[str, float]
    per_group_after: dict[str, float]


@dataclass(frozen=True)
class Unexplained:
    where: str
    description: str
    magnitude_um: float


@dataclass(frozen=True, eq=False)
class LoopResult:
    base: Identification
    final: Identification
    cv_before: CrossValidation
    cv_after: CrossValidation
    steps: tuple[Step, ...]
    unexplained: tuple[Unexplained, ...]
    warnings: tuple[str, ...]

    @property
    def kept(self) -> tuple[Effect, ...]:
        return tuple(self.final.effects)  # type: ignore[arg-type]

    def effects_report(self) -> list[dict[str, object]]:
        out = []
        for effect, values, cov in zip(
            self.final.effects,
            self.final.effect_parameters,
            self.final.effect_covariances,
            strict=True,
        ):
            assert isinstance(effect, Effect)
            out.append(
                {
                    "kind": effect.kind,
                    "axis": effect.axis,
                    "parameters": effect.parameters(values, cov),
                }
            )
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
                    "effect": {
                        "kind": effect.kind,
                        "axis": effect.axis,
                        "label": effect.label,
                        "parameters": s.parameters,
                        "evidence": s.finding.evidence(),
                    },
                    "kept": s.kept,
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
            "cv_rms_um": {
                "before_loop": self.cv_before.rms_um,
                "after_loop": self.cv_after.rms_um,
                "method": self.cv_after.method,
            },
            "unexplained": [
                {"where": u.where, "description": u.description, "magnitude_um": u.magnitude_um}
                for u in self.unexplained
            ],
            "warnings": list(self.warnings),
        }


# --------------------------------------------------------------------------------------------
# Residual groups
# --------------------------------------------------------------------------------------------


def line_group(readings: Readings, index: int) -> str:
    """ "X", "Y", "Z" for a line whose reading is along one machine axis, "diagonal", "angular"."""
    spec = readings.lines[index].spec
    if spec.quantity == "angular":
        return "angular"
    axis = np.asarray(spec.direction if spec.quantity == "linear" else spec.sensitive, float)
    k = int(np.argmax(np.abs(axis)))
    return AXES[k] if abs(axis[k]) > 0.999 else "diagonal"


def group_rms(identification: Identification) -> dict[str, float]:
    readings = identification.readings
    groups: dict[str, list[FloatArray]] = {}
    for index in range(len(readings.lines)):
        groups.setdefault(line_group(readings, index), []).append(
            identification.residual[readings.line == index]
        )
    return {g: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for g, v in sorted(groups.items())}


# --------------------------------------------------------------------------------------------
# The F-test of candidate columns against the current fit
# --------------------------------------------------------------------------------------------


class _Tester:
    """Tests candidate columns against an identification's residual."""

    def __init__(self, identification: Identification) -> None:
        self.ident = identification
        system = identification.system
        self.system = system
        self.w = system.weights
        self.r = identification.residual
        self.wr = self.w * self.r
        n_targets = system.target_design.shape[0]
        n = len(self.r)
        # readings -> targets summation as a sparse matrix (np.add.at is far slower)
        self.to_targets = sparse.csr_matrix(
            (np.ones(n), (system.target_of_reading, np.arange(n))), shape=(n_targets, n)
        )
        dof = max(len(self.r) - identification.identifiability.rank, 1)
        self.dof = dof
        self.sigma2 = float(np.sum(self.w * self.r**2) / dof)

    def test(self, columns: FloatArray) -> tuple[float, float, float, FloatArray]:
        """(F, log10 false-alarm probability, detectability, parameters) of candidate columns.

        The columns are projected onto what the current model cannot absorb (S = DᵀWD −
        DᵀWA·(AᵀWA)⁺·AᵀWD); columns it absorbs entirely (e.g. the rigid part of a cross-axis
        term, which a roll reproduces) carry no evidence and are left out.
        """
        d = np.atleast_2d(columns.T).T
        system = self.system
        wd = d * self.w[:, None]
        agg = self.to_targets @ wd
        atwd = np.vstack([system.target_design.T @ agg, system.effect_design.T @ wd])
        dtwd = d.T @ wd
        s = dtwd - atwd.T @ self.ident.normal_inverse @ atwd
        diag = np.diag(dtwd)
        share = np.where(diag > 0, np.diag(s) / np.where(diag > 0, diag, 1.0), 0.0)
        useful = share > 1e-4
        beta = np.zeros(d.shape[1])
        if not useful.any():
            return 0.0, 0.0, 0.0, beta
        detect = float(np.min(share[useful]))
        values, vectors = np.linalg.eigh(s[np.ix_(useful, useful)])
        keep = values > 1e-9 * max(values.max(initial=0.0), 1e-300)
        k = int(keep.sum())
        if k == 0:
            return 0.0, 0.0, detect, beta
        proj = vectors[:, keep].T @ (d.T @ self.wr)[useful]
        delta = float(np.sum(proj**2 / values[keep]))
        beta[useful] = vectors[:, keep] @ (proj / values[keep])
        f_stat = (delta / k) / self.sigma2
        from scipy import stats  # slow to import: only when a candidate is tested

        log_p = float(stats.f.logsf(f_stat, k, self.dof))
        if not np.isfinite(log_p):
            # far in the tail: the χ² limit, then its leading exponential term
            log_p = float(stats.chi2.logsf(f_stat * k, k))
            if not np.isfinite(log_p):
                log_p = -0.5 * f_stat * k
        return float(f_stat), log_p / np.log(10.0), detect, beta

    def score(self, columns: FloatArray) -> float:
        """Cheap screening statistic: residual correlation ignoring the model's absorption."""
        d = columns.reshape(len(self.r), -1)
        g = d.T @ self.wr
        dtwd = np.einsum("ni,n,ni->i", d, self.w, d)
        return float(np.sum(g**2 / np.maximum(dtwd, 1e-300)) / self.sigma2)


# --------------------------------------------------------------------------------------------
# Diagnostics
# --------------------------------------------------------------------------------------------


def _moving_axes(readings: Readings) -> dict[str, bool]:
    """Axes that move (with both approach directions) in at least one displacement line."""
    out = {}
    for axis in AXES:
        k = AXIS_INDEX[axis]
        moving = False
        for line in readings.lines:
            if line.spec.quantity == "angular":
                continue
            if (
                abs(line.spec.direction[k]) > 1e-6
                and len(set(line.data.run_direction.tolist())) > 1
            ):
                moving = True
        out[axis] = moving
    return out


def _where(readings: Readings, columns: FloatArray, beta: FloatArray) -> str:
    """The line where an effect's fitted contribution is largest."""
    contribution = np.abs(columns @ beta) if columns.ndim == 2 else np.abs(columns * beta[0])
    if not np.any(contribution > 0):
        return "nowhere"
    i = int(np.argmax(contribution))
    line = readings.lines[int(readings.line[i])]
    return f"line {line.name} at {readings.target_mm[i]:.1f} mm"


def diagnose(
    identification: Identification,
    exclude: Sequence[tuple[str, str | None, str]] = (),
) -> tuple[list[Finding], list[str]]:
    """Test every effect the plan could reveal; return findings (strongest first) and warnings."""
    readings = identification.readings
    model = identification.model
    machine = model.machine
    tester = _Tester(identification)
    findings: list[Finding] = []
    warnings: list[str] = []
    excluded_kind_axis = {(k, a) for k, a, _ in exclude}
    excluded = set(exclude)

    def add(effect: Effect) -> None:
        _append(findings, tester, effect, readings, model, excluded)

    moving = _moving_axes(readings)
    step = _typical_step(readings)
    for axis in AXES:
        low, high = machine.stroke(axis)
        ref = machine.reference(axis)
        moves = any(abs(line.spec.direction[AXIS_INDEX[axis]]) > 1e-6 for line in readings.lines)
        if not moves:
            continue
        if moving[axis] and ("reversal", axis) not in excluded_kind_axis:
            add(Reversal(axis, 0, (low, high)))
        elif moving[axis]:
            add(Reversal(axis, 1, (low, high)))
        if ("cyclic", axis) not in excluded_kind_axis:
            lead = machine.screw_lead_mm.get(axis)
            if lead:
                effect = Cyclic(axis, lead, (1, 2), ref)
                columns = effect.design(readings, model)
                _, _, detect, _ = tester.test(columns)
                if detect < 0.2:
                    warnings.append(
                        f"the targets of the lines along {axis} (about every {step[axis]:.3g} mm) "
                        f"cannot reveal a cyclic error at the {lead:g} mm screw lead: it is "
                        "aliased into the smooth error functions; use steps of 1–3 mm over a "
                        "few leads or irregular target spacing"
                    )
                add(effect)
            _search_period(
                tester, readings, model, axis, ref, step[axis], high - low, findings, excluded
            )
        if ("thermal_drift", axis) not in excluded_kind_axis:
            temp = readings.material_temp_c
            if np.all(np.isfinite(temp)) and np.ptp(temp) > 0.05:
                add(ThermalDrift(axis, "temperature", reference_mm=ref))
            else:
                taus = [1800.0, 3600.0, 7200.0, 14400.0, 28800.0, 57600.0]
                drifts = [ThermalDrift(axis, "time", tau, ref) for tau in taus]
                scores = [tester.test(d.design(readings, model))[0] for d in drifts]
                best_drift = drifts[int(np.argmax(scores))]
                _append(
                    findings,
                    tester,
                    best_drift,
                    readings,
                    model,
                    excluded,
                    len(taus),
                    "all lines along " + axis,
                )
        _search_local(tester, readings, model, axis, findings, excluded)
    for direction in AXES:
        for along in AXES:
            for across in AXES:
                if len({direction, along, across}) < 2 or along == across:
                    continue
                if ("cross_axis", direction) in excluded_kind_axis:
                    continue
                add(CrossAxis(direction, along, across, machine))
    for eid in AXIS_ERROR_IDS:
        basis = model.functions[eid].basis
        spacing = getattr(basis, "breakpoints_mm", None)
        current = float(np.diff(spacing).mean()) if spacing else 50.0
        add(HigherOrder(eid, current / 2.0, machine, current))
    for index, line in enumerate(readings.lines):
        if line.spec.quantity == "angular":
            continue
        add(AbbeOffset(index, line.name))
        if line.spec.quantity == "linear":
            add(Cosine(index, line.name))
    total = len(findings)
    # family-wise correction over everything tested in this step
    findings = [
        replace(f, log10_false_alarm=_corrected(f.log10_false_alarm, total)) for f in findings
    ]
    findings.sort(key=lambda f: (f.log10_false_alarm, -f.f_statistic))
    return findings, warnings


def _append(
    findings: list[Finding],
    tester: _Tester,
    effect: Effect,
    readings: Readings,
    model: ErrorModel,
    excluded: set[tuple[str, str | None, str]],
    trials: int = 1,
    where: str | None = None,
) -> None:
    """Test one candidate (unless already kept or rejected) and keep it as a finding when the
    model cannot absorb it all."""
    if effect.key in excluded:
        return
    columns = effect.design(readings, model)
    if not np.any(columns):
        return
    f, log10_p, detect, beta = tester.test(columns)
    if detect <= 0.0:
        return
    place = where if where is not None else _where(readings, columns, beta)
    findings.append(
        Finding(
            effect, f, _corrected(log10_p, trials), trials, effect.magnitude_um(beta), detect, place
        )
    )


def _corrected(log10_p: float, trials: int) -> float:
    """Bonferroni in log10: min(1, p·trials)."""
    return min(0.0, log10_p + float(np.log10(max(trials, 1))))


def _typical_step(readings: Readings) -> dict[str, float]:
    out = {}
    for axis in AXES:
        k = AXIS_INDEX[axis]
        steps = [
            float(np.median(np.diff(line.data.targets_mm)) * abs(line.spec.direction[k]))
            for line in readings.lines
            if abs(line.spec.direction[k]) > 1e-6 and len(line.data.targets_mm) > 1
        ]
        out[axis] = float(np.median(steps)) if steps else float("nan")
    return out


def _search_period(
    tester: _Tester,
    readings: Readings,
    model: ErrorModel,
    axis: str,
    ref: float,
    step: float,
    span: float,
    findings: list[Finding],
    excluded: set[tuple[str, str | None, str]],
) -> None:
    """Least-squares periodogram along an axis: periods from twice the step (or 2 mm) to a
    quarter of the stroke; the best one is a finding with its false-alarm level."""
    shortest = max(2.0, 2.0 * step if np.isfinite(step) else 2.0)
    longest = span / 4.0
    if longest <= shortest:
        return
    periods = np.geomspace(shortest, longest, 240)
    k = AXIS_INDEX[axis]
    proj = readings.projection[:, k] * ~readings.is_angular
    q = readings.position_mm[:, k]
    best = None
    for period in periods:
        phase = 2 * np.pi * (q - ref) / period
        columns = proj[:, None] * np.stack([np.sin(phase), np.cos(phase)], axis=-1)
        score = tester.score(columns)
        if best is None or score > best[0]:
            best = (score, period)
    if best is None:
        return
    # independent frequencies over the band: span/shortest − span/longest
    trials = max(1, int(span / shortest - span / longest))
    effect = Cyclic(axis, float(best[1]), (1,), ref)
    _append(
        findings,
        tester,
        effect,
        readings,
        model,
        excluded,
        trials,
        f"along {axis}, period {best[1]:.3g} mm",
    )


def _search_local(
    tester: _Tester,
    readings: Readings,
    model: ErrorModel,
    axis: str,
    findings: list[Finding],
    excluded: set[tuple[str, str | None, str]],
) -> None:
    """A scan of Gaussian bumps along an axis, in each direction, at several widths."""
    machine = model.machine
    low, high = machine.stroke(axis)
    k = AXIS_INDEX[axis]
    q = readings.position_mm[:, k]
    for direction in AXES:
        proj = readings.projection[:, AXIS_INDEX[direction]] * ~readings.is_angular
        if not np.any(proj):
            continue
        best = None
        trials = 0
        for width in (4.0, 8.0, 16.0):
            centers = np.arange(low + width, high - width + 1e-9, width)
            trials += len(centers)
            for center in centers:
                s = (q - center) / width
                column = proj * np.exp(-0.5 * s * s)
                score = tester.score(column)
                if best is None or score > best[0]:
                    best = (score, center, width)
        if best is None:
            continue
        effect = LocalDefect(axis, direction, float(best[1]), float(best[2]))
        _append(
            findings,
            tester,
            effect,
            readings,
            model,
            excluded,
            trials,
            f"{axis} at {best[1]:.0f} mm, width {best[2]:.0f} mm, in {direction}",
        )


# --------------------------------------------------------------------------------------------
# Unexplained structure
# --------------------------------------------------------------------------------------------


def unexplained(
    identification: Identification,
    cross_validation: CrossValidation | None = None,
    alpha: float = 1e-4,
) -> list[Unexplained]:
    """Lines whose run-averaged residual is larger than their repeatability allows.

    For each line and target the mean residual over runs is compared with σ/√runs (χ² test over
    the targets, Bonferroni over the lines) on the fit's residual; a significant line is reported
    with where its largest systematic residual sits and how large it is. With a cross-validation,
    the place and size come from its held-out residuals: a structure on one line is then sized as
    that line shows it, not as what is left after the fit bent the model partly towards it.
    """
    readings = identification.readings
    held_out = identification.residual if cross_validation is None else cross_validation.residual
    out = []
    count = len(readings.lines)
    for index, line in enumerate(readings.lines):
        mask = readings.line == index
        targets = readings.target[mask]
        r = identification.residual[mask]
        sigma = float(readings.sigma[mask][0])
        k = int(targets.max()) + 1
        sums = np.bincount(targets, weights=r, minlength=k)
        n = np.bincount(targets, minlength=k)
        valid = n > 0
        means = sums[valid] / n[valid]
        from scipy import stats

        chi2 = float(np.sum(means**2 * n[valid]) / sigma**2)
        p = float(stats.chi2.sf(chi2, int(valid.sum()))) * count
        if p >= alpha:
            continue
        # place and size from the held-out residual (the same as the fit's without one)
        sums = np.bincount(targets, weights=held_out[mask], minlength=k)
        means = sums[valid] / n[valid]
        worst = int(np.argmax(np.abs(means)))
        position = float(line.data.targets_mm[np.flatnonzero(valid)[worst]])
        unit = "µrad" if line.spec.quantity == "angular" else "µm"
        magnitude = float(np.max(np.abs(means)))
        rms = float(np.sqrt(np.mean(means**2)))
        out.append(
            Unexplained(
                where=f"line {line.name} at {position:.1f} mm",
                description=(
                    f"systematic residual on {line.spec.quantity} line {line.name}: RMS "
                    f"{rms:.3g} {unit} over its targets, peak {magnitude:.3g} {unit} at "
                    f"{position:.1f} mm, beyond its repeatability ({sigma:.3g} {unit}); no effect "
                    "of the catalogue explains it"
                ),
                magnitude_um=magnitude,
            )
        )
    return out


# --------------------------------------------------------------------------------------------
# The loop
# --------------------------------------------------------------------------------------------


def close_loop(
    measurement: Measurement,
    options: LoopOptions | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
) -> LoopResult:
    """Identify, then add effects from the catalogue while cross-validation says they help."""
    options = options or LoopOptions()
    readings = flatten(measurement)
    report(progress, 0.0, "identifying the 21 errors")
    base = identify(measurement, options.identify, readings=readings, cancel=cancel)
    redundant = base.identifiability.redundant_lines
    cv_base = cross_validate(base.system, readings, redundant)
    refit_options = replace(options.identify, redundancy=False, max_iterations=3)
    current, cv = base, cv_base
    kept: list[Effect] = []
    steps: list[Step] = []
    warnings: list[str] = []
    rejected: set[tuple[str, str | None, str]] = set()
    for number in range(1, options.max_steps + 1):
        check(cancel)
        report(progress, 0.1 + 0.8 * number / (options.max_steps + 1), f"loop step {number}")
        findings, step_warnings = diagnose(current, [e.key for e in kept] + sorted(rejected))
        warnings += [w for w in step_warnings if w not in warnings]
        proposals = [f for f in findings if f.log10_false_alarm < np.log10(options.alpha)]
        if not proposals:
            break
        trials = []
        for finding in proposals[: options.candidates_per_step]:
            check(cancel)
            effects = _with(kept, finding.effect)
            refit = identify(
                measurement,
                refit_options,
                effects=effects,
                readings=readings,
                cancel=cancel,
                initial=current.model,
            )
            cv_new = cross_validate(refit.system, readings, redundant)
            trials.append(
                (
                    cv_new.rms_um if np.isfinite(cv_new.rms_um) else cv_new.rms_urad,
                    finding,
                    refit,
                    cv_new,
                )
            )
        trials.sort(key=lambda t: t[0])
        score, finding, refit, cv_new = trials[0]
        before = cv.rms_um if np.isfinite(cv.rms_um) else cv.rms_urad
        improvement = 1.0 - score / before if before > 0 else 0.0
        keep = improvement >= options.margin
        index = list(refit.effects).index(finding.effect)
        params = finding.effect.parameters(
            refit.effect_parameters[index], refit.effect_covariances[index]
        )
        reason = (
            f"cross-validated RMS {before:.4g} → {score:.4g} ({100 * improvement:.1f} % better)"
        )
        if not keep:
            reason += f"; below the {100 * options.margin:.0f} % margin: rejected"
        steps.append(
            Step(
                number,
                finding,
                keep,
                reason,
                residual_rms(current)[0],
                residual_rms(refit)[0],
                cv.rms_um,
                cv_new.rms_um,
                params,
                group_rms(current),
                group_rms(refit),
            )
        )
        for _, other, _, _ in trials[1:]:
            rejected.add(other.effect.key)
        if not keep:
            rejected.add(finding.effect.key)
            if all(t[0] >= before * (1 - options.margin) for t in trials):
                break
            continue
        kept = list(refit.effects)  # type: ignore[arg-type]
        current, cv = refit, cv_new
    report(progress, 0.95, "looking for what is still unexplained")
    leftover = unexplained(current, cv)
    report(progress, 1.0, "loop closed")
    return LoopResult(base, current, cv_base, cv, tuple(steps), tuple(leftover), tuple(warnings))


def _with(kept: list[Effect], effect: Effect) -> list[Effect]:
    """Kept effects plus a new one; a position-dependent reversal replaces the constant one."""
    out = [
        e
        for e in kept
        if not (isinstance(effect, Reversal) and isinstance(e, Reversal) and e.axis == effect.axis)
    ]
    return out + [effect]


__all__ = [
    "Finding",
    "LoopOptions",
    "LoopResult",
    "close_loop",
    "diagnose",
    "unexplained",
]
