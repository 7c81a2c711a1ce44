"""An independent virtual machine and laser for testing volucal's closed loop.

Nothing here imports volucal: the machine, its errors, its effects, the laser and the Renishaw-style
log files are written from the conventions of DESIGN.md and the file layout of REFERENCE.md §5
only, with their own parameterisation, so that the loop is proved on data it was not shaped by.

- Rigid-body errors: sums of a few sine half-waves plus a lead (scale) error, in the gauge
  DESIGN.md states (zero at the stroke start; straightness with zero least-squares slope), and
  three squareness angles. The tool point follows the homogeneous-transform chain of a WXYFZT
  machine with exact rotation matrices.
- Machine effects act on the tool point: reversal (constant or varying along the stroke), a cycle
  at any period (with a second harmonic), a thermal drift of the axis scale (first-order, time
  constant τ), a 2-D surface error over two axes (products of orthogonalised sine shapes, not
  polynomials), a raised-cosine guideway bump.
- Set-up effects: an undeclared optics offset (Abbe), a misaligned beam (cosine).
- Effects outside every catalogue: a scale that oscillates in time, twitches of a reflector mount
  on several lines, a laser that drifts as a random walk, a beam interruption re-zeroing one line.
- The laser: zeroed at the first target of the first run, bidirectional runs, travel and dwell
  times, straightness optics with an alignment slope, Gaussian noise; files written as .rtl/.rta
  with start and end time, and material temperature logged at both.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

AXES = "XYZ"
SESSION_START = 1_790_000_000.0  # 2026-09-21T14:13:20Z
#: Effect kinds a closed loop's catalogue is expected to hold (report.json kinds).
CATALOGUE = ("reversal", "cyclic", "thermal_drift", "cross_axis", "local", "abbe_offset", "cosine")


# --------------------------------------------------------------------------------------------
# Smooth error functions in the gauge
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Waves:
    """f(q) = lead·(q − low)/1000 + Σ a_k·sin(k·π·u + φ_k), u = (q − low)/(high − low), then put
    in the gauge: zero at ``low`` and, for a straightness, zero least-squares slope."""

    low: float
    high: float
    amplitudes: tuple[float, ...]
    phases: tuple[float, ...]
    lead_per_m: float = 0.0
    straightness: bool = False

    def raw(self, q: np.ndarray) -> np.ndarray:
        u = (np.asarray(q, float) - self.low) / (self.high - self.low)
        out = self.lead_per_m * (np.asarray(q, float) - self.low) / 1000.0
        for k, (a, phi) in enumerate(zip(self.amplitudes, self.phases, strict=True), start=1):
            out = out + a * np.sin(k * np.pi * u + phi)
        return out

    def __call__(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, float)
        value = self.raw(q)
        if self.straightness:
            grid = np.linspace(self.low, self.high, 2001)
            slope, _ = np.polyfit(grid, self.raw(grid), 1)
            value = value - slope * q
            return value - (self.raw(np.array([self.low]))[0] - slope * self.low)
        return value - self.raw(np.array([self.low]))[0]


def random_waves(
    rng: np.random.Generator, low: float, high: float, size: float, straightness: bool, lead: float
) -> Waves:
    # half-waves of at least 100 mm: smooth enough for the 50 mm default basis
    count = max(1, min(4, int((high - low) // 100)))
    amplitudes = tuple(float(a) for a in rng.normal(0.0, size, count) / np.arange(1, count + 1))
    phases = tuple(float(p) for p in rng.uniform(0, 2 * np.pi, count))
    return Waves(low, high, amplitudes, phases, lead, straightness)


# --------------------------------------------------------------------------------------------
# The rigid-body machine (WXYFZT, DESIGN.md "Conventions")
# --------------------------------------------------------------------------------------------


def rotation(ea: np.ndarray, eb: np.ndarray, ec: np.ndarray) -> np.ndarray:
    """Exact rotation (n, 3, 3) for angles (rad) about X, Y, Z: Rz·Ry·Rx."""
    ca, sa, cb, sb, cc, sc = np.cos(ea), np.sin(ea), np.cos(eb), np.sin(eb), np.cos(ec), np.sin(ec)
    r = np.empty((len(ea), 3, 3))
    r[:, 0, 0] = cc * cb
    r[:, 0, 1] = cc * sb * sa - sc * ca
    r[:, 0, 2] = cc * sb * ca + sc * sa
    r[:, 1, 0] = sc * cb
    r[:, 1, 1] = sc * sb * sa + cc * ca
    r[:, 1, 2] = sc * sb * ca - cc * sa
    r[:, 2, 0] = -sb
    r[:, 2, 1] = cb * sa
    r[:, 2, 2] = cb * ca
    return r


@dataclass
class RigidMachine:
    """Stroke (mm), the 18 error functions keyed by ISO id (µm, µrad) and squareness (µrad)."""

    stroke: dict[str, tuple[float, float]]
    functions: dict[str, Callable[[np.ndarray], np.ndarray]]
    squareness: dict[str, float]
    tool_mm: tuple[float, float, float]

    def _axis_terms(self, axis: str, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotation (n, 3, 3) and translation (n, 3) mm of one axis' error transform."""
        angles = [self.functions[f"E{c}{axis}"](q) * 1e-6 for c in "ABC"]
        shift = np.stack([self.functions[f"E{c}{axis}"](q) for c in AXES], axis=-1) * 1e-3
        if axis == "Y":
            shift[:, 0] -= q * self.squareness["EC0Y"] * 1e-6
        if axis == "Z":
            shift[:, 0] += q * self.squareness["EB0Z"] * 1e-6
            shift[:, 1] -= q * self.squareness["EA0Z"] * 1e-6
        return rotation(*angles), shift

    def tool_point(self, q: np.ndarray, tool: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Actual tool point (n, 3) mm and total rotation (n, 3, 3) at NC positions q (n, 3)."""
        n = len(q)
        rot = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        point = np.zeros((n, 3))
        for k, axis in enumerate(AXES):
            travel = np.zeros((n, 3))
            travel[:, k] = q[:, k]
            point = point + np.einsum("nij,nj->ni", rot, travel)
            r_axis, t_axis = self._axis_terms(axis, q[:, k])
            point = point + np.einsum("nij,nj->ni", rot, t_axis)
            rot = np.einsum("nij,njk->nik", rot, r_axis)
        tool = np.broadcast_to(np.asarray(tool, float), (n, 3))
        point = point + np.einsum("nij,nj->ni", rot, tool)
        return point, rot

    def error_um(self, q: np.ndarray, tool: np.ndarray) -> np.ndarray:
        point, _ = self.tool_point(q, tool)
        return (point - q - tool) * 1e3

    def rotation_urad(self, q: np.ndarray) -> np.ndarray:
        _, rot = self.tool_point(q, np.zeros(3))
        axial = np.stack(
            [rot[:, 2, 1] - rot[:, 1, 2], rot[:, 0, 2] - rot[:, 2, 0], rot[:, 1, 0] - rot[:, 0, 1]],
            axis=-1,
        )
        return axial / 2.0 * 1e6


def random_rigid(
    rng: np.random.Generator, stroke: dict[str, tuple[float, float]], tool: tuple[float, ...]
) -> RigidMachine:
    functions = {}
    for axis in AXES:
        low, high = stroke[axis]
        for c in AXES:
            eid = f"E{c}{axis}"
            positioning = c == axis
            size = 1.5 if positioning else 1.2
            lead = float(rng.normal(0.0, 12.0)) if positioning else 0.0
            functions[eid] = random_waves(rng, low, high, size, not positioning, lead)
        for c in "ABC":
            functions[f"E{c}{axis}"] = random_waves(rng, low, high, 3.0, False, 0.0)
    squareness = {s: float(rng.normal(0.0, 15.0)) for s in ("EC0Y", "EB0Z", "EA0Z")}
    return RigidMachine(dict(stroke), functions, squareness, (tool[0], tool[1], tool[2]))


# --------------------------------------------------------------------------------------------
# Effects
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MachineEffect:
    """An effect on the tool point. ``kind`` and ``target`` name what volucal should report:
    the kind of report.json and its axis (the machine direction it changes)."""

    kind: str
    target: str
    parameters: dict[str, float | str]

    @property
    def where(self) -> str:
        if self.kind == "cross_axis":
            pair = sorted((str(self.parameters["a"]), str(self.parameters["b"])))
            return f"{self.target} over {pair[0]}×{pair[1]}"
        if self.kind == "local":
            return f"{self.target} in {self.parameters['direction']}"
        return self.target

    def error_um(
        self,
        stroke: dict[str, tuple[float, float]],
        q: np.ndarray,
        approach: np.ndarray,
        time_s: np.ndarray,
    ) -> np.ndarray:
        p = self.parameters
        e = np.zeros_like(q)
        if self.kind == "reversal":
            k = AXES.index(self.target)
            low, high = stroke[self.target]
            u = (q[:, k] - low) / (high - low)
            e[:, k] += 0.5 * (float(p["b0"]) + float(p["b1"]) * u) * approach[:, k]
        elif self.kind == "cyclic":
            k = AXES.index(self.target)
            phase = 2 * np.pi * q[:, k] / float(p["period"]) + float(p["phase"])
            e[:, k] += float(p["amp"]) * np.sin(phase) + float(p["amp2"]) * np.sin(2 * phase)
        elif self.kind == "thermal_drift":
            k = AXES.index(self.target)
            low = stroke[self.target][0]
            rise = 1.0 - np.exp(-time_s / float(p["tau"]))
            e[:, k] += float(p["ppm"]) * (q[:, k] - low) * 1e-3 * rise
        elif self.kind == "cross_axis":
            d = AXES.index(self.target)
            e[:, d] += float(p["amp"]) * _surface(stroke, q, p)
        elif self.kind == "local":
            k = AXES.index(self.target)
            x = (q[:, k] - float(p["center"])) / float(p["half_width"])
            bump = np.where(np.abs(x) < 1.0, 0.5 * (1.0 + np.cos(np.pi * x)), 0.0)
            e[:, AXES.index(str(p["direction"]))] += float(p["amp"]) * bump
        elif self.kind == "oscillating_scale":
            k = AXES.index(self.target)
            low = stroke[self.target][0]
            wave = np.sin(2 * np.pi * time_s / float(p["period_s"]) + float(p["phase"]))
            e[:, k] += float(p["ppm"]) * (q[:, k] - low) * 1e-3 * wave
        return e


def _orthogonal_shape(u: np.ndarray, k: float, phi: float) -> np.ndarray:
    """sin(k·π·u + φ) on [0, 1] less its least-squares line, scaled to peak 1 (no part a rigid
    body could take: no constant and no linear term)."""
    grid = np.linspace(0.0, 1.0, 2001)
    raw = np.sin(k * np.pi * grid + phi)
    slope, intercept = np.polyfit(grid, raw, 1)
    scale = np.max(np.abs(raw - slope * grid - intercept))
    return (np.sin(k * np.pi * u + phi) - slope * u - intercept) / scale


def _surface(stroke: dict[str, tuple[float, float]], q: np.ndarray, p: dict) -> np.ndarray:
    out = np.ones(len(q))
    for name in ("a", "b"):
        axis = str(p[name])
        low, high = stroke[axis]
        u = (q[:, AXES.index(axis)] - low) / (high - low)
        out = out * _orthogonal_shape(u, float(p[f"k_{name}"]), float(p[f"phi_{name}"]))
    return out


@dataclass(frozen=True)
class SetupEffect:
    """An effect of one line's set-up: ``abbe_offset`` (optics offset, mm) or ``cosine`` (beam
    misalignment, µrad)."""

    kind: str
    line: str
    parameters: dict[str, float]


@dataclass(frozen=True)
class OutsideEffect:
    """Something no catalogue describes, applied to the readings of some lines."""

    kind: str  # "twitches", "random_walk", "rezero", "oscillating_scale"
    lines: tuple[str, ...]
    parameters: dict[str, float]


# --------------------------------------------------------------------------------------------
# Plan geometry and the laser
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LineSetup:
    name: str
    quantity: str
    start: np.ndarray
    direction: np.ndarray
    sensitive: np.ndarray | None
    reflector: np.ndarray
    length: float


def read_geometry(plan_path: Path) -> tuple[dict, list[LineSetup]]:
    """The machine table and the lines' geometry of a plan.toml (DESIGN.md); each line's length
    is how far it can travel inside the stroke."""
    with open(plan_path, "rb") as handle:
        plan = tomllib.load(handle)
    machine = plan["machine"]
    stroke = {a: (float(v[0]), float(v[1])) for a, v in machine["stroke"].items()}
    tool = np.asarray(machine.get("tool_offset", [0, 0, 0]), float)
    lines = []
    for entry in plan["line"]:
        start = np.asarray(entry["start"], float)
        direction = np.asarray(entry["direction"], float)
        direction = direction / np.linalg.norm(direction)
        length = math.inf
        for k, axis in enumerate(AXES):
            low, high = stroke[axis]
            if direction[k] > 1e-9:
                length = min(length, (high - start[k]) / direction[k])
            elif direction[k] < -1e-9:
                length = min(length, (low - start[k]) / direction[k])
        sensitive = entry.get("sensitive")
        lines.append(
            LineSetup(
                str(entry["name"]),
                str(entry["quantity"]),
                start,
                direction,
                None if sensitive is None else np.asarray(sensitive, float),
                np.asarray(entry.get("reflector", tool), float),
                float(length),
            )
        )
    return {
        "name": machine["name"],
        "chain": machine["chain"],
        "stroke": stroke,
        "tool": tool,
        "screw_lead": machine.get("screw_lead", {}),
    }, lines


@dataclass(frozen=True)
class Laser:
    runs_per_direction: int = 3
    noise: float = 0.1  # µm, and µrad for angular optics
    step_mm: float = 8.0
    jitter_mm: float = 2.0
    feed_mm_s: float = 20.0
    dwell_s: float = 3.0
    setup_s: tuple[float, float] = (300.0, 1200.0)
    alignment_urad: float = 40.0
    log_temperature: bool = True
    expansion_ppm_per_c: float = 11.5


@dataclass
class Scenario:
    """One machine, one plan and what it carries."""

    seed: int
    plan_path: Path
    machine: RigidMachine
    laser: Laser
    effects: list[MachineEffect] = field(default_factory=list)
    setups: list[SetupEffect] = field(default_factory=list)
    outside: list[OutsideEffect] = field(default_factory=list)

    @property
    def expected(self) -> set[tuple[str, str]]:
        """(kind, where) of every catalogue effect it carries: the axis of a machine effect (with
        the two axes of a cross-axis error and the direction of a local defect), the line of a
        set-up effect."""
        machine = {(e.kind, e.where) for e in self.effects if e.kind in CATALOGUE}
        return machine | {(s.kind, s.line) for s in self.setups}


@dataclass
class MeasuredLine:
    setup: LineSetup
    targets: np.ndarray
    deviations: np.ndarray  # (runs, targets), µm or µrad, measured − nominal
    times: np.ndarray  # (runs, targets), s since session start
    start_s: float
    end_s: float
    material_c: tuple[float, float]
    visible: dict[str, float]  # per catalogue effect label: peak contribution after zeroing


def _targets(rng: np.random.Generator, length: float, laser: Laser) -> np.ndarray:
    count = max(2, int(round(length / laser.step_mm)))
    t = np.linspace(0.0, length, count + 1)
    t[1:-1] += rng.uniform(-laser.jitter_mm, laser.jitter_mm, count - 1)
    return np.sort(t)


def measure(scenario: Scenario, seed: int) -> tuple[dict, list[MeasuredLine]]:
    """Measure the scenario's plan once (``seed`` draws the noise, alignments and timing)."""
    rng = np.random.default_rng(seed)
    info, setups = read_geometry(scenario.plan_path)
    laser = scenario.laser
    stroke = info["stroke"]
    clock = 0.0
    out = []
    drift_ppm = sum(
        float(e.parameters["ppm"]) for e in scenario.effects if e.kind == "thermal_drift"
    )
    drift_tau = next(
        (float(e.parameters["tau"]) for e in scenario.effects if e.kind == "thermal_drift"), 3600.0
    )
    for setup in setups:
        targets = _targets(rng, setup.length, laser)
        runs = 2 * laser.runs_per_direction
        k = len(targets)
        times = np.empty((runs, k))
        run_direction = np.array([1 if r % 2 == 0 else -1 for r in range(runs)])
        line_start = clock
        for r in range(runs):
            order = np.arange(k) if run_direction[r] > 0 else np.arange(k)[::-1]
            gaps = np.abs(np.diff(targets[order], prepend=targets[order][0]))
            visit = clock + np.cumsum(gaps / laser.feed_mm_s + laser.dwell_s)
            times[r, order] = visit
            clock = float(visit[-1]) + 4.0  # over-travel and reversal
        nominal = setup.start + np.outer(targets, setup.direction)
        reflector = setup.reflector.copy()
        for s in scenario.setups:
            if s.kind == "abbe_offset" and s.line == setup.name:
                reflector = reflector + np.array([s.parameters[f"d{a}"] for a in "xyz"])
        dev = np.empty((runs, k))
        parts: dict[str, np.ndarray] = {}
        for r in range(runs):
            approach = np.zeros((k, 3))
            approach[:, :] = np.sign(setup.direction)[None, :] * run_direction[r]
            dev[r], contributions = _read(
                scenario, stroke, setup, nominal, approach, times[r], reflector, targets
            )
            for label, value in contributions.items():
                parts.setdefault(label, np.zeros((runs, k)))[r] = value
        for s in scenario.setups:
            if s.kind == "cosine" and s.line == setup.name:
                theta = s.parameters["angle_urad"] * 1e-6
                value = -(1.0 - math.cos(theta)) * targets * 1e3
                dev = dev + value
                parts[f"cosine {s.line}"] = np.broadcast_to(value, dev.shape).copy()
        for o in scenario.outside:
            if setup.name in o.lines:
                dev = _outside(o, setup, dev, targets, times, rng)
        dev = dev + rng.normal(0.0, laser.noise, dev.shape)
        if setup.quantity == "straightness":
            dev = dev + rng.normal(0.0, laser.alignment_urad) * 1e-3 * targets
        dev = dev - dev[0, 0]  # zeroed at the first target of the first run
        material = (20.0, 20.0)
        if laser.log_temperature and drift_ppm:
            rise = drift_ppm / laser.expansion_ppm_per_c
            material = tuple(
                20.0 + rise * (1.0 - math.exp(-t / drift_tau)) for t in (line_start, clock)
            )  # type: ignore[assignment]
        visible = {label: _visible(v, setup, targets) for label, v in parts.items()}
        out.append(MeasuredLine(setup, targets, dev, times, line_start, clock, material, visible))
        clock += float(rng.uniform(*laser.setup_s))
    return info, out


