"""Thermal test tables: declared units, conversions, and clear errors for bad input."""

from pathlib import Path

import numpy as np
import pytest
from volucal.core.io.thermal_table import ErrorColumn, ThermalTableFormat, read_thermal_table
from volucal.core.thermal import thermal_measurement
from volucal.core.userror import FormatError, UserError

HEADER = "time [min],drift [mm],tilt (arcsec),T spindle (°C),T bed (K)"


def write(tmp_path: Path, text: str, name: str = "run.csv", bom: bool = False) -> Path:
    path = tmp_path / name
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode("utf-8"))
    return path


def table(rows: list[str], header: str = HEADER) -> str:
    return "\n".join([header, *rows]) + "\n"


ROWS = [
    "0,0.000,0.0,22.0,295.15",
    "1,0.001,0.5,22.5,295.25",
    "2,0.003,1.0,23.5,295.45",
    "3,0.004,1.5,24.0,295.65",
]
BOTH = (ErrorColumn("drift"), ErrorColumn("tilt"))


def test_header_units_are_converted_once(tmp_path: Path) -> None:
    path = write(tmp_path, table(ROWS), bom=True)
    m = read_thermal_table(path, ThermalTableFormat(errors=BOTH))
    np.testing.assert_allclose(m.time_s, [0, 60, 120, 180])
    drift, tilt = m.errors
    assert (drift.name, drift.unit, drift.raw_unit) == ("drift", "um", "mm")
    np.testing.assert_allclose(drift.values, [0, 1, 3, 4])
    assert (tilt.unit, tilt.raw_unit) == ("urad", "arcsec")
    np.testing.assert_allclose(tilt.values, np.array([0, 0.5, 1, 1.5]) * np.pi / 648000 * 1e6)
    assert m.sensor_names == ("T spindle", "T bed")
    np.testing.assert_allclose(m.temperature_map()["T bed"], [22.0, 22.1, 22.3, 22.5])
    assert m.source_bytes == path.read_bytes()
    assert "time column" in m.time_source


def test_declared_units_for_a_bare_header(tmp_path: Path) -> None:
    text = "\n".join(["dz T1 T2", "0 20 21", "0.5 20.5 21.1", "1.0 21 21.3"]) + "\n"
    path = write(tmp_path, text, "run.txt")
    fmt = ThermalTableFormat(errors=(ErrorColumn("dz", "um", sign=-1),), temperature_unit="F",
                             sample_interval_s=30.0)
    m = read_thermal_table(path, fmt)
    np.testing.assert_allclose(m.errors[0].values, [0, -0.5, -1.0])
    np.testing.assert_allclose(m.temperature_map()["T1"], (np.array([20, 20.5, 21]) - 32) / 1.8)
    np.testing.assert_allclose(m.time_s, [0, 30, 60])
    assert "declared sample interval 30 s" in m.time_source


def test_a_missing_unit_is_an_error_that_asks_for_one(tmp_path: Path) -> None:
    text = "\n".join(["t,dz,T1", "0,0,20", "1,1,21"]) + "\n"
    path = write(tmp_path, text)
    with pytest.raises(FormatError, match=r"error column 'dz' has no unit: declare it"):
        read_thermal_table(path, ThermalTableFormat((ErrorColumn("dz"),), temperature_unit="C",
                                                    time_unit="s"))
    with pytest.raises(FormatError, match=r"temperature column 'T1' has no unit"):
        read_thermal_table(path, ThermalTableFormat((ErrorColumn("dz", "um"),), time_unit="s"))
    with pytest.raises(FormatError, match=r"time column 't' has no unit.*--time-unit"):
        read_thermal_table(path, ThermalTableFormat((ErrorColumn("dz", "um"),),
                                                    temperature_unit="C"))
    no_time = write(tmp_path, "dz,T1\n0,20\n1,21\n", "b.csv")
    with pytest.raises(FormatError, match=r"no time column.*--interval"):
        read_thermal_table(no_time, ThermalTableFormat((ErrorColumn("dz", "um"),),
                                                       temperature_unit="C"))


def test_declared_and_header_units_must_agree(tmp_path: Path) -> None:
    path = write(tmp_path, table(ROWS))
    with pytest.raises(FormatError, match=r"declared as 'um' but the header says 'mm'"):
        read_thermal_table(path, ThermalTableFormat((ErrorColumn("drift", "um"),)))
    with pytest.raises(FormatError, match=r"declared as 'C' but the header says 'K'"):
        read_thermal_table(path, ThermalTableFormat(BOTH, temperature_unit="C"))
    # a column left to the temperatures by default must be a temperature
    with pytest.raises(FormatError, match=r"'tilt \(arcsec\)': unit 'arcsec' is not a "
                       "temperature unit"):
        read_thermal_table(path, ThermalTableFormat((ErrorColumn("drift"),)))


@pytest.mark.parametrize(
    ("cell", "what"),
    [("", "a gap"), ("NaN", "NaN"), ("n/a", "a gap")],
)
def test_a_gap_or_nan_names_file_line_and_column(tmp_path: Path, cell: str, what: str) -> None:
    rows = list(ROWS)
    rows[2] = f"2,0.003,1.0,{cell},295.45"
    path = write(tmp_path, table(rows))
    with pytest.raises(FormatError) as caught:
        read_thermal_table(path, ThermalTableFormat(errors=BOTH))
    message = str(caught.value)
    assert str(path) in message and "line 4" in message
    assert "'T spindle (°C)'" in message and what in message
    assert caught.value.line == 4


