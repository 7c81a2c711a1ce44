"""Choosing what to compensate from a global sensitivity ranking, and the tolerance of each value.

The input is a plain ranking ``{error id: first-order index S1}`` of one volumetric output (Ex,
Ey, Ez or ET) from an EFAST analysis (paper section 3; volucal.core.sensitivity computes it) and
the design tolerance T (µm) of that output. The errors are taken in decreasing S1 until their
cumulative S1 reaches the asked coverage (0.95 by default): compensating them removes, to first
order, that share of the output's variance; the rest is the expected residual.

Tolerances of the compensation values follow the paper's eq. 19, S_i = 6σ_i²/T = V_i/V, which
gives σ_i = √(S_i·T/6) — as published (Table 3: S1 = 0.23 for δx(x) and T = 25 µm give 0.98 µm,
the paper prints 0.97 µm). The formula mixes units (σ² over a length; for angles it is not an
angle), so a dimensionally sound form is given too: the error's share of the output standard
deviation, √S_i · T/6 (T taken as the ±3σ band of the output), divided by the error's sensitivity
coefficient |∂E/∂e_i| (µm per µm or per µrad) when that is known.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from ..errors import ERROR_INFO
from ..userror import UserError

SELECTION_DEFINITION = (
    "errors taken in decreasing first-order index S1 until the cumulative S1 reaches the "
    "coverage; residual variance fraction = 1 - sum of the selected S1 (first order); "
    "sigma_eq19_published = sqrt(S1*T/6) (paper eq. 19 as printed); sigma_sound = "
    "sqrt(S1)*T/6/|dE/de_i| in the error's unit"
)


@dataclass(frozen=True)
class ErrorAllocation:
    """One error's rank, whether it is compensated, and the tolerance of its value.

    sigma_published : eq. 19 as published, √(S1·T/6) (in the paper's units for that error).
    sigma_sound : √S1 · T/6 / |coefficient|, in the error's unit (µm or µrad); None when no
        sensitivity coefficient was given.
    """

    id: str
    s1: float
    cumulative_s1: float
    selected: bool
    sigma_published: float
    sigma_sound: float | None
    unit: str

    def to_json(self) -> dict[str, object]:
        return {
            "id": self.id,
            "S1": self.s1,
            "cumulative_S1": self.cumulative_s1,
            "selected": self.selected,
            "sigma_eq19_published": self.sigma_published,
            "sigma_sound": self.sigma_sound,
            "unit": self.unit,
        }


@dataclass(frozen=True)
class CompensationSelection:
    """The errors to compensate and the residual expected when the others are left.

    residual_variance_fraction : 1 − Σ S1 of the selected errors (first order: interactions
        and the unselected main effects are counted as residual).
    residual_std_um : √fraction · σ_out, with σ_out the output's standard deviation when given,
        else T/6 (T read as the ±3σ band).
    """

    output: str
    tolerance_um: float
    coverage: float
    allocations: tuple[ErrorAllocation, ...]
    residual_variance_fraction: float
    output_std_um: float
    residual_std_um: float

    @property
    def selected(self) -> tuple[str, ...]:
        return tuple(a.id for a in self.allocations if a.selected)

    @property
    def tolerance_met(self) -> bool:
        """Whether the expected residual's ±3σ band fits in the tolerance."""
        return 6.0 * self.residual_std_um <= self.tolerance_um

    def to_json(self) -> dict[str, object]:
        return {
            "output": self.output,
            "tolerance_um": self.tolerance_um,
            "coverage": self.coverage,
            "selected": list(self.selected),
            "residual_variance_fraction": self.residual_variance_fraction,
            "output_std_um": self.output_std_um,
            "residual_std_um": self.residual_std_um,
            "tolerance_met": self.tolerance_met,
            "allocations": [a.to_json() for a in self.allocations],
            "definition": SELECTION_DEFINITION,
        }


def select_compensation(
    s1: Mapping[str, float],
    tolerance_um: float = 25.0,
    coverage: float = 0.95,
    output: str = "ET",
    coefficients: Mapping[str, float] | None = None,
    output_std_um: float | None = None,
) -> CompensationSelection:
    """Rank errors by S1, select up to the coverage, allocate eq. 19 tolerances.

    Parameters
    ----------
    s1 : mapping error id -> first-order index
        From an EFAST analysis of one output; ids are ISO 230-1 (``EXX``, ``EC0Y``, ...).
        Negative estimates (EFAST noise) count as zero.
    tolerance_um : float
        Design tolerance T of the output (the paper uses 25 µm).
    coverage : float
        Cumulative S1 to reach, in (0, 1].
    output : str
        Which output the indices belong to (Ex, Ey, Ez, ET), for the report.
    coefficients : mapping error id -> sensitivity coefficient, optional
        |∂E_output/∂e_i| in µm per unit of the error (µm/µm or µm/µrad), for the sound form.
    output_std_um : float, optional
        Standard deviation of the output before compensation; T/6 when not given.
    """
    if not 0.0 < coverage <= 1.0:
        raise UserError(f"coverage must be in (0, 1], got {coverage}")
    if not (math.isfinite(tolerance_um) and tolerance_um > 0):
        raise UserError(f"tolerance must be a positive number of µm, got {tolerance_um}")
    unknown = sorted(set(s1) - set(ERROR_INFO))
    if unknown:
        raise UserError(
            f"unknown error id(s) {', '.join(unknown)} in the sensitivity ranking; use ISO 230-1 "
            "ids such as EXX, ECY, EC0Y"
        )
    clean = {eid: max(0.0, float(value)) for eid, value in s1.items()}
    ranked = sorted(clean.items(), key=lambda item: (-item[1], item[0]))
    allocations = []
    cumulative = 0.0
    reached = False
    for eid, value in ranked:
        selected = not reached and value > 0.0
        cumulative += value
        if cumulative >= coverage:
            reached = True
        coefficient = None if coefficients is None else coefficients.get(eid)
        sound = None
        if coefficient is not None and abs(coefficient) > 0:
            sound = math.sqrt(value) * tolerance_um / 6.0 / abs(coefficient)
        allocations.append(
            ErrorAllocation(
                id=eid,
                s1=value,
                cumulative_s1=cumulative,
                selected=selected,
                sigma_published=math.sqrt(value * tolerance_um / 6.0),
                sigma_sound=sound,
                unit=ERROR_INFO[eid].unit,
            )
        )
    covered = sum(a.s1 for a in allocations if a.selected)
    fraction = max(0.0, 1.0 - covered)
    sigma_out = tolerance_um / 6.0 if output_std_um is None else float(output_std_um)
    return CompensationSelection(
        output=output,
        tolerance_um=float(tolerance_um),
        coverage=float(coverage),
        allocations=tuple(allocations),
        residual_variance_fraction=fraction,
        output_std_um=sigma_out,
        residual_std_um=math.sqrt(fraction) * sigma_out,
    )
