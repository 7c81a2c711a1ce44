"""Thermal error models a controller can evaluate: a constant plus a few terms in temperatures.

A model predicts an error channel e(t) (µm or µrad) from temperature sensors::

    e(t) = c0 + Σ_i c_i · (F_i(t) − R_i)^p_i

where F_i is sensor i's temperature seen through a first-order lag of time constant τ_i
(τ_i = 0: the temperature itself, a *static* term), R_i a reference temperature the term is
centred on (the mean of F_i over the data it was fitted on, so that c0 is the error at the
typical state and the coefficients are well conditioned), and p_i = 1 (linear) or 2 (quadratic).
The lag is the continuous-time filter dF/dt = (T − F)/τ started at equilibrium, F(t0) = T(t0):
the response of a body that follows the sensor's temperature with one time constant — the
"first-order dynamic model" of thermal-error practice, and exactly what LinuxCNC's ``lowpass``
component computes (``gain = 1 − exp(−period/τ)``). It is discretised exactly for a temperature
that varies linearly between samples (first-order hold), so irregular sampling is handled.

The coefficients are fitted by least squares. Their uncertainty is heteroskedasticity- and
autocorrelation-consistent (Newey & West 1987, Bartlett kernel, bandwidth by Andrews' 1991 AR(1)
plug-in): the residuals of a thermal fit are strongly autocorrelated from one sample to the next,
and the ordinary least-squares standard errors would be many times too small.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from .userror import UserError

FloatArray = NDArray[np.float64]
UNIT_SYMBOL = {"um": "µm", "urad": "µrad"}


# --------------------------------------------------------------------------------------------
# The first-order lag
# --------------------------------------------------------------------------------------------


def first_order_response(time_s: FloatArray, values: FloatArray, tau_s: float) -> FloatArray:
    """``values`` (samples, or samples × columns) seen through dF/dt = (T − F)/τ, F(t0) = T(t0).

    τ = 0 returns the values unchanged. Exact for a T that is linear between samples; uniform
    sampling runs as one recursive filter, irregular sampling step by step.
    """
    x = np.asarray(values, dtype=float)
    if tau_s < 0 or not math.isfinite(tau_s):
        raise ValueError(f"time constant {tau_s!r} s: must be zero or positive")
    if tau_s == 0 or x.shape[0] < 2:
        return x.copy()
    t = np.asarray(time_s, dtype=float)
    h = np.diff(t)
    if np.allclose(h, h[0], rtol=1e-9, atol=0.0):
        a, b_new, b_old = _hold_weights(np.array([h[0] / tau_s]))
        start = x[:1]
        return lfilter([b_new[0], b_old[0]], [1.0, -a[0]], x - start, axis=0) + start
    a_k, new_k, old_k = _hold_weights(h / tau_s)
    out = np.empty_like(x)
    out[0] = x[0]
    for k in range(h.size):
        out[k + 1] = a_k[k] * out[k] + new_k[k] * x[k + 1] + old_k[k] * x[k]
    return out


def _hold_weights(x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Weights of F(k+1) = a·F(k) + b_new·T(k+1) + b_old·T(k) for steps x = h/τ.

    a = e^(−x); b_new = 1 − (1 − a)/x; b_old = (1 − a) − b_new. Written with expm1 and, for
    small x, the series of b_new = x/2 − x²/6 + x³/24 − …, so that a step much shorter than τ
    (a controller's millisecond against minutes) loses no digits to cancellation.
    """
    one_minus_a = -np.expm1(-x)
    with np.errstate(all="ignore"):
        direct = (x + np.expm1(-x)) / x
    series = x * (0.5 - x * (1 / 6 - x * (1 / 24 - x * (1 / 120 - x / 720))))
    b_new = np.where(x < 1e-2, series, direct)
    return 1.0 - one_minus_a, b_new, one_minus_a - b_new


