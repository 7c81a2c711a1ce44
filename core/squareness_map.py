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
machine effects, at the model's tool offset — on a grid of places over the measured volume, with
its standard uncertainty at every place from the fit's covariance of every unknown.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np
from numpy.typing import NDArray

from .effects import Effect
from .identify import Identification
from .kinematics import jacobian
from .loop_source import LoopSource, measured_range, parameter_map

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
#: Places per axis of the grid the angle is read on (the range's ends and evenly between; odd,
#: so that the volume's centre is one of them).
GRID_PER_AXIS = 5


@dataclass(frozen=True, eq=False)
class SquarenessAtPlaces:
    """One squareness error as the tool's paths make it over the measured volume (µrad, mm):
    the angle and its standard uncertainty at every place of the grid, and the places that
    matter named."""

    squareness_id: str
    axes: tuple[str, str]
    #: per axis the range (mm) the paths span and the grid covers
    volume_mm: dict[str, tuple[float, float]]
    parameter_urad: float
    #: (N, 3) the grid's places, X slowest; the angle there and its standard uncertainty (N,)
    places_mm: FloatArray
    angle_urad: FloatArray
    std_urad: FloatArray
    #: the kept machine effects that tilt one of the two paths somewhere on the grid
    tilted_by: tuple[str, ...]

    @property
    def centre(self) -> int:
        return len(self.places_mm) // 2

    @property
    def lowest(self) -> int:
        return int(np.argmin(self.angle_urad))

    @property
    def highest(self) -> int:
        return int(np.argmax(self.angle_urad))

    @property
    def least_certain(self) -> int:
        return int(np.argmax(self.std_urad))

    @property
    def centre_mm(self) -> tuple[float, float, float]:
        return _place(self.places_mm[self.centre])

    @property
    def at_centre_urad(self) -> float:
        return float(self.angle_urad[self.centre])

    @property
    def at_centre_std_urad(self) -> float:
        return float(self.std_urad[self.centre])

    def to_json(self) -> dict[str, object]:
        out: dict[str, object] = {
            "axes": list(self.axes),
            "volume_mm": {axis: list(span) for axis, span in self.volume_mm.items()},
            "parameter_urad": self.parameter_urad,
        }
        for key, index in (
            ("at_centre", self.centre),
            ("lowest", self.lowest),
            ("highest", self.highest),
            ("least_certain", self.least_certain),
        ):
            where = "centre_mm" if key == "at_centre" else f"{key}_at_mm"
            out[where] = list(_place(self.places_mm[index]))
            out[f"{key}_urad"] = float(self.angle_urad[index])
            out[f"{key}_std_urad"] = float(self.std_urad[index])
        out["tilted_by"] = list(self.tilted_by)
        out["places"] = {
            "place_mm": [list(_place(p)) for p in self.places_mm],
            "angle_urad": [float(v) for v in self.angle_urad],
            "std_urad": [float(v) for v in self.std_urad],
        }
        return out


def squareness_map(source: LoopSource) -> tuple[SquarenessAtPlaces, ...]:
    """Per squareness error the plan identifies, with both straightness functions of its pair
    of axes: the angle between the tool point's least-squares paths along the two axes through
    each place of a :data:`GRID_PER_AXIS`-per-axis grid over the measured volume
    (``source.measured_range_mm``, else the strokes), at the model's tool offset, with no
    approach direction (a reversal's halves cancel), and its standard uncertainty there. The
    uncertainty is first order: the angle's gradient over every unknown of the fit (the 21
    errors' gauge coordinates and the kept effects' values) through their joint covariance."""
    fit = source.identification
    assert fit is not None, "the map needs the fit's covariance: a stored source has none"
    ranges = _ranges(source)
    places = _grid(ranges)
    mapping = parameter_map(fit, source.model)
    covariance = fit.normal_inverse * fit.sigma_scale**2
    out = []
    for sid, (first, second, _) in PATHS.items():
        pair = (f"E{second}{first}", f"E{first}{second}")
        if not all(fit.is_identified(eid) for eid in (sid, *pair)):
            continue
        gradients = _gradients(source, mapping, ranges, places, sid)
        variances = np.einsum("ij,jk,ik->i", gradients, covariance, gradients)
        out.append(
            SquarenessAtPlaces(
                squareness_id=sid,
                axes=(first, second),
                volume_mm={axis: (_mm(a), _mm(b)) for axis, (a, b) in ranges.items()},
                parameter_urad=float(fit.model.squareness_urad[sid]),
                places_mm=places,
                angle_urad=_angles(source, ranges, places, sid),
                std_urad=np.sqrt(np.maximum(variances, 0.0)),
                tilted_by=_tilting(source, ranges, places, sid),
            )
        )
    return tuple(out)


