"""The ``import`` and ``iso230-2`` commands through ``volucal.core.cli.main``."""

import json
import re
import shutil
import subprocess
import sys
import unicodedata
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


def _with_an_outlier(plan: Path) -> np.ndarray:
    """Write the plan's x_y0_z0 log anew with one reading (run 3, target 5 at 200 mm) 9 µm off
    the other runs; return its deviations."""
    rng = np.random.default_rng(8)
    runs, count = 10, 9
    direction = np.tile([1, -1], runs // 2)
    deviations = np.round(rng.normal(0, 0.2, (runs, count)), 4)
    deviations[2, 4] += 9.0
    times = reading_times(runs, count, 900.0, direction)
    data = LineData(np.linspace(0, 400, count), deviations, direction, times, start_time=1.7e9)
    write_rtl(plan.parent / "x_axis_hand.rtl", data)
    return deviations


def test_import_reports_and_drops_outliers(plan, tmp_path, capsys):
    deviations = _with_an_outlier(plan)
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


def test_calibrate_names_the_outliers_flagged_at_import(plan, tmp_path, capsys):
    # a reading 9 µm off the other runs: the import flags it; calibrate fitted it silently,
    # its console said nothing, and report.json held the flag as a Python repr
    _with_an_outlier(plan)
    report = tmp_path / "r.json"
    assert main(["calibrate", str(plan), "--no-sensitivity", "--report", str(report)]) == 0
    out = capsys.readouterr().out
    assert "1 outlier flag(s) at import, kept in the fit (--drop-outliers leaves them out):" in out
    (flag,) = json.loads(report.read_text())["outlier_flags"]
    assert flag.startswith("line x_y0_z0: reading at 200 mm, run 3 ")
    assert "σ" in flag and f"  {flag}" in out.splitlines()
    assert json.loads(report.read_text())["outliers_dropped"] is False

    assert main(["calibrate", str(plan), "--no-sensitivity", "--drop-outliers"]) == 0
    assert "1 outlier flag(s) at import, set to missing (--drop-outliers):" in (
        capsys.readouterr().out
    )


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


def test_iso230_2_tabulates_the_targets_where_the_plan_or_the_file_puts_them(plan, capsys):
    # a file alone: the positions it gives (TGT_DATA 10, 20, 30 mm), as an ISO 230-2 report
    # lists them, beside the distances from the first target
    assert main(["iso230-2", str(DATA / "ecmc_hand.dat"), "--json"]) == 0
    entry = json.loads(capsys.readouterr().out)["lines"][0]
    assert entry["targets_mm"] == [0.0, 10.0, 20.0]
    assert entry["positions_mm"] == [10.0, 20.0, 30.0] and entry["positions_of"] == "file"
    assert main(["iso230-2", str(DATA / "ecmc_hand.dat")]) == 0
    rows = capsys.readouterr().out.splitlines()
    heading = next(i for i, row in enumerate(rows) if "x̄↑" in row)
    assert rows[heading].split()[:2] == ["position", "mm"]
    assert [row.split()[0] for row in rows[heading + 1 :]] == ["10.000", "20.000", "30.000"]
    # a plan's line along Z from Z = -180 mm: the machine's Z of each target
    assert main(["iso230-2", str(plan), "--json"]) == 0
    z = {e["name"]: e for e in json.loads(capsys.readouterr().out)["lines"]}["z_iso"]
    assert z["targets_mm"] == [0.0, 60.0, 120.0, 180.0]
    assert z["positions_mm"] == [-180.0, -120.0, -60.0, 0.0] and z["positions_of"] == "Z"
    # and the import's note that the file lists them at 0 … 180 mm
    assert any("file puts its targets at 0 … 180 mm" in note for note in z["notes"])
    assert main(["iso230-2", str(plan)]) == 0
    out = capsys.readouterr().out
    z_table = out[out.index("z_iso (") :].splitlines()
    heading = next(i for i, row in enumerate(z_table) if "x̄↑" in row)
    assert z_table[heading].split()[:2] == ["Z", "mm"]
    assert z_table[heading + 1].split()[0] == "-180.000"


def test_iso230_2_lists_a_real_ecmc_table_at_its_target_positions(realdata, capsys):
    # ESS's ecmc test data: targets TGT_DATA 15 … 55 mm, as its own report lists them
    path = realdata / "ess_ecmc_iso230_2" / "slit11360_axis1_testdata_ISO230_2.dat"
    assert main(["iso230-2", str(path), "--json"]) == 0
    entry = json.loads(capsys.readouterr().out)["lines"][0]
    assert entry["positions_mm"] == [15.0, 25.0, 35.0, 45.0, 55.0]
    assert entry["targets_mm"] == [0.0, 10.0, 20.0, 30.0, 40.0]


def test_iso230_2_text_table(capsys):
    assert main(["iso230-2", str(DATA / "x_axis_hand.rtl"), "--sign", "-1"]) == 0
    out = capsys.readouterr().out
    assert "A  accuracy" in out and "B  reversal value" in out
    assert "2.200" in out  # |B| does not depend on the sign
    assert "-8.300" in out  # x̄↑ at 400 mm, flipped


def test_iso230_2_straightness_of_a_vendor_file(realdata, capsys):
    path = realdata / "aerotech_flatness_angular" / "643630-1-1-X-test_Flatness.dat"
    # the file states no unit for its positions: volucal asks for one rather than assume mm
    args = ["iso230-2", str(path), "--columns", "position=Position,deviation=Flat", "--unit", "mm",
            "--data-marker", ":START", "--straightness"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'Position' has no unit" in err and "--position-unit" in err
    assert main([*args, "--position-unit", "mm", "--json"]) == 0
    entry = json.loads(capsys.readouterr().out)["lines"][0]
    assert round(entry["straightness_ls_um"], 3) == 1.444
    assert round(entry["straightness_mz_um"], 3) == 1.418
    assert round(entry["straightness_ep_um"], 3) == 1.512
    values = entry["straightness"]
    assert values["least_squares_um"] == entry["straightness_ls_um"]
    assert values["minimum_zone_um"] == entry["straightness_mz_um"]
    assert values["methods"]["minimum_zone"] == "minimum zone (ISO 230-1)"
    assert main(["iso230-2", str(path), "--columns", "deviation=Flat", "--unit", "mm",
                 "--position-unit", "mm", "--data-marker", ":START", "--straightness"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"least-squares reference line \(ISO 230-1\)\s+1\.444", out)
    assert re.search(r"minimum zone \(ISO 230-1\)\s+1\.418", out)
    assert "note: deviations converted from mm" in out


def test_iso230_2_bad_file_is_one_line(tmp_path, capsys):
    path = tmp_path / "bad.rtl"
    path.write_text("HEADER::\n")
    assert main(["iso230-2", str(path)]) == 1
    err = capsys.readouterr().err
    assert f"{path}, line 1:" in err and err.count("\n") == 1


def test_iso230_2_straightness_lines_of_a_plan_always_get_both_methods(plan, capsys):
    assert main(["iso230-2", str(plan), "--json"]) == 0
    lines = {entry["name"]: entry for entry in json.loads(capsys.readouterr().out)["lines"]}
    straight = lines["y_straightness_x"]["straightness"]
    assert straight["minimum_zone_um"] <= straight["least_squares_um"]
    assert "straightness" not in lines["x_y0_z0"]  # a linear line, no --straightness


def test_iso230_2_refuses_a_table_without_a_unit(realdata, capsys):
    """Yaw/pitch/roll columns without a unit were read as µm and labelled linear."""
    path = realdata / "aerotech_flatness_angular" / "643630-1-1-X-test_Angular.dat"
    args = ["iso230-2", str(path), "--data-marker", ":START", "--columns", "deviation=Yaw",
            "--position-unit", "mm"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'Yaw' has no unit" in err and "--unit" in err
    assert main([*args, "--unit", "um"]) == 1
    assert "holds an angle" in capsys.readouterr().err
    assert main([*args, "--unit", "arcsec", "--json"]) == 0
    entry = json.loads(capsys.readouterr().out)["lines"][0]
    assert entry["quantity"] == "angular" and "E_up_urad" in entry


def test_iso230_2_excludes_and_lists_outliers(realdata, capsys):
    """Cycle 1 of the ESS mcu1025 file reads +114 µm at the first target (46 σ)."""
    path = realdata / "psi_ecmc_iso230_2" / "ess_mcu1025_fat_sat_report.md_ISO230.dat"
    assert main(["iso230-2", str(path), "--json"]) == 0
    kept = json.loads(capsys.readouterr().out)["lines"][0]
    assert main(["iso230-2", str(path), "--json", "--exclude-outliers"]) == 0
    cleaned = json.loads(capsys.readouterr().out)["lines"][0]
    excluded = cleaned["excluded"]
    assert {(flag["run"], flag["target"]) for flag in excluded} >= {(1, 1), (1, 2)}
    first = next(flag for flag in excluded if (flag["run"], flag["target"]) == (1, 1))
    assert first["statistic"] > 40
    assert cleaned["A_up_um"] < kept["A_up_um"] - 100  # the +114 µm reading no longer counts
    assert main(["iso230-2", str(path), "--exclude-outliers"]) == 0
    out = capsys.readouterr().out
    assert f"excluded as outliers (--exclude-outliers), {len(excluded)}:" in out
    assert "run 1 (forward)" in out
    assert main(["iso230-2", str(DATA / "x_axis_hand.rtl"), "--exclude-outliers"]) == 0
    assert "excluded as outliers (--exclude-outliers): none" in capsys.readouterr().out


def test_iso230_2_columns_stay_apart_for_large_values(tmp_path, capsys):
    path = tmp_path / "big.csv"
    rows = [f"{r},{d},{t * 100},{123456.789 * (1 + t) * (-1) ** r + r}"
            for r, d in ((1, "+1"), (2, "-1"), (3, "+1"), (4, "-1")) for t in range(3)]
    path.write_text("run,direction,position_mm,deviation_um\n" + "\n".join(rows) + "\n")
    assert main(["iso230-2", str(path)]) == 0
    out = capsys.readouterr().out.splitlines()
    start = next(i for i, line in enumerate(out) if "position mm" in line)
    table = out[start:]
    assert len(table) == 4
    for line in table:  # every cell two spaces from the next: 8 columns, whatever the width
        assert len(re.split(r"\s{2,}", line.strip())) == 8, line
    # right-aligned columns end together (the bar of x̄ takes no column on a terminal)
    right = {sum(not unicodedata.combining(c) for c in line) for line in table}
    assert len(right) == 1
    summary = out[1:8]
    assert all(len(re.split(r"\s{2,}", line.strip())) >= 2 for line in summary)


def test_iso230_2_refuses_devices_in_one_line(capsys):
    assert main(["iso230-2", "/dev/zero"]) == 1
    err = capsys.readouterr().err
    assert err == "volucal: error: /dev/zero: is a device, not a measurement file\n"


def test_a_closed_pipe_ends_quietly(tmp_path):
    """``volucal iso230-2 --json F | head -1``: no BrokenPipeError traceback."""
    files = [str(DATA / "x_axis_hand.rtl")] * 200  # far more than a pipe buffer holds
    command = [sys.executable, "-m", "volucal.core.cli", "iso230-2", "--json", *files]
    producer = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert producer.stdout is not None and producer.stderr is not None
    first = producer.stdout.readline()
    producer.stdout.close()  # what head -1 does after its line
    err = producer.stderr.read()
    assert producer.wait(timeout=120) == 141
    assert first == b"{\n" and err == b""


def test_import_reads_outside_the_plan_folder_only_when_allowed(tmp_path, capsys):
    folder = tmp_path / "plans"
    folder.mkdir()
    shutil.copy(DATA / "x_axis_hand.rtl", tmp_path / "x.rtl")
    plan = folder / "plan.toml"
    plan.write_text('[machine]\nstroke = { X = [0, 400], Y = [0, 400], Z = [0, 400] }\n\n'
                    '[[line]]\nfile = "../x.rtl"\nquantity = "linear"\nstart = [0, 0, 0]\n'
                    "direction = [1, 0, 0]\n")
    project = tmp_path / "p.h5"
    assert main(["import", str(project), str(plan)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "outside the plan's folder" in err and "line 5" in err
    assert not project.exists()
    assert main(["import", str(project), str(plan), "--files-root", str(tmp_path)]) == 0
    assert "1 line(s), 20 readings" in capsys.readouterr().out
