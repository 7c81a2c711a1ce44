"""The evidence plots of the closed loop, computed from a residual (GUI-free).

Each step of the loop names an effect; the plot that shows why is the residual's signature of
that effect (REFERENCE.md §4):

- reversal: the forward minus backward mean residual per target, along the axis;
- cyclic error: a least-squares periodogram of the residual along the axis, with the screw lead
  and its half marked;
- thermal drift: the residual against time (or material temperature);
- cross-axis, higher order, local defect: the mean residual per target along the axis, line by
  line — what a rigid body cannot produce;
- Abbe offset, cosine misalignment: the residual along the one line concerned.

Every function returns an :class:`Evidence`, a list of named x/y series that a plot widget draws.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from volucal.core.display_units import DisplayUnits
from volucal.core.machine import AXES, AXIS_INDEX, Machine

from .records import ReadingTable

FloatArray = NDArray[np.float64]

#: A line takes part in an axis' evidence when its travel has at least this component along it.
MOVING = 0.5
#: Periods scanned by the periodogram.
PERIOD_COUNT = 400


@dataclass(frozen=True)
class Series:
    name: str
    x: FloatArray
    y: FloatArray
    style: str = "line"  # "line" or "points"


@dataclass(frozen=True)
class Evidence:
    """A plot's content. ``y`` values are in ``y_unit`` ("um", "urad", or "" for a pure
    number); :meth:`y_axis` names the axis in the units it is shown in."""

    title: str
    x_label: str
    y_label: str
    series: tuple[Series, ...]
    markers: tuple[tuple[float, str], ...] = ()  # vertical lines: (x, label)
    note: str = ""
    log_x: bool = False
    extra: Mapping[str, Any] = field(default_factory=dict)
    y_unit: str = ""

    def y_axis(self, units: DisplayUnits) -> str:
        return f"{self.y_label} ({units.symbol(self.y_unit)})" if self.y_unit else self.y_label

    def y_shown(self, y: FloatArray, units: DisplayUnits) -> FloatArray:
        return units.convert(y, self.y_unit) if self.y_unit else np.asarray(y, dtype=float)


def _moving_lines(readings: ReadingTable, axis: str, reading_along: bool = False) -> list[int]:
    """Displacement lines travelling along ``axis``; with ``reading_along`` only those that also
    read along it (a linear line along X sees an X reversal, an X straightness line does not)."""
    k = AXIS_INDEX[axis]
    out = []
    for index, group in enumerate(readings.group):
        if group == "angular" or abs(readings.direction[index, k]) < MOVING:
            continue
        if reading_along and abs(readings.projection[index, k]) < MOVING:
            continue
        out.append(index)
    return out


def reversal_difference(readings: ReadingTable, axis: str) -> Evidence:
    """Forward minus backward mean residual per target for the lines moving along ``axis``."""
    k = AXIS_INDEX[axis]
    series = []
    for index in _moving_lines(readings, axis, reading_along=True):
        mask = readings.line_mask(index)
        targets = readings.target[mask]
        forward = readings.approach[mask, k] > 0
        residual = readings.residual[mask]
        position = readings.position_mm[mask, k]
        xs, ys = [], []
        for t in np.unique(targets):
            at = targets == t
            up, down = residual[at & forward], residual[at & ~forward]
            if up.size and down.size:
                xs.append(float(position[at][0]))
                ys.append(float(up.mean() - down.mean()))
        if xs:
            order = np.argsort(xs)
            series.append(Series(readings.line_names[index], np.asarray(xs)[order],
                                 np.asarray(ys)[order]))
    return Evidence(
        f"Reversal along {axis}: forward − backward mean residual",
        f"{axis} position (mm)", "forward − backward", tuple(series), y_unit="um",
        note=f"lines reading along {axis}; a reversal the 21-error model lacks shows as a "
             "constant step, scaled by how much of the reading is along the axis",
    )


def periodogram(
    readings: ReadingTable, axis: str, machine: Machine, period_mm: float | None = None
) -> Evidence:
    """Least-squares periodogram of the residual along ``axis``.

    For each trial period p the residual (its mean removed line by line) is fitted with
    a·sin(2πq/p) + b·cos(2πq/p); the plotted power is the fraction of the residual's variance the
    sinusoid explains (the least-squares spectrum that Lomb–Scargle approximates).
    """
    k = AXIS_INDEX[axis]
    lines = _moving_lines(readings, axis, reading_along=True)
    mask = np.isin(readings.line, lines)
    q = readings.position_mm[mask, k]
    y = readings.residual[mask].copy()
    line = readings.line[mask]
    for index in lines:
        at = line == index
        if at.any():
            y[at] -= y[at].mean()
    low_stroke, high_stroke = machine.stroke(axis)
    span = high_stroke - low_stroke
    steps = np.diff(np.unique(np.round(q, 3)))
    shortest = max(2.0 * float(np.median(steps)) if steps.size else 2.0, 1.0)
    markers: list[tuple[float, str]] = []
    lead = machine.screw_lead_mm.get(axis)
    if lead:
        markers += [(lead, f"screw lead {lead:g} mm"), (lead / 2.0, f"lead/2 {lead / 2:g} mm")]
    if period_mm is not None and not any(abs(period_mm - m[0]) < 1e-6 for m in markers):
        markers.append((period_mm, f"found {period_mm:.4g} mm"))
    # the screw lead, its half and the period found are scanned exactly, not between two grid
    # periods (the peak of a 400 mm record is only a few per cent wide)
    grid = np.geomspace(shortest, max(span / 2.0, shortest * 2.0), PERIOD_COUNT)
    periods = np.unique(np.concatenate([grid, [m[0] for m in markers]]))
    power = np.zeros(periods.size)
    total = float(np.sum(y**2))
    if q.size >= 4 and total > 0:
        for start in range(0, periods.size, 50):
            w = 2.0 * math.pi / periods[start:start + 50, None]
            s, c = np.sin(w * q), np.cos(w * q)
            ss, cc, sc = (s * s).sum(1), (c * c).sum(1), (s * c).sum(1)
            sy, cy = s @ y, c @ y
            det = ss * cc - sc * sc
            with np.errstate(divide="ignore", invalid="ignore"):
                a = (cc * sy - sc * cy) / det
                b = (ss * cy - sc * sy) / det
            power[start:start + 50] = np.nan_to_num((a * sy + b * cy) / total)
    return Evidence(
        f"Periodogram of the residual along {axis}",
        "period (mm)", "share of the residual variance", (Series("power", periods, power),),
        markers=tuple(markers), log_x=True,
        note=f"{len(lines)} line(s) moving along {axis}, {int(mask.sum())} readings",
    )


def residual_vs_time(readings: ReadingTable, temperature: bool = False) -> Evidence:
    """The displacement residual against time (hours) or material temperature (°C)."""
    series = []
    for index, name in enumerate(readings.line_names):
        if readings.group[index] == "angular":
            continue
        mask = readings.line_mask(index)
        x = readings.material_temp_c[mask] if temperature else readings.time_s[mask] / 3600.0
        keep = np.isfinite(x)
        if keep.any():
            series.append(Series(name, x[keep], readings.residual[mask][keep], "points"))
    what = "material temperature (°C)" if temperature else "time since the first reading (h)"
    return Evidence(
        "Residual against " + ("material temperature" if temperature else "time"),
        what, "residual", tuple(series), y_unit="um",
        note="" if series else "no material temperature was logged",
    )


def departure_along(readings: ReadingTable, axis: str, line_names: tuple[str, ...] = ()
                    ) -> Evidence:
    """Mean residual per target along ``axis``, line by line: the rigid-body departure."""
    k = AXIS_INDEX[axis]
    lines = _moving_lines(readings, axis)
    if line_names:
        lines = [i for i, n in enumerate(readings.line_names) if n in line_names]
    series = []
    for index in lines:
        mask = readings.line_mask(index)
        targets = readings.target[mask]
        position = readings.position_mm[mask, k]
        residual = readings.residual[mask]
        unique = np.unique(targets)
        xs = np.array([position[targets == t][0] for t in unique])
        ys = np.array([residual[targets == t].mean() for t in unique])
        order = np.argsort(xs)
        series.append(Series(readings.line_names[index], xs[order], ys[order]))
    unit = "urad" if series and all(readings.group[i] == "angular" for i in lines) else "um"
    return Evidence(
        f"Departure from the rigid-body model along {axis}",
        f"{axis} position (mm)", "mean residual", tuple(series), y_unit=unit,
        note="structure shared by parallel lines is a rigid-body error; what differs between "
             "them is not",
    )


def line_residual(readings: ReadingTable, name: str) -> Evidence:
    """Residual of one line against its target, one series per run."""
    if name not in readings.line_names:
        return Evidence(f"Line {name}", "target (mm)", "residual", (),
                        note=f"line {name!r} is not in this identification")
    index = readings.line_names.index(name)
    mask = readings.line_mask(index)
    unit = "urad" if readings.group[index] == "angular" else "um"
    series = []
    for run in np.unique(readings.run[mask]):
        at = mask & (readings.run == run)
        order = np.argsort(readings.target_mm[at])
        series.append(Series(f"run {run + 1}", readings.target_mm[at][order],
                             readings.residual[at][order]))
    return Evidence(f"Residual of line {name}", "target (mm)", "residual", tuple(series),
                    y_unit=unit)


def for_effect(readings: ReadingTable, effect: Mapping[str, Any], machine: Machine) -> Evidence:
    """The evidence plot of a loop step's effect (``{"kind", "axis", "parameters", ...}`` as in
    report.json, optionally with the constructor ``fields``)."""
    kind = str(effect.get("kind", ""))
    axis = str(effect.get("axis") or "")
    parameters = effect.get("parameters", {}) or {}
    fields = (effect.get("effect") or {}).get("fields", {}) if isinstance(
        effect.get("effect"), Mapping) else {}
    if kind == "reversal" and axis in AXES:
        return reversal_difference(readings, axis)
    if kind == "cyclic" and axis in AXES:
        period = parameters.get("period_mm", fields.get("period_mm"))
        return periodogram(readings, axis, machine, None if period is None else float(period))
    if kind == "thermal_drift":
        use_temperature = fields.get("mode") == "temperature" or "temperature" in str(
            effect.get("label", ""))
        evidence = residual_vs_time(readings, temperature=use_temperature)
        if use_temperature and not evidence.series:
            return residual_vs_time(readings)
        return evidence
    if kind in ("abbe_offset", "cosine"):
        name = parameters.get("line") or fields.get("line_name")
        if name:
            return line_residual(readings, str(name))
    if kind == "cross_axis":
        along = parameters.get("depends_on", [fields.get("along", axis)])[0]
        if along in AXES:
            return departure_along(readings, along)
    if axis in AXES:
        return departure_along(readings, axis)
    return Evidence(str(effect.get("label", kind)), "", "", (),
                    note="no evidence plot for this effect")
