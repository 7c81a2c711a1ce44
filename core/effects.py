"""Effects beyond the 21 rigid-body errors: a catalogue the closed loop searches.

Every effect is linear in its parameters over the measurement context (position, approach
direction, time, temperature, line): ``design(readings, model)`` returns one column per parameter
(the change of each reading per unit parameter) and identification fits them together with the
21 errors. Machine effects also give their volumetric error (``error_um``) so that compensation
can use them; set-up effects (Abbe offset, cosine misalignment) describe the measurement, not the
machine, and have no volumetric error.

Kinds (report.json): reversal, cyclic, thermal_drift, abbe_offset, cosine, cross_axis,
higher_order, local. Units: µm for displacements, mm for positions, s for time, °C.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .errors import AXIS_ERROR_IDS, ERROR_INFO, BSplineBasis, ErrorModel, gauge_null_space
from .kinematics import error_value_jacobian, rotation_error
from .machine import AXES, AXIS_INDEX, Machine
from .readings import QUANTITY_CODE, Readings

FloatArray = NDArray[np.float64]
ANGULAR = QUANTITY_CODE["angular"]


def _displacement(readings: Readings, direction: int) -> FloatArray:
    """How much a unit volumetric error along ``direction`` moves each reading (0 for angular)."""
    out = readings.projection[:, direction].copy()
    out[readings.is_angular] = 0.0
    return out


@dataclass(frozen=True)
class Plausibility:
    """What a real set-up or machine can show: a fitted effect beyond these explains nothing.

    A set-up effect is an unknown of the measurement (where the optics really sat, how the beam was
    aligned); a fit that needs an optics mount a third of a metre from where the plan puts it, or a
    beam so far off that no return spot reaches the detector, has found structure the catalogue
    lacks, not a set-up error. Machine effects get generous bounds against numerical blow-ups.
    """

    abbe_offset_mm: float = 100.0  # undeclared displacement of the optics from the plan
    cosine_angle_urad: float = 5000.0  # beyond ~5 mrad the return beam leaves the detector
    reversal_um: float = 200.0
    amplitude_um: float = 50.0  # cyclic, local, cross-axis peak
    thermal_scale_ppm: float = 300.0  # time-driven scale reached for t ≫ τ
    expansion_ppm_per_c: tuple[float, float] = (-5.0, 40.0)  # steel 11.5, cast iron 10, Al 23
    time_constant_s: tuple[float, float] = (300.0, 7 * 86400.0)
    #: A positive cosine scale (a beam that reads *longer* than the travel) is impossible; allow
    #: this many standard deviations of it before calling it implausible.
    sign_sigmas: float = 3.0


@dataclass(frozen=True, eq=False)
class Effect:
    """Base class: one effect with a linear design over the readings."""

    kind: str = field(init=False, default="")
    line_index: int | None = field(init=False, default=None)

    @property
    def axis(self) -> str | None:
        return None

    @property
    def key(self) -> tuple[str, str | None, str]:
        """Identity for "one entry per (kind, axis)" plus what tells variants apart."""
        return (self.kind, self.axis, self.label)

    @property
    def searched(self) -> int:
        """How many of its quantities were searched for in the data (a period, a time constant,
        a place and a width) rather than given: they count against it as parameters do."""
        return 0

    @property
    def label(self) -> str:
        raise NotImplementedError

    def design(self, readings: Readings, model: ErrorModel) -> FloatArray:
        raise NotImplementedError

    def parameters(self, values: FloatArray, covariance: FloatArray) -> dict[str, object]:
        """Report the fitted size with units (report.json ``parameters``)."""
        raise NotImplementedError

    def magnitude_um(self, values: FloatArray) -> float:
        """Peak size of the effect on the volumetric error (µm), for reports."""
        raise NotImplementedError

    def implausible(
        self, values: FloatArray, covariance: FloatArray, limits: Plausibility
    ) -> str | None:
        """Why the fitted parameters cannot be real for this set-up, or None when they can."""
        return None

    def error_um(
        self,
        values: FloatArray,
        machine: Machine,
        positions_mm: FloatArray,
        approach: FloatArray | None = None,
        time_s: FloatArray | None = None,
    ) -> FloatArray:
        """Volumetric error (µm) of a machine effect at states; zero for set-up effects."""
        return np.zeros_like(np.atleast_2d(positions_mm), dtype=float)


def _std(covariance: FloatArray, index: int = 0) -> float:
    return float(np.sqrt(max(covariance[index, index], 0.0))) if covariance.size else float("nan")


# --------------------------------------------------------------------------------------------
# Machine effects
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Reversal(Effect):
    """Reversal (backlash) of an axis: ±B/2 along the axis by approach direction, so that the
    ISO 230-2 reversal x̄↑ − x̄↓ equals B. ``order`` 1 lets B vary linearly over the stroke."""

    axis_name: str = "X"
    order: int = 0
    stroke_mm: tuple[float, float] = (0.0, 1.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", "reversal")

    @property
    def axis(self) -> str:
        return self.axis_name

    @property
    def label(self) -> str:
        return f"reversal {self.axis_name}" + (" (position-dependent)" if self.order else "")

    def _shape(self, q: FloatArray) -> FloatArray:
        low, high = self.stroke_mm
        s = (2 * q - low - high) / (high - low)
        return np.stack([np.ones_like(q), s][: self.order + 1], axis=-1)

    def design(self, readings: Readings, model: ErrorModel) -> FloatArray:
        k = AXIS_INDEX[self.axis_name]
        along = _displacement(readings, k) * readings.approach[:, k] * 0.5
        return along[:, None] * self._shape(readings.position_mm[:, k])

    def parameters(self, values: FloatArray, covariance: FloatArray) -> dict[str, object]:
        out: dict[str, object] = {"value_um": float(values[0]), "value_std_um": _std(covariance)}
        if self.order:
            out["slope_um_per_stroke"] = float(2 * values[1])
            out["slope_std_um_per_stroke"] = 2 * _std(covariance, 1)
        return out

    def magnitude_um(self, values: FloatArray) -> float:
        return float(abs(values[0]) + (abs(values[1]) if self.order else 0.0))

    def implausible(self, values, covariance, limits):  # type: ignore[no-untyped-def]
        if self.magnitude_um(values) > limits.reversal_um:
            return (
                f"a reversal of {self.magnitude_um(values):.4g} µm is beyond "
                f"{limits.reversal_um:g} µm"
            )
        return None

    def error_um(self, values, machine, positions_mm, approach=None, time_s=None):  # type: ignore[no-untyped-def]
        q = np.atleast_2d(positions_mm)
        e = np.zeros_like(q, dtype=float)
        if approach is None:
            return e
        k = AXIS_INDEX[self.axis_name]
        e[:, k] = 0.5 * np.asarray(approach)[:, k] * (self._shape(q[:, k]) @ values)
        return e


@dataclass(frozen=True, eq=False)
class Cyclic(Effect):
    """A cyclic error along an axis (screw lead and harmonics): Σ a·sin + b·cos of
    2πh(q − ref)/period, the same in both directions."""

    axis_name: str = "X"
    period_mm: float = 16.0
    harmonics: tuple[int, ...] = (1,)
    reference_mm: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", "cyclic")

    @property
    def axis(self) -> str:
        return self.axis_name

    #: the period came from a search of the data, not from the machine's screw lead
    period_searched: bool = False

    @property
    def label(self) -> str:
        label = f"cyclic {self.axis_name} {self.period_mm:.4g} mm"
        if self.harmonics != (1,):
            label += " with harmonics " + ", ".join(str(h) for h in self.harmonics)
        return label

    @property
    def searched(self) -> int:
        return 1 if self.period_searched else 0

    def _waves(self, q: FloatArray) -> FloatArray:
        cols = []
        for h in self.harmonics:
            phase = 2 * np.pi * h * (q - self.reference_mm) / self.period_mm
            cols += [np.sin(phase), np.cos(phase)]
        return np.stack(cols, axis=-1)

    def design(self, readings: Readings, model: ErrorModel) -> FloatArray:
        k = AXIS_INDEX[self.axis_name]
        return _displacement(readings, k)[:, None] * self._waves(readings.position_mm[:, k])

    def parameters(self, values: FloatArray, covariance: FloatArray) -> dict[str, object]:
        out: dict[str, object] = {"period_mm": self.period_mm}
        for i, h in enumerate(self.harmonics):
            a, b = values[2 * i], values[2 * i + 1]
            amp = float(np.hypot(a, b))
            # std of the amplitude by first-order propagation
            grad = np.array([a, b]) / amp if amp > 0 else np.array([1.0, 0.0])
            block = covariance[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] if covariance.size else None
            std = float(np.sqrt(grad @ block @ grad)) if block is not None else float("nan")
            suffix = "" if h == 1 else f"_h{h}"
            out[f"amplitude_um{suffix}"] = amp
            out[f"amplitude_std_um{suffix}"] = std
            out[f"phase_rad{suffix}"] = float(np.arctan2(b, a))
        return out

    def magnitude_um(self, values: FloatArray) -> float:
        return float(
            sum(np.hypot(values[2 * i], values[2 * i + 1]) for i in range(len(self.harmonics)))
        )

    def implausible(self, values, covariance, limits):  # type: ignore[no-untyped-def]
        if self.magnitude_um(values) > limits.amplitude_um:
            return (
                f"a cycle of {self.magnitude_um(values):.4g} µm is beyond "
                f"{limits.amplitude_um:g} µm"
            )
        return None

    def error_um(self, values, machine, positions_mm, approach=None, time_s=None):  # type: ignore[no-untyped-def]
        q = np.atleast_2d(positions_mm)
        e = np.zeros_like(q, dtype=float)
        k = AXIS_INDEX[self.axis_name]
        e[:, k] = self._waves(q[:, k]) @ values
        return e


@dataclass(frozen=True, eq=False)
class ThermalDrift(Effect):
    """Scale of an axis drifting with the machine's temperature: κ·(q − ref)·g(t).

    With a logged material temperature that changes, g is its rise since the session's first
    reading (°C) and κ is an expansion in ppm/°C; otherwise g = 1 − exp(−t/τ) (τ chosen by the
    loop) and κ is the scale reached for t ≫ τ, in ppm. The identified 21 errors describe the
    machine at the first reading (DESIGN.md, "Time").

    A file that logs the temperature only at its first and last reading says nothing of how it
    went in between: read as a straight line in time, a structure that settles within a long
    line (τ of 15 min in a 75 min line) changes size from run to run against it. With
    ``first_order`` the temperature between a file's two logs follows a first-order response of
    time constant τ (chosen by the loop), the way a structure settles after a change of heat
    input: T(t) = T₀ + (T₁ − T₀)·(1 − exp(−(t − t₀)/τ))/(1 − exp(−(t₁ − t₀)/τ)). It meets both
    logs exactly for every τ and tends to the straight line for τ ≫ t₁ − t₀; temperatures
    logged at every reading are used as they are.
    """

    axis_name: str = "X"
    mode: str = "temperature"  # or "time"
    time_constant_s: float = 3600.0
    reference_mm: float = 0.0
    first_order: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", "thermal_drift")

    @property
    def axis(self) -> str:
        return self.axis_name

    @property
    def label(self) -> str:
        if self.mode == "temperature" and self.first_order:
            return f"thermal drift {self.axis_name} (material temperature, first order)"
        if self.mode == "temperature":
            return f"thermal drift {self.axis_name} (material temperature)"
        return f"thermal drift {self.axis_name} (time)"

    @property
    def key(self) -> tuple[str, str | None, str]:
        # τ is estimated, not part of the candidate's identity
        return (self.kind, self.axis, self.label)

    @property
    def searched(self) -> int:
        return 1 if self.mode == "time" or self.first_order else 0

    def _driver(self, readings: Readings) -> FloatArray:
        if self.mode == "temperature":
            temp = readings.material_temp_c
            if self.first_order:
                temp = first_order_temperature(readings, self.time_constant_s)
            first = int(np.argmin(readings.time_s))
            return np.nan_to_num(temp - temp[first])
        return 1.0 - np.exp(-readings.time_s / self.time_constant_s)

    def along(self, readings: Readings) -> FloatArray:
        """Per reading, the drift's shape in position: what 1 ppm of the axis' scale moves the
        reading (µm), before its course in time."""
        k = AXIS_INDEX[self.axis_name]
        span_m = (readings.position_mm[:, k] - self.reference_mm) * 1e-3
        # µm per ppm: 1 ppm over 1 m is 1 µm
        return _displacement(readings, k) * span_m

    def design(self, readings: Readings, model: ErrorModel) -> FloatArray:
        return (self.along(readings) * self._driver(readings))[:, None]

    def parameters(self, values: FloatArray, covariance: FloatArray) -> dict[str, object]:
        if self.mode == "temperature":
            out: dict[str, object] = {
                "mode": "temperature",
                "expansion_ppm_per_c": float(values[0]),
                "expansion_std_ppm_per_c": _std(covariance),
            }
            if self.first_order:
                out["between_logs"] = "first order"
                out["time_constant_s"] = self.time_constant_s
            return out
        return {
            "mode": "time",
            "scale_ppm": float(values[0]),
            "scale_std_ppm": _std(covariance),
            "time_constant_s": self.time_constant_s,
        }

    def magnitude_um(self, values: FloatArray) -> float:
        return float(abs(values[0]) * 0.4)  # over a typical 400 mm at the end of the drift

    def implausible(self, values, covariance, limits):  # type: ignore[no-untyped-def]
        if self.mode == "temperature":
            low, high = limits.expansion_ppm_per_c
            if not low <= values[0] <= high:
                return (
                    f"an expansion of {values[0]:.4g} ppm/°C is outside [{low:g}, {high:g}] "
                    "ppm/°C of machine materials"
                )
            return self._implausible_time_constant(limits) if self.first_order else None
        why = self._implausible_time_constant(limits)
        if why is None and abs(values[0]) > limits.thermal_scale_ppm:
            why = f"a drift of {values[0]:.4g} ppm is beyond {limits.thermal_scale_ppm:g} ppm"
        return why

    def _implausible_time_constant(self, limits) -> str | None:  # type: ignore[no-untyped-def]
        low, high = limits.time_constant_s
        if not low <= self.time_constant_s <= high:
            return (
                f"a time constant of {self.time_constant_s:.4g} s is outside the "
                f"[{low:g}, {high:g}] s a machine structure warms with"
            )
        return None

    def error_um(self, values, machine, positions_mm, approach=None, time_s=None):  # type: ignore[no-untyped-def]
        # The model describes the machine at the session's first reading: compensation uses
        # the 21 errors there, and the drift is reported, not compensated.
        return np.zeros_like(np.atleast_2d(positions_mm), dtype=float)


def first_order_temperature(readings: Readings, time_constant_s: float) -> FloatArray:
    """The material temperature of every reading, where a file logs it only at its two ends
    read as a first-order response of time constant ``time_constant_s`` between them (see
    :class:`ThermalDrift`); the logged or interpolated temperature elsewhere."""
    temp = np.array(readings.material_temp_c, dtype=float)
    ends = np.isfinite(readings.material_ends_c).all(axis=1)
    if not np.any(ends):
        return temp
    (t0, t1), (c0, c1) = readings.material_ends_s[ends].T, readings.material_ends_c[ends].T
    elapsed = np.clip(readings.time_s[ends] - t0, 0.0, None)
    span = np.maximum(t1 - t0, 1e-9)
    # (1 − e^(−Δt/τ)) / (1 − e^(−span/τ)), written with expm1 to stay exact for τ ≫ span
    fraction = np.expm1(-elapsed / time_constant_s) / np.expm1(-span / time_constant_s)
    temp[ends] = c0 + (c1 - c0) * fraction
    return temp


@dataclass(frozen=True, eq=False)
class CrossAxis(Effect):
    """Error along ``direction`` that depends on two axes at once (sag, twist of a table, a
    guideway that bends with the load): a smooth function of both positions,

        f(q_a, q_b) = Σ c_ij · P_i(s) · P_j(t),   i ≥ m, j ≥ m, i + j ≤ order,

    with P the Legendre polynomials and s, t the two positions scaled to [−1, 1] over their
    strokes. What depends on one axis alone is the error functions' part, and a product with a
    linear factor in either position looks like an angular error times a lever arm (a roll of X
    times the Y position is f(x)·y in EZ). By default (m = 2) the surface holds only what no rigid
    body produces, so it cannot trade with the 21 errors. With ``lever_terms`` (m = 1) it also
    holds the linear-factor products: a carriage that is not rigid shows one roll on the angular
    line and another between straightness lines at different offsets; the loop's test projects
    out what the 21 errors can take, so only the contradiction is evidence. The family and the
    order are chosen by cross-validation among the candidates.
    """

    direction: str = "Z"
    along: str = "X"
    across: str = "Y"
    machine: Machine | None = None
    order: int = 4
    lever_terms: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", "cross_axis")

    @property
    def axis(self) -> str:
        return self.direction

    @property
    def label(self) -> str:
        lever = ", with lever-arm terms" if self.lever_terms else ""
        pair = f"{self.along}×{self.across}"
        return f"cross-axis E{self.direction} over {pair} (order {self.order}{lever})"

    def _terms(self) -> list[tuple[int, int]]:
        lowest = 1 if self.lever_terms else 2
        return [
            (i, total - i)
            for total in range(2 * lowest, self.order + 1)
            for i in range(lowest, total - lowest + 1)
        ]

    @property
    def term_names(self) -> tuple[str, ...]:
        """The shape functions' names in parameter order, e.g. "P1(Y)·P2(Z)"."""
        return tuple(f"P{i}({self.along})·P{j}({self.across})" for i, j in self._terms())

    def _scaled(self, q: FloatArray, axis: str) -> FloatArray:
        assert self.machine is not None
        low, high = self.machine.stroke(axis)
        return (2.0 * q[:, AXIS_INDEX[axis]] - low - high) / (high - low)

    def shape(self, q: FloatArray) -> FloatArray:
        """The shape functions at machine positions ``q`` (rows), one column per term."""
        from numpy.polynomial import legendre

        s = self._scaled(q, self.along)
        t = self._scaled(q, self.across)
        columns = []
        for i, j in self._terms():
            ci = np.zeros(i + 1)
            ci[i] = 1.0
            cj = np.zeros(j + 1)
            cj[j] = 1.0
            columns.append(legendre.legval(s, ci) * legendre.legval(t, cj))
        return np.stack(columns, axis=-1)

    def design(self, readings: Readings, model: ErrorModel) -> FloatArray:
        k = AXIS_INDEX[self.direction]
        return _displacement(readings, k)[:, None] * self.shape(readings.position_mm)

    def grid(self, machine: Machine, count: int = 21) -> FloatArray:
        """Machine positions (rows) on a ``count`` × ``count`` grid over the pair's strokes,
        the third axis at zero."""
        a = np.linspace(*machine.stroke(self.along), count)
        b = np.linspace(*machine.stroke(self.across), count)
        q = np.zeros((count * count, 3))
        aa, bb = np.meshgrid(a, b, indexing="ij")
        q[:, AXIS_INDEX[self.along]] = aa.ravel()
        q[:, AXIS_INDEX[self.across]] = bb.ravel()
        return q

    def _surface(self, values: FloatArray, count: int = 21) -> FloatArray:
        assert self.machine is not None
        return np.asarray(self.shape(self.grid(self.machine, count)) @ values)

    def parameters(self, values: FloatArray, covariance: FloatArray) -> dict[str, object]:
        assert self.machine is not None
        design = self.shape(self.grid(self.machine))
        surface = design @ values
        variance = np.einsum("ij,jk,ik->i", design, covariance, design)
        return {
            "depends_on": [self.along, self.across],
            "order": self.order,
            "lever_terms": self.lever_terms,
            "terms": list(self.term_names),
            "coefficients_um": [float(v) for v in values],
            "coefficients_std_um": [_std(covariance, i) for i in range(len(values))],
            "peak_um": float(np.max(np.abs(surface))),
            "rms_um": float(np.sqrt(np.mean(surface**2))),
            # the surface's standard uncertainty, RMS over the pair's strokes; a shape the plan
            # does not settle between orders is in it (core/loop_choice.py, unsettled)
            "rms_std_um": float(np.sqrt(max(float(np.mean(variance)), 0.0))),
        }

    def magnitude_um(self, values: FloatArray) -> float:
        return float(np.max(np.abs(self._surface(values, 11))))

    def implausible(self, values, covariance, limits):  # type: ignore[no-untyped-def]
        peak = self.magnitude_um(values)
        if peak > limits.amplitude_um:
            return f"a cross-axis error of {peak:.4g} µm is beyond {limits.amplitude_um:g} µm"
        return None

    def error_um(self, values, machine, positions_mm, approach=None, time_s=None):  # type: ignore[no-untyped-def]
        q = np.atleast_2d(positions_mm)
        e = np.zeros_like(q, dtype=float)
        e[:, AXIS_INDEX[self.direction]] = self.shape(q) @ values
        return e


