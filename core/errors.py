"""The 21 geometric error components, their bases and the error model.

Ids and signs follow ISO 230-1 with right-hand rotations (DESIGN.md, "Conventions"). For an axis J:
``EXJ, EYJ, EZJ`` are the translational errors of J in µm (``EJJ`` is the positioning error, the two
others its straightness), ``EAJ, EBJ, ECJ`` its rotations about X, Y and Z in µrad. Squareness:
``EC0Y`` (Y to X, about Z), ``EB0Z`` (Z to X, about Y), ``EA0Z`` (Z to Y, about X), in µrad.

The paper's symbols are display aliases only: δx(x) = EXX, εz(y) = ECY, Sxy = EC0Y, Syz = EA0Z and
**Sxz = −EB0Z** (the paper's eq. 3 writes x = −z·Sxz, ISO's EB0Z gives x = +z·EB0Z).

Every error function is a linear combination of basis functions over the axis stroke, so that
identification stays linear in its coefficients.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .machine import AXES, Machine

FloatArray = NDArray[np.float64]

#: Error components of one axis, in the column order used everywhere in volucal.
COMPONENTS = ("X", "Y", "Z", "A", "B", "C")
SQUARENESS_IDS = ("EC0Y", "EB0Z", "EA0Z")


def axis_error_ids(axis: str) -> tuple[str, ...]:
    """``("EXX", "EYX", "EZX", "EAX", "EBX", "ECX")`` for ``axis="X"``."""
    return tuple(f"E{c}{axis}" for c in COMPONENTS)


AXIS_ERROR_IDS: tuple[str, ...] = tuple(i for a in AXES for i in axis_error_ids(a))
ERROR_IDS: tuple[str, ...] = AXIS_ERROR_IDS + SQUARENESS_IDS

_PAPER_LETTER = {"X": "x", "Y": "y", "Z": "z"}
_ROTATION_LETTER = {"A": "x", "B": "y", "C": "z"}


@dataclass(frozen=True)
class ErrorInfo:
    """Static description of one error component."""

    id: str
    axis: str | None  # the moving axis, None for squareness
    component: str  # X, Y, Z (translation) or A, B, C (rotation); squareness: its rotation
    kind: str  # positioning, straightness, roll, pitch, yaw, tilt, squareness
    unit: str  # "um" or "urad"
    paper: str  # the paper's symbol, for display
    paper_sign: int  # value in the paper's symbol = paper_sign * ISO value
    description: str

    @property
    def is_straightness(self) -> bool:
        return self.kind == "straightness"


def _axis_kind(axis: str, component: str) -> str:
    if component == axis:
        return "positioning"
    if component in "XYZ":
        return "straightness"
    rotation_axis = {"A": "X", "B": "Y", "C": "Z"}[component]
    if rotation_axis == axis:
        return "roll"
    # Vertical mill naming: X and Y pitch about the horizontal axis across them, yaw about Z;
    # the vertical Z axis tilts about X and Y.
    if axis == "Z":
        return "tilt"
    return "yaw" if component == "C" else "pitch"


def _build_info() -> dict[str, ErrorInfo]:
    info: dict[str, ErrorInfo] = {}
    for axis in AXES:
        q = _PAPER_LETTER[axis]
        for component in COMPONENTS:
            eid = f"E{component}{axis}"
            kind = _axis_kind(axis, component)
            if component in "XYZ":
                paper = f"δ{_PAPER_LETTER[component]}({q})"
                unit = "um"
                what = f"{kind} error of {axis} in {component}"
            else:
                paper = f"ε{_ROTATION_LETTER[component]}({q})"
                unit = "urad"
                what = f"{kind} of {axis} (rotation about {_ROTATION_LETTER[component].upper()})"
            info[eid] = ErrorInfo(eid, axis, component, kind, unit, paper, 1, what)
    info["EC0Y"] = ErrorInfo(
        "EC0Y", None, "C", "squareness", "urad", "Sxy", 1, "squareness of Y to X (about Z)"
    )
    info["EB0Z"] = ErrorInfo(
        "EB0Z", None, "B", "squareness", "urad", "Sxz", -1, "squareness of Z to X (about Y)"
    )
    info["EA0Z"] = ErrorInfo(
        "EA0Z", None, "A", "squareness", "urad", "Syz", 1, "squareness of Z to Y (about X)"
    )
    return info


ERROR_INFO: Mapping[str, ErrorInfo] = _build_info()


def error_label(eid: str) -> str:
    """Display label ``"EXX δx(x)"``; files and APIs use the ISO id alone."""
    info = ERROR_INFO[eid]
    sign = "−" if info.paper_sign < 0 else ""
    return f"{eid} ({sign}{info.paper})"


# --------------------------------------------------------------------------------------------
# Bases
# --------------------------------------------------------------------------------------------


class Basis:
    """A linear basis over an axis stroke ``[low, high]`` (mm).

    Subclasses return the design matrix (n positions × ``size`` functions); positions outside the
    stroke are clamped to its ends (an error function is only defined where the axis travels).
    """

    kind: str = ""
    low: float
    high: float

    @property
    def size(self) -> int:
        raise NotImplementedError

    def design(self, position_mm: ArrayLike) -> FloatArray:
        raise NotImplementedError

    def evaluate(self, position_mm: ArrayLike, coefficients: ArrayLike) -> FloatArray:
        """Values of the combination ``design(q) @ coefficients`` (fast path where possible)."""
        return self.design(position_mm) @ np.asarray(coefficients, dtype=float)

    def describe(self) -> dict[str, object]:
        """A JSON-friendly description (``report.json`` "basis")."""
        raise NotImplementedError

    def _clamp(self, position_mm: ArrayLike) -> FloatArray:
        return np.clip(np.asarray(position_mm, dtype=float), self.low, self.high)


@dataclass(frozen=True, eq=False)
class ConstantBasis(Basis):
    """One function, 1 everywhere. Under the zero-at-reference gauge it leaves no freedom:
    an error given this basis is modelled as identically zero."""

    low: float
    high: float
    kind: str = "constant"

    @property
    def size(self) -> int:
        return 1

    def design(self, position_mm: ArrayLike) -> FloatArray:
        q = np.atleast_1d(self._clamp(position_mm))
        return np.ones((q.size, 1))

    def describe(self) -> dict[str, object]:
        return {"kind": self.kind, "domain_mm": [self.low, self.high]}


@dataclass(frozen=True, eq=False)
class PolynomialBasis(Basis):
    """Legendre polynomials P0..P_degree on the stroke mapped to [-1, 1]."""

    low: float
    high: float
    degree: int = 3
    kind: str = "polynomial"

    def __post_init__(self) -> None:
        if self.degree < 0:
            raise ValueError(f"polynomial degree must be >= 0, got {self.degree}")

    @property
    def size(self) -> int:
        return self.degree + 1

    def _s(self, position_mm: ArrayLike) -> FloatArray:
        q = self._clamp(position_mm)
        return (2.0 * q - (self.low + self.high)) / (self.high - self.low)

    def design(self, position_mm: ArrayLike) -> FloatArray:
        s = np.atleast_1d(self._s(position_mm))
        return np.polynomial.legendre.legvander(s, self.degree)

    def evaluate(self, position_mm: ArrayLike, coefficients: ArrayLike) -> FloatArray:
        return np.asarray(np.polynomial.legendre.legval(self._s(position_mm), coefficients))

    def describe(self) -> dict[str, object]:
        return {"kind": self.kind, "degree": self.degree, "domain_mm": [self.low, self.high]}


@dataclass(frozen=True, eq=False)
class BSplineBasis(Basis):
    """Clamped cubic B-splines with the given breakpoints (including both stroke ends)."""

    breakpoints_mm: tuple[float, ...]
    degree: int = 3
    kind: str = "bspline"

    def __post_init__(self) -> None:
        points = tuple(float(b) for b in self.breakpoints_mm)
        if len(points) < 2 or any(b <= a for a, b in zip(points, points[1:], strict=False)):
            raise ValueError(f"B-spline breakpoints must be strictly increasing: {points}")
        object.__setattr__(self, "breakpoints_mm", points)

    @property
    def low(self) -> float:  # type: ignore[override]
        return self.breakpoints_mm[0]

    @property
    def high(self) -> float:  # type: ignore[override]
        return self.breakpoints_mm[-1]

    @cached_property
    def knots(self) -> FloatArray:
        b = np.asarray(self.breakpoints_mm)
        return np.concatenate([[b[0]] * self.degree, b, [b[-1]] * self.degree])

    @property
    def size(self) -> int:
        return len(self.knots) - self.degree - 1

    def design(self, position_mm: ArrayLike) -> FloatArray:
        from scipy.interpolate import BSpline  # scipy.interpolate is slow to import

        q = np.atleast_1d(self._clamp(position_mm))
        return BSpline.design_matrix(q, self.knots, self.degree).toarray()

    def evaluate(self, position_mm: ArrayLike, coefficients: ArrayLike) -> FloatArray:
        from scipy.interpolate import BSpline

        spline = BSpline(self.knots, np.asarray(coefficients, dtype=float), self.degree)
        return np.asarray(spline(self._clamp(position_mm)))

    def describe(self) -> dict[str, object]:
        return {
            "kind": self.kind,
            "degree": self.degree,
            "breakpoints_mm": list(self.breakpoints_mm),
        }

    @classmethod
    def uniform(cls, low: float, high: float, spacing_mm: float = 50.0) -> BSplineBasis:
        """Breakpoints about every ``spacing_mm`` over the stroke (at least one interval)."""
        intervals = max(1, round((high - low) / spacing_mm))
        return cls(tuple(np.linspace(low, high, intervals + 1)))


@dataclass(frozen=True, eq=False)
class NodeTableBasis(Basis):
    """Piecewise-linear hat functions on the given nodes: coefficients are the node values."""

    nodes_mm: tuple[float, ...]
    kind: str = "table"

    def __post_init__(self) -> None:
        nodes = tuple(float(n) for n in self.nodes_mm)
        if len(nodes) < 2 or any(b <= a for a, b in zip(nodes, nodes[1:], strict=False)):
            raise ValueError(f"table nodes must be strictly increasing: {nodes}")
        object.__setattr__(self, "nodes_mm", nodes)

    @property
    def low(self) -> float:  # type: ignore[override]
        return self.nodes_mm[0]

    @property
    def high(self) -> float:  # type: ignore[override]
        return self.nodes_mm[-1]

    @property
    def size(self) -> int:
        return len(self.nodes_mm)

    def design(self, position_mm: ArrayLike) -> FloatArray:
        q = np.atleast_1d(self._clamp(position_mm))
        nodes = np.asarray(self.nodes_mm)
        index = np.clip(np.searchsorted(nodes, q, side="right") - 1, 0, len(nodes) - 2)
        frac = (q - nodes[index]) / (nodes[index + 1] - nodes[index])
        out = np.zeros((q.size, len(nodes)))
        rows = np.arange(q.size)
        out[rows, index] = 1.0 - frac
        out[rows, index + 1] += frac
        return out

    def evaluate(self, position_mm: ArrayLike, coefficients: ArrayLike) -> FloatArray:
        return np.interp(self._clamp(position_mm), self.nodes_mm, np.asarray(coefficients, float))

    def describe(self) -> dict[str, object]:
        return {"kind": self.kind, "nodes_mm": list(self.nodes_mm)}


def basis_from_description(description: Mapping[str, object]) -> Basis:
    """Inverse of ``Basis.describe()`` (used by the project reader)."""
    kind = description["kind"]
    if kind == "constant":
        low, high = description["domain_mm"]  # type: ignore[misc]
        return ConstantBasis(float(low), float(high))
    if kind == "polynomial":
        low, high = description["domain_mm"]  # type: ignore[misc]
        return PolynomialBasis(float(low), float(high), int(description["degree"]))  # type: ignore[call-overload]
    if kind == "bspline":
        return BSplineBasis(tuple(description["breakpoints_mm"]), int(description["degree"]))  # type: ignore[arg-type,call-overload]
    if kind == "table":
        return NodeTableBasis(tuple(description["nodes_mm"]))  # type: ignore[arg-type]
    raise ValueError(f"unknown basis kind {kind!r}")


def default_basis(machine: Machine, axis: str, spacing_mm: float = 50.0) -> Basis:
    """The default smooth basis: cubic B-splines with breakpoints about every 50 mm."""
    low, high = machine.stroke(axis)
    return BSplineBasis.uniform(low, high, spacing_mm)


# --------------------------------------------------------------------------------------------
# Gauges
# --------------------------------------------------------------------------------------------


def gauge_constraints(basis: Basis, reference_mm: float, straightness: bool) -> FloatArray:
    """Rows ``G`` with ``G @ coefficients = 0`` for a gauged error function.

    Every function is zero at the reference position; a straightness function also has zero
    least-squares slope over the stroke (ISO 230-1 reference straight line), so the squareness
    parameters carry the angle between the axes.
    """
    rows = [basis.design([reference_mm])[0]]
    if straightness:
        q = np.linspace(basis.low, basis.high, 801)
        weights = q - q.mean()
        rows.append(weights @ basis.design(q) / len(q))
    return np.asarray(rows)


def gauge_null_space(basis: Basis, reference_mm: float, straightness: bool) -> FloatArray:
    """Orthonormal ``N`` (size × free) with every ``N @ θ`` satisfying the gauge."""
    constraints = gauge_constraints(basis, reference_mm, straightness)
    _, singular, vt = np.linalg.svd(constraints, full_matrices=True)
    rank = int(np.sum(singular > 1e-12 * max(1.0, singular.max(initial=0.0))))
    return np.ascontiguousarray(vt[rank:].T)


def project_to_gauge(
    basis: Basis, coefficients: ArrayLike, reference_mm: float, straightness: bool
) -> FloatArray:
    """The gauged coefficients closest (in coefficient space) to ``coefficients``."""
    null = gauge_null_space(basis, reference_mm, straightness)
    c = np.asarray(coefficients, dtype=float)
    return np.asarray(null @ (null.T @ c))


# --------------------------------------------------------------------------------------------
# Error functions and the model
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ErrorFunction:
    """One error component of one axis: ``value(q) = basis.design(q) @ coefficients``.

    Values are in µm (translations) or µrad (rotations), positions in mm.
    """

    id: str
    basis: Basis
    coefficients: FloatArray

    def __post_init__(self) -> None:
        c = np.asarray(self.coefficients, dtype=float).reshape(-1)
        if c.size != self.basis.size:
            raise ValueError(
                f"{self.id}: {c.size} coefficients for a basis of {self.basis.size} functions"
            )
        c.setflags(write=False)
        object.__setattr__(self, "coefficients", c)

    @property
    def info(self) -> ErrorInfo:
        return ERROR_INFO[self.id]

    def __call__(self, position_mm: ArrayLike) -> FloatArray:
        return self.basis.evaluate(position_mm, self.coefficients)

    def with_coefficients(self, coefficients: ArrayLike) -> ErrorFunction:
        return ErrorFunction(self.id, self.basis, np.asarray(coefficients, dtype=float))


@dataclass(frozen=True, eq=False)
class ErrorModel:
    """The 21 geometric errors of a machine: 18 error functions and 3 squareness values (µrad).

    The canonical parameter vector (``parameters``) concatenates the coefficients of the 18
    functions in ``AXIS_ERROR_IDS`` order, then ``EC0Y, EB0Z, EA0Z``.
    """

    machine: Machine
    functions: Mapping[str, ErrorFunction]
    squareness_urad: Mapping[str, float] = field(
        default_factory=lambda: {k: 0.0 for k in SQUARENESS_IDS}
    )

    def __post_init__(self) -> None:
        missing = [i for i in AXIS_ERROR_IDS if i not in self.functions]
        if missing:
            raise ValueError(f"error model lacks functions for {', '.join(missing)}")
        square = {k: float(self.squareness_urad.get(k, 0.0)) for k in SQUARENESS_IDS}
        object.__setattr__(self, "squareness_urad", square)
        object.__setattr__(self, "functions", {i: self.functions[i] for i in AXIS_ERROR_IDS})

    @classmethod
    def zero(
        cls,
        machine: Machine,
        basis_for: Callable[[str, str], Basis] | None = None,
    ) -> ErrorModel:
        """A model with all errors zero; ``basis_for(axis, error_id)`` picks each basis."""

        def pick(axis: str, eid: str) -> Basis:
            return basis_for(axis, eid) if basis_for else default_basis(machine, axis)

        functions = {}
        for axis in AXES:
            for eid in axis_error_ids(axis):
                basis = pick(axis, eid)
                functions[eid] = ErrorFunction(eid, basis, np.zeros(basis.size))
        return cls(machine, functions)

    # ---- evaluation -----------------------------------------------------------------------

    def axis_values(self, axis: str, position_mm: ArrayLike) -> FloatArray:
        """Errors of one axis at positions q: columns EXJ, EYJ, EZJ (µm), EAJ, EBJ, ECJ (µrad)."""
        q = np.asarray(position_mm, dtype=float)
        return np.stack([self.functions[i](q) for i in axis_error_ids(axis)], axis=-1)

    def value(self, eid: str, position_mm: ArrayLike | None = None) -> FloatArray | float:
        if eid in SQUARENESS_IDS:
            return self.squareness_urad[eid]
        assert position_mm is not None
        return self.functions[eid](position_mm)

    # ---- parameter vector -----------------------------------------------------------------

    @cached_property
    def parameter_slices(self) -> dict[str, slice]:
        """Where each error's coefficients sit in the canonical parameter vector."""
        out: dict[str, slice] = {}
        start = 0
        for eid in AXIS_ERROR_IDS:
            size = self.functions[eid].basis.size
            out[eid] = slice(start, start + size)
            start += size
        for eid in SQUARENESS_IDS:
            out[eid] = slice(start, start + 1)
            start += 1
        return out

    @property
    def parameter_count(self) -> int:
        return self.parameter_slices["EA0Z"].stop

    @property
    def parameters(self) -> FloatArray:
        parts = [self.functions[i].coefficients for i in AXIS_ERROR_IDS]
        parts.append(np.array([self.squareness_urad[i] for i in SQUARENESS_IDS]))
        return np.concatenate(parts)

    def with_parameters(self, parameters: ArrayLike) -> ErrorModel:
        p = np.asarray(parameters, dtype=float)
        if p.size != self.parameter_count:
            raise ValueError(f"expected {self.parameter_count} parameters, got {p.size}")
        slices = self.parameter_slices
        functions = {i: self.functions[i].with_coefficients(p[slices[i]]) for i in AXIS_ERROR_IDS}
        square = {i: float(p[slices[i]][0]) for i in SQUARENESS_IDS}
        return ErrorModel(self.machine, functions, square)

    def scaled(self, factor: float) -> ErrorModel:
        """Every error multiplied by ``factor`` (used to check how nonlinearity scales)."""
        return self.with_parameters(self.parameters * factor)

    def gauged(self) -> ErrorModel:
        """The model projected onto the gauge (zero at reference, zero straightness slope)."""
        functions = {}
        for eid in AXIS_ERROR_IDS:
            f = self.functions[eid]
            ref = self.machine.reference(ERROR_INFO[eid].axis or "X")
            c = project_to_gauge(f.basis, f.coefficients, ref, ERROR_INFO[eid].is_straightness)
            functions[eid] = f.with_coefficients(c)
        return ErrorModel(self.machine, functions, dict(self.squareness_urad))

    def sampled(self, eid: str, count: int = 101) -> tuple[FloatArray, FloatArray]:
        """(positions mm, values) over the axis stroke in ascending position."""
        axis = ERROR_INFO[eid].axis
        assert axis is not None
        low, high = self.machine.stroke(axis)
        q = np.linspace(low, high, count)
        return q, self.functions[eid](q)
