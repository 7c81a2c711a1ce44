"""The scale of an axis that a line nothing explains reads apart from the model.

The 21 errors describe the machine at the session's first reading (DESIGN, "Time"); a thermal
drift the loop keeps is referred to that moment. Where no drift is kept, an axis whose scale
changed during the session is fitted at the scale its lines share, weighted by how much of each
they hold, and nothing says which of the scales it went through it had at the first reading. A
linear line moving the axis alone that the loop reports unexplained, and whose runs read the
axis' scale apart from the model's, says how far it went: blind 54153 (the plan of the demo; the
X scale warming by 25 ppm with τ 43 min from the session's first reading, x_linear measured
then, the other three X lines ten hours later) kept no drift, since what held out x_linear
could not predict it, and stated EXX 25 ppm (5.8 µm RMS) from the machine at the first reading
with 0.19 µm of standard uncertainty; x_linear's runs read the scale 13.8 to 22.3 ppm below the
model's.

The largest scale a run of such a line reads apart from the model, h, bounds the doubt without
saying how it is distributed: its positioning error's covariance is widened by a scale of
±h ppm about the reference position as a rectangular distribution (u = h/√3, GUM 4.3.7), and the
line's entry names it. A line whose residual has no scale beyond its noise adds nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from scipy import special

from .effects import ThermalDrift
from .identify import Identification
from .loop_courses import moving_one_axis, scales_in_time
from .loop_end import STROKE_POINTS, fit_in_gauge, with_shape_doubt
from .loop_records import ScaleDoubt, Unexplained
from .loop_unexplained import LineScale, line_scale

#: A rectangular distribution of half-width h has the standard deviation h / √3 (GUM 4.3.7).
RECTANGULAR = 1.0 / np.sqrt(3.0)


def scale_doubts(
    final: Identification, lines: Sequence[str], axes: Sequence[str], alpha: float
) -> dict[str, ScaleDoubt]:
    """Per axis without a kept drift: the doubt of the unexplained line moving it alone (of
    ``lines``, names, or any such line of ``axes``, whose lines read different scales over the
    session) whose runs read its scale farthest from ``final``'s, where the line's scale
    differs from the model's beyond its noise (its mean, or its course in time,
    :func:`~volucal.core.loop_courses.scales_in_time`; Bonferroni over the lines tested, at
    ``alpha``) and the doubt exceeds the error's stated standard uncertainty."""
    readings = final.readings
    drifting = {e.axis for e in final.effects if isinstance(e, ThermalDrift)}
    names = set(lines)
    tested = [
        (index, axis)
        for index, axis in moving_one_axis(readings)
        if (readings.lines[index].name in names or axis in axes) and axis not in drifting
    ]
    if not tested:
        return {}
    in_time = scales_in_time(final, alpha)
    found: dict[str, tuple[int, LineScale, float]] = {}
    for index, axis in tested:
        runs = line_scale(final, index)
        if runs.dof <= 0:
            continue
        # its mean scale against its noise, Bonferroni over the lines tested; or its course in time
        p_mean = float(special.fdtrc(1, runs.dof, runs.slope**2 / runs.variance))
        if p_mean * len(tested) >= alpha and index not in in_time:
            continue
        p = min(p_mean, in_time[index][1] if index in in_time else 1.0)
        if axis not in found or _farthest(runs) > _farthest(found[axis][1]):
            found[axis] = (index, runs, p)
    out = {}
    model = final.model
    for axis, (index, runs, p) in found.items():
        eid = f"E{axis}{axis}"
        low, high = model.machine.stroke(axis)
        q = np.linspace(low, high, STROKE_POINTS)
        values = RECTANGULAR * _farthest(runs) * 1e-3 * (q - model.machine.reference(axis))
        coefficients = fit_in_gauge(model, eid, q, values)
        delta = np.zeros(model.parameter_count)
        delta[model.parameter_slices[eid]] = coefficients
        move = float(np.sqrt(np.mean((model.functions[eid].basis.design(q) @ coefficients) ** 2)))
        _, _, std = final.band(eid)
        stated = float(np.sqrt(np.mean(std**2)))
        if move <= stated:
            continue
        ppm = 1e3 * runs.run_slopes
        far = int(np.argmax(np.abs(ppm)))
        name = readings.lines[index].name
        out[name] = ScaleDoubt(
            axis,
            eid,
            name,
            (float(ppm.min()), float(ppm.max())),
            int(runs.run_numbers[far]),
            float(runs.run_minutes[far]),
            float(np.log10(max(p, 1e-300))),
            move,
            stated,
            delta,
        )
    return out


def _farthest(scale: LineScale) -> float:
    """The largest scale a run of the line reads apart from the model (ppm)."""
    return 1e3 * float(np.max(np.abs(scale.run_slopes)))


def with_scale_doubts(
    final: Identification, unexplained: Sequence[Unexplained], alpha: float
) -> tuple[Identification, list[Unexplained]]:
    """``final`` widened by the scale doubts of its unexplained lines (:func:`scale_doubts`), and
    the entries saying them (on each line's first entry)."""
    lines = {u.line for u in unexplained if u.line}
    doubts = scale_doubts(final, sorted(lines), [u.axis for u in unexplained if u.axis], alpha)
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
        description = item.description.rstrip(". ") + "; " + doubt.sentence()
        out.append(replace(item, description=description, scale=doubt))
    return widened, out


__all__ = ["RECTANGULAR", "scale_doubts", "with_scale_doubts"]
