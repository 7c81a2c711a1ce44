"""Cross-validation of a grid model: what the model predicts where it measured nothing.

Two questions, two kinds of held-out readings:

- **The cross-axis surface's smoothing**: points spread over the grid are held out (fold
  ``(i + 2j) mod K``); every lattice line keeps readings, so the rigid-body functions are known
  there and only the surface has to predict the held-out node from its neighbours.
- **Each error function between its nodes** (the smooth part's degree and smoothing and the
  carry of the nodes' departures, :mod:`volucal.core.grid2d_departures`): whole lattice lines
  are held out — columns for a function of x, rows for a function of y (fold ``i mod K``), never
  the first or last line nor the reference line, so that a held-out line always lies halfway
  between two measured lines. That is the prediction a user of the table needs: a controller
  applies the correction between the measured nodes, where no reading says what the machine
  does. Held-out points would not test it: their line's other readings fix the function's
  value on that line.

Each fold refits the whole model without its readings (the node tables and gauges, then the
surface on what they leave) and predicts the held-out readings.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .grid2d_departures import best_carry, carry_kernel, fit_smooth_part, smooth_basis
from .grid2d_surface import SurfaceSolver
from .grid2d_system import Readings, RigidSystem, Term

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def _significant(
    errors: FloatArray, baseline: FloatArray, line: IntArray, standard_errors: float
) -> bool:
    """Whether ``errors`` beat ``baseline`` in mean square by more than ``standard_errors``
    standard errors of the gain, lines taken as the independent units (the readings of one
    held-out line share its departure)."""
    held = np.isfinite(errors)
    lines, inverse = np.unique(line[held], return_inverse=True)
    if lines.size < 2:
        return False
    gain = (
        np.bincount(inverse, weights=baseline[held] ** 2 - errors[held] ** 2, minlength=lines.size)
        / held.sum()
        * lines.size
    )
    return bool(gain.mean() > standard_errors * gain.std(ddof=1) / np.sqrt(lines.size))


@dataclass(frozen=True)
class FunctionChoice:
    """The smooth part's basis degree (1: node table, 3: cubic B-spline) and smoothing weight,
    and the carry of the nodes' departures between nodes."""

    degree: int
    smoothing: float
    carry: float


@dataclass
class _Fold:
    """One fold of a line cross-validation: held-out readings and what the refit says there."""

    held: NDArray[np.bool_]
    base: FloatArray  # prediction of the held-out readings by everything but the line's terms
    node_values: dict[str, FloatArray]  # node values of the line's terms, fitted without them
    measured: dict[str, NDArray[np.bool_]]  # their lattice nodes with a kept reading


