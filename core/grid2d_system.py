"""The linear system of a grid's rigid-body model: its terms, readings and normal equations.

Every error function is a node table on its lattice nodes (one value per lattice line), so the
system holds the least-squares node values: what each line's readings say, tied to one another
only by the gauges (module notes of :mod:`volucal.core.grid2d_fit`). A tiny first-difference
penalty fills lattice lines that have no reading. :mod:`volucal.core.grid2d_departures` then
splits each function into a smooth part and its nodes' departures.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sparse
from numpy.typing import NDArray
from scipy.linalg import LinAlgError, cho_factor, cho_solve

from .errors import NodeTableBasis, gauge_null_space
from .grid2d import UM_PER_MM_URAD, GridMeasurement, Lattice
from .userror import UserError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Weight of the first-difference penalty of the node tables: it only decides lattice lines
#: without a reading (filled linearly from their neighbours) and is negligible elsewhere.
NODE_TABLE_PENALTY = 1e-6


@dataclass(frozen=True)
class Term:
    """One error function: which coordinate it is a function of, which readings it enters and
    the lever arm that multiplies it there."""

    id: str
    argument: int  # 0: function of x, 1: function of y
    direction: int  # 0: enters the X readings, 1: the Y readings
    lever: str  # "", "x" (1e-3·x) or "-y" (−1e-3·y)
    straightness: bool


TERMS = (
    Term("EXX", 0, 0, "", False),
    Term("EXY", 1, 0, "", True),
    Term("EYX", 0, 1, "", True),
    Term("EYY", 1, 1, "", False),
)
YAW = {"Y": Term("ECY", 1, 1, "x", False), "X": Term("ECX", 0, 0, "-y", False)}


@dataclass
class Readings:
    """Every reading of every grid, stacked: X readings and Y readings in one vector."""

    position: FloatArray  # (m, 2)
    value: FloatArray  # (m,)
    direction: IntArray  # (m,)
    grid: IntArray  # (m,)
    ix: IntArray
    iy: IntArray

    def lever(self, term: Term) -> FloatArray:
        """The factor of ``term`` in every reading: 0 in the other direction's readings."""
        factor = np.where(self.direction == term.direction, 1.0, 0.0)
        if term.lever == "x":
            factor = factor * UM_PER_MM_URAD * self.position[:, 0]
        elif term.lever == "-y":
            factor = factor * -UM_PER_MM_URAD * self.position[:, 1]
        return factor

    def node(self, term: Term) -> IntArray:
        """The lattice index of every reading along ``term``'s argument."""
        return self.ix if term.argument == 0 else self.iy


def stack_readings(grids: Sequence[GridMeasurement], lattice: Lattice) -> Readings:
    parts = []
    for g, grid in enumerate(grids):
        ix, iy = lattice.index(grid.position_mm)
        for k in range(2):
            ok = np.isfinite(grid.deviation_um[:, k])
            parts.append(
                (
                    grid.position_mm[ok],
                    grid.deviation_um[ok, k],
                    np.full(ok.sum(), k),
                    np.full(ok.sum(), g),
                    ix[ok],
                    iy[ok],
                )
            )
    stacked = [np.concatenate([p[i] for p in parts]) for i in range(6)]
    return Readings(
        stacked[0],
        stacked[1],
        stacked[2].astype(np.int64),
        stacked[3].astype(np.int64),
        stacked[4].astype(np.int64),
        stacked[5].astype(np.int64),
    )


def build_system(
    readings: Readings,
    lattice: Lattice,
    terms: Sequence[Term],
    reference: tuple[float, float],
    grid_count: int,
    directions: set[int],
    square: bool,
) -> RigidSystem:
    """The node-table system of the rigid-body model (module notes) with its gauges."""
    r = readings
    m = r.value.size
    nodes = (lattice.x_mm, lattice.y_mm)
    blocks: list[sparse.csr_matrix] = []
    transforms: list[FloatArray] = []
    penalties: list[FloatArray] = []
    bases: dict[str, NodeTableBasis] = {}
    for term in terms:
        basis = NodeTableBasis(tuple(nodes[term.argument]))
        bases[term.id] = basis
        rows = np.flatnonzero(r.direction == term.direction)
        design = basis.design(r.position[rows, term.argument]) * r.lever(term)[rows, None]
        block = np.zeros((m, basis.size))
        block[rows] = design
        blocks.append(sparse.csr_matrix(block))
        null = gauge_null_space(basis, reference[term.argument], term.straightness)
        transforms.append(null)
        difference = np.diff(np.eye(basis.size), axis=0)
        penalties.append(NODE_TABLE_PENALTY * null.T @ difference.T @ difference @ null)
    extra = []
    names = []
    x, y = r.position[:, 0], r.position[:, 1]
    if square:
        extra.append(np.where(r.direction == 0, -UM_PER_MM_URAD * y, 0.0))
        names.append("EC0Y")
    for g in range(grid_count):
        mine = r.grid == g
        if 0 in directions:
            extra.append(np.where(mine & (r.direction == 0), 1.0, 0.0))
            names.append(f"offset_x:{g}")
        if 1 in directions:
            extra.append(np.where(mine & (r.direction == 1), 1.0, 0.0))
            names.append(f"offset_y:{g}")
        extra.append(np.where(mine, np.where(r.direction == 0, -y, x) * UM_PER_MM_URAD, 0.0))
        names.append(f"rotation:{g}")
    blocks.append(sparse.csr_matrix(np.stack(extra, axis=1)))
    transforms.append(np.eye(len(extra)))
    penalties.append(np.zeros((len(extra), len(extra))))
    return RigidSystem(
        sparse.hstack(blocks).tocsr(), transforms, penalties, bases, names, list(terms)
    )


