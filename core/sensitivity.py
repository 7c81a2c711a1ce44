"""Global sensitivity of the volumetric error to the 21 geometric errors (paper, section 3).

A :class:`SensitivityProblem` names the factors (error values with their distributions), where the
machine is (fixed positions, one analysis per point: a map; or positions as factors of the design,
uniform over the strokes) and the tool offset. :func:`analyse` runs EFAST (:mod:`.efast`) on the
exact volumetric error of :mod:`.kinematics` for several outputs at once (Ex, Ey, Ez, ET = |E| of
the paper's eqs. 5–7, or any callable) and returns a frozen :class:`SensitivityResult`.

Positions are never random noise outside the design: a position drawn afresh for every run but
not given a frequency puts the position-driven variance at every frequency of the spectrum, where
it reads as an interaction of every factor (with Table 2 every error of Ex gets ST ≈ 0.87 and the
S1 sum to 0.11; REFERENCE §1). Such a problem is refused with :class:`PositionNoiseError`.

Evaluation. With error values that do not depend on the position (the paper's Table 2 treats each
error as one random scalar) the exact chain is affine in the NC position for a given set of error
values, E(q) = a + G·q (:func:`chain_affine`): a map costs one chain evaluation per run, Ex, Ey,
Ez at a point are combinations of four precomputed spectra and ET² a quadratic form in (1, q).
Error values identified as functions of the position (an
:class:`ErrorSpread`) are either evaluated exactly point by point or, for large maps, linearised
about the identified values with the exact Jacobian (``chain="linear"``): the terms left out are
products of two deviations, below 1e-6 of the output for errors of a few µm and µrad.

Tolerance allocation (paper eq. 19) is in :func:`allocate_tolerances`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
import scipy.fft
from numpy.typing import ArrayLike, NDArray

from .efast import (
    Distribution,
    EfastDesign,
    MainEffectTails,
    Normal,
    Uniform,
    efast_design,
    efast_indices,
    fft_workers,
    repeat_std,
    spectral_indices,
)
from .errors import ERROR_IDS, ERROR_INFO, SQUARENESS_IDS, ErrorModel
from .kinematics import (
    RAD_PER_URAD,
    UM_PER_MM,
    VolumetricModel,
    compose_error,
    error_value_jacobian,
)
from .machine import AXES, AXIS_INDEX, PAPER_MACHINE, Machine
from .progress import CancelToken, ProgressCallback, check, report
from .userror import UserError

FloatArray = NDArray[np.float64]

OUTPUT_NAMES = ("Ex", "Ey", "Ez", "ET")
CHAINS = ("auto", "exact", "linear")
# Evaluations per chunk of a map: bounds the working set to a few hundred MB.
_CHUNK_EVALUATIONS = 1 << 22
# Below this many chain evaluations a map with position-dependent errors is evaluated exactly.
_EXACT_LIMIT = 4_000_000


class SensitivityError(UserError, ValueError):
    """A sensitivity setting that cannot work; the message says how to fix it."""


class PositionNoiseError(SensitivityError):
    """Positions drawn as noise outside the EFAST design: refused, with the reason."""


NOISE_EXPLANATION = (
    "positions drawn at random for every run but kept outside the EFAST design are refused: "
    "their variance spreads over every frequency of the spectrum and reads as an interaction of "
    "every error (with the paper's Table 2 each error of Ex gets ST ≈ 0.87 while the S1 sum to "
    "0.11; docs/sensitivity.md). Make the positions factors of the design (positions='design': "
    "uniform over the strokes) or fix them (one position, or a map with one analysis per point)"
)


# --------------------------------------------------------------------------------------------
# Outputs
# --------------------------------------------------------------------------------------------

OutputFunction = Callable[[FloatArray, FloatArray], FloatArray]


@dataclass(frozen=True)
class Output:
    """A scalar output of the volumetric error.

    ``function(error_um, positions_mm)`` receives the components first: ``error_um[0]`` is Ex
    (µm) and ``positions_mm[0]`` the X position (mm), each of shape (...), and returns (...).
    Components first keeps every component contiguous over the millions of runs of a map.
    """

    name: str
    function: OutputFunction


def _component(index: int) -> OutputFunction:
    def value(error_um: FloatArray, positions_mm: FloatArray) -> FloatArray:
        return error_um[index]

    return value


def _total(error_um: FloatArray, positions_mm: FloatArray) -> FloatArray:
    return np.sqrt(np.einsum("i...,i...->...", error_um, error_um))


BUILTIN_OUTPUTS: Mapping[str, Output] = {
    "Ex": Output("Ex", _component(0)),
    "Ey": Output("Ey", _component(1)),
    "Ez": Output("Ez", _component(2)),
    "ET": Output("ET", _total),
}
# The built-in components, which a map of Table-2 style errors analyses without a transform.
_COMPONENTS: Mapping[Output, int] = {BUILTIN_OUTPUTS[f"E{c}"]: k for k, c in enumerate("xyz")}
_TOTAL = BUILTIN_OUTPUTS["ET"]
# Maps of at least this many points read Ex, Ey, Ez from precomputed spectra.
_SHORTCUT_POINTS = 4


def resolve_outputs(outputs: Sequence[str | Output] | str | Output) -> tuple[Output, ...]:
    """Output objects for names (Ex, Ey, Ez, ET) or given Output objects."""
    items = [outputs] if isinstance(outputs, str | Output) else list(outputs)
    resolved = []
    for item in items:
        if isinstance(item, Output):
            resolved.append(item)
        elif item in BUILTIN_OUTPUTS:
            resolved.append(BUILTIN_OUTPUTS[item])
        else:
            raise SensitivityError(
                f"unknown output {item!r}; use {', '.join(OUTPUT_NAMES)} or an "
                "Output(name, function)"
            )
    names = [o.name for o in resolved]
    if not resolved or len(set(names)) != len(names):
        raise SensitivityError(f"outputs must be distinct and at least one, got {names}")
    return tuple(resolved)


# --------------------------------------------------------------------------------------------
# Problems
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Factor:
    """One factor of the design: an error value (ISO id) or a position (``"X"``, ``"Y"``, ``"Z"``).

    ``unit`` is ``"um"``, ``"urad"``, ``"mm"``, or ``"sd"`` for the standardised deviation of an
    identified error (error value = identified value + standard deviation × factor).
    """

    id: str
    distribution: Distribution
    unit: str


@dataclass(frozen=True, eq=False)
class ErrorSpread:
    """Position-dependent mean and standard deviation of the 21 error values of an identification.

    The mean is the identified function; the standard deviation propagates the covariance of the
    function's coefficients through its basis design row, σ(q)² = d(q)ᵀ·C·d(q), with a floor;
    ``spread`` gives an explicit standard deviation per error id instead.
    """

    model: ErrorModel
    covariance: FloatArray | None = None
    floor_um: float = 0.0
    floor_urad: float = 0.0
    spread: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.covariance is not None:
            cov = np.asarray(self.covariance, dtype=float)
            count = self.model.parameter_count
            if cov.shape != (count, count):
                raise SensitivityError(
                    f"covariance of shape {cov.shape} does not match the model's {count} parameters"
                )
            object.__setattr__(self, "covariance", cov)
        unknown = sorted(set(self.spread) - set(ERROR_IDS))
        if unknown:
            raise SensitivityError(f"spread: unknown error id(s) {', '.join(unknown)}")
        if self.floor_um < 0 or self.floor_urad < 0:
            raise SensitivityError("spread floors must not be negative")

    def mean_sd(self, positions_mm: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Error values and their standard deviations at positions (n, 3): two (n, 21) arrays."""
        q = np.atleast_2d(np.asarray(positions_mm, dtype=float))
        mean = np.empty((len(q), len(ERROR_IDS)))
        sd = np.zeros_like(mean)
        slices = self.model.parameter_slices
        for column, eid in enumerate(ERROR_IDS):
            info = ERROR_INFO[eid]
            if info.axis is None:
                mean[:, column] = self.model.squareness_urad[eid]
                row = None
            else:
                function = self.model.functions[eid]
                mean[:, column] = function(q[:, AXIS_INDEX[info.axis]])
                row = function.basis.design(q[:, AXIS_INDEX[info.axis]])
            if eid in self.spread:
                sd[:, column] = float(self.spread[eid])
                continue
            if self.covariance is not None:
                block = self.covariance[slices[eid], slices[eid]]
                if row is None:
                    sd[:, column] = math.sqrt(max(float(block[0, 0]), 0.0))
                else:
                    variance = np.einsum("ni,ij,nj->n", row, block, row)
                    sd[:, column] = np.sqrt(np.clip(variance, 0.0, None))
            floor = self.floor_um if info.unit == "um" else self.floor_urad
            sd[:, column] = np.maximum(sd[:, column], floor)
        return mean, sd


