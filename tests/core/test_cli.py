"""The command line as a user meets it: help, the demo, calibrate, identify, clear errors."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
from volucal.core import plans
from volucal.core.calibrate import main_report_keys
from volucal.core.cli import main
from volucal.core.simulate import Reversal, VirtualMachine, random_truth, write_session


def volucal(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "volucal.core.cli", *args],
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_help_lists_the_commands() -> None:
    out = volucal("--help")
    assert out.returncode == 0
    for command in ("calibrate", "demo", "identify"):
        assert command in out.stdout


@pytest.fixture(scope="module")
def small_plan(tmp_path_factory) -> Path:  # type: ignore[no-untyped-def]
    folder = tmp_path_factory.mktemp("plan")
    truth = random_truth(seed=31)
    vm = VirtualMachine(truth, (Reversal("Y", 3.0),), seed=31)
    return write_session(vm.measure(plans.direct(truth.machine, 20.0, 3.0)), folder)


def test_calibrate_writes_project_report_and_tables(small_plan: Path, tmp_path: Path) -> None:
    out = volucal(
        "calibrate",
        str(small_plan),
        "--project",
        str(tmp_path / "p.h5"),
        "--report",
        str(tmp_path / "r.json"),
        "--export",
        str(tmp_path / "comp"),
        "--quiet",
    )
    assert out.returncode == 0, out.stderr
    report = json.loads((tmp_path / "r.json").read_text())
    for key in main_report_keys():
        assert key in report, key
    assert [e["kind"] for e in report["effects"]] == ["reversal"]
    assert report["effects"][0]["axis"] == "Y"
    assert (tmp_path / "p.h5").is_file()
    assert list((tmp_path / "comp" / "linuxcnc").iterdir())
    assert "closed loop" in out.stdout


def test_identify_reads_the_project(small_plan: Path, tmp_path: Path) -> None:
    project = tmp_path / "p.h5"
    assert (
        volucal(
            "calibrate", str(small_plan), "--project", str(project), "--quiet", "--no-sensitivity"
        ).returncode
        == 0
    )
    out = volucal("identify", str(project), "--json")
    assert out.returncode == 0, out.stderr
    content = json.loads(out.stdout)
    assert content["identifiability"]["rank"] <= content["identifiability"]["unknowns"]
    assert set(content["parameters"]) >= {"EXX", "EC0Y", "EB0Z", "EA0Z"}


def test_missing_plan_is_one_clear_line_and_no_traceback(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    code = main(["calibrate", str(tmp_path / "nope.toml")])
    err = capsys.readouterr().err
    assert code != 0
    assert "nope.toml" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_bad_plan_value_names_the_line_entry_and_field(
    tmp_path: Path, capsys, small_plan: Path
) -> None:  # type: ignore[no-untyped-def]
    text = small_plan.read_text().replace(
        "direction = [1.0, 0.0, 0.0]", "direction = [0.0, 0.0, 0.0]", 1
    )
    bad = small_plan.parent / "bad.toml"
    bad.write_text(text)
    code = main(["calibrate", str(bad), "--quiet"])
    err = capsys.readouterr().err
    assert code != 0 and "Traceback" not in err
    assert "bad.toml" in err and "direction" in err
