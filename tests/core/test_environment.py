"""Air refractive index against published NIST Engineering Metrology Toolbox values, and the
re-correction of raw readings."""

from pathlib import Path

import numpy as np
import pytest
from volucal.core.environment import (
    air_refractive_index,
    correct_line_data,
    correct_linear,
    saturation_vapour_pressure_pa,
    standard_air_index,
)
from volucal.core.io.rtl import read_rtl

DATA = Path(__file__).resolve().parents[1] / "data" / "io"

# Modified Edlén values computed with the NIST EMT calculator (emtoolbox.nist.gov/Wavelength/
# Edlen.asp) at 20 °C, 101.325 kPa, 30 %RH, as published in Geant4's optical materials table
# (nm, n); and the calculator's default case (20 °C, 101.325 kPa, 50 %RH, 633 nm).
NIST_EDLEN_20C_30RH = [
    (300.0, 1.000286349), (350.0, 1.000280985), (400.0, 1.000277679), (450.0, 1.000275484),
    (500.0, 1.000273949), (550.0, 1.000272831), (600.0, 1.000271990), (650.0, 1.000271341),
    (700.0, 1.000270830),
]


@pytest.mark.parametrize("wavelength_nm, expected", NIST_EDLEN_20C_30RH)
def test_nist_emt_modified_edlen_table(wavelength_nm, expected):
    n = air_refractive_index(20.0, 101325.0, 30.0, wavelength_um=wavelength_nm / 1000)
    assert n == pytest.approx(expected, abs=1.5e-9)  # the published values have 9 decimals


def test_nist_emt_default_case():
    assert air_refractive_index(20.0, 101325.0, 50.0) == pytest.approx(1.000271374, abs=1.5e-9)
    assert standard_air_index() == pytest.approx(1.000271374, abs=1.5e-9)


def test_saturation_vapour_pressure_matches_steam_tables():
    # IAPWS steam tables: 2.3392 kPa at 20 °C, 3.1699 kPa at 25 °C, 101.418 kPa at 100 °C
    np.testing.assert_allclose(saturation_vapour_pressure_pa([20.0, 25.0, 100.0]),
                               [2339.2, 3169.9, 101418.0], rtol=2e-4)
    with pytest.raises(ValueError):
        saturation_vapour_pressure_pa(-5.0)


def test_vapour_pressure_and_humidity_agree():
    pv = 0.4 * saturation_vapour_pressure_pa(22.0)
    assert air_refractive_index(22.0, 100000.0, vapour_pressure_pa=pv) == pytest.approx(
        air_refractive_index(22.0, 100000.0, 40.0), abs=1e-15)
    with pytest.raises(ValueError):
        air_refractive_index(22.0, 100000.0, 40.0, vapour_pressure_pa=pv)
    with pytest.raises(ValueError):
        air_refractive_index(22.0, 100000.0, 140.0)


def test_nist_shop_floor_formula_agrees():
    """NIST EMT Appendix B: n = 1 + 7.86e-4 p/(273 + t) − 1.5e-11 RH (t² + 160), p in kPa,
    stated to agree with the full equation to a few parts in 1e8 near room conditions."""
    t, p, rh = np.meshgrid([15.0, 20.0, 25.0, 30.0], [95.0, 101.325, 105.0], [20.0, 50.0, 80.0])
    shop = 1 + 7.86e-4 * p / (273 + t) - 1.5e-11 * rh * (t**2 + 160)
    full = air_refractive_index(t, p * 1e3, rh)
    assert np.max(np.abs(shop - full)) < 1e-7


def test_known_sensitivities_of_a_length_reading():
    """Air refractivity changes by about −0.93 ppm/K and +0.27 ppm/hPa near 20 °C, 1013 hPa:
    a 400 mm reading taken with standard air assumed grows by those amounts."""
    base = dict(pressure_pa=101325.0, humidity_pct=50.0)
    same = correct_linear(0.0, 400.0, air_temp_c=20.0, **base)
    assert same == pytest.approx(0.0, abs=1e-9)
    warmer = correct_linear(0.0, 400.0, air_temp_c=21.0, **base)
    assert warmer == pytest.approx(-400e3 * -0.93e-6, rel=0.03)
    higher = correct_linear(0.0, 400.0, air_temp_c=20.0, pressure_pa=101425.0, humidity_pct=50.0)
    assert higher == pytest.approx(-400e3 * 0.27e-6, rel=0.03)


def test_material_normalisation_to_20c():
    # steel at 22 °C: the 400 mm the laser measured are 400·(1 − 11.5e-6·2) mm at 20 °C
    value = correct_linear(0.0, 400.0, material_temp_c=22.0, expansion_ppm_per_c=11.5)
    assert value == pytest.approx(-400e3 * 11.5e-6 * 2.0, abs=1e-9)
    # nothing to do at 20 °C, and nothing is done without a coefficient
    assert correct_linear(3.0, 400.0, material_temp_c=20.0, expansion_ppm_per_c=11.5) == 3.0
    assert correct_linear(3.0, 400.0, material_temp_c=25.0) == 3.0


def test_correct_line_data_uses_the_logged_environment():
    data = read_rtl(DATA / "x_axis_hand.rtl").data
    corrected, applied = correct_line_data(data)
    assert len(applied) == 2 and "Edlén" in applied[0] and "11.5 ppm" in applied[1]
    # the first target is the laser zero: almost untouched
    assert corrected.deviations[0, 0] == pytest.approx(data.deviations[0, 0], abs=1e-9)
    # at 400 mm: 99.04 kPa air lowers n by ~6.2 ppm (+2.5 µm), material at ~20.2 °C (−1.0 µm)
    shift = corrected.deviations[0, 4] - data.deviations[0, 4]
    n = air_refractive_index(data.air_temp_c[0, 4], 99.039005e3 + (99.049346e3 - 99.039005e3)
                             * 240 / 1140, 46.954897 + (46.893887 - 46.954897) * 240 / 1140)
    length = 400e3 + data.deviations[0, 4]
    expected = length * standard_air_index() / n * (
        1 - 11.5e-6 * (data.material_temp_c[0, 4] - 20)) - length
    assert shift == pytest.approx(expected, abs=1e-6)
    assert 1.2 < shift < 1.8


def test_correct_line_data_refuses_without_data_and_implausible_values():
    from dataclasses import replace

    from volucal.core.measurement import Environment

    data = read_rtl(DATA / "x_axis_hand.rtl").data
    bare = replace(data, environment=Environment(), air_temp_c=None, material_temp_c=None)
    with pytest.raises(ValueError, match="neither air temperature"):
        correct_line_data(bare)
    mbar = replace(data, environment=replace(data.environment, air_pressure_kpa=(990.4, 990.5)))
    with pytest.raises(ValueError, match="mbar"):
        correct_line_data(mbar)
