"""volucal's closed loop on the blind generator's scenarios (tests/blind), scored like
:mod:`loop_scenarios`: the generator wrote the files and a truth manifest without knowing the
method; this module only reads the manifest.

A catalogue effect counts as *visible* when what the generator's own rigid-body fit leaves of it
(``after_rigid_fit_peak``) reaches 4× the noise, the bar of :mod:`loop_scenarios`; the
generator's own, lower bar (2.5× the noise, at least 0.4 µm) is kept beside it. The lines that
show an effect are those where ``after_rigid_fit_per_line`` reaches the same bar; with the
manifest's environment they decide which visible effects are attributable
(:meth:`loop_scenarios.Outcome.attributable`).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from loop_scenarios import (
    MATERIAL_CHANGE_C,
    VISIBLE_FACTOR,
    Outcome,
    _gauged,
    _slope,
    kept_effects,
    squareness_errors,
    squareness_ratio,
)

from tests.blind.scenarios import build_scenario, write_scenario


def _where(effect: dict) -> tuple[str, str]:
    kind = effect["kind"]
    if kind in ("abbe_offset", "cosine"):
        return kind, effect["line"]
    if kind == "cross_axis":
        pair = sorted(effect["depends_on"])
        return kind, f"{effect['axis']} over {pair[0]}×{pair[1]}"
    if kind == "local":
        return kind, f"{effect['axis']} in {effect['direction']}"
    return kind, effect["axis"]


def _material_logged(truth: dict) -> bool:
    """Whether the logs carry a material temperature that changes over the session by more
    than MATERIAL_CHANGE_C: the manifest's flag, and the warming its thermal drift (the logged
    temperature is base + ΔT(t), scenarios.set_environment) brings from the first reading to
    the session's end; without a drift the logged temperature is constant."""
    if not truth["session"]["environment"]["material_temperature_logged"]:
        return False
    duration_s = float(truth["session"]["duration_s"])
    for effect in truth["effects"]:
        if effect["kind"] == "thermal_drift":
            p = effect["parameters"]
            rise = float(p["delta_T_inf_K"]) * (1.0 - np.exp(-duration_s / (60 * p["tau_min"])))
            if abs(rise) > MATERIAL_CHANGE_C:
                return True
    return False


def _accuracy(seed: int, truth: dict, result) -> tuple[dict[str, float], dict[str, float], float]:  # type: ignore[no-untyped-def]
    """As :func:`loop_scenarios._accuracy`, against the manifest: every identified function with
    its gauge removed, cycles and local defects folded into the function they change and
    surfaces folded in along the line through the middle of the other strokes
    (:func:`loop_scenarios.fold_states`; the generator's and volucal's alike)."""
    from loop_scenarios import _single_axis_model, fold_states

    single: dict[str, list] = {}
    surfaces: dict[str, list] = {}
    for effect in build_scenario(seed).effects:
        if effect.kind in ("cyclic", "local"):
            eid = f"E{getattr(effect, 'direction', effect.axis)}{effect.axis}"
            single.setdefault(eid, []).append(effect)
        elif effect.kind == "cross_axis":
            for along in effect.depends_on:
                surfaces.setdefault(f"E{effect.axis}{along}", []).append(effect)
    machine = result.final.model.machine
    stroke = {axis: machine.stroke(axis) for axis in "XYZ"}
    identified = set(result.base.identifiability.identified_ids)
    functions = {}
    slopes: dict[str, tuple[float, float]] = {}
    worst_ratio = 0.0
    for eid, table in truth["machine"]["functions"].items():
        if eid not in identified:
            continue
        q = np.asarray(table["position_mm"], float)
        straightness = table["kind"] == "straightness"
        value = np.asarray(table["value"], float)
        for effect in single.get(eid, ()):
            value = value + effect.value(q)
        for effect in surfaces.get(eid, ()):
            states = fold_states(stroke, eid[2], q)
            a, b = (states[:, "XYZ".index(axis)] for axis in effect.depends_on)
            value = value + effect.value(a, b)
        model, std = _single_axis_model(result, eid, q)
        if straightness:
            slopes[eid] = (_slope(value, q), _slope(model, q))
        difference = _gauged(model, q, straightness) - _gauged(value, q, straightness)
        functions[eid] = float(np.sqrt(np.mean(difference**2)))
        spread = float(np.sqrt(np.mean(std**2)))
        if spread > 0:
            worst_ratio = max(worst_ratio, functions[eid] / spread)
    squareness = squareness_errors(
        truth["machine"]["squareness_urad"],
        result.final.model.squareness_urad,
        slopes,
        identified,
    )
    return functions, squareness, max(worst_ratio, squareness_ratio(result, squareness))


def run_blind(seed: int) -> Outcome:
    """Write the blind scenario ``seed``, import it with volucal, close the loop, score."""
    from volucal.core.io.plan import import_plan, load_plan
    from volucal.core.residuals import close_loop

    with tempfile.TemporaryDirectory(prefix="volucal-blind-") as tmp:
        plan_path, truth = write_scenario(seed, tmp)
        start = time.perf_counter()
        measurement = import_plan(load_plan(plan_path)).measurement
        result = close_loop(measurement)
        seconds = time.perf_counter() - start
    report = result.to_report()
    kept, implausible = kept_effects(report)
    noise = float(truth["noise"]["sigma_um"])
    catalogue = [e for e in truth["effects"] if not e["kind"].startswith("outside:")]
    visibility = {
        " ".join(_where(e)): float(e["visibility"]["after_rigid_fit_peak"]) / noise
        for e in catalogue
    }
    showing = {
        " ".join(_where(e)): sorted(
            name
            for name, peak in e["visibility"]["after_rigid_fit_per_line"].items()
            if float(peak) / noise >= VISIBLE_FACTOR
        )
        for e in catalogue
    }
    function_error, squareness_error, band_ratio = _accuracy(seed, truth, result)
    return Outcome(
        seed,
        Path(truth["plan"]["source"]).stem,
        truth["category"],
        noise,
        {_where(e) for e in catalogue},
        all(v >= VISIBLE_FACTOR for v in visibility.values()),
        kept,
        implausible,
        len(report["unexplained"]),
        function_error,
        squareness_error,
        seconds,
        len(report["warnings"]),
        report["effects"],
        visibility,
        band_ratio,
        showing,
        _material_logged(truth),
        [u["where"] for u in report["unexplained"]],
    )