def test_a_row_cut_short_and_a_word_are_errors(tmp_path: Path) -> None:
    rows = list(ROWS)
    rows[1] = "1,0.001,0.5"
    path = write(tmp_path, table(rows))
    with pytest.raises(FormatError, match=r"line 3: column 'T spindle \(°C\)' \(temperature\) "
                       r"has no value: the row has 3 fields"):
        read_thermal_table(path, ThermalTableFormat(errors=BOTH))
    rows = list(ROWS)
    rows[3] = "3,0.004,1.5,hot,295.65"
    path = write(tmp_path, table(rows), "c.csv")
    with pytest.raises(FormatError, match=r"line 5: column 'T spindle \(°C\)' \(temperature\): "
                       r"expected a number, found 'hot'"):
        read_thermal_table(path, ThermalTableFormat(errors=BOTH))


def test_time_must_increase(tmp_path: Path) -> None:
    rows = list(ROWS)
    rows[2] = "0.5,0.003,1.0,23.5,295.45"
    path = write(tmp_path, table(rows))
    with pytest.raises(FormatError, match=r"line 4: time column 'time \[min\]' goes back "
                       r"\(0.5 after 1 on line 3\)"):
        read_thermal_table(path, ThermalTableFormat(errors=BOTH))
    rows[2] = "1,0.003,1.0,23.5,295.45"
    path = write(tmp_path, table(rows), "d.csv")
    with pytest.raises(FormatError, match=r"line 4: time column 'time \[min\]' repeats"):
        read_thermal_table(path, ThermalTableFormat(errors=BOTH))


def test_iso_date_times(tmp_path: Path) -> None:
    text = "\n".join(["time,dz [um],T1 [C]", "2024-03-01T08:00:00,0,20",
                      "2024-03-01T08:01:00,1,21", "2024-03-01T08:03:00,2,22"]) + "\n"
    m = read_thermal_table(write(tmp_path, text), ThermalTableFormat((ErrorColumn("dz"),)))
    np.testing.assert_allclose(m.time_s, [0, 60, 180])
    assert m.start_time == pytest.approx(1709280000.0)


def test_a_stuck_sensor_is_excluded_with_a_warning(tmp_path: Path) -> None:
    text = "\n".join(["dz [um],T1 [C],T2 [C]", "0,20,25.5", "1,21,25.5", "2,22,25.5"]) + "\n"
    m = read_thermal_table(write(tmp_path, text), ThermalTableFormat(
        (ErrorColumn("dz"),), sample_interval_s=60))
    assert m.sensor_names == ("T1",)
    assert [e.name for e in m.excluded] == ["T2"]
    assert any("'T2' is stuck at 25.5 °C" in w and "left out" in w for w in m.warnings)


def test_columns_by_number_without_header(tmp_path: Path) -> None:
    path = write(tmp_path, "0 20 1.5\n1 21 1.7\n2 23 2.0\n", "n.txt")
    m = read_thermal_table(path, ThermalTableFormat(
        (ErrorColumn(3, "um", name="Z"),), temperatures=(2,), temperature_unit="C",
        time=1, time_unit="h"))
    np.testing.assert_allclose(m.time_s, [0, 3600, 7200])
    assert m.errors[0].name == "Z" and m.sensor_names == ("T2",)
    with pytest.raises(FormatError, match="no header row: give the error column 'dz' by number"):
        read_thermal_table(path, ThermalTableFormat((ErrorColumn("dz", "um"),),
                                                    temperature_unit="C", sample_interval_s=1))


def test_measurement_checks_from_arrays() -> None:
    with pytest.raises(UserError, match="time does not increase at sample 3"):
        thermal_measurement("m", [0, 1, 1, 2], {"e": [0, 1, 2, 3]}, {"T": [1, 2, 3, 4]})
    with pytest.raises(UserError, match="channel 'T' has no value at sample 2"):
        thermal_measurement("m", [0, 1, 2], {"e": [0, 1, 2]}, {"T": [1, np.nan, 3]})
    m = thermal_measurement("m", [10, 11, 12, 100], {"e": [0, 1, 2, 3]}, {"T": [1, 2, 3, 4]})
    np.testing.assert_allclose(m.time_s, [0, 1, 2, 90])
    assert any("a gap of 88 s between samples 3 and 4" in w for w in m.warnings)
    with pytest.raises(UserError, match="no error channel 'x'"):
        m.error("x")


def test_a_time_column_beside_a_declared_interval_is_not_a_temperature(tmp_path: Path) -> None:
    text = "\n".join(["time [s],dz [um],T1 [C]", "0,0,20", "7,1,21", "30,2,22"]) + "\n"
    m = read_thermal_table(write(tmp_path, text), ThermalTableFormat(
        (ErrorColumn("dz"),), sample_interval_s=10.0))
    assert m.sensor_names == ("T1",)
    np.testing.assert_allclose(m.time_s, [0, 10, 20])
    assert any("'time [s]' is not used" in w for w in m.warnings)
