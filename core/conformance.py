"""Conformance with a tolerance in the manner of ISO 14253-1 (decision rules with the expanded
uncertainty of the measurement).

For an upper specification limit T on a measured value y with expanded uncertainty U (k = 2,
about 95 % coverage), ISO 14253-1 clause 5 splits the scale into three zones:

- conformance is proven when y + U ≤ T (the whole uncertainty interval lies within T);
- non-conformance is proven when y − U > T (the whole interval lies beyond T);
- otherwise no decision can be made: y lies in the uncertainty range around T.

volucal decides on one of two quantities of the machine as measured (before compensation):

``accuracy``
    The bidirectional positioning accuracy A of ISO 230-2 (clause 2.20) of every linear line of
    the plan (axis-parallel lines and diagonals alike), from the corrected readings. U = 2·u with
    u the standard uncertainty of a positioning error over the line's travel from the set-up's
    uncertainty budget (laser, air and material temperature, expansion coefficient, cosine and
    dead-path terms: :class:`volucal.core.identify.UncertaintyBudget`, in the manner of ISO 230-9).
    The run-to-run spread is already inside A (its ±2s), so it is not counted again.
``volumetric``
    The largest magnitude of the volumetric error ET = |E| (paper eq. 6, exact chain) of the
    identified 21-error model over a regular grid of the workspace at the machine's tool offset.
    U = 2·u with u² = êᵀ J C Jᵀ ê + Σ_k (ê_k u_k)², where J is the Jacobian of E with respect to
    the model's parameters at the worst point, C their covariance, ê the unit vector of E there
    and u_k the budget's positioning uncertainty of axis k at that point (first-order
    propagation, GUM clause 5.1). Effects the closed loop added (reversal, screw cycle, …) are not
    part of E here; the report lists them with their magnitudes.

The decision for several lines is "conforms" when every line conforms, "does not conform" when
at least one line does not, and "no decision" otherwise.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .errors import ErrorModel
from .identify import UncertaintyBudget
from .iso230_2 import evaluate
from .kinematics import VolumetricModel, jacobian
from .machine import AXES
from .measurement import Line
from .userror import UserError

FloatArray = NDArray[np.float64]

CONFORMS = "conforms"
DOES_NOT_CONFORM = "does not conform"
NO_DECISION = "no decision (within the uncertainty range)"
QUANTITIES = ("accuracy", "volumetric")
#: Coverage factor of the expanded uncertainty (about 95 % for a normal distribution).
COVERAGE_K = 2.0


def decide(value_um: float, expanded_uncertainty_um: float, tolerance_um: float) -> str:
    """ISO 14253-1 decision for an upper specification limit (module notes).

    Parameters
    ----------
    value_um : the measured value (a magnitude: a range or a largest deviation).
    expanded_uncertainty_um : U, coverage factor k = 2.
    tolerance_um : the upper specification limit T.
    """
    if not np.isfinite(value_um) or not np.isfinite(expanded_uncertainty_um):
        return NO_DECISION
    if value_um + expanded_uncertainty_um <= tolerance_um:
        return CONFORMS
    if value_um - expanded_uncertainty_um > tolerance_um:
        return DOES_NOT_CONFORM
    return NO_DECISION


def combine(verdicts: Sequence[str]) -> str:
    """One decision for several items (module notes)."""
    if not verdicts:
        return NO_DECISION
    if any(v == DOES_NOT_CONFORM for v in verdicts):
        return DOES_NOT_CONFORM
    if all(v == CONFORMS for v in verdicts):
        return CONFORMS
    return NO_DECISION


@dataclass(frozen=True)
class ConformanceItem:
    """One decided value: what it is, its value, U, and the verdict."""

    name: str
    value_um: float
    expanded_uncertainty_um: float
    verdict: str
    where: str = ""


@dataclass(frozen=True)
class Conformance:
    """The decision on one quantity against the tolerance."""

    quantity: str
    description: str
    tolerance_um: float
    items: tuple[ConformanceItem, ...]
    verdict: str
    uncertainty_statement: str

    def to_json(self) -> dict[str, object]:
        return {
            "quantity": self.quantity,
            "description": self.description,
            "tolerance_um": self.tolerance_um,
            "coverage_factor": COVERAGE_K,
            "verdict": self.verdict,
            "uncertainty_statement": self.uncertainty_statement,
            "items": [
                {
                    "name": i.name,
                    "value_um": i.value_um,
                    "expanded_uncertainty_um": i.expanded_uncertainty_um,
                    "verdict": i.verdict,
                    "where": i.where,
                }
                for i in self.items
            ],
        }


def accuracy_conformance(
    lines: Sequence[Line], budget: UncertaintyBudget, tolerance_um: float
) -> Conformance:
    """Decide on the ISO 230-2 accuracy A of every linear line (module notes)."""
    _check_tolerance(tolerance_um)
    items = []
    for line in lines:
        if line.spec.quantity != "linear":
            continue
        result = evaluate(line.data)
        value = result.A_um
        if not np.isfinite(value):  # one direction only: the unidirectional accuracy
            value = result.A_up_um if np.isfinite(result.A_up_um) else result.A_down_um
        travel = float(np.ptp(line.data.targets_mm))
        u = float(budget.positioning_std_um(np.array([travel]))[0])
        expanded = COVERAGE_K * u
        items.append(
            ConformanceItem(
                line.name,
                float(value),
                expanded,
                decide(float(value), expanded, tolerance_um),
                f"travel {travel:.0f} mm",
            )
        )
    if not items:
        raise UserError(
            "the project has no linear line: the positioning accuracy A cannot be "
            "decided on (use --tolerance-on volumetric)"
        )
    return Conformance(
        quantity="accuracy",
        description="bidirectional positioning accuracy A (ISO 230-2) of each linear line, "
        "machine as measured",
        tolerance_um=float(tolerance_um),
        items=tuple(items),
        verdict=combine([i.verdict for i in items]),
        uncertainty_statement=(
            "U = 2·u (k = 2), u = standard uncertainty of a positioning error over the line's "
            f"travel from the set-up budget: scale {budget.scale_ppm():.3f} ppm (laser, air and "
            "material temperature, expansion coefficient, cosine), dead path and Abbe terms"
        ),
    )


def volumetric_conformance(
    model: ErrorModel,
    covariance: FloatArray,
    budget: UncertaintyBudget,
    tolerance_um: float,
    grid_step_mm: float = 25.0,
) -> Conformance:
    """Decide on the largest volumetric error |E| over the workspace (module notes)."""
    _check_tolerance(tolerance_um)
    machine = model.machine
    covariance = np.asarray(covariance, dtype=float)
    if covariance.shape != (model.parameter_count, model.parameter_count):
        raise UserError(
            f"the stored covariance ({covariance.shape}) does not fit the model "
            f"({model.parameter_count} parameters): identify again"
        )
    axes = [_grid(*machine.stroke(a), grid_step_mm) for a in AXES]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    error = VolumetricModel(model).error(points)
    magnitude = np.linalg.norm(error, axis=1)
    worst = int(np.argmax(magnitude))
    q = points[worst]
    value = float(magnitude[worst])
    unit = error[worst] / value if value > 0 else np.zeros(3)
    j = jacobian(model, q[None, :])[0]  # (3, P)
    statistical = float(unit @ j @ covariance @ j.T @ unit)
    setup = sum(
        (unit[k] * float(budget.positioning_std_um(np.array([q[k] - machine.reference(a)]))[0]))
        ** 2
        for k, a in enumerate(AXES)
    )
    expanded = COVERAGE_K * float(np.sqrt(max(statistical, 0.0) + setup))
    where = "X {:.0f} Y {:.0f} Z {:.0f} mm".format(*q)
    item = ConformanceItem(
        "ET = |E| (largest over the workspace)",
        value,
        expanded,
        decide(value, expanded, tolerance_um),
        where,
    )
    return Conformance(
        quantity="volumetric",
        description=(
            "largest volumetric error ET = |E| of the identified 21-error model over a "
            f"{grid_step_mm:g} mm grid of the workspace, tool offset "
            "{:g} {:g} {:g} mm, machine as measured".format(*machine.tool_offset_mm)
        ),
        tolerance_um=float(tolerance_um),
        items=(item,),
        verdict=item.verdict,
        uncertainty_statement=(
            "U = 2·u (k = 2), u² = statistical part êᵀJCJᵀê of the identification (covariance "
            "of the 21 errors, first-order propagation) + the set-up budget's positioning "
            f"uncertainty of each axis at the worst point (scale {budget.scale_ppm():.3f} ppm)"
        ),
    )


def budget_from(uncertainty: Mapping[str, float]) -> UncertaintyBudget:
    """The project's ``[uncertainty]`` overrides on top of the default budget."""
    return UncertaintyBudget.from_mapping(uncertainty) if uncertainty else UncertaintyBudget()


def _grid(low: float, high: float, step_mm: float) -> FloatArray:
    count = max(2, int(np.ceil((high - low) / step_mm - 1e-9)) + 1)
    return np.linspace(low, high, count)


def _check_tolerance(tolerance_um: float) -> None:
    if not np.isfinite(tolerance_um) or tolerance_um <= 0:
        raise UserError(f"tolerance {tolerance_um!r} µm: give a positive number of micrometres")
