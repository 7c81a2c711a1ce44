"""`volucal export PROJECT` writes the files `volucal calibrate --export` wrote: the loop's kept
machine effects (the demo's reversal of X and screw cycle of Y) are in the project and in the
tables, not only in the run that found them."""

import json

import numpy as np
import pytest
from volucal.core.cli import main
from volucal.core.project import Project
from volucal.core.resources import demo_plan

FORMATS = ("linuxcnc", "siemens", "fanuc", "heidenhain", "isg", "csv", "json")


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):  # type: ignore[no-untyped-def]
    """The demo plan through `volucal calibrate`, exported in every table format."""
    folder = tmp_path_factory.mktemp("demo")
    project = folder / "demo.h5"
    args = ["calibrate", str(demo_plan()), "--project", str(project), "--no-sensitivity"]
    args += ["--export", str(folder / "calibrate"), "--quiet"]
    for fmt in FORMATS:
        args += ["--format", fmt]
    assert main(args) == 0
    return folder, project


def test_an_export_of_the_project_is_the_export_of_the_run(calibrated, capsys) -> None:
    folder, project = calibrated
    for fmt in FORMATS:
        out = folder / "export" / fmt
        assert main(["export", str(project), "--format", fmt, "--out", str(out)]) == 0
        written = sorted(p.name for p in (folder / "calibrate" / fmt).iterdir())
        assert sorted(p.name for p in out.iterdir()) == written
        for name in written:
            expected = (folder / "calibrate" / fmt / name).read_bytes()
            assert (out / name).read_bytes() == expected, f"{fmt}/{name}"
    capsys.readouterr()
    # the reversal of X the loop kept (4 µm) is in the tables: forward and backward differ
    nominal, forward, backward = np.loadtxt(folder / "export" / "linuxcnc" / "joint0_X.comp").T
    assert np.allclose(forward - backward, 4.0e-3, atol=0.05e-3)
    assert np.max(np.abs(forward - nominal)) > 5e-3


def test_a_project_without_the_effects_values_is_refused_with_what_to_do(
    calibrated, tmp_path, capsys
) -> None:
    _, source = calibrated
    project = Project.open(source)
    tree = dict(project.result("identifications", "loop"))
    entries = json.loads(tree["effects_json"])
    labels = [e["label"] for e in entries]
    assert labels == ["reversal X", "cyclic Y 16 mm with harmonics 1, 2"]
    for entry in entries:
        del entry["values"]
    tree["effects_json"] = json.dumps(entries)
    project.put_result("identifications", "loop", tree)
    old = tmp_path / "old.h5"
    project.save(old)
    out = tmp_path / "out"
    assert main(["export", str(old), "--format", "linuxcnc", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"volucal: error: {old}: ")
    assert all(label in err for label in labels)
    assert "volucal calibrate" in err and "--identification main" in err
    assert not out.exists()
    # the fit before the loop still exports: the 21 errors alone
    assert (
        main(
            [
                "export",
                str(old),
                "--format",
                "linuxcnc",
                "--out",
                str(out),
                "--identification",
                "main",
            ]
        )
        == 0
    )
