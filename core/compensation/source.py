"""Where compensation values come from: an error source.

Compensation is computed from a generic *error source*, so that it works for the 21-error model
and for the extended model the closed loop produces (reversal, cyclic error, sag, ...). A source
answers one question: the volumetric error E (µm) at NC positions, for a given direction of
approach of each axis and a given tool offset.

Semantics used throughout ``volucal.core.compensation``: the actual tool position is
``commanded + E(commanded)``; a compensation changes the commanded position so that
``commanded + E(commanded) = nominal``.

``approach[:, j]`` is the sign of the last motion of axis j: +1 when the axis arrived from below
(moving in its positive direction), −1 from above. ``approach=None`` asks for the direction-free
(mean) error; a source without reversal ignores ``approach``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ErrorModel
from ..kinematics import VolumetricModel
from ..machine import AXES, AXIS_INDEX, Machine

FloatArray = NDArray[np.float64]

#: A reversal value: a constant (µm) or a function of the axis position (mm) returning µm.
ReversalValue = float | Callable[[FloatArray], ArrayLike]


@runtime_checkable
class ErrorSource(Protocol):
    """Anything that gives the volumetric error of a machine.

    Attributes
    ----------
    machine : Machine
        The machine (strokes, reference, default tool offset).

    Optional attributes a source may carry (looked up with ``getattr``):
    ``model`` (the rigid-body :class:`ErrorModel`, needed by exporters that load the 21 error
    functions themselves, e.g. Beckhoff/ISG volumetric compensation) and ``measured_range_mm``
    (``{axis: (low, high)}``, where the source is backed by measurements; the machine strokes
    otherwise).
    """

    machine: Machine

    def error_um(
        self,
        positions_mm: ArrayLike,
        approach: ArrayLike | None = None,
        tool_offset_mm: ArrayLike | None = None,
    ) -> FloatArray:
        """Volumetric error E (µm), shape (n, 3), at NC positions (n, 3) mm."""
        ...


class ModelSource:
    """The 21-error rigid-body model as an error source (no reversal).

    Parameters
    ----------
    model : ErrorModel
        Identified or simulated error model; evaluated with the exact chain of
        :class:`volucal.core.kinematics.VolumetricModel` (paper eqs. 4–5).
    """

    def __init__(self, model: ErrorModel) -> None:
        self.model = model
        self.machine = model.machine
        self._volumetric = VolumetricModel(model)

    def error_um(
        self,
        positions_mm: ArrayLike,
        approach: ArrayLike | None = None,
        tool_offset_mm: ArrayLike | None = None,
    ) -> FloatArray:
        q = _positions(positions_mm)
        return self._volumetric.error(q, tool_offset_mm)

    def __repr__(self) -> str:
        return f"ModelSource({self.machine.name!r})"


class ReversalSource:
    """A base source plus a reversal (backlash) along each listed axis.

    Adds ``approach_j · b_j(q_j) / 2`` to the component of E along axis j, so that the error
    approached from below minus the error approached from above is ``b_j`` — the sign of the
    ISO 230-2 reversal value B_i = x̄↑ − x̄↓ (REFERENCE.md §4, "±b/2 by approach direction").
    With ``approach=None`` the reversal term is left out (the mean of both directions).

    Parameters
    ----------
    base : ErrorSource
        The error without reversal.
    reversal_um : mapping axis -> float or callable
        ``b_j`` in µm, a constant or a function of the axis position in mm.
    """

    def __init__(self, base: ErrorSource, reversal_um: Mapping[str, ReversalValue]) -> None:
        unknown = sorted(set(reversal_um) - set(AXES))
        if unknown:
            raise ValueError(f"reversal for unknown axis {', '.join(unknown)}; use X, Y, Z")
        self.base = base
        self.machine = base.machine
        self.reversal_um = dict(reversal_um)

    @property
    def model(self) -> ErrorModel | None:
        return getattr(self.base, "model", None)

    @property
    def measured_range_mm(self) -> Mapping[str, tuple[float, float]]:
        return measured_range(self.base)

    def reversal_at(self, axis: str, position_mm: ArrayLike) -> FloatArray:
        """b_j (µm) at positions along axis j; zero for an axis without reversal."""
        q = np.asarray(position_mm, dtype=float)
        value = self.reversal_um.get(axis, 0.0)
        if callable(value):
            return np.broadcast_to(np.asarray(value(q), dtype=float), q.shape).astype(float)
        return np.full(q.shape, float(value))

    def error_um(
        self,
        positions_mm: ArrayLike,
        approach: ArrayLike | None = None,
        tool_offset_mm: ArrayLike | None = None,
    ) -> FloatArray:
        q = _positions(positions_mm)
        e = np.array(self.base.error_um(q, approach, tool_offset_mm), dtype=float)
        if approach is None:
            return e
        signs = approach_array(approach, len(q))
        for axis in self.reversal_um:
            k = AXIS_INDEX[axis]
            e[:, k] += signs[:, k] * self.reversal_at(axis, q[:, k]) / 2.0
        return e

    def __repr__(self) -> str:
        return f"ReversalSource({self.base!r}, axes={sorted(self.reversal_um)})"


def as_source(source: ErrorSource | ErrorModel) -> ErrorSource:
    """Wrap an :class:`ErrorModel` in a :class:`ModelSource`; pass sources through."""
    if isinstance(source, ErrorModel):
        return ModelSource(source)
    if not isinstance(source, ErrorSource):
        raise TypeError(
            f"expected an ErrorModel or an object with .machine and .error_um(), got {source!r}"
        )
    return source


def measured_range(source: ErrorSource) -> dict[str, tuple[float, float]]:
    """Where the source is backed by measurement: its ``measured_range_mm`` or the strokes."""
    declared = getattr(source, "measured_range_mm", None)
    if declared:
        return {a: (float(declared[a][0]), float(declared[a][1])) for a in AXES}
    return {a: source.machine.stroke(a) for a in AXES}


def unmoved_axes(source: ErrorSource) -> dict[str, float]:
    """The axes no measured line moved: every reading of the measurement at one position of
    the axis (a plan that measures X alone holds Y and Z still). Per axis, that position (mm)."""
    return {axis: low for axis, (low, high) in measured_range(source).items() if not high > low}


def table_extents(
    source: ErrorSource, range_mm: Mapping[str, tuple[float, float]] | None = None
) -> dict[str, tuple[float, float]]:
    """Per axis, the extent a compensation table or a verification grid spans: ``range_mm``
    where given, else the measured range; an axis no line moved (:func:`unmoved_axes`) spans its
    stroke (a range of one position would leave the axis without a table, which no controller
    loads), along which the identified machine (:class:`~volucal.core.loop_source.LoopSource`)
    holds what was measured at that position."""
    extents = dict(measured_range(source))
    for axis in unmoved_axes(source):
        extents[axis] = source.machine.stroke(axis)
    if range_mm:
        extents.update({a: (float(v[0]), float(v[1])) for a, v in range_mm.items()})
    return extents


def rigid_model(source: ErrorSource) -> ErrorModel | None:
    """The rigid-body ErrorModel behind a source, when it exposes one."""
    model = getattr(source, "model", None)
    return model if isinstance(model, ErrorModel) else None


def approach_array(approach: ArrayLike, count: int) -> FloatArray:
    """Approach signs as an (n, 3) array of ±1; a (3,) vector applies to every point."""
    a = np.asarray(approach, dtype=float)
    a = np.broadcast_to(a, (count, 3)) if a.ndim == 1 else a
    if a.shape != (count, 3):
        raise ValueError(f"approach must have shape (3,) or ({count}, 3), got {a.shape}")
    if not np.all(np.abs(a) == 1.0):
        raise ValueError("approach values must be +1 (from below) or -1 (from above)")
    return a


def _positions(positions_mm: ArrayLike) -> FloatArray:
    q = np.atleast_2d(np.asarray(positions_mm, dtype=float))
    if q.ndim != 2 or q.shape[1] != 3:
        raise ValueError(f"positions must have shape (n, 3), got {q.shape}")
    return q
