"""An error function of a grid as a smooth part plus the departures of its measured nodes.

A grid measures each planar error function (EXY(y), the straightness of Y in X, say) only on
its lattice lines: the value at a measured node is the least-squares value of its line (all the
readings of that line hold it), but what the function does *between* two measured lines is not
measured. A lookup table interpolates the node values linearly, as if a node's departure from
the function's trend continued halfway to the next node. On a real machine it may not: the
straightness of Y in X of the linear-motor stage of grid 643494 is 0.38 µm RMS off a smooth
trend at a 5 mm pitch, more than half of it at periods under 20 mm: a table at 10 mm cannot
follow it, and linear interpolation carries each row's offset half-way to the next row, where
it is no better a guess than the trend.

So a function is written as

    f(q) = s(q) + Σ_n d_n · h_n(q; w)

- ``s``: the smooth part, a penalised spline with knots at the lattice nodes fitted to the
  node values: a node table penalised by its slope or a cubic B-spline penalised by its
  curvature (the cubic smoothing spline, Reinsch 1967), :func:`roughness_penalty`;
- ``d_n = value_n − s(q_n)``: the departure of measured node n;
- ``h_n``: a kernel that is 1 at node n, ``w/2`` halfway to its neighbours and 0 at them,
  piecewise linear in between. ``w``, the *carry*, is the share of the neighbours' mean
  departure kept halfway between two measured nodes: ``w = 1`` is the linear interpolation of
  the node values (a lookup table), ``w = 0`` the smooth part alone.

At the measured nodes the function is its node values whatever ``s`` and ``w``; between them
it is the model's prediction. The degree and smoothing of ``s`` and the carry ``w`` are chosen
by cross-validation over held-out lattice lines (:mod:`volucal.core.grid2d_fit`). The kernel is
the linear interpolation of a table at half the node spacing, so a correction table written at
half the measured step carries the model between the measured nodes to a controller that
interpolates linearly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import Basis, BSplineBasis, NodeTableBasis

FloatArray = NDArray[np.float64]


SmoothBasis = NodeTableBasis | BSplineBasis


def smooth_basis(nodes_mm: FloatArray, degree: int) -> SmoothBasis:
    """The smooth part's basis on the lattice nodes: a node table (1) or cubic B-spline (3)."""
    return NodeTableBasis(tuple(nodes_mm)) if degree == 1 else BSplineBasis(tuple(nodes_mm))


def roughness_penalty(basis: SmoothBasis) -> FloatArray:
    """``Ω`` with ``cᵀΩc = h^(2m−1)·∫ f^(m)(q)² dq`` over the stroke (``h`` the mean node step):
    the slope (m = 1) of a node table, the curvature (m = 2) of a cubic B-spline.

    The integral makes the smooth part a smoothing spline (a penalised spline with knots at
    every node is then the smoothing spline of its node values, whichever nodes hold a value),
    and the factor ``h^(2m−1)`` makes the weight a pure number: weight 1 balances one node
    value's squared departure against the roughness over one node step.
    """
    from scipy.interpolate import BSpline  # scipy.interpolate is slow to import

    if isinstance(basis, NodeTableBasis):
        nodes = np.asarray(basis.nodes_mm)
        gaps = np.diff(nodes)
        step = float(gaps.mean())
        difference = np.diff(np.eye(nodes.size), axis=0)
        return np.asarray(difference.T @ np.diag(step / gaps) @ difference)
    breaks = np.asarray(basis.breakpoints_mm)
    step = float(np.diff(breaks).mean())
    # f'' of a cubic is linear on each interval: 2-point Gauss-Legendre quadrature is exact
    offset = 0.5 / np.sqrt(3.0)
    middle = 0.5 * (breaks[:-1] + breaks[1:])
    width = np.diff(breaks)
    points = np.concatenate([middle - offset * width, middle + offset * width])
    weights = np.concatenate([0.5 * width, 0.5 * width])
    curvature = BSpline(basis.knots, np.eye(basis.size), 3).derivative(2)(points)
    return np.asarray(step**3 * (curvature.T * weights) @ curvature)


