"""The scale of an axis that a line nothing explains reads apart from the model.

The 21 errors describe the machine at the session's first reading (DESIGN, "Time"); a thermal
drift the loop keeps is referred to that moment. Where no drift is kept, an axis whose scale
changed during the session is fitted at the scale its lines share, weighted by how much of each
they hold, and nothing says which of the scales it went through it had at the first reading. A
linear line moving the axis alone that the loop reports unexplained, and whose passes read the
axis' scale apart from the model's, says how far it went: blind 54153 (the plan of the demo; the
X scale warming by 25 ppm with τ 43 min from the session's first reading, x_linear measured
then, the other three X lines ten hours later) kept no drift, since what held out x_linear
could not predict it, and stated EXX 25 ppm (5.8 µm RMS) from the machine at the first reading
with 0.19 µm of standard uncertainty; x_linear's passes read the scale 13.8 to 22.3 ppm below
the model's.

The largest scale a pass of such a line reads apart from the model, h, bounds the doubt without
saying how it is distributed: its positioning error's covariance is widened by a scale of
±h ppm about the reference position as a rectangular distribution (u = h/√3, GUM 4.3.7), and the
line's entry names it. Nothing is added where the line's scale is within its noise (neither its
mean nor its course in time beyond it) or where the doubt is within the error's stated
uncertainty.

A scale the machine had at its first reading beyond every line's is read by no line; where the
files log the material temperature, it says how far that may be: the temperature doubt
(:func:`temperature_doubts`) of an axis all of whose lines were measured warmer or cooler than
the first reading, bounded by the expansion coefficient the files state and by how far the lines
at other temperatures read the scale following it.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy import special

from .effects import ThermalDrift
from .errors import ErrorModel
from .identify import Identification
from .loop_courses import moving_one_axis, scales_in_time
from .loop_end import STROKE_POINTS, fit_in_gauge, with_shape_doubt
from .loop_reach import rms_std
from .loop_records import FloatArray, ScaleDoubt, TemperatureDoubt, Unexplained
from .loop_tester import Tester, log10_text
from .loop_unexplained import line_scale

#: A rectangular distribution of half-width h has the standard deviation h / √3 (GUM 4.3.7).
RECTANGULAR = 1.0 / np.sqrt(3.0)


def scale_doubts(
    final: Identification, lines: Collection[str], axes: Collection[str], alpha: float
) -> dict[str, ScaleDoubt]:
    """Per axis without a kept drift: the doubt of the unexplained line moving it alone (of
    ``lines``, names, or any such line of ``axes``, whose lines read different scales over the
    session) whose passes read its scale farthest from ``final``'s, where the line's scale
    differs from the model's beyond its noise (its mean, or its course in time,
    :func:`~volucal.core.loop_courses.scales_in_time`; Bonferroni over the lines tested, at
    ``alpha``) and the doubt exceeds the error's stated standard uncertainty (an error the plan
    does not identify has none to widen)."""
    readings = final.readings
    drifting = _drifting(final)
    tested = [
        (index, axis)
        for index, axis in moving_one_axis(readings)
        if (readings.lines[index].name in lines or axis in axes) and axis not in drifting
    ]
    if not tested:
        return {}
    in_time = scales_in_time(final, alpha)
    found: dict[str, tuple[int, _Passes, float]] = {}
    for index, axis in tested:
        scale = line_scale(final, index)
        if scale.dof <= 0:
            continue
        # its mean scale against its noise, Bonferroni over the lines tested; or its course in time
        p_mean = float(special.fdtrc(1, scale.dof, scale.slope**2 / scale.variance))
        if p_mean * len(tested) < alpha:
            p = p_mean
        elif index in in_time:
            p = in_time[index][1]
        else:
            continue
        passes = _passes(final, index)
        if passes is None:
            continue
        if axis not in found or passes.farthest > found[axis][1].farthest:
            found[axis] = (index, passes, p)
    out = {}
    model = final.model
    for axis, (index, passes, p) in found.items():
        eid = f"E{axis}{axis}"
        if not final.is_identified(eid):
            continue
        delta, move = _scale_move(model, axis, passes.farthest)
        stated = rms_std(final, eid)
        if move <= stated:
            continue
        far = int(np.argmax(np.abs(passes.scale_ppm)))
        name = readings.lines[index].name
        out[name] = ScaleDoubt(
            axis,
            eid,
            name,
            (float(passes.scale_ppm.min()), float(passes.scale_ppm.max())),
            passes.runs[far],
            float(passes.minutes[far]),
            p,
            move,
            stated,
            delta,
        )
    return out


def _scale_move(model: ErrorModel, axis: str, half_width_ppm: float) -> tuple[FloatArray, float]:
    """The move of ``model``'s parameters a rectangular scale doubt of ±``half_width_ppm`` about
    the axis' reference position makes (its standard deviation, h/√3, in the axis' positioning
    error, within its gauge), and that move's RMS over the stroke (µm)."""
    eid = f"E{axis}{axis}"
    low, high = model.machine.stroke(axis)
    q = np.linspace(low, high, STROKE_POINTS)
    values = RECTANGULAR * half_width_ppm * 1e-3 * (q - model.machine.reference(axis))
    coefficients = fit_in_gauge(model, eid, q, values)
    delta = np.zeros(model.parameter_count)
    delta[model.parameter_slices[eid]] = coefficients
    move = float(np.sqrt(np.mean((model.functions[eid].basis.design(q) @ coefficients) ** 2)))
    return delta, move


