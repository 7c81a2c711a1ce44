"""The units values are shown in: µm, mm or inch for deviations; µrad, arcsec or µm/m for angles.

volucal computes and stores deviations in µm and angles in µrad (DESIGN.md, "Units"); a view or
the report converts once, when it shows a number, and says the unit it shows. Positions stay in
millimetres everywhere.

1 inch = 25 400 µm exactly; 1 arcsec = π/648 000 rad = 4.848 137 µrad; an angle of 1 µrad is a
slope of 1 µm/m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .userror import UserError

URAD_PER_ARCSEC = math.pi / 648_000.0 * 1e6


@dataclass(frozen=True)
class Unit:
    """One display unit: its symbol, the factor from the core unit, and the decimals that show
    a tenth of a micrometre (a hundredth of a microradian)."""

    key: str
    symbol: str
    per_core_unit: float
    decimals: int


LENGTH_UNITS: dict[str, Unit] = {
    "um": Unit("um", "µm", 1.0, 3),
    "mm": Unit("mm", "mm", 1e-3, 6),
    "inch": Unit("inch", "in", 1.0 / 25_400.0, 7),
}
ANGLE_UNITS: dict[str, Unit] = {
    "urad": Unit("urad", "µrad", 1.0, 2),
    "arcsec": Unit("arcsec", "arcsec", 1.0 / URAD_PER_ARCSEC, 3),
    "um_per_m": Unit("um_per_m", "µm/m", 1.0, 2),
}


@dataclass(frozen=True)
class DisplayUnits:
    """The length and angle units values are shown in (keys of :data:`LENGTH_UNITS` and
    :data:`ANGLE_UNITS`)."""

    length: str = "um"
    angle: str = "urad"

    def __post_init__(self) -> None:
        if self.length not in LENGTH_UNITS:
            raise UserError(f"length unit {self.length!r}: use one of {', '.join(LENGTH_UNITS)}")
        if self.angle not in ANGLE_UNITS:
            raise UserError(f"angle unit {self.angle!r}: use one of {', '.join(ANGLE_UNITS)}")

    def unit(self, core_unit: str) -> Unit:
        """The display unit of values stored in ``core_unit`` ("um" or "urad")."""
        if core_unit == "um":
            return LENGTH_UNITS[self.length]
        if core_unit == "urad":
            return ANGLE_UNITS[self.angle]
        raise ValueError(f"no display unit for {core_unit!r}")

    def symbol(self, core_unit: str) -> str:
        return self.unit(core_unit).symbol

    def convert(self, values: ArrayLike, core_unit: str) -> NDArray[np.float64]:
        """Values stored in ``core_unit`` in the display unit."""
        return np.asarray(values, dtype=float) * self.unit(core_unit).per_core_unit

    def value(self, value: float, core_unit: str) -> float:
        return float(value) * self.unit(core_unit).per_core_unit

    def to_core(self, value: float, core_unit: str) -> float:
        """A value typed in the display unit, back in ``core_unit``."""
        return float(value) / self.unit(core_unit).per_core_unit

    def text(
        self, value: float | None, core_unit: str, with_symbol: bool = True, extra_decimals: int = 0
    ) -> str:
        """A value for a table: the unit's decimals, "—" when unknown, never "-0.000"."""
        if value is None or not math.isfinite(float(value)):
            return "—"
        unit = self.unit(core_unit)
        text = f"{self.value(value, core_unit):.{unit.decimals + extra_decimals}f}"
        if float(text) == 0.0:
            text = text.lstrip("-")
        return f"{text} {unit.symbol}" if with_symbol else text

    def to_json(self) -> dict[str, str]:
        return {"length": self.length, "angle": self.angle}
