"""How much of an effect a 21-error rigid-body fit could absorb: this generator's own, independent
least-squares projection (used only to grade how visible a drawn effect is).

The first-order model of a reading, linear in the error functions (derived in README.md):

    E = δX + δY + δZ + εX × ((0, y, z) + t) + εY × ((0, 0, z) + t) + εZ × t     (WXYFZT)
        + (−(y − y0)·EC0Y + (z − z0)·EB0Z, −(z − z0)·EA0Z, 0)
    linear: u·E,  straightness: v·E + slope·s,  angular: v·(εX + εY + εZ);  + a zero offset

In another chain each axis' ε acts through the travel of the axes after it ("WFYXZT": εY ×
((x, 0, z) + t), εX × ((0, 0, z) + t), εZ × t).

Each of the 18 functions is a cubic B-spline with knots about every ``knot_mm`` (50 mm, the
DESIGN.md default, widened with the targets' stride on an axis longer than 1.5 m), each basis
function shifted to be zero at the reference position; every line has its own offset, every
straightness line its own slope. A rigid model predicts the same value for every run at a
target, so the projection works on the per-target means over the runs.
Pure numpy; never imports volucal.
"""

from __future__ import annotations

import numpy as np

from .laser import LineSchedule, PlanSpec, stride_scale
from .machine import AXES, chain_axes


def bspline_basis(x: np.ndarray, lo: float, hi: float, intervals: int) -> np.ndarray:
    """Cubic B-spline basis (N, intervals + 3) on [lo, hi] with uniform knots (Cox–de Boor)."""
    inner = np.linspace(lo, hi, intervals + 1)
    knots = np.concatenate([[lo] * 3, inner, [hi] * 3])
    x = np.clip(np.asarray(x, dtype=float), lo, hi - 1e-9 * (hi - lo))
    basis = np.array([(knots[i] <= x) & (x < knots[i + 1])
                      for i in range(len(knots) - 1)], dtype=float).T
    for degree in range(1, 4):
        nxt = np.zeros((len(x), len(knots) - degree - 1))
        for i in range(len(knots) - degree - 1):
            left = knots[i + degree] - knots[i]
            right = knots[i + degree + 1] - knots[i + 1]
            term = np.zeros(len(x))
            if left > 0:
                term += (x - knots[i]) / left * basis[:, i]
            if right > 0:
                term += (knots[i + degree + 1] - x) / right * basis[:, i + 1]
            nxt[:, i] = term
        basis = nxt
    return basis


