"""The linear system of identification, stored by line (dense plans, issues 14 and 17).

The readings at one target share their row of the design: the 21 errors' gauge coordinates the
reading moves, the line's zero offset and, for a straightness line, its alignment slope. Those rows
are kept as a sparse matrix in which all the rows of a line share their columns; the effects'
columns (core/effects.py) are kept per reading. A line's contribution to the normal equations, its
part (:class:`~volucal.core.identify_blocks.LinePart`), is built from its rows on the columns it
touches. Nothing of size lines × unknowns² is stored: memory grows with the readings and with the
unknowns.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy import sparse

from .errors import (
    AXIS_ERROR_IDS,
    ERROR_IDS,
    ERROR_INFO,
    SQUARENESS_IDS,
    ErrorModel,
    axis_error_ids,
    gauge_null_space,
)
from .identify_blocks import Elimination, LinePart, largest_eigenvalue
from .kinematics import VolumetricModel, error_value_jacobian, rotation_error
from .machine import AXES, AXIS_INDEX
from .readings import QUANTITY_CODE, Readings

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Eigenvalues of the column-scaled normal matrix below this fraction of the largest are taken as
#: zero: a direction whose singular value is 1e-6 of the strongest is not seen by the plan.
RANK_TOLERANCE = 1e-12


@dataclass(frozen=True)
class ColumnBlock:
    kind: str  # "error", "offset", "slope", "effect"
    key: str  # error id, line name or effect label
    columns: slice
    line: int | None = None  # the only line this block acts on, if any


@dataclass(eq=False)
class LinearSystem:
    """Weighted least squares in normal-equation form, stored by line.

    ``normal`` = AᵀWA and ``rhs`` = AᵀWy over all readings (dense, unknowns × unknowns).
    ``target_design`` holds the rows of A shared by the readings at one target — the 21 errors'
    gauge coordinates, the lines' zero offsets and straightness slopes — as a sparse CSR matrix
    (T × p_target) in which every row of a line has the same columns: the errors that line moves
    and its own offset and slope. ``effect_design`` (readings × p_effect) holds the effects'
    columns. A line's contribution to the normal equations (:meth:`line_part`, for
    leave-one-line-out and the rank test of a line) is built from its rows when needed, on the
    columns it touches only: nothing of size lines × unknowns² is ever stored.

    ``line_targets`` (lines + 1) bounds each line's rows of ``target_design`` (targets are
    sorted by line); ``reading_order`` lists the readings line by line and ``reading_bounds``
    (lines + 1) bounds each line's readings in it.
    """

    blocks: list[ColumnBlock]
    normal: FloatArray
    rhs: FloatArray
    target_design: sparse.csr_matrix  # (T, p_target): geometric + nuisance columns per target
    target_of_reading: NDArray[np.int64]
    effect_design: FloatArray  # (n, p_effect)
    y: FloatArray  # the (pseudo-)observations of this linearisation
    weights: FloatArray
    line_targets: NDArray[np.int64]
    reading_order: NDArray[np.int64]
    reading_bounds: NDArray[np.int64]
    #: the effects' separable directions (see :func:`separable_reduction`), if restricted
    reduction: Reduction | None = None
    #: once the system is fitted, its column scaling and the constraint vectors (scaled, P × d,
    #: in the reduced unknowns) the fit holds at zero: what the plan leaves unseen at zero
    #: errors, on the global columns only (:meth:`NullSpace.held_on_errors`). A
    #: linearisation about identified errors may see a little of them through second-order
    #: couplings, which the fit does not use; cross-validation must not use them either
    unseen: tuple[FloatArray, FloatArray] | None = None
    #: each line's part once built, while :meth:`keeping_parts` is in effect
    _parts: list[LinePart | None] | None = field(default=None, init=False, repr=False)
    #: eliminations of the lines' own columns already made (see :func:`eliminate`)
    _eliminations: dict[tuple[str, ...], tuple[Elimination, float]] = field(
        default_factory=dict, init=False, repr=False
    )

    def reduced(self) -> LinearSystem:
        """The same least-squares problem in the reduced unknowns (effects restricted to their
        separable directions); itself when unrestricted."""
        if self.reduction is None:
            return self
        r = self.reduction.matrix
        rigid = self.target_design.shape[1]
        blocks = [b for b in self.blocks if b.kind != "effect"] + list(self.reduction.blocks)
        return replace(
            self,
            blocks=blocks,
            normal=expand_pair(self.normal, r, rigid, transpose=True),
            rhs=np.concatenate([self.rhs[:rigid], r[rigid:, rigid:].T @ self.rhs[rigid:]]),
            effect_design=self.effect_design @ r[rigid:, rigid:],
            reduction=None,
        )

    @property
    def size(self) -> int:
        return self.normal.shape[0]

    @property
    def lines(self) -> int:
        return len(self.line_targets) - 1

    def design_rows(self, mask: NDArray[np.bool_] | None = None) -> FloatArray:
        """Explicit (dense) rows of A for the readings in ``mask`` (all by default)."""
        idx = self.target_of_reading if mask is None else self.target_of_reading[mask]
        eff = self.effect_design if mask is None else self.effect_design[mask]
        return np.hstack([self.target_design[idx].toarray(), eff])

    def line_columns(self, line: int) -> NDArray[np.int64]:
        cols = [np.arange(b.columns.start, b.columns.stop) for b in self.blocks if b.line == line]
        return np.concatenate(cols) if cols else np.empty(0, dtype=np.int64)

    def own_columns(self, kinds: tuple[str, ...] = ("offset", "slope", "effect")) -> list[IntArray]:
        """Per line, the columns of the blocks of those ``kinds`` that act on that line only (an
        effect said to act on one line whose design reaches other readings is kept global)."""
        own: list[list[IntArray]] = [[] for _ in range(self.lines)]
        p_t = self.target_design.shape[1]
        for b in self.blocks:
            if b.line is None or b.kind not in kinds:
                continue
            columns = np.arange(b.columns.start, b.columns.stop)
            if b.kind == "effect":
                design = self.effect_design[:, columns - p_t]
                inside = np.count_nonzero(design[self.line_readings(b.line)], axis=0)
                if np.any(np.count_nonzero(design, axis=0) != inside):
                    continue
            own[b.line].append(columns)
        return [np.concatenate(c) if c else np.empty(0, dtype=np.int64) for c in own]

    def line_readings(self, line: int) -> IntArray:
        """Indices of the line's readings."""
        return self.reading_order[self.reading_bounds[line] : self.reading_bounds[line + 1]]

    def line_rows(self, line: int) -> tuple[IntArray, FloatArray]:
        """(columns, rows) of the line's targets in ``target_design``: the dense block
        (targets × columns) its rows hold on the columns they share."""
        a, z = self.line_targets[line], self.line_targets[line + 1]
        td = self.target_design
        start, stop = td.indptr[a], td.indptr[z]
        if z == a:
            return np.empty(0, dtype=np.int64), np.zeros((0, 0))
        k = (td.indptr[a + 1] - start) if z > a else 0
        return td.indices[start : start + k].astype(np.int64), td.data[start:stop].reshape(z - a, k)

    def line_part(self, line: int, keep: NDArray[np.bool_] | None = None) -> LinePart:
        """The line's contribution to the normal equations, on the columns it touches: from its
        readings (those in ``keep`` only, if given). Built once and kept (for all readings)."""
        if keep is not None or self._parts is None:
            return self._build_part(line, keep)
        part = self._parts[line]
        if part is None:
            part = self._parts[line] = self._build_part(line, None)
        return part

    @contextmanager
    def keeping_parts(self) -> Iterator[LinearSystem]:
        """Keep each line's part once built, for the duration of the block (the rank analysis,
        the solves and leave-one-line-out use them several times); they are released after, so
        that a stored identification does not hold them."""
        if self._parts is not None:
            yield self
            return
        self._parts = [None] * self.lines
        try:
            yield self
        finally:
            self._parts = None

    def _build_part(self, line: int, keep: NDArray[np.bool_] | None) -> LinePart:
        columns, block = self.line_rows(line)
        readings = self.line_readings(line)
        if keep is not None:
            readings = readings[keep[readings]]
        count = block.shape[0]
        local = self.target_of_reading[readings] - self.line_targets[line]
        w = self.weights[readings]
        y = self.y[readings]
        w_t = np.bincount(local, weights=w, minlength=count)
        wy_t = np.bincount(local, weights=w * y, minlength=count)
        normal = (block * w_t[:, None]).T @ block
        rhs = block.T @ wy_t
        if self.effect_design.shape[1] and readings.size:
            e = self.effect_design[readings]
            touched = np.flatnonzero(np.any(e != 0.0, axis=0))
            if touched.size:
                e = e[:, touched]
                we = e * w[:, None]
                agg = np.stack(
                    [np.bincount(local, weights=col, minlength=count) for col in we.T], axis=-1
                )
                cross = block.T @ agg
                normal = np.block([[normal, cross], [cross.T, e.T @ we]])
                rhs = np.concatenate([rhs, we.T @ y])
                columns = np.concatenate([columns, self.target_design.shape[1] + touched])
        return LinePart(columns, normal, rhs)

    def stored_nbytes(self) -> dict[str, int]:
        """Bytes held per kind of storage: what is stored by line (design rows, index arrays)
        and the dense unknowns × unknowns normal matrix."""
        td = self.target_design
        by_line = sum(
            a.nbytes
            for a in (
                td.data,
                td.indices,
                td.indptr,
                self.target_of_reading,
                self.effect_design,
                self.y,
                self.weights,
                self.line_targets,
                self.reading_order,
                self.reading_bounds,
            )
        )
        by_line += sum(
            p.columns.nbytes + p.normal.nbytes + p.rhs.nbytes
            for p in self._parts or []
            if p is not None
        )
        return {"lines": int(by_line), "normal": int(self.normal.nbytes + self.rhs.nbytes)}