#: A run counts towards a line's scale where its targets' spread about their mean (Σ q²) is at
#: least this share of the fullest run's: a run cut short reads any offset as a slope.
FULL_RUN_SHARE = 0.5


@dataclass(frozen=True)
class _Passes:
    """A line's scale relative to a fit, pass by pass (:func:`_passes`)."""

    scale_ppm: FloatArray  # per pass
    runs: tuple[tuple[int, ...], ...]  # per pass: its runs' numbers (from 1)
    minutes: FloatArray  # per pass: its mid-time, from the session's first reading

    @property
    def farthest(self) -> float:
        """The largest scale a pass reads apart from the model (ppm)."""
        return float(np.max(np.abs(self.scale_ppm)))


def _passes(fit: Identification, index: int) -> _Passes | None:
    """Line ``index``'s scale relative to ``fit``, per pass: each run's slope of its residual over
    its targets (about their mean in that run), and where a run out is followed by one back, the
    mean of the two. A drift of the laser's reading in time reads as a slope in a run that moves
    one way, and as the opposite slope in the run back; a scale reads alike in both (a backlash
    is an offset of each direction, no slope). Runs cut short (:data:`FULL_RUN_SHARE`) are left
    out; None where no run is left."""
    readings = fit.readings
    rows = np.flatnonzero(readings.line == index)
    numbers, run = np.unique(readings.run[rows], return_inverse=True)
    count = np.bincount(run).astype(float)
    q = readings.target_mm[rows]
    q = q - (np.bincount(run, weights=q) / count)[run]
    qq = np.bincount(run, weights=q * q)
    full = qq >= FULL_RUN_SHARE * qq.max() if qq.max() > 0 else np.zeros(qq.size, dtype=bool)
    if not full.any():
        return None
    slope = np.bincount(run, weights=q * fit.residual[rows]) / np.maximum(qq, 1e-300)
    minutes = np.bincount(run, weights=readings.time_s[rows]) / count / 60.0
    direction = readings.lines[index].data.run_direction[numbers]
    order = [int(i) for i in np.argsort(minutes) if full[i]]
    groups: list[list[int]] = []
    for i in order:
        # a run back after a run out (or out after back) joins it; else it starts a pass
        if groups and len(groups[-1]) == 1 and direction[groups[-1][0]] != direction[i]:
            groups[-1].append(i)
        else:
            groups.append([i])
    scales = [1e3 * float(np.mean(slope[g])) for g in groups]
    runs = [tuple(int(numbers[i]) + 1 for i in g) for g in groups]
    times = [float(np.mean(minutes[g])) for g in groups]
    return _Passes(np.array(scales), tuple(runs), np.array(times))


def _sentence(doubt: ScaleDoubt) -> str:
    """What the doubt adds to the description of its entry."""
    low, high = doubt.scale_ppm
    runs = "run" if len(doubt.runs) == 1 else "runs"
    return (
        f"line {doubt.line}'s runs read the {doubt.axis} scale {low:+.3g} to {high:+.3g} ppm "
        f"from the model's ({runs} {' and '.join(map(str, doubt.runs))}, {doubt.minutes:.0f} min "
        f"into the session, the farthest; log10 false alarm {log10_text(doubt.false_alarm)}); "
        "the 21 errors describe the machine at the session's first reading, and no kept effect "
        f"says which of these scales it had: {doubt.error_id}'s stated uncertainty includes a "
        f"scale of ±{doubt.half_width_ppm:.3g} ppm, rectangular ({doubt.move:.3g} µm RMS over "
        f"its stroke, {doubt.move / max(doubt.stated_std, 1e-300):.3g} times its standard "
        "uncertainty before this doubt)"
    )