@dataclass(frozen=True, eq=False)
class LocalDefect(Effect):
    """A local guideway defect: a bump of the error in ``direction`` along ``axis``.

    ``profile`` "gaussian": one Gaussian of 1 σ ``width_mm`` (one amplitude). "free": a bump of
    unknown profile, five cubic B-splines on uniform knots spanning ``center_mm`` ± ``width_mm``
    (value, slope and curvature zero at both ends): a dent, a worn or a raised stretch of a guideway
    is no Gaussian, and a Gaussian fitted to another profile leaves up to 5 % of its height, which
    a finer function would then be kept for. Five splines follow a smooth symmetric or lopsided
    bump to about 1 % of its height and a triangular one to about 5 % (three: 1–2 % and 8 %; on the
    suites of benchmarks/bench_loop_suite.py five did better on one generator and as well on the
    other).

    With ``beside_spacing_mm`` (the breakpoint spacing of the error function the bump adds to,
    and ``machine``), a free profile holds nothing that a spline of that function vanishing
    outside the bump's span could hold: those splines' least-squares share (over the stroke) is
    taken out of its columns. Beside the function at that spacing the fit and its predictions
    stay as they were; the fit fixes poorly how they split between bump and function where a
    spline lies within the bump, and the two traded tens of µm with opposite signs (blind 54086:
    a −3.0 µm bump of X, 36 mm wide, fitted over 323 ± 121 mm as +51.7 µm against −48 µm of the
    function and refused as implausible; it now reads −2.5 µm). Splines that reach beyond the
    bump's span still trade with it.
    A bump narrower than the function's splines keeps its profile as fitted."""

    axis_name: str = "X"
    direction: str = "Z"
    center_mm: float = 0.0
    width_mm: float = 5.0
    profile: str = "gaussian"
    machine: Machine | None = None
    beside_spacing_mm: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", "local")

    @property
    def axis(self) -> str:
        return self.axis_name

    @property
    def label(self) -> str:
        place = f"local defect {self.axis_name} in {self.direction} at {self.center_mm:.0f} mm"
        if self.profile == "gaussian":
            return f"{place} (Gaussian, 1 σ {self.width_mm:.3g} mm)"
        return place

    @property
    def reach_mm(self) -> float:
        """How far from its centre the bump reaches (mm): a free profile's half-span; three
        1 σ widths of a Gaussian, where it has fallen to 1 % of its height."""
        return self.width_mm if self.profile == "free" else 3.0 * self.width_mm

    @property
    def searched(self) -> int:
        return 2

    def _bump(self, q: FloatArray) -> FloatArray:
        """The profile's columns at positions ``q`` (one per fitted value)."""
        if self.profile == "gaussian":
            s = (q - self.center_mm) / self.width_mm
            return np.exp(-0.5 * s * s)[:, None]
        columns = _free_profile(q, self.center_mm, self.width_mm)
        if self.beside_spacing_mm is None or self.machine is None:
            return columns
        low, high = self.machine.stroke(self.axis_name)
        basis, share = _function_share(
            float(low), float(high), float(self.beside_spacing_mm), self.center_mm, self.width_mm
        )
        return columns - basis.design(q) @ share

    def _peak(self, values: FloatArray) -> tuple[float, FloatArray, float]:
        """The profile's largest deviation (signed), its columns there and where it is (mm)."""
        if self.profile == "gaussian":
            return float(values[0]), np.ones(1), self.center_mm
        low, high = self.center_mm - self.width_mm, self.center_mm + self.width_mm
        if self.machine is not None:
            stroke = self.machine.stroke(self.axis_name)
            low, high = max(low, stroke[0]), min(high, stroke[1])
        q = np.linspace(low, high, 121)
        columns = self._bump(q)
        i = int(np.argmax(np.abs(columns @ values)))
        return float(columns[i] @ values), columns[i], float(q[i])

    def design(self, readings: Readings, model: ErrorModel) -> FloatArray:
        k = AXIS_INDEX[self.direction]
        # evaluated once per distinct position: runs repeat their targets
        positions, inverse = np.unique(
            readings.position_mm[:, AXIS_INDEX[self.axis_name]], return_inverse=True
        )
        bump = self._bump(positions)[inverse]
        return _displacement(readings, k)[:, None] * bump

    def parameters(self, values: FloatArray, covariance: FloatArray) -> dict[str, object]:
        peak, at, where = self._peak(values)
        # where the defect is and how large first: the console shows an effect's first few
        return {
            "direction": self.direction,
            "peak_mm": where,
            "amplitude_um": peak,
            "amplitude_std_um": float(np.sqrt(max(at @ covariance @ at, 0.0)))
            if covariance.size
            else float("nan"),
            "center_mm": self.center_mm,
            "width_mm": self.width_mm,
            "profile": self.profile,
        }

    def magnitude_um(self, values: FloatArray) -> float:
        return abs(self._peak(values)[0])

    def implausible(self, values, covariance, limits):  # type: ignore[no-untyped-def]
        peak = self._peak(values)[0]
        if abs(peak) > limits.amplitude_um:
            return f"a local defect of {peak:.4g} µm is beyond {limits.amplitude_um:g} µm"
        return None

    def error_um(self, values, machine, positions_mm, approach=None, time_s=None):  # type: ignore[no-untyped-def]
        q = np.atleast_2d(positions_mm)
        e = np.zeros_like(q, dtype=float)
        e[:, AXIS_INDEX[self.direction]] = self._bump(q[:, AXIS_INDEX[self.axis_name]]) @ values
        return e


