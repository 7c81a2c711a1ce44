"""Units accepted in files, plans and options, and their conversion to volucal's units (µm, µrad,
mm, s, °C, kPa).

Conversion happens once, at import (STYLE.md). Every quantity read from a file has a unit from
the file itself (its format's definition, a header such as ``Flat [mm]``, a ``# unit:`` line), from
the plan or from the command line; volucal never assumes one (docs/formats.md, "Units").
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
LENGTH_UNITS = ("nm", "um", "mm", "m", "in")
POSITION_FACTOR = {"mm": 1.0, "um": 1e-3, "nm": 1e-6, "m": 1e3, "in": 25.4}
TIME_FACTOR = {"s": 1.0, "ms": 1e-3, "min": 60.0, "h": 3600.0}
#: Factor from a pressure unit to kPa (mmHg: 101.325/760 kPa, inHg: 3.386389 kPa).
PRESSURE_FACTOR_KPA = {
    "kpa": 1.0,
    "pa": 1e-3,
    "hpa": 0.1,
    "mbar": 0.1,
    "bar": 100.0,
    "mmhg": 101.325 / 760.0,
    "inhg": 3.386389,
}
#: Temperature units: (factor, offset) so that °C = value · factor + offset.
TEMPERATURE_UNITS = {"c": (1.0, 0.0), "f": (5.0 / 9.0, -32.0 * 5.0 / 9.0), "k": (1.0, -273.15)}

_ALIASES = {
    # lengths
    "µm": "um",
    "μm": "um",
    "micron": "um",
    "microns": "um",
    "micrometre": "um",
    "micrometres": "um",
    "micrometer": "um",
    "micrometers": "um",
    "nanometer": "nm",
    "nanometers": "nm",
    "nanometre": "nm",
    "nanometres": "nm",
    "millimetre": "mm",
    "millimetres": "mm",
    "millimeter": "mm",
    "millimeters": "mm",
    "metre": "m",
    "meter": "m",
    "metres": "m",
    "meters": "m",
    "inch": "in",
    "inches": "in",
    '"in': "in",
    # angles
    "µrad": "urad",
    "μrad": "urad",
    "microradian": "urad",
    "microradians": "urad",
    "um/m": "urad",
    "µm/m": "urad",
    "μm/m": "urad",
    "milliradian": "mrad",
    "milliradians": "mrad",
    "mm/m": "mrad",
    "radian": "rad",
    "radians": "rad",
    "arc-sec": "arcsec",
    "arc sec": "arcsec",
    "arcsecond": "arcsec",
    "arcseconds": "arcsec",
    "arc-second": "arcsec",
    "arc-seconds": "arcsec",
    '"': "arcsec",
    "″": "arcsec",
    "degree": "deg",
    "degrees": "deg",
    "°": "deg",
    # time
    "sec": "s",
    "second": "s",
    "seconds": "s",
    "minute": "min",
    "minutes": "min",
    "hour": "h",
    "hours": "h",
    "millisecond": "ms",
    "milliseconds": "ms",
    # pressure
    "torr": "mmhg",
    "mm hg": "mmhg",
    "mm-hg": "mmhg",
    "in hg": "inhg",
    "in-hg": "inhg",
    "inches hg": "inhg",
    "millibar": "mbar",
    "hectopascal": "hpa",
    "kilopascal": "kpa",
    "pascal": "pa",
    # temperature
    "°c": "c",
    "ºc": "c",
    "degc": "c",
    "deg c": "c",
    "celsius": "c",
    "°f": "f",
    "ºf": "f",
    "degf": "f",
    "deg f": "f",
    "fahrenheit": "f",
    "kelvin": "k",
}


def normalise_unit(unit: str) -> str:
    """``"µm"`` → ``"um"``, ``"Micron"`` → ``"um"``, ``"mmHg"`` → ``"mmhg"``, ``"°C"`` → ``"c"``;
    other spellings lower-cased and otherwise unchanged."""
    text = unit.strip()
    key = " ".join(text.lower().split())
    return _ALIASES.get(text, _ALIASES.get(key, key))


def is_angle(unit: str) -> bool:
    return normalise_unit(unit) in ANGLE_UNITS


def describe(unit: str) -> str:
    """How a normalised unit is printed: ``"um"`` → ``"µm"``, ``"mmhg"`` → ``"mmHg"``."""
    return _DISPLAY.get(unit, unit)


_DISPLAY = {
    "um": "µm",
    "urad": "µrad",
    "in": "inch",
    "kpa": "kPa",
    "pa": "Pa",
    "hpa": "hPa",
    "mbar": "mbar",
    "bar": "bar",
    "mmhg": "mmHg",
    "inhg": "inHg",
    "c": "°C",
    "f": "°F",
    "k": "K",
}


def choices(table: dict[str, object] | tuple[str, ...]) -> str:
    """The units of a table as a user reads them: ``"µm, nm, mm, …"``."""
    return ", ".join(describe(u) for u in table)
