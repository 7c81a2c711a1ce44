"""The closed loop's F tests: a candidate's columns against what the current model leaves,
after projecting out what the model can already absorb, and the diagnosis they fill; with the
measures every part of the loop uses (the RMS over chosen readings, the exchange of µrad for µm,
a run's cell of a line, the Bonferroni correction)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy import sparse, special

from .effects import Effect
from .errors import ErrorModel
from .identify import Identification
from .loop_records import EffectKey, Finding, FloatArray
from .machine import AXES, AXIS_INDEX
from .measurement import LineSpec
from .readings import Readings

#: A column of a candidate, or a group of a fitted contribution in a size test
#: (:meth:`Tester.test_split`), is left out when the model takes up all but this share of its
#: weighted energy: together, the directions of several such columns are too close to null for
#: rounding to leave their test alone.
USEFUL_SHARE = 1e-4


#: The same for a candidate of one column, whose test is a ratio of two numbers: rounding leaves
#: ~1e-13 of a column the model absorbs, and a drift whose contribution the 21 errors take up
#: almost whole (a scale the later lines see settled, absorbed line by line) shows only in what
#: changes within the first line, ~1e-5 of it.
USEFUL_SHARE_ONE_COLUMN = 1e-9


def noise_variance(identification: Identification) -> float:
    """The weighted residual variance of a fit (σ², per degree of freedom): the unit a test's
    χ² is counted in."""
    residual = identification.residual
    dof = max(len(residual) - identification.fitted_rank, 1)
    return float(np.sum(identification.system.weights * residual**2) / dof)


class Tester:
    """Tests candidate columns against an identification's residual."""

    def __init__(self, identification: Identification) -> None:
        self.ident = identification
        system = identification.system
        self.system = system
        self.w = system.weights
        self.r = identification.residual
        self.wr = self.w * self.r
        n_targets = system.target_design.shape[0]
        n = len(self.r)
        # readings -> targets summation as a sparse matrix (np.add.at is far slower)
        self.to_targets = sparse.csr_matrix(
            (np.ones(n), (system.target_of_reading, np.arange(n))), shape=(n_targets, n)
        )
        self.dof = max(len(self.r) - identification.fitted_rank, 1)
        self.sigma2 = noise_variance(identification)

    def drop(self, columns: FloatArray) -> float:
        """The drop of the weighted residual sum of squares (σ²) that adding ``columns`` would
        bring, what the model absorbs projected out (:meth:`test`'s F·k)."""
        return self.test(columns)[0] * self.last_dimensions

    def test(self, columns: FloatArray) -> tuple[float, float, float, FloatArray]:
        """(F, log10 false-alarm probability, detectability, parameters) of candidate columns.

        F·k (k the columns' independent dimensions, :attr:`last_dimensions`) is the drop of the
        weighted residual sum of squares, in units of σ², that adding them would bring.

        The columns are projected onto what the current model cannot absorb (S = DᵀWD −
        DᵀWA·(AᵀWA)⁺·AᵀWD); columns it absorbs entirely (e.g. the rigid part of a cross-axis
        term, which a roll reproduces) carry no evidence and are left out.
        """
        d = np.atleast_2d(columns.T).T
        wd = d * self.w[:, None]
        agg = self.to_targets @ wd
        # set-up effects act on one line: multiply only the targets they touch
        touched = np.flatnonzero(np.any(agg != 0.0, axis=1))
        if touched.size < 0.25 * agg.shape[0]:
            target_part = self.system.target_design[touched].T @ agg[touched]
        else:
            target_part = self.system.target_design.T @ agg
        atwd = np.vstack([target_part, self.system.effect_design.T @ wd])
        least = USEFUL_SHARE_ONE_COLUMN if d.shape[1] == 1 else USEFUL_SHARE
        return self._f_test(d.T @ wd, atwd, d.T @ self.wr, least)

    def test_split(
        self, values: FloatArray, groups: NDArray[np.int64]
    ) -> tuple[float, float, FloatArray, FloatArray]:
        """Whether one fitted contribution ``values`` (per reading) has the same size in every
        group of readings (``groups``: a label per reading, e.g. the line or the run).

        The contribution split by group gives one column per group with a disjoint support, so
        DᵀWD is diagonal and the columns never need to be formed. Returns F, log10 false-alarm
        level, the relative change of size each group asks for (0 where the model absorbs the
        split) and each group's share of the contribution's weighted energy.
        """
        keys, inverse = np.unique(groups, return_inverse=True)
        n = len(values)
        wc = self.w * values
        d = sparse.csr_matrix((values, (np.arange(n), inverse)), shape=(n, keys.size))
        wd = sparse.csr_matrix((wc, (np.arange(n), inverse)), shape=(n, keys.size))
        agg = (self.to_targets @ wd).toarray()
        atwd = np.vstack(
            [self.system.target_design.T @ agg, np.asarray((wd.T @ self.system.effect_design).T)]
        )
        energy = np.bincount(inverse, weights=wc * values, minlength=keys.size)
        f, log_p, _, beta = self._f_test(
            np.diag(energy), atwd, np.asarray(d.T @ self.wr), USEFUL_SHARE
        )
        share = energy / max(float(energy.sum()), 1e-300)
        return f, log_p, beta, share

    def line_energy(self, values: FloatArray) -> FloatArray:
        """Per line: the weighted energy (in units of σ²) of a contribution that the current
        model cannot absorb — where it could be seen if this fit lacked it."""
        readings = self.ident.readings
        n = len(values)
        lines = len(readings.lines)
        wc = self.w * values
        wd = sparse.csr_matrix((wc, (np.arange(n), readings.line)), shape=(n, lines))
        agg = (self.to_targets @ wd).toarray()
        atwd = np.vstack(
            [self.system.target_design.T @ agg, np.asarray((wd.T @ self.system.effect_design).T)]
        )
        energy = np.bincount(readings.line, weights=wc * values, minlength=lines)
        absorbed = np.einsum("ij,ik,kj->j", atwd, self.ident.normal_inverse, atwd)
        return np.maximum(energy - absorbed, 0.0) / self.sigma2

    def _f_test(
        self, dtwd: FloatArray, atwd: FloatArray, dtwr: FloatArray, useful_share: float
    ) -> tuple[float, float, float, FloatArray]:
        """The projected F-test of candidate columns from DᵀWD, AᵀWD and DᵀWr; columns the model
        takes up but for ``useful_share`` of their energy are left out."""
        s = dtwd - atwd.T @ self.ident.normal_inverse @ atwd
        diag = np.diag(dtwd)
        share = np.where(diag > 0, np.diag(s) / np.where(diag > 0, diag, 1.0), 0.0)
        useful = share > useful_share
        beta = np.zeros(dtwd.shape[0])
        self.last_dimensions = 0
        if not useful.any():
            return 0.0, 0.0, 0.0, beta
        detect = float(np.min(share[useful]))
        values, vectors = np.linalg.eigh(s[np.ix_(useful, useful)])
        keep = values > 1e-9 * max(values.max(initial=0.0), 1e-300)
        k = int(keep.sum())
        self.last_dimensions = k
        if k == 0:
            return 0.0, 0.0, detect, beta
        proj = vectors[:, keep].T @ np.ravel(dtwr)[useful]
        delta = float(np.sum(proj**2 / values[keep]))
        beta[useful] = vectors[:, keep] @ (proj / values[keep])
        f_stat = (delta / k) / self.sigma2

        with np.errstate(divide="ignore"):
            log_p = float(np.log(special.fdtrc(k, self.dof, f_stat)))
            if not np.isfinite(log_p):
                # far in the tail: the χ² limit, then its leading exponential term
                log_p = float(np.log(special.chdtrc(k, f_stat * k)))
        if not np.isfinite(log_p):
            log_p = -0.5 * f_stat * k
        return float(f_stat), log_p / np.log(10.0), detect, beta

    def score(self, columns: FloatArray) -> float:
        """Cheap screening statistic: residual correlation ignoring the model's absorption."""
        d = columns.reshape(len(self.r), -1)
        g = d.T @ self.wr
        dtwd = np.einsum("ni,n,ni->i", d, self.w, d)
        return float(np.sum(g**2 / np.maximum(dtwd, 1e-300)) / self.sigma2)

    def target_sums(self, direction: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Per target: its position (T, 3), Σ w·r·p and Σ w·p² over its readings, with p what a
        unit error along ``direction`` moves the reading (0 for angular readings).

        Screening columns that are p times a function of the position only are then scored on
        the targets (a few thousand) instead of the readings (tens of thousands).
        """
        cache = self.__dict__.setdefault("_target_sums", {})
        if direction not in cache:
            readings = self.ident.readings
            p = readings.projection[:, direction] * ~readings.is_angular
            first = np.unique(self.system.target_of_reading, return_index=True)[1]
            cache[direction] = (
                readings.position_mm[first],
                self.to_targets @ (self.wr * p),
                self.to_targets @ (self.w * p * p),
            )
        return cache[direction]

    def score_on_targets(
        self, direction: int, shapes: FloatArray, targets: NDArray[np.bool_] | None = None
    ) -> FloatArray:
        """:meth:`score` of many single-shape candidates at once: ``shapes`` (T, m) holds the
        function of each candidate at every target (at the ``targets`` selected, if given: the
        others must not see the direction); returns m scores."""
        _, wrp, wpp = self.target_sums(direction)
        if targets is not None:
            wrp, wpp = wrp[targets], wpp[targets]
        g = shapes.T @ wrp
        dtwd = (shapes * shapes).T @ wpp
        return np.asarray(g**2 / np.maximum(dtwd, 1e-300) / self.sigma2)


def moving_axes(readings: Readings) -> dict[str, bool]:
    """Axes that move (with both approach directions) in at least one displacement line."""
    out = {}
    for axis in AXES:
        k = AXIS_INDEX[axis]
        moving = False
        for line in readings.lines:
            if line.spec.quantity == "angular":
                continue
            if (
                abs(line.spec.direction[k]) > 1e-6
                and len(set(line.data.run_direction.tolist())) > 1
            ):
                moving = True
        out[axis] = moving
    return out


def _where(readings: Readings, columns: FloatArray, beta: FloatArray) -> str:
    """The line where an effect's fitted contribution is largest."""
    contribution = np.abs(columns @ beta) if columns.ndim == 2 else np.abs(columns * beta[0])
    if not np.any(contribution > 0):
        return "nowhere"
    i = int(np.argmax(contribution))
    line = readings.lines[int(readings.line[i])]
    return f"line {line.name} at {readings.target_mm[i]:.1f} mm"


@dataclass
class Diagnosis:
    """What one diagnosis step collects."""

    tester: Tester
    readings: Readings
    model: ErrorModel
    excluded: set[EffectKey]
    findings: list[Finding] = field(default_factory=list)

    def add(
        self,
        effect: Effect,
        trials: int = 1,
        where: str | None = None,
        alias_mm: tuple[float, ...] = (),
    ) -> Finding | None:
        """Test one candidate (unless already kept) and keep it as a finding when the model
        cannot absorb it all."""
        if effect.key in self.excluded:
            return None
        columns = effect.design(self.readings, self.model)
        if not np.any(columns):
            return None
        f, log10_p, detect, beta = self.tester.test(columns)
        if detect <= 0.0:
            return None
        place = where if where is not None else _where(self.readings, columns, beta)
        finding = Finding(
            effect,
            f,
            corrected(log10_p, trials),
            trials,
            effect.magnitude_um(beta),
            detect,
            place,
            f * self.tester.last_dimensions,
            alias_mm,
        )
        self.findings.append(finding)
        return finding


def corrected(log10_p: float, trials: int) -> float:
    """Bonferroni in log10: min(1, p·trials)."""
    return min(0.0, log10_p + float(np.log10(max(trials, 1))))


def line_unit(spec: LineSpec) -> str:
    """The unit of a line's readings."""
    return "µrad" if spec.quantity == "angular" else "µm"


def log10_text(p: float) -> str:
    """log10 of a false-alarm level for a sentence; below what a double holds, said so."""
    return f"{np.log10(p):.0f}" if p >= 1e-300 else "below −300"


def cell_key(readings: Readings, index: int) -> NDArray[np.int64]:
    """Per reading of a line, its cell: the target and the approach direction."""
    mask = readings.line == index
    direction = readings.lines[index].data.run_direction[readings.run[mask]]
    return np.asarray(readings.target[mask] * 2 + (direction > 0), dtype=np.int64)


def exchange(readings: Readings) -> FloatArray:
    """Per reading, the factor that puts its residual on the displacement lines' scale: 1 for a
    displacement reading; for an angular one, the displacement lines' median repeatability over
    the angular lines' (1 where the plan has one quantity only). The loop's comparisons weigh a
    µrad on an angular line as the µm its noise is worth: what a drift or a surface settles on
    the angular lines counts as well as what it settles on the displacement lines."""
    angular = readings.is_angular
    out = np.ones(len(readings))
    if angular.any() and (~angular).any():
        out[angular] = np.median(readings.sigma[~angular]) / np.median(readings.sigma[angular])
    return out


def rms_over(residual: FloatArray, readings: Readings, rows: NDArray[np.bool_]) -> float:
    """RMS of ``residual`` over ``rows``, angular readings on the displacement scale."""
    scaled = residual[rows] * exchange(readings)[rows]
    return float(np.sqrt(np.mean(scaled**2))) if scaled.size else float("nan")


def fit_metric(identification: Identification, rows: NDArray[np.bool_]) -> float:
    """RMS of the fit's own residual over ``rows``, in displacement units (µm, or µrad for a
    plan of angular lines only)."""
    residual = identification.residual
    return rms_over(residual, identification.readings, rows & np.isfinite(residual))


def in_words(names: Sequence[str], word: str = "and") -> str:
    """Names joined in words: A; A and B; A, B and C (with ``word`` "or": A, B or C)."""
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} {word} {names[-1]}"