#: Cubic B-splines of a free-profile local defect.
FREE_SPLINES = 5


def _free_profile(q: FloatArray, center_mm: float, width_mm: float) -> FloatArray:
    """The free profile's columns at positions ``q``: :data:`FREE_SPLINES` cubic B-splines on
    uniform knots over ``center_mm`` ± ``width_mm``."""
    spacing = 2.0 * width_mm / (FREE_SPLINES + 3)
    columns = [
        _cubic_b_spline((q - (center_mm - width_mm + i * spacing)) / spacing)
        for i in range(FREE_SPLINES)
    ]
    return np.stack(columns, axis=1)


@functools.lru_cache(maxsize=256)
def _function_share(
    low: float, high: float, spacing_mm: float, center_mm: float, width_mm: float
) -> tuple[BSplineBasis, FloatArray]:
    """The error function's B-splines every ``spacing_mm`` over the stroke and, for each
    free-profile column, the coefficients of the least-squares fit (over the stroke) by those
    splines that vanish outside the bump's span: the part of a bump a function that is zero
    outside it can take. A bump narrower than the function's splines has none."""
    basis = BSplineBasis.uniform(low, high, spacing_mm)
    knots = basis.knots
    start, end = center_mm - width_mm - 1e-9, center_mm + width_mm + 1e-9
    inside = [
        i for i in range(basis.size) if knots[i] >= start and knots[i + basis.degree + 1] <= end
    ]
    share = np.zeros((basis.size, FREE_SPLINES))
    if inside:
        q = np.linspace(low, high, 801)
        share[inside] = np.linalg.lstsq(
            basis.design(q)[:, inside], _free_profile(q, center_mm, width_mm), rcond=None
        )[0]
    share.setflags(write=False)
    return basis, share