def squareness_report(source: LoopSource) -> dict[str, dict[str, object]]:
    """report.json's ``squareness_over_volume``: :func:`squareness_map` per squareness id."""
    return {entry.squareness_id: entry.to_json() for entry in squareness_map(source)}


def identification_squareness(identification: Identification) -> dict[str, dict[str, object]]:
    """:func:`squareness_report` of ``identification`` over the volume its lines measured, as a
    project keeps it with the identification."""
    return squareness_report(LoopSource(identification, measured_range(identification)))


def place_text(place_mm: Sequence[float]) -> str:
    """A place as the console, the workbench and the certificate print it: "(x, y, z) mm"."""
    return "(" + ", ".join(f"{v:g}" for v in place_mm) + ") mm"


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


def _over_places(
    ranges: dict[str, tuple[float, float]],
    places: FloatArray,
    sid: str,
    per_leg: Callable[[FloatArray, FloatArray, int], FloatArray | float],
) -> FloatArray:
    """Per place, ``per_leg(states, weights, component)`` summed over its two paths
    (:func:`_legs`). A path spans its axis' whole range, so the places along it share it: each
    path is evaluated once."""
    seen: dict[tuple[float, ...], FloatArray] = {}
    out = []
    for place in places:
        total: FloatArray | float = 0.0
        for states, weights, component in _legs(ranges, place, sid):
            key = (component, *states[0], *states[-1])
            if key not in seen:
                seen[key] = np.asarray(per_leg(states, weights, component), dtype=float)
            total = total + seen[key]
        out.append(total)
    return np.asarray(out, dtype=float)


def path_angle(source: LoopSource, squareness_id: str, place_mm: FloatArray) -> float:
    """The angle (µrad) between the tool point's least-squares paths along the two axes of
    ``squareness_id`` through ``place_mm``, each over its axis' measured range, in the sign of
    that squareness (:data:`PATHS`)."""
    place = np.asarray(place_mm, float)[None, :]
    return float(_angles(source, _ranges(source), place, squareness_id)[0])


def _ranges(source: LoopSource) -> dict[str, tuple[float, float]]:
    return {axis: source.measured_range_mm.get(axis, source.machine.stroke(axis)) for axis in AXES}


def _angles(
    source: LoopSource, ranges: dict[str, tuple[float, float]], places: FloatArray, sid: str
) -> FloatArray:
    def slope(states: FloatArray, weights: FloatArray, component: int) -> float:
        return float(weights @ source.error_um(states)[:, component])

    return PATHS[sid][2] * _over_places(ranges, places, sid, slope)


def _gradients(
    source: LoopSource,
    mapping: FloatArray,
    ranges: dict[str, tuple[float, float]],
    places: FloatArray,
    sid: str,
) -> FloatArray:
    """The angle's gradient at each of ``places`` over the fit's unknowns; ``mapping`` takes
    them to the refined model's parameters (:func:`parameter_map`)."""
    fit = source.identification
    assert fit is not None
    columns = [b.columns for b in fit.system.blocks if b.kind == "effect"]
    tool = source.machine.tool_offset_mm
    sign = PATHS[sid][2]

    def path_gradient(states: FloatArray, weights: FloatArray, component: int) -> FloatArray:
        design = jacobian(source.model, states, tool)[:, component, :]
        gradient = mapping.T @ (weights @ design)
        for effect, values, at in zip(fit.effects, fit.effect_parameters, columns, strict=True):
            if not isinstance(effect, Effect):
                continue
            units = np.eye(len(values))
            per_value = np.stack(
                [effect.error_um(u, source.machine, states)[:, component] for u in units], axis=1
            )
            gradient[at] += weights @ per_value
        return np.asarray(sign * gradient)

    return _over_places(ranges, places, sid, path_gradient)


def _tilting(
    source: LoopSource, ranges: dict[str, tuple[float, float]], places: FloatArray, sid: str
) -> tuple[str, ...]:
    """The kept machine effects whose error tilts either path somewhere on the grid by more
    than 1e-3 µrad."""
    labels = []
    for effect, values in source.effects:
        tilt = partial(_effect_tilt, source, effect, values)
        if np.any(_over_places(ranges, places, sid, tilt) > 1e-3):
            labels.append(effect.label)
    return tuple(labels)


def _effect_tilt(
    source: LoopSource,
    effect: Effect,
    values: FloatArray,
    states: FloatArray,
    weights: FloatArray,
    component: int,
) -> float:
    """How much ``effect`` tilts one path (µrad, absolute)."""
    return abs(float(weights @ effect.error_um(values, source.machine, states)[:, component]))
