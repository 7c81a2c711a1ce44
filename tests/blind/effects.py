"""Effects beyond the 21 rigid-body errors, in this generator's own forms.

Every effect acts through one or more of four hooks, all evaluated on a :class:`Readings` batch
(the readings of one line, flattened):

- ``axis_delta``: translations (µm) added to an axis' δ inside the rigid-body chain (reversal,
  screw cycle, thermal scale drift, local guideway defect, scale oscillating in time, column bend);
- ``volumetric``: a translation (µm) added to the tool point's volumetric error (cross-axis sag
  surface, a periodic error in time);
- ``reflector_shift_mm`` / ``beam``: how one line's optics really sat (undeclared Abbe offset,
  cosine misalignment of the beam);
- ``reading``: a value added to a line's laser readings after zeroing (reflector mount twitching
  between runs, laser random walk, beam interruption that re-zeroes the line).

``describe()`` gives the manifest entry: ``kind`` in volucal's report.json vocabulary (reversal,
cyclic, thermal_drift, abbe_offset, cosine, cross_axis, local) or ``outside:<name>``, ``axis``,
and ``parameters`` whose keys carry their units. Pure numpy; never imports volucal.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .machine import AXES

AXIS_INDEX = {a: i for i, a in enumerate(AXES)}


@dataclass(frozen=True)
class Readings:
    """The readings of one line (flattened runs × targets) and what the machine did at each.

    ``approach``: (N, 3) the sign of each axis' motion when it arrived at the target (0 for an axis
    that does not move along this line); ``time_s``: seconds since the session's first reading.
    """

    line: str
    quantity: str
    position_mm: np.ndarray
    along_mm: np.ndarray
    approach: np.ndarray
    time_s: np.ndarray
    run: np.ndarray
    visit: np.ndarray

    def __len__(self) -> int:
        return len(self.time_s)


class Effect:
    """Base: an effect that does nothing through any hook."""

    kind = "none"

    def axis_delta(self, r: Readings) -> dict[str, np.ndarray]:
        return {}

    def volumetric(self, r: Readings) -> np.ndarray | None:
        return None

    def reflector_shift_mm(self, line: str) -> np.ndarray | None:
        return None

    def beam(self, line: str) -> tuple[float, np.ndarray] | None:
        return None

    def reading(self, r: Readings) -> np.ndarray | None:
        return None

    def describe(self) -> dict[str, object]:
        raise NotImplementedError


def _on_axis(axis: str, component: int, values: np.ndarray) -> dict[str, np.ndarray]:
    out = np.zeros((len(values), 3))
    out[:, component] = values
    return {axis: out}


def _stroke_fraction(p: np.ndarray, stroke: tuple[float, float], start: float) -> np.ndarray:
    return (p - start) / (max(stroke) - min(stroke))


# --------------------------------------------------------------------------------------------
# Catalogue effects
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Reversal(Effect):
    """ISO 230-2 reversal B(p) = x̄↑ − x̄↓ of an axis, constant or linear along the stroke.

    The axis' positioning gets +B/2 when it arrived moving in its + direction and −B/2 when it
    arrived moving in −. B(p) = B_start + (B_end − B_start)·(p − start)/stroke length.
    """

    axis: str
    stroke: tuple[float, float]
    start_mm: float
    b_start_um: float
    b_end_um: float
    kind: str = "reversal"

    def value(self, p: np.ndarray) -> np.ndarray:
        f = _stroke_fraction(p, self.stroke, self.start_mm)
        return self.b_start_um + (self.b_end_um - self.b_start_um) * f

    def axis_delta(self, r: Readings) -> dict[str, np.ndarray]:
        i = AXIS_INDEX[self.axis]
        p = r.position_mm[:, i]
        return _on_axis(self.axis, i, 0.5 * self.value(p) * r.approach[:, i])

    def describe(self) -> dict[str, object]:
        return {
            "kind": self.kind, "axis": self.axis, "error_id": f"E{self.axis}{self.axis}",
            "parameters": {
                "form": "constant" if self.b_start_um == self.b_end_um else "linear",
                "B_at_stroke_start_um": self.b_start_um,
                "B_at_stroke_end_um": self.b_end_um,
                "definition": "B = mean error approached moving + minus approached moving −; "
                              "±B/2 added to the positioning by approach direction",
            },
        }


@dataclass(frozen=True)
class ScrewCycle(Effect):
    """Cyclic positioning error a1·sin(2π(p − p0)/P + φ1) + a2·sin(4π(p − p0)/P + φ2)."""

    axis: str
    start_mm: float
    period_mm: float
    amplitude_um: float
    phase_rad: float
    amplitude2_um: float
    phase2_rad: float
    at_screw_lead: bool
    kind: str = "cyclic"

    def value(self, p: np.ndarray) -> np.ndarray:
        w = 2 * np.pi * (p - self.start_mm) / self.period_mm
        return (self.amplitude_um * np.sin(w + self.phase_rad)
                + self.amplitude2_um * np.sin(2 * w + self.phase2_rad))

    def axis_delta(self, r: Readings) -> dict[str, np.ndarray]:
        i = AXIS_INDEX[self.axis]
        return _on_axis(self.axis, i, self.value(r.position_mm[:, i]))

    def describe(self) -> dict[str, object]:
        return {
            "kind": self.kind, "axis": self.axis, "error_id": f"E{self.axis}{self.axis}",
            "parameters": {
                "period_mm": self.period_mm, "at_screw_lead": self.at_screw_lead,
                "amplitude_um": self.amplitude_um, "phase_rad": self.phase_rad,
                "harmonic2_amplitude_um": self.amplitude2_um,
                "harmonic2_phase_rad": self.phase2_rad,
                "origin_mm": self.start_mm,
                "form": "a1 sin(2π(p−origin)/P + φ1) + a2 sin(4π(p−origin)/P + φ2)",
            },
        }


@dataclass(frozen=True)
class ThermalDrift(Effect):
    """Scale of an axis growing with first-order response: α·ΔT(t)·(p − fixed point).

    ΔT(t) = ΔT∞·(1 − exp(−t/τ)), t from the session's first reading; α in ppm/K. When the logs
    carry a material temperature, it is T0 + ΔT(t) (the sensor sits on this axis).
    """

    axis: str
    fixed_point_mm: float
    alpha_ppm_per_k: float
    delta_t_inf_k: float
    tau_s: float
    kind: str = "thermal_drift"

    def delta_t(self, t_s: np.ndarray) -> np.ndarray:
        return self.delta_t_inf_k * (1.0 - np.exp(-np.asarray(t_s) / self.tau_s))

    def axis_delta(self, r: Readings) -> dict[str, np.ndarray]:
        i = AXIS_INDEX[self.axis]
        p = r.position_mm[:, i]
        scale = self.alpha_ppm_per_k * self.delta_t(r.time_s) * 1e-3  # µm per mm
        return _on_axis(self.axis, i, scale * (p - self.fixed_point_mm))

    def describe(self) -> dict[str, object]:
        return {
            "kind": self.kind, "axis": self.axis, "error_id": f"E{self.axis}{self.axis}",
            "parameters": {
                "alpha_ppm_per_K": self.alpha_ppm_per_k, "delta_T_inf_K": self.delta_t_inf_k,
                "tau_min": self.tau_s / 60.0, "fixed_point_mm": self.fixed_point_mm,
                "time_origin": "first reading of the session",
                "form": "alpha*1e-3*dT(t)*(p - fixed_point) um, dT = dT_inf (1 - exp(-t/tau))",
            },
        }


#: Interaction monomials (power of u, power of v) a cross-axis surface is made of.
CROSS_TERMS = ((1, 1), (2, 1), (1, 2), (2, 2), (3, 1), (1, 3))


@dataclass(frozen=True)
class CrossAxis(Effect):
    """A smooth surface added to the error in direction ``axis`` as a function of two axes.

    f(u, v) = Σ c_ij u^i v^j over interaction monomials only (CROSS_TERMS), with u, v the two
    positions normalised to [−1, 1] over their strokes: terms in one variable alone would be
    straightness or positioning, affine ones rigid-body errors.
    """

    axis: str
    depends_on: tuple[str, str]
    centre_mm: tuple[float, float]
    half_range_mm: tuple[float, float]
    coefficients: dict[str, float]
    peak_um: float
    nonrigid_peak_um: float = float("nan")
    kind: str = "cross_axis"

    def value(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        u = (a - self.centre_mm[0]) / self.half_range_mm[0]
        v = (b - self.centre_mm[1]) / self.half_range_mm[1]
        out = np.zeros(np.broadcast(u, v).shape)
        for key, c in self.coefficients.items():
            i, j = (int(s) for s in key.split(","))
            out = out + c * u**i * v**j
        return out

    def volumetric(self, r: Readings) -> np.ndarray:
        a = r.position_mm[:, AXIS_INDEX[self.depends_on[0]]]
        b = r.position_mm[:, AXIS_INDEX[self.depends_on[1]]]
        out = np.zeros((len(r), 3))
        out[:, AXIS_INDEX[self.axis]] = self.value(a, b)
        return out

    def describe(self) -> dict[str, object]:
        a, b = self.depends_on
        return {
            "kind": self.kind, "axis": self.axis, "depends_on": list(self.depends_on),
            "error_id": f"E{self.axis}({a},{b})",
            "parameters": {
                "depends_on": list(self.depends_on),
                "peak_um": self.peak_um,
                "nonrigid_peak_um": self.nonrigid_peak_um,
                "centre_mm": list(self.centre_mm), "half_range_mm": list(self.half_range_mm),
                "coefficients_um": {f"u^{k.split(',')[0]} v^{k.split(',')[1]}": v
                                    for k, v in self.coefficients.items()},
                "form": f"sum c * u^i * v^j, u = ({a} - centre)/half_range, v likewise for {b}",
            },
        }


@dataclass(frozen=True)
class LocalDefect(Effect):
    """A bump in a guideway: amplitude·shape((p − centre)/width) added to one component of an
    axis' δ (along the axis: positioning; across it: straightness). ``width_mm`` is the full
    width at half maximum for both shapes."""

    axis: str
    direction: str
    centre_mm: float
    width_mm: float
    amplitude_um: float
    shape: str
    kind: str = "local"

    def value(self, p: np.ndarray) -> np.ndarray:
        x = (np.asarray(p) - self.centre_mm) / self.width_mm
        if self.shape == "gaussian":
            return self.amplitude_um * np.exp(-4 * np.log(2) * x**2)
        return self.amplitude_um * np.clip(1.0 - np.abs(x), 0.0, None)

    def axis_delta(self, r: Readings) -> dict[str, np.ndarray]:
        i = AXIS_INDEX[self.axis]
        return _on_axis(self.axis, AXIS_INDEX[self.direction], self.value(r.position_mm[:, i]))

    def describe(self) -> dict[str, object]:
        return {
            "kind": self.kind, "axis": self.axis, "direction": self.direction,
            "error_id": f"E{self.direction}{self.axis}",
            "parameters": {
                "direction": self.direction, "centre_mm": self.centre_mm,
                "width_fwhm_mm": self.width_mm, "amplitude_um": self.amplitude_um,
                "shape": self.shape,
                "along_axis": self.direction == self.axis,
            },
        }


@dataclass(frozen=True)
class AbbeOffset(Effect):
    """The optics of one line sat ``offset_mm`` away from where the plan says (undeclared)."""

    line: str
    offset_mm: tuple[float, float, float]
    kind: str = "abbe_offset"
    axis: None = None

    def reflector_shift_mm(self, line: str) -> np.ndarray | None:
        return np.asarray(self.offset_mm) if line == self.line else None

    def describe(self) -> dict[str, object]:
        return {
            "kind": self.kind, "axis": None, "line": self.line,
            "parameters": {"offset_mm": list(self.offset_mm),
                           "magnitude_mm": float(np.linalg.norm(self.offset_mm)),
                           "meaning": "true reflector = plan reflector + offset"},
        }


@dataclass(frozen=True)
class CosineError(Effect):
    """The beam of one linear line tilted by θ from the travel towards ``tilt`` (a unit vector
    perpendicular to the travel): the laser reads the motion projected on the beam, so its
    deviations read short by (1 − cos θ) times the travel."""

    line: str
    theta_mrad: float
    tilt: tuple[float, float, float]
    kind: str = "cosine"
    axis: None = None

    def beam(self, line: str) -> tuple[float, np.ndarray] | None:
        if line != self.line:
            return None
        return self.theta_mrad * 1e-3, np.asarray(self.tilt)

    def describe(self) -> dict[str, object]:
        theta = self.theta_mrad * 1e-3
        return {
            "kind": self.kind, "axis": None, "line": self.line,
            "parameters": {"theta_mrad": self.theta_mrad, "tilt_towards": list(self.tilt),
                           "scale_ppm": -(1 - np.cos(theta)) * 1e6,
                           "meaning": "beam = cos(theta)*direction + sin(theta)*tilt"},
        }


# --------------------------------------------------------------------------------------------
# Effects outside the catalogue
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ScaleOscillation(Effect):
    """An axis' scale oscillating in time: A·sin(2πt/T + φ)·(p − start)/stroke length."""

    axis: str
    start_mm: float
    length_mm: float
    amplitude_um: float
    period_s: float
    phase_rad: float
    kind: str = "outside:scale_oscillation"

    def axis_delta(self, r: Readings) -> dict[str, np.ndarray]:
        i = AXIS_INDEX[self.axis]
        f = (r.position_mm[:, i] - self.start_mm) / self.length_mm
        s = np.sin(2 * np.pi * r.time_s / self.period_s + self.phase_rad)
        return _on_axis(self.axis, i, self.amplitude_um * s * f)

    def describe(self) -> dict[str, object]:
        return {
            "kind": self.kind, "axis": self.axis, "error_id": f"E{self.axis}{self.axis}",
            "parameters": {"amplitude_at_stroke_end_um": self.amplitude_um,
                           "period_min": self.period_s / 60, "phase_rad": self.phase_rad,
                           "form": "A sin(2 pi t/T + phase) (p - start)/length"},
        }


