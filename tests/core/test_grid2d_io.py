"""Grid readers: the generic column map (a KGM-style export), the Aerotech Accuracy2D preset on a
checked-in synthetic sample, and bad input named by file and line."""

import shutil
from pathlib import Path

import numpy as np
import pytest
from volucal.core.grid2d_table import GridColumnMap, GridFormat, read_grid_table
from volucal.core.io.accuracy2d import is_accuracy2d, read_accuracy2d
from volucal.core.io.source import SourceText
from volucal.core.userror import FormatError

DATA = Path(__file__).resolve().parents[1] / "data" / "grid"
KGM = GridFormat(columns=GridColumnMap(x="X", y="Y", deviation_x="dX", deviation_y="dY"))


def test_kgm_style_table_with_units_in_the_header():
    grid = read_grid_table(DATA / "kgm_grid.csv", KGM)
    assert grid.count == 20
    np.testing.assert_array_equal(grid.position_mm[:5, 0], [-20, -10, 0, 10, 20])
    assert grid.deviation_um[0, 0] == pytest.approx(-0.6046)  # dX [um] as written
    assert grid.deviation_um[0, 1] == pytest.approx(-0.4212)
    assert grid.units["position"].startswith("mm (header")
    assert grid.units["deviation"].startswith("µm (header")
    assert grid.file_lines[0] == 3


def test_declared_units_convert_and_must_agree_with_the_header(tmp_path):
    path = tmp_path / "g.txt"
    path.write_text("x y dx dy\n0 0 1 2\n0.5 0 1 2\n0 0.5 1 2\n0.5 0.5 1 2\n")
    fmt = GridFormat(columns=GridColumnMap(deviation_x="dx", deviation_y="dy"),
                     position_unit="in", deviation_unit="nm")
    grid = read_grid_table(path, fmt)
    np.testing.assert_allclose(grid.position_mm[1], [12.7, 0.0])
    np.testing.assert_allclose(grid.deviation_um[0], [0.001, 0.002])
    clash = tmp_path / "h.txt"
    clash.write_text("x [mm] y [mm] dx dy\n0 0 1 2\n")  # spaced units stay with their names
    with pytest.raises(FormatError, match=r"h\.txt, line 1: .*says 'mm'.*declared as 'in'"):
        read_grid_table(clash, fmt)


