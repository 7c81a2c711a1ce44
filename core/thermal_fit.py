"""Choose and fit a thermal error model honestly: sensors, lags and orders from the past only.

:func:`fit_thermal` takes a :class:`ThermalFitRequest` (a thermal measurement, the error channel,
:class:`ThermalFitOptions`) and returns a :class:`ThermalFitResult`. The record is split in time:
the first ``train_fraction`` of the samples is the *training* part, the rest the *test* part. Every
choice — which sensors, which time constants, which squared terms — is made on the training part
alone, by cross-validation that respects time; the test part is used once, at the end, for the
held-out error that the result reports.

Cross-validation is *rolling origin* (forward chaining; Tashman 2000, Hyndman & Athanasopoulos,
"Forecasting: principles and practice", §5.10): the training part is cut into ``blocks``
contiguous blocks; each fold fits on all the blocks before one block and predicts that block, for
the blocks that start after the first ``initial_fraction`` of the training part (a model fitted on
a few minutes of a warm-up says nothing about the hours after it, and early folds would only add
noise to the comparison). Never random rows: neighbouring samples of a thermal record are nearly
equal, and a random split would score an overfitted model as perfect.

The search, in order (each step keeps a change only if it lowers the cross-validated RMS by at
least ``min_improvement``, 2 % by default):

1. *Sensors.* For every number of sensors up to ``max_sensors`` the best subset of static linear
   terms (exhaustively when there are few enough subsets, else forward selection with swaps); the
   smallest subset whose CV error is within ``min_improvement`` of the best is chosen.
2. *Lags.* Where the static model leaves lag, a first-order time constant per chosen sensor
   (coordinate descent over a log grid from two sample intervals to a tenth of the training span
   — a time constant is only identified by a record many times longer than itself — then
   refined continuously) — kept only if the CV error drops.
3. *Order.* A squared term per chosen sensor, kept only if the CV error drops.

The baselines beside the chosen model: the error left uncompensated, a static least-squares fit on
every usable sensor, and the best single static sensor by the same cross-validation.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import combinations
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar

from .outliers import SeriesFlag, screen_series
from .progress import CancelToken, ProgressCallback, check, report
from .thermal import ThermalMeasurement
from .thermal_model import (
    UNIT_SYMBOL,
    ThermalModel,
    ThermalTerm,
    first_order_response,
    fit_model,
)
from .userror import UserError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: The longest time constant tried is the training span divided by this.
LONGEST_LAG_SPANS = 10.0
#: Fewest training samples a model is chosen from.
MIN_TRAINING_SAMPLES = 20


@dataclass(frozen=True)
class ThermalFitOptions:
    """How a thermal model is chosen (module notes).

    ``time_constants_s`` None builds the lag grid from the record (two sample intervals to a
    tenth of the training span, 12 steps); ``sensors`` None offers every usable sensor.
    """

    train_fraction: float = 0.5
    max_sensors: int = 6
    blocks: int = 10
    initial_fraction: float = 0.5
    dynamic: bool = True
    quadratic: bool = True
    prune: bool = True
    min_improvement: float = 0.02
    time_constants_s: tuple[float, ...] | None = None
    sensors: tuple[str, ...] | None = None
    #: at most this many subsets are scored exhaustively; beyond, forward selection with swaps
    exhaustive_limit: int = 60_000

    def __post_init__(self) -> None:
        if not 0 < self.train_fraction <= 1:
            raise UserError("the training fraction must be in (0, 1]")
        if self.max_sensors < 1:
            raise UserError("max_sensors must be at least 1")
        if self.blocks < 3:
            raise UserError("cross-validation needs at least 3 blocks")
        if not 0 < self.initial_fraction < 1:
            raise UserError("the initial window must be a fraction in (0, 1)")
        if self.min_improvement < 0:
            raise UserError("min_improvement cannot be negative")


@dataclass(frozen=True)
class ThermalFitRequest:
    """A thermal model to choose and fit for one error channel (None: the only one)."""

    measurement: ThermalMeasurement
    channel: str | None = None
    options: ThermalFitOptions = field(default_factory=ThermalFitOptions)


@dataclass(frozen=True)
class SubsetScore:
    """The best set of ``size`` static sensors and its cross-validated RMS."""

    sensors: tuple[str, ...]
    cv_rms: float


@dataclass(frozen=True)
class Baseline:
    """A reference model fitted on the same training part, scored the same way."""

    name: str
    sensors: tuple[str, ...]
    train_rms: float
    cv_rms: float | None
    test_rms: float | None


@dataclass(frozen=True, eq=False)
class ThermalFitResult:
    """The chosen model, how it was chosen, and how well it predicts the held-out part."""

    measurement: str
    channel: str
    unit: str
    model: ThermalModel
    options: ThermalFitOptions
    train_samples: int
    test_samples: int
    split_time_s: float
    cv_description: str
    cv_rms: float
    train_rms: float
    test_rms: float | None
    test_max_abs: float | None
    uncompensated_test_rms: float | None
    static_cv_rms: float
    subsets: tuple[SubsetScore, ...]
    decisions: tuple[str, ...]
    baselines: tuple[Baseline, ...]
    time_s: FloatArray = field(repr=False)
    measured: FloatArray = field(repr=False)
    predicted: FloatArray = field(repr=False)
    #: per term, the standard deviation over the record of its contribution c·(F − R)^p, in
    #: the channel's unit: how much of the error the term carries (the view's sensor weights)
    term_spread: tuple[float, ...] = ()
    outliers: tuple[SeriesFlag, ...] = ()
    warnings: tuple[str, ...] = ()
    elapsed_s: float = 0.0

    @property
    def residual(self) -> FloatArray:
        """measured − predicted, what is left after compensation."""
        return self.measured - self.predicted

    @property
    def symbol(self) -> str:
        return UNIT_SYMBOL.get(self.unit, self.unit)

    def to_json(self) -> dict[str, Any]:
        """Everything but the series (see :meth:`series_json`)."""
        return {
            "measurement": self.measurement,
            "channel": self.channel,
            "unit": self.unit,
            "sign_convention": "error = measured − nominal (as in the file, after its sign); "
            "a compensation applies −error",
            "model": self.model.to_json(),
            "sensors": list(self.model.sensors),
            "dynamic": self.model.dynamic,
            "train_samples": self.train_samples,
            "test_samples": self.test_samples,
            "train_fraction": self.options.train_fraction,
            "split_time_s": self.split_time_s,
            "cross_validation": self.cv_description,
            f"cv_rms_{self.unit}": self.cv_rms,
            f"static_cv_rms_{self.unit}": self.static_cv_rms,
            f"train_rms_{self.unit}": self.train_rms,
            f"test_rms_{self.unit}": self.test_rms,
            f"test_max_abs_{self.unit}": self.test_max_abs,
            f"uncompensated_test_rms_{self.unit}": self.uncompensated_test_rms,
            "subsets": [
                {
                    "size": len(s.sensors),
                    "sensors": list(s.sensors),
                    f"cv_rms_{self.unit}": s.cv_rms,
                }
                for s in self.subsets
            ],
            "decisions": list(self.decisions),
            "weights": [
                {
                    "term": t.label(),
                    "sensor": t.sensor,
                    "coefficient": float(c),
                    f"spread_{self.unit}": w,
                }
                for t, c, w in zip(
                    self.model.terms, self.model.coefficients, self.term_spread, strict=True
                )
            ],
            "baselines": [
                {
                    "name": b.name,
                    "sensors": list(b.sensors),
                    f"train_rms_{self.unit}": b.train_rms,
                    f"cv_rms_{self.unit}": b.cv_rms,
                    f"test_rms_{self.unit}": b.test_rms,
                }
                for b in self.baselines
            ],
            "outliers": [f.to_json() for f in self.outliers],
            "warnings": list(self.warnings),
            "elapsed_s": self.elapsed_s,
            "options": {
                "max_sensors": self.options.max_sensors,
                "blocks": self.options.blocks,
                "initial_fraction": self.options.initial_fraction,
                "dynamic": self.options.dynamic,
                "quadratic": self.options.quadratic,
                "min_improvement": self.options.min_improvement,
            },
        }


# --------------------------------------------------------------------------------------------
# Cross-validation that respects time
# --------------------------------------------------------------------------------------------


def rolling_origin_folds(
    samples: int, blocks: int = 10, initial_fraction: float = 0.5
) -> list[tuple[IntArray, IntArray]]:
    """(fit rows, validation rows) per fold: contiguous blocks, each predicted from all the rows
    before it, for the blocks that start at or after ``initial_fraction`` of the samples."""
    edges = np.linspace(0, samples, blocks + 1).round().astype(np.int64)
    folds = []
    for j in range(1, blocks):
        if edges[j] < initial_fraction * samples - 1e-9:
            continue
        folds.append((np.arange(0, edges[j]), np.arange(edges[j], edges[j + 1])))
    return folds


class _Scorer:
    """Cross-validated RMS of linear models on the training rows, from per-fold Gram matrices
    (so that thousands of sensor subsets cost little)."""

    def __init__(
        self, features: FloatArray, y: FloatArray, folds: list[tuple[IntArray, IntArray]]
    ) -> None:
        self.mean = features.mean(axis=0)
        scale = features.std(axis=0)
        self.scale = np.where(scale > 0, scale, 1.0)
        x = np.column_stack([np.ones(len(y)), (features - self.mean) / self.scale])
        self.folds = folds
        self.count = sum(v.size for _, v in folds)
        self.fit_gram = np.stack([x[f].T @ x[f] for f, _ in folds])
        self.fit_rhs = np.stack([x[f].T @ y[f] for f, _ in folds])
        self.val_gram = np.stack([x[v].T @ x[v] for _, v in folds])
        self.val_rhs = np.stack([x[v].T @ y[v] for _, v in folds])
        self.val_yy = np.array([y[v] @ y[v] for _, v in folds])
        # a whisker of ridge keeps exactly collinear sensors from making a fold singular
        self.ridge = 1e-10 * np.array([f.size for f, _ in folds])

    def rms(self, subsets: IntArray) -> FloatArray:
        """CV RMS of each row of ``subsets`` (feature indexes, 0-based; the constant is added)."""
        subsets = np.atleast_2d(subsets)
        index = np.column_stack([np.zeros(len(subsets), dtype=np.int64), subsets + 1])
        sse = np.zeros(len(subsets))
        eye = np.eye(index.shape[1])
        for k in range(len(self.folds)):
            a = self.fit_gram[k][index[:, :, None], index[:, None, :]] + self.ridge[k] * eye
            b = self.fit_rhs[k][index]
            c = np.linalg.solve(a, b[..., None])[..., 0]
            gv = self.val_gram[k][index[:, :, None], index[:, None, :]]
            sse += (
                self.val_yy[k]
                - 2 * np.einsum("ij,ij->i", c, self.val_rhs[k][index])
                + np.einsum("ij,ijk,ik->i", c, gv, c)
            )
        return np.sqrt(np.maximum(sse, 0.0) / self.count)


def cv_rms(features: FloatArray, y: FloatArray, folds: list[tuple[IntArray, IntArray]]) -> float:
    """CV RMS of one linear model (a constant plus the feature columns)."""
    if features.shape[1] == 0:
        sse = sum(float(np.sum((y[v] - y[f].mean()) ** 2)) for f, v in folds)
        return math.sqrt(sse / sum(v.size for _, v in folds))
    scorer = _Scorer(features, y, folds)
    return float(scorer.rms(np.arange(features.shape[1])[None, :])[0])


# --------------------------------------------------------------------------------------------
# The search
# --------------------------------------------------------------------------------------------


def best_subsets(
    scorer: _Scorer,
    candidates: int,
    max_size: int,
    exhaustive_limit: int,
    cancel: CancelToken | None = None,
) -> list[tuple[tuple[int, ...], float]]:
    """The best subset of each size 1…max_size and its CV RMS."""
    sizes = range(1, min(max_size, candidates) + 1)
    total = sum(math.comb(candidates, k) for k in sizes)
    out: list[tuple[tuple[int, ...], float]] = []
    if total <= exhaustive_limit:
        for k in sizes:
            check(cancel)
            subsets = np.array(list(combinations(range(candidates), k)), dtype=np.int64)
            scores = np.concatenate(
                [
                    scorer.rms(chunk)
                    for chunk in np.array_split(subsets, max(1, len(subsets) // 4000))
                ]
            )
            top = int(np.argmin(scores))
            out.append((tuple(int(i) for i in subsets[top]), float(scores[top])))
        return out
    chosen: list[int] = []
    for _k in sizes:
        check(cancel)
        others = [i for i in range(candidates) if i not in chosen]
        trial = np.array([[*chosen, i] for i in others], dtype=np.int64)
        scores = scorer.rms(trial)
        chosen.append(others[int(np.argmin(scores))])
        best = float(scores.min())
        improved = True
        while improved:  # swap members out while that helps (Miller 2002, "sequential replacement")
            improved = False
            for position in range(len(chosen)):
                rest = [i for i in range(candidates) if i not in chosen]
                if not rest:
                    break
                trial = np.array(
                    [chosen[:position] + [i] + chosen[position + 1 :] for i in rest], dtype=np.int64
                )
                scores = scorer.rms(trial)
                if scores.min() < best * (1 - 1e-9):
                    best = float(scores.min())
                    chosen[position] = rest[int(np.argmin(scores))]
                    improved = True
        out.append((tuple(chosen), best))
    return out


def default_time_constants(
    time_s: FloatArray, train_rows: int, steps: int = 12
) -> tuple[float, ...]:
    """A log grid from two sample intervals to a tenth of the training span: a time constant is
    identified from a record several times longer than itself (10 τ here), a longer one only
    reshapes the slow trend of the training part and extrapolates badly."""
    interval = float(np.median(np.diff(time_s)))
    span = float(time_s[train_rows - 1] - time_s[0])
    low, high = 2 * interval, max(span / LONGEST_LAG_SPANS, 4 * interval)
    return tuple(float(v) for v in np.geomspace(low, high, steps))


class _Features:
    """Lagged and squared sensor columns on demand, cached."""

    def __init__(
        self, time_s: FloatArray, temperatures: dict[str, FloatArray], train: slice
    ) -> None:
        self.time_s = time_s
        self.temperatures = temperatures
        self.train = train
        self._cache: dict[tuple[str, float], FloatArray] = {}

    def lagged(self, sensor: str, tau_s: float) -> FloatArray:
        key = (sensor, round(tau_s, 9))
        if key not in self._cache:
            self._cache[key] = first_order_response(self.time_s, self.temperatures[sensor], tau_s)
        return self._cache[key]

    def matrix(self, terms: Sequence[ThermalTerm]) -> FloatArray:
        columns = []
        for term in terms:
            lagged = self.lagged(term.sensor, term.tau_s)
            centre = lagged[self.train].mean()
            columns.append((lagged - centre) ** term.power)
        return np.column_stack(columns) if columns else np.empty((self.time_s.size, 0))


def fit_thermal(
    request: ThermalFitRequest,
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
) -> ThermalFitResult:
    """Choose, fit and validate a thermal error model (module notes)."""
    started = time.perf_counter()
    options = request.options
    measurement = request.measurement
    channel = measurement.error(request.channel)
    y = channel.values
    n = measurement.samples
    train_n = n if options.train_fraction >= 1 else int(round(options.train_fraction * n))
    if train_n < MIN_TRAINING_SAMPLES:
        raise UserError(
            f"{measurement.name}: {train_n} training samples are too few to choose a "
            f"model (at least {MIN_TRAINING_SAMPLES}); use a longer record or a larger "
            "training fraction"
        )
    train = slice(0, train_n)
    test = slice(train_n, n)
    temperatures = measurement.temperature_map()
    sensors = list(options.sensors) if options.sensors is not None else list(temperatures)
    unknown = [s for s in sensors if s not in temperatures]
    if unknown:
        excluded = {e.name for e in measurement.excluded}
        why = [f"{s!r} (excluded: stuck)" if s in excluded else repr(s) for s in unknown]
        raise UserError(
            f"{measurement.name}: no usable temperature sensor {', '.join(why)}; "
            f"usable: {', '.join(temperatures) or 'none'}"
        )
    if not sensors:
        raise UserError(
            f"{measurement.name}: no usable temperature sensor to model {channel.name!r} with"
        )
    folds = rolling_origin_folds(train_n, options.blocks, options.initial_fraction)
    if not folds or min(f.size for f, _ in folds) <= options.max_sensors + 2:
        raise UserError(
            f"{measurement.name}: the training part ({train_n} samples) is too short "
            f"for {options.blocks}-block cross-validation with up to "
            f"{options.max_sensors} sensors"
        )
    first_val = int(folds[0][1][0])
    cv_text = (
        f"rolling origin over the training part: {options.blocks} contiguous blocks, each "
        f"of the last {len(folds)} predicted from all samples before it (validation from "
        f"sample {first_val + 1} of {train_n}); never random rows"
    )
    features = _Features(measurement.time_s, temperatures, train)
    y_train = y[train]
    decisions: list[str] = []
    unit = channel.unit
    sym = UNIT_SYMBOL[unit]

    # 1. sensors (static, linear)
    report(progress, 0.05, "choosing sensors")
    static = np.column_stack([temperatures[s][train] for s in sensors])
    scorer = _Scorer(static, y_train, folds)
    ranked = best_subsets(
        scorer, len(sensors), options.max_sensors, options.exhaustive_limit, cancel
    )
    subsets = tuple(SubsetScore(tuple(sensors[i] for i in idx), score) for idx, score in ranked)
    best_score = min(s.cv_rms for s in subsets)
    chosen = next(s for s in subsets if s.cv_rms <= best_score * (1 + options.min_improvement))
    decisions.append(
        f"sensors: {len(chosen.sensors)} ({', '.join(chosen.sensors)}), CV RMS "
        f"{chosen.cv_rms:.3f} {sym}; the best of each size: "
        + ", ".join(f"{len(s.sensors)}: {s.cv_rms:.3f}" for s in subsets)
    )
    terms = [ThermalTerm(s) for s in chosen.sensors]
    static_cv = chosen.cv_rms
    current = static_cv

    def score(candidate: Sequence[ThermalTerm]) -> float:
        return cv_rms(features.matrix(candidate)[train], y_train, folds)

    # 2. lags
    if options.dynamic:
        report(progress, 0.4, "fitting time constants")
        grid = options.time_constants_s or default_time_constants(measurement.time_s, train_n)
        lagged_terms, lagged_cv = _search_lags(terms, grid, score, cancel)
        if lagged_cv <= current * (1 - options.min_improvement):
            decisions.append(
                f"lags: kept ({', '.join(t.label() for t in lagged_terms if t.dynamic)}), CV RMS "
                f"{current:.3f} → {lagged_cv:.3f} {sym}"
            )
            terms, current = lagged_terms, lagged_cv
        else:
            decisions.append(
                f"lags: not kept, the static model leaves no lag they remove (best CV RMS "
                f"{lagged_cv:.3f} {sym} against {current:.3f} {sym} static)"
            )

    # parsimony: a term whose removal costs less than min_improvement goes (the static sensor
    # choice may have taken an extra sensor to stand in for a lag the lags now model)
    if options.prune and len(terms) > 1:
        best_cv = current
        while len(terms) > 1:
            check(cancel)
            trials = [(score(terms[:i] + terms[i + 1 :]), i) for i in range(len(terms))]
            value, index = min(trials)
            if value > best_cv * (1 + options.min_improvement):
                break
            decisions.append(
                f"term {terms[index].label()}: removed, CV RMS {current:.3f} → "
                f"{value:.3f} {sym} without it"
            )
            terms = terms[:index] + terms[index + 1 :]
            current = value
            best_cv = min(best_cv, value)

    # 3. squared terms
    if options.quadratic:
        report(progress, 0.75, "trying squared terms")
        for sensor_term in list(terms):
            check(cancel)
            if sensor_term.power != 1:
                continue
            trial = [*terms, ThermalTerm(sensor_term.sensor, sensor_term.tau_s, 2)]
            trial_cv = score(trial)
            if trial_cv <= current * (1 - options.min_improvement):
                decisions.append(
                    f"squared term {trial[-1].label()}: kept, CV RMS {current:.3f} "
                    f"→ {trial_cv:.3f} {sym}"
                )
                terms, current = trial, trial_cv
        if not any(t.power == 2 for t in terms):
            decisions.append(
                f"squared terms: none lowers the CV error by {100 * options.min_improvement:g} %"
            )

    report(progress, 0.9, "fitting and validating")
    time_s = measurement.time_s
    model = fit_model(channel.name, unit, time_s, y, temperatures, terms, train)
    design = model.design(time_s, temperatures)
    predicted = design @ np.concatenate([[model.intercept], model.coefficients])
    spread = tuple(float(np.std(design[:, k + 1] * c)) for k, c in enumerate(model.coefficients))
    residual = y - predicted
    train_rms = _rms(residual[train])
    test_rms = _rms(residual[test]) if train_n < n else None
    test_max = float(np.max(np.abs(residual[test]))) if train_n < n else None
    uncompensated = _rms(y[test]) if train_n < n else None
    baselines = _baselines(
        measurement, channel.name, y, sensors, train, test, folds, scorer, subsets, train_n < n
    )
    outliers = tuple(screen_series(time_s, y, name=channel.name, unit=unit))
    report(progress, 1.0, "done")
    return ThermalFitResult(
        measurement=measurement.name,
        channel=channel.name,
        unit=unit,
        model=model,
        options=options,
        train_samples=train_n,
        test_samples=n - train_n,
        split_time_s=float(time_s[train_n - 1]),
        cv_description=cv_text,
        cv_rms=current,
        train_rms=train_rms,
        test_rms=test_rms,
        test_max_abs=test_max,
        uncompensated_test_rms=uncompensated,
        static_cv_rms=static_cv,
        subsets=subsets,
        decisions=tuple(decisions),
        baselines=baselines,
        time_s=time_s,
        measured=y,
        predicted=predicted,
        term_spread=spread,
        outliers=outliers,
        warnings=measurement.warnings,
        elapsed_s=time.perf_counter() - started,
    )


def _search_lags(
    terms: list[ThermalTerm], grid: Sequence[float], score: Any, cancel: CancelToken | None
) -> tuple[list[ThermalTerm], float]:
    """Coordinate descent on each term's τ over {0} ∪ grid, twice round, then a continuous
    refinement of each non-zero τ in log τ between its grid neighbours."""
    taus = [0.0, *sorted(grid)]
    current = list(terms)
    best = score(current)
    for _ in range(2):
        changed = False
        for i, term in enumerate(current):
            check(cancel)
            for tau in taus:
                if tau == term.tau_s:
                    continue
                trial = current[:i] + [ThermalTerm(term.sensor, tau)] + current[i + 1 :]
                value = score(trial)
                if value < best * (1 - 1e-6):
                    best, current, term, changed = value, trial, trial[i], True
        if not changed:
            break
    positive = sorted(grid)
    for i, term in enumerate(current):
        if not term.dynamic:
            continue
        check(cancel)
        k = int(np.argmin(np.abs(np.log(positive) - math.log(term.tau_s))))
        low = math.log(positive[max(k - 1, 0)])
        high = math.log(positive[min(k + 1, len(positive) - 1)])
        if high <= low:
            continue

        def objective(log_tau: float, i: int = i, base: list[ThermalTerm] = current) -> float:
            trial = base[:i] + [ThermalTerm(base[i].sensor, math.exp(log_tau))] + base[i + 1 :]
            return float(score(trial))

        found = minimize_scalar(
            objective, bounds=(low, high), method="bounded", options={"xatol": 0.02}
        )
        if found.fun < best:
            best = float(found.fun)
            current = (
                current[:i]
                + [ThermalTerm(term.sensor, float(math.exp(found.x)))]
                + current[i + 1 :]
            )
    return current, best


def _baselines(
    measurement: ThermalMeasurement,
    channel: str,
    y: FloatArray,
    sensors: list[str],
    train: slice,
    test: slice,
    folds: list[tuple[IntArray, IntArray]],
    scorer: _Scorer,
    subsets: tuple[SubsetScore, ...],
    has_test: bool,
) -> tuple[Baseline, ...]:
    time_s = measurement.time_s
    temperatures = measurement.temperature_map()
    out = [Baseline("uncompensated", (), _rms(y[train]), None, _rms(y[test]) if has_test else None)]
    everything = fit_model(
        channel,
        "um",
        time_s,
        y,
        temperatures,
        [ThermalTerm(s) for s in sensors],
        train,
        covariance=False,
    )
    residual = y - everything.predict(time_s, temperatures)
    out.append(
        Baseline(
            "all sensors, static least squares",
            tuple(sensors),
            _rms(residual[train]),
            float(scorer.rms(np.arange(len(sensors))[None, :])[0]),
            _rms(residual[test]) if has_test else None,
        )
    )
    single = subsets[0].sensors
    one = fit_model(
        channel, "um", time_s, y, temperatures, [ThermalTerm(single[0])], train, covariance=False
    )
    residual = y - one.predict(time_s, temperatures)
    out.append(
        Baseline(
            "best single sensor by cross-validation",
            single,
            _rms(residual[train]),
            subsets[0].cv_rms,
            _rms(residual[test]) if has_test else None,
        )
    )
    return tuple(out)


def _rms(values: FloatArray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else math.nan
