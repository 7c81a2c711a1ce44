"""``volucal grid`` through the user's path (cli.main) and grids in the HDF5 project."""

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from volucal.core.cli import main
from volucal.core.compensation.export_grid2d import read_aerotech_cal
from volucal.core.grid2d_store import get_grid, grid_identification, grid_names, put_grid
from volucal.core.io.accuracy2d import read_accuracy2d
from volucal.core.project import Project
from volucal.core.userror import UserError

DATA = Path(__file__).resolve().parents[1] / "data" / "grid"
SAMPLE = DATA / "accuracy2d_small.dat"
KGM_COLUMNS = "x=X,y=Y,deviation_x=dX,deviation_y=dY"


def test_accuracy2d_json(capsys):
    assert main(["grid", str(SAMPLE), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    grid = result["grids"][0]
    assert grid["readings"] == 12 and grid["nodes"] == {"x": 4, "y": 3}
    assert grid["metadata"]["preset"] == "aerotech-accuracy2d"
    ident = result["identification"]
    assert set(ident["parameters"]) >= {"EXX", "EYY", "EYX", "EXY", "ECY", "EC0Y"}
    assert ident["parameters"]["EXX"]["unit"] == "um"
    assert ident["parameters"]["ECY"]["unit"] == "urad"
    assert ident["upper_axis"] == "Y"
    assert "accuracy2d_small" in ident["gauges"]


def test_exports_and_text_report(tmp_path, capsys):
    cal, csv = tmp_path / "out.cal", tmp_path / "out.csv"
    assert main(["grid", str(SAMPLE), "--export-cal", str(cal), "--export-csv", str(csv)]) == 0
    text = capsys.readouterr().out
    assert "EC0Y  squareness of Y to X" in text
    assert f"wrote {cal}" in text and "correction = −(measured − commanded)" in text
    table = read_aerotech_cal(cal)
    assert (table.row_axis, table.column_axis) == (1, 2)  # AxisIndex 2 ; 1, Axis 1 = X
    assert table.values.shape == (2, 3, 4)
    assert csv.read_text().count("\n") == 4 + 12  # comment, sign, reference, header


def test_compare_with_its_own_cal(tmp_path, capsys):
    cal = tmp_path / "own.cal"
    assert main(["grid", str(SAMPLE), "--export-cal", str(cal)]) == 0
    capsys.readouterr()
    assert main(["grid", str(SAMPLE), "--compare-cal", str(cal), "--json"]) == 0
    comparison = json.loads(capsys.readouterr().out)["comparison"]
    assert comparison["matching_sign"] == "same"
    assert comparison["same_sign"]["rms_um"]["X"] < 1e-4  # the .cal's 0.1 nm rounding


def test_kgm_table_with_a_column_map(capsys):
    assert main(["grid", str(DATA / "kgm_grid.csv"), "--columns", KGM_COLUMNS,
                 "--upper-axis", "none", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["grids"][0]["nodes"] == {"x": 5, "y": 4}
    assert "ECY" not in result["identification"]["parameters"]


def test_bad_input_is_one_line_naming_file_and_line(tmp_path, capsys):
    bad = tmp_path / "cut.dat"
    bad.write_bytes(SAMPLE.read_bytes()[:-40])
    shutil.copy(DATA / "accuracy2d_small.set", tmp_path / "cut.set")
    assert main(["grid", str(bad)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert err.startswith(f"volucal: error: {bad}, line 54:")
    assert main(["grid", str(DATA / "kgm_grid.csv")]) == 1
    assert "--columns is needed" in capsys.readouterr().err
    assert main(["grid", str(DATA / "kgm_grid.csv"), "--columns", "x=X,y=Y,dx=dX"]) == 1
    assert "unknown grid column key(s) dx" in capsys.readouterr().err


def test_grids_are_stored_in_the_project(tmp_path, capsys):
    project = tmp_path / "p.h5"
    assert main(["grid", str(SAMPLE), "--project", str(project)]) == 0
    assert f"stored /grids/accuracy2d_small in {project} (created)" in capsys.readouterr().out
    with h5py.File(project, "r") as handle:
        assert "grids/accuracy2d_small/position_mm" in handle
        assert handle["grids/accuracy2d_small/deviation_um"].attrs["unit"] == "um"
    opened = Project.open(project)
    assert grid_names(opened) == ["accuracy2d_small"]
    stored = get_grid(opened, "accuracy2d_small")
    original = read_accuracy2d(SAMPLE)
    np.testing.assert_array_equal(stored.deviation_um, original.deviation_um)
    assert stored.source_bytes == SAMPLE.read_bytes()
    assert stored.units == original.units and stored.upper_axis == "Y"
    assert "EC0Y" in grid_identification(opened, "accuracy2d_small")["parameters"]
    assert main(["grid", str(SAMPLE), "--project", str(project)]) == 1
    assert "already has a grid" in capsys.readouterr().err
    assert main(["grid", str(SAMPLE), "--project", str(project), "--replace"]) == 0


def test_store_round_trip_of_a_partial_grid_and_old_projects(tmp_path):
    from volucal.core.grid2d import GridMeasurement

    position = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    deviation = np.array([[0.1, np.nan], [0.2, np.nan], [0.3, np.nan], [0.4, np.nan]])
    grid = GridMeasurement("kgm", position, deviation, units={"position": "mm"})
    project = Project.create()
    put_grid(project, grid)
    path = project.save(tmp_path / "a.h5")
    back = get_grid(Project.open(path), "kgm")
    np.testing.assert_array_equal(back.deviation_um, deviation)
    assert back.air_temp_c is None and back.upper_axis is None
    with pytest.raises(UserError, match="grid name"):
        put_grid(project, GridMeasurement("a/b", position, deviation))
    plain = Project.create().save(tmp_path / "plain.h5")
    assert grid_names(Project.open(plain)) == []