@dataclass(frozen=True)
class ColumnBending(Effect):
    """Z straightness growing in time (a column bending as it warms):
    A·g(t)·((z − start)/length)², g(t) = 1 − exp(−t/τ) normalised to 1 at the session's end."""

    direction: str
    start_mm: float
    length_mm: float
    amplitude_um: float
    tau_s: float
    session_end_s: float
    axis: str = "Z"
    kind: str = "outside:column_bending"

    def growth(self, t: np.ndarray) -> np.ndarray:
        return (1 - np.exp(-t / self.tau_s)) / (1 - np.exp(-self.session_end_s / self.tau_s))

    def axis_delta(self, r: Readings) -> dict[str, np.ndarray]:
        f = ((r.position_mm[:, 2] - self.start_mm) / self.length_mm) ** 2
        values = self.amplitude_um * self.growth(r.time_s) * f
        return _on_axis("Z", AXIS_INDEX[self.direction], values)

    def describe(self) -> dict[str, object]:
        return {
            "kind": self.kind, "axis": "Z", "direction": self.direction,
            "error_id": f"E{self.direction}Z",
            "parameters": {"amplitude_at_session_end_um": self.amplitude_um,
                           "tau_min": self.tau_s / 60, "direction": self.direction,
                           "form": "A g(t) ((z - start)/length)^2, g(end of session) = 1"},
        }