class RigidProjector:
    """Orthogonal projection of per-target run means on the span of the rigid-body model."""

    def __init__(self, plan: PlanSpec, lines: list[LineSchedule],
                 knot_mm: float | None = None) -> None:
        self.lines = lines
        reference = plan.reference_mm or {a: plan.stroke_mm[a][0] for a in AXES}
        bases = {}
        for axis in AXES:
            lo, hi = min(plan.stroke_mm[axis]), max(plan.stroke_mm[axis])
            # 50 mm, widened as the operator widens the targets' stride on a long axis
            knots = 50.0 * stride_scale(hi - lo) if knot_mm is None else knot_mm
            intervals = max(int(round((hi - lo) / knots)), 1)
            bases[axis] = (lo, hi, intervals, bspline_basis(
                np.array([reference[axis]]), lo, hi, intervals)[0])
        blocks = []
        self.rows: list[slice] = []
        start = 0
        straight = [i for i, line in enumerate(lines) if line.spec.quantity == "straightness"]
        # an axis' rotation acts through the travel of the axes after it in the chain
        order = chain_axes(plan.chain)
        after = {a: np.array([float(b in order[order.index(a) + 1:]) for b in AXES])
                 for a in AXES}
        for index, line in enumerate(lines):
            spec = line.spec
            s = line.targets_mm
            q = spec.start_mm + np.outer(s, spec.direction)
            k = len(s)
            t = spec.reflector_mm
            sense = spec.direction if spec.quantity == "linear" else spec.sensitive
            columns = []
            for j, axis in enumerate(AXES):
                lo, hi, intervals, at_ref = bases[axis]
                g = bspline_basis(q[:, j], lo, hi, intervals) - at_ref
                lever = t + q * after[axis]
                if spec.quantity == "angular":
                    translation = np.zeros(3)
                    rotation = np.tile(sense, (k, 1))
                else:
                    translation = sense
                    rotation = np.cross(lever, sense) * 1e-3
                for c in range(3):
                    columns.append(translation[c] * g)
                for c in range(3):
                    columns.append(rotation[:, c:c + 1] * g)
            if spec.quantity == "angular":
                square = np.zeros((k, 3))
            else:
                dy = (q[:, 1] - reference["Y"]) * 1e-3
                dz = (q[:, 2] - reference["Z"]) * 1e-3
                square = np.stack([-sense[0] * dy, sense[0] * dz, -sense[1] * dz], axis=1)
            offsets = np.zeros((k, len(lines)))
            offsets[:, index] = 1.0
            slopes = np.zeros((k, len(straight)))
            if index in straight:
                slopes[:, straight.index(index)] = s
            blocks.append(np.hstack(columns + [square, offsets, slopes]))
            self.rows.append(slice(start, start + k))
            start += k
        design = np.vstack(blocks)
        scale = np.linalg.norm(design, axis=0)
        scale[scale == 0] = 1.0
        self.bases = bases
        self.scale = scale
        # Orthonormal basis of the column space from the Gram matrix's eigenvectors: much faster
        # than an SVD of the tall matrix when the BLAS threads compete for the cores.
        a = self.scaled = design / scale
        values, vectors = np.linalg.eigh(a.T @ a)
        keep = values > values[-1] * 1e-12
        self.basis = a @ (vectors[:, keep] / np.sqrt(values[keep]))
        self.rank = int(keep.sum())
        self.unknowns = design.shape[1]

    def residual_peaks(self, diffs: dict[str, np.ndarray]) -> dict[str, float]:
        """Per line, max |reading − rigid-body fit| of noise-free contributions (runs, targets)."""
        means = np.concatenate([diffs[line.spec.name].mean(axis=0) for line in self.lines])
        fitted = self.basis @ (self.basis.T @ means)
        out = {}
        for line, rows in zip(self.lines, self.rows, strict=True):
            residual = diffs[line.spec.name] - fitted[rows]
            out[line.spec.name] = float(np.max(np.abs(residual)))
        return out

    def fit(self, diffs: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict[str, float],
                                                          float]:
        """The rigid-body model's least-squares fit of noise-free contributions (runs, targets):
        each function's B-spline coefficients (µm; µrad for the angles: zero at the reference
        position, evaluated by :meth:`function_values`), the three squareness errors (µrad) and
        the residual's norm relative to the contribution's over every line's target means (0
        when a rigid body produces it exactly on these lines; infinite when no line sees it)."""
        means = np.concatenate([diffs[line.spec.name].mean(axis=0) for line in self.lines])
        # minimum norm on the directions the lines do not see (the gauges: a squareness against
        # the straightness slopes, an angle no line reads), as the projection's rank does
        scaled, *_ = np.linalg.lstsq(self.scaled, means, rcond=1e-6)
        residual = means - self.scaled @ scaled
        coef = scaled / self.scale
        size = float(np.linalg.norm(means))
        functions: dict[str, np.ndarray] = {}
        start = 0
        for axis in AXES:
            count = self.bases[axis][2] + 3
            for name in ("X", "Y", "Z", "A", "B", "C"):
                functions[f"E{name}{axis}"] = coef[start:start + count]
                start += count
        squareness = dict(zip(("EC0Y", "EB0Z", "EA0Z"), coef[start:start + 3].tolist(),
                              strict=True))
        share = float(np.linalg.norm(residual)) / size if size > 0 else float("inf")
        return functions, squareness, share

    def function_values(self, eid: str, coefficients: np.ndarray, q: np.ndarray) -> np.ndarray:
        """A function of :meth:`fit` at positions q (mm) along its axis."""
        lo, hi, intervals, at_ref = self.bases[eid[2]]
        return (bspline_basis(np.asarray(q, float), lo, hi, intervals) - at_ref) @ coefficients