def carry_kernel(position_mm: ArrayLike, nodes_mm: FloatArray, carry: float) -> FloatArray:
    """(n positions × nodes) kernel ``h_n(q; w)`` of the module notes.

    It is the linear interpolation of a table on the nodes and the midpoints between them,
    holding 1 at its node and ``carry/2`` at the two midpoints; outside the nodes the end
    node's value is held (as a lookup table does).
    """
    q = np.atleast_1d(np.asarray(position_mm, dtype=float))
    nodes = np.asarray(nodes_mm, dtype=float)
    out = np.zeros((q.size, nodes.size))
    if nodes.size == 1:
        out[:, 0] = 1.0
        return out
    half = np.empty(2 * nodes.size - 1)
    half[0::2] = nodes
    half[1::2] = 0.5 * (nodes[:-1] + nodes[1:])
    qc = np.clip(q, half[0], half[-1])
    index = np.clip(np.searchsorted(half, qc, side="right") - 1, 0, half.size - 2)
    frac = (qc - half[index]) / (half[index + 1] - half[index])
    rows = np.arange(q.size)
    for end, weight in ((index, 1.0 - frac), (index + 1, frac)):
        on_node = end % 2 == 0
        # a half-table node is a lattice node (its own column, value 1) or a midpoint
        # (value carry/2 in the columns of the two nodes either side)
        np.add.at(out, (rows[on_node], end[on_node] // 2), weight[on_node])
        mid = ~on_node
        left = (end[mid] - 1) // 2
        np.add.at(out, (rows[mid], left), 0.5 * carry * weight[mid])
        np.add.at(out, (rows[mid], left + 1), 0.5 * carry * weight[mid])
    return out


@dataclass(frozen=True, eq=False)
class NodeDepartureBasis(Basis):
    """The basis of ``s(q) + Σ d_n h_n(q; w)`` (module notes): the smooth part's functions,
    then one kernel per measured node. Coefficients: the smooth part's, then the departures."""

    smooth: Basis
    nodes_mm: tuple[float, ...]
    carry: float
    kind: str = "smooth+departures"

    def __post_init__(self) -> None:
        nodes = tuple(float(n) for n in self.nodes_mm)
        if not nodes or any(b <= a for a, b in zip(nodes, nodes[1:], strict=False)):
            raise ValueError(f"measured nodes must be strictly increasing: {nodes}")
        if not 0.0 <= self.carry <= 1.0:
            raise ValueError(f"the carry must lie in [0, 1], got {self.carry}")
        object.__setattr__(self, "nodes_mm", nodes)

    @property
    def low(self) -> float:  # type: ignore[override]
        return self.smooth.low

    @property
    def high(self) -> float:  # type: ignore[override]
        return self.smooth.high

    @property
    def size(self) -> int:
        return self.smooth.size + len(self.nodes_mm)

    def design(self, position_mm: ArrayLike) -> FloatArray:
        q = np.atleast_1d(self._clamp(position_mm))
        return np.hstack(
            [self.smooth.design(q), carry_kernel(q, np.asarray(self.nodes_mm), self.carry)]
        )

    def describe(self) -> dict[str, object]:
        return {
            "kind": self.kind,
            "smooth": self.smooth.describe(),
            "nodes_mm": list(self.nodes_mm),
            "carry": self.carry,
        }


def fit_smooth_part(
    basis: SmoothBasis, nodes_mm: FloatArray, values: FloatArray, weight: float
) -> FloatArray:
    """Coefficients of the smooth part through node values (module notes).

    Penalised least squares over the nodes, ``Σ (value_n − s(q_n))² + weight·|D c|²``. The
    smooth part is free of the function's gauge: the node values keep it (zero at the reference
    node, zero least-squares slope of a straightness), and the function is its node values at
    the nodes; a gauge imposed on the trend would pin it to the reference node's value.
    """
    design = basis.design(nodes_mm)
    data = design.T @ design
    # a ridge far below one node value's weight keeps a line of two nodes solvable
    ridge = 1e-12 * max(float(np.trace(data)), 1.0) / data.shape[0]
    normal = data + weight * roughness_penalty(basis) + ridge * np.eye(data.shape[0])
    return np.asarray(np.linalg.solve(normal, design.T @ values))


def best_carry(target: FloatArray, departures: FloatArray) -> float:
    """The carry in [0, 1] that minimises ``Σ (target − w·departures)²``."""
    norm = float(np.dot(departures, departures))
    if norm <= 0.0:
        return 1.0
    return float(np.clip(np.dot(target, departures) / norm, 0.0, 1.0))