def expand_pair(
    matrix: FloatArray, r: FloatArray, rigid: int, transpose: bool = False
) -> FloatArray:
    """r·M·rᵀ (or rᵀ·M·r with ``transpose``) for a reduction matrix r that is the identity on the
    first ``rigid`` columns and block-structured after: computed by blocks (r is P × P')."""
    e = r[rigid:, rigid:]
    if transpose:
        e = e.T
    n_out = rigid + e.shape[0]
    out = np.empty((n_out, n_out))
    out[:rigid, :rigid] = matrix[:rigid, :rigid]
    cross = matrix[:rigid, rigid:] @ e.T
    out[:rigid, rigid:] = cross
    out[rigid:, :rigid] = cross.T
    out[rigid:, rigid:] = e @ matrix[rigid:, rigid:] @ e.T
    return out


def column_scale(normal: FloatArray) -> FloatArray:
    """1/‖column‖ for the columns of A (from AᵀA's diagonal); columns whose norm is below 1e-12
    of the largest are rounding noise of an unseen parameter and are left unscaled, so that
    they stay (numerically) zero instead of being blown up to unit size."""
    diag = np.diag(normal).copy()
    seen = diag > 1e-24 * max(float(diag.max(initial=0.0)), 1e-300)
    return np.where(seen, 1.0 / np.sqrt(np.where(seen, diag, 1.0)), 1.0)


