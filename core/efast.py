"""EFAST: the extended Fourier amplitude sensitivity test (Saltelli, Tarantola & Chan 1999).

One block of ``n`` model runs per factor: in block i the factor of interest runs along the search
curve at the high frequency ω = ⌊(n − 1)/2M⌋ and every other factor at a low complementary
frequency in 1…⌊ω/2M⌋ (paper eq. 8). The spectrum Λ_k = |FFT_k/n|² of the block's output gives

    V  = 2 Σ_k Λ_k                               (paper eq. 13)
    S1 = 2 Σ_{p=1..M} Λ_{pω} / V                 (paper eqs. 12, 16)
    ST = 1 − 2 Σ_{k=1..⌊ω/2⌋} Λ_k / V            (the complement's variance lies below ω/2)

This is the estimator of SALib, R ``fast99`` and GlobalSensitivity.jl (``method="classic"``; fed
the same sample matrix it reproduces SALib's numbers).

The default ``method="tail"`` adds back what the classic bands miss. Each factor's search curve
x = G(½ + arcsin(sin(ωs + φ))/π) carries harmonics beyond the M-th: 0.23 % of the variance of a
uniform factor, 4.2 % of a normal one (the quantile of the curve's peaks puts the normal tails into
high harmonics), 1.4 % of a V-shaped effect such as |4x − 2|. The classic S1 loses that share of
every first-order variance, and the classic ST counts the complement's lost harmonics as
interactions of the factor of interest. The tail estimator fits each factor's main effect as a
polynomial in the factor (linear, plus a quadratic term for bounded distributions:
:func:`tail_degrees`), to the very bins the classic estimator reads — the harmonics pω for the
factor of interest, the band below ω/2 for the others — and adds the power the fitted effects put
outside those bins. With the factors' distributions known, the fitted linear coefficients also
serve as a control variate for the sampling error of the inputs: each block's realised input
covariance (curves whose frequencies share harmonics correlate by up to 0.25) is replaced by the
population one (:class:`MainEffectTails`). The power inside the bands is still read from the
output's spectrum, so both corrections are exact for main effects of the fitted form and leave
the rest as the classic estimator reads it. docs/sensitivity.md gives the measured bias of both
methods.

Uncertainty comes from repeats with independent random phases (never from a bootstrap of one
curve: SALib issues #649, #684).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import scipy.fft
from numpy.typing import ArrayLike, NDArray
from scipy.special import ndtr, ndtri

from .userror import UserError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

METHODS = ("tail", "classic")
# Keeps the normal quantile finite where the search curve touches 0 or 1 exactly (about 7σ).
_UNIT_CLIP = 1e-12


class EfastError(UserError, ValueError):
    """An EFAST setting that cannot work; the message says how to fix it."""


# --------------------------------------------------------------------------------------------
# Distributions of the factors
# --------------------------------------------------------------------------------------------


class Distribution(Protocol):
    """A factor's distribution, sampled through its quantile function along the search curve."""

    @property
    def mean(self) -> float: ...

    @property
    def std(self) -> float: ...

    def ppf(self, unit: FloatArray) -> FloatArray: ...

    def describe(self) -> dict[str, object]: ...


def _positive(value: float, what: str) -> float:
    number = float(value)
    if not (math.isfinite(number) and number > 0):
        raise EfastError(f"{what} must be a positive number, got {value!r}")
    return number


def _finite(value: float, what: str) -> float:
    number = float(value)
    if not math.isfinite(number):
        raise EfastError(f"{what} must be a finite number, got {value!r}")
    return number


@dataclass(frozen=True)
class Normal:
    """Normal distribution N(mean, sd²) (the paper's Table 2)."""

    mean: float
    sd: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "mean", _finite(self.mean, "normal mean"))
        object.__setattr__(self, "sd", _positive(self.sd, "normal standard deviation"))

    @property
    def std(self) -> float:
        return self.sd

    def ppf(self, unit: FloatArray) -> FloatArray:
        z = ndtri(np.clip(unit, _UNIT_CLIP, 1.0 - _UNIT_CLIP))
        z *= self.sd
        z += self.mean
        return np.asarray(z)

    def describe(self) -> dict[str, object]:
        return {"kind": "normal", "mean": self.mean, "sd": self.sd}


@dataclass(frozen=True)
class Uniform:
    """Uniform distribution on [low, high]."""

    low: float
    high: float

    def __post_init__(self) -> None:
        low = _finite(self.low, "uniform low")
        high = _finite(self.high, "uniform high")
        if not high > low:
            raise EfastError(f"uniform distribution: high ({high:g}) must exceed low ({low:g})")
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)

    @property
    def mean(self) -> float:
        return 0.5 * (self.low + self.high)

    @property
    def std(self) -> float:
        return (self.high - self.low) / math.sqrt(12.0)

    def ppf(self, unit: FloatArray) -> FloatArray:
        return self.low + (self.high - self.low) * np.asarray(unit, dtype=float)

    def describe(self) -> dict[str, object]:
        return {"kind": "uniform", "low": self.low, "high": self.high}


