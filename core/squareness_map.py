"""The squareness the tool's paths make at a place: what a square, or a laser's squareness
optics, would read there on the identified machine.

The model's squareness errors (EC0Y, EB0Z, EA0Z) are the angles between the axes' directions
with every straightness function gauged to zero least-squares slope (DESIGN.md, Gauges). What a
metrologist measures at a place is another angle: the one between the least-squares lines of the
tool point's two paths through it (ISO 230-1, squareness between two linear axes). It adds to
the parameter the slopes that the angular errors draw through the lever arms of that place and
of the tool, and the tilt of any kept effect that adds to a path (a cross-axis surface's slice
changes from place to place: a table that twists makes the axes square at one height and not at
another). This module reads that angle off the extended model — the 21 errors with the kept
machine effects, at the model's tool offset — on a grid of places over the measured volume, and
its standard uncertainty at the volume's centre from the fit's covariance of every unknown.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .effects import Effect
from .kinematics import jacobian
from .loop_source import LoopSource, parameter_map

FloatArray = NDArray[np.float64]

#: Per squareness id: the first axis, the second, and the sign that makes the angle between
#: their paths the squareness itself on a machine with no other error. EC0Y rotates Y about +Z,
#: so a path along Y reads E_x = −y·EC0Y: the angle is −(dE_x/dy + dE_y/dx); EB0Z rotates Z
#: about +Y (E_x = +z·EB0Z): +(dE_x/dz + dE_z/dx); EA0Z rotates Z about +X (E_y = −z·EA0Z):
#: −(dE_y/dz + dE_z/dy). Slopes in µm/mm are mrad.
PATHS = {"EC0Y": ("X", "Y", -1.0), "EB0Z": ("X", "Z", 1.0), "EA0Z": ("Y", "Z", -1.0)}
AXES = "XYZ"
#: Points along each path (uniform over the measured range of its axis).
PATH_POINTS = 101
#: Places per axis of the grid the angle is read on (the range's ends and evenly between).
GRID_PER_AXIS = 5


@dataclass(frozen=True)
class SquarenessAtPlaces:
    """One squareness error as the tool's paths make it over the measured volume (µrad, mm)."""

    squareness_id: str
    axes: tuple[str, str]
    #: per axis the range (mm) the paths span and the grid covers
    volume_mm: dict[str, tuple[float, float]]
    parameter_urad: float
    centre_mm: tuple[float, float, float]
    at_centre_urad: float
    at_centre_std_urad: float
    lowest_urad: float
    lowest_at_mm: tuple[float, float, float]
    highest_urad: float
    highest_at_mm: tuple[float, float, float]
    #: the kept machine effects that tilt one of the two paths somewhere on the grid
    tilted_by: tuple[str, ...]

    def to_json(self) -> dict[str, object]:
        return {
            "axes": list(self.axes),
            "volume_mm": {axis: list(span) for axis, span in self.volume_mm.items()},
            "parameter_urad": self.parameter_urad,
            "centre_mm": list(self.centre_mm),
            "at_centre_urad": self.at_centre_urad,
            "at_centre_std_urad": self.at_centre_std_urad,
            "lowest_urad": self.lowest_urad,
            "lowest_at_mm": list(self.lowest_at_mm),
            "highest_urad": self.highest_urad,
            "highest_at_mm": list(self.highest_at_mm),
            "tilted_by": list(self.tilted_by),
        }


def squareness_map(source: LoopSource) -> tuple[SquarenessAtPlaces, ...]:
    """Per squareness error the plan identifies, with both straightness functions of its pair
    of axes: the angle between the tool point's least-squares paths along the two axes through
    each place of a :data:`GRID_PER_AXIS`-per-axis grid over the measured volume
    (``source.measured_range_mm``, else the strokes), at the model's tool offset, with no
    approach direction (a reversal's halves cancel); its value and standard uncertainty at the
    grid's centre, and where it is lowest and highest. The uncertainty is first order: the
    angle's gradient over every unknown of the fit (the 21 errors' gauge coordinates and the
    kept effects' values) through their joint covariance."""
    fit = source.identification
    ranges = _ranges(source)
    places = _grid(ranges)
    centre = np.array([0.5 * sum(ranges[axis]) for axis in AXES])
    mapping = parameter_map(fit, source.model)
    out = []
    for sid, (first, second, _) in PATHS.items():
        pair = (f"E{second}{first}", f"E{first}{second}")
        if not all(fit.is_identified(eid) for eid in (sid, *pair)):
            continue
        angles = np.array([_angle(source, ranges, p, sid) for p in places])
        at_centre = _angle(source, ranges, centre, sid)
        low, high = int(np.argmin(angles)), int(np.argmax(angles))
        out.append(
            SquarenessAtPlaces(
                squareness_id=sid,
                axes=(first, second),
                volume_mm={axis: (_mm(a), _mm(b)) for axis, (a, b) in ranges.items()},
                parameter_urad=float(fit.model.squareness_urad[sid]),
                centre_mm=_place(centre),
                at_centre_urad=at_centre,
                at_centre_std_urad=_std_at(source, mapping, ranges, centre, sid),
                lowest_urad=float(angles[low]),
                lowest_at_mm=_place(places[low]),
                highest_urad=float(angles[high]),
                highest_at_mm=_place(places[high]),
                tilted_by=_tilting(source, ranges, places, sid),
            )
        )
    return tuple(out)


