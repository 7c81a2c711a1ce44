"""Units accepted in files and plans, and their conversion to volucal's units (µm, µrad, mm, s).

Conversion happens once, at import (STYLE.md): readers return values in the file's own unit and
record which; :mod:`volucal.core.io.plan` converts.
"""

from __future__ import annotations

import math

#: Factor from a deviation unit to µm (translations) or µrad (rotations).
DEVIATION_FACTOR = {
    "um": 1.0,
    "nm": 1e-3,
    "mm": 1e3,
    "m": 1e6,
    "in": 25400.0,
    "urad": 1.0,
    "mrad": 1e3,
    "rad": 1e6,
    "arcsec": math.pi / 648000.0 * 1e6,
    "deg": math.pi / 180.0 * 1e6,
}
ANGLE_UNITS = ("urad", "mrad", "rad", "arcsec", "deg")
POSITION_FACTOR = {"mm": 1.0, "um": 1e-3, "m": 1e3, "in": 25.4}
TIME_FACTOR = {"s": 1.0, "ms": 1e-3, "min": 60.0, "h": 3600.0}
PRESSURE_FACTOR_KPA = {"kpa": 1.0, "pa": 1e-3, "hpa": 0.1, "mbar": 0.1, "bar": 100.0}

_ALIASES = {
    "µm": "um", "μm": "um", "micron": "um", "microns": "um", "micrometre": "um",
    "micrometer": "um", "µrad": "urad", "μrad": "urad", "um/m": "urad", "µm/m": "urad",
    "arc-sec": "arcsec", "arcsecond": "arcsec", "arcseconds": "arcsec", '"': "arcsec",
    "sec": "s", "second": "s", "seconds": "s", "minute": "min", "minutes": "min",
    "millimetre": "mm", "millimeter": "mm", "inch": "in",
}


def normalise_unit(unit: str) -> str:
    """``"µm"`` → ``"um"``, ``"Micron"`` → ``"um"``; other spellings unchanged (lower case)."""
    text = unit.strip()
    key = text.lower()
    return _ALIASES.get(text, _ALIASES.get(key, key))


def is_angle(unit: str) -> bool:
    return normalise_unit(unit) in ANGLE_UNITS