def rank_limit(normal: FloatArray, scale: FloatArray) -> float:
    """Eigenvalues of the column-scaled normal matrix at or below this are taken as zero."""
    largest = largest_eigenvalue(normal * scale[:, None] * scale[None, :])
    return RANK_TOLERANCE * max(largest, 1e-300)


def eliminate(
    system: LinearSystem, kinds: tuple[str, ...] = ("offset", "slope", "effect")
) -> tuple[Elimination, float]:
    """The system with every line's own columns eliminated, and the rank limit (made once per
    system: the subspace, the rank analysis and the first solve share it)."""
    if kinds not in system._eliminations:
        scale = column_scale(system.normal)
        limit = rank_limit(system.normal, scale)
        elimination = Elimination.of(
            system.line_part, system.own_columns(kinds), system.size, scale, limit
        )
        system._eliminations[kinds] = (elimination, limit)
    return system._eliminations[kinds]


@dataclass(frozen=True, eq=False)
class Reduction:
    """The effects' unknowns restricted to what the plan tells apart from a rigid body.

    ``matrix`` (P × P') maps the reduced unknowns to all of them: the identity on the 21 errors'
    and the lines' columns (which come first), and for each effect the separable directions of
    its columns. ``blocks`` are the effects' column blocks in the reduced unknowns.
    """

    matrix: FloatArray
    blocks: tuple[ColumnBlock, ...]
    #: per effect, what of it a rigid body produces as well (left to the 21 errors)
    shared: tuple[SharedPart, ...] = ()


