"""The extended model the loop produced, as an error source of the machine (no Qt, no I/O)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .compensation.source import unmoved_axes
from .effects import Effect, HigherOrder, refined_model
from .errors import AXIS_ERROR_IDS, SQUARENESS_IDS, ErrorModel, NodeTableBasis
from .identify import Gauge, Identification
from .kinematics import VolumetricModel
from .machine import AXES, Machine

FloatArray = NDArray[np.float64]


class LoopSource:
    """The extended model the loop produced, as a compensation error source: the 21 errors
    (with kept higher-order refinements folded in) plus the machine effects (reversal, cyclic,
    cross-axis, local defect). Set-up effects describe the measurement and are left out; a
    thermal drift is reported, not compensated (the model is referred to the session start).
    Along an axis every reading saw at one position (a plan that measures X alone), the source
    holds the errors measured there: no measurement says how they change along it."""

    def __init__(
        self,
        identification: Identification,
        measured_range_mm: Mapping[str, tuple[float, float]] | None = None,
    ) -> None:
        effects = tuple(e for e in identification.effects if isinstance(e, Effect))
        self.identification: Identification | None = identification
        self._extend(
            identification.model,
            tuple(zip(effects, identification.effect_parameters, strict=True)),
            measured_range_mm,
        )

    @classmethod
    def stored(
        cls,
        model: ErrorModel,
        effects: Sequence[tuple[Effect, FloatArray]],
        measured_range_mm: Mapping[str, tuple[float, float]] | None = None,
    ) -> LoopSource:
        """The source of an identification as a project keeps it: its 21 errors (``model``,
        before the kept refinements are folded in) and each kept effect with its fitted values;
        no covariance, no readings (``identification`` is None)."""
        source = object.__new__(cls)
        source.identification = None
        source._extend(model, tuple(effects), measured_range_mm)
        return source

    def _extend(
        self,
        model: ErrorModel,
        effects: tuple[tuple[Effect, FloatArray], ...],
        measured_range_mm: Mapping[str, tuple[float, float]] | None,
    ) -> None:
        self.model = refined_model(
            model, tuple(e for e, _ in effects), tuple(v for _, v in effects)
        )
        self.machine: Machine = self.model.machine
        self.effects = effects
        self._volumetric = VolumetricModel(self.model)
        self.measured_range_mm = dict(measured_range_mm or {})
        # an axis every reading saw at one position: what the model says away from it, no
        # measurement backs (the plan sees combinations only, split at minimum norm), so the
        # source holds the error measured there along that axis
        self._pins = {AXES.index(axis): at for axis, at in unmoved_axes(self).items()}

    def error_um(
        self,
        positions_mm: ArrayLike,
        approach: ArrayLike | None = None,
        tool_offset_mm: ArrayLike | None = None,
    ) -> FloatArray:
        q = np.atleast_2d(np.asarray(positions_mm, dtype=float))
        if self._pins:
            q = q.copy()
            for k, position in self._pins.items():
                q[:, k] = position
        e = self._volumetric.error(q, tool_offset_mm)
        a = None if approach is None else np.atleast_2d(np.asarray(approach, dtype=float))
        for effect, values in self.effects:
            e = e + effect.error_um(values, self.machine, q, a)
        return e


def measured_range(identification: Identification) -> dict[str, tuple[float, float]]:
    """Per axis, the range of positions the measured lines covered."""
    return range_of(identification.readings.position_mm)


def range_of(positions_mm: ArrayLike) -> dict[str, tuple[float, float]]:
    """Per axis, the lowest and highest of ``positions_mm`` (n × 3), to the nanometre: a plan's
    positions (start + s·direction) carry rounding of 10⁻¹⁴ mm, which would print as −0."""
    q = np.asarray(positions_mm, dtype=float).reshape(-1, 3)
    return {
        a: (round(float(q[:, k].min()), 6) + 0.0, round(float(q[:, k].max()), 6) + 0.0)
        for k, a in enumerate(AXES)
    }


def parameter_map(identification: Identification, refined: ErrorModel) -> FloatArray:
    """The linear map (rows: ``refined``'s parameters; columns: every unknown of the fit, the
    gauge's coordinates then the effects' values) from what ``identification`` fitted to
    ``refined``, its model with the higher-order refinements folded in
    (:func:`~volucal.core.effects.refined_model`). A refined function is a node table whose
    values are the coarse function plus the refinement at the nodes: both are linear in the
    fitted unknowns, so covariances propagate through it exactly, cross terms included."""
    base = identification.model
    gauge = Gauge.for_model(base)
    system = identification.system
    refinements = {
        effect.error_id: (effect, block.columns)
        for effect, block in zip(
            identification.effects,
            [b for b in system.blocks if b.kind == "effect"],
            strict=True,
        )
        if isinstance(effect, HigherOrder)
    }
    base_slices = base.parameter_slices
    rows = []
    for eid in (*AXIS_ERROR_IDS, *SQUARENESS_IDS):
        to_base = np.zeros((base_slices[eid].stop - base_slices[eid].start, system.size))
        to_base[:, : gauge.size] = gauge.matrix[base_slices[eid]]
        if eid not in refinements:
            rows.append(to_base)
            continue
        effect, columns = refinements[eid]
        table = refined.functions[eid].basis
        assert isinstance(table, NodeTableBasis)
        nodes = np.asarray(table.nodes_mm)
        rows_eid = base.functions[eid].basis.design(nodes) @ to_base
        rows_eid[:, columns] += effect.refinement_design(nodes)
        rows.append(rows_eid)
    return np.vstack(rows)
