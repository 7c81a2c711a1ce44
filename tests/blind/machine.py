"""A rigid-body 3-axis machine of any serial chain, written from DESIGN.md's conventions only.

Chain (DESIGN.md "Conventions", the paper's eq. 4 for "WXYFZT")::

    T = T(x) · E_X(x) · T(y) · E_Y(y) · T(z) · E_Z(z) · T(tool)

so the tool point, in the workpiece frame, is

    P = (x,0,0) + δX + R_X [ (0,y,0) + δY + R_Y [ (0,0,z) + δZ + R_Z · t ] ]

Another chain multiplies its axes in its own order, the letters X, Y, Z as the string lists
them from the workpiece to the tool ("WFYXZT", a gantry whose bridge moves along Y and carries
X: Y, then X, then Z); where F stands changes nothing (DESIGN.md). An axis' rotation acts
through the travel of every axis after it and the tool.

with δj the translation errors of axis j and R_j the exact rotation of its three angular errors
(a rotation vector (εa, εb, εc), turned into a matrix by Rodrigues' formula). Squareness enters the
translations of Y and Z with ISO 230-1 signs: x += −(y − y_ref)·EC0Y, x += +(z − z_ref)·EB0Z,
y += −(z − z_ref)·EA0Z. The volumetric error is E = P − (x, y, z) − t.

Error ids follow ISO 230-1: E<direction><axis>, A/B/C for rotations about X/Y/Z. For each axis the
six functions are ordered (δx, δy, δz, εa, εb, εc)::

    X: EXX EYX EZX EAX EBX ECX     Y: EXY EYY EZY EAY EBY ECY     Z: EXZ EYZ EZZ EAZ EBZ ECZ

Gauge (DESIGN.md): every function is zero at the reference position (the stroke start unless the
plan sets ``reference``); the two straightness functions of each axis have zero least-squares slope
over the stroke (continuous least squares, uniform weight), so squareness carries the angle between
the axes.

Units: positions mm, translations µm, angles µrad. Pure numpy; this module never imports volucal.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

AXES = ("X", "Y", "Z")
#: The six error ids of each axis, in the order (δx, δy, δz, εa, εb, εc).
ERROR_IDS = {
    axis: (f"EX{axis}", f"EY{axis}", f"EZ{axis}", f"EA{axis}", f"EB{axis}", f"EC{axis}")
    for axis in AXES
}
SQUARENESS_IDS = ("EC0Y", "EB0Z", "EA0Z")
#: The chain of the paper's machine, and of every plan that names none.
PAPER_CHAIN = "WXYFZT"
ARCSEC_URAD = np.pi / 180 / 3600 * 1e6  # 1″ = 4.848 µrad


def chain_axes(chain: str) -> tuple[str, ...]:
    """The axes of a chain string in product order, from the workpiece to the tool ("WFYXZT" →
    Y, X, Z); ValueError unless it is W, F, T and the three axes, W first and T last."""
    letters = str(chain).upper()
    if sorted(letters) != sorted("WFTXYZ") or letters[0] != "W" or letters[-1] != "T":
        raise ValueError(f"chain {chain!r}: expected W, the axes X, Y, Z and F in some order, T")
    return tuple(c for c in letters if c in AXES)


def error_kind(error_id: str) -> str:
    """'positioning', 'straightness' or 'angular' for an error id such as EYX."""
    direction, axis = error_id[1], error_id[2]
    if direction in "ABC":
        return "angular"
    return "positioning" if direction == axis else "straightness"


# --------------------------------------------------------------------------------------------
# Smooth error functions
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SmoothFunction:
    """f(p) = scale · [g(p) − g(p_ref) − slope · (p − p_ref)] over one stroke.

    g is a low-order Chebyshev series on the stroke (degree ≤ 3) plus a draw of a Gaussian process
    with squared-exponential covariance of correlation length ``length_mm``, represented by random
    Fourier features (frequencies ω ~ N(0, 1/ℓ²) truncated to |ω| ≤ 2.5/ℓ), so it is an exact
    closed form that can be evaluated anywhere. ``slope`` is g's continuous least-squares slope
    over the stroke for straightness functions (the ISO reference straight line) and 0 otherwise.
    """

    stroke: tuple[float, float]
    reference: float
    cheb: tuple[float, ...]
    omega: tuple[float, ...]
    phase: tuple[float, ...]
    weight: tuple[float, ...]
    length_mm: float
    slope: float = 0.0
    scale: float = 1.0

    def _raw(self, p: np.ndarray) -> np.ndarray:
        lo, hi = min(self.stroke), max(self.stroke)
        u = (2.0 * p - (lo + hi)) / (hi - lo)
        out = np.polynomial.chebyshev.chebval(u, self.cheb)
        om = np.asarray(self.omega)
        out = out + np.cos(np.multiply.outer(p, om) + np.asarray(self.phase)) @ np.asarray(
            self.weight)
        return out

    def _gauged(self, p: np.ndarray) -> np.ndarray:
        ref = np.asarray(self.reference, dtype=float)
        return self._raw(p) - self._raw(ref) - self.slope * (p - self.reference)

    def __call__(self, p: np.ndarray | float) -> np.ndarray:
        p = np.asarray(p, dtype=float)
        return self.scale * self._gauged(p)


def stroke_grid(stroke: tuple[float, float], count: int = 4001) -> np.ndarray:
    lo, hi = min(stroke), max(stroke)
    return np.linspace(lo, hi, count)


def ls_slope(p: np.ndarray, f: np.ndarray) -> float:
    """Least-squares slope of f(p) on a uniform grid (the continuous one as the grid refines)."""
    pc = p - p.mean()
    return float(pc @ (f - f.mean()) / (pc @ pc))


def random_function(
    rng: np.random.Generator,
    stroke: tuple[float, float],
    reference: float,
    kind: str,
) -> SmoothFunction:
    """A random smooth error function of the given kind, gauged and sized (REFERENCE.md §4).

    Sizes: positioning = a lead (scale) error of up to ±12 µm at the stroke end plus a smooth
    part, the whole at most 15 µm in magnitude; straightness peak-to-valley 2–8 µm after removing
    the least-squares line; angles max |ε| 5–25 µrad (1–5″).
    """
    length = float(rng.uniform(120.0, 260.0))
    count = 24
    omega = rng.normal(0.0, 1.0 / length, count)
    omega = np.clip(omega, -2.5 / length, 2.5 / length)
    phase = rng.uniform(0.0, 2 * np.pi, count)
    weight = rng.normal(0.0, np.sqrt(2.0 / count), count)
    cheb = np.zeros(4)
    cheb[1:] = rng.normal(0.0, [0.6, 0.4, 0.25])
    if kind == "positioning":
        # The lead error: a linear term dominates a real screw's accumulated error.
        cheb[1] = rng.normal(0.0, 1.0) * 3.0
    base = SmoothFunction((float(stroke[0]), float(stroke[1])), float(reference), tuple(cheb),
                          tuple(omega), tuple(phase), tuple(weight), length)
    grid = stroke_grid(stroke)
    slope = ls_slope(grid, base._gauged(grid)) if kind == "straightness" else 0.0
    shaped = SmoothFunction(base.stroke, base.reference, base.cheb, base.omega, base.phase,
                            base.weight, length, slope, 1.0)
    values = shaped(grid)
    if kind == "positioning":
        peak = float(np.max(np.abs(values)))
        scale = rng.uniform(3.0, 15.0) / peak
    elif kind == "straightness":
        scale = rng.uniform(2.0, 8.0) / float(np.ptp(values))
    else:
        scale = rng.uniform(5.0, 25.0) / float(np.max(np.abs(values)))
    return SmoothFunction(base.stroke, base.reference, base.cheb, base.omega, base.phase,
                          base.weight, length, slope, float(scale))


# --------------------------------------------------------------------------------------------
# Rotations
# --------------------------------------------------------------------------------------------


def rotation_matrices(rotvec_rad: np.ndarray) -> np.ndarray:
    """(N, 3, 3) exact rotation matrices of rotation vectors (N, 3) in rad (Rodrigues)."""
    w = np.atleast_2d(rotvec_rad)
    theta = np.linalg.norm(w, axis=1)
    a = np.sinc(theta / np.pi)  # sin θ / θ
    b = 0.5 * np.sinc(theta / (2 * np.pi)) ** 2  # (1 − cos θ) / θ²
    k = np.zeros((len(w), 3, 3))
    k[:, 0, 1], k[:, 0, 2] = -w[:, 2], w[:, 1]
    k[:, 1, 0], k[:, 1, 2] = w[:, 2], -w[:, 0]
    k[:, 2, 0], k[:, 2, 1] = -w[:, 1], w[:, 0]
    return np.eye(3) + a[:, None, None] * k + b[:, None, None] * (k @ k)


def rotation_vectors(r: np.ndarray) -> np.ndarray:
    """Rotation vectors (N, 3), rad, of rotation matrices (N, 3, 3) with angles below π/2."""
    v = 0.5 * np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0],
                        r[:, 1, 0] - r[:, 0, 1]], axis=1)
    s = np.linalg.norm(v, axis=1)
    theta = np.arcsin(np.clip(s, 0.0, 1.0))
    return v / np.sinc(theta / np.pi)[:, None]


# --------------------------------------------------------------------------------------------
# The machine
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Machine:
    """Ground truth: strokes, reference, the 18 error functions and three squareness values."""

    stroke_mm: dict[str, tuple[float, float]]
    reference_mm: dict[str, float]
    functions: dict[str, SmoothFunction]
    squareness_urad: dict[str, float]
    chain: str = PAPER_CHAIN
    extra: dict[str, object] = field(default_factory=dict)

    def axis_errors(self, axis: str, position_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(δ (N, 3) µm, ε (N, 3) µrad) of one axis at its positions, squareness excluded."""
        p = np.asarray(position_mm, dtype=float)
        ids = ERROR_IDS[axis]
        delta = np.stack([self.functions[i](p) for i in ids[:3]], axis=-1)
        eps = np.stack([self.functions[i](p) for i in ids[3:]], axis=-1)
        return delta, eps

    def pose_error(
        self,
        position_mm: np.ndarray,
        tool_mm: np.ndarray,
        extra_delta_um: dict[str, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Exact volumetric error (N, 3) µm and tool rotation vector (N, 3) µrad.

        ``position_mm``: (N, 3) NC positions x, y, z; ``tool_mm``: (3,) or (N, 3) tool point
        offset; ``extra_delta_um``: per axis, (N, 3) translations added to that axis' δ (effects
        such as reversal or a local defect act there, inside the chain).
        """
        q = np.atleast_2d(np.asarray(position_mm, dtype=float))
        n = len(q)
        t = np.broadcast_to(np.asarray(tool_mm, dtype=float), (n, 3))
        deltas, rots = {}, {}
        for index, axis in enumerate(AXES):
            d, e = self.axis_errors(axis, q[:, index])
            if extra_delta_um and axis in extra_delta_um:
                d = d + extra_delta_um[axis]
            deltas[axis] = d * 1e-3  # µm → mm
            rots[axis] = rotation_matrices(e * 1e-6)
        ref = self.reference_mm
        sq = self.squareness_urad
        dy = q[:, 1] - ref["Y"]
        dz = q[:, 2] - ref["Z"]
        deltas["Y"][:, 0] += -dy * sq["EC0Y"] * 1e-6
        deltas["Z"][:, 0] += dz * sq["EB0Z"] * 1e-6
        deltas["Z"][:, 1] += -dz * sq["EA0Z"] * 1e-6
        # from the tool outwards: each axis' travel, its δ, and its rotation of all that follows
        order = chain_axes(self.chain)
        p = np.array(t)
        for axis in reversed(order):
            travel = np.zeros((n, 3))
            travel[:, AXES.index(axis)] = q[:, AXES.index(axis)]
            p = travel + deltas[axis] + np.einsum("nij,nj->ni", rots[axis], p)
        error_um = (p - q - t) * 1e3
        total = rots[order[0]] @ rots[order[1]] @ rots[order[2]]
        return error_um, rotation_vectors(total) * 1e6

    def truth(self, step_mm: float = 2.0) -> dict[str, object]:
        """The 18 functions sampled in ascending position, and the squareness values."""
        functions: dict[str, object] = {}
        for axis in AXES:
            lo, hi = min(self.stroke_mm[axis]), max(self.stroke_mm[axis])
            count = int(round((hi - lo) / step_mm)) + 1
            grid = np.linspace(lo, hi, count)
            for error_id in ERROR_IDS[axis]:
                kind = error_kind(error_id)
                functions[error_id] = {
                    "kind": kind,
                    "unit": "urad" if kind == "angular" else "um",
                    "position_mm": [round(float(v), 6) for v in grid],
                    "value": [round(float(v), 6) for v in self.functions[error_id](grid)],
                }
        return {
            "chain": self.chain,
            "stroke_mm": {a: list(self.stroke_mm[a]) for a in AXES},
            "reference_mm": dict(self.reference_mm),
            "functions": functions,
            "squareness_urad": {k: float(v) for k, v in self.squareness_urad.items()},
        }


def random_machine(
    rng: np.random.Generator,
    stroke_mm: dict[str, tuple[float, float]],
    reference_mm: dict[str, float] | None = None,
    chain: str = PAPER_CHAIN,
) -> Machine:
    """A machine of ``chain`` with random smooth errors of realistic size (REFERENCE.md §4)."""
    reference = {a: float(stroke_mm[a][0]) for a in AXES}
    if reference_mm:
        reference.update({a: float(v) for a, v in reference_mm.items()})
    functions = {}
    for axis in AXES:
        for error_id in ERROR_IDS[axis]:
            functions[error_id] = random_function(
                rng, stroke_mm[axis], reference[axis], error_kind(error_id))
    squareness = {
        k: float(rng.choice([-1.0, 1.0]) * rng.uniform(2.0, 10.0) * ARCSEC_URAD)
        for k in SQUARENESS_IDS
    }
    chain_axes(chain)  # refuses a chain this machine cannot be
    return Machine({a: (float(stroke_mm[a][0]), float(stroke_mm[a][1])) for a in AXES},
                   reference, functions, squareness, chain)