@dataclass(frozen=True, eq=False)
class SharedPart:
    """A direction of an effect's parameters that the plan sees but cannot tell from a change
    of the 21 errors: the fit leaves it to the errors, which then carry it.

    ``effect`` is the effect's position among the system's effects, ``direction`` the change of
    its parameters (unit norm in the column-scaled coordinates), ``errors`` the errors whose
    change produces the same readings, the largest change first (coefficient norm, µm or µrad;
    each at least :data:`SHARE_NAMED` of the largest)."""

    effect: int
    direction: FloatArray
    errors: tuple[str, ...]


#: An error is named as carrying an effect's shared part when its change (coefficient norm, µm
#: or µrad) reaches this fraction of the largest error's; a surface's shape function is named
#: when its column-scaled weight in the shared direction reaches this fraction of the largest.
SHARE_NAMED = 0.1
#: A direction of an effect the 21 errors take up entirely is *shared* with them (and said so)
#: when what they reproduce of it reaches this (column-scaled information); below, the plan does
#: not see it at all.
SHARED_SEEN = 1e-3


@dataclass(frozen=True, eq=False)
class Targets:
    """Unique (line, target) points of a measurement, sorted by line."""

    line: NDArray[np.int64]
    position_mm: FloatArray
    reflector_mm: FloatArray
    projection: FloatArray
    quantity: NDArray[np.int64]
    target_mm: FloatArray
    of_reading: NDArray[np.int64]

    def rows(self, start: int, stop: int) -> Targets:
        """The targets start … stop − 1 (``of_reading`` is left as is)."""
        return Targets(
            self.line[start:stop],
            self.position_mm[start:stop],
            self.reflector_mm[start:stop],
            self.projection[start:stop],
            self.quantity[start:stop],
            self.target_mm[start:stop],
            self.of_reading,
        )

    def bounds(self, lines: int) -> NDArray[np.int64]:
        """(lines + 1) bounds of each line's targets."""
        return np.searchsorted(self.line, np.arange(lines + 1)).astype(np.int64)


def unique_targets(readings: Readings) -> Targets:
    key = readings.line * 1_000_000 + readings.target
    unique, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    return Targets(
        readings.line[first],
        readings.position_mm[first],
        readings.reflector_mm[first],
        readings.projection[first],
        readings.quantity[first],
        readings.target_mm[first],
        inverse.astype(np.int64),
    )


@dataclass(frozen=True, eq=False)
class Gauge:
    """Block-diagonal map from free gauge coordinates θ to model parameters: p = N θ."""

    matrix: FloatArray  # (P, G)
    blocks: dict[str, slice]  # error id -> columns of θ

    @classmethod
    def for_model(cls, model: ErrorModel) -> Gauge:
        columns = []
        blocks: dict[str, slice] = {}
        start = 0
        for eid in AXIS_ERROR_IDS:
            f = model.functions[eid]
            axis = ERROR_INFO[eid].axis
            assert axis is not None
            null = gauge_null_space(
                f.basis, model.machine.reference(axis), ERROR_INFO[eid].is_straightness
            )
            columns.append(null)
            blocks[eid] = slice(start, start + null.shape[1])
            start += null.shape[1]
        for eid in SQUARENESS_IDS:
            columns.append(np.ones((1, 1)))
            blocks[eid] = slice(start, start + 1)
            start += 1
        rows = sum(c.shape[0] for c in columns)
        matrix = np.zeros((rows, start))
        r = 0
        for c, eid in zip(columns, ERROR_IDS, strict=True):
            matrix[r : r + c.shape[0], blocks[eid]] = c
            r += c.shape[0]
        return cls(matrix, blocks)

    @property
    def size(self) -> int:
        return self.matrix.shape[1]


def geometric_rows(model: ErrorModel, targets: Targets) -> FloatArray:
    """d(reading)/d(model parameters) per target (T, P): exact chain for displacement optics,
    the first-order sum of the axes' angles for angular optics.

    The chain's derivatives with respect to each error's *value* (T × 3 × 6 per axis) are
    projected on the optics first and then spread over the error's basis functions, so nothing
    of size T × 3 × P is formed."""
    rows = np.zeros((len(targets.line), model.parameter_count))
    angular = targets.quantity == QUANTITY_CODE["angular"]
    disp = ~angular
    slices = model.parameter_slices
    if disp.any():
        q = targets.position_mm[disp]
        w = targets.projection[disp]
        per_axis, squareness = error_value_jacobian(model, q, targets.reflector_mm[disp])
        block = np.zeros((len(q), model.parameter_count))
        for axis in AXES:
            k = AXIS_INDEX[axis]
            along = np.einsum("nc,ncj->nj", w, per_axis[axis])  # d(reading)/d(error value)
            for j, eid in enumerate(axis_error_ids(axis)):
                design = model.functions[eid].basis.design(q[:, k])
                block[:, slices[eid]] = along[:, j, None] * design
        for sid in SQUARENESS_IDS:
            block[:, slices[sid].start] = np.einsum("nc,nc->n", w, squareness[sid])
        rows[disp] = block
    if angular.any():
        q = targets.position_mm[angular]
        w = targets.projection[angular]
        block = np.zeros((int(angular.sum()), model.parameter_count))
        for axis in AXES:
            for j, component in enumerate("ABC"):
                eid = f"E{component}{axis}"
                design = model.functions[eid].basis.design(q[:, AXIS_INDEX[axis]])
                block[:, slices[eid]] += w[:, j, None] * design
        rows[angular] = block
    return rows