def _cubic_b_spline(t: FloatArray) -> FloatArray:
    """The uniform cubic B-spline on knots 0, 1, 2, 3, 4 (zero outside [0, 4], peak 2/3 at 2)."""
    t = np.asarray(t, dtype=float)
    out = np.zeros_like(t)
    for lo, poly in (
        (0.0, lambda u: u**3),
        (1.0, lambda u: -3 * u**3 + 12 * u**2 - 12 * u + 4),
        (2.0, lambda u: 3 * u**3 - 24 * u**2 + 60 * u - 44),
        (3.0, lambda u: (4 - u) ** 3),
    ):
        inside = (t >= lo) & (t < lo + 1.0)
        out[inside] = poly(t[inside]) / 6.0
    return out


@dataclass(frozen=True, eq=False)
class HigherOrder(Effect):
    """A finer basis for one of the 18 error functions (a refinement, not a physical effect):
    B-splines every ``spacing_mm`` in the gauge, added to the function."""

    error_id: str = "EXX"
    spacing_mm: float = 25.0
    machine: Machine | None = None
    coarse_spacing_mm: float = 50.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", "higher_order")

    @property
    def axis(self) -> str:
        axis = ERROR_INFO[self.error_id].axis
        assert axis is not None
        return axis

    @property
    def label(self) -> str:
        return f"higher order {self.error_id} ({self.spacing_mm:g} mm)"

    def _basis(self) -> tuple[BSplineBasis, FloatArray]:
        """The finer B-splines in the gauge, restricted to shapes orthogonal (over the stroke) to
        the current coarse basis, so the refinement's size is what it adds and nothing else."""
        assert self.machine is not None
        low, high = self.machine.stroke(self.axis)
        return _refinement_basis(
            float(low),
            float(high),
            float(self.machine.reference(self.axis)),
            ERROR_INFO[self.error_id].is_straightness,
            float(self.spacing_mm),
            float(self.coarse_spacing_mm),
        )

    def design(self, readings: Readings, model: ErrorModel) -> FloatArray:
        basis, null = self._basis()
        k = AXIS_INDEX[self.axis]
        # evaluated once per distinct position: runs repeat their targets
        positions, inverse = np.unique(readings.position_mm[:, k], return_inverse=True)
        shape = (basis.design(positions) @ null)[inverse]
        column = AXIS_ERROR_IDS.index(self.error_id)
        return value_sensitivity(readings, model)[:, column, None] * shape

    def parameters(self, values: FloatArray, covariance: FloatArray) -> dict[str, object]:
        basis, null = self._basis()
        low, high = basis.low, basis.high
        q = np.linspace(low, high, 201)
        added = basis.design(q) @ null @ values
        unit = ERROR_INFO[self.error_id].unit
        return {
            "error": self.error_id,
            "spacing_mm": self.spacing_mm,
            f"added_rms_{unit}": float(np.sqrt(np.mean(added**2))),
            f"added_max_{unit}": float(np.max(np.abs(added))),
        }

    def magnitude_um(self, values: FloatArray) -> float:
        return float(self.parameters(values, np.zeros((0, 0))).get("added_max_um", 0.0))

    def added_function(self, values: FloatArray) -> tuple[BSplineBasis, FloatArray]:
        basis, null = self._basis()
        return basis, null @ values

    def refinement_design(self, position_mm: FloatArray) -> FloatArray:
        """d(added value at the positions)/d(parameters), (n, k)."""
        basis, null = self._basis()
        return np.asarray(basis.design(position_mm) @ null)

    def error_um(self, values, machine, positions_mm, approach=None, time_s=None):  # type: ignore[no-untyped-def]
        # A refinement of an error function: compensation folds it into the model itself
        # (see :func:`refined_model`).
        return np.zeros_like(np.atleast_2d(positions_mm), dtype=float)


