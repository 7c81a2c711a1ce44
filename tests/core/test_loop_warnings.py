"""A plan the loop cannot fully use is said so, in report.json and on the console, never skipped
in silence and never as an exception (issue 12, "Bad input")."""

import json

from volucal.core import plans
from volucal.core import simulate as sim
from volucal.core.cli import main
from volucal.core.machine import Machine


def _calibrate(measurement, tmp_path, capsys) -> tuple[int, dict, str]:  # type: ignore[no-untyped-def]
    """Run `volucal calibrate` on a simulated session; (exit code, report.json, console)."""
    plan = sim.write_session(measurement, tmp_path / "session")
    report_path = tmp_path / "report.json"
    code = main(["calibrate", str(plan), "--report", str(report_path), "--quiet"])
    out, err = capsys.readouterr()
    report = json.loads(report_path.read_text()) if report_path.exists() else {}
    return code, report, out + err


def test_lines_too_short_to_cross_validate_are_a_warning(tmp_path, capsys) -> None:
    # a small stage: every line, diagonals included, is shorter than three held-out blocks of
    # 15 mm, and not every line is redundant
    machine = Machine(
        name="micro stage",
        chain="WXYFZT",
        stroke_mm={"X": (0.0, 20.0), "Y": (0.0, 20.0), "Z": (0.0, 20.0)},
        tool_offset_mm=(0.0, 0.0, 20.0),
    )
    truth = sim.random_truth(machine, seed=3, spacing_mm=10.0)
    vm = sim.VirtualMachine(truth, (sim.Reversal("X", 2.0),), seed=3)
    measurement = vm.measure(plans.layout("direct", machine, 2.0, 0.3))
    code, report, console = _calibrate(measurement, tmp_path, capsys)
    assert code == 0, console
    message = "the loop cannot cross-validate this plan"
    assert any(message in w for w in report["warnings"]), report["warnings"]
    assert f"warning: {message}" in console
    assert report["effects"] == []
    # what the loop could not look at is still reported as unexplained where it is significant
    assert report["unexplained"], "a 2 µm reversal left in the residual must be reported"


def test_targets_in_step_with_the_screw_lead_are_a_warning(tmp_path, capsys) -> None:
    truth = sim.random_truth(seed=14)
    vm = sim.VirtualMachine(truth, (), seed=14)
    measurement = vm.measure(plans.layout("direct", truth.machine, 16.0, 0.0))
    code, report, console = _calibrate(measurement, tmp_path, capsys)
    assert code == 0, console
    message = "cannot reveal a cyclic error at the 16 mm screw lead"
    assert any(message in w for w in report["warnings"]), report["warnings"]
    assert "warning: the targets" in console and message in console
