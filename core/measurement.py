"""Measured lines: where a line was measured (LineSpec, from plan.toml) and what it read (LineData).

A line with start P0, unit travel direction u and targets s_k reads at NC positions
P_k = P0 + s_k·u. Units: positions mm; deviations µm (linear, straightness) or µrad (angular);
time s; temperatures °C; pressure kPa; humidity %RH. Deviations are stored as
``measured − nominal`` after the plan's ``sign`` has been applied (DESIGN.md, plan.toml).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .io.units import ANGLE_UNITS, DEVIATION_FACTOR
from .machine import AXES, AXIS_INDEX, Machine
from .userror import UserError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

QUANTITIES = ("linear", "straightness", "angular")


class PlanError(UserError, ValueError):
    """A plan value that cannot be right; the message names the line entry and the field."""


@dataclass(frozen=True)
class LineSpec:
    """Where and how one line was measured (one ``[[line]]`` entry of plan.toml).

    ``reflector_mm`` is the optics position relative to the spindle gauge point; it replaces the
    machine's tool offset for this line. ``sensitive`` is the deviation direction of a
    straightness line or the rotation axis of an angular line.

    ``deviation_unit`` is the unit of a file that does not state its own; it counts only when
    ``deviation_unit_stated`` (a plan that omits it leaves the unit to the file, and a file
    without one is then refused at import: volucal assumes no unit).
    """

    name: str
    quantity: str
    start_mm: tuple[float, float, float]
    direction: tuple[float, float, float]
    reflector_mm: tuple[float, float, float]
    sensitive: tuple[float, float, float] | None = None
    file: str | None = None
    deviation_unit: str = "um"
    sign: int = 1
    env_corrected: bool = True
    #: How to read the file (format, column map, units, capture binning; docs/formats.md).
    reader: Mapping[str, object] = field(default_factory=dict, hash=False)
    #: whether the plan gave ``deviation_unit``; it guides reading the file only, so two specs
    #: of the same line compare equal with or without it (a project stores the unit read)
    deviation_unit_stated: bool = field(default=True, compare=False)

    def __post_init__(self) -> None:
        where = f"line {self.name!r}"
        if self.quantity not in QUANTITIES:
            raise PlanError(
                f"{where}: quantity {self.quantity!r} is not one of {', '.join(QUANTITIES)}"
            )
        object.__setattr__(self, "start_mm", _vec(self.start_mm, f"{where}: start"))
        object.__setattr__(self, "reflector_mm", _vec(self.reflector_mm, f"{where}: reflector"))
        object.__setattr__(self, "direction", _unit(self.direction, f"{where}: direction"))
        if self.quantity == "linear":
            if self.sensitive is not None:
                object.__setattr__(self, "sensitive", _unit(self.sensitive, f"{where}: sensitive"))
        else:
            if self.sensitive is None:
                what = "deviation direction" if self.quantity == "straightness" else "rotation axis"
                raise PlanError(
                    f"{where}: sensitive is required for a {self.quantity} line ({what})"
                )
            sensitive = _unit(self.sensitive, f"{where}: sensitive")
            if self.quantity == "straightness" and abs(np.dot(sensitive, self.direction)) > 1e-6:
                raise PlanError(
                    f"{where}: sensitive {sensitive} must be perpendicular to direction "
                    f"{self.direction} for a straightness line"
                )
            object.__setattr__(self, "sensitive", sensitive)
        expected = "urad" if self.quantity == "angular" else "um"
        if self.deviation_unit not in DEVIATION_FACTOR:
            raise PlanError(
                f"{where}: deviation_unit {self.deviation_unit!r} is not supported; "
                f"use one of {', '.join(DEVIATION_FACTOR)}"
            )
        if (self.deviation_unit in ANGLE_UNITS) != (expected == "urad"):
            raise PlanError(
                f"{where}: deviation_unit {self.deviation_unit!r} does not fit a "
                f"{self.quantity} line"
            )
        if self.sign not in (1, -1):
            raise PlanError(f"{where}: sign must be +1 or -1, got {self.sign!r}")

    @property
    def unit(self) -> str:
        """Unit of the stored deviations: "um" or "urad"."""
        return "urad" if self.quantity == "angular" else "um"

    def positions(self, targets_mm: FloatArray) -> FloatArray:
        """NC positions (n, 3) mm of the targets."""
        return np.asarray(self.start_mm) + np.outer(targets_mm, self.direction)


def _vec(values: Sequence[float], where: str) -> tuple[float, float, float]:
    if isinstance(values, str) or not isinstance(values, Sequence) or len(values) != 3:
        raise PlanError(f"{where}: expected three numbers [x, y, z], got {values!r}")
    out = []
    for v in values:
        try:
            number = float(v)
        except (TypeError, ValueError):
            raise PlanError(f"{where}: {v!r} is not a number") from None
        if not math.isfinite(number):
            raise PlanError(f"{where}: {v!r} is not a finite number")
        out.append(number)
    return (out[0], out[1], out[2])


def _unit(values: Sequence[float], where: str) -> tuple[float, float, float]:
    v = np.asarray(_vec(values, where))
    scale = float(np.max(np.abs(v)))
    if scale < 1e-9:
        raise PlanError(f"{where}: a zero-length vector has no direction")
    # scaled first: [1e308, 1e308, 0] has a direction although its norm overflows
    v = v / scale
    v = v / float(np.linalg.norm(v))
    return (float(v[0]), float(v[1]), float(v[2]))


@dataclass(frozen=True)
class Environment:
    """Environment logged with a file: values at the start and end of the measurement."""

    air_temp_c: tuple[float, float] | None = None
    air_pressure_kpa: tuple[float, float] | None = None
    air_humidity_pct: tuple[float, float] | None = None
    material_temp_c: tuple[tuple[float, float], ...] = ()
    expansion_ppm_per_c: float | None = None


@dataclass(frozen=True, eq=False)
class LineData:
    """What one line read: runs × targets.

    targets_mm : (K,) target distances from the line's start along its direction, ascending.
    deviations : (R, K) in the line's unit (µm or µrad), ``measured − nominal``, NaN where a run
        did not reach a target.
    run_direction : (R,) +1 for a run that travelled towards increasing targets, −1 backwards.
    times_s : (R, K) time of each reading in seconds since ``start_time`` (POSIX seconds).
    air_temp_c, material_temp_c : optional (R, K) per-reading temperatures.
    origin_mm : the file's position of relative target 0 (its first target), so that
        ``origin_mm + targets_mm`` are the file's own target positions; None where the file gives
        no positions (a capture binned in time) or the line was not read from a file.
    """

    targets_mm: FloatArray
    deviations: FloatArray
    run_direction: IntArray
    times_s: FloatArray
    start_time: float = 0.0
    environment: Environment = field(default_factory=Environment)
    air_temp_c: FloatArray | None = None
    material_temp_c: FloatArray | None = None
    metadata: Mapping[str, str] = field(default_factory=dict)
    origin_mm: float | None = None

    def __post_init__(self) -> None:
        targets = np.asarray(self.targets_mm, dtype=float).reshape(-1)
        deviations = np.atleast_2d(np.asarray(self.deviations, dtype=float))
        directions = np.asarray(self.run_direction, dtype=np.int64).reshape(-1)
        times = np.atleast_2d(np.asarray(self.times_s, dtype=float))
        if deviations.shape[1] != targets.size:
            raise ValueError(f"{deviations.shape[1]} deviation columns for {targets.size} targets")
        if directions.size != deviations.shape[0] or times.shape != deviations.shape:
            raise ValueError("run_direction, times_s and deviations disagree in shape")
        object.__setattr__(self, "targets_mm", targets)
        object.__setattr__(self, "deviations", deviations)
        object.__setattr__(self, "run_direction", directions)
        object.__setattr__(self, "times_s", times)
        if self.origin_mm is not None:
            object.__setattr__(self, "origin_mm", float(self.origin_mm))

    @property
    def runs(self) -> int:
        return int(self.deviations.shape[0])


#: A line travels along a machine axis when its direction is this close to it.
AXIS_PARALLEL = 0.999


def travel_axis(direction: Sequence[float]) -> str | None:
    """The machine axis a line of this (unit) direction travels along, or None (a diagonal)."""
    along = np.abs(np.asarray(direction, dtype=float))
    k = int(np.argmax(along))
    return AXES[k] if along[k] > AXIS_PARALLEL else None


@dataclass(frozen=True)
class TargetPositions:
    """Where a line's targets are, as a table or a graph of the line shows them: ``values_mm``
    (one per target, in the order of ``targets_mm``) and ``of``: "X", "Y" or "Z" (the machine
    axis position, from the plan's start of a line along that axis), "file" (the positions the
    file gives) or "line" (the distance from the line's start)."""

    values_mm: FloatArray
    of: str

    @property
    def label(self) -> str:
        """The heading of a column or an axis of these positions ("X mm", "position mm", …)."""
        return position_label(self.of)

    @property
    def axis_title(self) -> str:
        """The title of a plot's axis of these positions ("X (mm)", "position (mm)", …)."""
        return self.label.removesuffix(" mm") + " (mm)"


def position_label(of: str) -> str:
    """The heading of target positions of kind ``of`` (:class:`TargetPositions`)."""
    return {"file": "position mm", "line": "target mm"}.get(of, f"{of} mm")


def target_positions(
    targets_mm: FloatArray, spec: LineSpec | None = None, origin_mm: float | None = None
) -> TargetPositions:
    """The positions of a line's targets (``targets_mm``, relative to its first) as a
    metrology engineer reads them: on the machine axis for a plan's line along one axis
    (``spec``, :func:`travel_axis`: that axis' coordinate of the target, the plan's start plus
    the distance along the direction; the positions ISO 230-2 tabulates), where the file put
    them for a file read without a plan (``origin_mm``, :attr:`LineData.origin_mm`), and
    otherwise the distance from the line's start."""
    targets = np.asarray(targets_mm, dtype=float)
    if spec is not None:
        axis = travel_axis(spec.direction)
        if axis is not None:
            return TargetPositions(spec.positions(targets)[:, AXIS_INDEX[axis]], axis)
        return TargetPositions(targets.copy(), "line")
    if origin_mm is not None:
        return TargetPositions(origin_mm + targets, "file")
    return TargetPositions(targets.copy(), "line")


@dataclass(frozen=True, eq=False)
class Line:
    """A measured line: its specification and its data."""

    spec: LineSpec
    data: LineData

    @property
    def name(self) -> str:
        return self.spec.name

    def positions(self) -> FloatArray:
        return self.spec.positions(self.data.targets_mm)


@dataclass(frozen=True, eq=False)
class Plan:
    """A machine and the lines measured on it (plan.toml, parsed)."""

    machine: Machine
    lines: tuple[LineSpec, ...]
    path: Path | None = None
    uncertainty: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        seen: set[str] = set()
        for spec in self.lines:
            if spec.name in seen:
                raise PlanError(f"line {spec.name!r}: the name is used twice; names must be unique")
            seen.add(spec.name)


@dataclass(frozen=True, eq=False)
class Measurement:
    """A plan with the data of every line, ordered by time (the session)."""

    machine: Machine
    lines: tuple[Line, ...]
    uncertainty: Mapping[str, float] = field(default_factory=dict)

    @property
    def session_start(self) -> float:
        """POSIX time of the session's first reading (the time origin of a thermal drift)."""
        return min(
            line.data.start_time + float(np.nanmin(line.data.times_s)) for line in self.lines
        )

    def held_axes(self) -> dict[str, tuple[float, ...]]:
        """The axes no line moves (no line's direction has a component along them), each with
        the positions (mm, increasing) its lines hold it at. An axis held at one position is
        one whose readings all lie there (``compensation.source.unmoved_axes`` of the
        identified machine)."""
        held = {}
        for axis, k in AXIS_INDEX.items():
            if all(line.spec.direction[k] == 0.0 for line in self.lines):
                at = {round(line.spec.start_mm[k], 6) + 0.0 for line in self.lines}
                held[axis] = tuple(sorted(at))
        return held

    def line(self, name: str) -> Line:
        for line in self.lines:
            if line.name == name:
                return line
        raise KeyError(name)