def with_scale_doubts(
    final: Identification, unexplained: Sequence[Unexplained], alpha: float
) -> tuple[Identification, list[Unexplained]]:
    """``final`` widened by the scale doubts of its unexplained lines (:func:`scale_doubts`), and
    the entries saying them (on each line's first entry)."""
    lines = {u.line for u in unexplained if u.line}
    doubts = scale_doubts(final, lines, {u.axis for u in unexplained if u.axis}, alpha)
    if not doubts:
        return final, list(unexplained)
    widened = with_shape_doubt(final, [d.delta for d in doubts.values()], share=1.0)
    # said on the line's first entry, else on its axis' entry
    by_axis = {d.axis: d for d in doubts.values() if d.line not in lines}
    out, said = [], set()
    for item in unexplained:
        doubt = doubts.get(item.line) if item.line else by_axis.get(item.axis)
        if doubt is None or doubt.line in said:
            out.append(item)
            continue
        said.add(doubt.line)
        description = item.description.rstrip(". ") + "; " + _sentence(doubt)
        out.append(replace(item, description=description, scale=doubt))
    return widened, out


def temperature_doubts(final: Identification, fitted: Identification) -> list[TemperatureDoubt]:
    """Per axis without a kept drift: the doubt its material's change of temperature puts on its
    positioning error, where its files log the material temperature and state an expansion
    coefficient.

    The 21 errors describe the machine at the session's first reading (DESIGN, "Time"). A drift
    the loop keeps refers the scale back there; without one, the axis' positioning error is the
    scale of the hours its lines were measured in. Where the material was ΔT warmer (or cooler)
    then than at the first reading, a structure expanding with the coefficient α its files state
    had a scale α·ΔT apart at the first reading, and nothing in the readings says whether it
    did: a drift that settled before the axis' first line (blind 54085: Y warming by 2.4 °C with
    τ 80 min, its first line at 190 min) leaves every line of the axis at one scale, which the
    21 errors take up whole. A line of the axis measured at the first reading's temperature
    reads its scale there, and lines at other temperatures read how far it followed
    (:func:`following`, on ``fitted``: ``final`` before any doubt widened it; None where no line
    reads it); what no line reads is the way from the temperature nearest the first reading's to
    it. So h = |ΔT|·min(α, followed), ΔT of the line moving the axis alone whose mean
    temperature is nearest the first reading's and α as its file states it (else as the axis'
    other files do), is the half-width of a rectangular scale doubt about the reference position
    (u = h/√3, GUM 4.3.7): the bound carries the scale's following read between other
    temperatures back to the first reading's, as a straight line in the temperature. Nothing is
    added where that is within the error's stated standard uncertainty, where the first reading
    or a line of the axis logs no temperature (that line may have read the scale there), or
    where no file of the axis states a coefficient."""
    readings = final.readings
    temperature = readings.material_temp_c
    if not readings.time_s.size:
        return []
    first = int(np.argmin(readings.time_s))
    if not np.isfinite(temperature[first]):
        return []  # not logged at the first reading: nothing says how far it changed since
    drifting = _drifting(final)
    lines: dict[str, list[tuple[float, int, float, float | None]]] = {}
    for index, axis in moving_one_axis(readings):
        rows = np.flatnonzero(readings.line == index)
        if axis in drifting or rows.size == 0:
            continue
        change = float(np.mean(temperature[rows]) - temperature[first])  # NaN: not logged
        minutes = float(np.mean(readings.time_s[rows])) / 60.0
        stated = readings.lines[index].data.environment.expansion_ppm_per_c
        lines.setdefault(axis, []).append((change, index, minutes, stated))
    nearest: dict[str, tuple[int, float, float, float]] = {}
    for axis, measured in lines.items():
        # a line whose file logs no temperature may have read the scale at the first reading's
        if not all(np.isfinite(change) for change, *_ in measured):
            continue
        measured.sort(key=lambda m: abs(m[0]))
        change, index, minutes, _ = measured[0]
        expansions = [abs(float(a)) for *_, a in measured if a is not None and np.isfinite(a)]
        # the nearest line's coefficient, else the one the axis' other files state
        if expansions and change * expansions[0] != 0.0 and final.is_identified(f"E{axis}{axis}"):
            nearest[axis] = (index, change, minutes, expansions[0])
    # read only for the axes a doubt may be given (a Tester and an F test each)
    followed = following(fitted, list(nearest)) if nearest else {}
    out = []
    model = final.model
    for axis, (index, change, minutes, expansion) in nearest.items():
        eid = f"E{axis}{axis}"
        bound = followed.get(axis)
        half_width = abs(change) * (expansion if bound is None else min(expansion, float(bound)))
        delta, move = _scale_move(model, axis, half_width)
        stated = rms_std(final, eid)
        if move <= stated:
            continue
        name = readings.lines[index].name
        out.append(
            TemperatureDoubt(
                axis,
                eid,
                name,
                change,
                minutes,
                expansion,
                half_width,
                bound,
                move,
                stated,
                delta,
            )
        )
    return out


