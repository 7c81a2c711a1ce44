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
from dataclasses import replace
from pathlib import Path

import numpy as np
from loop_scenarios import (
    MATERIAL_CHANGE_C,
    VISIBLE_FACTOR,
    Outcome,
    PerError,
    expected_errors,
    gauged,
    kept_effects,
    ls_slope,
    named_errors,
    one_line_refused,
    squareness_errors,
    squareness_ratios,
)
from numpy.polynomial import legendre

from tests.blind import effects as fx
from tests.blind.laser import measure_line
from tests.blind.rigid_fit import RigidProjector
from tests.blind.scenarios import Scenario, build_scenario, draw_plan_and_category, write_scenario

#: A surface term is a rigid body's on the plan when the generator's own 21-error fit leaves
#: less than this share of its contribution (one norm over every line's target means; a term no
#: line sees stays in the surface).
RIGID_SHARE = 1e-3


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


def _legendre_terms(effect: fx.CrossAxis) -> dict[tuple[int, int], float]:
    """The surface's coefficients on the products P_k(u)·P_l(v) of Legendre polynomials (the
    same u, v), k, l ≥ 0."""
    out: dict[tuple[int, int], float] = {}
    for key, c in effect.coefficients.items():
        i, j = (int(t) for t in key.split(","))
        for k, a in enumerate(legendre.poly2leg([0] * i + [1])):
            for m, b in enumerate(legendre.poly2leg([0] * j + [1])):
                if abs(a * b) > 1e-15:
                    out[(k, m)] = out.get((k, m), 0.0) + c * a * b
    return out


def _product(effect: fx.CrossAxis, k: int, m: int, c: float) -> fx.CrossAxis:
    """c·P_k(u)·P_m(v) as a surface of the generator (its monomials)."""
    pu = legendre.leg2poly([0] * k + [1])
    pv = legendre.leg2poly([0] * m + [1])
    coefficients = {
        f"{i},{j}": c * a * b for i, a in enumerate(pu) for j, b in enumerate(pv) if abs(a * b) > 0
    }
    return replace(effect, coefficients=coefficients)


def rigid_share(
    scenario: Scenario,
) -> tuple[RigidProjector | None, dict[str, np.ndarray], dict[str, float], list]:
    """What the scenario's surfaces hold that a rigid body produces exactly on its plan.

    Each surface is split into products of Legendre polynomials of its two positions (the
    shape functions a fit of a surface uses); a product both of whose factors vary is the
    rigid body's when the generator's own 21-error fit (:mod:`tests.blind.rigid_fit`) reproduces
    its contribution to every line. No method can tell such a term from the angular errors and
    squareness that produce it (a twist c·u·v of X over Y×Z is a roll of Y growing along Y, seen
    through the Z travel): it is a gauge of the split between the 21 errors and the surface,
    and volucal leaves it to the 21 errors. Returned: the generator's fit (None without a
    surface); per function, the coefficients of that fit to add to the truth's
    (:meth:`RigidProjector.function_values`); per squareness, the µrad to add; and the surfaces
    less those terms (for the folding along the middle of the strokes)."""
    surfaces = [e for e in scenario.effects if isinstance(e, fx.CrossAxis)]
    if not surfaces:
        return None, {}, {}, []
    projector = RigidProjector(scenario.plan, scenario.session.lines)
    baseline = {
        line.spec.name: measure_line(scenario.machine, [], line) for line in scenario.session.lines
    }
    functions: dict[str, np.ndarray] = {}
    squareness: dict[str, float] = {}
    remaining = []
    for effect in surfaces:
        left = dict(effect.coefficients)
        for (k, m), c in _legendre_terms(effect).items():
            if k == 0 or m == 0 or abs(c) < 1e-12:
                continue
            term = _product(effect, k, m, 1.0)
            diffs = {
                line.spec.name: measure_line(scenario.machine, [term], line)
                - baseline[line.spec.name]
                for line in scenario.session.lines
            }
            fitted, square, share = projector.fit(diffs)
            if share >= RIGID_SHARE:
                continue
            for eid, coefficients in fitted.items():
                functions[eid] = functions.get(eid, 0.0) + c * coefficients
            for sid, value in square.items():
                squareness[sid] = squareness.get(sid, 0.0) + c * value
            for key, value in _product(effect, k, m, c).coefficients.items():
                left[key] = left.get(key, 0.0) - value
        remaining.append(replace(effect, coefficients=left))
    return projector, functions, squareness, remaining