@dataclass(frozen=True)
class TimePeriodic(Effect):
    """A periodic error in time, not position: A·sin(2πt/T + φ) added to one direction."""

    axis: str
    amplitude_um: float
    period_s: float
    phase_rad: float
    kind: str = "outside:time_periodic"

    def volumetric(self, r: Readings) -> np.ndarray:
        out = np.zeros((len(r), 3))
        out[:, AXIS_INDEX[self.axis]] = self.amplitude_um * np.sin(
            2 * np.pi * r.time_s / self.period_s + self.phase_rad)
        return out

    def describe(self) -> dict[str, object]:
        return {
            "kind": self.kind, "axis": self.axis,
            "parameters": {"amplitude_um": self.amplitude_um, "period_s": self.period_s,
                           "phase_rad": self.phase_rad},
        }


@dataclass(frozen=True)
class ReflectorTwitch(Effect):
    """A reflector mount that settles differently on every run: each run of each linear and
    straightness line gets its own offset (the laser was zeroed during run 1, so run 1's is 0)."""

    sigma_um: float
    offsets_um: dict[str, tuple[float, ...]] = field(default_factory=dict)
    kind: str = "outside:reflector_twitch"
    axis: None = None

    def reading(self, r: Readings) -> np.ndarray | None:
        if r.line not in self.offsets_um:
            return None
        offsets = np.asarray(self.offsets_um[r.line])
        return offsets[r.run] - offsets[0]

    def describe(self) -> dict[str, object]:
        return {"kind": self.kind, "axis": None,
                "parameters": {"sigma_um": self.sigma_um,
                               "lines": sorted(self.offsets_um),
                               "offsets_um": {k: list(v) for k, v in self.offsets_um.items()}}}