@dataclass
class RigidSystem:
    """Design, gauge null spaces and penalties of the rigid-body model (node tables)."""

    design: sparse.csr_matrix  # readings × original coefficients
    transforms: list[FloatArray]  # gauge null spaces per block (identity for the scalars)
    penalties: list[FloatArray]  # per block, in reduced coordinates
    bases: dict[str, NodeTableBasis]
    scalar_names: list[str]
    terms: list[Term]
    _fold_cache: dict[int, tuple[IntArray, list[FloatArray]]] = field(default_factory=dict)

    @cached_property
    def transform(self) -> FloatArray:
        size_in = sum(t.shape[0] for t in self.transforms)
        size_out = sum(t.shape[1] for t in self.transforms)
        out = np.zeros((size_in, size_out))
        i = j = 0
        for t in self.transforms:
            out[i : i + t.shape[0], j : j + t.shape[1]] = t
            i += t.shape[0]
            j += t.shape[1]
        return out

    @cached_property
    def penalty(self) -> FloatArray:
        size = sum(p.shape[0] for p in self.penalties)
        out = np.zeros((size, size))
        i = 0
        for p in self.penalties:
            out[i : i + p.shape[0], i : i + p.shape[0]] = p
            i += p.shape[0]
        return out

    @cached_property
    def reduced_design(self) -> sparse.csr_matrix:
        """The design in the gauge-reduced coordinates."""
        return (self.design @ sparse.csr_matrix(self.transform)).tocsr()

    def gram(self, values: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Reduced normal matrix and right-hand side of all readings."""
        t = self.transform
        return (t.T @ (self.design.T @ self.design).toarray() @ t, t.T @ (self.design.T @ values))

    def solve(self, values: FloatArray) -> FloatArray:
        """Reduced coefficients fitted to all readings."""
        normal, rhs = self.gram(values)
        return solve(normal + self.penalty, rhs)

    def fold_solutions(self, folds: IntArray, count: int, values: FloatArray) -> list[FloatArray]:
        """Reduced coefficients fitted without each fold's readings (cached per folds)."""
        key = id(folds)
        cached = self._fold_cache.get(key)
        if cached is None or cached[0] is not folds:
            t = self.transform
            total = (self.design.T @ self.design).toarray()
            total_rhs = self.design.T @ values
            solutions = []
            for f in range(count):
                rows = self.design[folds == f]
                inner = (rows.T @ rows).toarray()
                solutions.append(
                    solve(
                        t.T @ (total - inner) @ t + self.penalty,
                        t.T @ (total_rhs - rows.T @ values[folds == f]),
                    )
                )
            cached = (folds, solutions)
            self._fold_cache[key] = cached
        return cached[1]

    def block_slices(self) -> list[slice]:
        out, start = [], 0
        for t in self.transforms:
            out.append(slice(start, start + t.shape[1]))
            start += t.shape[1]
        return out

    def node_values(self, reduced: FloatArray, index: int) -> FloatArray:
        """The node values of term ``index`` (its node table) from reduced coefficients."""
        return np.asarray(self.transforms[index] @ reduced[self.block_slices()[index]])


def solve(normal: FloatArray, rhs: FloatArray) -> FloatArray:
    """Solve a symmetric positive (semi-)definite system, scaled, by Cholesky."""
    scale = np.sqrt(np.maximum(np.diag(normal), 1e-300))
    scaled = normal / scale[:, None] / scale[None, :]
    try:
        factor = cho_factor(scaled + 1e-12 * np.eye(scaled.shape[0]))
    except LinAlgError:
        raise UserError(
            "the grid cannot separate the planar errors (a singular system): it needs at least "
            "two nodes along each axis in each measured direction"
        ) from None
    return np.asarray(cho_solve(factor, rhs / scale) / scale)
