"""The block structure of identification's normal equations (dense plans, issues 14 and 17).

A line's readings touch few columns of the design: its own nuisance columns (zero offset,
straightness slope, set-up effects), which no other line touches, and the "global" columns it
moves (the gauge coordinates of the errors of the axes it travels along or stands on, and the
machine-level effects). Its contribution to the normal matrix, its *part*, is a small dense block
on those columns. Eliminating every line's own columns (a Schur complement per line) leaves a
system on the global columns whose size does not depend on the number of lines; what each line
keeps of its elimination is a few numbers per touched column. Everything identification needs is
built from these pieces, so its time grows linearly with the number of lines and its memory with
the number of unknowns:

- the rank and the null space of the whole normal matrix (what the plan cannot see): the null
  space of the reduced system, each vector completed on the lines' own columns, plus the own
  directions a line cannot fix by itself;
- the least-squares solution restricted to a subspace (the identifiable directions fixed at the
  first linearisation) and the matching (AᵀWA)⁺: an equality-constrained (KKT) system whose own
  blocks are eliminated line by line in the same way;
- leave-one-line-out fits by downdating the reduced system with one line's Schur part, and the
  rank test of a line (its leverage: the eigenvalues of its part against the reduced matrix).

Everything here works in column-scaled coordinates (x = scale · x_s, each column of A scaled to
unit norm, as :func:`volucal.core.identify._column_scale` does), where the rank tolerance is
defined.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lu_factor, lu_solve

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class LinePart:
    """One line's contribution to the normal equations, on the columns it touches only.

    ``columns`` are sorted column indices; ``normal`` (k × k) and ``rhs`` (k) the line's AᵀWA and
    AᵀWy on them. Column indices a line does not touch hold zero in the full matrices.
    """

    columns: IntArray
    normal: FloatArray
    rhs: FloatArray


PartSource = Callable[[int], LinePart]


def largest_eigenvalue(matrix: FloatArray) -> float:
    """The largest eigenvalue of a symmetric positive semi-definite matrix (a few Lanczos
    iterations; it only sets the rank tolerance, so 1e-8 relative accuracy is plenty)."""
    size = matrix.shape[0]
    if size == 0:
        return 0.0
    if size <= 64:
        return float(np.linalg.eigvalsh(matrix)[-1])
    from scipy.sparse.linalg import eigsh

    start = np.ones(size) / np.sqrt(size)
    value = eigsh(matrix, k=1, which="LA", return_eigenvectors=False, tol=1e-10, v0=start)
    return float(value[0])


# --------------------------------------------------------------------------------------------
# Eliminating the lines' own columns
# --------------------------------------------------------------------------------------------


@dataclass(eq=False)
class OwnBlock:
    """What a line keeps of the elimination of its own columns (scaled coordinates).

    ``columns`` : its own columns (full numbering); ``touched`` : positions (in the reduced
    system) of the global columns it touches; ``normal`` (o × o), ``coupling`` (o × t) and
    ``rhs`` (o): the own-own, own-global and own parts of its normal equations; ``inverse``
    (o × o): the (pseudo-)inverse of the own block used in the elimination; ``null`` (o × m):
    own directions the line does not determine (readings that cannot tell its own columns apart).
    """

    columns: IntArray
    touched: IntArray
    normal: FloatArray
    coupling: FloatArray
    rhs: FloatArray
    inverse: FloatArray
    null: FloatArray


def _own_inverse(normal: FloatArray, limit: float) -> tuple[FloatArray, FloatArray]:
    """(truncated pseudo-inverse, null directions) of a small own block."""
    if normal.shape[0] == 0:
        return np.zeros((0, 0)), np.zeros((0, 0))
    values, vectors = np.linalg.eigh(normal)
    keep = values > limit
    kept = vectors[:, keep]
    return (kept / values[keep]) @ kept.T, vectors[:, ~keep]


def _constrained_inverse(normal: FloatArray, null: FloatArray) -> FloatArray:
    """V (Vᵀ N V)⁻¹ Vᵀ with V spanning the complement of ``null``: the own block's inverse on
    the directions a constraint leaves free."""
    size = normal.shape[0]
    if size == 0:
        return np.zeros((0, 0))
    if null.shape[1] == 0:
        free = np.eye(size)
    else:
        q, _ = np.linalg.qr(null, mode="complete")
        free = q[:, null.shape[1] :]
    inner = free.T @ normal @ free
    return (
        np.asarray(free @ np.linalg.solve(inner, free.T))
        if free.shape[1]
        else np.zeros((size, size))
    )


@dataclass(eq=False)
class Elimination:
    """The normal equations with every line's own columns eliminated (scaled coordinates).

    ``glob`` : the global columns (full numbering, sorted); ``reduced`` (g × g) and
    ``reduced_rhs`` (g): the Schur complement ``Σ_l (N_gg − N_goN_oo⁺N_og)`` and its right-hand
    side; ``lines`` : per line, its :class:`OwnBlock`.
    """

    size: int
    scale: FloatArray
    glob: IntArray
    reduced: FloatArray
    reduced_rhs: FloatArray
    lines: list[OwnBlock]
    _eigen: tuple[FloatArray, FloatArray] | None = None
    _pinv: dict[float, FloatArray] = field(default_factory=dict)

    @classmethod
    def of(
        cls,
        parts: PartSource,
        own: Sequence[IntArray],
        size: int,
        scale: FloatArray,
        limit: float,
        own_null: Sequence[FloatArray] | None = None,
        ridge: float = 0.0,
    ) -> Elimination:
        """Eliminate each line's ``own`` columns from its part.

        The own block is inverted on the directions its eigenvalues (scaled) put above ``limit``
        (the rest are the line's undetermined own directions); with ``own_null`` given (per line,
        scaled own directions held at zero by a constraint), on the complement of those instead;
        with a ``ridge``, ridge·I is added to every (scaled) diagonal, own and global, and the own
        blocks are inverted as they are.
        """
        owner = np.full(size, -1, dtype=np.int64)
        for index, columns in enumerate(own):
            owner[columns] = index
        glob = np.flatnonzero(owner < 0)
        position = np.full(size, -1, dtype=np.int64)
        position[glob] = np.arange(glob.size)
        reduced = np.zeros((glob.size, glob.size))
        reduced_rhs = np.zeros(glob.size)
        lines = []
        for index, own_columns in enumerate(own):
            part = parts(index)
            s = scale[part.columns]
            normal = part.normal * np.outer(s, s)
            rhs = part.rhs * s
            mine = owner[part.columns]
            if np.any((mine >= 0) & (mine != index)):
                raise ValueError(f"line {index} touches another line's own columns")
            g = np.flatnonzero(mine < 0)
            # own columns in the order given; those the part does not touch stay zero
            where = np.searchsorted(part.columns, own_columns)
            present = where < part.columns.size
            present[present] = part.columns[where[present]] == own_columns[present]
            o = own_columns.size
            p = np.flatnonzero(present)
            n_oo = np.zeros((o, o))
            n_og = np.zeros((o, g.size))
            b_o = np.zeros(o)
            n_oo[np.ix_(p, p)] = normal[np.ix_(where[p], where[p])]
            n_og[p] = normal[where[p]][:, g]
            b_o[p] = rhs[where[p]]
            inverse: FloatArray
            if ridge:
                inverse = np.asarray(
                    np.linalg.inv(n_oo + ridge * np.eye(o)) if o else np.zeros((0, 0)),
                    dtype=np.float64,
                )
                null = np.zeros((o, 0))
            elif own_null is None:
                inverse, null = _own_inverse(n_oo, limit)
            else:
                null = own_null[index]
                inverse = _constrained_inverse(n_oo, null)
            y = inverse @ n_og
            touched = position[part.columns[g]]
            if g.size and g[-1] == g.size - 1:  # the global columns come first (no effects)
                n_gg = normal[: g.size, : g.size]
            else:
                n_gg = normal[np.ix_(g, g)]
            reduced[np.ix_(touched, touched)] += n_gg - n_og.T @ y
            reduced_rhs[touched] += rhs[g] - n_og.T @ (inverse @ b_o)
            lines.append(OwnBlock(own_columns, touched, n_oo, n_og, b_o, inverse, null))
        reduced[np.diag_indices_from(reduced)] += ridge
        return cls(size, scale, glob, reduced, reduced_rhs, lines)

    # ---- the reduced system's spectrum -------------------------------------------------------

    @property
    def eigen(self) -> tuple[FloatArray, FloatArray]:
        if self._eigen is None:
            self._eigen = np.linalg.eigh(self.reduced)
        return self._eigen

    def reduced_pinv(self, limit: float) -> FloatArray:
        """The reduced matrix's pseudo-inverse on its eigenvalues above ``limit``."""
        if limit not in self._pinv:
            values, vectors = self.eigen
            keep = values > limit
            kept = vectors[:, keep]
            self._pinv[limit] = np.asarray((kept / values[keep]) @ kept.T)
        return self._pinv[limit]

    def null_space(self, limit: float) -> NullSpace:
        """The null space of the whole normal matrix (scaled coordinates): each null vector of
        the reduced system completed on the lines' own columns (x_o = −N_oo⁺N_og x_g), and the own
        directions a line does not determine."""
        values, vectors = self.eigen
        null_g = vectors[:, values <= limit]
        return NullSpace(
            self.size, self._completed(null_g), [b.null for b in self.lines], self.lines
        )

    def null_space_beside(self, limit: float, held: FloatArray) -> FloatArray:
        """The constraint vectors (scaled, P × d) to hold at zero when those of ``held`` (P × k,
        scaled, e.g. the fit's, linearly independent on the global columns) are held at zero
        whether this system sees them or not: ``held``, then the null vectors of the reduced
        system on the complement of held's global part, held on the global columns only (as
        :meth:`NullSpace.held_on_errors`: what this system alone cannot see stays out of the
        errors, and the lines' own terms take what they can)."""
        held_g = held[self.glob]
        if held_g.shape[1] == 0:
            return self.null_space(limit).held_on_errors().vectors
        q, _ = np.linalg.qr(held_g, mode="complete")
        free = q[:, held_g.shape[1] :]
        values, vectors = np.linalg.eigh(free.T @ self.reduced @ free)
        beside = np.zeros((self.size, int(np.count_nonzero(values <= limit))))
        beside[self.glob] = free @ vectors[:, values <= limit]
        return np.hstack([held, beside])

    def _completed(self, null_g: FloatArray) -> FloatArray:
        """Directions of the reduced system (g × d) completed on the lines' own columns
        (x_o = −N_oo⁺N_og x_g), P × d."""
        out = np.zeros((self.size, null_g.shape[1]))
        out[self.glob] = null_g
        for block in self.lines:
            out[block.columns] = -block.inverse @ block.coupling @ null_g[block.touched]
        return out