def _accuracy(seed: int, truth: dict, result) -> tuple[PerError, PerError, PerError]:  # type: ignore[no-untyped-def]
    """As :func:`loop_scenarios._accuracy`, against the manifest: every identified function with
    its gauge removed, cycles and local defects folded into the function they change and
    surfaces folded in along the line through the middle of the other strokes
    (:func:`loop_scenarios.fold_states`; the generator's and volucal's alike)."""
    from loop_scenarios import fold_states, single_axis_model

    single: dict[str, list] = {}
    surfaces: dict[str, list] = {}
    scenario = build_scenario(seed, plan=truth["plan"]["source"])
    projector, rigid, rigid_squareness, remaining = rigid_share(scenario)
    for effect in scenario.effects:
        if effect.kind in ("cyclic", "local"):
            eid = f"E{getattr(effect, 'direction', effect.axis)}{effect.axis}"
            single.setdefault(eid, []).append(effect)
    for effect in remaining:
        for along in effect.depends_on:
            surfaces.setdefault(f"E{effect.axis}{along}", []).append(effect)
    machine = result.final.model.machine
    stroke = {axis: machine.stroke(axis) for axis in "XYZ"}
    identified = set(result.base.identifiability.identified_ids)
    functions = {}
    slopes: dict[str, tuple[float, float]] = {}
    ratios: dict[str, float] = {}
    for eid, table in truth["machine"]["functions"].items():
        if eid not in identified:
            continue
        q = np.asarray(table["position_mm"], float)
        straightness = table["kind"] == "straightness"
        value = np.asarray(table["value"], float)
        for effect in single.get(eid, ()):
            value = value + effect.value(q)
        if projector is not None and eid in rigid:
            value = value + projector.function_values(eid, rigid[eid], q)
        for effect in surfaces.get(eid, ()):
            states = fold_states(stroke, eid[2], q)
            a, b = (states[:, "XYZ".index(axis)] for axis in effect.depends_on)
            value = value + effect.value(a, b)
        model, spread = single_axis_model(result, eid, q)
        if straightness:
            slopes[eid] = (ls_slope(value, q), ls_slope(model, q))
        difference = gauged(model, q, straightness) - gauged(value, q, straightness)
        functions[eid] = float(np.sqrt(np.mean(difference**2)))
        if spread > 0:
            ratios[eid] = functions[eid] / spread
    truth_squareness = {
        sid: value + rigid_squareness.get(sid, 0.0)
        for sid, value in truth["machine"]["squareness_urad"].items()
    }
    squareness = squareness_errors(
        truth_squareness,
        result.final.model.squareness_urad,
        slopes,
        identified,
    )
    return functions, squareness, {**ratios, **squareness_ratios(result, squareness)}


def calibrated_report(seed: int) -> dict:
    """report.json of ``volucal calibrate`` (no sensitivity) on the blind scenario ``seed``, as a
    user runs it on the files the generator writes."""
    import json

    from volucal.core.cli import main

    with tempfile.TemporaryDirectory(prefix="volucal-blind-") as tmp:
        plan, _ = write_scenario(seed, tmp)
        report_path = Path(tmp) / "report.json"
        code = main(
            ["calibrate", str(plan), "--report", str(report_path), "--no-sensitivity", "--quiet"]
        )
        assert code == 0
        return json.loads(report_path.read_text(encoding="utf-8"))


def run_blind(
    seed: int, noise_draw: int = 0, paths: bool = False, plans: dict[str, Path] | None = None
) -> Outcome:
    """Write the blind scenario ``seed`` (with ``noise_draw``, its readings' noise drawn anew:
    :func:`scenarios.build_scenario`), import it with volucal, close the loop, score; with
    ``paths``, also the squareness between the tool's paths (:func:`path_squareness`). With
    ``plans`` (the generator's plan sources to other plans: benchmarks/machines.py), the plan
    the seed draws is replaced by its counterpart, every other draw of the seed kept."""
    from volucal.core.io.plan import import_plan, load_plan
    from volucal.core.residuals import close_loop

    plan = None
    if plans is not None:
        plan = str(plans[draw_plan_and_category(seed)[0]])
    with tempfile.TemporaryDirectory(prefix="volucal-blind-") as tmp:
        plan_path, truth = write_scenario(seed, tmp, plan=plan, noise_draw=noise_draw)
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
    function_error, squareness_error, ratios = _accuracy(seed, truth, result)
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
        showing,
        _material_logged(truth),
        [u["where"] for u in report["unexplained"]],
        max(
            (
                float(e["visibility"]["after_rigid_fit_peak"]) / noise
                for e in truth["effects"]
                if e["kind"].startswith("outside:")
            ),
            default=0.0,
        ),
        report.get("basis", {}).get("spacing_mm"),
        expected_errors(result),
        path_squareness(seed, truth, result) if paths else {},
        error_ratios=ratios,
        named=named_errors(report),
        one_line_refused=one_line_refused(report),
    )