@dataclass(frozen=True)
class TruncatedNormal:
    """N(parent_mean, parent_sd²) truncated to [low, high] (e.g. the paper's ±3σ zone)."""

    parent_mean: float
    parent_sd: float
    low: float
    high: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "parent_mean", _finite(self.parent_mean, "truncated normal mean"))
        object.__setattr__(
            self, "parent_sd", _positive(self.parent_sd, "truncated normal standard deviation")
        )
        low = _finite(self.low, "truncated normal low")
        high = _finite(self.high, "truncated normal high")
        if not high > low:
            raise EfastError(f"truncated normal: high ({high:g}) must exceed low ({low:g})")
        if not ndtr((high - self.parent_mean) / self.parent_sd) > ndtr(
            (low - self.parent_mean) / self.parent_sd
        ):
            raise EfastError(
                f"truncated normal: [{low:g}, {high:g}] holds no probability of "
                f"N({self.parent_mean:g}, {self.parent_sd:g}²)"
            )
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)

    def _standard_bounds(self) -> tuple[float, float]:
        return (self.low - self.parent_mean) / self.parent_sd, (
            self.high - self.parent_mean
        ) / self.parent_sd

    def _moments(self) -> tuple[float, float]:
        alpha, beta = self._standard_bounds()
        mass = float(ndtr(beta) - ndtr(alpha))
        pdf_a = math.exp(-0.5 * alpha * alpha) / math.sqrt(2.0 * math.pi)
        pdf_b = math.exp(-0.5 * beta * beta) / math.sqrt(2.0 * math.pi)
        shift = (pdf_a - pdf_b) / mass
        variance = 1.0 + (alpha * pdf_a - beta * pdf_b) / mass - shift * shift
        return self.parent_mean + self.parent_sd * shift, self.parent_sd * math.sqrt(variance)

    @property
    def mean(self) -> float:
        return self._moments()[0]

    @property
    def std(self) -> float:
        return self._moments()[1]

    def ppf(self, unit: FloatArray) -> FloatArray:
        alpha, beta = self._standard_bounds()
        lo, hi = float(ndtr(alpha)), float(ndtr(beta))
        p = lo + (hi - lo) * np.clip(unit, _UNIT_CLIP, 1.0 - _UNIT_CLIP)
        return np.clip(self.parent_mean + self.parent_sd * ndtri(p), self.low, self.high)

    def describe(self) -> dict[str, object]:
        return {
            "kind": "truncated_normal",
            "parent_mean": self.parent_mean,
            "parent_sd": self.parent_sd,
            "low": self.low,
            "high": self.high,
        }


@dataclass(frozen=True)
class Triangular:
    """Triangular distribution on [low, high] with its peak at ``mode``."""

    low: float
    mode: float
    high: float

    def __post_init__(self) -> None:
        low = _finite(self.low, "triangular low")
        mode = _finite(self.mode, "triangular mode")
        high = _finite(self.high, "triangular high")
        if not (high > low and low <= mode <= high):
            raise EfastError(
                f"triangular distribution needs low < high and low <= mode <= high, got "
                f"({low:g}, {mode:g}, {high:g})"
            )
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "mode", mode)
        object.__setattr__(self, "high", high)

    @property
    def mean(self) -> float:
        return (self.low + self.mode + self.high) / 3.0

    @property
    def std(self) -> float:
        a, c, b = self.low, self.mode, self.high
        return math.sqrt((a * a + b * b + c * c - a * b - a * c - b * c) / 18.0)

    def ppf(self, unit: FloatArray) -> FloatArray:
        u = np.asarray(unit, dtype=float)
        a, c, b = self.low, self.mode, self.high
        split = (c - a) / (b - a)
        left = a + np.sqrt(np.clip(u, 0.0, None) * (b - a) * (c - a))
        right = b - np.sqrt(np.clip(1.0 - u, 0.0, None) * (b - a) * (b - c))
        return np.where(u < split, left, right)

    def describe(self) -> dict[str, object]:
        return {"kind": "triangular", "low": self.low, "mode": self.mode, "high": self.high}


def distribution_from_description(description: Mapping[str, object]) -> Distribution:
    """Inverse of ``describe()`` (used to read stored problems)."""
    kind = description.get("kind")
    values = {k: float(v) for k, v in description.items() if k != "kind"}  # type: ignore[arg-type]
    try:
        if kind == "normal":
            return Normal(values["mean"], values["sd"])
        if kind == "uniform":
            return Uniform(values["low"], values["high"])
        if kind == "truncated_normal":
            return TruncatedNormal(
                values["parent_mean"], values["parent_sd"], values["low"], values["high"]
            )
        if kind == "triangular":
            return Triangular(values["low"], values["mode"], values["high"])
    except KeyError as missing:
        raise EfastError(f"{kind} distribution: missing field {missing}") from None
    raise EfastError(
        f"unknown distribution {kind!r}; use normal, uniform, truncated_normal or triangular"
    )


