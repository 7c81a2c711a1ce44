"""A plan that moves one axis alone (an ISO 230-2 run of X, say) is a whole job: `volucal calibrate`
identifies what it sees, closes the loop, exports the tables and says what it cannot compensate,
instead of refusing at the end and losing the run."""

import json
import math
import shutil

import numpy as np
from volucal.core.cli import main
from volucal.core.compensation.verify import RATE_FLOOR_UM, compensation_rates
from volucal.core.resources import demo_plan


def _x_alone(tmp_path):  # type: ignore[no-untyped-def]
    """The demo's plan cut to its first line, x_linear, with its log."""
    source = demo_plan()
    head, first, *_ = source.read_text().split("[[line]]")
    assert 'name = "x_linear"' in first
    folder = tmp_path / "session"
    (folder / "logs").mkdir(parents=True)
    shutil.copy(source.parent / "logs" / "x_linear.rtl", folder / "logs")
    plan = folder / "plan.toml"
    plan.write_text(head + "[[line]]" + first)
    return plan


def _comp_columns(path):  # type: ignore[no-untyped-def]
    """A LinuxCNC type 1 COMP_FILE as (nominal, forward, backward) columns, mm."""
    return np.loadtxt(path, ndmin=2).T


def test_a_plan_that_moves_x_alone_is_calibrated_exported_and_says_what_it_cannot_compensate(
    tmp_path, capsys
) -> None:
    plan = _x_alone(tmp_path)
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
        assert math.isfinite(rates["X"]) and rates["X"] > 50.0
        assert rates["Y"] is None and rates["Z"] is None
    warning = "no measured line moved Y or Z (every reading at Y = 0 mm, Z = 0 mm)"
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