class CrossValidation:
    """K-fold cross-validation of the whole model (module notes)."""

    def __init__(
        self,
        readings: Readings,
        system: RigidSystem,
        solver: SurfaceSolver,
        nodes: tuple[FloatArray, FloatArray],
        reference: tuple[float, float],
        folds: int,
        directions: Sequence[int],
    ) -> None:
        self.readings = readings
        self.system = system
        self.solver = solver
        self.nodes = nodes
        self.reference = reference
        self.count = folds
        self.directions = list(directions)
        self.node = solver.node(readings.ix, readings.iy)
        self.point_folds = (readings.ix + 2 * readings.iy) % folds
        self.line_folds = {a: self._line_folds(a) for a in (0, 1)}

    def _line_folds(self, axis: int) -> IntArray:
        index = self.readings.ix if axis == 0 else self.readings.iy
        nodes = self.nodes[axis]
        folds = index % self.count
        reference = int(np.argmin(np.abs(nodes - self.reference[axis])))
        keep = (index == 0) | (index == nodes.size - 1) | (index == reference)
        return np.where(keep, -1, folds).astype(np.int64)

    # ---- the surface --------------------------------------------------------------------------

    def surface_errors(self, weights: dict[int, float] | None, folds: IntArray) -> FloatArray:
        """Prediction error of every reading when its fold is held out: the node tables and
        gauges refitted without it, plus the surface (when ``weights``) fitted to what they
        leave of the kept readings. Readings in no fold get 0."""
        values = self.readings.value
        error = np.zeros_like(values)
        for f, reduced in enumerate(self.system.fold_solutions(folds, self.count, values)):
            held = folds == f
            if not held.any():
                continue
            prediction = self.system.reduced_design @ reduced
            if weights is not None:
                prediction = prediction + self._surface(folds, f, values - prediction, weights)
            error[held] = values[held] - prediction[held]
        return error

    def _surface(
        self, folds: IntArray, f: int, residual: FloatArray, weights: dict[int, float]
    ) -> FloatArray:
        """The surface fitted to the kept readings' ``residual``, at every reading's node."""
        out = np.zeros_like(residual)
        kept = folds != f
        for k in self.directions:
            mine = self.readings.direction == k
            fit = self.solver.fit(
                self.node[kept & mine],
                residual[kept & mine],
                weights[k],
                key=(id(folds), f, k, weights[k]),
            )
            out[mine] = fit[self.node[mine]]
        return out

    def choose_surface(self, candidates: Sequence[float]) -> dict[int, float]:
        """The surface smoothing per direction with the least held-out-point error."""
        chosen = {}
        for k in self.directions:
            rows = self.readings.direction == k
            scores = [
                float(
                    np.mean(
                        self.surface_errors({d: w for d in self.directions}, self.point_folds)[rows]
                        ** 2
                    )
                )
                for w in candidates
            ]
            chosen[k] = candidates[int(np.argmin(scores))]
        return chosen

    # ---- the error functions between their nodes ------------------------------------------

    def _folds(self, axis: int, surface: dict[int, float] | None) -> list[_Fold]:
        """Refits without each fold of held-out lines along ``axis``."""
        system, r = self.system, self.readings
        folds = self.line_folds[axis]
        slices = system.block_slices()
        out = []
        for f, reduced in enumerate(system.fold_solutions(folds, self.count, r.value)):
            held = folds == f
            if not held.any():
                continue
            rigid = system.reduced_design @ reduced
            base = rigid.copy()
            if surface is not None:
                base += self._surface(folds, f, r.value - rigid, surface)
            values, measured = {}, {}
            for index, term in enumerate(system.terms):
                if term.argument != axis:
                    continue
                # the line's terms are predicted by their candidates, not by the node tables
                columns = system.reduced_design[:, slices[index]]
                base -= columns @ reduced[slices[index]]
                values[term.id] = system.node_values(reduced, index)
                seen = np.zeros(self.nodes[axis].size, dtype=bool)
                seen[r.node(term)[(folds != f) & (r.direction == term.direction)]] = True
                measured[term.id] = seen
            out.append(_Fold(held, base, values, measured))
        return out

    def _pieces(
        self, term: Term, choice: FunctionChoice, folds: list[_Fold]
    ) -> tuple[NDArray[np.bool_], FloatArray, FloatArray]:
        """For one candidate: the held-out readings it enters, and its prediction there as
        ``fixed + carry·slope`` (the kernel is linear in the carry): (rows, fixed, slope)."""
        r = self.readings
        nodes = self.nodes[term.argument]
        basis = smooth_basis(nodes, choice.degree)
        lever = r.lever(term)
        rows = np.zeros(r.value.size, dtype=bool)
        fixed = np.zeros(r.value.size)
        slope = np.zeros(r.value.size)
        for fold in folds:
            mine = fold.held & (r.direction == term.direction)
            seen = fold.measured[term.id]
            values = fold.node_values[term.id][seen]
            coefficients = fit_smooth_part(basis, nodes[seen], values, choice.smoothing)
            departures = values - basis.design(nodes[seen]) @ coefficients
            q = r.position[mine, term.argument]
            without = carry_kernel(q, nodes[seen], 0.0) @ departures
            full = carry_kernel(q, nodes[seen], 1.0) @ departures
            rows |= mine
            fixed[mine] = lever[mine] * (basis.design(q) @ coefficients + without)
            slope[mine] = lever[mine] * (full - without)
        return rows, fixed, slope

    def choose_functions(
        self,
        terms: Sequence[Term],
        degrees: Sequence[int],
        smoothing: Sequence[float],
        surface: dict[int, float] | None,
        sweeps: int,
        significance: float,
    ) -> dict[str, FunctionChoice]:
        """Each function's smooth part and carry with the least held-out-line error.

        The linear interpolation of the node values (a lookup table) is the default: another
        choice must beat it by ``significance`` standard errors of its held-out gain. A held-out
        line lies halfway across a gap of two node steps, twice the gap the model is used
        across; there smoothing gains more over linear interpolation (linear interpolation's
        error on a smooth function grows as the square of the gap, a node's departure does
        not), so a gain within the noise of the cross-validation is not taken.

        Functions of the same coordinate (EXY, EYY and ECY all follow y) are predicted
        together on a held-out line, so they are chosen in turn, each with the others' current
        choice (``sweeps`` passes), starting from the lookup table.
        """
        choices = {t.id: FunctionChoice(1, min(smoothing), 1.0) for t in terms}
        values = self.readings.value
        for axis in (0, 1):
            mine = [t for t in terms if t.argument == axis]
            if not mine:
                continue
            folds = self._folds(axis, surface)
            base = np.zeros_like(values)
            for fold in folds:
                base[fold.held] = fold.base[fold.held]
            predicted = {t.id: self._prediction(t, choices[t.id], folds) for t in mine}
            for _ in range(sweeps):
                for term in mine:
                    others = sum(
                        (predicted[u.id] for u in mine if u.id != term.id), np.zeros_like(values)
                    )
                    target = values - base - others
                    lookup = FunctionChoice(1, min(smoothing), 1.0)
                    best = (self._errors(term, lookup, folds, target), lookup)
                    baseline = best[0]
                    if not np.isfinite(baseline).any():
                        continue  # no line between two measured ones: the lookup table stays
                    for degree in degrees:
                        for weight in smoothing:
                            candidate = FunctionChoice(degree, weight, 1.0)
                            rows, fixed, slope = self._pieces(term, candidate, folds)
                            carry = best_carry(target[rows] - fixed[rows], slope[rows])
                            errors = np.where(rows, target - fixed - carry * slope, np.nan)
                            if np.nanmean(errors**2) < np.nanmean(best[0] ** 2):
                                best = (errors, FunctionChoice(degree, weight, carry))
                    if best[1] != lookup and not _significant(
                        best[0], baseline, self.readings.node(term), significance
                    ):
                        best = (baseline, lookup)
                    choices[term.id] = best[1]
                    predicted[term.id] = self._prediction(term, best[1], folds)
        return choices

    def _errors(
        self, term: Term, choice: FunctionChoice, folds: list[_Fold], target: FloatArray
    ) -> FloatArray:
        rows, fixed, slope = self._pieces(term, choice, folds)
        return np.where(rows, target - fixed - choice.carry * slope, np.nan)

    def _prediction(self, term: Term, choice: FunctionChoice, folds: list[_Fold]) -> FloatArray:
        rows, fixed, slope = self._pieces(term, choice, folds)
        return np.where(rows, fixed + choice.carry * slope, 0.0)

    def line_errors(
        self,
        terms: Sequence[Term],
        choices: dict[str, FunctionChoice],
        surface: dict[int, float] | None,
        axis: int,
    ) -> tuple[FloatArray, NDArray[np.bool_]]:
        """Prediction error of the readings on held-out lines along ``axis`` with the given
        choices, and which readings were held out."""
        folds = self._folds(axis, surface)
        values = self.readings.value
        prediction = np.zeros_like(values)
        held = np.zeros(values.size, dtype=bool)
        for fold in folds:
            prediction[fold.held] = fold.base[fold.held]
            held |= fold.held
        for term in terms:
            if term.argument == axis:
                prediction += self._prediction(term, choices[term.id], folds)
        return np.where(held, values - prediction, 0.0), held