# --------------------------------------------------------------------------------------------
# The design
# --------------------------------------------------------------------------------------------


def frequencies(n: int, m: int, factors: int) -> tuple[int, IntArray]:
    """ω of the factor of interest and the complementary frequencies of the others.

    ω = ⌊(n − 1)/2M⌋; the others take frequencies in 1…⌊ω/2M⌋, spread evenly when there are
    enough, repeated cyclically otherwise (Saltelli et al. 1999, as SALib assigns them).
    """
    if m < 1:
        raise EfastError(f"the interference factor M must be at least 1, got {m}")
    if factors < 1:
        raise EfastError("EFAST needs at least one factor")
    if n <= 4 * m * m:
        raise EfastError(
            f"N = {n} samples per curve is too few for M = {m}: EFAST needs N > 4·M² = {4 * m * m}"
        )
    omega = (n - 1) // (2 * m)
    top = omega // (2 * m)
    others = factors - 1
    if others == 0:
        return omega, np.zeros(0, dtype=np.int64)
    if top >= others:
        complementary = np.floor(np.linspace(1, top, others)).astype(np.int64)
    else:
        complementary = (np.arange(others) % top + 1).astype(np.int64)
    return omega, complementary


@dataclass(frozen=True, eq=False)
class EfastDesign:
    """Where an EFAST analysis samples: ``repeats`` independent sets of ``factors`` blocks.

    Block i of repeat r runs factor i at ω and the others at the complementary frequencies, all
    with the block's random phase ``phases[r, i]`` (Saltelli et al. 1999). The sample layout is
    (repeats, block, run, factor); with one repeat, ``unit_samples().reshape(-1, factors)`` is
    SALib's ``fast_sampler`` matrix before scaling.
    """

    factors: int
    n: int
    m: int
    phases: FloatArray
    seed: int | None = None

    def __post_init__(self) -> None:
        phases = np.atleast_2d(np.asarray(self.phases, dtype=float))
        if phases.shape[1] != self.factors:
            raise EfastError(f"{phases.shape[1]} phases per repeat for {self.factors} factors")
        phases.setflags(write=False)
        object.__setattr__(self, "phases", phases)
        frequencies(self.n, self.m, self.factors)

    @property
    def repeats(self) -> int:
        return int(self.phases.shape[0])

    @property
    def omega(self) -> int:
        return frequencies(self.n, self.m, self.factors)[0]

    @property
    def complementary(self) -> IntArray:
        return frequencies(self.n, self.m, self.factors)[1]

    @property
    def runs(self) -> int:
        """Model evaluations in all: repeats × factors × n."""
        return self.repeats * self.factors * self.n

    def frequency_matrix(self) -> IntArray:
        """Row i: the frequency of every factor in block i (ω on the diagonal)."""
        return frequency_matrix(self.n, self.m, self.factors)

    def _phase_grid(self) -> tuple[FloatArray, tuple[IntArray, IntArray, IntArray]]:
        """The curve on its phase grid and where each column reads it.

        In block i every factor's phase ω·s_k + φ_i falls on the grid 2π·m/n + φ_i with
        m = ω·k mod n, so one vector U[r, i, m] = ½ + arcsin(sin(2πm/n + φ))/π serves every
        factor of the block; column (j, r, i) is U[r, i, index[j, i, :]].
        """
        # ½ + arcsin(sin θ)/π is the triangle wave 1 − |2f − 1| of the phase fraction
        # f = (θ + π/2)/2π mod 1; integer phases m keep the grid exact.
        fraction = np.arange(self.n) / self.n + (self.phases / (2.0 * np.pi) + 0.25)[..., None]
        fraction -= np.floor(fraction)
        fraction *= 2.0
        fraction -= 1.0
        np.abs(fraction, out=fraction)
        grid = 1.0 - fraction  # (repeats, blocks, n)
        frequency = self.frequency_matrix().T  # [factor, block]
        # few distinct frequencies: one table of ω·k mod n each, gathered per column
        distinct, which = np.unique(frequency, return_inverse=True)
        table = (distinct[:, None] * np.arange(self.n)[None, :]) % self.n
        index = table[which.reshape(frequency.shape)]
        repeat = np.arange(self.repeats)[None, :, None, None]
        block = np.arange(self.factors)[None, None, :, None]
        return grid, (repeat, block, index[:, None, :, :])

    def unit_columns(self) -> FloatArray:
        """Search-curve values in [0, 1] by factor: (factor, repeats, block, n) (paper eq. 8).

        Factor-major, so that every factor's values are one contiguous row for a model that takes
        one row per factor.
        """
        grid, where = self._phase_grid()
        return np.asarray(grid[where])

    def unit_samples(self) -> FloatArray:
        """Search-curve values in [0, 1], shape (repeats, block, n, factor).

        With one repeat, ``unit_samples().reshape(-1, factors)`` is SALib's sample matrix.
        """
        return np.moveaxis(self.unit_columns(), 0, -1)

    def value_columns(self, distributions: Sequence[Distribution]) -> FloatArray:
        """Factor values by factor: (factor, repeats, block, n), contiguous.

        Each quantile function is evaluated on the n-point phase grid of every block and then
        read where the column falls on it; normal and uniform factors share one evaluation.
        """
        if len(distributions) != self.factors:
            raise EfastError(f"{len(distributions)} distributions for {self.factors} factors")
        grid, (repeat, block, index) = self._phase_grid()
        standard_normal: FloatArray | None = None
        out = np.empty((self.factors, self.repeats, self.factors, self.n))
        for j, dist in enumerate(distributions):
            where = (repeat[0], block[0], index[j])
            if isinstance(dist, Normal):
                if standard_normal is None:
                    standard_normal = Normal(0.0, 1.0).ppf(grid)
                np.multiply(standard_normal[where], dist.sd, out=out[j])
                out[j] += dist.mean
            elif isinstance(dist, Uniform):
                np.multiply(grid[where], dist.high - dist.low, out=out[j])
                out[j] += dist.low
            else:
                out[j] = dist.ppf(grid)[where]
        return out

    def values(self, distributions: Sequence[Distribution]) -> FloatArray:
        """Factor values along the search curves, shape (repeats, block, n, factor)."""
        return np.moveaxis(self.value_columns(distributions), 0, -1)