#: The coverage factor of the bound on how far an axis' scale followed the material
#: temperature (:func:`following`).
FOLLOWED_COVERAGE = 2.0


def _drifting(fit: Identification) -> set[str]:
    """The axes of the drifts ``fit`` keeps: their scale is referred to the first reading."""
    return {e.axis for e in fit.effects if isinstance(e, ThermalDrift)}


def following(fit: Identification, axes: Sequence[str]) -> dict[str, float | None]:
    """Per axis of ``axes``, how far its scale may follow the material temperature by
    what the readings read (ppm/°C): |κ| + 2u(κ) of a drift driven by the temperature since the
    session's first reading, fitted to what ``fit`` leaves once it absorbed what it can (the F
    test's projection; ``fit`` as fitted, its covariance not yet widened). Lines measured at
    different temperatures read it; None where none does (the drift's column is absorbed
    whole, as where every line of the axis was measured at one temperature)."""
    readings = fit.readings
    # a reading without a temperature would count as at the first reading's
    if not readings.time_s.size or not np.isfinite(readings.material_temp_c).all():
        return {}
    tester = Tester(fit)
    out: dict[str, float | None] = {}
    for axis in axes:
        reference = fit.model.machine.reference(axis)
        drift = ThermalDrift(axis, "temperature", reference_mm=reference)
        f_stat, _, _, beta = tester.test(drift.design(readings, fit.model))
        size = abs(float(beta[0]))
        if tester.last_dimensions == 0 or f_stat <= 0.0 or size == 0.0:
            out[axis] = None
        else:
            out[axis] = size + FOLLOWED_COVERAGE * size / float(np.sqrt(f_stat))
    return out


def temperature_warning(doubt: TemperatureDoubt) -> str:
    """What the report says of a temperature doubt."""
    bound = f"at the {doubt.expansion_ppm_per_c:.3g} ppm/°C its files state"
    if (
        doubt.followed_ppm_per_c is not None
        and doubt.followed_ppm_per_c < doubt.expansion_ppm_per_c
    ):
        bound += (
            f" (the lines read at other temperatures say it followed at most "
            f"{doubt.followed_ppm_per_c:.3g} ppm/°C)"
        )
    return (
        f"the material was {abs(doubt.change_c):.2g} °C "
        f"{'warmer' if doubt.change_c > 0 else 'cooler'} than at the session's first reading on "
        f"every line moving {doubt.axis} alone, {doubt.line} ({doubt.minutes:.0f} min into the "
        f"session) the nearest, and no kept drift refers the {doubt.axis} scale back to it: "
        f"{bound}, the scale may have been {doubt.half_width_ppm:.3g} ppm apart then, which the "
        f"readings cannot tell; {doubt.error_id}'s stated uncertainty includes a scale of "
        f"±{doubt.half_width_ppm:.3g} ppm, rectangular ({doubt.move:.3g} µm RMS over its "
        f"stroke, {doubt.move / max(doubt.stated_std, 1e-300):.3g} times its standard "
        "uncertainty before this doubt)"
    )


def with_temperature_doubts(
    final: Identification, fitted: Identification
) -> tuple[Identification, list[TemperatureDoubt]]:
    """``final`` widened by its axes' temperature doubts (:func:`temperature_doubts`; ``fitted``
    is ``final`` before any doubt widened it)."""
    doubts = temperature_doubts(final, fitted)
    if not doubts:
        return final, []
    return with_shape_doubt(final, [d.delta for d in doubts], share=1.0), doubts


__all__ = [
    "RECTANGULAR",
    "following",
    "scale_doubts",
    "temperature_doubts",
    "temperature_warning",
    "with_scale_doubts",
    "with_temperature_doubts",
]