@dataclass(eq=False)
class NullSpace:
    """What a normal matrix does not determine (scaled coordinates): ``vectors`` (P × d) completed
    from the reduced system's null space, and per line ``own`` (o × m) its undetermined own
    directions (zero elsewhere)."""

    size: int
    vectors: FloatArray
    own: list[FloatArray]
    lines: list[OwnBlock]

    @property
    def dimensions(self) -> int:
        return int(self.vectors.shape[1] + sum(u.shape[1] for u in self.own))

    def orthonormal(self) -> FloatArray:
        """An orthonormal basis (P × d) of the whole null space."""
        columns = [self.vectors]
        for block, own in zip(self.lines, self.own, strict=True):
            if own.shape[1]:
                full = np.zeros((self.size, own.shape[1]))
                full[block.columns] = own
                columns.append(full)
        basis = np.hstack(columns)
        if basis.shape[1] == 0:
            return basis
        q, _ = np.linalg.qr(basis)
        return np.asarray(q)

    def held_on_errors(self) -> NullSpace:
        """The same null space, held at zero on the global columns only: each vector's part on
        the lines' own columns (offsets, slopes, a line's own effects) set to zero, so that a
        constraint Zᵀx = 0 keeps what the plan cannot see out of the errors and leaves the lines'
        own terms free to take what they can. (Held on whole vectors, the minimum norm over
        errors and offsets together let a line's offset share itself with errors no line sees.)
        The own null directions stay as they are."""
        vectors = self.vectors.copy()
        for block in self.lines:
            vectors[block.columns] = 0.0
        return NullSpace(self.size, vectors, self.own, self.lines)

    def rescaled(self, ratio: FloatArray) -> NullSpace:
        """The same constraint in other column scalings: a vector z (scaled by s0) constrains
        x = s0·x0 as z·x0 = 0; in a scaling s that reads (z·s/s0)·x_s = 0, so each row is
        multiplied by ``ratio`` = s/s0."""
        own = [ratio[b.columns, None] * u for b, u in zip(self.lines, self.own, strict=True)]
        return NullSpace(self.size, self.vectors * ratio[:, None], own, self.lines)


