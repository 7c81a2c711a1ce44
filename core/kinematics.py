"""Volumetric error from homogeneous transforms (paper eqs. 1–6).

For the chain order (A1, A2, A3) of a machine (``("X", "Y", "Z")`` for ``"WXYFZT"``) the tool point
in the workpiece frame is

    p = T(q1)·E1(q1)·T(q2)·E2(q2)·T(q3)·E3(q3)·t

with T(q) a translation by q along the axis' direction (Y and Z directions carry the squareness
errors) and E_k = [R_k, d_k] the error transform of axis k. The volumetric error is
E = p − (q + t) (paper eq. 5), in µm.

Rotations are exact: R = Rz(EC)·Ry(EB)·Rx(EA), which reduces to the paper's small-angle matrix
[[1, −εz, εy], [εz, 1, −εx], [−εy, εx, 1]] (eq. 3) at first order. The squareness errors rotate the
nominal axis directions: u_Y = Rz(EC0Y)·e_y and u_Z = Ry(EB0Z)·Rx(EA0Z)·e_z, so that at first
order the Y translation gains −y·EC0Y in X and the Z translation +z·EB0Z in X and −z·EA0Z in Y
(eq. 3 with Sxy = EC0Y, Syz = EA0Z, Sxz = −EB0Z).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import (
    AXIS_ERROR_IDS,
    SQUARENESS_IDS,
    BSplineBasis,
    ErrorModel,
    NodeTableBasis,
    PolynomialBasis,
    axis_error_ids,
)
from .machine import AXES, AXIS_INDEX, Machine

FloatArray = NDArray[np.float64]

UM_PER_MM = 1e3
RAD_PER_URAD = 1e-6
CHUNK = 1 << 15  # points per chunk: keeps the working set of one chunk in cache


# --------------------------------------------------------------------------------------------
# Rotations
# --------------------------------------------------------------------------------------------


def rotation_matrices(a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    """R = Rz(c)·Ry(b)·Rx(a) for arrays of angles in rad; shape (..., 3, 3)."""
    ca, sa = np.cos(a), np.sin(a)
    cb, sb = np.cos(b), np.sin(b)
    cc, sc = np.cos(c), np.sin(c)
    r = np.empty(np.shape(a) + (3, 3))
    r[..., 0, 0] = cc * cb
    r[..., 0, 1] = cc * sb * sa - sc * ca
    r[..., 0, 2] = cc * sb * ca + sc * sa
    r[..., 1, 0] = sc * cb
    r[..., 1, 1] = sc * sb * sa + cc * ca
    r[..., 1, 2] = sc * sb * ca - cc * sa
    r[..., 2, 0] = -sb
    r[..., 2, 1] = cb * sa
    r[..., 2, 2] = cb * ca
    return r


def _rotation_derivatives(a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    """dR/da, dR/db, dR/dc of R = Rz(c)·Ry(b)·Rx(a); shape (3, ..., 3, 3)."""
    ca, sa = np.cos(a), np.sin(a)
    cb, sb = np.cos(b), np.sin(b)
    cc, sc = np.cos(c), np.sin(c)
    zero = np.zeros_like(a)
    one = np.ones_like(a)

    def mat(rows: list[list[FloatArray]]) -> FloatArray:
        return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)

    rx = mat([[one, zero, zero], [zero, ca, -sa], [zero, sa, ca]])
    ry = mat([[cb, zero, sb], [zero, one, zero], [-sb, zero, cb]])
    rz = mat([[cc, -sc, zero], [sc, cc, zero], [zero, zero, one]])
    drx = mat([[zero, zero, zero], [zero, -sa, -ca], [zero, ca, -sa]])
    dry = mat([[-sb, zero, cb], [zero, zero, zero], [-cb, zero, -sb]])
    drz = mat([[-sc, -cc, zero], [cc, -sc, zero], [zero, zero, zero]])
    return np.stack([rz @ ry @ drx, rz @ dry @ rx, drz @ ry @ rx])


def axis_directions(squareness_urad: dict[str, float] | ErrorModel) -> FloatArray:
    """Unit directions of the X, Y, Z axes (rows) including squareness."""
    sq = (
        squareness_urad.squareness_urad
        if isinstance(squareness_urad, ErrorModel)
        else squareness_urad
    )
    c = sq["EC0Y"] * RAD_PER_URAD
    b = sq["EB0Z"] * RAD_PER_URAD
    a = sq["EA0Z"] * RAD_PER_URAD
    return np.array(
        [
            [1.0, 0.0, 0.0],
            [-np.sin(c), np.cos(c), 0.0],
            [np.sin(b) * np.cos(a), -np.sin(a), np.cos(b) * np.cos(a)],
        ]
    )


def _direction_derivatives(model: ErrorModel) -> dict[str, tuple[int, FloatArray]]:
    """d u_axis / d squareness (per rad) for each squareness id: (axis index, vector)."""
    sq = model.squareness_urad
    c = sq["EC0Y"] * RAD_PER_URAD
    b = sq["EB0Z"] * RAD_PER_URAD
    a = sq["EA0Z"] * RAD_PER_URAD
    return {
        "EC0Y": (1, np.array([-np.cos(c), -np.sin(c), 0.0])),
        "EB0Z": (2, np.array([np.cos(b) * np.cos(a), 0.0, -np.sin(b) * np.cos(a)])),
        "EA0Z": (2, np.array([-np.sin(b) * np.sin(a), -np.cos(a), -np.cos(b) * np.sin(a)])),
    }


# --------------------------------------------------------------------------------------------
# Fast evaluation of the six errors of an axis: one piecewise polynomial table per axis
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class AxisPiecewise:
    """The six errors of one axis as piecewise polynomials on shared breakpoints.

    ``coefficients[i, k, j]`` multiplies u**k on interval i for error j, with
    u = (q − breakpoints[i]) / (breakpoints[i+1] − breakpoints[i]) in [0, 1]. The conversion is
    exact (up to rounding) for every basis volucal has: each function is a polynomial of at most
    ``degree`` on every interval of the union of all breakpoints.
    """

    breakpoints: FloatArray
    coefficients: FloatArray  # (intervals, degree + 1, 6)

    @classmethod
    def from_model(cls, model: ErrorModel, axis: str) -> AxisPiecewise:
        low, high = model.machine.stroke(axis)
        points = {low, high}
        degree = 0
        for eid in axis_error_ids(axis):
            basis = model.functions[eid].basis
            if isinstance(basis, BSplineBasis):
                points.update(basis.breakpoints_mm)
                degree = max(degree, basis.degree)
            elif isinstance(basis, NodeTableBasis):
                points.update(basis.nodes_mm)
                degree = max(degree, 1)
            elif isinstance(basis, PolynomialBasis):
                degree = max(degree, basis.degree)
        breaks = np.array(sorted(p for p in points if low <= p <= high))
        # Sample each interval at Chebyshev points of the local variable u and solve exactly.
        nodes = 0.5 - 0.5 * np.cos(np.pi * (np.arange(degree + 1) + 0.5) / (degree + 1))
        vander = np.vander(nodes, degree + 1, increasing=True)
        width = np.diff(breaks)
        q = breaks[:-1, None] + width[:, None] * nodes[None, :]
        values = np.stack([model.functions[e](q.ravel()) for e in axis_error_ids(axis)], axis=-1)
        values = values.reshape(len(width), degree + 1, 6)
        coefficients = np.linalg.solve(vander[None, :, :], values)
        return cls(breaks, np.ascontiguousarray(coefficients))

    def __call__(self, position_mm: FloatArray) -> FloatArray:
        q = np.clip(position_mm, self.breakpoints[0], self.breakpoints[-1])
        index = np.searchsorted(self.breakpoints, q, side="right") - 1
        np.clip(index, 0, len(self.breakpoints) - 2, out=index)
        start = self.breakpoints[index]
        u = (q - start) / (self.breakpoints[index + 1] - start)
        table = self.coefficients[index]  # (n, degree + 1, 6)
        value = table[:, -1, :].copy()
        for k in range(table.shape[1] - 2, -1, -1):
            value *= u[:, None]
            value += table[:, k, :]
        return value


# --------------------------------------------------------------------------------------------
# The volumetric error
# --------------------------------------------------------------------------------------------


class VolumetricModel:
    """An ErrorModel prepared for fast evaluation of E at many positions.

    Build it once per model (it converts the error functions into per-axis tables) and call
    ``error(positions, tool_offset)``.
    """

    def __init__(self, model: ErrorModel) -> None:
        self.model = model
        self.order = tuple(AXIS_INDEX[a] for a in model.machine.axis_order)
        self.tables = {a: AxisPiecewise.from_model(model, a) for a in AXES}
        self.directions = axis_directions(model)

    def error(
        self,
        positions_mm: ArrayLike,
        tool_offset_mm: ArrayLike | None = None,
        threads: int | None = None,
    ) -> FloatArray:
        """Volumetric error E (µm), shape (n, 3), at NC positions (n, 3) mm.

        ``tool_offset_mm`` is one (3,) vector or one per point (n, 3); default: the machine's.
        Work is chunked (compiled kernel, :mod:`volucal.core._chain_kernel`) and spread over
        ``threads`` (default: the CPU count).
        """
        q = np.ascontiguousarray(np.atleast_2d(np.asarray(positions_mm, dtype=float)))
        if q.shape[-1] != 3:
            raise ValueError(f"positions must have shape (n, 3), got {q.shape}")
        if tool_offset_mm is None:
            tool_offset_mm = self.model.machine.tool_offset_mm
        t = np.ascontiguousarray(np.atleast_2d(np.asarray(tool_offset_mm, dtype=float)))
        per_point = np.ndim(tool_offset_mm) == 2
        if per_point and len(t) != len(q):
            raise ValueError(f"{len(t)} tool offsets for {len(q)} positions")
        from ._chain_kernel import chain_error  # numba: compiled (or loaded from cache) on use

        out = np.empty_like(q)
        starts = range(0, len(q), CHUNK)
        tables = [self.tables[a] for a in AXES]
        order = np.array(self.order, dtype=np.int64)

        def work(start: int) -> None:
            stop = min(start + CHUNK, len(q))
            chain_error(
                q[start:stop],
                t[start:stop] if per_point else t,
                per_point,
                order,
                self.directions,
                tables[0].breakpoints,
                tables[0].coefficients,
                tables[1].breakpoints,
                tables[1].coefficients,
                tables[2].breakpoints,
                tables[2].coefficients,
                out[start:stop],
            )

        workers = threads or os.cpu_count() or 1
        if workers > 1 and len(q) > 2 * CHUNK:
            with ThreadPoolExecutor(workers) as pool:
                list(pool.map(work, starts))
        else:
            for start in starts:
                work(start)
        return out

    def grid_error(
        self,
        x_mm: ArrayLike,
        y_mm: ArrayLike,
        z_mm: ArrayLike,
        tool_offset_mm: ArrayLike | None = None,
    ) -> Iterator[tuple[int, FloatArray]]:
        """E (µm) on a regular grid, one slice at a time along the first chain axis.

        Yields ``(index, E)`` with E of shape (n2, n3, 3) over the other two chain axes (in chain
        order). Each axis' errors depend on that axis only, so they are evaluated once per grid
        line and combined by broadcasting: the cost per grid point is a few multiply-adds.
        """
        grids = [np.asarray(v, dtype=float) for v in (x_mm, y_mm, z_mm)]
        t = (
            np.asarray(
                self.model.machine.tool_offset_mm if tool_offset_mm is None else tool_offset_mm,
                float,
            )
            / 1.0
        )
        a1, a2, a3 = self.order
        per_axis = {}
        for k in (a1, a2, a3):
            errors = self.tables[AXES[k]](grids[k])
            r = rotation_matrices(*(errors[:, 3:].T * RAD_PER_URAD))
            per_axis[k] = (r, errors[:, :3] / UM_PER_MM)
        # innermost: v3 = q3 u3 + R3 t + d3      (n3, 3)
        r3, d3 = per_axis[a3]
        v3 = grids[a3][:, None] * self.directions[a3] + r3 @ t + d3
        # v2 = q2 u2 + R2 v3 + d2                 (n2, n3, 3)
        r2, d2 = per_axis[a2]
        v2 = np.einsum("aij,bj->abi", r2, v3)
        v2 += (grids[a2][:, None] * self.directions[a2] + d2)[:, None, :]
        nominal23 = np.zeros((len(grids[a2]), len(grids[a3]), 3))
        nominal23[..., a2] += grids[a2][:, None]
        nominal23[..., a3] += grids[a3][None, :]
        nominal23 += t
        r1, d1 = per_axis[a1]
        flat = v2.reshape(-1, 3)
        for i, q1 in enumerate(grids[a1]):
            p = flat @ r1[i].T
            p += q1 * self.directions[a1] + d1[i]
            e = p.reshape(v2.shape)
            e -= nominal23
            e[..., a1] -= q1
            e *= UM_PER_MM
            yield i, e


def _compose(
    order: tuple[int, ...],
    directions: FloatArray,
    q: FloatArray,
    t: FloatArray,
    values: dict[str, FloatArray],
) -> FloatArray:
    """The exact chain for given error values per point; directions (3, 3) or (n, 3, 3)."""
    p = np.broadcast_to(t, q.shape).copy()
    for axis_index in reversed(order):
        errors = values[AXES[axis_index]]
        r = rotation_matrices(
            errors[..., 3] * RAD_PER_URAD,
            errors[..., 4] * RAD_PER_URAD,
            errors[..., 5] * RAD_PER_URAD,
        )
        p = np.einsum("...ij,...j->...i", r, p)
        p += errors[..., :3] / UM_PER_MM
        p += q[:, axis_index, None] * directions[..., axis_index, :]
    p -= q
    p -= t
    p *= UM_PER_MM
    return p


def compose_error(
    machine: Machine,
    positions_mm: ArrayLike,
    axis_values: dict[str, ArrayLike],
    squareness_urad: dict[str, ArrayLike],
    tool_offset_mm: ArrayLike | None = None,
) -> FloatArray:
    """Exact volumetric error (µm) for error *values* given per point.

    ``axis_values[axis]`` has shape (n, 6) or (6,): EXJ, EYJ, EZJ (µm), EAJ, EBJ, ECJ (µrad) of
    that axis at that point; ``squareness_urad[id]`` is a scalar or an (n,) array. This is the
    model a sensitivity analysis samples when the 21 errors are random variables (paper, Table 2).
    """
    q = np.atleast_2d(np.asarray(positions_mm, dtype=float))
    n = len(q)
    t = np.asarray(machine.tool_offset_mm if tool_offset_mm is None else tool_offset_mm, float)
    values = {a: np.broadcast_to(np.asarray(axis_values[a], float), (n, 6)) for a in AXES}
    sq = {k: np.broadcast_to(np.asarray(squareness_urad[k], float), (n,)) for k in SQUARENESS_IDS}
    c = sq["EC0Y"] * RAD_PER_URAD
    b = sq["EB0Z"] * RAD_PER_URAD
    a = sq["EA0Z"] * RAD_PER_URAD
    directions = np.zeros((n, 3, 3))
    directions[:, 0, 0] = 1.0
    directions[:, 1, 0] = -np.sin(c)
    directions[:, 1, 1] = np.cos(c)
    directions[:, 2, 0] = np.sin(b) * np.cos(a)
    directions[:, 2, 1] = -np.sin(a)
    directions[:, 2, 2] = np.cos(b) * np.cos(a)
    order = tuple(AXIS_INDEX[x] for x in machine.axis_order)
    return _compose(order, directions, q, t, values)


def volumetric_error(
    model: ErrorModel, positions_mm: ArrayLike, tool_offset_mm: ArrayLike | None = None
) -> FloatArray:
    """Exact volumetric error E (µm) at positions (n, 3) mm; see :class:`VolumetricModel`."""
    return VolumetricModel(model).error(positions_mm, tool_offset_mm)


# --------------------------------------------------------------------------------------------
# First-order form (paper eq. 6 without its products of errors)
# --------------------------------------------------------------------------------------------


def first_order_error(
    model: ErrorModel, positions_mm: ArrayLike, tool_offset_mm: ArrayLike | None = None
) -> FloatArray:
    """Volumetric error linearised in the errors (µm), shape (n, 3).

    E ≈ Σ_k [d_k + θ_k × v_k] + squareness terms, where v_k is the nominal vector from axis k to
    the tool point (the sum of the positions of the axes after k in the chain plus the tool
    offset). For "WXYFZT" this is the paper's eq. 6 with the products of two errors dropped.
    """
    q = np.atleast_2d(np.asarray(positions_mm, dtype=float))
    t = np.asarray(
        model.machine.tool_offset_mm if tool_offset_mm is None else tool_offset_mm, float
    )
    lever = np.broadcast_to(t, q.shape).astype(float)
    e = np.zeros_like(q)
    order = [AXIS_INDEX[a] for a in model.machine.axis_order]
    for k in reversed(order):
        axis = AXES[k]
        values = model.axis_values(axis, q[:, k])
        theta = values[:, 3:] * RAD_PER_URAD
        e += values[:, :3] + np.cross(theta, lever) * UM_PER_MM
        lever = lever.copy()
        lever[:, k] += q[:, k]
    sq = model.squareness_urad
    e[:, 0] += (-q[:, 1] * sq["EC0Y"] + q[:, 2] * sq["EB0Z"]) * RAD_PER_URAD * UM_PER_MM
    e[:, 1] += -q[:, 2] * sq["EA0Z"] * RAD_PER_URAD * UM_PER_MM
    return e


# --------------------------------------------------------------------------------------------
# Jacobian with respect to the basis coefficients
# --------------------------------------------------------------------------------------------


def error_value_jacobian(
    model: ErrorModel, positions_mm: ArrayLike, tool_offset_mm: ArrayLike | None = None
) -> tuple[dict[str, FloatArray], dict[str, FloatArray]]:
    """Exact derivatives of E (µm) with respect to the error *values* at each point.

    Returns ``(per_axis, squareness)``: ``per_axis[axis]`` has shape (n, 3, 6) — dE/d(EXJ, EYJ,
    EZJ in µm, EAJ, EBJ, ECJ in µrad) at that axis' position; ``squareness[id]`` has shape (n, 3),
    dE/d(id in µrad).
    """
    q = np.atleast_2d(np.asarray(positions_mm, dtype=float))
    n = len(q)
    t = np.asarray(
        model.machine.tool_offset_mm if tool_offset_mm is None else tool_offset_mm, float
    )
    directions = axis_directions(model)
    order = [AXIS_INDEX[a] for a in model.machine.axis_order]
    rotations, translations, angles = {}, {}, {}
    for k in order:
        values = model.axis_values(AXES[k], q[:, k])
        angles[k] = values[:, 3:] * RAD_PER_URAD
        rotations[k] = rotation_matrices(*angles[k].T)
        translations[k] = values[:, :3] / UM_PER_MM
    # vectors from each axis to the tool: v_after[k] = q_next u_next + R_next v_after[next] + d_next
    after: dict[int, FloatArray] = {}
    v = np.broadcast_to(t, q.shape).astype(float)
    for k in reversed(order):
        after[k] = v
        v = (
            q[:, k, None] * directions[k]
            + np.einsum("nij,nj->ni", rotations[k], v)
            + translations[k]
        )
    # prefix rotations M_k = R_1 ... R_{k-1}
    prefix: dict[int, FloatArray] = {}
    m = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for k in order:
        prefix[k] = m
        m = m @ rotations[k]
    per_axis: dict[str, FloatArray] = {}
    for k in order:
        jac = np.empty((n, 3, 6))
        jac[:, :, :3] = prefix[k]  # µm per µm
        dr = _rotation_derivatives(*angles[k].T)  # (3, n, 3, 3)
        for j in range(3):
            jac[:, :, 3 + j] = np.einsum("nij,njk,nk->ni", prefix[k], dr[j], after[k]) * (
                UM_PER_MM * RAD_PER_URAD
            )
        per_axis[AXES[k]] = jac
    squareness: dict[str, FloatArray] = {}
    for sid, (axis_index, du) in _direction_derivatives(model).items():
        squareness[sid] = (
            np.einsum("nij,j->ni", prefix[axis_index], du)
            * q[:, axis_index, None]
            * (UM_PER_MM * RAD_PER_URAD)
        )
    return per_axis, squareness


def jacobian(
    model: ErrorModel, positions_mm: ArrayLike, tool_offset_mm: ArrayLike | None = None
) -> FloatArray:
    """dE/d(parameters) of the exact chain, shape (n, 3, P), in the order of ``model.parameters``.

    E is in µm; the parameters are the basis coefficients (µm or µrad per unit of basis function)
    and the squareness values (µrad).
    """
    q = np.atleast_2d(np.asarray(positions_mm, dtype=float))
    per_axis, squareness = error_value_jacobian(model, q, tool_offset_mm)
    out = np.zeros((len(q), 3, model.parameter_count))
    slices = model.parameter_slices
    for axis in AXES:
        k = AXIS_INDEX[axis]
        for j, eid in enumerate(axis_error_ids(axis)):
            design = model.functions[eid].basis.design(q[:, k])
            out[:, :, slices[eid]] = per_axis[axis][:, :, j, None] * design[:, None, :]
    for sid in SQUARENESS_IDS:
        out[:, :, slices[sid].start] = squareness[sid]
    return out


def naive_error(
    model: ErrorModel, positions_mm: ArrayLike, tool_offset_mm: ArrayLike | None = None
) -> FloatArray:
    """Reference implementation: one 4×4 homogeneous product per point (slow; for checks)."""
    q = np.atleast_2d(np.asarray(positions_mm, dtype=float))
    t = np.asarray(
        model.machine.tool_offset_mm if tool_offset_mm is None else tool_offset_mm, float
    )
    directions = axis_directions(model)
    out = np.empty_like(q)
    for n, point in enumerate(q):
        total = np.eye(4)
        for axis in model.machine.axis_order:
            k = AXIS_INDEX[axis]
            move = np.eye(4)
            move[:3, 3] = point[k] * directions[k]
            e = model.axis_values(axis, point[k : k + 1])[0]
            err = np.eye(4)
            err[:3, :3] = rotation_matrices(*(e[3:] * RAD_PER_URAD))
            err[:3, 3] = e[:3] / UM_PER_MM
            total = total @ move @ err
        tool = total @ np.append(t, 1.0)
        out[n] = (tool[:3] - point - t) * UM_PER_MM
    return out


# --------------------------------------------------------------------------------------------
# Angular error of the tool relative to the workpiece (what angular optics read)
# --------------------------------------------------------------------------------------------


def rotation_error(model: ErrorModel, positions_mm: ArrayLike) -> FloatArray:
    """Rotation vector (µrad), shape (n, 3), of the tool frame relative to the workpiece frame.

    Exact: the rotation R_1·R_2·R_3 of the chain converted to its rotation vector. Squareness
    rotates axis directions, not the carried bodies, so it does not enter. At first order this is
    the sum of the three axes' (EA, EB, EC).
    """
    q = np.atleast_2d(np.asarray(positions_mm, dtype=float))
    total = np.broadcast_to(np.eye(3), (len(q), 3, 3)).copy()
    for axis in model.machine.axis_order:
        values = model.axis_values(axis, q[:, AXIS_INDEX[axis]])
        total = total @ rotation_matrices(*(values[:, 3:].T * RAD_PER_URAD))
    return rotation_vector(total) / RAD_PER_URAD


def rotation_vector(matrices: FloatArray) -> FloatArray:
    """Rotation vectors (rad) of rotation matrices (..., 3, 3), accurate for small angles."""
    skew = 0.5 * np.stack(
        [
            matrices[..., 2, 1] - matrices[..., 1, 2],
            matrices[..., 0, 2] - matrices[..., 2, 0],
            matrices[..., 1, 0] - matrices[..., 0, 1],
        ],
        axis=-1,
    )
    sin_angle = np.linalg.norm(skew, axis=-1, keepdims=True)
    cos_angle = 0.5 * (np.trace(matrices, axis1=-2, axis2=-1)[..., None] - 1.0)
    angle = np.arctan2(sin_angle, cos_angle)
    scale = np.where(sin_angle > 1e-300, angle / np.maximum(sin_angle, 1e-300), 1.0)
    return np.asarray(skew * scale)


__all__ = [
    "AXIS_ERROR_IDS",
    "AxisPiecewise",
    "VolumetricModel",
    "error_value_jacobian",
    "first_order_error",
    "jacobian",
    "naive_error",
    "rotation_error",
    "rotation_matrices",
    "volumetric_error",
]
