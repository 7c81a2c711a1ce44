"""Measurement plan layouts: where each laser line is set up on the machine.

Each layout returns :class:`PlannedLine` entries (a LineSpec and its targets). The layouts are the
plan presets of ``resources/plans/`` (written by ``resources/plans/make_presets.py``) and what the
virtual machine measures in tests and in the demo. What each layout can and cannot identify is
computed by :func:`volucal.core.identify.identifiability`, never assumed (docs/plans.md).

Positions: every line starts at a machine position and travels along a unit direction; targets are
distances from the start. ``reflector`` is the optics position relative to the spindle gauge point.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .machine import AXES, AXIS_INDEX, Machine
from .measurement import LineSpec

FloatArray = NDArray[np.float64]
Vector = tuple[float, float, float]

UNIT = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}


@dataclass(frozen=True, eq=False)
class PlannedLine:
    """A line to measure: its specification and its targets (mm from the start)."""

    spec: LineSpec
    targets_mm: FloatArray


def targets(length_mm: float, step_mm: float, jitter_mm: float = 0.0, seed: int = 0) -> FloatArray:
    """Targets 0 … length every ``step_mm``; interior targets moved by up to ±``jitter_mm``.

    ISO 230-2 recommends irregular target spacing so that a periodic error (a screw cycle) is not
    hidden by sampling in step with it (REFERENCE §2, "Sampling trap").
    """
    count = max(1, round(length_mm / step_mm))
    t = np.linspace(0.0, length_mm, count + 1)
    if jitter_mm > 0 and count > 1:
        rng = np.random.default_rng(seed)
        t[1:-1] += rng.uniform(-jitter_mm, jitter_mm, count - 1)
        t = np.sort(t)
    return t


class _Builder:
    def __init__(self, machine: Machine, step_mm: float, jitter_mm: float, reflector: Vector):
        self.machine = machine
        self.step_mm = step_mm
        self.jitter_mm = jitter_mm
        self.reflector = reflector
        self.lines: list[PlannedLine] = []

    def low(self, axis: str) -> float:
        return self.machine.stroke(axis)[0]

    def high(self, axis: str) -> float:
        return self.machine.stroke(axis)[1]

    def mid(self, axis: str) -> float:
        return 0.5 * (self.low(axis) + self.high(axis))

    def start(self, **fixed: float) -> Vector:
        return tuple(fixed.get(a, self.low(a)) for a in AXES)  # type: ignore[return-value]

    def add(
        self,
        name: str,
        quantity: str,
        start: Vector,
        end: Vector,
        sensitive: Vector | None = None,
        reflector: Vector | None = None,
    ) -> None:
        s = np.asarray(start, float)
        e = np.asarray(end, float)
        length = float(np.linalg.norm(e - s))
        direction = tuple((e - s) / length)
        spec = LineSpec(
            name=name,
            quantity=quantity,
            start_mm=start,
            direction=direction,  # type: ignore[arg-type]
            reflector_mm=reflector if reflector is not None else self.reflector,
            sensitive=sensitive,
            file=f"logs/{name}.{'rta' if quantity == 'angular' else 'rtl'}",
            deviation_unit="urad" if quantity == "angular" else "um",
        )
        seed = len(self.lines) + 1
        self.lines.append(PlannedLine(spec, targets(length, self.step_mm, self.jitter_mm, seed)))

    def axis_line(
        self,
        name: str,
        axis: str,
        quantity: str = "linear",
        sensitive: str | None = None,
        reflector: Vector | None = None,
        **fixed: float,
    ) -> None:
        start = self.start(**fixed)
        end = list(start)
        end[AXIS_INDEX[axis]] = self.high(axis)
        self.add(
            name,
            quantity,
            start,
            tuple(end),  # type: ignore[arg-type]
            UNIT[sensitive] if sensitive else None,
            reflector,
        )

    def diagonal(
        self, name: str, start: Vector, end: Vector, reflector: Vector | None = None
    ) -> None:
        self.add(name, "linear", start, end, None, reflector)


def _face_diagonals(
    b: _Builder, both: bool = True, suffix: str = "", reflector: Vector | None = None
) -> None:
    lo = {a: b.low(a) for a in AXES}
    hi = {a: b.high(a) for a in AXES}
    faces = [("xy", "X", "Y", "Z"), ("xz", "X", "Z", "Y"), ("yz", "Y", "Z", "X")]
    for label, u, v, w in faces:
        fixed = b.mid(w)
        s1 = {u: lo[u], v: lo[v], w: fixed}
        e1 = {u: hi[u], v: hi[v], w: fixed}
        b.diagonal(f"diag_{label}_pp{suffix}", _vec(s1), _vec(e1), reflector)
        if both:
            s2 = {u: lo[u], v: hi[v], w: fixed}
            e2 = {u: hi[u], v: lo[v], w: fixed}
            b.diagonal(f"diag_{label}_pm{suffix}", _vec(s2), _vec(e2), reflector)


def _offset_diagonals(b: _Builder, lever_mm: float = 150.0) -> None:
    """One face diagonal per plane with the optics displaced across the plane: the roll of the
    axis normal to the plane then acts through a lever arm (it is invisible otherwise)."""
    t = np.asarray(b.machine.tool_offset_mm, float)
    for label, u, v, w in [("xy", "X", "Y", "Z"), ("xz", "X", "Z", "Y"), ("yz", "Y", "Z", "X")]:
        reflector = t.copy()
        reflector[AXIS_INDEX[w]] += lever_mm
        fixed = b.mid(w)
        s = {u: b.low(u), v: b.low(v), w: fixed}
        e = {u: b.high(u), v: b.high(v), w: fixed}
        b.diagonal(f"diag_{label}_pp_offset", _vec(s), _vec(e), tuple(reflector))  # type: ignore[arg-type]


def _body_diagonals(b: _Builder) -> None:
    lo = [b.low(a) for a in AXES]
    hi = [b.high(a) for a in AXES]
    corners = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)]
    names = ["ppp", "mpp", "pmp", "mmp"]
    for corner, name in zip(corners, names, strict=True):
        start = tuple(hi[k] if corner[k] else lo[k] for k in range(3))
        end = tuple(lo[k] if corner[k] else hi[k] for k in range(2)) + (hi[2],)
        b.diagonal(f"body_{name}", start, end)  # type: ignore[arg-type]


def _vec(values: dict[str, float]) -> Vector:
    return (values["X"], values["Y"], values["Z"])


def _parallel_nine(b: _Builder) -> None:
    """Three parallel displacement lines per axis: a base line and two with a lever arm in each
    perpendicular direction. An axis' angles act through the positions of the axes after it in
    the chain and through the optics offset, so the lever comes from moving a later axis to the
    far end of its stroke, or else from displacing the reflector by 150 mm."""
    order = b.machine.axis_order
    t = np.asarray(b.machine.tool_offset_mm, float)
    for axis in AXES:
        others = [a for a in AXES if a != axis]
        b.axis_line(f"{axis.lower()}_lin_1", axis)
        for k, other in enumerate(others, start=2):
            if order.index(other) > order.index(axis):
                b.axis_line(f"{axis.lower()}_lin_{k}", axis, **{other: b.high(other)})
            else:
                reflector = t.copy()
                reflector[AXIS_INDEX[other]] += 150.0
                b.axis_line(f"{axis.lower()}_lin_{k}", axis, reflector=tuple(reflector))


def nine_line(machine: Machine, step_mm: float = 12.0, jitter_mm: float = 0.0) -> list[PlannedLine]:
    """Nine axis-parallel displacement lines (three per axis, at different offsets)."""
    b = _Builder(machine, step_mm, jitter_mm, machine.tool_offset_mm)
    _parallel_nine(b)
    return b.lines


def twelve_line(
    machine: Machine, step_mm: float = 12.0, jitter_mm: float = 0.0
) -> list[PlannedLine]:
    """The paper's twelve-line method as reconstructed here (docs/plans.md): the nine parallel
    lines plus three face diagonals (one per coordinate plane, two-axis simultaneous moves)."""
    b = _Builder(machine, step_mm, jitter_mm, machine.tool_offset_mm)
    _parallel_nine(b)
    _face_diagonals(b, both=False)
    return b.lines


def body_diagonals(
    machine: Machine, step_mm: float = 12.0, jitter_mm: float = 0.0
) -> list[PlannedLine]:
    """The four body diagonals of ISO 230-6."""
    b = _Builder(machine, step_mm, jitter_mm, machine.tool_offset_mm)
    _body_diagonals(b)
    return b.lines


def displacement_full(
    machine: Machine, step_mm: float = 12.0, jitter_mm: float = 0.0
) -> list[PlannedLine]:
    """Displacement lines only that identify all 21 errors (25 lines): nine parallel lines, six
    face diagonals, three face diagonals repeated with the optics offset across their plane (roll),
    four body diagonals and three off-centre face diagonals (one per plane)."""
    b = _Builder(machine, step_mm, jitter_mm, machine.tool_offset_mm)
    _parallel_nine(b)
    _face_diagonals(b, both=True)
    _offset_diagonals(b)
    _body_diagonals(b)
    # Off-centre: a diagonal that does not span its face breaks the mirror symmetry that leaves
    # the antisymmetric parts of EYX and EXY undetermined by the two full face diagonals.
    quarter = {a: 0.25 * (b.high(a) - b.low(a)) for a in AXES}
    for label, u, v, w in [("xy", "X", "Y", "Z"), ("xz", "X", "Z", "Y"), ("yz", "Y", "Z", "X")]:
        s = {u: b.low(u), v: b.low(v) + quarter[v], w: b.mid(w)}
        e = {u: b.high(u) - quarter[u], v: b.high(v), w: b.mid(w)}
        b.diagonal(f"diag_{label}_offcentre", _vec(s), _vec(e))
    return b.lines


def direct(machine: Machine, step_mm: float = 12.0, jitter_mm: float = 0.0) -> list[PlannedLine]:
    """Direct optics per axis: linear, both straightnesses (two of them at two lever arms, for
    roll), the two angles a laser sees, plus the three face diagonals for squareness."""
    b = _Builder(machine, step_mm, jitter_mm, machine.tool_offset_mm)
    t = np.asarray(machine.tool_offset_mm, float)
    for axis in AXES:
        others = [a for a in AXES if a != axis]
        b.axis_line(f"{axis.lower()}_linear", axis)
        for s in others:
            b.axis_line(f"{axis.lower()}_straight_{s.lower()}", axis, "straightness", s)
        # Roll: the same straightness with the optics displaced across the travel.
        s = others[1]
        lever_axis = others[0]
        reflector = t.copy()
        reflector[AXIS_INDEX[lever_axis]] += 150.0
        b.axis_line(
            f"{axis.lower()}_straight_{s.lower()}_offset", axis, "straightness", s, tuple(reflector)
        )
        for rot in others:
            b.axis_line(f"{axis.lower()}_angle_{rot.lower()}", axis, "angular", rot)
    _face_diagonals(b, both=False)
    return b.lines


def full(machine: Machine, step_mm: float = 12.0, jitter_mm: float = 0.0) -> list[PlannedLine]:
    """A full, redundant plan: the direct optics per axis, extra parallel displacement lines
    (Abbe levers, rigid-body checks across the workspace), all face diagonals and the body
    diagonals. Every line is redundant for the 21 errors, so leave-one-line-out
    cross-validation applies."""
    lines = direct(machine, step_mm, jitter_mm)
    b = _Builder(machine, step_mm, jitter_mm, machine.tool_offset_mm)
    b.lines = list(lines)
    for axis in AXES:
        others = [a for a in AXES if a != axis]
        b.axis_line(f"{axis.lower()}_linear_far", axis, **{o: b.high(o) for o in others})
        b.axis_line(
            f"{axis.lower()}_linear_mid",
            axis,
            **{others[0]: b.mid(others[0]), others[1]: b.low(others[1])},
        )
        b.axis_line(
            f"{axis.lower()}_linear_side",
            axis,
            **{others[0]: b.low(others[0]), others[1]: b.high(others[1])},
        )
        for s in others:
            b.axis_line(
                f"{axis.lower()}_straight_{s.lower()}_far",
                axis,
                "straightness",
                s,
                **{o: b.high(o) for o in others},
            )
    _face_diagonals(b, both=True, suffix="_b")
    _offset_diagonals(b)
    _body_diagonals(b)
    return b.lines


LAYOUTS: dict[str, Callable[..., list[PlannedLine]]] = {
    "nine-line": nine_line,
    "twelve-line": twelve_line,
    "body-diagonals": body_diagonals,
    "displacement-only": displacement_full,
    "direct": direct,
    "full": full,
}


def layout(
    name: str, machine: Machine, step_mm: float = 12.0, jitter_mm: float = 0.0
) -> list[PlannedLine]:
    try:
        return LAYOUTS[name](machine, step_mm, jitter_mm)
    except KeyError:
        raise ValueError(
            f"unknown plan layout {name!r}; choose one of {', '.join(LAYOUTS)}"
        ) from None
