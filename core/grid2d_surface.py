"""The cross-axis surface of a grid: node values on the lattice, bilinear between the nodes.

The surface holds what the rigid-body planar terms leave of a map. It is fitted by penalised
least squares: each reading pulls its node's value, and a first-difference penalty of weight
``w`` ties every node to its four neighbours (so nodes no reading reaches are interpolated by
their neighbours, harmonically). Readings sit on nodes, so the normal matrix is the reading
count per node plus ``w`` times the lattice's graph Laplacian: banded with the shorter side as
bandwidth, and solved by banded Cholesky.
"""

from __future__ import annotations

from collections.abc import Hashable

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cho_solve_banded, cholesky_banded

from .grid2d import Lattice

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: A tiny ridge keeps the system definite when the penalty weight is tiny.
_RIDGE = 1e-9


class SurfaceSolver:
    """Fits node values of one lattice from readings at nodes (module notes)."""

    def __init__(self, lattice: Lattice) -> None:
        self.shape = lattice.shape  # (ny, nx)
        ny, nx = self.shape
        # Number the nodes along the longer side first so that the band is the shorter side.
        self._transpose = nx > ny
        self._width, self._length = (ny, nx) if self._transpose else (nx, ny)
        self.size = nx * ny
        width, length = self._width, self._length
        along = np.arange(self.size) % width
        across = np.arange(self.size) // width
        banded = np.zeros((width + 1, self.size))  # upper banded form (solveh_banded)
        banded[width] = (
            (along > 0).astype(float) + (along < width - 1) + (across > 0) + (across < length - 1)
        )
        banded[width - 1, 1:] = np.where(along[1:] > 0, -1.0, 0.0)
        banded[0, width:] = -1.0
        self._laplacian = banded
        self._factors: dict[Hashable, FloatArray] = {}

    def node(self, ix: IntArray, iy: IntArray) -> IntArray:
        """Index of each reading's node in the solver's numbering."""
        if self._transpose:
            return np.asarray(ix * self._width + iy, dtype=np.int64)
        return np.asarray(iy * self._width + ix, dtype=np.int64)

    def fit(
        self, node: IntArray, values: FloatArray, weight: float, key: Hashable | None = None
    ) -> FloatArray:
        """Node values (solver numbering) of the surface through ``values`` read at ``node``.

        The matrix depends only on which nodes are read and the weight: with a ``key`` naming
        that pair, its factor is kept and reused (cross-validation refits the same folds many
        times with other rigid-body terms).
        """
        factor = self._factors.get(key) if key is not None else None
        if factor is None:
            counts = np.bincount(node, minlength=self.size).astype(float)
            banded = weight * self._laplacian
            banded[self._width] += counts + _RIDGE
            factor = cholesky_banded(banded, check_finite=False)
            if key is not None:
                self._factors[key] = factor
        sums = np.bincount(node, weights=values, minlength=self.size)
        return np.asarray(cho_solve_banded((factor, False), sums, check_finite=False))

    def as_grid(self, values: FloatArray) -> FloatArray:
        """Node values as a (ny, nx) table indexed [row (Y), column (X)]."""
        table = values.reshape(self._length, self._width)
        return table.T if self._transpose else table
