"""A simulated laser interferometer session over the lines of a plan.toml, and its log files.

- ``read_plan``: the plan's machine and lines (tomllib; DESIGN.md's plan.toml contract).
- ``schedule_session``: targets along every line (this generator's own spacing rules), bidirectional
  runs and the time of every reading (feed, settling, dwell, overrun at each reversal, set-up gaps).
- ``measure_line``: the readings of one line on a machine with effects: the laser zeroed at the
  first target of the first run, straightness optics with an alignment slope, Gaussian noise.
- ``rtl_text`` / ``plan_text``: Renishaw-style .rtl/.rta text (REFERENCE.md §5) and a plan.toml.

Pure numpy + tomllib; never imports volucal.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from .effects import Effect, Readings
from .machine import AXES, PAPER_CHAIN, Machine, chain_axes

# --------------------------------------------------------------------------------------------
# Plan
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LineSpec:
    name: str
    quantity: str
    start_mm: np.ndarray
    direction: np.ndarray
    sensitive: np.ndarray | None
    reflector_mm: np.ndarray
    entry: dict

    @property
    def angular(self) -> bool:
        return self.quantity == "angular"

    @property
    def axis_label(self) -> str:
        moving = [a for a, c in zip(AXES, self.direction, strict=True) if abs(c) > 1e-9]
        return "".join(moving)


@dataclass(frozen=True)
class PlanSpec:
    path: Path
    machine: dict
    stroke_mm: dict[str, tuple[float, float]]
    reference_mm: dict[str, float] | None
    screw_lead_mm: dict[str, float]
    tool_offset_mm: np.ndarray
    lines: tuple[LineSpec, ...]
    chain: str = PAPER_CHAIN


def read_plan(path: str | Path) -> PlanSpec:
    """Machine and lines of a plan.toml (files are ignored: the generator writes its own)."""
    path = Path(path)
    document = tomllib.loads(path.read_text(encoding="utf-8"))
    machine = document["machine"]
    chain = str(machine.get("chain", PAPER_CHAIN))
    try:
        chain_axes(chain)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    stroke = {a: (float(machine["stroke"][a][0]), float(machine["stroke"][a][1])) for a in AXES}
    reference = None
    if "reference" in machine:
        reference = {a: float(v) for a, v in zip(AXES, machine["reference"], strict=True)}
    tool = np.asarray(machine.get("tool_offset", [0.0, 0.0, 0.0]), dtype=float)
    lines = []
    for entry in document["line"]:
        direction = np.asarray(entry["direction"], dtype=float)
        direction = direction / np.linalg.norm(direction)
        sensitive = entry.get("sensitive")
        lines.append(LineSpec(
            name=entry.get("name", Path(entry["file"]).stem),
            quantity=entry["quantity"],
            start_mm=np.asarray(entry["start"], dtype=float),
            direction=direction,
            sensitive=None if sensitive is None else np.asarray(sensitive, dtype=float),
            reflector_mm=np.asarray(entry.get("reflector", tool), dtype=float),
            entry=dict(entry),
        ))
    return PlanSpec(path, dict(machine), stroke, reference,
                    {k: float(v) for k, v in machine.get("screw_lead", {}).items()}, tool,
                    tuple(lines), chain)


def line_length(spec: LineSpec, stroke_mm: dict[str, tuple[float, float]]) -> float:
    """The longest travel from the line's start along its direction inside the strokes."""
    best = np.inf
    for i, axis in enumerate(AXES):
        lo, hi = min(stroke_mm[axis]), max(stroke_mm[axis])
        c = spec.direction[i]
        if abs(c) < 1e-12:
            continue
        limit = (hi - spec.start_mm[i]) / c if c > 0 else (lo - spec.start_mm[i]) / c
        best = min(best, limit)
    return float(np.floor(best * 100 + 1e-6) / 100)


# --------------------------------------------------------------------------------------------
# Session: targets and times
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SessionSettings:
    """How the operator measured: drawn once per scenario (see README)."""

    runs_per_direction: int
    spacing: str  # jittered | irregular | fine
    stride_mm: float
    jitter: float
    feed_mm_per_min: float
    dwell_s: float
    settle_s: float
    overrun_mm: float
    gap_min_s: float
    gap_max_s: float
    shuffle_lines: bool


