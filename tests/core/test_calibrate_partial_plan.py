"""A plan that moves one axis alone (an ISO 230-2 run of X, say) is a whole job: `volucal calibrate`
identifies what it sees, closes the loop, exports the tables and says what it cannot compensate,
instead of refusing at the end and losing the run."""

import json
import math
import shutil

import numpy as np
import pytest
from volucal.core.cli import main
from volucal.core.compensation.verify import RATE_FLOOR_UM, compensation_rates
from volucal.core.resources import demo_plan


def _x_alone(tmp_path, start=(0.0, 0.0, 0.0)):  # type: ignore[no-untyped-def]
    """The demo's plan cut to its first line, x_linear, with its log, starting at ``start``."""
    source = demo_plan()
    head, first, *_ = source.read_text().split("[[line]]")
    assert 'name = "x_linear"' in first and "start = [0.0, 0.0, 0.0]" in first
    first = first.replace("start = [0.0, 0.0, 0.0]", f"start = {list(start)}")
    folder = tmp_path / "session"
    (folder / "logs").mkdir(parents=True)
    shutil.copy(source.parent / "logs" / "x_linear.rtl", folder / "logs")
    plan = folder / "plan.toml"
    plan.write_text(head + "[[line]]" + first)
    return plan


def _comp_columns(path):  # type: ignore[no-untyped-def]
    """A LinuxCNC type 1 COMP_FILE as (nominal, forward, backward) columns, mm."""
    return np.loadtxt(path, ndmin=2).T


def _csv_rows(path):  # type: ignore[no-untyped-def]
    """A generic CSV export's numeric columns (comment lines left out; an axis column kept as
    text) by name."""
    lines = [line for line in path.read_text().splitlines() if not line.startswith("#")]
    names = lines[0].split(",")
    rows = [line.split(",") for line in lines[1:] if line]
    columns = {}
    for k, name in enumerate(names):
        cells = [row[k] for row in rows]
        columns[name] = np.array(cells) if name.endswith("axis") else np.array(cells, float)
    return columns