# --------------------------------------------------------------------------------------------
# Least squares restricted to a subspace (the complement of a null space)
# --------------------------------------------------------------------------------------------


@dataclass(eq=False)
class ConstrainedSystem:
    """min ½xᵀNx − bᵀx subject to Zᵀx = 0 (scaled coordinates), Z a :class:`NullSpace`: the
    solution and the matching inverse (upper-left block of the KKT matrix's inverse, which is
    T(TᵀNT)⁻¹Tᵀ for T spanning the directions left free).

    The lines' own columns are eliminated block by block (their own null directions are held
    by the own blocks' constrained inverses), leaving a KKT system on the global columns and
    the multipliers of the remaining constraints.
    """

    elimination: Elimination
    constraint: FloatArray  # (P × d) the completed null vectors in these scaled coordinates
    _lu: tuple[FloatArray, FloatArray]
    _couplings: list[FloatArray]  # per line: inverse @ [coupling | C_o]  (o × (g + d))

    @classmethod
    def of(cls, elimination: Elimination, constraint: FloatArray) -> ConstrainedSystem:
        e = elimination
        g = e.glob.size
        d = constraint.shape[1]
        kkt = np.zeros((g + d, g + d))
        kkt[:g, :g] = e.reduced
        kkt[:g, g:] = constraint[e.glob]
        couplings = []
        for block in e.lines:
            c_o = constraint[block.columns]
            y = np.zeros((block.columns.size, g + d))
            y[:, block.touched] = block.inverse @ block.coupling
            y[:, g:] = block.inverse @ c_o
            # the own-global part is already in e.reduced; add the multipliers' rows
            kkt[block.touched, g:] -= block.coupling.T @ y[:, g:]
            kkt[g:, g:] -= c_o.T @ y[:, g:]
            couplings.append(y)
        kkt[g:, :g] = kkt[:g, g:].T
        return cls(e, constraint, lu_factor(kkt, check_finite=False), couplings)

    def solve(self, rhs: FloatArray | None = None) -> FloatArray:
        """The constrained solution (scaled coordinates, P) for the system's right-hand side or
        for ``rhs`` (scaled, P)."""
        e = self.elimination
        g = e.glob.size
        d = self.constraint.shape[1]
        ext_rhs = np.zeros(g + d)
        if rhs is None:
            ext_rhs[:g] = e.reduced_rhs
        else:
            ext_rhs[:g] = rhs[e.glob]
        own_solutions = []
        for block in e.lines:
            b_o = block.rhs if rhs is None else rhs[block.columns]
            z = block.inverse @ b_o
            if rhs is not None:
                ext_rhs[block.touched] -= block.coupling.T @ z
            ext_rhs[g:] -= self.constraint[block.columns].T @ z
            own_solutions.append(z)
        rhs = ext_rhs
        ext = lu_solve(self._lu, rhs, check_finite=False)
        x = np.zeros(e.size)
        x[e.glob] = ext[:g]
        for block, z, y in zip(e.lines, own_solutions, self._couplings, strict=True):
            x[block.columns] = z - y @ ext
        return x

    def inverse(self) -> FloatArray:
        """T(TᵀNT)⁻¹Tᵀ in scaled coordinates (P × P)."""
        e = self.elimination
        g = e.glob.size
        size = g + self.constraint.shape[1]
        kkt_inverse = lu_solve(self._lu, np.eye(size), check_finite=False)
        kkt_inverse = 0.5 * (kkt_inverse + kkt_inverse.T)
        own_columns = (
            np.concatenate([b.columns for b in e.lines]) if e.lines else np.zeros(0, np.int64)
        )
        y = np.vstack(self._couplings) if e.lines else np.zeros((0, size))
        out = np.zeros((e.size, e.size))
        out[np.ix_(e.glob, e.glob)] = kkt_inverse[:g, :g]
        cross = -(y @ kkt_inverse[:, :g])
        out[np.ix_(own_columns, e.glob)] = cross
        out[np.ix_(e.glob, own_columns)] = cross.T
        own = y @ kkt_inverse @ y.T
        start = 0
        for block in e.lines:
            stop = start + block.columns.size
            own[start:stop, start:stop] += block.inverse
            start = stop
        out[np.ix_(own_columns, own_columns)] = own
        return out