def gauge_rows(rows: FloatArray, model: ErrorModel, gauge: Gauge) -> FloatArray:
    """rows · N (T × G) by the gauge map's diagonal blocks (one per error), skipping the errors
    these rows do not move."""
    out = np.zeros((rows.shape[0], gauge.size))
    slices = model.parameter_slices
    for eid in ERROR_IDS:
        part = rows[:, slices[eid]]
        if np.any(part):
            out[:, gauge.blocks[eid]] = part @ gauge.matrix[slices[eid], gauge.blocks[eid]]
    return out


def predict_geometric(model: ErrorModel, targets: Targets) -> FloatArray:
    """Exact prediction of each target's reading from the 21 errors (without nuisances)."""
    out = np.zeros(len(targets.line))
    angular = targets.quantity == QUANTITY_CODE["angular"]
    disp = ~angular
    if disp.any():
        e = VolumetricModel(model).error(targets.position_mm[disp], targets.reflector_mm[disp])
        out[disp] = np.einsum("nc,nc->n", e, targets.projection[disp])
    if angular.any():
        rot = rotation_error(model, targets.position_mm[angular])
        out[angular] = np.einsum("nc,nc->n", rot, targets.projection[angular])
    return out


class EffectTerm:
    """What identification needs of an effect (core/effects.py implements it)."""

    label: str
    line_index: int | None  # the only line it acts on (a set-up effect), or None

    def design(self, readings: Readings, model: ErrorModel) -> FloatArray:  # (n, k)
        raise NotImplementedError


#: Target rows (targets × parameters) built at once: about 32 MB of them.
_ROW_ENTRIES = 4_000_000


