"""The ``import`` and ``iso230-2`` commands through ``volucal.core.cli.main``."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from volucal.core.cli import main
from volucal.core.io.rtl import reading_times, write_rtl
from volucal.core.measurement import LineData
from volucal.core.project import Project

DATA = Path(__file__).resolve().parents[1] / "data" / "io"


@pytest.fixture
def plan(tmp_path) -> Path:
    for item in DATA.iterdir():
        if item.is_file():
            shutil.copy(item, tmp_path / item.name)
    return tmp_path / "plan.toml"


def test_import_creates_then_adds(plan, tmp_path, capsys):
    project = tmp_path / "p.h5"
    assert main(["import", str(project), str(plan)]) == 0
    out = capsys.readouterr().out
    assert "created; 5 line(s), 73 readings" in out
    assert "sign −1: the file's deviations are flipped" in out
    assert "no outliers flagged" in out
    assert Project.open(project).results("loops") == []

    # adding the same lines again is refused with one clear line on stderr
    assert main(["import", str(project), str(plan)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("volucal: error: the project already has line(s)")
    assert err.count("\n") == 1

    assert main(["import", str(project), str(plan), "--replace", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["created"] is False and summary["line_count"] == 5
    assert summary["readings"] == 73
    line = {entry["name"]: entry for entry in summary["lines"]}["z_linear"]
    assert line["sign"] == -1 and line["corrections"] == ["deviations converted from nm to um"]
    assert line["runs"] == 2 and line["targets"] == 4 and line["format"] == "table"


def test_import_reports_and_drops_outliers(plan, tmp_path, capsys):
    rng = np.random.default_rng(8)
    runs, count = 10, 9
    direction = np.tile([1, -1], runs // 2)
    deviations = np.round(rng.normal(0, 0.2, (runs, count)), 4)
    deviations[2, 4] += 9.0
    write_rtl(plan.parent / "x_axis_hand.rtl",
              LineData(np.linspace(0, 400, count), deviations, direction,
                       reading_times(runs, count, 900.0, direction), start_time=1.7e9))
    assert main(["import", str(tmp_path / "a.h5"), str(plan), "--json"]) == 0
    kept = json.loads(capsys.readouterr().out)
    assert [(f["line"], f["run"], f["target"], f["dropped"]) for f in kept["outliers"]] == [
        ("x_y0_z0", 3, 5, False)]
    assert "σ" in kept["outliers"][0]["reason"]
    stored = Project.open(tmp_path / "a.h5").measurement().line("x_y0_z0").data
    assert stored.deviations[2, 4] == deviations[2, 4]

    assert main(["import", str(tmp_path / "b.h5"), str(plan), "--drop-outliers"]) == 0
    out = capsys.readouterr().out
    assert "1 outlier flag(s), set to missing (--drop-outliers)" in out
    stored = Project.open(tmp_path / "b.h5").measurement().line("x_y0_z0").data
    assert np.isnan(stored.deviations[2, 4])
    raw = Project.open(tmp_path / "b.h5").raw_data("x_y0_z0")
    assert raw.deviations[2, 4] == deviations[2, 4]  # the raw values keep everything


def test_import_errors_are_one_line(plan, tmp_path, capsys):
    text = plan.read_text().replace("direction = [0, 1, 0]", "direction = [0, 1]")
    plan.write_text(text)
    assert main(["import", str(tmp_path / "p.h5"), str(plan)]) == 1
    err = capsys.readouterr().err
    assert "plan.toml, line " in err and "field 'direction'" in err and err.count("\n") == 1
    assert not (tmp_path / "p.h5").exists()


def test_iso230_2_json_for_logs_and_plans(plan, capsys):
    assert main(["iso230-2", str(DATA / "x_axis_hand.rtl"), str(DATA / "x_pitch_hand.rta"),
                 "--json"]) == 0
    lines = json.loads(capsys.readouterr().out)["lines"]
    assert lines[0]["name"] == "x_axis_hand" and lines[0]["B_um"] == pytest.approx(2.2)
    assert lines[0]["E_up_um"] == pytest.approx(8.2)
    assert lines[1]["unit"] == "urad" and "E_urad" in lines[1]
    assert main(["iso230-2", str(plan), "--json"]) == 0
    lines = json.loads(capsys.readouterr().out)["lines"]
    assert [entry["name"] for entry in lines] == [
        "x_y0_z0", "x_pitch_hand", "y_straightness_x", "z_linear", "z_iso"]
    z = {entry["name"]: entry for entry in lines}["z_iso"]
    assert z["runs_up"] == 3 and z["runs_down"] == 3


def test_iso230_2_text_table(capsys):
    assert main(["iso230-2", str(DATA / "x_axis_hand.rtl"), "--sign", "-1"]) == 0
    out = capsys.readouterr().out
    assert "A  accuracy" in out and "B  reversal value" in out
    assert "2.200" in out  # |B| does not depend on the sign
    assert "-8.300" in out  # x̄↑ at 400 mm, flipped


def test_iso230_2_straightness_of_a_vendor_file(realdata, capsys):
    path = realdata / "aerotech_flatness_angular" / "643630-1-1-X-test_Flatness.dat"
    assert main(["iso230-2", str(path), "--columns", "position=Position,deviation=Flat",
                 "--unit", "mm", "--data-marker", ":START", "--straightness", "--json"]) == 0
    entry = json.loads(capsys.readouterr().out)["lines"][0]
    assert round(entry["straightness_ls_um"], 3) == 1.444
    assert round(entry["straightness_ep_um"], 3) == 1.512


def test_iso230_2_bad_file_is_one_line(tmp_path, capsys):
    path = tmp_path / "bad.rtl"
    path.write_text("HEADER::\n")
    assert main(["iso230-2", str(path)]) == 1
    err = capsys.readouterr().err
    assert f"{path}, line 1:" in err and err.count("\n") == 1