def test_measured_positions_give_the_deviation_and_sign_minus_one_flips_it(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("x_mm,y_mm,mx_mm,my_mm\n0,0,0.001,-0.002\n10,0,10.002,0\n"
                    "0,10,0,10.001\n10,10,10,10\n")
    columns = GridColumnMap(measured_x="mx", measured_y="my")
    grid = read_grid_table(path, GridFormat(columns=columns))
    np.testing.assert_allclose(grid.deviation_um[0], [1.0, -2.0])
    flipped = read_grid_table(path, GridFormat(columns=columns, sign=-1))
    np.testing.assert_allclose(flipped.deviation_um[0], [-1.0, 2.0])


def test_a_missing_unit_is_an_error_that_asks_for_it(tmp_path):
    path = tmp_path / "nounit.csv"
    path.write_text("x,y,dx,dy\n0,0,1,1\n")
    fmt = GridFormat(columns=GridColumnMap(deviation_x="dx", deviation_y="dy"))
    with pytest.raises(FormatError, match=r"nounit\.csv, line 1: no unit for 'x'.*"
                       r"--position-unit"):
        read_grid_table(path, fmt)
    with pytest.raises(FormatError, match="no unit for 'dx'.*--deviation-unit"):
        read_grid_table(path, GridFormat(columns=fmt.columns, position_unit="mm"))


@pytest.mark.parametrize("body, line, message", [
    ("0,0,1,1\n10,0,1\n", 3, "3 fields where the header .* has 4: the file is cut short"),
    ("0,0,1,1\n10,0,x,1\n", 3, r"dx_um \(deviation_x\): expected a number, found 'x'"),
    ("0,0,1,1\n10,0,1,1\n0,10,1,1\n10,13,1,1\n", 5, "commanded Y = 13 mm is 3 mm off the "
     "grid's 10 mm nodes: check this line"),
    ("0,0,1,1\n10,0,1,1\n0,10,1,1\n", 4, "no reading at X = 10 mm, Y = 10 mm"),
    ("0,0,1,1\n10,0,1,1\n0,10,1,1\n10,10,1,2000\n", 5, "the Y deviation is 2 mm .*check "
     "the column map"),
])
def test_malformed_tables_name_the_line_and_what_to_do(tmp_path, body, line, message):
    path = tmp_path / "bad.csv"
    path.write_text("x_mm,y_mm,dx_um,dy_um\n" + body)
    fmt = GridFormat(columns=GridColumnMap(deviation_x="dx", deviation_y="dy"))
    with pytest.raises(FormatError, match=rf"bad\.csv, line {line}: {message}"):
        read_grid_table(path, fmt)


def test_environment_columns_are_converted_and_checked(tmp_path):
    path = tmp_path / "env.txt"
    rows = "".join(f"{x} {y} 0.1 0.2 20.5 750 {h}\n" for y in (0, 5) for x in (0, 5)
                   for h in (45,))
    path.write_text("x_mm y_mm dx_um dy_um T P RH\n" + rows)
    columns = GridColumnMap(deviation_x="dx", deviation_y="dy", air_temp="T", pressure="P",
                            humidity="RH")
    grid = read_grid_table(path, GridFormat(columns=columns, temperature_unit="C",
                                            pressure_unit="mmHg"))
    assert grid.pressure_kpa[0] == pytest.approx(99.99, abs=0.01)  # 750 mmHg
    assert grid.air_temp_c[0] == 20.5
    swapped = GridColumnMap(deviation_x="dx", deviation_y="dy", air_temp="P", pressure="T")
    with pytest.raises(FormatError, match=r"env\.txt, line 2: air temp 750 .*not plausible.*"
                       "check the column map"):
        read_grid_table(path, GridFormat(columns=swapped, temperature_unit="C",
                                         pressure_unit="mmHg"))


def test_accuracy2d_sample(tmp_path):
    path = DATA / "accuracy2d_small.dat"
    assert is_accuracy2d(SourceText.read(path))
    grid = read_accuracy2d(path)
    assert grid.count == 12
    assert grid.upper_axis == "Y"
    assert grid.metadata["axis_number_X"] == "2" and grid.metadata["axis_number_Y"] == "1"
    assert grid.units["position"].startswith("mm (PositionUnitName in accuracy2d_small.set")
    # LaserData − Position, in µm (the reading at X = 10 mm, Y = 10 mm)
    assert grid.deviation_um[5, 0] == pytest.approx((10.00049 - 10.0) * 1e3)
    assert grid.deviation_um[5, 1] == pytest.approx((9.99829 - 10.0) * 1e3)
    assert grid.pressure_kpa[0] == pytest.approx(745.20 * 0.1333223874)
    assert grid.material_temp_c[0] == 20.70
    swapped = read_accuracy2d(path, axes="YX")
    np.testing.assert_array_equal(swapped.position_mm[:, ::-1], grid.position_mm)


def test_accuracy2d_without_its_set_file_needs_the_unit(tmp_path):
    copy = tmp_path / "lonely.dat"
    shutil.copy(DATA / "accuracy2d_small.dat", copy)
    with pytest.raises(FormatError, match=r"lonely\.dat: no unit for the positions.*"
                       r"lonely\.set.*--position-unit mm"):
        read_accuracy2d(copy)
    assert read_accuracy2d(copy, position_unit="mm").count == 12


@pytest.mark.parametrize("edit, line, message", [
    (lambda t: t.replace("TestType : Accuracy2D", "TestType : Accuracy"), 15, "not 'Accuracy2D'"),
    (lambda t: t.replace("LaserData2", "Laser2"), 41, "expected the columns"),
    (lambda t: t.rsplit("\r\n", 2)[0] + "\r\n", 53, "11 readings where StepSize and "
     "TestLength .* announce 12: the file is cut short"),
    (lambda t: t.replace(":START", "START"), 54, "no ':START' line"),
    (lambda t: t.replace("SerialNum : 000000-1-1-XStage ; 000000-1-1-YStage",
                         "SerialNum : A ; B"), 2, "cannot tell which of Axis 1 and Axis 2 is X"),
])
def test_malformed_accuracy2d_files(tmp_path, edit, line, message):
    text = (DATA / "accuracy2d_small.dat").read_bytes().decode("ascii")
    bad = tmp_path / "bad.dat"
    bad.write_bytes(edit(text).encode("ascii"))
    shutil.copy(DATA / "accuracy2d_small.set", tmp_path / "bad.set")
    with pytest.raises(FormatError, match=rf"bad\.dat, line {line}: .*{message}"):
        read_accuracy2d(bad)