#: The squareness ids with their first and second axis, and the sign that makes the angle
#: between the two paths the squareness on a machine with no other error (ISO 230-1: EC0Y turns
#: Y about +Z, EB0Z turns Z about +Y, EA0Z turns Z about +X), written from the generator's
#: chain (:meth:`tests.blind.machine.Machine.pose_error`).
PATH_PAIRS = {"EC0Y": ("X", "Y", -1.0), "EB0Z": ("X", "Z", 1.0), "EA0Z": ("Y", "Z", -1.0)}


def true_tool_error(scenario: Scenario, tool_mm: np.ndarray, states: np.ndarray) -> np.ndarray:
    """The generator's tool error (µm, (N, 3)) at machine ``states`` at the session's first
    moment, no approach direction (a reversal's halves cancel): its exact chain with every
    effect's hooks as :func:`tests.blind.laser.measure_line` applies them, without any line's
    set-up."""
    n = len(states)
    zeros = np.zeros(n)
    readings = fx.Readings(
        "path",
        "linear",
        states,
        zeros,
        np.zeros((n, 3)),
        zeros,
        zeros.astype(int),
        zeros.astype(int),
    )
    deltas: dict[str, np.ndarray] = {}
    extra = np.zeros((n, 3))
    for effect in scenario.effects:
        for axis, delta in effect.axis_delta(readings).items():
            deltas[axis] = deltas.get(axis, 0.0) + delta
        added = effect.volumetric(readings)
        if added is not None:
            extra = extra + added
    return scenario.machine.pose_error(states, tool_mm, deltas or None)[0] + extra


def true_path_angle(
    scenario: Scenario,
    tool_mm: np.ndarray,
    squareness_id: str,
    place_mm: np.ndarray,
    ranges_mm: dict[str, tuple[float, float]],
) -> float:
    """The angle (µrad) between the true tool paths along the two axes of ``squareness_id``
    through ``place_mm``, each over its range in ``ranges_mm``: least-squares slopes of
    :func:`true_tool_error` on 101 points (numpy.polyfit)."""
    first, second, sign = PATH_PAIRS[squareness_id]
    total = 0.0
    for along, towards in ((first, second), (second, first)):
        q = np.linspace(*ranges_mm[along], 101)
        states = np.tile(np.asarray(place_mm, float), (len(q), 1))
        states[:, "XYZ".index(along)] = q
        error = true_tool_error(scenario, tool_mm, states)
        total += 1000.0 * np.polyfit(q, error[:, "XYZ".index(towards)], 1)[0]
    return sign * total


def path_squareness(  # type: ignore[no-untyped-def]
    seed: int, truth: dict, result
) -> dict[str, tuple[float, float, float, np.ndarray]]:
    """Per squareness volucal maps over the measured volume (core/squareness_map.py): its error
    at the volume's centre against the generator's paths (µrad), its stated standard
    uncertainty there, its largest error over every place of its grid, and at every place the
    error divided by the standard uncertainty stated there."""
    from volucal.core.calibrate import measured_range
    from volucal.core.loop_source import LoopSource
    from volucal.core.squareness_map import squareness_map

    source = LoopSource(result.final, measured_range(result.final))
    scenario = build_scenario(seed, plan=truth["plan"]["source"])
    tool = np.asarray(truth["plan"]["tool_offset_mm"], float)
    out = {}
    for entry in squareness_map(source):
        sid, ranges = entry.squareness_id, entry.volume_mm
        true = np.array([true_path_angle(scenario, tool, sid, p, ranges) for p in entry.places_mm])
        errors = entry.angle_urad - true
        out[sid] = (
            float(errors[entry.centre]),
            entry.at_centre_std_urad,
            float(np.max(np.abs(errors))),
            errors / entry.std_urad,
        )
    return out