def efast_design(
    factors: int, n: int, m: int = 4, seed: int | None = None, repeats: int = 1
) -> EfastDesign:
    """A design with one independent random phase per block and repeat.

    With ``seed`` an integer and one repeat, the phases are those SALib's ``fast_sampler.sample``
    draws with the same seed, so the two samplers give the same matrix.
    """
    if repeats < 1:
        raise EfastError(f"repeats must be at least 1, got {repeats}")
    if seed is None:
        seed = int(np.random.default_rng().integers(2**63))
    rng = np.random.default_rng(seed)
    phases = 2.0 * np.pi * rng.random((repeats, factors))
    return EfastDesign(factors, n, m, phases, seed)


def efast_sample(
    distributions: Sequence[Distribution],
    n: int,
    m: int = 4,
    seed: int | None = None,
    repeats: int = 1,
) -> tuple[EfastDesign, FloatArray]:
    """The design and its factor values (repeats, factors, n, factors)."""
    design = efast_design(len(distributions), n, m, seed, repeats)
    return design, design.values(distributions)


# --------------------------------------------------------------------------------------------
# The analysis
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class EfastIndices:
    """First-order and total indices, shape (..., repeats, factors) for every output.

    ``variance`` is the output variance V of each block (same shape), so that V·S1 is the
    first-order variance of the factor in the output's units squared.
    """

    s1: FloatArray
    st: FloatArray
    variance: FloatArray
    n: int
    m: int
    method: str

    @property
    def repeats(self) -> int:
        return int(self.s1.shape[-2])

    @property
    def s1_mean(self) -> FloatArray:
        return np.asarray(self.s1.mean(axis=-2))

    @property
    def st_mean(self) -> FloatArray:
        return np.asarray(self.st.mean(axis=-2))

    @property
    def s1_std(self) -> FloatArray:
        """Spread of the single-repeat estimates (NaN with one repeat)."""
        return repeat_std(self.s1)

    @property
    def st_std(self) -> FloatArray:
        return repeat_std(self.st)


def repeat_std(values: FloatArray) -> FloatArray:
    """Standard deviation over the repeat axis (second to last) of single-repeat estimates;
    NaN with one repeat."""
    if values.shape[-2] < 2:
        return np.full(values.shape[:-2] + values.shape[-1:], np.nan)
    return np.asarray(values.std(axis=-2, ddof=1))


# Transforms of fewer values than this run on one thread: starting workers costs more than it
# saves there, and much more when the cores are busy.
_THREADED_FFT_SIZE = 1 << 23


def fft_workers(size: int) -> int:
    """Threads for a transform of ``size`` values in all."""
    return (os.cpu_count() or 1) if size >= _THREADED_FFT_SIZE else 1


def tail_degrees(distributions: Sequence[Distribution]) -> tuple[int, ...]:
    """Degree of the main-effect fit per factor: 2 for bounded distributions, 1 for the normal.

    A quadratic term captures even (V- or U-shaped) main effects, whose harmonics a linear fit
    misses. With an unbounded input the search curve's peaks reach ±3.5σ, where a quadratic fit
    of an effect that grows less than quadratically (such as ET = |E| near E = 0) overshoots and
    adds too much tail; the fit stays linear there (docs/sensitivity.md gives the numbers).
    """
    return tuple(1 if isinstance(d, Normal) else 2 for d in distributions)


