"""Environmental correction of laser readings: air refractive index and material temperature.

A laser interferometer counts fringes of its wavelength *in air*; the displacement it reports is
``N·λ_vac / (2·n)`` with the refractive index ``n`` it assumed. Laser software normally measures
the air and applies the right ``n`` and normalises the reading to a 20 °C machine (the plan's
default ``env_corrected = true`` trusts that). For readings taken without it, volucal re-corrects
from the logged air temperature, pressure and humidity and the material temperature:

    L_air = L_read · n_assumed / n(t, p, h)            (refractive index, modified Edlén)
    L_20  = L_air · (1 − α·(T_material − 20 °C))       (material normalisation, ISO 1 reference)

with L the displacement since the laser was zeroed (the line's first target).

The refractive index follows the modified Edlén equation of the NIST Engineering Metrology
Toolbox (Stone & Zimmerman; Birch & Downs 1993/1994 with NIST's water-vapour term), REFERENCE.md
§5, and the saturation vapour pressure of its Appendix A-I (IAPWS 1997, over water).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .measurement import LineData

FloatArray = NDArray[np.float64]

HENE_WAVELENGTH_UM = 0.633
#: The conditions an uncompensated laser is taken to have assumed unless the plan says otherwise.
STANDARD_AIR = {"temp_c": 20.0, "pressure_pa": 101325.0, "humidity_pct": 50.0}

# IAPWS-IF97 saturation-pressure coefficients (NIST EMT, Appendix A-I)
_K = (
    1.16705214528e3,
    -7.24213167032e5,
    -1.70738469401e1,
    1.20208247025e4,
    -3.23255503223e6,
    1.49151086135e1,
    -4.82326573616e3,
    4.05113405421e5,
    -2.38555575678e-1,
    6.50175348448e2,
)


def saturation_vapour_pressure_pa(temp_c: ArrayLike) -> FloatArray:
    """Saturation vapour pressure over water (Pa), IAPWS 1997 as in NIST EMT Appendix A-I.

    Valid from 0 °C to 100 °C (the range checked here); 2339.2 Pa at 20 °C.
    """
    t = np.asarray(temp_c, dtype=float)
    if np.any((t < 0.0) | (t > 100.0)):
        raise ValueError("saturation vapour pressure: temperature outside 0 … 100 °C")
    k = _K
    kelvin = t + 273.15
    omega = kelvin + k[8] / (kelvin - k[9])
    a = omega**2 + k[0] * omega + k[1]
    b = k[2] * omega**2 + k[3] * omega + k[4]
    c = k[5] * omega**2 + k[6] * omega + k[7]
    x = -b + np.sqrt(b**2 - 4.0 * a * c)
    return np.asarray(1e6 * (2.0 * c / x) ** 4)


def air_refractive_index(
    temp_c: ArrayLike,
    pressure_pa: ArrayLike,
    humidity_pct: ArrayLike | None = None,
    *,
    vapour_pressure_pa: ArrayLike | None = None,
    wavelength_um: float = HENE_WAVELENGTH_UM,
) -> FloatArray:
    """Refractive index of air by the modified Edlén equation (NIST EMT, Appendix A-IV).

    Parameters
    ----------
    temp_c : air temperature, °C.
    pressure_pa : air pressure, Pa.
    humidity_pct : relative humidity, %; or give ``vapour_pressure_pa`` (partial pressure of
        water vapour, Pa) instead. Neither means dry air.
    wavelength_um : vacuum wavelength, µm (HeNe 0.633).

    Notes
    -----
    S = 1/λ², n_s − 1 = 1e-8 (8342.54 + 2406147/(130 − S) + 15998/(38.9 − S)),
    X = (1 + 1e-8 (0.601 − 0.00972 t) p)/(1 + 0.003661 t), n_tp = 1 + p (n_s − 1) X / 96095.43,
    n = n_tp − 1e-10 (292.75/(t + 273.15)) (3.7345 − 0.0401 S) p_v.
    """
    t = np.asarray(temp_c, dtype=float)
    p = np.asarray(pressure_pa, dtype=float)
    if humidity_pct is not None and vapour_pressure_pa is not None:
        raise ValueError("give humidity_pct or vapour_pressure_pa, not both")
    if vapour_pressure_pa is not None:
        pv = np.asarray(vapour_pressure_pa, dtype=float)
    elif humidity_pct is not None:
        h = np.asarray(humidity_pct, dtype=float)
        if np.any((h < 0.0) | (h > 100.0)):
            raise ValueError("relative humidity outside 0 … 100 %")
        pv = h / 100.0 * saturation_vapour_pressure_pa(t)
    else:
        pv = np.zeros_like(t)
    s = 1.0 / wavelength_um**2
    ns_minus_1 = 1e-8 * (8342.54 + 2406147.0 / (130.0 - s) + 15998.0 / (38.9 - s))
    x = (1.0 + 1e-8 * (0.601 - 0.00972 * t) * p) / (1.0 + 0.003661 * t)
    n_tp = 1.0 + p * ns_minus_1 * x / 96095.43
    return np.asarray(n_tp - 1e-10 * (292.75 / (t + 273.15)) * (3.7345 - 0.0401 * s) * pv)


def standard_air_index(wavelength_um: float = HENE_WAVELENGTH_UM) -> float:
    """Index of air at 20 °C, 101.325 kPa, 50 %RH (what an uncompensated reading assumed)."""
    return float(
        air_refractive_index(
            STANDARD_AIR["temp_c"],
            STANDARD_AIR["pressure_pa"],
            STANDARD_AIR["humidity_pct"],
            wavelength_um=wavelength_um,
        )
    )


def correct_linear(
    deviation_um: ArrayLike,
    position_mm: ArrayLike,
    *,
    air_temp_c: ArrayLike | None = None,
    pressure_pa: ArrayLike | None = None,
    humidity_pct: ArrayLike | None = None,
    material_temp_c: ArrayLike | None = None,
    expansion_ppm_per_c: float | None = None,
    assumed_index: float | None = None,
    wavelength_um: float = HENE_WAVELENGTH_UM,
) -> FloatArray:
    """Re-correct linear deviations (µm) read at ``position_mm`` from the laser's zero.

    With air temperature and pressure given, the reading is rescaled from the index the laser
    assumed (``assumed_index``, default :func:`standard_air_index`) to the modified-Edlén index of
    the logged air; with material temperature and ``expansion_ppm_per_c`` given, it is normalised
    to 20 °C: L₂₀ = L·(1 − α (T − 20)). Either step is skipped when its inputs are None. Returns
    ``L − position`` in µm (the corrected deviation).
    """
    position_um = np.asarray(position_mm, dtype=float) * 1e3
    length_um = position_um + np.asarray(deviation_um, dtype=float)
    if air_temp_c is not None and pressure_pa is not None:
        n_air = air_refractive_index(
            air_temp_c, pressure_pa, humidity_pct, wavelength_um=wavelength_um
        )
        n_assumed = standard_air_index(wavelength_um) if assumed_index is None else assumed_index
        length_um = length_um * n_assumed / n_air
    if material_temp_c is not None and expansion_ppm_per_c is not None:
        delta_c = np.asarray(material_temp_c, dtype=float) - 20.0
        length_um = length_um * (1.0 - expansion_ppm_per_c * 1e-6 * delta_c)
    return np.asarray(length_um - position_um)


def correct_line_data(
    data: LineData,
    *,
    expansion_ppm_per_c: float | None = None,
    assumed_index: float | None = None,
    wavelength_um: float = HENE_WAVELENGTH_UM,
) -> tuple[LineData, list[str]]:
    """Apply :func:`correct_linear` to a linear line, per reading, from its logged environment.

    Air temperature and material temperature come per reading when the file gave them, otherwise
    they (and pressure and humidity) are interpolated in time between the start and end values of
    ``data.environment``. The expansion coefficient defaults to the file's. Returns the corrected
    data and a description of each correction applied.

    Raises
    ------
    ValueError
        If neither correction can be made, or a logged value is implausible (the message says
        which and how to fix it).
    """
    env = data.environment
    times = data.times_s
    span = float(np.nanmax(times) - np.nanmin(times)) if np.isfinite(times).any() else 0.0
    fraction = (times - np.nanmin(times)) / span if span > 0 else np.zeros_like(times)

    def interpolate(pair: tuple[float, float] | None) -> FloatArray | None:
        return None if pair is None else pair[0] + (pair[1] - pair[0]) * fraction

    air = data.air_temp_c if data.air_temp_c is not None else interpolate(env.air_temp_c)
    pressure_kpa = interpolate(env.air_pressure_kpa)
    humidity = interpolate(env.air_humidity_pct)
    material = data.material_temp_c
    if material is None and env.material_temp_c:
        sensors = np.asarray(env.material_temp_c)
        material = interpolate((float(sensors[:, 0].mean()), float(sensors[:, 1].mean())))
    alpha = expansion_ppm_per_c if expansion_ppm_per_c is not None else env.expansion_ppm_per_c

    applied: list[str] = []
    if air is not None and pressure_kpa is not None:
        _check_range(
            pressure_kpa,
            60.0,
            120.0,
            "air pressure",
            "kPa",
            " (a value near 1000 is in mbar/hPa: divide by 10)",
        )
        _check_range(air, 0.0, 40.0, "air temperature", "°C", "")
        if humidity is not None:
            _check_range(humidity, 0.0, 100.0, "relative humidity", "%", "")
        applied.append(
            "air refractive index by the modified Edlén equation from the logged air "
            "temperature, pressure"
            + (
                " and humidity"
                if humidity is not None
                else " (no humidity logged: dry air assumed)"
            )
        )
    else:
        air = None
    if material is not None and alpha is not None:
        _check_range(material, -10.0, 60.0, "material temperature", "°C", "")
        applied.append(f"material temperature normalised to 20 °C with α = {alpha:g} ppm/°C")
    else:
        material = None
    if not applied:
        raise ValueError(
            "env_corrected = false, but the file logs neither air temperature and pressure nor a "
            "material temperature with an expansion coefficient; set env_corrected = true if the "
            "laser software compensated, or give expansion_ppm_per_c"
        )
    corrected = correct_linear(
        data.deviations,
        np.broadcast_to(data.targets_mm, data.deviations.shape),
        air_temp_c=air,
        pressure_pa=None if pressure_kpa is None else pressure_kpa * 1e3,
        humidity_pct=humidity,
        material_temp_c=material,
        expansion_ppm_per_c=alpha,
        assumed_index=assumed_index,
        wavelength_um=wavelength_um,
    )
    return replace(data, deviations=corrected), applied


def _check_range(
    values: FloatArray, low: float, high: float, what: str, unit: str, hint: str
) -> None:
    finite = values[np.isfinite(values)]
    if finite.size and (finite.min() < low or finite.max() > high):
        raise ValueError(
            f"logged {what} {finite.min():g} … {finite.max():g} {unit} is outside the plausible "
            f"range {low:g} … {high:g} {unit}{hint}"
        )