@dataclass(frozen=True, eq=False)
class GeometricDesign:
    """d(reading)/dθ of every target in the gauge coordinates, line by line: ``columns[l]`` are
    the gauge coordinates line l moves, ``rows[l]`` (its targets × those columns) the values."""

    columns: list[IntArray]
    rows: list[FloatArray]

    @classmethod
    def of(
        cls, model: ErrorModel, targets: Targets, gauge: Gauge, bounds: IntArray
    ) -> GeometricDesign:
        budget = max(1, _ROW_ENTRIES // max(model.parameter_count, 1))
        lines = len(bounds) - 1
        columns: list[IntArray] = []
        rows: list[FloatArray] = []
        first = 0
        while first < lines:
            last = first + 1
            while last < lines and bounds[last + 1] - bounds[first] <= budget:
                last += 1
            a = bounds[first]
            geo = gauge_rows(geometric_rows(model, targets.rows(a, bounds[last])), model, gauge)
            for line in range(first, last):
                sub = geo[bounds[line] - a : bounds[line + 1] - a]
                touched = np.flatnonzero(np.any(sub != 0.0, axis=0))
                columns.append(touched)
                rows.append(np.ascontiguousarray(sub[:, touched]))
            first = last
        return cls(columns, rows)

    def apply(self, theta: FloatArray) -> FloatArray:
        """rows · θ for every target."""
        parts = [r @ theta[c] for c, r in zip(self.columns, self.rows, strict=True)]
        return np.concatenate(parts) if parts else np.zeros(0)


def build_system(
    readings: Readings,
    targets: Targets,
    model: ErrorModel,
    gauge: Gauge,
    effects: Sequence[EffectTerm],
    pseudo_y: FloatArray,
    effect_model: ErrorModel | None = None,
    geometric: GeometricDesign | None = None,
) -> LinearSystem:
    """Assemble the normal equations for one linearisation (effects designed with
    ``effect_model``, by default the linearisation point itself; the geometric rows given or
    computed at ``model``)."""
    n_lines = len(readings.lines)
    bounds = targets.bounds(n_lines)
    if geometric is None:
        geometric = GeometricDesign.of(model, targets, gauge, bounds)
    blocks: list[ColumnBlock] = [ColumnBlock("error", eid, gauge.blocks[eid]) for eid in ERROR_IDS]
    start = gauge.size
    for index, line in enumerate(readings.lines):
        blocks.append(
            ColumnBlock("offset", line.name, slice(start + index, start + index + 1), index)
        )
    offset_of = start + np.arange(n_lines)
    start += n_lines
    straight_lines = [
        i for i, line in enumerate(readings.lines) if line.spec.quantity == "straightness"
    ]
    slope_of: dict[int, int] = {}
    for k, index in enumerate(straight_lines):
        blocks.append(
            ColumnBlock("slope", readings.lines[index].name, slice(start + k, start + k + 1), index)
        )
        slope_of[index] = start + k
    start += len(straight_lines)
    p_t = start
    # target rows line by line: the line's error columns, then its offset (and slope) column
    data, indices, row_length = [], [], []
    for index in range(n_lines):
        a, z = bounds[index], bounds[index + 1]
        columns: list[IntArray] = [geometric.columns[index], offset_of[index : index + 1]]
        pieces = [geometric.rows[index], np.ones((z - a, 1))]
        if index in slope_of:
            columns.append(np.array([slope_of[index]]))
            # slope per metre of travel keeps the columns on the scale of the others
            pieces.append(targets.target_mm[a:z, None] / 1000.0)
        columns_l = np.concatenate(columns).astype(np.int32)
        data.append(np.hstack(pieces).ravel())
        indices.append(np.tile(columns_l, z - a))
        row_length.append(np.full(z - a, columns_l.size))
    indptr = np.concatenate([[0], np.cumsum(np.concatenate(row_length))]) if n_lines else [0]
    target_design = sparse.csr_matrix(
        (
            np.concatenate(data) if data else np.zeros(0),
            np.concatenate(indices) if indices else np.zeros(0, np.int32),
            np.asarray(indptr, dtype=np.int64),
        ),
        shape=(len(targets.line), p_t),
    )
    del data, indices
    effect_parts = []
    for effect in effects:
        d = effect.design(readings, effect_model or model)
        effect_parts.append(d)
        blocks.append(
            ColumnBlock("effect", effect.label, slice(start, start + d.shape[1]), effect.line_index)
        )
        start += d.shape[1]
    effect_design = np.hstack(effect_parts) if effect_parts else np.zeros((len(readings), 0))
    order = np.argsort(readings.line, kind="stable").astype(np.int64)
    system = LinearSystem(
        blocks,
        np.zeros((start, start)),
        np.zeros(start),
        target_design,
        targets.of_reading,
        effect_design,
        pseudo_y,
        1.0 / readings.sigma**2,
        bounds,
        order,
        np.searchsorted(readings.line[order], np.arange(n_lines + 1)).astype(np.int64),
    )
    # identification uses the parts several times (normal matrix, eliminations, rank analysis):
    # they are kept until it is done with this linearisation (identify releases them)
    system._parts = [None] * n_lines
    for index in range(n_lines):
        part = system.line_part(index)
        system.normal[np.ix_(part.columns, part.columns)] += part.normal
        system.rhs[part.columns] += part.rhs
    return system


def without_effects(system: LinearSystem) -> LinearSystem:
    """The system restricted to the 21 errors and the lines' nuisances (effect columns, which
    come last, left out)."""
    size = min((b.columns.start for b in system.blocks if b.kind == "effect"), default=system.size)
    if size == system.size:
        return system
    out = replace(
        system,
        blocks=[b for b in system.blocks if b.kind != "effect"],
        normal=system.normal[:size, :size],
        rhs=system.rhs[:size],
        effect_design=np.zeros((len(system.target_of_reading), 0)),
        reduction=None,
    )
    # the parts without the effects' columns (which come last)
    if system._parts is None:
        return out
    out._parts = [
        None
        if p is None
        else LinePart(
            p.columns[p.columns < size],
            p.normal[np.ix_(p.columns < size, p.columns < size)],
            p.rhs[p.columns < size],
        )
        for p in system._parts
    ]
    return out
