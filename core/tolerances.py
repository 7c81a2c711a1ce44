"""The user's ISO 230-2 tolerances per axis, and the pass/fail of every linear line against them.

A metrologist accepts a machine axis by its ISO 230-2 values (clause 2: accuracy A, systematic
positioning error E, repeatability R, reversal B, mean bidirectional positioning error M) against
limits per axis. Each value of each linear line that travels along one machine axis is checked
twice:

- *pass/fail*: the value against the limit, as acceptance tests are usually read;
- *ISO 14253-1*: the decision with the expanded uncertainty U of the value
  (:func:`volucal.core.conformance.decide`): conforms when y + U ≤ T, does not conform when
  y − U > T, no decision in between.

U (k = 2) comes from the set-up's uncertainty budget (ISO 230-9 manner,
:class:`volucal.core.identify.UncertaintyBudget`). A, E and M are positioning deviations over the
line's travel: a length-scale error (laser, air and material temperature, expansion
coefficient, cosine) acts on them, so U is that of a positioning error over the travel, as
:func:`volucal.core.conformance.accuracy_conformance` takes it. R and B compare readings at the
same target: the scale terms are equal in both and cancel; only the budget's terms that do not
scale with the distance (dead path, Abbe) remain in their U.

Tolerances are stored in the project under ``/report/tolerances`` (``tolerances_json``), limits
in µm.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .conformance import COVERAGE_K, decide
from .identify import UncertaintyBudget
from .iso230_2 import Iso230Result, evaluate
from .machine import AXES
from .measurement import Line, travel_axis
from .userror import UserError

#: The ISO 230-2 values a limit can be set on, with their names.
QUANTITIES: dict[str, str] = {
    "A": "accuracy A",
    "E": "systematic positioning error E",
    "R": "repeatability R",
    "B": "reversal value B",
    "M": "mean bidirectional positioning error M",
}
#: Values that compare readings at one target (scale terms of U cancel).
SAME_TARGET = ("R", "B")
PASS = "pass"
FAIL = "fail"


@dataclass(frozen=True)
class Tolerances:
    """Limits (µm) per axis and ISO 230-2 value: ``limits_um["X"]["A"] = 12.0``. An axis or a
    value without a limit is not checked."""

    limits_um: Mapping[str, Mapping[str, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for axis, limits in self.limits_um.items():
            if axis not in AXES:
                raise UserError(f"tolerance for axis {axis!r}: the axes are {', '.join(AXES)}")
            for key, value in limits.items():
                if key not in QUANTITIES:
                    raise UserError(
                        f"tolerance {key!r} of axis {axis}: set limits on {', '.join(QUANTITIES)}"
                    )
                if not (math.isfinite(float(value)) and float(value) > 0):
                    raise UserError(
                        f"tolerance {key} of axis {axis}: {value!r} µm; give a "
                        "positive number of micrometres"
                    )

    @property
    def empty(self) -> bool:
        return not any(self.limits_um.values())

    def limit(self, axis: str, quantity: str) -> float | None:
        value = self.limits_um.get(axis, {}).get(quantity)
        return None if value is None else float(value)

    def to_json(self) -> dict[str, dict[str, float]]:
        return {
            a: {k: float(v) for k, v in limits.items()}
            for a, limits in self.limits_um.items()
            if limits
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Tolerances:
        return cls(
            {
                str(a): {str(k): float(v) for k, v in dict(limits).items()}
                for a, limits in dict(data).items()
            }
        )

    # ---- the project -------------------------------------------------------------------------

    def to_tree(self) -> dict[str, Any]:
        return {"tolerances_json": json.dumps(self.to_json())}

    @classmethod
    def of_project(cls, project: Any) -> Tolerances:
        """The tolerances stored in a project (none when it has none)."""
        if "tolerances" not in project.results("report"):
            return cls()
        tree = project.result("report", "tolerances")
        return cls.from_json(json.loads(str(tree.get("tolerances_json", "{}"))))


def line_axis(line: Line) -> str | None:
    """The machine axis a linear line travels along, or None (diagonals, other quantities)."""
    if line.spec.quantity != "linear":
        return None
    return travel_axis(line.spec.direction)


@dataclass(frozen=True)
class ToleranceCheck:
    """One ISO 230-2 value of one line against its limit."""

    line: str
    axis: str
    quantity: str
    value_um: float
    limit_um: float
    expanded_uncertainty_um: float
    passed: bool
    decision: str

    @property
    def verdict(self) -> str:
        return PASS if self.passed else FAIL

    def to_json(self) -> dict[str, Any]:
        return {
            "line": self.line,
            "axis": self.axis,
            "quantity": self.quantity,
            "value_um": self.value_um,
            "limit_um": self.limit_um,
            "expanded_uncertainty_um": self.expanded_uncertainty_um,
            "verdict": self.verdict,
            "iso_14253_1": self.decision,
        }


def iso_value(result: Iso230Result, quantity: str) -> float:
    """The bidirectional value, or the unidirectional one of a line measured one way only."""
    value = float(getattr(result, f"{quantity}_um"))
    if math.isfinite(value) or quantity not in ("A", "E", "R"):
        return value
    up = float(getattr(result, f"{quantity}_up_um"))
    return up if math.isfinite(up) else float(getattr(result, f"{quantity}_down_um"))


def expanded_uncertainty_um(line: Line, quantity: str, budget: UncertaintyBudget) -> float:
    """U (k = 2) of an ISO 230-2 value of ``line`` from the set-up budget (module notes)."""
    travel = float(np.ptp(line.data.targets_mm)) if quantity not in SAME_TARGET else 0.0
    return COVERAGE_K * float(budget.positioning_std_um(np.array([travel]))[0])


def check_line(
    line: Line,
    tolerances: Tolerances,
    budget: UncertaintyBudget,
    result: Iso230Result | None = None,
) -> list[ToleranceCheck]:
    """Every limit of the line's axis against the line's ISO 230-2 values (none for a line
    that is not along one axis)."""
    axis = line_axis(line)
    if axis is None:
        return []
    result = result or evaluate(line.data, line.spec.unit)
    out = []
    for quantity in QUANTITIES:
        limit = tolerances.limit(axis, quantity)
        if limit is None:
            continue
        value = iso_value(result, quantity)
        u = expanded_uncertainty_um(line, quantity, budget)
        out.append(
            ToleranceCheck(
                line.name,
                axis,
                quantity,
                value,
                limit,
                u,
                bool(math.isfinite(value) and value <= limit),
                decide(value, u, limit),
            )
        )
    return out


def check_lines(
    lines: Sequence[Line], tolerances: Tolerances, budget: UncertaintyBudget
) -> list[ToleranceCheck]:
    """:func:`check_line` over ``lines`` (the linear axis-parallel ones)."""
    return [c for line in lines for c in check_line(line, tolerances, budget)]


def axis_verdicts(checks: Sequence[ToleranceCheck]) -> dict[str, str]:
    """Per axis: "pass" when every checked value of every line of the axis is within its
    limit, else "fail"."""
    out: dict[str, str] = {}
    for check in checks:
        if out.get(check.axis) != FAIL:
            out[check.axis] = check.verdict
    return out