# --------------------------------------------------------------------------------------------
# Terms and models
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ThermalTerm:
    """One term (F − R)^p of a model: a sensor, its lag τ (0 static), power p and centre R."""

    sensor: str
    tau_s: float = 0.0
    power: int = 1
    reference_c: float = 0.0

    def __post_init__(self) -> None:
        if self.power not in (1, 2):
            raise ValueError(f"term {self.sensor}: power must be 1 or 2, got {self.power}")
        if not (self.tau_s >= 0 and math.isfinite(self.tau_s)):
            raise ValueError(f"term {self.sensor}: time constant must be ≥ 0 s")

    @property
    def dynamic(self) -> bool:
        return self.tau_s > 0

    def label(self) -> str:
        """``T13``, ``T13 lag 20 min``, ``(T13 − 31.2 °C)²``… for tables and plots."""
        base = self.sensor if not self.dynamic else f"{self.sensor} lag {_duration(self.tau_s)}"
        return base if self.power == 1 else f"({base})²"

    def unit(self, error_unit: str) -> str:
        """Unit of the term's coefficient, e.g. ``µm/°C`` or ``µm/°C²``."""
        per = "°C" if self.power == 1 else "°C²"
        return f"{UNIT_SYMBOL.get(error_unit, error_unit)}/{per}"

    def lagged(self, time_s: FloatArray, temperature_c: FloatArray) -> FloatArray:
        return first_order_response(time_s, temperature_c, self.tau_s)

    def values(self, time_s: FloatArray, temperature_c: FloatArray) -> FloatArray:
        return (self.lagged(time_s, temperature_c) - self.reference_c) ** self.power

    def to_json(self) -> dict[str, Any]:
        return {
            "sensor": self.sensor,
            "tau_s": self.tau_s,
            "power": self.power,
            "reference_c": self.reference_c,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ThermalTerm:
        return cls(
            str(data["sensor"]),
            float(data["tau_s"]),
            int(data["power"]),
            float(data["reference_c"]),
        )


def _duration(seconds: float) -> str:
    if seconds >= 7200:
        return f"{seconds / 3600:.3g} h"
    if seconds >= 120:
        return f"{seconds / 60:.3g} min"
    return f"{seconds:.3g} s"


@dataclass(frozen=True, eq=False)
class ThermalModel:
    """e = c0 + Σ c_i (F_i − R_i)^p_i (module notes), fitted; ``covariance`` is over
    (c0, c_1 … c_n), Newey–West. Sign: e is the error channel as measured (measured − nominal);
    a compensation applies −e."""

    channel: str
    unit: str
    intercept: float
    terms: tuple[ThermalTerm, ...]
    coefficients: FloatArray
    covariance: FloatArray = field(repr=False)

    @property
    def sensors(self) -> tuple[str, ...]:
        """The sensors the model reads, in the order of their first term."""
        seen: list[str] = []
        for term in self.terms:
            if term.sensor not in seen:
                seen.append(term.sensor)
        return tuple(seen)

    @property
    def intercept_std(self) -> float:
        return float(math.sqrt(max(self.covariance[0, 0], 0.0)))

    @property
    def coefficient_std(self) -> FloatArray:
        return np.sqrt(np.clip(np.diag(self.covariance)[1:], 0.0, None))

    @property
    def dynamic(self) -> bool:
        return any(t.dynamic for t in self.terms)

    def design(self, time_s: FloatArray, temperatures: Mapping[str, FloatArray]) -> FloatArray:
        """(samples, 1 + terms): a column of ones, then each term's values."""
        time = np.asarray(time_s, dtype=float)
        columns = [np.ones(time.size)]
        for term in self.terms:
            if term.sensor not in temperatures:
                raise UserError(
                    f"the model of {self.channel!r} reads sensor {term.sensor!r}, "
                    "which the data do not have"
                )
            columns.append(term.values(time, np.asarray(temperatures[term.sensor], float)))
        return np.column_stack(columns)

    def predict(self, time_s: FloatArray, temperatures: Mapping[str, FloatArray]) -> FloatArray:
        """The predicted error over a record (the lags run from its first sample)."""
        design = self.design(time_s, temperatures)
        return design @ np.concatenate([[self.intercept], self.coefficients])

    def predict_steady(self, temperatures_c: Mapping[str, float]) -> float:
        """The error once every sensor has held the given temperature long enough for the lags
        to settle (F = T): what a controller outputs at constant temperatures."""
        total = self.intercept
        for term, c in zip(self.terms, self.coefficients, strict=True):
            total += c * (float(temperatures_c[term.sensor]) - term.reference_c) ** term.power
        return float(total)

    def formula(self, digits: int = 4) -> str:
        """The model as one line, e.g. ``e [µm] = 1.2 + 0.45·(T13 − 31.2) − 0.8·(F(T14, τ=20
        min) − 20.1)``."""
        unit = UNIT_SYMBOL.get(self.unit, self.unit)
        parts = [f"{self.intercept:.{digits}g}"]
        for term, c in zip(self.terms, self.coefficients, strict=True):
            sign = "−" if c < 0 else "+"
            signal = (
                term.sensor
                if not term.dynamic
                else (f"F({term.sensor}, τ={_duration(term.tau_s)})")
            )
            inner = f"({signal} − {term.reference_c:.{digits}g})"
            power = "²" if term.power == 2 else ""
            parts.append(f"{sign} {abs(c):.{digits}g}·{inner}{power}")
        return f"{self.channel} [{unit}] = " + " ".join(parts)

    def to_json(self) -> dict[str, Any]:
        return {
            "channel": self.channel,
            "unit": self.unit,
            "intercept": self.intercept,
            "intercept_std": self.intercept_std,
            "terms": [
                {
                    **t.to_json(),
                    "label": t.label(),
                    "coefficient": float(c),
                    "coefficient_std": float(s),
                    "coefficient_unit": t.unit(self.unit),
                }
                for t, c, s in zip(self.terms, self.coefficients, self.coefficient_std, strict=True)
            ],
            "covariance": self.covariance.tolist(),
            "sensors": list(self.sensors),
            "formula": self.formula(),
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ThermalModel:
        terms = tuple(ThermalTerm.from_json(t) for t in data["terms"])
        return cls(
            channel=str(data["channel"]),
            unit=str(data["unit"]),
            intercept=float(data["intercept"]),
            terms=terms,
            coefficients=np.array([float(t["coefficient"]) for t in data["terms"]]),
            covariance=np.asarray(data["covariance"], dtype=float).reshape(
                len(terms) + 1, len(terms) + 1
            ),
        )


# --------------------------------------------------------------------------------------------
# Fitting
# --------------------------------------------------------------------------------------------


def centred_terms(
    time_s: FloatArray,
    temperatures: Mapping[str, FloatArray],
    terms: Sequence[ThermalTerm],
    rows: NDArray[np.int64] | slice,
) -> tuple[ThermalTerm, ...]:
    """The terms with each reference R set to the mean of its lagged sensor over ``rows``."""
    out = []
    for term in terms:
        lagged = first_order_response(
            time_s, np.asarray(temperatures[term.sensor], float), term.tau_s
        )
        out.append(ThermalTerm(term.sensor, term.tau_s, term.power, float(np.mean(lagged[rows]))))
    return tuple(out)


def fit_model(
    channel: str,
    unit: str,
    time_s: FloatArray,
    error: FloatArray,
    temperatures: Mapping[str, FloatArray],
    terms: Sequence[ThermalTerm],
    rows: NDArray[np.int64] | slice = slice(None),
    covariance: bool = True,
) -> ThermalModel:
    """Least-squares fit of the terms to ``error`` over ``rows`` (the lags run over the whole
    record from its first sample, as they would in the controller), Newey–West covariance
    (NaN when ``covariance`` is False: a baseline that only needs its predictions)."""
    centred = centred_terms(time_s, temperatures, terms, rows)
    shell = ThermalModel(
        channel, unit, 0.0, centred, np.zeros(len(centred)), np.zeros((len(centred) + 1,) * 2)
    )
    design = shell.design(time_s, temperatures)[rows]
    y = np.asarray(error, dtype=float)[rows]
    if design.shape[0] <= design.shape[1]:
        raise UserError(
            f"{channel}: {design.shape[0]} samples cannot fit {design.shape[1]} "
            "parameters; use fewer sensors or more data"
        )
    solution, *_ = np.linalg.lstsq(design, y, rcond=None)
    residual = y - design @ solution
    cov = (
        newey_west_covariance(design, residual)
        if covariance
        else np.full((design.shape[1],) * 2, np.nan)
    )
    return ThermalModel(channel, unit, float(solution[0]), centred, solution[1:].copy(), cov)


def newey_west_bandwidth(residual: FloatArray) -> int:
    """Andrews' (1991) AR(1) plug-in lag for the Bartlett kernel, at most n − 1."""
    n = residual.size
    e = residual - residual.mean()
    denominator = float(e[:-1] @ e[:-1])
    rho = float(e[1:] @ e[:-1]) / denominator if denominator > 0 else 0.0
    rho = min(max(rho, -0.999), 0.999)
    alpha = 4 * rho**2 / ((1 - rho) ** 2 * (1 + rho) ** 2)
    return int(min(n - 1, math.ceil(1.1447 * (alpha * n) ** (1 / 3))))


def newey_west_covariance(
    design: FloatArray, residual: FloatArray, lags: int | None = None
) -> FloatArray:
    """(XᵀX)⁻¹ S (XᵀX)⁻¹ with S the Bartlett-weighted sum of the score autocovariances."""
    n, p = design.shape
    lag = newey_west_bandwidth(residual) if lags is None else lags
    score = design * residual[:, None]
    # all lagged cross-products Γ_k[i, j] = Σ_t u_i(t + k) u_j(t) at once, by FFT
    size = 1 << int(math.ceil(math.log2(2 * n)))
    spectrum = np.fft.rfft(score, size, axis=0)
    cross = np.fft.irfft(spectrum[:, :, None] * np.conj(spectrum[:, None, :]), size, axis=0)
    weights = 1.0 - np.arange(1, lag + 1) / (lag + 1.0)
    gamma = np.tensordot(weights, cross[1 : lag + 1], axes=(0, 0))
    s = cross[0] + gamma + gamma.T
    inverse = np.linalg.pinv(design.T @ design)
    return inverse @ s @ inverse * (n / max(n - p, 1))
