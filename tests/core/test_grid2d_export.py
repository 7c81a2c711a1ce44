"""2-D correction tables: the Aerotech .cal layout against a hand-written golden file, round
trips of the .cal and the CSV, the sign convention, and bad .cal files named by line."""

import numpy as np
import pytest
from volucal.core.compensation.export_grid2d import (
    Grid2DTable,
    cal_as_table,
    grid_table,
    read_aerotech_cal,
    write_aerotech_cal,
    write_grid_csv,
)
from volucal.core.grid2d import GridGauge, GridMeasurement
from volucal.core.grid2d_fit import GridFitRequest, identify_grid
from volucal.core.grid2d_vendor import vendor_correction
from volucal.core.userror import FormatError, UserError


def small_table(x0: float = 0.0, y0: float = 0.0) -> Grid2DTable:
    x = x0 + np.array([0.0, 5.0, 10.0])
    y = y0 + np.array([0.0, 5.0])
    error = np.array([[[0.0, 0.25, -0.5], [1.0, 1.125, 2.0]],      # X errors, rows Y
                      [[0.0, -0.75, 0.1], [0.3, 0.0, -1.23456]]])  # Y errors
    return Grid2DTable(x, y, error, (x0, y0), np.zeros((2, 3), dtype=bool))


GOLDEN = (
    "; from a hand-made table\r\n"
    "; volucal 2-D correction table in the layout of Aerotech's 2-D calibration files\r\n"
    "; sign: error = measured - commanded (um) with the set-up's gauge terms removed (laser "
    "zero per direction, mirror rotation), zero at the reference node; correction = -error, "
    "the value to add to the commanded position\r\n"
    "; values: X correction then Y correction per node, um (CORUNIT=PRIMARY/1000 with mm "
    "primary units)\r\n"
    "; rows: Y (axis 5) from 0 to 5 mm; columns: X (axis 6) from 0 to 10 mm\r\n"
    "; zero at X = 0 mm, Y = 0 mm\r\n"
    ":START2D 5 6 6 5 5.000 5.000 3 \r\n"
    ":START2D POSUNIT=PRIMARY CORUNIT=PRIMARY/1000\r\n"
    "0.0000  0.0000  \t-0.2500  0.7500  \t0.5000  -0.1000  \t\r\n"
    "-1.0000  -0.3000  \t-1.1250  0.0000  \t-2.0000  1.2346  \t\r\n"
    ":END\r\n"
)


def test_cal_file_layout_matches_the_vendor_layout_byte_for_byte(tmp_path):
    path = tmp_path / "t.cal"
    write_aerotech_cal(path, small_table(), {"X": 6, "Y": 5},
                       comments=["from a hand-made table"])
    assert path.read_bytes().decode("ascii") == GOLDEN


def test_cal_round_trip_offsets_and_column_axis(tmp_path):
    table = small_table(-10.0, -25.0)
    for columns in ("X", "Y"):
        path = tmp_path / f"{columns}.cal"
        write_aerotech_cal(path, table, {"X": 3, "Y": 1}, column_axis=columns)
        cal = read_aerotech_cal(path)
        if columns == "X":
            assert (cal.row_axis, cal.column_axis, cal.output_axes) == (1, 3, (3, 1))
            assert (cal.offset_row_mm, cal.offset_column_mm) == (25.0, 10.0)
        else:
            assert (cal.row_axis, cal.column_axis, cal.output_axes) == (3, 1, (1, 3))
        lattice, correction = cal_as_table(cal, {"X": 3, "Y": 1})
        np.testing.assert_array_equal(lattice.x_mm, table.x_mm)
        np.testing.assert_array_equal(lattice.y_mm, table.y_mm)
        np.testing.assert_allclose(correction, np.round(-table.error_um, 4), atol=1e-12)


def test_csv_grid_states_the_sign_and_holds_error_and_correction(tmp_path):
    path = tmp_path / "t.csv"
    write_grid_csv(path, small_table(), ["from a hand-made table"])
    lines = path.read_text().splitlines()
    assert lines[0] == "# from a hand-made table"
    assert lines[1].startswith("# sign: error = measured - commanded")
    assert lines[3] == ("x_mm,y_mm,error_x_um,error_y_um,correction_x_um,correction_y_um,"
                        "beyond_measured")
    assert lines[6] == "10.000000,0.000000,-0.5000,0.1000,0.5000,-0.1000,0"
    assert len(lines) == 4 + 6


def test_the_table_is_the_negated_error_zero_at_the_reference():
    x, y = np.meshgrid(np.arange(0.0, 41.0, 10.0), np.arange(0.0, 31.0, 10.0))
    position = np.stack([x.ravel(), y.ravel()], axis=1)
    error = np.stack([0.01 * position[:, 0] + 0.3, -0.02 * position[:, 1]], axis=1)
    grid = GridMeasurement("g", position, error + GridGauge(2.0, 1.0, 10.0).evaluate(position),
                           upper_axis=None)
    result = identify_grid(grid, GridFitRequest(surface=False, upper_axis=None))
    table = grid_table(result)
    assert table.error_um[:, 0, 0] == pytest.approx([0.0, 0.0], abs=1e-9)
    np.testing.assert_allclose(table.correction_um[0, 0], -0.01 * table.x_mm, atol=1e-4)
    finer = grid_table(result, 5.0)
    assert finer.x_mm.size == 9 and finer.y_mm.size == 7


def test_bad_cal_files_name_the_line(tmp_path):
    path = tmp_path / "bad.cal"
    path.write_text(":START2D 5 6 6 5 5.000 5.000 3\n:START2D POSUNIT=PRIMARY\n"
                    "0 0 1 1 2 2\n0 0 1 1 2\n:END\n")
    with pytest.raises(FormatError, match=r"bad\.cal, line 4: 5 values where :START2D "
                       "announces 6"):
        read_aerotech_cal(path)
    path.write_text("0 0 1 1\n")
    with pytest.raises(FormatError, match=r"bad\.cal, line 1: a table row before"):
        read_aerotech_cal(path)
    path.write_text(":START2D 5 6 6 5 5.000 5.000\n")
    with pytest.raises(FormatError, match="line 1: :START2D: expected"):
        read_aerotech_cal(path)
    cal_path = tmp_path / "ok.cal"
    write_aerotech_cal(cal_path, small_table(), {"X": 6, "Y": 5})
    with pytest.raises(UserError, match="neither X"):
        cal_as_table(read_aerotech_cal(cal_path), {"X": 1, "Y": 2})
    with pytest.raises(UserError, match="axis number of X"):
        write_aerotech_cal(cal_path, small_table(), {"Y": 5})


def test_vendor_method_on_a_known_map():
    x, y = np.meshgrid(np.arange(0.0, 21.0, 10.0), np.arange(0.0, 21.0, 10.0))
    position = np.stack([x.ravel(), y.ravel()], axis=1)
    # a turned mirror (−θ·y, +θ·x), offsets and a squareness-like slope in X only
    theta = 50.0e-3  # µm/mm
    error = np.stack([5.0 - theta * position[:, 1] - 0.02 * position[:, 1],
                      -3.0 + theta * position[:, 0]], axis=1)
    table = vendor_correction(GridMeasurement("g", position, error), scan_axis="X")
    # the method removes one rotation chosen to zero the X slope: the squareness lands in Y
    np.testing.assert_allclose(table.correction_um[0], 0.0, atol=1e-4)
    np.testing.assert_allclose(table.correction_um[1][0], [0.0, 0.2, 0.4], atol=1e-4)
    assert table.orthogonality_urad == pytest.approx(-20.0, abs=1e-6)