@dataclass(frozen=True, eq=False)
class SensitivityProblem:
    """What varies, where the machine is, and the tool offset.

    Parameters
    ----------
    machine : Machine
    factors : the error factors, a subset of the 21 ISO ids in ``ERROR_IDS`` order; errors that
        are not factors keep the value in ``fixed`` (0 by default).
    positions : ``"design"`` (X, Y, Z become factors, uniform over the strokes) or fixed NC
        positions (3,) or (P, 3) in mm (one analysis per point: a map). ``"noise"`` is refused.
    tool_offset_mm : the tool point (D1, D2, D3); default the machine's.
    fixed : values (µm, µrad) of the errors that are not factors.
    spread : when set, the factors are standardised deviations of identified error values.
    name : shown in reports.
    """

    machine: Machine
    factors: tuple[Factor, ...]
    positions: str | FloatArray = "design"
    tool_offset_mm: tuple[float, float, float] | None = None
    fixed: Mapping[str, float] = field(default_factory=dict)
    spread: ErrorSpread | None = None
    name: str = "by hand"

    def __post_init__(self) -> None:
        ids = [f.id for f in self.factors]
        unknown = [i for i in ids if i not in ERROR_IDS]
        if unknown:
            raise SensitivityError(
                f"unknown error id(s) {', '.join(unknown)}; use ISO ids such as EXX or EB0Z"
            )
        if ids != [i for i in ERROR_IDS if i in ids]:
            raise SensitivityError("error factors must be distinct and in ERROR_IDS order")
        if not ids:
            raise SensitivityError("a sensitivity problem needs at least one varying error")
        bad_fixed = sorted(set(self.fixed) - set(ERROR_IDS))
        if bad_fixed:
            raise SensitivityError(f"fixed: unknown error id(s) {', '.join(bad_fixed)}")
        if self.spread is not None and ids != list(ERROR_IDS):
            raise SensitivityError("an identified problem has all 21 errors as factors")
        tool = self.machine.tool_offset_mm if self.tool_offset_mm is None else self.tool_offset_mm
        tool_vector = tuple(float(v) for v in tool)
        if len(tool_vector) != 3 or not all(math.isfinite(v) for v in tool_vector):
            raise SensitivityError(f"tool offset must be three finite numbers (mm), got {tool!r}")
        object.__setattr__(self, "tool_offset_mm", tool_vector)
        object.__setattr__(self, "factors", tuple(self.factors))
        object.__setattr__(self, "positions", _check_positions(self.machine, self.positions))

    @property
    def design_positions(self) -> bool:
        """True when X, Y, Z are factors of the design."""
        return isinstance(self.positions, str)

    @property
    def positions_mm(self) -> FloatArray | None:
        """Fixed positions (P, 3), or None when the positions are design factors."""
        return None if isinstance(self.positions, str) else self.positions

    @property
    def error_ids(self) -> tuple[str, ...]:
        return tuple(f.id for f in self.factors)

    @property
    def position_factors(self) -> tuple[Factor, ...]:
        if not self.design_positions:
            return ()
        return tuple(Factor(a, Uniform(*self.machine.stroke(a)), "mm") for a in AXES)

    @property
    def all_factors(self) -> tuple[Factor, ...]:
        """The design's factors: the errors, then X, Y, Z when positions are factors."""
        return self.factors + self.position_factors

    def describe(self) -> dict[str, object]:
        """A JSON-friendly description of the problem."""
        positions: object
        if self.design_positions:
            positions = {a: list(self.machine.stroke(a)) for a in AXES}
            mode = "design factors, uniform over the strokes"
        else:
            assert self.positions_mm is not None
            positions = self.positions_mm.tolist() if len(self.positions_mm) <= 8 else None
            mode = f"fixed: {len(self.positions_mm)} point(s), one analysis per point"
        return {
            "name": self.name,
            "machine": self.machine.name,
            "chain": self.machine.chain,
            "tool_offset_mm": list(self.tool_offset_mm or ()),
            "positions": mode,
            "positions_mm": positions,
            "factors": {
                f.id: {"unit": f.unit, **f.distribution.describe()} for f in self.all_factors
            },
            "fixed": dict(self.fixed),
            "identified": self.spread is not None,
        }