@functools.lru_cache(maxsize=64)
def _refinement_basis(
    low: float,
    high: float,
    reference: float,
    straightness: bool,
    spacing_mm: float,
    coarse_spacing_mm: float,
) -> tuple[BSplineBasis, FloatArray]:
    """:meth:`HigherOrder._basis`, computed once per stroke and spacing (the loop asks for it
    at every step)."""
    basis = BSplineBasis.uniform(low, high, spacing_mm)
    fine = gauge_null_space(basis, reference, straightness)
    coarse_basis = BSplineBasis.uniform(low, high, coarse_spacing_mm)
    coarse = gauge_null_space(coarse_basis, reference, straightness)
    q = np.linspace(low, high, 801)
    cross = (coarse_basis.design(q) @ coarse).T @ (basis.design(q) @ fine)
    _, s, vt = np.linalg.svd(cross, full_matrices=True)
    rank = int(np.sum(s > 1e-9 * max(s.max(initial=0.0), 1e-300)))
    null = fine @ vt[rank:].T
    null.setflags(write=False)
    return basis, null


_SENSITIVITY_CACHE: list[tuple[Readings, ErrorModel, FloatArray]] = []


def value_sensitivity(readings: Readings, model: ErrorModel) -> FloatArray:
    """d(reading)/d(value of each of the 18 error functions at the reading's position), (n, 18).

    Evaluated once per distinct (line, target) and kept for the last (readings, model) pair: the
    loop asks for it once per error function while diagnosing one fit.
    """
    for cached_readings, cached_model, value in _SENSITIVITY_CACHE:
        if cached_readings is readings and cached_model is model:
            return value
    key = readings.line * 1_000_000 + readings.target
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    positions = readings.position_mm[first]
    projection = readings.projection[first]
    angular = readings.is_angular[first]
    out = np.zeros((len(first), len(AXIS_ERROR_IDS)))
    disp = ~angular
    if disp.any():
        per_axis, _ = error_value_jacobian(
            model, positions[disp], readings.reflector_mm[first][disp]
        )
        for a, axis in enumerate(AXES):
            out[disp, 6 * a : 6 * a + 6] = np.einsum("nc,ncj->nj", projection[disp], per_axis[axis])
    if angular.any():
        for a in range(3):
            out[angular, 6 * a + 3 : 6 * a + 6] = projection[angular]
    result = out[inverse]
    _SENSITIVITY_CACHE[:] = [(readings, model, result)]
    return result