@dataclass(frozen=True)
class LaserRandomWalk(Effect):
    """The laser's reading wanders as a random walk in time (σ·√(minutes) at each line's end
    relative to its zero); one walk per line, drawn at the readings' times."""

    sigma_um_per_sqrt_min: float
    walks_um: dict[str, np.ndarray] = field(default_factory=dict, compare=False)
    kind: str = "outside:laser_random_walk"
    axis: None = None

    def reading(self, r: Readings) -> np.ndarray | None:
        return self.walks_um.get(r.line)

    def describe(self) -> dict[str, object]:
        return {"kind": self.kind, "axis": None,
                "parameters": {"sigma_um_per_sqrt_min": self.sigma_um_per_sqrt_min,
                               "applies_to": "every line (µrad on angular lines)"}}


@dataclass(frozen=True)
class BeamInterruption(Effect):
    """The beam was cut on one line at one reading; the operator re-zeroed there, so every later
    reading of the line carries a step (the fringe count lost plus the deviation at that target)."""

    line: str
    run: int
    visit: int
    time_s: float
    step_um: float
    kind: str = "outside:beam_interruption"
    axis: None = None

    def reading(self, r: Readings) -> np.ndarray | None:
        if r.line != self.line:
            return None
        return np.where(r.time_s >= self.time_s, self.step_um, 0.0)

    def describe(self) -> dict[str, object]:
        return {"kind": self.kind, "axis": None, "line": self.line,
                "parameters": {"run": self.run + 1, "visit_index": self.visit + 1,
                               "time_s": self.time_s, "step_um": self.step_um}}
