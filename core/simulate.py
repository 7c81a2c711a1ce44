"""The virtual machine: ground-truth errors, effects the 21-error model lacks, and a laser.

It feeds the demo, the tests and the benchmarks. A :class:`VirtualMachine` has ground-truth error
functions of realistic magnitude (REFERENCE §4), optional effects (reversal, screw cycle, thermal
drift, Abbe offset and cosine misalignment of a setup, cross-axis sag, a local guideway defect) and
measurement noise. It measures a plan the way a laser does:

- bidirectional runs (5 per direction by default), forward runs approach every target from below,
  backward runs from above;
- the laser is zeroed once, at the first target of the first run: every later reading is relative
  to that one, so drift shows across runs;
- straightness optics carry a random alignment slope (and angular optics an offset);
- lines are measured one after another in a session, so drift shows across lines; every file gets
  its start and end time and its environment.

Sign convention of the readings: deviation = actual − nominal (the plan's default ``sign = +1``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .errors import (
    AXIS_ERROR_IDS,
    ERROR_INFO,
    SQUARENESS_IDS,
    BSplineBasis,
    ErrorFunction,
    ErrorModel,
    gauge_null_space,
)
from .kinematics import VolumetricModel, rotation_error
from .machine import AXES, AXIS_INDEX, PAPER_MACHINE, Machine
from .measurement import Environment, Line, LineData, Measurement
from .plans import PlannedLine

FloatArray = NDArray[np.float64]

#: A controller compensation: (nominal positions (n, 3), approach signs (n, 3)) -> commanded.
Compensation = Callable[[FloatArray, FloatArray], FloatArray]

SESSION_START = 1_767_225_600.0  # 2026-01-01T00:00:00Z: a fixed, readable origin for demo files


# --------------------------------------------------------------------------------------------
# Effects of the virtual machine (ground truth; the closed loop must find them undeclared)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Reversal:
    """Reversal (backlash): ±value/2 along the axis by approach direction, so that the ISO 230-2
    reversal B = x̄↑ − x̄↓ of a line along the axis equals ``value_um`` (negative for an axis that
    lags behind its command)."""

    axis: str
    value_um: float


@dataclass(frozen=True)
class CyclicError:
    """A screw cycle along the axis: amplitude·sin(2π(q − ref)/period + phase), µm."""

    axis: str
    amplitude_um: float
    period_mm: float
    phase_rad: float = 0.0


@dataclass(frozen=True)
class ThermalDrift:
    """The axis scale grows as the machine warms: α·(q − ref)·ΔT(t), with
    ΔT(t) = ΔT∞·(1 − exp(−t/τ)) from the session's first reading. The material temperature logged
    with each file follows 20 °C + ΔT(t)."""

    axis: str
    expansion_ppm_per_c: float
    delta_t_c: float
    time_constant_s: float


@dataclass(frozen=True)
class AbbeSetup:
    """The optics of one line sit ``offset_mm`` away from where the plan says (undeclared)."""

    line: str
    offset_mm: tuple[float, float, float]


@dataclass(frozen=True)
class CosineMisalignment:
    """The beam of one linear line is misaligned by ``angle_urad``: readings scale by cos θ."""

    line: str
    angle_urad: float


@dataclass(frozen=True)
class CrossAxisSag:
    """Error in direction ``axis`` that depends on two axes at once (not a rigid body):
    amplitude·sin(π·(q_along − low)/stroke)·(q_across − ref)/stroke_across, µm."""

    axis: str
    along: str
    across: str
    amplitude_um: float


@dataclass(frozen=True)
class LocalDefect:
    """A guideway bump: error in direction ``direction`` of ``axis`` travel,
    amplitude·exp(−½((q − center)/width)²), µm."""

    axis: str
    direction: str
    center_mm: float
    width_mm: float
    amplitude_um: float


SimEffect = (
    Reversal
    | CyclicError
    | ThermalDrift
    | AbbeSetup
    | CosineMisalignment
    | CrossAxisSag
    | LocalDefect
)


# --------------------------------------------------------------------------------------------
# Ground truth
# --------------------------------------------------------------------------------------------

#: Typical sizes (1 σ of the smooth part) for a precision 400 mm mill, REFERENCE §4.
TRUTH_SCALE = {
    "positioning_um": 3.0,  # smooth deviation on top of the scale error
    "scale_um_per_m": 20.0,  # lead error of a C3 screw, ±12–15 µm over 400–500 mm
    "straightness_um": 2.0,
    "angle_urad": 8.0,
    "squareness_urad": 25.0,
}


def random_truth(
    machine: Machine = PAPER_MACHINE,
    seed: int = 0,
    spacing_mm: float = 50.0,
    scale: Mapping[str, float] | None = None,
) -> ErrorModel:
    """Smooth random ground-truth errors of realistic magnitude, in the identification gauge
    (zero at the reference, straightness with zero least-squares slope)."""
    sizes = dict(TRUTH_SCALE, **(scale or {}))
    rng = np.random.default_rng(seed)
    functions = {}
    for eid in AXIS_ERROR_IDS:
        info = ERROR_INFO[eid]
        axis = info.axis
        assert axis is not None
        low, high = machine.stroke(axis)
        basis = BSplineBasis.uniform(low, high, spacing_mm)
        null = gauge_null_space(basis, machine.reference(axis), info.is_straightness)
        if info.kind == "positioning":
            sigma = sizes["positioning_um"]
        elif info.kind == "straightness":
            sigma = sizes["straightness_um"]
        else:
            sigma = sizes["angle_urad"]
        raw = rng.normal(0.0, sigma, basis.size)
        coefficients = null @ (null.T @ raw)
        if info.kind == "positioning":
            # the scale (lead) error: a straight line through zero at the reference
            slope = rng.normal(0.0, sizes["scale_um_per_m"]) / 1000.0
            greville = basis.knots[1:-1]
            greville = np.convolve(greville, np.ones(basis.degree) / basis.degree, mode="valid")
            coefficients = coefficients + slope * (greville - machine.reference(axis))
        functions[eid] = ErrorFunction(eid, basis, coefficients)
    squareness = {k: float(rng.normal(0.0, sizes["squareness_urad"])) for k in SQUARENESS_IDS}
    return ErrorModel(machine, functions, squareness)


# --------------------------------------------------------------------------------------------
# The machine and its laser
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LaserSetup:
    """How the virtual laser is used: repeats, timing, noise and environment."""

    runs_per_direction: int = 5
    noise_um: float = 0.1
    noise_urad: float = 0.1
    dwell_s: float = 4.0  # time per target (move + settle + read)
    setup_gap_s: float = 900.0  # time to set up the optics between lines
    straightness_slope_urad: float = 50.0  # 1 σ of the optics' alignment slope
    air_temp_c: float = 20.3
    air_pressure_kpa: float = 101.2
    air_humidity_pct: float = 45.0
    material_temp_c: float = 20.1
    expansion_ppm_per_c: float = 11.5


@dataclass(frozen=True, eq=False)
class VirtualMachine:
    """Ground truth plus effects plus a laser."""

    truth: ErrorModel
    effects: tuple[SimEffect, ...] = ()
    seed: int = 0
    laser: LaserSetup = field(default_factory=LaserSetup)

    @property
    def machine(self) -> Machine:
        return self.truth.machine

    # ---- the error of the machine at given states -------------------------------------------

    def effect_error_um(
        self, positions_mm: FloatArray, approach: FloatArray, time_s: FloatArray
    ) -> FloatArray:
        """Volumetric error (µm) of the machine-level effects (not the setup effects)."""
        q = np.atleast_2d(positions_mm)
        e = np.zeros_like(q)
        for effect in self.effects:
            if isinstance(effect, Reversal):
                k = AXIS_INDEX[effect.axis]
                e[:, k] += 0.5 * effect.value_um * approach[:, k]
            elif isinstance(effect, CyclicError):
                k = AXIS_INDEX[effect.axis]
                phase = (
                    2 * np.pi * (q[:, k] - self.machine.reference(effect.axis)) / effect.period_mm
                )
                e[:, k] += effect.amplitude_um * np.sin(phase + effect.phase_rad)
            elif isinstance(effect, ThermalDrift):
                k = AXIS_INDEX[effect.axis]
                delta_t = self.temperature_rise_c(time_s, effect)
                span = q[:, k] - self.machine.reference(effect.axis)
                e[:, k] += effect.expansion_ppm_per_c * 1e-6 * span * delta_t * 1e3
            elif isinstance(effect, CrossAxisSag):
                low, high = self.machine.stroke(effect.along)
                a_low, a_high = self.machine.stroke(effect.across)
                along = q[:, AXIS_INDEX[effect.along]]
                across = q[:, AXIS_INDEX[effect.across]] - self.machine.reference(effect.across)
                shape = np.sin(np.pi * (along - low) / (high - low)) * across / (a_high - a_low)
                e[:, AXIS_INDEX[effect.axis]] += effect.amplitude_um * shape
            elif isinstance(effect, LocalDefect):
                s = (q[:, AXIS_INDEX[effect.axis]] - effect.center_mm) / effect.width_mm
                e[:, AXIS_INDEX[effect.direction]] += effect.amplitude_um * np.exp(-0.5 * s * s)
        return e

    def temperature_rise_c(
        self, time_s: FloatArray, effect: ThermalDrift | None = None
    ) -> FloatArray:
        """Temperature rise of the machine since the session's first reading (°C)."""
        drifts = [effect] if effect else [e for e in self.effects if isinstance(e, ThermalDrift)]
        if not drifts:
            return np.zeros_like(np.asarray(time_s, float))
        d = drifts[0]
        return d.delta_t_c * (1.0 - np.exp(-np.asarray(time_s, float) / d.time_constant_s))

    def error_um(
        self,
        positions_mm: FloatArray,
        approach: FloatArray | None = None,
        time_s: FloatArray | None = None,
        tool_offset_mm: FloatArray | None = None,
    ) -> FloatArray:
        """Volumetric error (µm) at commanded positions with approach signs and times."""
        q = np.atleast_2d(np.asarray(positions_mm, float))
        a = np.ones_like(q) if approach is None else np.asarray(approach, float)
        t = np.zeros(len(q)) if time_s is None else np.asarray(time_s, float)
        geometric = self._volumetric.error(q, tool_offset_mm)
        return geometric + self.effect_error_um(q, a, t)

    @property
    def _volumetric(self) -> VolumetricModel:
        cached = self.__dict__.get("_vm")
        if cached is None:
            cached = VolumetricModel(self.truth)
            object.__setattr__(self, "_vm", cached)
        return cached

    # ---- measuring a plan --------------------------------------------------------------------

    def measure(
        self,
        lines: Sequence[PlannedLine],
        compensation: Compensation | None = None,
        session_start: float = SESSION_START,
        realisation: int = 0,
    ) -> Measurement:
        """Measure every line in order, as one session; returns the data as a laser logs it.

        ``realisation`` numbers independent measurements of the same machine: each has its own
        noise and its own optics alignment, as a new session on a real machine has. Realisation 0
        is the one the demo data were made with; a verification re-measures with others, never
        with the noise the model was fitted to.
        """
        rng = np.random.default_rng([self.seed + 7919, realisation])
        if realisation == 0:
            # the stream the demo data set and its checked-in logs were made with
            rng = np.random.default_rng(self.seed + 7919)
        clock = 0.0
        measured = []
        for planned in lines:
            data, clock = self._measure_line(planned, rng, clock, session_start, compensation)
            measured.append(Line(planned.spec, data))
            clock += self.laser.setup_gap_s
        return Measurement(self.machine, tuple(measured))

    def _measure_line(
        self,
        planned: PlannedLine,
        rng: np.random.Generator,
        clock: float,
        session_start: float,
        compensation: Compensation | None,
    ) -> tuple[LineData, float]:
        spec = planned.spec
        laser = self.laser
        targets = planned.targets_mm
        k = len(targets)
        runs = 2 * laser.runs_per_direction
        direction = np.asarray(spec.direction)
        run_direction = np.array([1 if r % 2 == 0 else -1 for r in range(runs)])
        # reading times: targets visited in travel order, run after run
        times = np.empty((runs, k))
        for r in range(runs):
            order = np.arange(k) if run_direction[r] > 0 else np.arange(k)[::-1]
            times[r, order] = clock + laser.dwell_s * (r * k + np.arange(k))
        end_clock = clock + laser.dwell_s * runs * k
        nominal = spec.positions(targets)  # (k, 3)
        reflector = np.asarray(spec.reflector_mm, float)
        for effect in self.effects:
            if isinstance(effect, AbbeSetup) and effect.line == spec.name:
                reflector = reflector + np.asarray(effect.offset_mm)
        deviations = np.empty((runs, k))
        moving = np.abs(direction) > 1e-12
        for r in range(runs):
            approach = np.ones((k, 3))
            approach[:, moving] = np.sign(direction[moving]) * run_direction[r]
            commanded = nominal if compensation is None else compensation(nominal, approach)
            deviations[r] = self._read(spec, commanded, nominal, approach, times[r], reflector)
        noise = laser.noise_urad if spec.quantity == "angular" else laser.noise_um
        deviations += rng.normal(0.0, noise, deviations.shape)
        # the laser is zeroed once, at the first target of the first run
        deviations -= deviations[0, 0]
        if spec.quantity == "straightness":
            slope = rng.normal(0.0, laser.straightness_slope_urad) * 1e-3  # µm per mm
            deviations += slope * targets
        for effect in self.effects:
            if isinstance(effect, CosineMisalignment) and effect.line == spec.name:
                theta = effect.angle_urad * 1e-6
                # the laser reads the projection of the travel on a beam tilted by θ
                deviations -= (1.0 - np.cos(theta)) * targets * 1e3
        material = laser.material_temp_c + self.temperature_rise_c(np.array([clock, end_clock]))
        environment = Environment(
            air_temp_c=(laser.air_temp_c, laser.air_temp_c + 0.05),
            air_pressure_kpa=(laser.air_pressure_kpa, laser.air_pressure_kpa),
            air_humidity_pct=(laser.air_humidity_pct, laser.air_humidity_pct),
            material_temp_c=((float(material[0]), float(material[1])),),
            expansion_ppm_per_c=laser.expansion_ppm_per_c,
        )
        data = LineData(
            targets_mm=targets,
            deviations=np.round(deviations, 4),
            run_direction=run_direction,
            times_s=times - clock,
            start_time=session_start + clock,
            environment=environment,
            metadata={"machine": self.machine.name, "axis": spec.name, "serial": "VM-XL80-0001"},
        )
        return data, end_clock

    def _read(
        self,
        spec,  # type: ignore[no-untyped-def]
        commanded: FloatArray,
        nominal: FloatArray,
        approach: FloatArray,
        times: FloatArray,
        reflector: FloatArray,
    ) -> FloatArray:
        """One run's raw readings (before zeroing) at the targets."""
        if spec.quantity == "angular":
            rotation = rotation_error(self.truth, commanded)
            return rotation @ np.asarray(spec.sensitive)
        actual = commanded + self.error_um(commanded, approach, times, reflector) / 1e3
        displacement_um = (actual - nominal) * 1e3
        axis = spec.direction if spec.quantity == "linear" else spec.sensitive
        return displacement_um @ np.asarray(axis)


