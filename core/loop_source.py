"""The extended model the loop produced, as an error source of the machine (no Qt, no I/O)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .effects import Effect, refined_model
from .identify import Identification
from .kinematics import VolumetricModel
from .machine import Machine

FloatArray = NDArray[np.float64]


class LoopSource:
    """The extended model the loop produced, as a compensation error source: the 21 errors
    (with kept higher-order refinements folded in) plus the machine effects (reversal, cyclic,
    cross-axis, local defect). Set-up effects describe the measurement and are left out; a
    thermal drift is reported, not compensated (the model is referred to the session start)."""

    def __init__(
        self,
        identification: Identification,
        measured_range_mm: Mapping[str, tuple[float, float]] | None = None,
    ) -> None:
        effects = tuple(e for e in identification.effects if isinstance(e, Effect))
        self.model = refined_model(identification.model, effects, identification.effect_parameters)
        self.machine: Machine = self.model.machine
        self.effects = tuple(zip(effects, identification.effect_parameters, strict=True))
        self._volumetric = VolumetricModel(self.model)
        self.measured_range_mm = dict(measured_range_mm or {})

    def error_um(
        self,
        positions_mm: ArrayLike,
        approach: ArrayLike | None = None,
        tool_offset_mm: ArrayLike | None = None,
    ) -> FloatArray:
        q = np.atleast_2d(np.asarray(positions_mm, dtype=float))
        e = self._volumetric.error(q, tool_offset_mm)
        a = None if approach is None else np.atleast_2d(np.asarray(approach, dtype=float))
        for effect, values in self.effects:
            e = e + effect.error_um(values, self.machine, q, a)
        return e