def draw_settings(rng: np.random.Generator) -> SessionSettings:
    spacing = str(rng.choice(["jittered", "irregular", "fine"], p=[0.5, 0.3, 0.2]))
    return SessionSettings(
        runs_per_direction=int(rng.integers(3, 6)),
        spacing=spacing,
        stride_mm=float(rng.uniform(8.0, 25.0)),
        jitter=float(rng.uniform(0.15, 0.35)),
        feed_mm_per_min=float(rng.uniform(1000.0, 4000.0)),
        dwell_s=float(rng.uniform(1.5, 4.0)),
        settle_s=float(rng.uniform(0.3, 1.0)),
        overrun_mm=float(rng.uniform(2.0, 5.0)),
        gap_min_s=300.0,
        gap_max_s=1200.0,
        shuffle_lines=bool(rng.random() < 0.25),
    )


#: The longest line (mm) on which the operator keeps the drawn stride; on a longer line the stride
#: grows in proportion (a 3 m axis is not measured every 8–25 mm).
STRIDE_LENGTH_MM = 1500.0


def stride_scale(length_mm: float) -> float:
    """How much the operator widens the drawn stride on a line of ``length_mm``: 1 up to
    :data:`STRIDE_LENGTH_MM`, then the length over it."""
    return max(1.0, float(length_mm) / STRIDE_LENGTH_MM)


def targets_along(rng: np.random.Generator, length: float, settings: SessionSettings,
                  fine: bool, scale: float = 1.0) -> np.ndarray:
    """Target positions (mm from the datum), first 0 and last ``length``, strictly increasing.

    jittered: an even grid near the stride with every interior target moved by up to
    ±jitter·step (ISO 230-2's advice against periodic errors hiding at regular steps);
    irregular: gaps drawn uniformly in [0.5, 1.5]·stride then rescaled to the length (the stride
    of both is ``stride_mm`` × ``scale``, :func:`stride_scale`);
    fine (axis-parallel linear lines only): a jittered 2.5–6 mm grid, at most 161 targets.
    """
    if fine:
        stride = float(rng.uniform(2.5, 6.0))
        count = min(int(round(length / stride)), 160) + 1
    else:
        stride = settings.stride_mm * scale
        count = max(int(round(length / stride)), 5) + 1
    if settings.spacing == "irregular" and not fine:
        gaps = rng.uniform(0.5, 1.5, count - 1)
        targets = np.concatenate([[0.0], np.cumsum(gaps / gaps.sum() * length)])
    else:
        targets = np.linspace(0.0, length, count)
        step = length / (count - 1)
        targets[1:-1] += rng.uniform(-settings.jitter, settings.jitter, count - 2) * step
    targets = np.round(targets, 2)
    targets[-1] = length
    if np.any(np.diff(targets) <= 0):
        raise AssertionError("targets must increase")
    return targets


@dataclass
class LineSchedule:
    """One line as measured: targets, run count, reading times (runs, targets; target index
    ascending), the optics' alignment slope (straightness) and the file's row layout."""

    spec: LineSpec
    targets_mm: np.ndarray
    runs: int
    time_s: np.ndarray
    alignment_um_per_mm: float = 0.0
    backward_rows: str = "visit"  # "visit" (K → 1) or "ascending" (1 → K)
    environment: dict = field(default_factory=dict)

    @property
    def first_s(self) -> float:
        return float(self.time_s.min())

    @property
    def last_s(self) -> float:
        return float(self.time_s.max())

    def run_direction(self) -> np.ndarray:
        return np.array([1 if r % 2 == 0 else -1 for r in range(self.runs)])

    def readings(self) -> Readings:
        k = len(self.targets_mm)
        run = np.repeat(np.arange(self.runs), k)
        target = np.tile(np.arange(k), self.runs)
        sign = self.run_direction()[run]
        visit = np.where(sign > 0, target, k - 1 - target)
        along = self.targets_mm[target]
        position = self.spec.start_mm + np.outer(along, self.spec.direction)
        moving = np.where(np.abs(self.spec.direction) > 1e-9, np.sign(self.spec.direction), 0.0)
        approach = np.outer(sign, moving)
        return Readings(self.spec.name, self.spec.quantity, position, along, approach,
                        self.time_s.reshape(-1), run, visit)


@dataclass
class Session:
    lines: list[LineSchedule]
    start_posix: float
    settings: SessionSettings

    @property
    def end_s(self) -> float:
        return max(line.last_s for line in self.lines)