#: Target spacing of the demo plan (mm) and the random shift of its interior targets.
DEMO_STEP_MM = 6.0
DEMO_JITTER_MM = 2.0


def demo_machine(seed: int = 2026) -> VirtualMachine:
    """The demo's virtual machine: the paper's XYTZ mill with X backlash and a Y screw cycle."""
    truth = random_truth(PAPER_MACHINE, seed)
    effects = (
        Reversal("X", 4.0),
        CyclicError("Y", 1.2, PAPER_MACHINE.screw_lead_mm["Y"], 0.6),
    )
    return VirtualMachine(truth, effects, seed=seed, laser=LaserSetup(noise_um=0.15))


__all__ = [
    "AXES",
    "AbbeSetup",
    "CosineMisalignment",
    "CrossAxisSag",
    "CyclicError",
    "LaserSetup",
    "LocalDefect",
    "Reversal",
    "ThermalDrift",
    "VirtualMachine",
    "demo_machine",
    "random_truth",
]


def write_session(
    measurement: Measurement,
    folder: str | Path,
    plan_name: str = "plan.toml",
    uncertainty: Mapping[str, float] | None = None,
) -> Path:
    """Write a measured session as Renishaw-style logs (.rtl linear and straightness, .rta
    angular) plus a plan.toml that places each line, exactly as DESIGN.md specifies."""
    from .io.plan import write_plan
    from .io.rtl import write_rtl
    from .measurement import Plan

    folder = Path(folder)
    specs = []
    for line in measurement.lines:
        spec = line.spec
        file = spec.file or f"logs/{spec.name}.{'rta' if spec.quantity == 'angular' else 'rtl'}"
        target = folder / file
        target.parent.mkdir(parents=True, exist_ok=True)
        user_text = {
            "Machine": measurement.machine.name,
            "Serial No": line.data.metadata.get("serial", ""),
            "By": "volucal virtual machine",
            "Axis": spec.name,
            "Location": "simulation",
            "TITLE": f"{spec.quantity} {spec.name}",
        }
        write_rtl(target, line.data, angular=spec.quantity == "angular", user_text=user_text)
        specs.append(replace(spec, file=str(target.resolve())))
    plan = Plan(measurement.machine, tuple(specs), folder / plan_name, dict(uncertainty or {}))
    write_plan(folder / plan_name, plan)
    return folder / plan_name