_ROTATION_CACHE: list[tuple[Readings, ErrorModel, FloatArray]] = []


def _tool_rotation(readings: Readings, model: ErrorModel) -> FloatArray:
    """Rotation of the tool (µrad, (n, 3)) at every reading, kept for the last (readings, model)
    pair: the loop asks for it once per line while diagnosing one fit."""
    for cached_readings, cached_model, value in _ROTATION_CACHE:
        if cached_readings is readings and cached_model is model:
            return value
    positions, inverse = np.unique(readings.position_mm, axis=0, return_inverse=True)
    result = rotation_error(model, positions)[inverse.reshape(-1)]
    _ROTATION_CACHE[:] = [(readings, model, result)]
    return result


# --------------------------------------------------------------------------------------------
# Set-up effects
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class AbbeOffset(Effect):
    """The optics of one line sit h (mm) away from where the plan says: the reading changes by
    u·(θ(P) × h), θ the rotation of the tool at P. Linear in h given the identified angles."""

    line: int = 0
    line_name: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", "abbe_offset")
        object.__setattr__(self, "line_index", self.line)

    @property
    def label(self) -> str:
        return f"Abbe offset of line {self.line_name}"

    def design(self, readings: Readings, model: ErrorModel) -> FloatArray:
        out = np.zeros((len(readings), 3))
        mask = (readings.line == self.line) & ~readings.is_angular
        if not mask.any():
            return out
        theta = _tool_rotation(readings, model)[mask] * 1e-6  # rad
        for j in range(3):
            unit = np.zeros(3)
            unit[j] = 1.0
            moved = np.cross(theta, unit) * 1e3  # µm per mm of offset
            out[mask, j] = np.einsum("nc,nc->n", moved, readings.projection[mask])
        return out

    def parameters(self, values: FloatArray, covariance: FloatArray) -> dict[str, object]:
        return {
            "line": self.line_name,
            "offset_mm": [float(v) for v in values],
            "offset_std_mm": [_std(covariance, j) for j in range(3)],
        }

    def magnitude_um(self, values: FloatArray) -> float:
        return float(np.linalg.norm(values) * 1e-2)  # 10 µrad over the offset

    def implausible(self, values, covariance, limits):  # type: ignore[no-untyped-def]
        worst = float(np.max(np.abs(values)))
        if worst > limits.abbe_offset_mm:
            return (
                f"an optics offset of {worst:.4g} mm from where the plan puts them is beyond the "
                f"{limits.abbe_offset_mm:g} mm a set-up can be off"
            )
        return None