def schedule_session(rng: np.random.Generator, plan: PlanSpec, settings: SessionSettings,
                     start_posix: float) -> Session:
    """Targets and reading times of every line, in measuring order, t = 0 at the first reading.

    A line: the laser is zeroed at its first target; forward runs visit targets 1 → K, backward
    runs K → 1; between targets the machine moves at the feed, settles and dwells (the reading is
    taken at the end of the dwell); at each reversal it overruns by ``overrun_mm`` and comes back
    so every target of a run is approached from the same side. Set-up gaps of 5–20 min separate
    lines (alignment of the next optics).
    """
    order = list(range(len(plan.lines)))
    if settings.shuffle_lines:
        rng.shuffle(order)
    speed = settings.feed_mm_per_min / 60.0
    clock = 0.0
    schedules = []
    for n, index in enumerate(order):
        spec = plan.lines[index]
        length = line_length(spec, plan.stroke_mm)
        fine = (settings.spacing == "fine" and spec.quantity == "linear"
                and int(np.sum(np.abs(spec.direction) > 1e-9)) == 1)
        targets = targets_along(rng, length, settings, fine, stride_scale(length))
        runs = 2 * settings.runs_per_direction
        k = len(targets)
        times = np.empty((runs, k))
        if n > 0:
            clock += rng.uniform(settings.gap_min_s, settings.gap_max_s)
        position = targets[0]
        first = True
        for r in range(runs):
            visit = range(k) if r % 2 == 0 else range(k - 1, -1, -1)
            if r > 0:
                clock += 2 * settings.overrun_mm / speed + settings.settle_s
            for t in visit:
                if not first:
                    clock += abs(targets[t] - position) / speed + settings.settle_s
                    clock += settings.dwell_s * rng.uniform(0.9, 1.1)
                first = False
                times[r, t] = clock
                position = targets[t]
        slope = 0.0
        if spec.quantity == "straightness":
            slope = float(rng.choice([-1, 1]) * rng.uniform(0.002, 0.03))
        schedules.append(LineSchedule(spec, targets, runs, times, slope,
                                      str(rng.choice(["visit", "ascending"]))))
    return Session(schedules, start_posix, settings)


# --------------------------------------------------------------------------------------------
# Measuring
# --------------------------------------------------------------------------------------------