@pytest.mark.parametrize("start", [(0.0, 0.0, 0.0), (0.0, 100.0, 50.0)])
def test_a_plan_that_moves_x_alone_is_calibrated_exported_and_says_what_it_cannot_compensate(
    tmp_path, capsys, start
) -> None:
    plan = _x_alone(tmp_path, start)
    project, report, out = tmp_path / "p.h5", tmp_path / "r.json", tmp_path / "out"
    args = ["calibrate", str(plan), "--project", str(project), "--report", str(report)]
    args += ["--export", str(out), "--format", "linuxcnc", "--format", "csv"]
    code = main([*args, "--no-sensitivity"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    written = json.loads(report.read_text())
    # X is measured: its tables correct it; Y and Z have nothing to compensate, and say so
    for method in ("volumetric", "axis_tables"):
        rates = written["compensation"]["rate_percent"][method]
        assert math.isfinite(rates["X"]) and rates["X"] > 90.0
        assert rates["Y"] is None and rates["Z"] is None
    # what the model says away from the line, along Y or Z, no measurement backs: the errors
    # are held at the line's place (no cross table, a grid constant along Y and Z)
    cross = _csv_rows(out / "csv" / "cross_axis_tables.csv")
    assert np.max(np.abs(cross["error_um"])) < 1e-3
    grid = _csv_rows(out / "csv" / "volumetric_grid.csv")
    for x in np.unique(grid["x_mm"]):
        assert np.ptp(grid["error_x_um"][grid["x_mm"] == x]) < 1e-6
    warning = (
        f"no measured line moved Y or Z (every reading at Y = {start[1]:g} mm, Z = {start[2]:g} mm)"
    )
    assert any(w.startswith(warning) for w in written["warnings"])
    assert f"warning: {warning}" in captured.out
    assert "—: no error along that direction to compensate" in captured.out
    # the tables of the axes no line moved hold what was measured at their one position: zero
    for joint in ("joint1_Y.comp", "joint2_Z.comp"):
        nominal, forward, backward = _comp_columns(out / "linuxcnc" / joint)
        assert nominal[0] == 0.0 and nominal[-1] > 300.0
        assert np.array_equal(forward, nominal) and np.array_equal(backward, nominal)
    nominal, forward, _ = _comp_columns(out / "linuxcnc" / "joint0_X.comp")
    assert np.max(np.abs(forward - nominal)) > 1e-3  # more than a micrometre somewhere
    flags = json.loads((out / "linuxcnc" / "volucal_export.json").read_text())["flags"]
    for axis in "YZ":
        assert any(f.startswith(f"{axis} table: no measured line moved {axis}") for f in flags)
    assert not any(f.startswith("X table") for f in flags)
    # the project exports later too
    later = ["export", str(project), "--format", "siemens", "--out", str(tmp_path / "siemens")]
    assert main(later) == 0, capsys.readouterr().err


def test_a_direction_without_error_has_no_rate() -> None:
    before = np.array([[1.0, 1e-14, 2.0 * RATE_FLOOR_UM], [-1.0, -1e-14, -2.0 * RATE_FLOOR_UM]])
    rates = compensation_rates(before, 0.5 * before)
    assert rates.rms_percent["X"] == 50.0 and rates.rms_percent["Z"] == 50.0
    assert math.isnan(rates.rms_percent["Y"]) and math.isnan(rates.range_percent["Y"])


def test_a_program_rewritten_along_an_axis_no_line_moved_is_flagged_once_per_axis(
    tmp_path, capsys
) -> None:
    plan = _x_alone(tmp_path)
    project = tmp_path / "p.h5"
    assert main(["calibrate", str(plan), "--project", str(project), "--no-sensitivity"]) == 0
    program = tmp_path / "part.ngc"
    program.write_text("G21 G90\nG0 X0 Y0 Z0\nG1 X100 Y50 F1000\nG1 Y200\nG1 X50 Z-10\nM2\n")
    out = tmp_path / "gcode"
    args = ["export", str(project), "--format", "gcode", "--program", str(program)]
    assert main([*args, "--out", str(out)]) == 0, capsys.readouterr().err
    manifest = json.loads((out / "volucal_export.json").read_text())
    said = manifest["notes"] + manifest["flags"]
    # lines 3 to 5 lie off Y = 0, line 5 off Z = 0: one flag per axis, not one per line
    assert [f for f in said if f.startswith("Y:")] == [
        "Y: no measured line moved Y (every reading at Y = 0 mm); 3 program line(s) lie "
        "elsewhere along it, where nothing was measured"
    ]
    assert len([f for f in said if f.startswith("Z:")]) == 1
    assert not any("goes beyond the measured range [0, 0] mm" in f for f in said)


def test_a_ranking_of_errors_the_plan_does_not_identify_says_so(tmp_path, capsys) -> None:
    from volucal.core.report_content import ReportRequest, Table, build_report

    plan = _x_alone(tmp_path)
    project = tmp_path / "p.h5"
    report = tmp_path / "report.json"
    args = ["calibrate", str(plan), "--project", str(project), "--report", str(report)]
    assert main([*args, "--quiet"]) == 0
    capsys.readouterr()
    # report.json: every output's ranking lists the errors the plan does not identify
    written = json.loads(report.read_text())
    unseen = written["identifiability"]["unidentifiable_ids"]
    assert {"EBX", "EXX", "EYY", "EA0Z"} <= set(unseen)
    assert set(written["sensitivity"]) == {"Ex", "Ey", "Ez", "ET"}
    assert all(
        sorted(block["not_identified"]) == unseen for block in written["sensitivity"].values()
    )
    # x_linear alone identifies no error by itself (EXX only with EBX): every one is marked
    args = ["sensitivity", str(project), "--output", "Ex", "--n", "300", "--repeats", "1"]
    assert main([*args, "--map", "200"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("    E")]
    assert len(rows) == 6 and all(row.endswith("  *") for row in rows)
    assert "* not fully identified by this plan: what it varies by was not all measured" in out
    assert main([*args, "--map", "200", "--json"]) == 0
    document = json.loads(capsys.readouterr().out)
    assert sorted(document["not_identified"]) == unseen
    assert sorted(document["sensitivity"]["Ex"]["not_identified"]) == unseen
    section = next(
        s
        for s in build_report(ReportRequest(project)).sections
        if s.title.startswith("Sensitivity")
    )
    ranked = [row[1] for block in section.blocks if isinstance(block, Table) for row in block.rows]
    assert ranked and all(label.endswith(" (not identified)") for label in ranked)
    assert any(
        'marked "not identified" are not seen by this plan, or only in part or in a combination'
        in getattr(b, "text", "")
        for b in section.blocks
    )


def test_x_lines_at_two_heights_of_y_put_nothing_unmeasured_in_the_y_tables(
    tmp_path, capsys
) -> None:
    """x_linear at Y = 0 and the same log again at Y = 200: the two heights measured the same,
    so nothing may depend on Y. The plan cannot see Y's own errors; the identification holds
    them at zero and the lines' offsets take the rest (half the X reversal, 2 µm, which the
    offsets used to share with EXY, EBY and EC0Y and which then came out as a 1.7 µm Y → X
    cross table). And calibrate says what the plan left unmeasured along Y."""
    plan = _x_alone(tmp_path)
    text = plan.read_text()
    first = text[text.index("[[line]]") :]
    far = first.replace('name = "x_linear"', 'name = "x_linear_far"')
    plan.write_text(
        text + "\n" + far.replace("start = [0.0, 0.0, 0.0]", "start = [0.0, 200.0, 0.0]")
    )
    report, out = tmp_path / "r.json", tmp_path / "out"
    args = ["calibrate", str(plan), "--report", str(report), "--export", str(out)]
    assert main([*args, "--format", "csv", "--no-sensitivity"]) == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    cross = _csv_rows(out / "csv" / "cross_axis_tables.csv")
    along_y = np.asarray(cross["input_axis"]) == "Y"
    assert along_y.sum() > 20
    assert np.max(np.abs(cross["error_um"][along_y])) < 1e-3
    written = json.loads(report.read_text())
    held = (
        "no measured line moved Y (its lines held it at Y = 0, 200 mm): no error of its own "
        "travel is identified; along Y the model and its tables hold only what the lines "
        "measured at those positions, and nothing was measured between them"
    )
    assert held in written["warnings"] and f"warning: {held}" in printed
    assert any(
        w.startswith("no measured line moved Z (every reading at Z = 0 mm)")
        for w in written["warnings"]
    )