@dataclass(frozen=True, eq=False)
class Cosine(Effect):
    """Laser cosine misalignment of one line: a pure scale, −θ²/2, on that line."""

    line: int = 0
    line_name: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", "cosine")
        object.__setattr__(self, "line_index", self.line)

    @property
    def label(self) -> str:
        return f"cosine misalignment of line {self.line_name}"

    def design(self, readings: Readings, model: ErrorModel) -> FloatArray:
        mask = readings.line == self.line
        column = np.where(mask, readings.target_mm, 0.0) * 1e-3  # µm per ppm
        return column[:, None]

    def parameters(self, values: FloatArray, covariance: FloatArray) -> dict[str, object]:
        scale_ppm = float(values[0])
        angle = float(np.sqrt(2 * max(-scale_ppm, 0.0) * 1e-6) * 1e6)
        return {
            "line": self.line_name,
            "scale_ppm": scale_ppm,
            "scale_std_ppm": _std(covariance),
            "angle_urad": angle,
        }

    def magnitude_um(self, values: FloatArray) -> float:
        return float(abs(values[0]) * 0.4)

    def implausible(self, values, covariance, limits):  # type: ignore[no-untyped-def]
        scale_ppm = float(values[0])
        if scale_ppm > limits.sign_sigmas * max(_std(covariance), 1e-6):
            return (
                f"a cosine error lengthens no reading, but line {self.line_name} reads "
                f"{scale_ppm:.3g} ppm long"
            )
        angle = float(np.sqrt(2 * max(-scale_ppm, 0.0) * 1e-6) * 1e6)
        if angle > limits.cosine_angle_urad:
            return (
                f"a beam misaligned by {angle:.4g} µrad (line {self.line_name}) would not return "
                f"to the detector (limit {limits.cosine_angle_urad:g} µrad)"
            )
        return None