def measure_line(
    machine: Machine,
    effects: list[Effect],
    line: LineSchedule,
    noise: float = 0.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Deviations (runs, targets) of one line, µm (µrad for angular), measured − nominal.

    reading = laser(P_k, context_k) − laser(P_1, context of the first reading) + effects' reading
    terms + N(0, noise²). Linear: the beam b (the travel direction, or tilted by a cosine effect)
    reads b·ΔP_actual − nominal travel; straightness: sensitive·ΔE + alignment slope·travel;
    angular: sensitive·Δ(rotation vector of the tool relative to the workpiece).
    """
    spec = line.spec
    r = line.readings()
    reflector = spec.reflector_mm.astype(float).copy()
    deltas: dict[str, np.ndarray] = {}
    extra = np.zeros((len(r), 3))
    beam_tilt = None
    added = np.zeros(len(r))
    for effect in effects:
        shift = effect.reflector_shift_mm(spec.name)
        if shift is not None:
            reflector = reflector + shift
        for axis, d in effect.axis_delta(r).items():
            deltas[axis] = deltas.get(axis, 0.0) + d
        v = effect.volumetric(r)
        if v is not None:
            extra = extra + v
        b = effect.beam(spec.name)
        if b is not None:
            beam_tilt = b
        a = effect.reading(r)
        if a is not None:
            added = added + a
    error_um, rot_urad = machine.pose_error(r.position_mm, reflector, deltas)
    error_um = error_um + extra
    travel_um = (r.along_mm - r.along_mm[0]) * 1e3
    d_error = error_um - error_um[0]
    if spec.quantity == "linear":
        u = spec.direction
        if beam_tilt is None:
            values = d_error @ u
        else:
            theta, n = beam_tilt
            beam = np.cos(theta) * u + np.sin(theta) * n
            values = d_error @ beam + (beam @ u - 1.0) * travel_um
    elif spec.quantity == "straightness":
        values = d_error @ spec.sensitive + line.alignment_um_per_mm * travel_um * 1e-3
    elif spec.quantity == "angular":
        values = (rot_urad - rot_urad[0]) @ spec.sensitive
    else:
        raise ValueError(f"line {spec.name}: unknown quantity {spec.quantity!r}")
    values = values + added
    if rng is not None and noise > 0:
        values = values + rng.normal(0.0, noise, len(values))
    return values.reshape(line.runs, len(line.targets_mm))


# --------------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------------


def _stamp(posix: float) -> str:
    moment = datetime.fromtimestamp(int(np.floor(posix + 0.5)), tz=UTC)
    months = ("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec")
    return (f"{moment.hour:02d}:{moment.minute:02d}:{moment.second:02d} "
            f"{months[moment.month - 1]} {moment.day:02d} {moment.year}")


def file_times(line: LineSchedule, session_start_posix: float) -> tuple[float, float]:
    """Start and end ``Date Time`` of a file: the first reading, and the last reading plus one mean
    reading interval (the reader spreads R·K readings evenly from start to end)."""
    count = line.time_s.size
    first, last = line.first_s, line.last_s
    step = (last - first) / (count - 1) if count > 1 else 0.0
    return session_start_posix + first, session_start_posix + last + step


def rtl_text(line: LineSchedule, deviations: np.ndarray, session_start_posix: float,
             machine_name: str) -> str:
    """The .rtl (or .rta for an angular line) text of one line, CRLF line ends."""
    spec = line.spec
    env = line.environment
    k = len(line.targets_mm)
    start, end = file_times(line, session_start_posix)
    day = datetime.fromtimestamp(start, tz=UTC).strftime("%Y-%m-%d")
    out = ["HEADER::",
           f"File type : {'Angular' if spec.angular else 'Linear'}",
           "Owner     : blind-generator",
           "Version no: 2",
           "",
           "TARGET DATA::",
           "Filetype  : ISO",
           f"Target-count: {k}",
           "Targets :"]
    for first in range(0, k, 5):
        out.append("".join(f"{t:12.3f}" for t in line.targets_mm[first:first + 5]))
    out += ["Flags: 0 0 2 0", "",
            "USER-TEXT::",
            f"Machine: {machine_name}",
            "Serial No: BLIND-0001",
            f"Date: {day}",
            "By: blind generator",
            f"Axis: {spec.axis_label}",
            "Location: simulated",
            f"TITLE: {spec.name} ({spec.quantity})",
            "",
            "RUNS::",
            f"Run-count: {line.runs}",
            "",
            "DEVIATIONS::",
            "Run Target Data:"]
    for r in range(line.runs):
        order = range(k)
        if r % 2 == 1 and line.backward_rows == "visit":
            order = range(k - 1, -1, -1)
        for t in order:
            out.append(f"{r + 1:>4} {t + 1:>4} {deviations[r, t]:12.4f}")
    if spec.angular:
        out += ["", "EQUIPMENT::", "Optics : angular interferometer", "Reflector : angular"]
    out += ["", "ENVIRONMENT::"]
    air, press, humid = env["air_temp_c"], env["air_pressure_kpa"], env["air_humidity_pct"]
    out.append(f"Air temp   : {air[0]:.2f} {air[1]:.2f} 0")
    out.append(f"Air press  : {press[0]:.3f} {press[1]:.3f} 0")
    out.append(f"Air humid  : {humid[0]:.1f} {humid[1]:.1f}")
    sensors = list(env.get("material_temp_c", []))
    while len(sensors) < 3:
        sensors.append((-10.0, -10.0))
    for index, (a, b) in enumerate(sensors[:3], start=1):
        out.append(f"Mat temp {index} : {a:.2f} {b:.2f} 0")
    coeff = env.get("expansion_ppm_per_c", 11.5)
    out.append(f"Exp coeff  : {coeff:.2f} {coeff:.2f} 0")
    out.append(f'Date Time  : "{_stamp(start)}" "{_stamp(end)}"')
    out += ["", "EOF::", ""]
    return "\r\n".join(out)


def _toml(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float | np.floating | np.integer):
        return repr(float(value)) if isinstance(value, float | np.floating) else str(int(value))
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list | tuple | np.ndarray):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"cannot write {value!r} to TOML")


LINE_FIELDS = ("quantity", "start", "direction", "sensitive", "reflector")


def plan_text(plan: PlanSpec, files: dict[str, str]) -> str:
    """plan.toml (DESIGN.md) of ``plan`` with each line's ``file`` replaced by ``files[name]``."""
    out = ["[machine]"]
    for key in ("name", "chain", "stroke", "screw_lead", "tool_offset", "reference"):
        if key in plan.machine:
            out.append(f"{key} = {_toml(plan.machine[key])}")
    for spec in plan.lines:
        out += ["", "[[line]]", f"name = {_toml(spec.name)}", f"file = {_toml(files[spec.name])}"]
        for key in LINE_FIELDS:
            if key in spec.entry:
                out.append(f"{key} = {_toml(spec.entry[key])}")
        # The logs are written in µm/µrad, measured − nominal, environment already compensated.
        out += [f"deviation_unit = {_toml('urad' if spec.angular else 'um')}", "sign = 1",
                "env_corrected = true"]
    return "\n".join(out) + "\n"
