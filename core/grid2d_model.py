"""The result of a grid identification: the planar errors, the cross-axis surface, the gauges.

:class:`GridIdentification` evaluates the identified map anywhere (the rigid-body terms exactly,
the surface bilinearly between its nodes, end values held outside) and reports it in volucal's
conventions (ISO 230-1 ids, µm, µrad, mm). :mod:`volucal.core.grid2d_fit` computes it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import ErrorFunction
from .grid2d import GRID_AXES, UM_PER_MM_URAD, GridGauge, Lattice, rms

FloatArray = NDArray[np.float64]
ARCSEC_PER_URAD = 0.206264806


@dataclass(frozen=True, eq=False)
class GridIdentification:
    """The planar errors identified from one or more grids (module notes).

    ``functions`` maps ISO ids (EXX, EXY, EYX, EYY and ECY or ECX) to error functions (µm or
    µrad over mm); ``squareness_urad`` is EC0Y at the reference; ``surface_um`` holds the
    cross-axis surface at the lattice nodes, indexed [direction, row (Y), column (X)].
    """

    lattice: Lattice
    reference_mm: tuple[float, float]
    upper_axis: str | None
    functions: dict[str, ErrorFunction]
    function_std: dict[str, FloatArray]  # standard uncertainty at the lattice nodes of its axis
    squareness_urad: float | None
    squareness_std_urad: float | None
    gauges: dict[str, GridGauge]
    surface_um: FloatArray | None  # (2, ny, nx)
    measured_nodes: NDArray[np.bool_]  # (ny, nx): nodes with a reading
    choices: dict[str, dict[str, float]]
    statistics: dict[str, Any]
    residual_um: dict[str, FloatArray] = field(repr=False)  # per grid, (n, 2), NaN unmeasured
    directions: tuple[str, ...] = GRID_AXES

    # ---- evaluation -----------------------------------------------------------------------

    def rigid_error(self, position_mm: FloatArray) -> FloatArray:
        """(n, 2) X and Y errors (µm) of the rigid-body terms (no gauge, no surface)."""
        q = np.atleast_2d(np.asarray(position_mm, dtype=float))
        x, y = q[:, 0], q[:, 1]
        out = np.zeros((q.shape[0], 2))
        for eid, function in self.functions.items():
            if eid == "ECY":
                out[:, 1] += UM_PER_MM_URAD * x * function(y)
            elif eid == "ECX":
                out[:, 0] -= UM_PER_MM_URAD * y * function(x)
            else:
                k = 0 if eid[1] == "X" else 1
                out[:, k] += function(x if eid[2] == "X" else y)
        if self.squareness_urad is not None:
            out[:, 0] -= UM_PER_MM_URAD * y * self.squareness_urad
        return out

    def surface_error(self, position_mm: FloatArray) -> FloatArray:
        """(n, 2) cross-axis surface (µm), bilinear between the nodes, ends held outside."""
        q = np.atleast_2d(np.asarray(position_mm, dtype=float))
        if self.surface_um is None:
            return np.zeros((q.shape[0], 2))
        return np.stack([_bilinear(self.lattice, self.surface_um[k], q) for k in range(2)], axis=1)

    def error(self, position_mm: FloatArray, *, surface: bool = True) -> FloatArray:
        """(n, 2) machine error in X and Y (µm) at the positions: measured − commanded less the
        gauge terms of a set-up."""
        out = self.rigid_error(position_mm)
        return out + self.surface_error(position_mm) if surface else out

    def beyond_measured(self, position_mm: FloatArray) -> NDArray[np.bool_]:
        """True where a position lies outside the lattice or next to no measured node."""
        q = np.atleast_2d(np.asarray(position_mm, dtype=float))
        lat = self.lattice
        outside = (
            (q[:, 0] < lat.x_mm[0] - 1e-9)
            | (q[:, 0] > lat.x_mm[-1] + 1e-9)
            | (q[:, 1] < lat.y_mm[0] - 1e-9)
            | (q[:, 1] > lat.y_mm[-1] + 1e-9)
        )
        ix, iy = lat.index(np.clip(q, [lat.x_mm[0], lat.y_mm[0]], [lat.x_mm[-1], lat.y_mm[-1]]))
        return outside | ~self.measured_nodes[iy, ix]

    def sampled(self, eid: str) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(positions mm, values, standard uncertainties) of a function at its lattice nodes."""
        function = self.functions[eid]
        nodes = self.lattice.x_mm if eid[2] == "X" else self.lattice.y_mm
        return nodes, np.asarray(function(nodes)), self.function_std[eid]

    @property
    def squareness_mean_urad(self) -> float | None:
        """The squareness from least-squares slopes of the identified map averaged over the
        lattice (rigid-body terms and surface): −(d mean_x Ex / dy + d mean_y Ey / dx).

        This is how Aerotech's tools compute orthogonality (theirs is the sum of the two slopes,
        so it has the opposite sign); it differs from EC0Y, which is taken at the reference,
        by the mean of the yaw's lever-arm term over the grid.
        """
        if self.squareness_urad is None:
            return None
        xx, yy = np.meshgrid(self.lattice.x_mm, self.lattice.y_mm)
        grid = self.error(np.stack([xx.ravel(), yy.ravel()], axis=1))
        ex = grid[:, 0].reshape(xx.shape)
        ey = grid[:, 1].reshape(xx.shape)
        slope_x = np.polyfit(self.lattice.y_mm, ex.mean(axis=1), 1)[0]
        slope_y = np.polyfit(self.lattice.x_mm, ey.mean(axis=0), 1)[0]
        return float(-(slope_x + slope_y) / UM_PER_MM_URAD)

    # ---- report ---------------------------------------------------------------------------

    def to_json(self) -> dict[str, Any]:
        """The result in volucal's report conventions (ISO ids, µm, µrad, mm)."""
        parameters: dict[str, Any] = {}
        for eid, function in self.functions.items():
            q, value, std = self.sampled(eid)
            parameters[eid] = {
                "basis": function.basis.describe(),
                "coefficients": [float(c) for c in function.coefficients],
                "position_mm": [float(v) for v in q],
                "value": [float(v) for v in value],
                "std": [float(v) for v in std],
                "unit": "urad" if eid[1] == "C" else "um",
                "range": float(np.ptp(value)),
            }
        if self.squareness_urad is not None:
            parameters["EC0Y"] = {
                "basis": None,
                "coefficients": [],
                "position_mm": [],
                "value": [self.squareness_urad],
                "std": [self.squareness_std_urad],
                "unit": "urad",
            }
        surface: dict[str, Any] | None = None
        if self.surface_um is not None:
            surface = {
                "x_mm": self.lattice.x_mm.tolist(),
                "y_mm": self.lattice.y_mm.tolist(),
                "x_um": self.surface_um[0].tolist(),
                "y_um": self.surface_um[1].tolist(),
                "rms_um": {
                    a: rms(self.surface_um[k][self.measured_nodes]) for k, a in enumerate(GRID_AXES)
                },
            }
        return {
            "reference_mm": list(self.reference_mm),
            "upper_axis": self.upper_axis,
            "parameters": parameters,
            "squareness": {
                "EC0Y_urad": self.squareness_urad,
                "EC0Y_std_urad": self.squareness_std_urad,
                "EC0Y_arcsec": None
                if self.squareness_urad is None
                else self.squareness_urad * ARCSEC_PER_URAD,
                "EC0Y_mean_slope_urad": self.squareness_mean_urad,
                "definition": "EC0Y: squareness of Y to X at the reference (X gains "
                "-EC0Y*y); EC0Y_mean_slope: from the map's least-squares slopes "
                "averaged over the grid, -(dEx/dy + dEy/dx), the negative of "
                "the orthogonality Aerotech's tools print",
            },
            "gauges": {name: g.to_json() for name, g in self.gauges.items()},
            "surface": surface,
            "choices": self.choices,
            "statistics": self.statistics,
        }


def _bilinear(lattice: Lattice, values: FloatArray, q: FloatArray) -> FloatArray:
    x = np.clip(q[:, 0], lattice.x_mm[0], lattice.x_mm[-1])
    y = np.clip(q[:, 1], lattice.y_mm[0], lattice.y_mm[-1])
    fx = (x - lattice.x_mm[0]) / lattice.step_mm[0]
    fy = (y - lattice.y_mm[0]) / lattice.step_mm[1]
    i = np.clip(np.floor(fx).astype(int), 0, lattice.x_mm.size - 2)
    j = np.clip(np.floor(fy).astype(int), 0, lattice.y_mm.size - 2)
    tx, ty = fx - i, fy - j
    return np.asarray(
        values[j, i] * (1 - tx) * (1 - ty)
        + values[j, i + 1] * tx * (1 - ty)
        + values[j + 1, i] * (1 - tx) * ty
        + values[j + 1, i + 1] * tx * ty
    )
