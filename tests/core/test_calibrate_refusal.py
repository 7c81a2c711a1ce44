"""`volucal calibrate --export` on a machine whose corrections exceed the plausibility limit: the
export is refused with one line, and the identification and the loop are still saved."""

import json
from dataclasses import replace

from volucal.core import plans
from volucal.core import simulate as sim
from volucal.core.cli import main
from volucal.core.project import Project


def _session(tmp_path):  # type: ignore[no-untyped-def]
    truth = sim.random_truth(seed=5)
    # 2 mrad out of square: 0.8 mm over the Y stroke, far beyond the 200 µm limit
    truth = replace(truth, squareness_urad={**truth.squareness_urad, "EC0Y": 2000.0})
    vm = sim.VirtualMachine(truth, (), seed=5)
    measurement = vm.measure(plans.layout("direct", truth.machine, 25.0, 3.0))
    return sim.write_session(measurement, tmp_path / "session")


def test_a_refused_export_keeps_the_project_and_the_report(tmp_path, capsys) -> None:
    plan = _session(tmp_path)
    project, report = tmp_path / "p.h5", tmp_path / "r.json"
    args = ["calibrate", str(plan), "--project", str(project), "--report", str(report)]
    code = main([*args, "--export", str(tmp_path / "out"), "--no-sensitivity", "--quiet"])
    err = capsys.readouterr().err
    assert code == 1
    assert err.count("\n") == 1 and "volucal: error:" in err and "max-correction-um" in err
    assert str(project) in err and str(report) in err
    written = json.loads(report.read_text())
    assert any(w.startswith("export refused:") for w in written["warnings"])
    # the per-axis LinuxCNC tables hold no squareness and pass; the volumetric grid is refused
    listed = set(written["compensation"]["files"])
    assert listed == {p.name for p in (tmp_path / "out" / "linuxcnc").iterdir()}
    assert not (tmp_path / "out" / "csv").exists() or not any((tmp_path / "out" / "csv").iterdir())
    assert "EC0Y" in written["parameters"] and written["loop"] is not None
    assert Project.open(project).measurement().lines


def test_the_limit_can_be_lifted_explicitly(tmp_path, capsys) -> None:
    plan = _session(tmp_path)
    out = tmp_path / "out"
    args = ["calibrate", str(plan), "--export", str(out), "--no-sensitivity", "--quiet"]
    assert main([*args, "--allow-large-corrections"]) == 0, capsys.readouterr().err
    assert (out / "linuxcnc" / "comp.ini").is_file()


def test_plan_files_outside_its_folder_need_files_root(tmp_path, capsys) -> None:
    session = _session(tmp_path).parent
    elsewhere = tmp_path / "plans" / "plan.toml"
    elsewhere.parent.mkdir()
    text = (session / "plan.toml").read_text().replace('file = "logs/', 'file = "../session/logs/')
    elsewhere.write_text(text)
    args = ["calibrate", str(elsewhere), "--no-sensitivity", "--quiet"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--files-root" in err
    assert main([*args, "--files-root", str(tmp_path), "--allow-large-corrections"]) == 0