def _check_positions(machine: Machine, positions: str | ArrayLike) -> str | FloatArray:
    if isinstance(positions, str):
        if positions == "noise":
            raise PositionNoiseError(NOISE_EXPLANATION)
        if positions != "design":
            raise SensitivityError(
                f"positions {positions!r}: use 'design' or fixed positions (x, y, z) in mm"
            )
        return "design"
    q = np.atleast_2d(np.asarray(positions, dtype=float))
    if q.ndim != 2 or q.shape[1] != 3 or len(q) == 0:
        raise SensitivityError(f"positions must have shape (3,) or (P, 3) in mm, got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise SensitivityError("positions must be finite numbers (mm)")
    for axis in AXES:
        low, high = machine.stroke(axis)
        column = q[:, AXIS_INDEX[axis]]
        outside = (column < low - 1e-9) | (column > high + 1e-9)
        if np.any(outside):
            value = float(column[outside][0])
            raise SensitivityError(
                f"position {axis} = {value:g} mm lies outside the stroke [{low:g}, {high:g}] mm"
            )
    q = q.copy()
    q.setflags(write=False)
    return q


def workspace_grid(machine: Machine, step_mm: float) -> FloatArray:
    """Grid points (P, 3) covering the strokes, ends included, spacing about ``step_mm``."""
    if not (math.isfinite(step_mm) and step_mm > 0):
        raise SensitivityError(f"map step must be a positive length in mm, got {step_mm!r}")
    axes = []
    for axis in AXES:
        low, high = machine.stroke(axis)
        count = max(2, round((high - low) / step_mm) + 1)
        axes.append(np.linspace(low, high, count))
    grid = np.meshgrid(*axes, indexing="ij")
    return np.stack([g.ravel() for g in grid], axis=-1)


def problem_from_distributions(
    distributions: Mapping[str, Distribution],
    positions: str | ArrayLike = "design",
    machine: Machine = PAPER_MACHINE,
    tool_offset_mm: ArrayLike | None = None,
    fixed: Mapping[str, float] | None = None,
    name: str = "by hand",
) -> SensitivityProblem:
    """A problem by hand: ``{ISO id: distribution}`` (µm, µrad); other errors fixed (default 0)."""
    unknown = sorted(set(distributions) - set(ERROR_IDS))
    if unknown:
        raise SensitivityError(f"unknown error id(s) {', '.join(unknown)}")
    factors = tuple(
        Factor(eid, distributions[eid], ERROR_INFO[eid].unit)
        for eid in ERROR_IDS
        if eid in distributions
    )
    return SensitivityProblem(
        machine,
        factors,
        _positions_argument(positions),
        _tool_argument(tool_offset_mm),
        dict(fixed or {}),
        None,
        name,
    )


def _positions_argument(positions: str | ArrayLike) -> str | FloatArray:
    return positions if isinstance(positions, str) else np.asarray(positions, dtype=float)


def _tool_argument(tool_offset_mm: ArrayLike | None) -> tuple[float, float, float] | None:
    if tool_offset_mm is None:
        return None
    values = np.asarray(tool_offset_mm, dtype=float).ravel()
    if values.size != 3:
        raise SensitivityError(f"tool offset must be three numbers (mm), got {tool_offset_mm!r}")
    return (float(values[0]), float(values[1]), float(values[2]))


def paper_problem(
    positions: str | ArrayLike = "design", tool_offset_mm: ArrayLike | None = None
) -> SensitivityProblem:
    """The paper's Table 2: 21 normal errors on PAPER_MACHINE (D = (0, 0, 200) mm by default).

    Angles are converted from 1e-4 rad to µrad (×100) and the paper's Sxz to ISO's EB0Z = −Sxz.
    """
    # The paper module holds the published tables and imports this one for its comparison.
    from .paper import table2_iso

    distributions = {eid: Normal(mean, sd) for eid, (mean, sd) in table2_iso().items()}
    return problem_from_distributions(
        distributions, positions, PAPER_MACHINE, tool_offset_mm, name="paper Table 2"
    )


def problem_from_model(
    model: ErrorModel,
    covariance: ArrayLike | None,
    positions: str | ArrayLike = "design",
    spread: Mapping[str, float] | None = None,
    floor_um: float = 0.0,
    floor_urad: float = 0.0,
    tool_offset_mm: ArrayLike | None = None,
) -> SensitivityProblem:
    """The 21 identified error values as factors at the analysed positions.

    Each factor is a standard normal deviation ξ_i: the error value is μ_i(q) + σ_i(q)·ξ_i with
    μ the identified function and σ from ``covariance`` (P × P over ``model.parameters``)
    propagated through the basis, at least ``floor_um`` / ``floor_urad``; ``spread`` overrides σ
    per id. Without a covariance, give ``spread`` or the floors.
    """
    if covariance is None and not spread and floor_um <= 0 and floor_urad <= 0:
        raise SensitivityError(
            "no covariance: give a spread per error or a floor (floor_um, floor_urad) so that "
            "the errors vary"
        )
    identified = ErrorSpread(
        model,
        None if covariance is None else np.asarray(covariance, dtype=float),
        float(floor_um),
        float(floor_urad),
        dict(spread or {}),
    )
    factors = tuple(Factor(eid, Normal(0.0, 1.0), "sd") for eid in ERROR_IDS)
    return SensitivityProblem(
        model.machine,
        factors,
        _positions_argument(positions),
        _tool_argument(tool_offset_mm),
        {},
        identified,
        "identified model",
    )


# --------------------------------------------------------------------------------------------
# The volumetric error for sampled error values
# --------------------------------------------------------------------------------------------


def _axis_values(values: FloatArray) -> tuple[dict[str, ArrayLike], dict[str, ArrayLike]]:
    """compose_error's arguments for rows of 21 error values (S, 21) in ERROR_IDS order."""
    per_axis: dict[str, ArrayLike] = {a: values[:, 6 * k : 6 * k + 6] for k, a in enumerate(AXES)}
    square: dict[str, ArrayLike] = {sid: values[:, 18 + k] for k, sid in enumerate(SQUARENESS_IDS)}
    return per_axis, square


def chain_affine(
    machine: Machine, values: ArrayLike, tool_offset_mm: ArrayLike | None = None
) -> tuple[FloatArray, FloatArray]:
    """The exact chain as an affine function of the NC position for given error values.

    ``values`` (S, 21) holds position-independent error values in ``ERROR_IDS`` order (µm,
    µrad). Returns ``offset`` (S, 3) in µm and ``gain`` (S, 3, 3) in µm/mm with
    E(q) = offset + gain·q exactly: for the chain T(q1)E1·T(q2)E2·T(q3)E3·t (paper eq. 4)
    p = d1 + R1 d2 + R1R2 d3 + R1R2R3 t + q1 u1 + q2 R1 u2 + q3 R1R2 u3.
    """
    v = np.atleast_2d(np.asarray(values, dtype=float))
    if v.shape[1] != len(ERROR_IDS):
        raise SensitivityError(f"error values must have {len(ERROR_IDS)} columns, got {v.shape}")
    t = np.asarray(machine.tool_offset_mm if tool_offset_mm is None else tool_offset_mm, float)
    offset, gain = _chain_affine_components(machine, np.ascontiguousarray(v.T), t)
    return np.moveaxis(offset, 0, -1), np.moveaxis(gain, -1, 0)


def _chain_affine_components(
    machine: Machine, values: FloatArray, tool: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """:func:`chain_affine` with the run axis last: values (21, S) -> (3, S), (3, 3, S).

    Runs last keeps every 3×3 product an elementwise operation on long contiguous rows.
    """
    count = values.shape[1]
    # the axes' angles (rows 3-5, 9-11, 15-17) at once, the squareness (18-20) apart: it is
    # often the largest angle and would hold the others to the longer series
    sines, cosines = _sin_cos(values[[3, 4, 5, 9, 10, 11, 15, 16, 17]] * RAD_PER_URAD)
    (sc, sb, sa), (cc, cb, ca) = _sin_cos(values[18:21] * RAD_PER_URAD)
    directions = np.zeros((3, 3, count))  # directions[k] is the unit vector of axis k
    directions[0, 0] = 1.0
    directions[1, 0] = -sc
    directions[1, 1] = cc
    directions[2, 0] = sb * ca
    directions[2, 1] = -sa
    directions[2, 2] = cb * ca
    offset = np.zeros((3, count))
    gain = np.zeros((3, 3, count))
    prefix: FloatArray | None = None
    for axis in machine.axis_order:
        k = AXIS_INDEX[axis]
        translation = values[6 * k : 6 * k + 3] / UM_PER_MM
        if prefix is None:
            offset += translation
            gain[:, k] = directions[k]
        else:
            offset += np.einsum("ijs,js->is", prefix, translation)
            gain[:, k] = np.einsum("ijs,js->is", prefix, directions[k])
        gain[k, k] -= 1.0
        rotation = _rotations(sines[3 * k : 3 * k + 3], cosines[3 * k : 3 * k + 3])
        prefix = rotation if prefix is None else np.einsum("ijs,jks->iks", prefix, rotation)
    assert prefix is not None
    offset += np.einsum("ijs,j->is", prefix, tool) - tool[:, None]
    return offset * UM_PER_MM, gain * UM_PER_MM


def _sin_cos(x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """sin and cos of error angles (rad), exact to double precision.

    Error angles are small: below 1e-4 rad, sin = x(1 − x²/6) and cos = 1 − x²/2 leave out
    x⁵/120 and x⁴/24, under 1e-16 relative; below 1e-2 rad the series to x⁷ and x⁶ leave out
    terms under 1e-20 (as kinematics' kernel). Larger angles use sin and cos themselves.
    """
    largest = max(-x.min(), x.max()) if x.size else 0.0
    if largest >= 1e-2:
        return np.sin(x), np.cos(x)
    x2 = x * x
    if largest < 1e-4:
        sine = x2 * (-1.0 / 6.0)
        sine += 1.0
        sine *= x
        cosine = x2 * -0.5
        cosine += 1.0
        return sine, cosine
    # in place: these arrays hold every angle of every run
    sine = x2 * (-1.0 / 42.0)
    cosine = x2 * (-1.0 / 30.0)
    for sine_step, cosine_step in ((-1.0 / 20.0, -1.0 / 12.0), (-1.0 / 6.0, -1.0 / 2.0)):
        sine += 1.0
        sine *= x2
        sine *= sine_step
        cosine += 1.0
        cosine *= x2
        cosine *= cosine_step
    sine += 1.0
    sine *= x
    cosine += 1.0
    return sine, cosine


def _rotations(sines: FloatArray, cosines: FloatArray) -> FloatArray:
    """R = Rz(c)·Ry(b)·Rx(a) (as kinematics.rotation_matrices) from the sines and cosines of
    (a, b, c), each (3, S), with the runs last: (3, 3, S)."""
    sa, sb, sc = sines
    ca, cb, cc = cosines
    r = np.empty((3, 3) + sa.shape)
    r[0, 0] = cc * cb
    r[0, 1] = cc * sb * sa - sc * ca
    r[0, 2] = cc * sb * ca + sc * sa
    r[1, 0] = sc * cb
    r[1, 1] = sc * sb * sa + cc * ca
    r[1, 2] = sc * sb * ca - cc * sa
    r[2, 0] = -sb
    r[2, 1] = cb * sa
    r[2, 2] = cb * ca
    return r


def _error_values(problem: SensitivityProblem, rows: FloatArray) -> FloatArray:
    """The 21 error values (21, S) of a problem without spread, from its error factor rows."""
    values = np.zeros((len(ERROR_IDS), rows.shape[1]))
    for eid, value in problem.fixed.items():
        values[ERROR_IDS.index(eid)] = value
    for row, eid in enumerate(problem.error_ids):
        values[ERROR_IDS.index(eid)] = rows[row]
    return values


def _jacobian_21(model: ErrorModel, positions: FloatArray, tool: FloatArray) -> FloatArray:
    """dE/d(error values) at positions: (P, 3, 21) in µm per µm or µrad."""
    per_axis, square = error_value_jacobian(model, positions, tool)
    parts = [per_axis[a] for a in AXES] + [square[s][:, :, None] for s in SQUARENESS_IDS]
    return np.concatenate(parts, axis=-1)


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------


def _json_number(value: float) -> float | None:
    return None if not math.isfinite(value) else float(value)


def _json_safe(value: object) -> object:
    """Settings with NaN/inf as None and numpy scalars as Python numbers."""
    if isinstance(value, Mapping):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return _json_number(value)
    return value


def not_identified_note(floor_um: float = 0.01, floor_urad: float = 0.1) -> str:
    """What the * beside a ranked error the plan does not fully identify means."""
    return (
        "* not fully identified by this plan: what it varies by was not all measured (the floor "
        f"of {floor_um:g} µm, {floor_urad:g} µrad, or its share of a combination the plan sees), "
        "so its indices are not the machine's alone"
    )


@dataclass(frozen=True, eq=False)
class SensitivityResult:
    """EFAST indices of every output at every analysed position.

    Arrays have shape (outputs, points, factors) — one point when the positions were design
    factors — and hold the mean over the repeats; ``*_std`` is the standard deviation of the
    single-repeat estimates (NaN with one repeat), so the standard error of the mean is
    std/√repeats. ``variance_um2`` (outputs, points) is the output variance.
    ``not_identified``: the error factors the identification behind the analysis does not
    fully identify (its plan sees them not at all, in part, or only in a combination); what they
    vary by (the analysis' floor, or their share of the combination) was not all measured, so
    their indices are not the machine's alone.
    """

    outputs: tuple[str, ...]
    factor_ids: tuple[str, ...]
    positions_mm: FloatArray | None
    s1: FloatArray
    st: FloatArray
    s1_std: FloatArray
    st_std: FloatArray
    variance_um2: FloatArray
    settings: Mapping[str, object]
    not_identified: tuple[str, ...] = ()

    def _output(self, output: str) -> int:
        if output not in self.outputs:
            raise SensitivityError(f"output {output!r} was not analysed; have {self.outputs}")
        return self.outputs.index(output)

    def workspace(self, output: str) -> dict[str, FloatArray]:
        """Indices over all analysed points, weighted by the output variance at each point.

        S1_ws = Σ_p V_p·S1_p / Σ_p V_p: the share of the workspace-averaged variance of the output
        (positions uniform over the analysed points) that each factor explains. Standard
        deviations are combined with the same weights (an upper bound: all points share one
        design).
        """
        o = self._output(output)
        weights = self.variance_um2[o] / self.variance_um2[o].sum()
        return {
            "S1": weights @ self.s1[o],
            "ST": weights @ self.st[o],
            "S1_std": weights @ self.s1_std[o],
            "ST_std": weights @ self.st_std[o],
        }

    def indices(self, output: str, kind: str = "S1", point: int | None = None) -> dict[str, float]:
        """``{factor id: index}`` at one point, or over the workspace when ``point`` is None."""
        if kind not in ("S1", "ST", "S1_std", "ST_std"):
            raise SensitivityError(f"unknown index kind {kind!r}; use S1, ST, S1_std or ST_std")
        if point is None:
            values = self.workspace(output)[kind]
        else:
            arrays = {"S1": self.s1, "ST": self.st, "S1_std": self.s1_std, "ST_std": self.st_std}
            values = arrays[kind][self._output(output), point]
        return {fid: float(v) for fid, v in zip(self.factor_ids, values, strict=True)}

    def top(self, output: str, kind: str = "S1", count: int = 6) -> list[tuple[str, float]]:
        """The ``count`` largest workspace indices, largest first."""
        ranked = sorted(self.indices(output, kind).items(), key=lambda item: -item[1])
        return ranked[:count]

    def to_report(self) -> dict[str, dict[str, object]]:
        """DESIGN.md report.json ``sensitivity``: {output: {"S1": {id: v}, "ST": {id: v}, ...}}.

        Keys are ISO error ids; workspace values for maps. Extra keys per output: ``S1_std``,
        ``ST_std``; when positions were factors, ``positions`` with their S1 and ST; when the
        identification left errors unidentified, ``not_identified`` with their ids.
        """
        out: dict[str, dict[str, object]] = {}
        errors = [i for i in self.factor_ids if i in ERROR_IDS]
        for name in self.outputs:
            ws = self.workspace(name)
            entry: dict[str, object] = {}
            for kind in ("S1", "ST", "S1_std", "ST_std"):
                values = dict(zip(self.factor_ids, ws[kind], strict=True))
                entry[kind] = {i: _json_number(values[i]) for i in errors}
            positions = [i for i in self.factor_ids if i in AXES]
            if positions:
                entry["positions"] = {
                    kind: {
                        a: _json_number(dict(zip(self.factor_ids, ws[kind], strict=True))[a])
                        for a in positions
                    }
                    for kind in ("S1", "ST")
                }
            if self.not_identified:
                entry["not_identified"] = list(self.not_identified)
            out[name] = entry
        return out

    def to_dict(self) -> dict[str, object]:
        """Everything, JSON-friendly (NaN as null); inverse of :meth:`from_dict`."""

        def listed(array: FloatArray) -> list[object]:
            return [_json_number(v) for v in array.ravel()]

        return {
            "outputs": list(self.outputs),
            "factors": list(self.factor_ids),
            "positions_mm": None if self.positions_mm is None else self.positions_mm.tolist(),
            "shape": list(self.s1.shape),
            "S1": listed(self.s1),
            "ST": listed(self.st),
            "S1_std": listed(self.s1_std),
            "ST_std": listed(self.st_std),
            "variance_um2": listed(self.variance_um2),
            "settings": _json_safe(self.settings),
            "not_identified": list(self.not_identified),
        }

    def to_tree(self) -> dict[str, object]:
        """Arrays and a JSON settings string, for the project's /sensitivity/<name> group."""
        positions = np.zeros((0, 3)) if self.positions_mm is None else self.positions_mm
        tree: dict[str, object] = {
            "outputs": list(self.outputs),
            "factors": list(self.factor_ids),
            "positions_mm": np.asarray(positions, dtype=float),
            "design_positions": self.positions_mm is None,
            "S1": self.s1,
            "ST": self.st,
            "S1_std": self.s1_std,
            "ST_std": self.st_std,
            "variance_um2": self.variance_um2,
            "settings_json": json.dumps(_json_safe(self.settings), allow_nan=False),
            "report_json": json.dumps(self.to_report(), allow_nan=False),
        }
        if self.not_identified:
            tree["not_identified"] = list(self.not_identified)
        return tree

    @classmethod
    def from_tree(cls, tree: Mapping[str, object]) -> SensitivityResult:
        """Inverse of :meth:`to_tree`."""
        positions = None if tree["design_positions"] else np.asarray(tree["positions_mm"], float)
        return cls(
            tuple(str(v) for v in tree["outputs"]),  # type: ignore[attr-defined]
            tuple(str(v) for v in tree["factors"]),  # type: ignore[attr-defined]
            positions,
            np.asarray(tree["S1"], dtype=float),
            np.asarray(tree["ST"], dtype=float),
            np.asarray(tree["S1_std"], dtype=float),
            np.asarray(tree["ST_std"], dtype=float),
            np.asarray(tree["variance_um2"], dtype=float),
            json.loads(str(tree["settings_json"])),
            tuple(str(v) for v in tree.get("not_identified", ())),  # type: ignore[attr-defined]
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> SensitivityResult:
        shape = tuple(int(v) for v in data["shape"])  # type: ignore[attr-defined]

        def array(key: str, dims: tuple[int, ...]) -> FloatArray:
            raw = [np.nan if v is None else float(v) for v in data[key]]  # type: ignore[attr-defined]
            return np.asarray(raw, dtype=float).reshape(dims)

        positions = data.get("positions_mm")
        return cls(
            tuple(data["outputs"]),  # type: ignore[arg-type]
            tuple(data["factors"]),  # type: ignore[arg-type]
            None if positions is None else np.asarray(positions, dtype=float),
            array("S1", shape),
            array("ST", shape),
            array("S1_std", shape),
            array("ST_std", shape),
            array("variance_um2", shape[:2]),
            dict(data.get("settings", {})),  # type: ignore[call-overload]
            tuple(data.get("not_identified", ())),  # type: ignore[arg-type]
        )


# --------------------------------------------------------------------------------------------
# The analysis
# --------------------------------------------------------------------------------------------


def analyse(
    problem: SensitivityProblem,
    outputs: Sequence[str | Output] | str | Output = OUTPUT_NAMES,
    n: int = 1400,
    m: int = 4,
    seed: int | None = None,
    repeats: int = 4,
    method: str = "tail",
    chain: str = "auto",
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
) -> SensitivityResult:
    """EFAST S1 and ST of every output for ``problem``.

    Parameters
    ----------
    n : samples per search curve (per factor); the model runs n × factors × repeats times per
        point (the paper: n = 1400).
    m : interference factor M (harmonics read for S1).
    seed : seed of the random phases; None draws one (recorded in the settings).
    repeats : independent designs (random phases); their spread is the reported uncertainty.
    method : ``"tail"`` (default: restores the harmonics the main effects put beyond the classic
        bands and removes the sampling error of the inputs) or ``"classic"`` (SALib's
        estimator); see :mod:`.efast` and docs/sensitivity.md.
    chain : for identified (position-dependent) errors at fixed positions: ``"exact"``,
        ``"linear"`` (about the identified values, exact Jacobian) or ``"auto"`` (exact up to a
        few million evaluations). Table-2 style problems always use the exact chain.
    """
    targets = resolve_outputs(outputs)
    if chain not in CHAINS:
        raise SensitivityError(f"unknown chain {chain!r}; use one of {', '.join(CHAINS)}")
    factors = problem.all_factors
    design = efast_design(len(factors), n, m, seed, repeats)
    columns = design.value_columns([f.distribution for f in factors])
    tails = None
    if method == "tail":
        tails = MainEffectTails.from_columns(columns, m, [f.distribution for f in factors])
    rows = columns.reshape(len(factors), -1)  # one row per factor, runs in block order
    check(cancel)
    if problem.design_positions:
        error = _design_error(problem, rows)
        q = rows[-3:]
        block = (repeats, len(factors), n)
        parts = [
            efast_indices(o.function(error, q).reshape(block), m, method=method, tails=tails)
            for o in targets
        ]
        s1, st, variance = (np.stack([p[k] for p in parts])[:, None] for k in range(3))
        used_chain = "exact"
        report(progress, 1.0, "sensitivity: done")
    else:
        s1, st, variance, used_chain = _map_indices(
            problem, targets, design, rows, tails, method, chain, progress, cancel
        )
    settings = {
        "n": n,
        "m": m,
        "seed": design.seed,
        "repeats": repeats,
        "method": method,
        "chain": used_chain,
        "omega": design.omega,
        "complementary_frequencies": [
            int(design.complementary.min(initial=0)),
            int(design.complementary.max(initial=0)),
        ],
        "runs_per_point": design.runs,
        "problem": problem.describe(),
    }
    return SensitivityResult(
        tuple(o.name for o in targets),
        tuple(f.id for f in factors),
        None if problem.positions_mm is None else np.array(problem.positions_mm),
        s1.mean(axis=-2),
        st.mean(axis=-2),
        repeat_std(s1),
        repeat_std(st),
        variance.mean(axis=(-2, -1)),
        settings,
    )


def _design_error(problem: SensitivityProblem, rows: FloatArray) -> FloatArray:
    """Exact E (3, S) for factor rows (F, S) whose last three rows are X, Y, Z."""
    q = np.ascontiguousarray(rows[-3:].T)
    if problem.spread is None:
        values = _error_values(problem, rows[:-3]).T
    else:
        mean, sd = problem.spread.mean_sd(q)
        values = mean + sd * rows[:-3].T
    per_axis, square = _axis_values(values)
    return compose_error(problem.machine, q, per_axis, square, problem.tool_offset_mm).T


def _map_indices(
    problem: SensitivityProblem,
    targets: tuple[Output, ...],
    design: EfastDesign,
    rows: FloatArray,
    tails: MainEffectTails | None,
    method: str,
    chain: str,
    progress: ProgressCallback | None,
    cancel: CancelToken | None,
) -> tuple[FloatArray, FloatArray, FloatArray, str]:
    """Indices at every fixed position, evaluated and analysed in chunks of points."""
    positions = problem.positions_mm
    assert positions is not None
    points = len(positions)
    runs = rows.shape[1]
    tool = np.asarray(problem.tool_offset_mm, dtype=float)
    shape = (len(targets), points, design.repeats, design.factors)
    s1, st, variance = np.empty(shape), np.empty(shape), np.empty(shape)
    evaluator: _AffineErrors | _LinearisedErrors | None = None
    if problem.spread is None:
        offset, gain = _chain_affine_components(problem.machine, _error_values(problem, rows), tool)
        evaluator = _AffineErrors(offset, gain, design)
        used = "exact"
    elif chain == "linear" or (chain == "auto" and points * runs > _EXACT_LIMIT):
        evaluator = _LinearisedErrors(problem, rows, tool, design)
        used = "linear"
    else:
        used = "exact"
    chunk = max(1, _CHUNK_EVALUATIONS // runs)
    block = (design.repeats, design.factors, design.n)
    for start in range(0, points, chunk):
        check(cancel)
        q = positions[start : start + chunk]
        error: FloatArray | None = None
        for k, target in enumerate(targets):
            # the shortcuts pay off from a few points on (their set-up costs a few transforms)
            shortcut = evaluator is not None and points >= _SHORTCUT_POINTS
            if shortcut and target in _COMPONENTS:
                assert evaluator is not None
                bins = evaluator.component_bins(_COMPONENTS[target], q)
                a, b, c = spectral_indices(*bins, design.m, method, tails)
            else:
                if shortcut and isinstance(evaluator, _AffineErrors) and target == _TOTAL:
                    values = evaluator.total(q)
                else:
                    if error is None:
                        error = (
                            _exact_spread_error(problem, q, rows, tool)
                            if evaluator is None
                            else evaluator.error(q)
                        )
                    values = target.function(error, np.broadcast_to(q.T[:, :, None], error.shape))
                shaped = values.reshape((len(q),) + block)
                a, b, c = efast_indices(shaped, design.m, method=method, tails=tails)
            s1[k, start : start + len(q)] = a
            st[k, start : start + len(q)] = b
            variance[k, start : start + len(q)] = c
        report(progress, min(start + chunk, points) / points, "sensitivity: map")
    return s1, st, variance, used


class _LinearSeries:
    """What EFAST reads of outputs that are weighted sums of run series, y_p = Σ_a w_pa·x_a.

    The spectrum of y_p at a bin is the same weighted sum of the series' spectra, and its
    variance the quadratic form of their covariance: a map needs one transform per series, not
    one per point. (The products here have a few terms: einsum, not BLAS, whose threads add tens
    of milliseconds per call on busy cores.)
    """

    def __init__(self, series: FloatArray, design: EfastDesign) -> None:
        # series (outputs, terms, repeats, factors, n)
        n = design.n
        omega = design.omega
        centred = series - series.mean(axis=-1, keepdims=True)
        spectrum = scipy.fft.rfft(centred, axis=-1, workers=fft_workers(centred.size)) / n
        self.shape = (design.repeats, design.factors)
        # the bins EFAST reads, as real and imaginary parts (outputs, terms, everything else)
        read = np.concatenate(
            [spectrum[..., np.arange(1, design.m + 1) * omega], spectrum[..., 1 : omega // 2 + 1]],
            axis=-1,
        )
        self.harmonic_count = design.m
        self.read_real = np.ascontiguousarray(read.real.reshape(read.shape[:2] + (-1,)))
        self.read_imag = np.ascontiguousarray(read.imag.reshape(read.shape[:2] + (-1,)))
        self.bin_count = read.shape[-1]
        # V = 2·Σ_{k=1}^{⌈n/2⌉−1}|F_k/n|² (the Nyquist bin of an even n is left out): by
        # Parseval the covariance of the series less the Nyquist term.
        blocks = np.moveaxis(centred, 1, -2)  # (outputs, repeats, factors, terms, n)
        covariance = np.einsum("orfan,orfbn->orfab", blocks, blocks) / n
        if n % 2 == 0:
            nyquist = np.moveaxis(spectrum[..., n // 2].real, 1, -1)
            covariance -= nyquist[..., :, None] * nyquist[..., None, :]
        # (outputs, terms, repeats·factors·terms): one matrix product per chunk of points
        terms = series.shape[1]
        self.covariance = np.ascontiguousarray(
            np.moveaxis(covariance, -2, 1).reshape(len(series), terms, -1)
        )

    def bins(
        self, output: int, weights: FloatArray
    ) -> tuple[FloatArray, NDArray[np.complex128], NDArray[np.complex128]]:
        """(V, harmonic bins, low bins) of output ``output`` for weights (points, terms)."""
        w = np.ascontiguousarray(weights)
        points, terms = w.shape
        half = np.einsum("pa,ak->pk", w, self.covariance[output])
        half = half.reshape((points,) + self.shape + (terms,))
        variance = np.einsum("prfb,pb->prf", half, w)
        read = np.einsum("pa,ak->pk", w, self.read_real[output]) + 1j * np.einsum(
            "pa,ak->pk", w, self.read_imag[output]
        )
        read = read.reshape((points,) + self.shape + (self.bin_count,))
        return variance, read[..., : self.harmonic_count], read[..., self.harmonic_count :]


# The ten products w_a·w_b of w = (1, x, y, z) in |offset + gain·q|² = Σ q_ab·w_a·w_b.
_PAIRS = ((0, 0), (1, 1), (2, 2), (3, 3), (0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))


class _AffineErrors:
    """E = offset + gain·q at any position for position-independent errors (exact).

    Each component is linear in w = (1, q) over four run series (offset and the three gain
    columns), and ET² is a quadratic form in w with ten coefficients per run: one product per
    chunk of points instead of an evaluation of E.
    """

    def __init__(self, offset: FloatArray, gain: FloatArray, design: EfastDesign) -> None:
        self.offset = offset  # (3, S)
        self.gain = gain  # (3, 3, S)
        self.design = design

    @cached_property
    def series(self) -> _LinearSeries:
        series = np.concatenate([self.offset[:, None, :], self.gain], axis=1)  # (component, 4, S)
        design = self.design
        return _LinearSeries(series.reshape(3, 4, design.repeats, design.factors, design.n), design)

    @cached_property
    def square(self) -> FloatArray:
        series = np.concatenate([self.offset[:, None, :], self.gain], axis=1)
        return np.stack(
            [
                (1.0 if a == b else 2.0) * np.einsum("cs,cs->s", series[:, a], series[:, b])
                for a, b in _PAIRS
            ]
        )

    def component_bins(
        self, component: int, q: FloatArray
    ) -> tuple[FloatArray, NDArray[np.complex128], NDArray[np.complex128]]:
        return self.series.bins(component, np.column_stack([np.ones(len(q)), q]))

    def total(self, q: FloatArray) -> FloatArray:
        """ET (P, S) at positions q: √(wᵀ·Q_s·w) with w = (1, q)."""
        w = np.column_stack([np.ones(len(q)), q])
        monomials = np.column_stack([w[:, a] * w[:, b] for a, b in _PAIRS])
        squared = np.einsum("pa,as->ps", monomials, self.square)
        np.maximum(squared, 0.0, out=squared)
        return np.sqrt(squared, out=squared)

    def error(self, q: FloatArray) -> FloatArray:
        """E (3, P, S) at positions q."""
        out = np.empty((3, len(q), self.offset.shape[1]))
        for i in range(3):
            # E_i[p, s] = offset[i, s] + Σ_k q[p, k]·gain[i, k, s]
            np.einsum("pk,ks->ps", q, self.gain[i], out=out[i])
            out[i] += self.offset[i]
        return out


class _LinearisedErrors:
    """Identified errors linearised about their values at each position (``chain="linear"``).

    E(q, ξ) = E(q) + J(q)·diag(σ(q))·ξ with the exact Jacobian J: each component is a weighted sum
    of the factor rows ξ with weights that depend on the position only. The weights of the last
    chunk of positions are kept, since every output of a chunk needs them.
    """

    def __init__(
        self,
        problem: SensitivityProblem,
        rows: FloatArray,
        tool: FloatArray,
        design: EfastDesign,
    ) -> None:
        assert problem.spread is not None
        self.spread = problem.spread
        self.volumetric = VolumetricModel(problem.spread.model)
        self.rows = rows  # (21, S)
        self.tool = tool
        self.series = _LinearSeries(
            rows.reshape(1, len(rows), design.repeats, design.factors, design.n), design
        )
        self._chunk: tuple[FloatArray, FloatArray, FloatArray] | None = None

    def _weights(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        if self._chunk is None or self._chunk[0] is not q:
            model = self.spread.model
            _, sd = self.spread.mean_sd(q)
            nominal = self.volumetric.error(q, self.tool)  # (P, 3)
            weights = _jacobian_21(model, q, self.tool) * sd[:, None, :]  # (P, 3, 21)
            self._chunk = (q, nominal, weights)
        return self._chunk[1], self._chunk[2]

    def component_bins(
        self, component: int, q: FloatArray
    ) -> tuple[FloatArray, NDArray[np.complex128], NDArray[np.complex128]]:
        _, weights = self._weights(q)
        return self.series.bins(0, weights[:, component])

    def error(self, q: FloatArray) -> FloatArray:
        """E (3, P, S) at positions q."""
        nominal, weights = self._weights(q)
        out = np.empty((3, len(q), self.rows.shape[1]))
        for i in range(3):
            np.matmul(np.ascontiguousarray(weights[:, i]), self.rows, out=out[i])
            out[i] += nominal[:, i, None]
        return out


def _exact_spread_error(
    problem: SensitivityProblem, q: FloatArray, rows: FloatArray, tool: FloatArray
) -> FloatArray:
    """Exact E (3, P, S) at each position for standardised deviations ``rows`` (21, S)."""
    assert problem.spread is not None
    mean, sd = problem.spread.mean_sd(q)
    out = np.empty((3, len(q), rows.shape[1]))
    for p in range(len(q)):
        values = (mean[p][:, None] + sd[p][:, None] * rows).T
        per_axis, square = _axis_values(values)
        where = np.broadcast_to(q[p], (rows.shape[1], 3))
        out[:, p] = compose_error(problem.machine, where, per_axis, square, tool).T
    return out


# --------------------------------------------------------------------------------------------
# One call for an identified model
# --------------------------------------------------------------------------------------------


def analyse_model(
    model: ErrorModel,
    covariance: ArrayLike | None,
    output: Sequence[str | Output] | str | Output = OUTPUT_NAMES,
    map_step_mm: float | None = None,
    position_mm: ArrayLike | None = None,
    n: int = 1400,
    m: int = 4,
    seed: int | None = 0,
    repeats: int = 4,
    method: str = "tail",
    spread: Mapping[str, float] | None = None,
    floor_um: float = 0.01,
    floor_urad: float = 0.1,
    tool_offset_mm: ArrayLike | None = None,
    not_identified: Collection[str] = (),
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
) -> SensitivityResult:
    """Sensitivity of an identified model: everything but file I/O.

    Positions: a map on a grid of about ``map_step_mm`` when given, else one ``position_mm``,
    else X, Y, Z as design factors (uniform over the strokes; their indices then measure how much
    of the output's variation over the workspace comes from where the tool is). The errors vary
    by their identification uncertainty (``covariance``), at least ``floor_um`` / ``floor_urad``.
    ``not_identified``: the errors the identification's plan cannot see (its identifiability's
    ``unidentifiable_ids``), carried into the result so every ranking can mark them.
    """
    if map_step_mm is not None and position_mm is not None:
        raise SensitivityError("give either a map step or one position, not both")
    positions: str | ArrayLike
    if map_step_mm is not None:
        positions = workspace_grid(model.machine, map_step_mm)
    elif position_mm is not None:
        positions = position_mm
    else:
        positions = "design"
    problem = problem_from_model(
        model, covariance, positions, spread, floor_um, floor_urad, tool_offset_mm
    )
    result = analyse(problem, output, n, m, seed, repeats, method, progress=progress, cancel=cancel)
    return replace(result, not_identified=tuple(sorted(set(not_identified))))


# --------------------------------------------------------------------------------------------
# Tolerance allocation (paper section 4.1, eq. 19)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ToleranceAllocation:
    """Standard deviations allowed for each error's compensation value.

    ``published``: the paper's eq. 19 as printed, S_i = 6σ_i²/T, so σ_i = √(S_i·T/6) (T in µm;
    the result is a length only formally — it reproduces the paper's Table 3 for the length
    errors). ``allowed``: the dimensionally sound form — T is the ±3σ band of the output, so its
    standard deviation is T/6; error i may use the share S_i of that variance, σ_out,i =
    √S_i·T/6, and its own standard deviation is σ_out,i divided by its sensitivity coefficient
    (RMS over the analysed positions of ∂output/∂error, µm per µm or µm per µrad).
    """

    output: str
    tolerance_um: float
    s1: Mapping[str, float]
    published: Mapping[str, float]
    output_share_um: Mapping[str, float]
    coefficient: Mapping[str, float]
    allowed: Mapping[str, float]
    units: Mapping[str, str]

    def to_dict(self) -> dict[str, object]:
        return {
            "output": self.output,
            "tolerance_um": self.tolerance_um,
            "S1": dict(self.s1),
            "eq19_published": dict(self.published),
            "output_share_um": dict(self.output_share_um),
            "coefficient_um_per_unit": dict(self.coefficient),
            "allowed_sd": dict(self.allowed),
            "units": dict(self.units),
        }


def allocate_tolerances(
    result: SensitivityResult,
    problem: SensitivityProblem,
    output: str = "ET",
    tolerance_um: float = 25.0,
) -> ToleranceAllocation:
    """Eq. 19 as published and in its dimensionally sound form, from the workspace S1."""
    if not (math.isfinite(tolerance_um) and tolerance_um > 0):
        raise SensitivityError(f"tolerance must be a positive length in µm, got {tolerance_um!r}")
    s1 = {k: max(v, 0.0) for k, v in result.indices(output, "S1").items() if k in ERROR_IDS}
    coefficient = sensitivity_coefficients(problem, output, result.positions_mm)
    published = {k: math.sqrt(v * tolerance_um / 6.0) for k, v in s1.items()}
    share = {k: math.sqrt(v) * tolerance_um / 6.0 for k, v in s1.items()}
    output_sd = math.sqrt(float(np.mean(result.variance_um2[result.outputs.index(output)])))
    spread = _factor_spreads(problem)
    allowed = {}
    for k in s1:
        # An error whose first-order effect is below 1e-3 of the output's spread (S1 < 1e-6)
        # acts only through products with other errors: the tolerance does not bind it.
        bound = coefficient[k] * spread[k] > 1e-3 * output_sd
        allowed[k] = share[k] / coefficient[k] if bound else math.inf
    units = {k: ERROR_INFO[k].unit for k in s1}
    return ToleranceAllocation(
        output, float(tolerance_um), s1, published, share, coefficient, allowed, units
    )


def _factor_spreads(problem: SensitivityProblem) -> dict[str, float]:
    """Each error's standard deviation (µm, µrad), the largest over the analysed positions."""
    if problem.spread is None:
        return {f.id: f.distribution.std for f in problem.factors}
    positions = problem.positions_mm
    if positions is None:
        positions = workspace_grid(problem.machine, 50.0)
    _, sd = problem.spread.mean_sd(positions)
    return {eid: float(v) for eid, v in zip(ERROR_IDS, sd.max(axis=0), strict=True)}


def sensitivity_coefficients(
    problem: SensitivityProblem, output: str, positions_mm: ArrayLike | None = None
) -> dict[str, float]:
    """RMS over positions of ∂output/∂(error value) at the mean values (µm per µm or µrad).

    Central differences of one standard deviation of each error: the chain is affine in every
    single error to well below 1e-6 of the output over such steps.
    """
    target = resolve_outputs(output)[0]
    if positions_mm is None:
        positions_mm = problem.positions_mm
    if positions_mm is None:
        positions_mm = workspace_grid(problem.machine, 50.0)
    q = np.atleast_2d(np.asarray(positions_mm, dtype=float))
    tool = np.asarray(problem.tool_offset_mm, dtype=float)
    ids = problem.error_ids
    if problem.spread is None:
        means = np.array([[f.distribution.mean] for f in problem.factors])
        mean = _error_values(problem, means).T
        step = np.array([f.distribution.std for f in problem.factors])
        base = np.repeat(mean, 2 * len(ids), axis=0)
        for k, eid in enumerate(ids):
            base[2 * k, ERROR_IDS.index(eid)] += step[k]
            base[2 * k + 1, ERROR_IDS.index(eid)] -= step[k]
        offset, gain = chain_affine(problem.machine, base, tool)
        error = np.einsum("sij,pj->ips", gain, q) + offset.T[:, None, :]
        values = target.function(error, np.broadcast_to(q.T[:, :, None], error.shape))
        slope = (values[:, 0::2] - values[:, 1::2]) / (2.0 * step[None, :])
    else:
        mean, sd = problem.spread.mean_sd(q)
        step = np.maximum(sd, 1e-3)
        slope = np.empty((len(q), len(ids)))
        for k in range(len(ids)):
            sides = []
            for sign in (1.0, -1.0):
                shifted = mean.copy()
                shifted[:, k] += sign * step[:, k]
                per_axis, square = _axis_values(shifted)
                error = compose_error(problem.machine, q, per_axis, square, tool)
                sides.append(target.function(error.T, q.T))
            slope[:, k] = (sides[0] - sides[1]) / (2.0 * step[:, k])
    rms = np.sqrt(np.mean(np.square(slope), axis=0))
    return {eid: float(v) for eid, v in zip(ids, rms, strict=True)}


__all__ = [
    "BUILTIN_OUTPUTS",
    "ErrorSpread",
    "Factor",
    "NOISE_EXPLANATION",
    "OUTPUT_NAMES",
    "Output",
    "PositionNoiseError",
    "SensitivityError",
    "SensitivityProblem",
    "SensitivityResult",
    "ToleranceAllocation",
    "allocate_tolerances",
    "analyse",
    "analyse_model",
    "chain_affine",
    "paper_problem",
    "problem_from_distributions",
    "problem_from_model",
    "resolve_outputs",
    "sensitivity_coefficients",
    "workspace_grid",
]
