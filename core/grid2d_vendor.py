"""Aerotech's published 2-D calibration method, for comparison with volucal's.

Written from the method's description (Aerotech's ``A3200Acc2D`` MATLAB program, published with
the 2-D stitching tools); no code is taken from it. Axis 1 is the scan axis (the table's
columns), Axis 2 the step axis (its rows). From the errors ``e = measured − commanded``:

1. the mean of each axis' errors is removed;
2. a straight line is fitted to the Axis-1 errors averaged along each row (a function of the
   Axis-2 position) and removed from the Axis-1 errors; the same line with its slope and offset
   negated is removed from the Axis-2 errors along Axis 1 ("the mirror slope is always of
   opposite sign between the axes"): one rotation of the mirror, so the whole squareness stays
   in the Axis-2 errors;
3. the errors at the first node are subtracted from every node (origin zeroed);
4. the correction is the negated error, rounded to 0.1 nm.

For the grid 643494 this reproduces the vendor's .cal to the last digit (``tests``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .grid2d import GRID_AXES, GridMeasurement, Lattice, common_lattice, missing_nodes
from .userror import UserError

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class VendorTable:
    """The vendor method's correction at the grid's nodes (µm), indexed [direction, row (Y),
    column (X)]; ``orthogonality_urad`` is the method's orthogonality (sum of the two slopes)."""

    lattice: Lattice
    correction_um: FloatArray
    orthogonality_urad: float
    scan_axis: str


def scan_axis_of(grid: GridMeasurement) -> str:
    """The grid's Axis 1 (scan axis) as the Accuracy2D reader recorded it, else X."""
    text = grid.metadata.get("axes", "")
    return "Y" if text.startswith("Axis 1 = Y") else "X"


def vendor_correction(grid: GridMeasurement, scan_axis: str | None = None) -> VendorTable:
    """The vendor method's 2-D correction table (module notes) of one complete grid.

    Raises
    ------
    UserError
        When a node has no reading in both directions (the method needs the full table).
    """
    scan = scan_axis or scan_axis_of(grid)
    if scan not in GRID_AXES:
        raise UserError(f"scan axis must be X or Y, got {scan!r}")
    lattice = common_lattice([grid])
    if missing_nodes(grid, lattice) or grid.measured_directions != GRID_AXES:
        raise UserError(
            f"{grid.source_file or grid.name}: the vendor method needs a reading "
            "in X and Y at every node"
        )
    ix, iy = lattice.index(grid.position_mm)
    ny, nx = lattice.shape
    error = np.zeros((2, ny, nx))
    count = np.zeros((ny, nx))
    np.add.at(count, (iy, ix), 1.0)
    for k in range(2):
        np.add.at(error[k], (iy, ix), grid.deviation_um[:, k])
        error[k] /= count
    # Work in the file's axes: axis 1 = scan (columns of its table), axis 2 = step (rows).
    a1, a2 = (0, 1) if scan == "X" else (1, 0)
    e1 = error[a1] - error[a1].mean()
    e2 = error[a2] - error[a2].mean()
    if scan == "Y":  # transpose so that rows follow axis 2 and columns axis 1
        e1, e2 = e1.T, e2.T
        pos1, pos2 = lattice.y_mm, lattice.x_mm
    else:
        pos1, pos2 = lattice.x_mm, lattice.y_mm
    slope1, offset1 = np.polyfit(pos2, e1.mean(axis=1), 1)
    slope2, _ = np.polyfit(pos1, e2.mean(axis=0), 1)
    e1 = e1 - (slope1 * pos2 + offset1)[:, None]
    e2 = e2 + (slope1 * pos1 + offset1)[None, :]
    e1 = e1 - e1[0, 0]
    e2 = e2 - e2[0, 0]
    if scan == "Y":
        e1, e2 = e1.T, e2.T
    out = np.zeros((2, ny, nx))
    out[a1] = -np.round(e1 * 1e4) / 1e4
    out[a2] = -np.round(e2 * 1e4) / 1e4
    return VendorTable(lattice, out + 0.0, float((slope1 + slope2) * 1e3), scan)