def _read(
    scenario: Scenario,
    stroke: dict[str, tuple[float, float]],
    setup: LineSetup,
    nominal: np.ndarray,
    approach: np.ndarray,
    times: np.ndarray,
    reflector: np.ndarray,
    targets: np.ndarray,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """One run's readings before noise and zeroing, and each machine effect's share of them."""
    machine = scenario.machine
    if setup.quantity == "angular":
        assert setup.sensitive is not None
        return machine.rotation_urad(nominal) @ setup.sensitive, {}
    axis = setup.direction if setup.quantity == "linear" else setup.sensitive
    assert axis is not None
    error = machine.error_um(nominal, reflector)
    contributions = {}
    for effect in scenario.effects:
        e = effect.error_um(stroke, nominal, approach, times)
        contributions[f"{effect.kind} {effect.target}"] = e @ axis
        error = error + e
    return error @ axis, contributions


def _visible(contribution: np.ndarray, setup: LineSetup, targets: np.ndarray) -> float:
    """What of an effect a line shows: its run readings less the line's zero (and alignment
    slope for straightness optics), peak value."""
    columns = [np.ones_like(targets)]
    if setup.quantity == "straightness":
        columns.append(targets)
    basis = np.stack(columns, axis=-1)
    worst = 0.0
    for run in contribution:
        coef, *_ = np.linalg.lstsq(basis, run, rcond=None)
        worst = max(worst, float(np.max(np.abs(run - basis @ coef))))
    return worst


def _outside(
    effect: OutsideEffect,
    setup: LineSetup,
    dev: np.ndarray,
    targets: np.ndarray,
    times: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    p = effect.parameters
    if effect.kind == "twitches":
        # the reflector mount of this line shifts at one place, differently in every run
        center = rng.uniform(targets[0], targets[-1])
        x = (targets - center) / p["half_width"]
        bump = np.where(np.abs(x) < 1.0, 0.5 * (1.0 + np.cos(np.pi * x)), 0.0)
        return dev + p["amp"] * bump * rng.uniform(0.5, 1.0, (dev.shape[0], 1))
    if effect.kind == "random_walk":
        steps = rng.normal(0.0, p["step"], dev.shape).ravel()
        order = np.argsort(times.ravel())
        walk = np.empty_like(steps)
        walk[order] = np.cumsum(steps[order])
        return dev + walk.reshape(dev.shape)
    if effect.kind == "rezero":
        run = int(rng.integers(1, dev.shape[0]))
        out = dev.copy()
        out[run:] += p["step_um"]
        return out
    return dev


# --------------------------------------------------------------------------------------------
# Log files and the plan (REFERENCE.md §5, DESIGN.md plan.toml)
# --------------------------------------------------------------------------------------------


def _stamp(seconds: float) -> str:
    import time as _time

    t = _time.gmtime(SESSION_START + seconds)
    return _time.strftime("%H:%M:%S %b %d %Y", t)


def write_log(path: Path, line: MeasuredLine, machine_name: str) -> None:
    """A Renishaw-style .rtl (.rta for angular optics); backward runs stored in travel order."""
    angular = line.setup.quantity == "angular"
    runs, k = line.deviations.shape
    text = [
        "HEADER::",
        f"File type : {'Angular' if angular else 'Linear'}",
        "Owner     : independent test laser",
        "Version no: 2",
        "",
        "TARGET DATA::",
        "Filetype  : ISO",
        f"Target-count: {k}",
        "Targets :",
    ]
    values = [f"{t:.4f}" for t in line.targets]
    text += ["  " + " ".join(values[i : i + 5]) for i in range(0, k, 5)]
    text += [
        "Flags: 0 0 2 0",
        "",
        "USER-TEXT::",
        f"Machine: {machine_name}",
        "Serial No: IND-0042",
        "By: scenario generator",
        f"Axis: {line.setup.name}",
        "",
        "RUNS::",
        f"Run-count: {runs}",
        "",
    ]
    if angular:
        text += ["EQUIPMENT::", "Optics : angular", ""]
    text += ["DEVIATIONS::", "Run Target Data:"]
    for r in range(runs):
        order = range(k) if r % 2 == 0 else range(k - 1, -1, -1)
        text += [f"{r + 1:4d} {i + 1:4d} {line.deviations[r, i]:12.4f}" for i in order]
    m0, m1 = line.material_c
    text += [
        "",
        "ENVIRONMENT::",
        "Air temp   : 20.200000 20.250000 0",
        "Air press  : 100.900000 100.950000 0",
        "Air humid  : 48.000000 47.000000",
        f"Mat temp 1 : {m0:.6f} {m1:.6f} 0",
        "Mat temp 2 : -10.000000 -10.000000 0",
        "Mat temp 3 : -10.000000 -10.000000 0",
        "Exp coeff  : 11.500000 11.500000 0",
        f'Date Time  : "{_stamp(line.start_s)}" "{_stamp(line.end_s)}"',
        "Final Data : 1 0",
        "",
        "EOF::",
    ]
    path.write_text("\n".join(text) + "\n", encoding="utf-8")


def _vector(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{float(x):.6g}" for x in v) + "]"


def write_session(folder: Path, info: dict, lines: list[MeasuredLine]) -> Path:
    """Write every line's log and a plan.toml that places it; returns the plan's path."""
    logs = folder / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    stroke = ", ".join(f"{a} = [{lo:g}, {hi:g}]" for a, (lo, hi) in info["stroke"].items())
    text = [
        "[machine]",
        f'name = "{info["name"]}"',
        f'chain = "{info["chain"]}"',
        f"stroke = {{ {stroke} }}",
    ]
    if info["screw_lead"]:
        leads = ", ".join(f"{a} = {v:g}" for a, v in info["screw_lead"].items())
        text.append(f"screw_lead = {{ {leads} }}")
    text += [f"tool_offset = {_vector(info['tool'])}", ""]
    for line in lines:
        s = line.setup
        suffix = "rta" if s.quantity == "angular" else "rtl"
        write_log(logs / f"{s.name}.{suffix}", line, info["name"])
        text += [
            "[[line]]",
            f'name = "{s.name}"',
            f'file = "logs/{s.name}.{suffix}"',
            f'quantity = "{s.quantity}"',
            f"start = {_vector(s.start)}",
            f"direction = {_vector(s.direction)}",
        ]
        if s.sensitive is not None:
            text.append(f"sensitive = {_vector(s.sensitive)}")
        text += [f"reflector = {_vector(s.reflector)}", ""]
    path = folder / "plan.toml"
    path.write_text("\n".join(text), encoding="utf-8")
    return path
