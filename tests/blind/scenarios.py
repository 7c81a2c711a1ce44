"""Blind scenarios: a random machine, effects and a simulated laser session over a plan, written as
Renishaw-style logs + plan.toml, with a JSON ground-truth manifest.

    make_scenario(seed) -> {"truth": manifest, "plan_toml": text, "logs": {relative path: text}}
    write_scenario(seed, folder) -> (plan path, manifest)       # also writes folder/truth.json
    build_scenario(seed) -> Scenario                            # the live objects, for tests

Run ``python -m tests.blind SEED FOLDER`` from the repository root to write one scenario.
Pure numpy + tomllib; never imports volucal.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from . import effects as fx
from .laser import (
    LineSchedule,
    PlanSpec,
    Session,
    draw_settings,
    file_times,
    measure_line,
    plan_text,
    read_plan,
    rtl_text,
    schedule_session,
)
from .machine import AXES, PAPER_CHAIN, Machine, chain_axes, random_machine
from .rigid_fit import RigidProjector

REPO = Path(__file__).resolve().parents[2]
#: Plans measured, with their weights.
PLANS = {
    "resources/demo/plan.toml": 0.35,
    "resources/plans/direct.toml": 0.30,
    "resources/plans/twelve-line.toml": 0.20,
    "resources/plans/displacement-only.toml": 0.15,
}
CATEGORIES = {"clean": 0.2, "effects": 0.6, "outside": 0.2}
CATALOGUE = ("reversal", "cyclic", "thermal_drift", "abbe_offset", "cosine", "cross_axis", "local")
OUTSIDE = ("scale_oscillation", "reflector_twitch", "laser_random_walk", "beam_interruption",
           "column_bending", "time_periodic")
#: Draws of one kind's parameters, and kinds tried, before an effect is kept as not visible.
MAX_ATTEMPTS = 12
KIND_TRIES = 3
SCHEMA = "volucal-blind-scenario/1"


@dataclass
class Scenario:
    seed: int
    plan_source: str
    plan: PlanSpec
    category: str
    machine: Machine
    session: Session
    effects: list[fx.Effect]
    effect_records: list[dict]
    noise: float
    material_logged: bool
    deviations: dict[str, np.ndarray]
    environment: dict


# --------------------------------------------------------------------------------------------
# Visibility
# --------------------------------------------------------------------------------------------


def _line_peak(line: LineSchedule, diff: np.ndarray) -> float:
    """max |diff − fit| with fit a least-squares constant (plus a slope on straightness lines)."""
    y = diff.reshape(-1)
    along = np.tile(line.targets_mm, line.runs)
    columns = [np.ones_like(y)]
    if line.spec.quantity == "straightness":
        columns.append(along)
    a = np.stack(columns, axis=1)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    return float(np.max(np.abs(y - a @ coef)))


def visibility(machine: Machine, session: Session, effect: fx.Effect,
               baseline: dict[str, np.ndarray],
               projector: RigidProjector) -> tuple[dict[str, float], dict[str, float]]:
    """Per line, two peaks of the effect's noise-free contribution to the readings, µm (µrad on
    angular lines): after removing the line's zero offset (and alignment slope for straightness)
    by least squares, and after a whole 21-error rigid-body fit (:mod:`rigid_fit`)."""
    simple, diffs = {}, {}
    for line in session.lines:
        diff = measure_line(machine, [effect], line) - baseline[line.spec.name]
        diffs[line.spec.name] = diff
        simple[line.spec.name] = _line_peak(line, diff)
    return simple, projector.residual_peaks(diffs)


# --------------------------------------------------------------------------------------------
# Drawing effects
# --------------------------------------------------------------------------------------------


def _stroke(plan: PlanSpec, axis: str) -> tuple[float, float]:
    return plan.stroke_mm[axis]


def _start(plan: PlanSpec, axis: str) -> float:
    if plan.reference_mm:
        return plan.reference_mm[axis]
    return plan.stroke_mm[axis][0]


def _length(plan: PlanSpec, axis: str) -> float:
    lo, hi = plan.stroke_mm[axis]
    return abs(hi - lo)


def _signed(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.choice([-1.0, 1.0]) * rng.uniform(lo, hi))


def _perpendicular(rng: np.random.Generator, to: np.ndarray) -> np.ndarray:
    """A unit vector ⟂ ``to``: a machine axis when one is perpendicular, else a random one."""
    axes = [np.eye(3)[i] for i in range(3) if abs(to[i]) < 1e-9]
    if axes:
        return axes[int(rng.integers(len(axes)))] * rng.choice([-1.0, 1.0])
    v = rng.normal(size=3)
    v -= (v @ to) * to
    return v / np.linalg.norm(v)


def rigid_family_residual(direction: str, axes: tuple[str, str], values: np.ndarray,
                          u: np.ndarray, v: np.ndarray, chain: str = PAPER_CHAIN) -> np.ndarray:
    """What no rigid-body error could produce of a surface in ``direction`` over ``axes`` (u along
    the first, v along the second).

    From the first-order chain (README, "Cross-axis"): on the (a, b) plane a rigid machine
    produces f(a) + g(b), plus h(a)·b when ``direction`` differs from b, a being the axis earlier
    in ``chain`` (an angular error of the earlier axis acting through the later one's travel).
    The residual of the least-squares projection on that family (polynomials of degree ≤ 4,
    exact for these surfaces) is returned.
    """
    columns = [np.ones_like(u)]
    columns += [u**i for i in range(1, 5)] + [v**j for j in range(1, 5)]
    order = chain_axes(chain)
    if order.index(axes[0]) < order.index(axes[1]):
        if direction != axes[1]:
            columns += [u**i * v for i in range(1, 5)]
    elif direction != axes[0]:
        columns += [v**j * u for j in range(1, 5)]
    a = np.stack([c.ravel() for c in columns], axis=1)
    coef, *_ = np.linalg.lstsq(a, values.ravel(), rcond=None)
    return (values.ravel() - a @ coef).reshape(values.shape)


def draw_cross_axis(rng: np.random.Generator, plan: PlanSpec, direction: str) -> fx.CrossAxis:
    pair = sorted(rng.choice(3, size=2, replace=False))
    axes = (AXES[pair[0]], AXES[pair[1]])
    grid = np.linspace(-1.0, 1.0, 41)
    u, v = np.meshgrid(grid, grid, indexing="ij")
    for _ in range(50):
        chosen = [fx.CROSS_TERMS[0]] + [
            t for t in fx.CROSS_TERMS[1:] if rng.random() < (0.5 if sum(t) < 4 else 0.3)]
        coefficients = {f"{i},{j}": float(rng.normal()) for i, j in chosen}
        values = sum(c * u ** int(k[0]) * v ** int(k[2]) for k, c in coefficients.items())
        peak = float(np.max(np.abs(values)))
        nonrigid = float(np.max(np.abs(rigid_family_residual(direction, axes, values, u, v,
                                                             plan.chain))))
        if nonrigid >= 0.4 * peak:
            break
    size = float(rng.uniform(0.5, 5.0))
    scale = size / peak
    centre = tuple(0.5 * sum(_stroke(plan, a)) for a in axes)
    half = tuple(0.5 * _length(plan, a) for a in axes)
    return fx.CrossAxis(direction, axes, centre, half,  # type: ignore[arg-type]
                        {k: c * scale for k, c in coefficients.items()}, size, nonrigid * scale)


def draw_catalogue(rng: np.random.Generator, kind: str, plan: PlanSpec, session: Session,
                   taken: set) -> fx.Effect:
    axis = str(rng.choice([a for a in AXES if (kind, a) not in taken] or list(AXES)))
    lo, hi = _stroke(plan, axis)
    if kind == "reversal":
        b = _signed(rng, 0.5, 5.0)
        b_end = b if rng.random() < 0.6 else float(np.clip(b * rng.uniform(0.3, 1.7), -5, 5))
        return fx.Reversal(axis, (lo, hi), _start(plan, axis), b, b_end)
    if kind == "cyclic":
        lead = plan.screw_lead_mm.get(axis)
        at_lead = lead is not None and rng.random() < 0.5
        period = float(lead) if at_lead else float(rng.uniform(6.0, 60.0))
        ratio = float(rng.uniform(0.2, 0.6)) if rng.random() < 0.5 else 0.0
        a1 = float(rng.uniform(0.5, 5.0) / (1 + ratio))
        return fx.ScrewCycle(axis, _start(plan, axis), period, a1, float(rng.uniform(0, 2 * np.pi)),
                             a1 * ratio, float(rng.uniform(0, 2 * np.pi)), at_lead)
    if kind == "thermal_drift":
        tau = float(rng.uniform(15.0, 240.0)) * 60.0
        alpha = float(rng.uniform(11.0, 12.0))
        # Steel at 11.5 ppm/K: 1 K is 4.6 µm over 400 mm; up to ~2.6 K of warming.
        size = float(rng.uniform(1.0, 12.0))
        reach = 1.0 - np.exp(-session.end_s / tau)
        dt_inf = size / (alpha * 1e-3 * _length(plan, axis) * reach)
        return fx.ThermalDrift(axis, _start(plan, axis), alpha, float(dt_inf), tau)
    if kind == "cross_axis":
        return draw_cross_axis(rng, plan, axis)
    if kind == "local":
        choices = [axis] + [a for a in AXES if a != axis]
        direction = str(rng.choice(choices, p=[1 / 3, 1 / 3, 1 / 3]))
        length = hi - lo
        centre = float(rng.uniform(lo + 0.15 * length, hi - 0.15 * length))
        return fx.LocalDefect(axis, direction, round(centre, 2), float(rng.uniform(5.0, 40.0)),
                              _signed(rng, 0.5, 5.0), str(rng.choice(["gaussian", "triangular"])))
    if kind == "abbe_offset":
        lines = [s for s in plan.lines if s.quantity in ("linear", "straightness")
                 and ("abbe_offset", s.name) not in taken]
        spec = lines[int(rng.integers(len(lines)))]
        away = spec.direction if spec.quantity == "linear" else spec.sensitive
        offset = _perpendicular(rng, away) * rng.uniform(20.0, 80.0)
        return fx.AbbeOffset(spec.name, tuple(float(round(v, 3)) for v in offset))
    if kind == "cosine":
        lines = [s for s in plan.lines
                 if s.quantity == "linear" and ("cosine", s.name) not in taken]
        spec = lines[int(rng.integers(len(lines)))]
        tilt = _perpendicular(rng, spec.direction)
        theta = float(rng.uniform(1.5, 4.5))
        return fx.CosineError(spec.name, theta, tuple(float(v) for v in tilt))
    raise ValueError(kind)


def draw_outside(rng: np.random.Generator, name: str, plan: PlanSpec,
                 session: Session) -> fx.Effect:
    if name == "scale_oscillation":
        axis = "X" if rng.random() < 0.5 else str(rng.choice(["Y", "Z"]))
        return fx.ScaleOscillation(axis, _start(plan, axis), _length(plan, axis),
                                   float(rng.uniform(0.5, 5.0)), float(rng.uniform(30, 120)) * 60,
                                   float(rng.uniform(0, 2 * np.pi)))
    if name == "reflector_twitch":
        sigma = float(rng.uniform(0.25, 2.5))
        offsets = {line.spec.name: tuple(float(v) for v in rng.normal(0, sigma, line.runs))
                   for line in session.lines if line.spec.quantity != "angular"}
        return fx.ReflectorTwitch(sigma, offsets)
    if name == "laser_random_walk":
        durations = [line.last_s - line.first_s for line in session.lines]
        median_min = float(np.median(durations)) / 60.0
        sigma = float(rng.uniform(0.5, 5.0)) / (2.0 * np.sqrt(median_min))
        walks = {}
        for line in session.lines:
            t = line.time_s.reshape(-1)
            order = np.argsort(t, kind="stable")
            steps = rng.normal(0.0, 1.0, len(t)) * sigma * np.sqrt(np.diff(t[order],
                                                                          prepend=t[order][0]) / 60)
            walk = np.empty(len(t))
            walk[order] = np.cumsum(steps)
            walks[line.spec.name] = walk - walk[0]
        return fx.LaserRandomWalk(sigma, walks)
    if name == "beam_interruption":
        lines = [line for line in session.lines if line.spec.quantity == "linear"]
        line = lines[int(rng.integers(len(lines)))]
        run = int(rng.integers(1, line.runs))
        k = len(line.targets_mm)
        visit = int(rng.integers(0, k))
        target = visit if run % 2 == 0 else k - 1 - visit
        return fx.BeamInterruption(line.spec.name, run, visit, float(line.time_s[run, target]),
                                   _signed(rng, 0.5, 5.0))
    if name == "column_bending":
        return fx.ColumnBending(str(rng.choice(["X", "Y"])), _start(plan, "Z"), _length(plan, "Z"),
                                _signed(rng, 0.5, 5.0), float(rng.uniform(30, 240)) * 60,
                                session.end_s)
    if name == "time_periodic":
        return fx.TimePeriodic(str(rng.choice(AXES)), _signed(rng, 0.5, 5.0),
                               float(rng.uniform(60, 600)), float(rng.uniform(0, 2 * np.pi)))
    raise ValueError(name)


def _taken_key(effect: fx.Effect) -> tuple:
    line = getattr(effect, "line", None)
    return (effect.kind, line if line is not None else effect.axis)


def draw_visible(rng: np.random.Generator, draw, machine: Machine, session: Session,
                 baseline: dict[str, np.ndarray], projector: RigidProjector,
                 threshold: float) -> tuple[fx.Effect, dict]:
    """Draw an effect until what a rigid-body fit leaves of it reaches ``threshold`` (at most
    MAX_ATTEMPTS draws; the draw that leaves most otherwise, flagged not visible)."""
    best = None
    attempts = 0
    while attempts < MAX_ATTEMPTS:
        attempts += 1
        effect = draw()
        simple, rigid = visibility(machine, session, effect, baseline, projector)
        score = max(rigid.values())
        if best is None or score > best[1]:
            best = (effect, score, simple, rigid)
        if score >= threshold:
            break
    effect, _, simple, rigid = best  # type: ignore[misc]
    simple_line = max(simple, key=simple.get)
    rigid_line = max(rigid, key=rigid.get)
    record = {
        "peak": round(simple[simple_line], 6),
        "line": simple_line,
        "unit": "urad" if _is_angular(session, simple_line) else "um",
        "per_line": {k: round(v, 6) for k, v in simple.items() if v >= 1e-3},
        "after_rigid_fit_peak": round(rigid[rigid_line], 6),
        "after_rigid_fit_line": rigid_line,
        "after_rigid_fit_per_line": {k: round(v, 6) for k, v in rigid.items() if v >= 1e-3},
        "threshold_um": round(threshold, 6),
        "visible": bool(simple[simple_line] >= threshold),
        "visible_after_rigid_fit": bool(rigid[rigid_line] >= threshold),
        "attempts": attempts,
        "definition": "peak: max over lines of max |noise-free contribution − least-squares "
                      "constant (plus slope on straightness lines)|; after_rigid_fit_peak: max "
                      "|contribution − its least-squares fit by the 21-error model (cubic "
                      "B-splines, knots ~50 mm, zero at the reference; squareness; per-line "
                      "offsets and straightness slopes)|; threshold = max(2.5·noise, 0.4 µm)",
        "rigid_fit": {"knot_mm": 50.0, "rank": projector.rank, "unknowns": projector.unknowns},
    }
    return effect, record


def _is_angular(session: Session, name: str) -> bool:
    return any(line.spec.name == name and line.spec.angular for line in session.lines)


# --------------------------------------------------------------------------------------------
# Environment of the logs
# --------------------------------------------------------------------------------------------


def set_environment(rng: np.random.Generator, session: Session, drift: fx.ThermalDrift | None,
                    material_logged: bool) -> dict:
    air0 = 20.0 + rng.uniform(-0.5, 1.5)
    air_amp, air_period, air_phase = rng.uniform(0, 0.4), rng.uniform(4, 12) * 3600, rng.uniform(
        0, 2 * np.pi)
    press0, press_rate = rng.uniform(99.5, 102.5), rng.uniform(-0.3, 0.3) / max(session.end_s, 1)
    humid0 = rng.uniform(35, 60)
    base = 20.0 + rng.uniform(-0.5, 1.5)
    sensors = int(rng.integers(1, 3))
    bias = rng.uniform(0.0, 0.05)
    biases = [0.0] if sensors == 1 else [bias, -bias]

    def material(t: float) -> float:
        return base + (float(drift.delta_t(t)) if drift is not None else 0.0)

    for line in session.lines:
        start, end = file_times(line, 0.0)
        ends = (start, end)
        line.environment = {
            "air_temp_c": tuple(air0 + air_amp * np.sin(2 * np.pi * t / air_period + air_phase)
                                for t in ends),
            "air_pressure_kpa": tuple(press0 + press_rate * t for t in ends),
            "air_humidity_pct": tuple(humid0 + rng.normal(0, 0.5) for _ in ends),
            "expansion_ppm_per_c": 11.5,
        }
        if material_logged:
            line.environment["material_temp_c"] = [
                (material(start) + b, material(end) + b) for b in biases]
    return {"material_temperature_logged": material_logged,
            "material_base_c": base if material_logged else None,
            "material_sensors": sensors if material_logged else 0,
            "material_sensor_bias_c": biases if material_logged else [],
            "expansion_coefficient_in_files_ppm_per_c": 11.5,
            "note": "Mat temp = base + the thermal drift's dT(t) (sensor on the drifting axis); "
                    "the readings are NOT normalised with it (env_corrected = true in the plan "
                    "means volucal applies nothing)"}


# --------------------------------------------------------------------------------------------
# The scenario
# --------------------------------------------------------------------------------------------


def _weighted(rng: np.random.Generator, weights: dict) -> str:
    keys = list(weights)
    p = np.asarray([weights[k] for k in keys], dtype=float)
    return str(keys[int(rng.choice(len(keys), p=p / p.sum()))])


def draw_plan_and_category(seed: int) -> tuple[str, str]:
    """The plan and category ``seed`` draws (the first two draws of its generator)."""
    rng = np.random.default_rng(seed)
    return _weighted(rng, PLANS), _weighted(rng, CATEGORIES)


def build_scenario(
    seed: int,
    plan: str | None = None,
    category: str | None = None,
    kinds: Sequence[str] | None = None,
    material_logged: bool | None = None,
    noise_draw: int = 0,
) -> Scenario:
    """Draw everything for ``seed``.

    Optional overrides (each leaves every other draw of the seed as it was): ``plan`` (a path
    relative to the repository), ``category``, ``kinds`` (catalogue kinds to draw, e.g.
    ``["reversal", "cosine"]``, or one outside name such as ``["time_periodic"]``; implies the
    category), ``material_logged`` and ``noise_draw`` (a positive number: the readings' noise
    drawn anew, the machine, effects and session as they were; 0: the seed's own noise).
    """
    rng = np.random.default_rng(seed)
    plan_source = _weighted(rng, PLANS)
    category_drawn = _weighted(rng, CATEGORIES)
    plan_source = plan or plan_source
    category = category or category_drawn
    if kinds:
        unknown = [k for k in kinds if k not in CATALOGUE and k not in OUTSIDE]
        if unknown:
            raise ValueError(f"unknown effect kind(s) {unknown}; catalogue {CATALOGUE}, "
                             f"outside {OUTSIDE}")
        if any(k in OUTSIDE for k in kinds) and not all(k in OUTSIDE for k in kinds):
            raise ValueError("catalogue and outside effects are not mixed in one scenario")
        category = "outside" if kinds[0] in OUTSIDE else "effects"
        if category == "outside" and len(kinds) != 1:
            raise ValueError("an outside scenario has exactly one outside effect")
    spec = read_plan(REPO / plan_source)
    settings = draw_settings(rng)
    start = datetime(2023, 1, 2, tzinfo=UTC).timestamp() + int(rng.integers(0, 900)) * 86400 + int(
        rng.uniform(7.5, 10.0) * 3600)
    session = schedule_session(rng, spec, settings, float(start))
    machine = random_machine(rng, spec.stroke_mm, spec.reference_mm, spec.chain)
    noise = float(rng.uniform(0.05, 0.5))
    threshold = max(2.5 * noise, 0.4)
    baseline = {line.spec.name: measure_line(machine, [], line) for line in session.lines}
    projector: RigidProjector | None = None

    effects: list[fx.Effect] = []
    records: list[dict] = []
    taken: set = set()
    if category in ("effects", "outside"):
        projector = RigidProjector(spec, session.lines)
    if category == "effects":
        count = int(rng.integers(1, 4))
        forced = list(kinds) if kinds else None
        for index in range(len(forced) if forced else count):
            tried: list[str] = []
            best = None
            for _ in range(1 if forced else KIND_TRIES):
                allowed = [k for k in CATALOGUE if k not in tried and not (
                    k == "thermal_drift" and any(isinstance(e, fx.ThermalDrift) for e in effects))]
                kind = forced[index] if forced else str(rng.choice(allowed))
                tried.append(kind)

                def draw(kind: str = kind) -> fx.Effect:
                    return draw_catalogue(rng, kind, spec, session, taken)

                effect, vis = draw_visible(rng, draw, machine, session, baseline, projector,
                                           threshold)
                vis["kinds_tried"] = list(tried)
                if best is None or vis["after_rigid_fit_peak"] > best[1]["after_rigid_fit_peak"]:
                    best = (effect, vis)
                if vis["visible_after_rigid_fit"]:
                    break
            effect, vis = best  # type: ignore[misc]
            taken.add(_taken_key(effect))
            effects.append(effect)
            records.append(vis)
    elif category == "outside":
        tried = []
        best = None
        for _ in range(1 if kinds else KIND_TRIES):
            name = kinds[0] if kinds else str(rng.choice([n for n in OUTSIDE if n not in tried]))
            tried.append(name)
            def draw(name: str = name) -> fx.Effect:
                return draw_outside(rng, name, spec, session)

            effect, vis = draw_visible(rng, draw, machine, session, baseline, projector, threshold)
            vis["kinds_tried"] = list(tried)
            if best is None or vis["after_rigid_fit_peak"] > best[1]["after_rigid_fit_peak"]:
                best = (effect, vis)
            if vis["visible_after_rigid_fit"]:
                break
        effects.append(best[0])  # type: ignore[index]
        records.append(best[1])  # type: ignore[index]
    elif category != "clean":
        raise ValueError(f"unknown category {category!r}")

    drift = next((e for e in effects if isinstance(e, fx.ThermalDrift)), None)
    logged = bool(rng.random() < 0.6)
    material_logged = logged if material_logged is None else material_logged
    environment = set_environment(rng, session, drift, material_logged)
    noise_rng = np.random.default_rng([seed, 1] if noise_draw == 0 else [seed, 1, noise_draw])
    deviations = {line.spec.name: measure_line(machine, effects, line, noise, noise_rng)
                  for line in session.lines}
    entries = []
    for effect, vis in zip(effects, records, strict=True):
        entry = effect.describe()
        entry["visibility"] = vis
        entries.append(entry)
    return Scenario(seed, plan_source, spec, category, machine, session, effects, entries, noise,
                    material_logged, deviations, environment)


def log_name(line: LineSchedule) -> str:
    return f"logs/{line.spec.name}.{'rta' if line.spec.angular else 'rtl'}"


def manifest(s: Scenario, truth_step_mm: float = 2.0) -> dict:
    """The JSON-serialisable ground truth of a scenario (schema in README.md)."""
    lines = []
    for line in s.session.lines:
        start, end = file_times(line, s.session.start_posix)
        steps = np.diff(line.targets_mm)
        lines.append({
            "name": line.spec.name, "quantity": line.spec.quantity, "file": log_name(line),
            "targets": len(line.targets_mm), "length_mm": float(line.targets_mm[-1]),
            "min_step_mm": float(steps.min()), "max_step_mm": float(steps.max()),
            "runs": line.runs, "first_reading_s": line.first_s, "last_reading_s": line.last_s,
            "file_start_posix": start, "file_end_posix": end,
            "alignment_slope_um_per_mm": line.alignment_um_per_mm,
            "backward_rows": line.backward_rows,
        })
    keys = ("kind", "axis", "direction", "depends_on", "line")
    catalogue = [{k: e[k] for k in keys if k in e} for e in s.effect_records
                 if not e["kind"].startswith("outside:")
                 and e["visibility"]["visible_after_rigid_fit"]]
    return {
        "schema": SCHEMA,
        "seed": s.seed,
        "category": s.category,
        "plan": {"source": s.plan_source, "lines": len(s.plan.lines),
                 "machine_name": s.plan.machine.get("name"),
                 "screw_lead_mm": s.plan.screw_lead_mm,
                 "tool_offset_mm": [float(v) for v in s.plan.tool_offset_mm]},
        "noise": {"sigma_um": s.noise, "sigma_urad": s.noise,
                  "model": "independent Gaussian per reading; the same number in µrad on "
                           "angular lines"},
        "machine": s.machine.truth(truth_step_mm),
        "effects": s.effect_records,
        "expected": {
            "catalogue_effects": catalogue,
            "outside": [e["kind"] for e in s.effect_records if e["kind"].startswith("outside:")],
            "note": "catalogue effects of which a rigid-body fit leaves at least the threshold; "
                    "an outside effect should be reported unexplained, never fitted as a "
                    "catalogue effect",
        },
        "session": {
            "start_posix": s.session.start_posix,
            "start_utc": datetime.fromtimestamp(s.session.start_posix, tz=UTC).isoformat(),
            "duration_s": s.session.end_s,
            "settings": asdict(s.session.settings),
            "environment": s.environment,
            "lines": lines,
            "time_origin": "t = 0 at the first reading of the session",
        },
    }


def _rounded(obj):
    if isinstance(obj, float):
        return round(obj, 9)
    if isinstance(obj, dict):
        return {k: _rounded(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_rounded(v) for v in obj]
    if isinstance(obj, np.floating):
        return round(float(obj), 9)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def make_scenario(seed: int, plan: str | None = None, category: str | None = None,
                  kinds: Sequence[str] | None = None, material_logged: bool | None = None,
                  noise_draw: int = 0) -> dict:
    """Everything a scenario folder holds, as text: ``truth`` (the manifest, JSON-serialisable),
    ``plan_toml`` and ``logs`` ({"logs/<line>.rtl": text}). Overrides as :func:`build_scenario`."""
    s = build_scenario(seed, plan, category, kinds, material_logged, noise_draw)
    files = {line.spec.name: log_name(line) for line in s.session.lines}
    logs = {
        log_name(line): rtl_text(line, s.deviations[line.spec.name], s.session.start_posix,
                                 str(s.plan.machine.get("name", "machine")))
        for line in s.session.lines
    }
    return {"truth": _rounded(manifest(s)), "plan_toml": plan_text(s.plan, files), "logs": logs}


def write_scenario(seed: int, folder: str | Path, plan: str | None = None,
                   category: str | None = None, kinds: Sequence[str] | None = None,
                   material_logged: bool | None = None, noise_draw: int = 0) -> tuple[Path, dict]:
    """Write plan.toml, logs/*.rtl|rta and truth.json into ``folder``; return (plan path, truth).
    Overrides as :func:`build_scenario`."""
    folder = Path(folder)
    made = make_scenario(seed, plan, category, kinds, material_logged, noise_draw)
    (folder / "logs").mkdir(parents=True, exist_ok=True)
    for relative, text in made["logs"].items():
        (folder / relative).write_bytes(text.encode("utf-8"))
    plan_path = folder / "plan.toml"
    plan_path.write_text(made["plan_toml"], encoding="utf-8")
    (folder / "truth.json").write_text(json.dumps(made["truth"], indent=1), encoding="utf-8")
    return plan_path, made["truth"]
