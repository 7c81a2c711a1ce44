"""Self-test of the blind scenario generator (tests/blind): its rigid-body machine against a
first-order formula derived here from DESIGN.md's chain, its gauge, its effects on a perfect
machine, and that the files it writes import with volucal (the test may import volucal; the
generator never does)."""

from __future__ import annotations

import ast
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from . import effects as fx
from .laser import LineSchedule, LineSpec, measure_line
from .machine import (
    ARCSEC_URAD,
    AXES,
    ERROR_IDS,
    Machine,
    error_kind,
    random_machine,
    rotation_matrices,
    rotation_vectors,
    stroke_grid,
)
from .rigid_fit import RigidProjector
from .scenarios import (
    CATALOGUE,
    OUTSIDE,
    build_scenario,
    draw_plan_and_category,
    make_scenario,
    rigid_family_residual,
    write_scenario,
)

STROKE = {"X": (0.0, 400.0), "Y": (0.0, 400.0), "Z": (0.0, 350.0)}
HERE = Path(__file__).resolve().parent


def cross_um(eps_urad: np.ndarray, lever_mm: np.ndarray) -> np.ndarray:
    return np.cross(eps_urad, lever_mm) * 1e-3


def first_order(machine: Machine, q: np.ndarray, tool: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Volumetric error and rotation to first order, derived from
    T = T(x)·E_X·T(y)·E_Y·T(z)·E_Z·T(tool) with R ≈ I + [ε]× (chain WXYFZT):

        E = δX + δY + δZ + εX × (0, y, z) + εY × (0, 0, z) + (εX + εY + εZ) × t
            + (−(y − y0)·EC0Y + (z − z0)·EB0Z, −(z − z0)·EA0Z, 0)
        rotation = εX + εY + εZ

    In another order the same product gives each ε acting through the travel of the axes the
    chain lists after it (written out here by the order's letters, not by the machine's code).
    """
    n = len(q)
    t = np.broadcast_to(tool, (n, 3))
    d, e = {}, {}
    for i, axis in enumerate(AXES):
        d[axis], e[axis] = machine.axis_errors(axis, q[:, i])
    order = [c for c in machine.chain if c in "XYZ"]
    error = d["X"] + d["Y"] + d["Z"]
    for k, axis in enumerate(order):
        travel = np.zeros((n, 3))
        for later in order[k + 1:]:
            travel[:, "XYZ".index(later)] = q[:, "XYZ".index(later)]
        error = error + cross_um(e[axis], travel)
    error = error + cross_um(e["X"] + e["Y"] + e["Z"], t)
    sq, ref = machine.squareness_urad, machine.reference_mm
    error[:, 0] += (-(q[:, 1] - ref["Y"]) * sq["EC0Y"] + (q[:, 2] - ref["Z"]) * sq["EB0Z"]) * 1e-3
    error[:, 1] += -(q[:, 2] - ref["Z"]) * sq["EA0Z"] * 1e-3
    return error, e["X"] + e["Y"] + e["Z"]


def scaled(machine: Machine, k: float) -> Machine:
    functions = {i: dataclasses.replace(f, scale=f.scale * k) for i, f in machine.functions.items()}
    squareness = {i: v * k for i, v in machine.squareness_urad.items()}
    return dataclasses.replace(machine, functions=functions, squareness_urad=squareness)


def positions(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.stack([rng.uniform(*STROKE[a], n) for a in AXES], axis=1)


# --------------------------------------------------------------------------------------------
# The rigid-body machine
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed, chain", [(0, "WXYFZT"), (1, "WXYFZT"), (2, "WXYFZT"),
                                         (3, "WFYXZT"), (4, "WYXFZT"), (5, "WZFYXT")])
def test_exact_chain_agrees_with_first_order_formula(seed: int, chain: str) -> None:
    rng = np.random.default_rng(seed)
    machine = random_machine(rng, STROKE, chain=chain)
    q = positions(rng, 300)
    tool = np.array([rng.uniform(-100, 100), rng.uniform(-100, 100), rng.uniform(0, 300)])
    exact, rot = machine.pose_error(q, tool)
    approx, rot1 = first_order(machine, q, tool)
    # What is left is second order: (25 µrad)² × 700 mm and 25 µrad × 15 µm, below 1 nm.
    assert np.max(np.abs(exact - approx)) < 2e-3
    assert np.max(np.abs(rot - rot1)) < 1e-3
    assert np.max(np.abs(exact)) > 1.0  # the errors are not trivially zero


def test_what_first_order_misses_is_second_order() -> None:
    """Scaling every error by k scales exact − first order by k²: the first-order part is right."""
    rng = np.random.default_rng(7)
    machine = random_machine(rng, STROKE)
    q = positions(rng, 200)
    tool = np.array([30.0, -40.0, 200.0])
    gaps = []
    for k in (50.0, 100.0):
        m = scaled(machine, k)
        exact, _ = m.pose_error(q, tool)
        approx, _ = first_order(m, q, tool)
        gaps.append(np.max(np.abs(exact - approx)))
    assert 3.5 < gaps[1] / gaps[0] < 4.5


class Linear:
    """f(p) = slope·(p − reference): a hand-made error function for sign checks."""

    def __init__(self, slope: float = 0.0, reference: float = 0.0) -> None:
        self.slope, self.reference = slope, reference

    def __call__(self, p):
        return self.slope * (np.asarray(p, dtype=float) - self.reference)


def perfect_machine(**functions: float) -> Machine:
    """All errors zero except the named ones, each ``slope``·position (µm or µrad per mm);
    squareness given as EC0Y=..., in µrad."""
    fns = {i: Linear(functions.get(i, 0.0)) for a in AXES for i in ERROR_IDS[a]}
    square = {k: functions.get(k, 0.0) for k in ("EC0Y", "EB0Z", "EA0Z")}
    return Machine(STROKE, {a: 0.0 for a in AXES}, fns, square)


def test_iso_signs_of_squareness_and_lever_arms() -> None:
    q = np.array([[100.0, 200.0, 300.0]])
    none = np.zeros(3)
    # DESIGN.md: x = −y·EC0Y, x = +z·EB0Z, y = −z·EA0Z.
    assert perfect_machine(EC0Y=10.0).pose_error(q, none)[0][0] == pytest.approx(
        [-200 * 10e-3, 0, 0], abs=1e-9)
    assert perfect_machine(EB0Z=10.0).pose_error(q, none)[0][0] == pytest.approx(
        [300 * 10e-3, 0, 0], abs=1e-9)
    assert perfect_machine(EA0Z=10.0).pose_error(q, none)[0][0] == pytest.approx(
        [0, -300 * 10e-3, 0], abs=1e-9)
    # Y's angles act through z and the tool only, never through x: yaw ECY moves x by −ECY·t_y.
    e, _ = perfect_machine(ECY=0.1).pose_error(q, np.array([0.0, 50.0, 0.0]))
    assert e[0] == pytest.approx([-0.1 * 200 * 50 * 1e-3, 0, 0], rel=1e-6, abs=1e-4)
    # X's pitch EBX (about Y) moves x by +EBX·(z + t_z).
    e, _ = perfect_machine(EBX=0.1).pose_error(q, np.array([0.0, 0.0, 200.0]))
    assert e[0] == pytest.approx([0.1 * 100 * 500 * 1e-3, 0, 0], rel=1e-6, abs=1e-4)
    # X's roll EAX (about X) moves z by +EAX·(y + t_y): the table tilts under the tool.
    e, _ = perfect_machine(EAX=0.1).pose_error(q, none)
    assert e[0] == pytest.approx([0, -0.1 * 100 * 300 * 1e-3, 0.1 * 100 * 200 * 1e-3],
                                 rel=1e-6, abs=1e-4)


def test_a_gantrys_bridge_yaw_acts_through_the_carriages_travel() -> None:
    """"WFYXZT": the bridge (Y) carries the carriage (X), so Y's yaw ECY turns x into y, which it
    never does in "WXYFZT"; X's yaw turns only the tool's offset."""
    q = np.array([[300.0, 200.0, 100.0]])
    none = np.zeros(3)
    gantry = dataclasses.replace(perfect_machine(ECY=0.1), chain="WFYXZT")
    e, rot = gantry.pose_error(q, none)
    # ECY(y) = 0.1 µrad/mm × 200 mm = 20 µrad about Z: (x, 0, 0) → y += 20e-6 · 300 mm
    assert e[0] == pytest.approx([0, 20e-6 * 300 * 1e3, 0], rel=1e-6, abs=1e-3)  # x: −x·θ²/2
    assert rot[0] == pytest.approx([0, 0, 20.0], rel=1e-9)
    assert perfect_machine(ECY=0.1).pose_error(q, none)[0][0] == pytest.approx([0, 0, 0], abs=1e-9)
    e, _ = dataclasses.replace(perfect_machine(ECX=0.1), chain="WFYXZT").pose_error(q, none)
    assert e[0] == pytest.approx([0, 0, 0], abs=1e-9)
    with pytest.raises(ValueError, match="chain 'WXYZT'"):
        random_machine(np.random.default_rng(0), STROKE, chain="WXYZT")


def test_rotation_round_trip() -> None:
    rng = np.random.default_rng(3)
    w = rng.normal(0, 3e-5, (50, 3))
    r = rotation_matrices(w)
    assert np.allclose(r @ np.transpose(r, (0, 2, 1)), np.eye(3), atol=1e-15)
    assert np.allclose(rotation_vectors(r), w, rtol=1e-9, atol=1e-18)


@pytest.mark.parametrize("seed", range(6))
def test_gauge_and_sizes(seed: int) -> None:
    machine = random_machine(np.random.default_rng(seed), STROKE)
    for axis in AXES:
        grid = stroke_grid(STROKE[axis])
        for error_id in ERROR_IDS[axis]:
            f = machine.functions[error_id]
            values = f(grid)
            assert abs(float(f(machine.reference_mm[axis]))) < 1e-9, error_id
            kind = error_kind(error_id)
            if kind == "straightness":
                pc = grid - grid.mean()
                assert abs(pc @ values / (pc @ pc)) < 1e-10, error_id
                assert 2.0 - 1e-9 <= np.ptp(values) <= 8.0 + 1e-9
            elif kind == "positioning":
                assert 3.0 - 1e-9 <= np.max(np.abs(values)) <= 15.0 + 1e-9
            else:
                assert 5.0 - 1e-9 <= np.max(np.abs(values)) <= 25.0 + 1e-9
            # Smooth for a 50 mm cubic B-spline basis: the second difference at 1 mm is tiny.
            fine = f(np.arange(STROKE[axis][0], STROKE[axis][1] + 1.0))
            assert np.max(np.abs(np.diff(fine, 2))) < 0.01 * max(np.ptp(fine), 1.0)
    for value in machine.squareness_urad.values():
        assert 2.0 <= abs(value) / ARCSEC_URAD <= 10.0


# --------------------------------------------------------------------------------------------
# The laser and the effects, on a perfect machine
# --------------------------------------------------------------------------------------------


def x_line(quantity: str = "linear", reflector=(0.0, 0.0, 200.0), runs: int = 4,
           sensitive=None) -> LineSchedule:
    spec = LineSpec("x", quantity, np.zeros(3), np.array([1.0, 0.0, 0.0]),
                    None if sensitive is None else np.asarray(sensitive, dtype=float),
                    np.asarray(reflector, dtype=float), {})
    targets = np.linspace(0.0, 400.0, 21)
    times = np.arange(runs * 21, dtype=float).reshape(runs, 21) * 5.0
    return LineSchedule(spec, targets, runs, times)


def test_reversal_cosine_and_abbe_on_a_perfect_machine() -> None:
    line = x_line()
    flat = perfect_machine()
    reversal = fx.Reversal("X", STROKE["X"], 0.0, -3.0, -3.0)
    readings = measure_line(flat, [reversal], line)
    assert np.allclose(readings[0], 0.0) and np.allclose(readings[1], 3.0)  # x̄↑ − x̄↓ = −3
    theta = 3e-3
    cosine = fx.CosineError("x", 3.0, (0.0, 1.0, 0.0))
    readings = measure_line(flat, [cosine], line)
    assert np.allclose(readings[0], -(1 - np.cos(theta)) * line.targets_mm * 1e3)
    pitch = perfect_machine(EBX=0.05)  # µrad per mm of x
    abbe = fx.AbbeOffset("x", (0.0, 0.0, 60.0))
    extra = measure_line(pitch, [abbe], line) - measure_line(pitch, [], line)
    assert np.allclose(extra[0], 0.05 * line.targets_mm * 60.0 * 1e-3)


def test_thermal_drift_and_straightness_slope() -> None:
    line = x_line(runs=2)
    drift = fx.ThermalDrift("X", 0.0, 11.5, 1.0, 1200.0)
    readings = measure_line(perfect_machine(), [drift], line)
    t = line.time_s
    expected = 11.5e-3 * (1 - np.exp(-t / 1200.0)) * line.targets_mm
    assert np.allclose(readings, expected)
    straight = x_line("straightness", sensitive=(0, 1, 0))
    straight.alignment_um_per_mm = 0.01
    readings = measure_line(perfect_machine(EYX=0.0), [], straight)
    assert np.allclose(readings, 0.01 * line.targets_mm)


def test_laser_is_zeroed_at_the_first_target_of_the_first_run() -> None:
    rng = np.random.default_rng(11)
    machine = random_machine(rng, STROKE)
    line = x_line()
    readings = measure_line(machine, [], line)
    assert readings[0, 0] == 0.0
    assert np.max(np.abs(readings)) > 0.5


def test_rigid_projection_absorbs_a_rigid_machine_but_not_a_reversal() -> None:
    s = build_scenario(4, plan="resources/plans/direct.toml", category="clean")
    projector = RigidProjector(s.plan, s.session.lines)
    base = {line.spec.name: measure_line(s.machine, [], line) for line in s.session.lines}
    assert max(np.max(np.abs(v)) for v in base.values()) > 5.0
    assert max(projector.residual_peaks(base).values()) < 0.02  # smooth 21 errors: absorbed
    reversal = fx.Reversal("X", STROKE["X"], 0.0, 2.0, 2.0)
    diffs = {line.spec.name: measure_line(s.machine, [reversal], line) - base[line.spec.name]
             for line in s.session.lines}
    assert max(projector.residual_peaks(diffs).values()) == pytest.approx(1.0, abs=1e-6)


def test_rigid_fit_recovers_the_functions_and_angles_of_a_rigid_machine() -> None:
    # the demo plan sees every function; a straightness is known up to its slope, and of a
    # squareness only the angle between its two axes (squareness plus both straightness slopes)
    s = build_scenario(4, plan="resources/demo/plan.toml", category="clean")
    projector = RigidProjector(s.plan, s.session.lines)
    base = {line.spec.name: measure_line(s.machine, [], line) for line in s.session.lines}
    functions, squareness, share = projector.fit(base)
    assert share < 1e-3

    def values(eid: str, fitted: bool) -> tuple[np.ndarray, np.ndarray]:
        q = np.linspace(*s.machine.stroke_mm[eid[2]], 81)
        if fitted:
            return q, projector.function_values(eid, functions[eid], q)
        return q, s.machine.functions[eid](q)

    for eid in functions:
        q, difference = values(eid, True)[0], values(eid, True)[1] - values(eid, False)[1]
        if error_kind(eid) == "straightness":
            difference -= np.polyval(np.polyfit(q, difference, 1), q)
        assert np.sqrt(np.mean(difference**2)) < 0.01, eid
    pairs = {"EC0Y": (("EXY", "EYX"), -1.0), "EB0Z": (("EXZ", "EZX"), 1.0),
             "EA0Z": (("EYZ", "EZY"), -1.0)}
    def angle(sid: str, fitted: bool) -> float:
        straightness, sign = pairs[sid]
        value = squareness[sid] if fitted else s.machine.squareness_urad[sid]
        slopes = (np.polyfit(*values(eid, fitted), 1)[0] for eid in straightness)
        return value + sign * 1e3 * sum(slopes)

    for sid in pairs:
        assert angle(sid, True) == pytest.approx(angle(sid, False), abs=0.01), sid


def test_rigid_family_of_cross_axis_surfaces() -> None:
    grid = np.linspace(-1, 1, 21)
    u, v = np.meshgrid(grid, grid, indexing="ij")
    # EZ(x, y) = x·y is X's roll growing along x acting through y: rigid.
    assert np.max(np.abs(rigid_family_residual("Z", ("X", "Y"), u * v, u, v))) < 1e-10
    # EY(x, y) = x·y: no rigid-body error of this chain produces it.
    assert np.max(np.abs(rigid_family_residual("Y", ("X", "Y"), u * v, u, v))) > 0.9
    # EZ(x, y) = x·y²: not rigid either (Y's angles never act through x).
    assert np.max(np.abs(rigid_family_residual("Z", ("X", "Y"), u * v**2, u, v))) > 0.3
    # On a gantry ("WFYXZT") Y comes first: Y's roll growing along y acting through x is rigid,
    # X's through y is not.
    gantry = ("Z", ("X", "Y"))
    assert np.max(np.abs(rigid_family_residual(*gantry, u * v**2, u, v, "WFYXZT"))) < 1e-10
    assert np.max(np.abs(rigid_family_residual(*gantry, u**2 * v, u, v, "WFYXZT"))) > 0.3


# --------------------------------------------------------------------------------------------
# Scenarios
# --------------------------------------------------------------------------------------------


def test_category_shares() -> None:
    draws = [draw_plan_and_category(seed)[1] for seed in range(3000)]
    shares = {c: draws.count(c) / len(draws) for c in ("clean", "effects", "outside")}
    assert shares["clean"] == pytest.approx(0.2, abs=0.03)
    assert shares["effects"] == pytest.approx(0.6, abs=0.03)
    assert shares["outside"] == pytest.approx(0.2, abs=0.03)


@pytest.mark.parametrize("kind", CATALOGUE + OUTSIDE)
def test_every_effect_kind_builds_and_is_described(kind: str) -> None:
    made = make_scenario(5, plan="resources/plans/twelve-line.toml", kinds=[kind])
    truth = json.loads(json.dumps(made["truth"]))
    assert len(truth["machine"]["functions"]) == 18
    assert set(truth["machine"]["squareness_urad"]) == {"EC0Y", "EB0Z", "EA0Z"}
    (effect,) = truth["effects"]
    assert effect["kind"] == (kind if kind in CATALOGUE else f"outside:{kind}")
    vis = effect["visibility"]
    assert vis["peak"] > 0 and vis["line"] in vis["per_line"]
    assert vis["after_rigid_fit_peak"] >= 0 and vis["after_rigid_fit_line"]
    expected = truth["expected"]
    if kind in OUTSIDE:
        assert expected["outside"] == [f"outside:{kind}"] and expected["catalogue_effects"] == []
    else:
        assert len(expected["catalogue_effects"]) == int(vis["visible_after_rigid_fit"])
    if kind in ("abbe_offset", "cosine"):
        assert effect["axis"] is None and effect["line"]
    elif kind == "cross_axis":
        assert effect["axis"] in AXES and len(effect["depends_on"]) == 2
    elif kind == "local":
        assert effect["axis"] in AXES and effect["direction"] in AXES


def test_scenarios_are_deterministic() -> None:
    assert make_scenario(21) == make_scenario(21)


def _import(plan_path: Path):
    from volucal.core.io.plan import import_plan, load_plan

    return {line.name: line.corrected for line in import_plan(load_plan(plan_path)).lines}


def test_written_files_import_with_volucal(tmp_path: Path) -> None:
    plan_path, truth = write_scenario(2, tmp_path, plan="resources/plans/direct.toml",
                                      kinds=["thermal_drift", "reversal"], material_logged=True)
    scenario = build_scenario(2, plan="resources/plans/direct.toml",
                              kinds=["thermal_drift", "reversal"], material_logged=True)
    imported = _import(plan_path)
    assert set(imported) == {line.spec.name for line in scenario.session.lines}
    drift = next(e for e in scenario.effects if isinstance(e, fx.ThermalDrift))
    base = truth["session"]["environment"]["material_base_c"]
    for line in scenario.session.lines:
        data = imported[line.spec.name]
        assert np.allclose(data.targets_mm, line.targets_mm, atol=1e-9)
        assert np.allclose(data.deviations, scenario.deviations[line.spec.name], atol=6e-5)
        assert list(data.run_direction) == list(line.run_direction())
        their_times = data.start_time + data.times_s
        our_times = scenario.session.start_posix + line.time_s
        assert np.max(np.abs(their_times - our_times)) < 120.0
        # The logged material temperature follows the drift: base + ΔT(t) at the file's ends.
        start = data.start_time - scenario.session.start_posix
        end = start + (line.time_s.max() - line.time_s.min()) * line.time_s.size / (
            line.time_s.size - 1)
        sensors = np.asarray(data.environment.material_temp_c).mean(axis=0)
        assert sensors == pytest.approx([base + drift.delta_t(start), base + drift.delta_t(end)],
                                        abs=0.01)


def test_volucal_cli_imports_a_scenario(tmp_path: Path) -> None:
    plan_path, _ = write_scenario(8, tmp_path / "s", plan="resources/demo/plan.toml")
    volucal = Path(sys.executable).with_name("volucal")
    done = subprocess.run([str(volucal), "import", str(tmp_path / "p.h5"), str(plan_path)],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "49 line(s)" in done.stdout


def test_generator_never_imports_volucal() -> None:
    for path in HERE.glob("*.py"):
        if path.name.startswith("test_"):
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            assert not any(n.split(".")[0] == "volucal" for n in names), path.name
