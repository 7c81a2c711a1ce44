"""Error models and sources shared by the compensation and export tests.

A "paper-like" machine: the XYTZ mill of the paper (400 × 400 × 350 mm, tool offset 200 mm) with
smooth errors of the magnitudes REFERENCE.md §4 gives for a precision 400 mm mill (positioning
about 10 µm over the stroke, straightness a few µm, angles a few µrad, squareness 10–20 µrad).
"""

from __future__ import annotations

import numpy as np
from volucal.core.errors import (
    AXIS_ERROR_IDS,
    ERROR_INFO,
    BSplineBasis,
    ErrorFunction,
    ErrorModel,
    PolynomialBasis,
)
from volucal.core.machine import PAPER_MACHINE, Machine

AMPLITUDE = {"positioning": 8.0, "straightness": 4.0}  # µm; angles: 6 µrad


def paper_like_model(seed: int = 0, machine: Machine = PAPER_MACHINE) -> ErrorModel:
    """Smooth random errors (B-splines every 50 mm), gauged, with squareness."""
    rng = np.random.default_rng(seed)
    functions = {}
    for eid in AXIS_ERROR_IDS:
        info = ERROR_INFO[eid]
        low, high = machine.stroke(info.axis)
        basis = BSplineBasis.uniform(low, high, 50.0)
        walk = np.cumsum(rng.normal(size=basis.size))
        walk -= walk.mean()
        amplitude = AMPLITUDE.get(info.kind, 6.0)
        coefficients = amplitude * walk / max(1e-9, np.ptp(walk))
        if info.kind == "positioning":
            coefficients = coefficients + np.linspace(0.0, amplitude, basis.size)
        functions[eid] = ErrorFunction(eid, basis, coefficients)
    square = {"EC0Y": 20.0, "EB0Z": 15.0, "EA0Z": -10.0}
    return ErrorModel(machine, functions, square).gauged()


def linear_model(
    slopes_um_per_mm: dict[str, float],
    machine: Machine = PAPER_MACHINE,
    squareness_urad: dict[str, float] | None = None,
) -> ErrorModel:
    """Errors linear in their axis position (value = slope × (q − stroke start)), others zero:
    hand-checkable volumetric errors."""
    functions = {}
    for eid in AXIS_ERROR_IDS:
        axis = ERROR_INFO[eid].axis
        low, high = machine.stroke(axis)
        basis = PolynomialBasis(low, high, 1)
        slope = slopes_um_per_mm.get(eid, 0.0)
        # Legendre P0, P1 on [low, high]: value(q) = c0 + c1 s, s = (2q - low - high)/(high - low)
        half = (high - low) / 2.0
        functions[eid] = ErrorFunction(eid, basis, np.array([slope * half, slope * half]))
    return ErrorModel(machine, functions, squareness_urad or {})