def _grid(ranges: dict[str, tuple[float, float]]) -> FloatArray:
    axes = [np.linspace(*ranges[axis], GRID_PER_AXIS) for axis in AXES]
    return np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], axis=-1)


def _mm(value: float) -> float:
    # a range's end read back from the readings can be −6e-14 mm: reported as the place it is
    return round(float(value), 6) + 0.0


def _place(p: FloatArray) -> tuple[float, float, float]:
    x, y, z = (_mm(v) for v in p)
    return (x, y, z)


def _path(ranges: dict[str, tuple[float, float]], place: FloatArray, axis: str) -> FloatArray:
    """The machine states along ``axis`` through ``place``, over the axis' measured range."""
    states = np.tile(place, (PATH_POINTS, 1)).astype(float)
    states[:, AXES.index(axis)] = np.linspace(*ranges[axis], PATH_POINTS)
    return states


def _slope_weights(q: FloatArray) -> FloatArray:
    """Weights w with w @ values the least-squares slope of values over positions q."""
    centred = q - q.mean()
    return np.asarray(centred / np.sum(centred**2))


def _legs(
    ranges: dict[str, tuple[float, float]], place: FloatArray, sid: str
) -> list[tuple[FloatArray, FloatArray, int]]:
    """Both paths of ``sid``'s axes through ``place``: their states, slope weights and the
    component of E whose slope along the path tilts it towards the other axis."""
    first, second, _ = PATHS[sid]
    legs = []
    for along, towards in ((first, second), (second, first)):
        states = _path(ranges, place, along)
        weights = 1000.0 * _slope_weights(states[:, AXES.index(along)])  # µm/mm → µrad
        legs.append((states, weights, AXES.index(towards)))
    return legs


def path_angle(source: LoopSource, squareness_id: str, place_mm: FloatArray) -> float:
    """The angle (µrad) between the tool point's least-squares paths along the two axes of
    ``squareness_id`` through ``place_mm``, each over its axis' measured range, in the sign of
    that squareness (:data:`PATHS`)."""
    return _angle(source, _ranges(source), np.asarray(place_mm, float), squareness_id)


def _ranges(source: LoopSource) -> dict[str, tuple[float, float]]:
    return {axis: source.measured_range_mm.get(axis, source.machine.stroke(axis)) for axis in AXES}


def _angle(
    source: LoopSource, ranges: dict[str, tuple[float, float]], place: FloatArray, sid: str
) -> float:
    total = 0.0
    for states, weights, component in _legs(ranges, place, sid):
        total += float(weights @ source.error_um(states)[:, component])
    return PATHS[sid][2] * total


def _std_at(
    source: LoopSource,
    mapping: FloatArray,
    ranges: dict[str, tuple[float, float]],
    place: FloatArray,
    sid: str,
) -> float:
    """The angle's first-order standard uncertainty at ``place``; ``mapping`` takes the fit's
    unknowns to the refined model's parameters (:func:`parameter_map`)."""
    fit = source.identification
    gradient = np.zeros(fit.system.size)
    columns = [b.columns for b in fit.system.blocks if b.kind == "effect"]
    tool = source.machine.tool_offset_mm
    sign = PATHS[sid][2]
    for states, weights, component in _legs(ranges, place, sid):
        design = jacobian(source.model, states, tool)[:, component, :]
        gradient += sign * (mapping.T @ (weights @ design))
        for effect, values, at in zip(fit.effects, fit.effect_parameters, columns, strict=True):
            if not isinstance(effect, Effect):
                continue
            units = np.eye(len(values))
            per_value = np.stack(
                [effect.error_um(u, source.machine, states)[:, component] for u in units], axis=1
            )
            gradient[at] += sign * (weights @ per_value)
    covariance = fit.normal_inverse * fit.sigma_scale**2
    variance = float(gradient @ covariance @ gradient)
    return float(np.sqrt(max(variance, 0.0)))


def _tilting(
    source: LoopSource, ranges: dict[str, tuple[float, float]], places: FloatArray, sid: str
) -> tuple[str, ...]:
    """The kept machine effects whose error tilts either path somewhere on the grid by more
    than 1e-3 µrad."""
    labels = []
    for effect, values in source.effects:
        for place in places:
            legs = _legs(ranges, place, sid)
            tilt = sum(
                abs(float(w @ effect.error_um(values, source.machine, s)[:, c])) for s, w, c in legs
            )
            if tilt > 1e-3:
                labels.append(effect.label)
                break
    return tuple(labels)