# --------------------------------------------------------------------------------------------
# One line out
# --------------------------------------------------------------------------------------------


def line_schur(block: OwnBlock, part: LinePart, scale: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The line's Schur part on its touched global columns (scaled): S = N_gg − N_goN_oo⁺N_og
    and c = b_g − N_goN_oo⁺b_o, in the order of ``block.touched``."""
    s = scale[part.columns]
    g = np.flatnonzero(~np.isin(part.columns, block.columns))
    n_gg = part.normal[np.ix_(g, g)] * s[g, None] * s[None, g]
    b_g = part.rhs[g] * s[g]
    schur = n_gg - block.coupling.T @ block.inverse @ block.coupling
    rhs = b_g - block.coupling.T @ (block.inverse @ block.rhs)
    return schur, rhs


def largest_leverage(rows: FloatArray, pinv_touched: FloatArray) -> float:
    """Largest eigenvalue of H = F Q_tt Fᵀ for a line's weighted, own-projected rows F (n × t):
    1 when leaving the line out loses rank, below 1 otherwise."""
    if rows.size == 0:
        return 0.0
    if rows.shape[0] > rows.shape[1]:
        # the same non-zero eigenvalues from the t × t factor F = Q_F R_F
        rows = np.asarray(np.linalg.qr(rows, mode="r"))
    h = rows @ pinv_touched @ rows.T
    return float(np.linalg.eigvalsh(0.5 * (h + h.T))[-1])


__all__ = [
    "ConstrainedSystem",
    "Elimination",
    "LinePart",
    "NullSpace",
    "largest_eigenvalue",
    "largest_leverage",
    "line_schur",
]