def refined_model(
    model: ErrorModel, effects: tuple[Effect, ...], values: tuple[FloatArray, ...]
) -> ErrorModel:
    """The model with every kept higher-order refinement folded into its error function
    (sampled on a fine node table), for compensation and display."""
    from .errors import ErrorFunction, NodeTableBasis

    functions = dict(model.functions)
    for effect, v in zip(effects, values, strict=True):
        if not isinstance(effect, HigherOrder):
            continue
        eid = effect.error_id
        basis, coefficients = effect.added_function(v)
        nodes = np.linspace(basis.low, basis.high, 401)
        total = functions[eid](nodes) + basis.evaluate(nodes, coefficients)
        functions[eid] = ErrorFunction(eid, NodeTableBasis(tuple(nodes)), total)
    return ErrorModel(model.machine, functions, dict(model.squareness_urad))


MACHINE_KINDS = ("reversal", "cyclic", "thermal_drift", "cross_axis", "higher_order", "local")
SETUP_KINDS = ("abbe_offset", "cosine")
KINDS = MACHINE_KINDS + SETUP_KINDS

__all__ = [
    "AXES",
    "Plausibility",
    "AbbeOffset",
    "Cosine",
    "CrossAxis",
    "Cyclic",
    "Effect",
    "HigherOrder",
    "LocalDefect",
    "Reversal",
    "ThermalDrift",
    "refined_model",
]
