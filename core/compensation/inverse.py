"""The inverse of the error model: which command lands the tool on the nominal position.

The actual tool position is ``c + E(c)`` for a commanded position c (µm errors, mm positions).
The compensated command solves ``c + E(c) = n`` for the nominal position n; it is found by the
fixed-point iteration ``c_{k+1} = n − E(c_k)``, starting at ``c_0 = n``. The iteration contracts
with the slope of E (about 1e-4 for a machine tool: a few µm of error change over tens of mm), so
two or three steps reach nanometres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..userror import UserError
from .source import ErrorSource, approach_array

FloatArray = NDArray[np.float64]
UM_PER_MM = 1e3


@dataclass(frozen=True, eq=False)
class InverseResult:
    """Compensated commands for a set of nominal positions.

    commanded_mm : (n, 3) commands such that ``commanded + E(commanded) = nominal``.
    correction_um : (n, 3) ``commanded − nominal`` in µm.
    iterations : steps taken.
    residual_um : largest ``|commanded + E(commanded) − nominal|`` over all points, µm.
    """

    commanded_mm: FloatArray
    correction_um: FloatArray
    iterations: int
    residual_um: float


def invert(
    source: ErrorSource,
    nominal_mm: ArrayLike,
    approach: ArrayLike | None = None,
    tool_offset_mm: ArrayLike | None = None,
    tolerance_um: float = 1e-6,
    max_iterations: int = 50,
) -> InverseResult:
    """Solve ``c + E(c) = n`` by fixed-point iteration ``c ← n − E(c)``.

    Parameters
    ----------
    source : ErrorSource
        Gives E (µm).
    nominal_mm : (n, 3)
        Nominal (wanted) tool positions, mm.
    approach : (3,) or (n, 3) of ±1, optional
        Direction of the last motion of each axis; passed to the source unchanged (a
        compensation of a few µm does not change the direction of motion).
    tool_offset_mm : (3,) or (n, 3), optional
        Tool point the compensation is for; the machine's by default.
    tolerance_um, max_iterations
        Stop when the update is below ``tolerance_um`` everywhere.

    Raises
    ------
    UserError
        When the iteration does not converge (an error model whose slope approaches 1 is not a
        machine tool; the message says where).
    """
    n = np.atleast_2d(np.asarray(nominal_mm, dtype=float))
    signs = None if approach is None else approach_array(approach, len(n))
    c = n.copy()
    delta = np.zeros_like(n)
    iterations = 0
    while iterations < max_iterations:
        iterations += 1
        updated = n - source.error_um(c, signs, tool_offset_mm) / UM_PER_MM
        broken = ~np.all(np.isfinite(updated), axis=1)
        if np.any(broken):
            where = n[int(np.argmax(broken))].round(3).tolist()
            raise UserError(
                f"the error model gives a value that is not a number at nominal {where} mm; no "
                "controller can load it — check the identification"
            )
        delta = np.abs(updated - c) * UM_PER_MM
        c = updated
        if float(np.max(delta, initial=0.0)) <= tolerance_um:
            break
    else:
        worst = int(np.argmax(np.max(delta, axis=1)))
        raise UserError(
            f"the compensation did not converge after {max_iterations} iterations (last update "
            f"{float(np.max(delta)):.3g} µm, worst at nominal {n[worst].round(3).tolist()} mm): "
            "the error model's slope is too large to be a machine tool's; check its units"
        )
    residual = c + source.error_um(c, signs, tool_offset_mm) / UM_PER_MM - n
    return InverseResult(
        commanded_mm=c,
        correction_um=(c - n) * UM_PER_MM,
        iterations=iterations,
        residual_um=float(np.max(np.abs(residual), initial=0.0)) * UM_PER_MM,
    )