def frequency_matrix(n: int, m: int, factors: int) -> IntArray:
    """Row i: the frequency of every factor in block i (ω on the diagonal)."""
    omega, complementary = frequencies(n, m, factors)
    out = np.empty((factors, factors), dtype=np.int64)
    for i in range(factors):
        out[i, i] = omega
        out[i, np.arange(factors) != i] = complementary
    return out


# Products in this module are small and batched: they use einsum rather than BLAS, whose threads
# add tens of milliseconds per call when the cores are busy (measured on a shared 2-core machine).


@dataclass(frozen=True)
class TailTerms:
    """What the tail method adds, per block: see :class:`MainEffectTails`."""

    own: FloatArray  # power of the fitted own effect outside the harmonics
    rest: FloatArray  # power of the fitted complement above ⌊ω/2⌋
    variance: FloatArray  # βᵀ(Σ − Ĉ)β over all linear terms
    own_variance: FloatArray  # the factor of interest's part of it
    rest_variance: FloatArray  # the complement's part of it


@dataclass(frozen=True, eq=False)
class MainEffectTails:
    """The fits the tail method needs, computed once from the inputs of every block.

    Each factor's main effect is modelled as β₁·(x − x̄) + β₂·((x − x̄)² − mean), the quadratic
    term only for factors of degree 2 (:func:`tail_degrees`). For the factor of interest, β is
    fitted to the output's harmonics pω, p ≤ M (the bins the classic S1 reads) by least squares,
    β = Re(``own_map``·Y_harmonics); the power of the fitted effect outside those bins,
    βᵀ·``own_gram``·β, is added to S1. The complement's effects are fitted to the output's low
    band (bins 1…⌊ω/2⌋, which the classic ST reads), β = Re(``rest_map``·Y_low); their power above
    ⌊ω/2⌋, βᵀ·``rest_gram``·β, is added to the complement's variance.

    With the factors' variances known, the linear coefficients also remove the sampling error of
    the block's inputs (a control variate): along one search curve a factor's realised variance
    differs from its distribution's by up to a few per cent; two complementary factors whose
    frequencies are odd multiples of each other (3 and 9, 5 and 15) share harmonics, so their
    columns correlate by up to 0.25 for normal inputs where they should be independent; and
    factors that share a frequency (more factors than frequencies, or a large M) move together.
    ``gap`` = Σ − Ĉ (population minus realised covariance of the linear terms, per block) turns
    every variance the linear effects contribute into its population value, bᵀ·gap·b, with each
    factor's coefficient b taken from its own block's harmonics, where it is never confounded.
    All of this depends on the inputs only: one set serves every output and every map point,
    and the fits read the spectrum the analysis computes anyway.
    """

    own_map: NDArray[np.complex128]  # (repeats, factors, terms, M)
    own_gram: FloatArray  # (repeats, factors, terms, terms)
    rest_map: NDArray[np.complex128]  # (repeats, factors, terms·(factors − 1), ⌊ω/2⌋)
    rest_gram: FloatArray  # (repeats, factors, terms·(factors − 1), terms·(factors − 1))
    gap: FloatArray  # (repeats, factors, factors, factors), zero without known variances
    m: int
    terms_per_factor: int = 1  # 2 when some factor's main effect has a quadratic term

    @property
    def repeats(self) -> int:
        return int(self.own_gram.shape[0])

    @property
    def factors(self) -> int:
        return int(self.own_gram.shape[1])

    @classmethod
    def from_inputs(
        cls, inputs: ArrayLike, m: int, distributions: Sequence[Distribution] | None = None
    ) -> MainEffectTails:
        """``inputs`` (block, n, factor) or (repeats, block, n, factor); as
        :meth:`from_columns`."""
        x = np.asarray(inputs, dtype=float)
        if x.ndim == 3:
            x = x[None]
        if x.ndim != 4 or x.shape[1] != x.shape[3]:
            raise EfastError(
                f"inputs must be laid out as (repeats, block, n, factor), got {x.shape}"
            )
        return cls.from_columns(np.moveaxis(x, 3, 0), m, distributions)

    @classmethod
    def from_columns(
        cls, columns: ArrayLike, m: int, distributions: Sequence[Distribution] | None = None
    ) -> MainEffectTails:
        """From factor values laid out as :meth:`EfastDesign.value_columns`.

        ``distributions`` (the factors' own) set the fit's degrees (:func:`tail_degrees`) and the
        population variances of the control variate; without them the fit is linear and the
        realised covariances are kept.
        """
        x = np.asarray(columns, dtype=float)
        if x.ndim != 4 or x.shape[0] != x.shape[2]:
            raise EfastError(
                f"columns must be laid out as (factor, repeats, block, n), got {x.shape}"
            )
        factors, repeats, _, n = x.shape
        if distributions is not None and len(distributions) != factors:
            raise EfastError(f"{len(distributions)} distributions for {factors} factors")
        order = np.asarray(tail_degrees(distributions) if distributions else [1] * factors)
        omega, _ = frequencies(n, m, factors)
        top = math.ceil(n / 2)
        harmonics = np.arange(1, m + 1) * omega
        band = omega // 2
        centred = x - x.mean(axis=-1, keepdims=True)
        # basis[r, i, terms·j + d]: factor j's term of degree d + 1 in block i, runs last; the
        # quadratic terms exist only if some factor has degree 2 (zero for the others)
        terms = int(order.max())
        if terms == 2:
            square = np.square(centred)
            square -= square.mean(axis=-1, keepdims=True)
            square[order == 1] = 0.0
            stacked = np.stack([centred, square], axis=1).reshape(2 * factors, repeats, factors, n)
        else:
            stacked = centred
        basis = np.ascontiguousarray(np.moveaxis(stacked, 0, 2))
        spectrum = scipy.fft.rfft(basis, axis=-1, workers=fft_workers(basis.size)) / n
        # Parseval: the realised covariance of the (centred) terms is the power over every bin;
        # the power over a set of bins is what remains after the others are taken out.
        # the one product here long enough for BLAS to pay off (n runs per term)
        covariance = np.matmul(basis, np.swapaxes(basis, -1, -2)) / n
        if n % 2 == 0:
            nyquist = spectrum[..., n // 2].real
            covariance -= nyquist[..., :, None] * nyquist[..., None, :]
        spectra = spectrum[..., 1:top]
        blocks = np.arange(factors)
        own_terms = terms * blocks[:, None] + np.arange(terms)[None, :]  # (factors, terms)
        at_harmonics = spectra[:, blocks[:, None, None], own_terms[:, :, None], harmonics - 1]
        # Re(AᴴB) = AᵣᵀBᵣ + AᵢᵀBᵢ keeps every product real and batched.
        harmonic_gram = _real_gram(at_harmonics)
        own_map = _apply_real(_pseudo_inverse_real(harmonic_gram), at_harmonics.conj())
        own_covariance = covariance[
            :, blocks[:, None, None], own_terms[:, :, None], own_terms[:, None, :]
        ]
        own_gram = own_covariance - 2.0 * harmonic_gram
        others = np.array([[t for t in range(terms * factors) if t // terms != i] for i in blocks])
        low = spectra[:, blocks[:, None, None], others[:, :, None], np.arange(band)]
        low_gram = _real_gram(low)
        rest_map = _apply_real(_pseudo_inverse_real(low_gram), low.conj())
        rest_covariance = covariance[
            :, blocks[:, None, None], others[:, :, None], others[:, None, :]
        ]
        rest_gram = rest_covariance - 2.0 * low_gram
        gap = np.zeros((repeats, factors, factors, factors))
        if distributions is not None:
            realised = covariance[..., ::terms, ::terms]  # the linear terms
            gap = np.diag([d.std**2 for d in distributions]) - realised
        return cls(own_map, own_gram, rest_map, rest_gram, gap, m, terms)

    def added(
        self, harmonic_bins: NDArray[np.complex128], low_bins: NDArray[np.complex128]
    ) -> TailTerms:
        """The added powers from the outputs' spectra divided by n.

        ``harmonic_bins`` (..., repeats, factors, M) holds bins pω, ``low_bins`` (..., repeats,
        factors, ⌊ω/2⌋) bins 1…⌊ω/2⌋.
        """
        own_beta = np.einsum("rfak,...rfk->...rfa", self.own_map, harmonic_bins).real
        own = np.einsum("...rfa,rfab,...rfb->...rf", own_beta, self.own_gram, own_beta)
        lead = low_bins.shape[:-3]
        repeats, factors, band = low_bins.shape[-3:]
        # (repeats, factors, rows, band), rows = every output and point of the call
        rows = np.moveaxis(low_bins.reshape((-1, repeats, factors, band)), 0, 2)
        mapping = self.rest_map
        fitted = np.einsum("rflb,rfkb->rflk", rows.real, mapping.real)
        fitted -= np.einsum("rflb,rfkb->rflk", rows.imag, mapping.imag)
        rest = np.einsum("rfla,rfab,rflb->rfl", fitted, self.rest_gram, fitted)
        rest = np.moveaxis(rest, 2, 0).reshape(lead + (repeats, factors))
        # Every factor's linear coefficient comes from its own block (its harmonics), where it
        # is not confounded with factors that share its frequency elsewhere.
        linear = own_beta[..., 0]  # (..., repeats, factors)
        spread = np.einsum("...rj,rijk->...rik", linear, self.gap)
        total = np.einsum("...rik,...rk->...ri", spread, linear)
        diagonal = np.arange(factors)
        own_gap = self.gap[:, diagonal, diagonal, diagonal]  # (repeats, factors)
        own_part = np.square(linear) * own_gap
        rest_part = total - 2.0 * linear * spread[..., diagonal, diagonal] + own_part
        return TailTerms(own, rest, total, own_part, rest_part)


def _power_sum(spectrum: NDArray[np.complex128]) -> FloatArray:
    """Σ_k |F_k|² over the last axis, in one pass over the real and imaginary parts."""
    if spectrum.strides[-1] != spectrum.itemsize:
        spectrum = np.ascontiguousarray(spectrum)
    pairs = spectrum.view(np.float64)
    return np.asarray(np.einsum("...k,...k->...", pairs, pairs))


def _apply_real(matrix: FloatArray, rows: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """matrix (..., a, b) times complex rows (..., b, k), as two real products."""
    real = np.einsum("...ab,...bk->...ak", matrix, rows.real)
    imag = np.einsum("...ab,...bk->...ak", matrix, rows.imag)
    return np.asarray(real + 1j * imag)


def _real_gram(rows: NDArray[np.complex128]) -> FloatArray:
    """Re(R·Rᴴ) over the last axis of complex rows (..., k, bins): (..., k, k)."""
    pairs = (
        rows.view(np.float64)
        if rows.strides[-1] == rows.itemsize
        else (np.ascontiguousarray(rows).view(np.float64))
    )
    return np.asarray(np.einsum("...ak,...bk->...ab", pairs, pairs))


def _pseudo_inverse_real(gram: FloatArray) -> FloatArray:
    """Pseudo-inverses of a stack of symmetric positive semi-definite Gram matrices.

    Equal-frequency complementary factors give collinear columns: the pseudo-inverse keeps their
    joint effect, which is all the tails need.
    """
    scale = np.sqrt(np.clip(np.diagonal(gram, axis1=-2, axis2=-1), 0.0, None))
    scale = np.where(scale > 0, scale, 1.0)
    outer = scale[..., :, None] * scale[..., None, :]
    values, vectors = np.linalg.eigh(gram / outer)
    keep = values > 1e-10 * values.max(axis=-1, keepdims=True)
    inverse_values = np.where(keep, 1.0 / np.where(keep, values, 1.0), 0.0)
    inverse = np.einsum("...ak,...bk->...ab", vectors * inverse_values[..., None, :], vectors)
    return np.asarray(inverse / outer)


def efast_indices(
    outputs: ArrayLike,
    m: int = 4,
    inputs: ArrayLike | None = None,
    method: str = "tail",
    tails: MainEffectTails | None = None,
    distributions: Sequence[Distribution] | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """S1, ST and V of outputs laid out per block: ``outputs`` (..., factors, n).

    The tail method needs the factor values the outputs were computed at: ``inputs``
    (factors, n, factors), or (repeats, factors, n, factors) when the outputs' axis before
    ``factors`` is the repeat axis, with the factors' ``distributions`` (without them the fits
    are linear and the inputs' realised variances are kept); or the same fits precomputed as
    ``tails``. Returns S1, ST and the output variance V (population estimate with the tail
    method), three arrays (..., factors).
    """
    y = np.asarray(outputs, dtype=float)
    if y.ndim < 2:
        raise EfastError("outputs must be laid out as (..., factors, n)")
    factors, n = y.shape[-2], y.shape[-1]
    omega, _ = frequencies(n, m, factors)
    top = math.ceil(n / 2)  # bins 1 … top−1, as SALib: the Nyquist bin of an even N is left out
    spectrum = scipy.fft.rfft(y, axis=-1, workers=fft_workers(y.size))
    spectrum /= n
    variance = 2.0 * _power_sum(spectrum[..., 1:top])
    if method == "tail" and tails is None:
        if inputs is None:
            raise EfastError("the tail method needs the factor values (inputs)")
        tails = MainEffectTails.from_inputs(inputs, m, distributions)
    return spectral_indices(
        variance,
        spectrum[..., np.arange(1, m + 1) * omega],
        spectrum[..., 1 : omega // 2 + 1],
        m,
        method,
        tails,
    )


def spectral_indices(
    variance: FloatArray,
    harmonic_bins: NDArray[np.complex128],
    low_bins: NDArray[np.complex128],
    m: int,
    method: str = "tail",
    tails: MainEffectTails | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """S1, ST and V from the parts of the spectrum EFAST reads, (..., factors, bins).

    ``harmonic_bins`` holds F_pω/n for p = 1…M, ``low_bins`` F_k/n for k = 1…⌊ω/2⌋ and
    ``variance`` V = 2·Σ_{k=1}^{⌈n/2⌉−1} |F_k/n|². A caller who knows these without a transform
    of every output (an output linear in precomputed series) calls this directly.
    """
    if method not in METHODS:
        raise EfastError(f"unknown EFAST method {method!r}; use one of {', '.join(METHODS)}")
    first = 2.0 * _power_sum(harmonic_bins)
    low = 2.0 * _power_sum(low_bins)
    if method == "tail":
        if tails is None:
            raise EfastError("the tail method needs the fits of the inputs (tails)")
        if tails.m != m:
            raise EfastError(f"tail fits were made for M = {tails.m}, the analysis uses M = {m}")
        with_repeats = harmonic_bins.ndim >= 3 and harmonic_bins.shape[-3] == tails.repeats
        if not with_repeats:
            harmonic_bins = harmonic_bins[..., None, :, :]
            low_bins = low_bins[..., None, :, :]
        if harmonic_bins.shape[-3:-1] != (tails.repeats, tails.factors):
            raise EfastError(
                f"outputs of {harmonic_bins.shape[-2]} blocks do not match inputs of "
                f"{tails.repeats} repeat(s) and {tails.factors} factors"
            )
        added = tails.added(harmonic_bins, low_bins)
        first = first + (added.own + added.own_variance).reshape(first.shape)
        low = low + (added.rest + added.rest_variance).reshape(low.shape)
        variance = variance + added.variance.reshape(variance.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        s1 = first / variance
        st = 1.0 - low / variance
    return s1, st, variance


def efast_analyse(
    design: EfastDesign,
    outputs: ArrayLike,
    inputs: ArrayLike | None = None,
    method: str = "tail",
    distributions: Sequence[Distribution] | None = None,
) -> EfastIndices:
    """Indices of outputs (..., repeats, factors, n) computed on ``design``.

    The tail method needs ``inputs``, the factor values (``design.values(distributions)``), and
    should have the ``distributions`` (see :func:`efast_indices`).
    """
    y = np.asarray(outputs, dtype=float)
    expected = (design.repeats, design.factors, design.n)
    if y.shape[-3:] != expected:
        raise EfastError(
            f"outputs end in shape {y.shape[-3:]}, the design expects (repeats, factors, n) = "
            f"{expected}"
        )
    s1, st, variance = efast_indices(y, design.m, inputs, method, distributions=distributions)
    return EfastIndices(s1, st, variance, design.n, design.m, method)


# --------------------------------------------------------------------------------------------
# Test functions with known answers
# --------------------------------------------------------------------------------------------


def ishigami(x: ArrayLike, a: float = 7.0, b: float = 0.1) -> FloatArray:
    """Ishigami function of x (..., 3), each factor uniform on [−π, π]."""
    v = np.asarray(x, dtype=float)
    return np.asarray(
        np.sin(v[..., 0]) + a * np.sin(v[..., 1]) ** 2 + b * v[..., 2] ** 4 * np.sin(v[..., 0])
    )


def ishigami_indices(a: float = 7.0, b: float = 0.1) -> tuple[FloatArray, FloatArray]:
    """Analytic (S1, ST) of the Ishigami function (Ishigami & Homma 1990; Sobol' 1999)."""
    pi4 = math.pi**4
    v1 = 0.5 * (1.0 + b * pi4 / 5.0) ** 2
    v2 = a * a / 8.0
    v13 = b * b * math.pi**8 * (1.0 / 18.0 - 1.0 / 50.0)
    total = v1 + v2 + v13
    s1 = np.array([v1, v2, 0.0]) / total
    st = np.array([v1 + v13, v2, v13]) / total
    return s1, st


def sobol_g(x: ArrayLike, a: ArrayLike) -> FloatArray:
    """Sobol' G function Π (|4x_i − 2| + a_i)/(1 + a_i) of x (..., d), factors uniform on [0, 1]."""
    v = np.asarray(x, dtype=float)
    weights = np.asarray(a, dtype=float)
    return np.asarray(np.prod((np.abs(4.0 * v - 2.0) + weights) / (1.0 + weights), axis=-1))


def sobol_g_indices(a: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Analytic (S1, ST) of the G function: V_i = 1/(3(1 + a_i)²), V = Π(1 + V_i) − 1."""
    weights = np.asarray(a, dtype=float)
    partial = 1.0 / (3.0 * (1.0 + weights) ** 2)
    product = np.prod(1.0 + partial)
    total = product - 1.0
    return partial / total, partial * product / (1.0 + partial) / total


def linear_model(x: ArrayLike, coefficients: ArrayLike) -> FloatArray:
    """Σ c_i x_i of x (..., d)."""
    return np.asarray(np.asarray(x, dtype=float) @ np.asarray(coefficients, dtype=float))


def linear_indices(coefficients: ArrayLike, sd: ArrayLike) -> FloatArray:
    """S1 = ST = c_i² σ_i² / Σ c_j² σ_j² of a linear model with independent factors."""
    share = np.square(np.asarray(coefficients, dtype=float) * np.asarray(sd, dtype=float))
    return np.asarray(share / share.sum())
