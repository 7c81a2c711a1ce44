"""The ``volucal export`` command: options, JSON output, one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from compensation_models import paper_like_model
from volucal.core import cli
from volucal.core.commands import export_cmd
from volucal.core.compensation import ModelSource

SEEN: dict[str, object] = {}


@pytest.fixture
def project(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """A stand-in for a project: the command's project reader returns a known model."""
    path = tmp_path / "machine.h5"
    path.write_bytes(b"")
    model = paper_like_model()
    SEEN.clear()

    def load(p: Path, identification: str | None = None) -> ModelSource:
        SEEN.update(path=p, identification=identification)
        return ModelSource(model)

    monkeypatch.setattr(export_cmd, "load_source", load)
    return path


def test_export_json_lists_files_rates_and_tool_offset(project: Path, tmp_path, capsys) -> None:
    out = tmp_path / "lcnc"
    code = cli.main(
        [
            "export",
            str(project),
            "--format",
            "linuxcnc",
            "--out",
            str(out),
            "--json",
            "--spacing",
            "20",
            "--tool-offset",
            "0",
            "0",
            "150",
            "--axis-names",
            "X=3,Y=4,Z=5",
            "--identification",
            "run2",
        ]
    )
    assert code == 0
    document = json.loads(capsys.readouterr().out)
    assert document["tool_offset_mm"] == [0.0, 0.0, 150.0]
    names = {Path(p).name for p in document["files"]}
    assert {"joint3_X.comp", "joint4_Y.comp", "joint5_Z.comp", "comp.ini"} <= names
    assert "[JOINT_3]" in (out / "comp.ini").read_text()
    assert len((out / "joint3_X.comp").read_text().splitlines()) == 21
    assert set(document["predicted"]["methods"]["export"]["rates"]["rms_percent"]) == set("XYZ")
    assert SEEN == {"path": project, "identification": "run2"}


def test_export_text_output(project: Path, tmp_path, capsys) -> None:
    code = cli.main(["export", str(project), "--format", "siemens", "--out", str(tmp_path / "s")])
    assert code == 0
    text = capsys.readouterr().out
    assert "AX_EEC.INI" in text and "tool offset assumed: 0 0 200 mm" in text
    assert "predicted compensation rates" in text
    # the model's inverse against the model is 100 % by construction: no predicted rate
    (row,) = [line for line in text.splitlines() if line.strip().startswith("nc_rewriting")]
    assert "not predicted" in row and "100.0" not in row


def test_export_gcode_with_work_offsets(project: Path, tmp_path, capsys) -> None:
    program = tmp_path / "part.ngc"
    program.write_text("G55\nG0 X10 Y10 Z20\nG1 X50 F100\nM2\n")
    code = cli.main(
        [
            "export",
            str(project),
            "--format",
            "gcode",
            "--out",
            str(tmp_path / "g"),
            "--program",
            str(program),
            "--work-offset",
            "G55=100,50,0",
            "--json",
        ]
    )
    assert code == 0
    document = json.loads(capsys.readouterr().out)
    assert document["details"]["rewrite"]["moves_in"] == 2
    assert (tmp_path / "g" / "part_volucal.ngc").exists()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--axis-names", "X"], "--axis-names"),
        (["--work-offset", "G60=1,2,3"], "--work-offset"),
        (["--work-offset", "G54=1,a,3"], "not a number"),
        (["--spacing", "1"], "at most 256"),
        (["--spacing", "-5"], "positive"),
    ],
)
def test_user_errors_are_one_line_on_stderr(
    project: Path, tmp_path, capsys, extra, message
) -> None:
    code = cli.main(
        ["export", str(project), "--format", "linuxcnc", "--out", str(tmp_path / "x"), *extra]
    )
    assert code == 1
    err = capsys.readouterr().err
    assert err.startswith("volucal: error:") and message in err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_missing_project_is_a_clear_error(tmp_path, capsys) -> None:
    code = cli.main(
        ["export", str(tmp_path / "nope.h5"), "--format", "csv", "--out", str(tmp_path / "o")]
    )
    assert code == 1
    err = capsys.readouterr().err
    assert "nope.h5" in err and "Traceback" not in err


def test_export_reads_the_identified_model_from_a_project(tmp_path, capsys) -> None:
    from volucal.core.project import Project, error_model_to_tree

    model = paper_like_model(seed=7)
    project = Project.create(model.machine)
    project.put_result("identifications", "main", {"model": error_model_to_tree(model)})
    path = project.save(tmp_path / "machine.h5")
    out = tmp_path / "csv"
    code = cli.main(["export", str(path), "--format", "csv", "--out", str(out), "--json"])
    assert code == 0
    json.loads(capsys.readouterr().out)
    rows = [
        r.split(",") for r in (out / "axis_tables.csv").read_text().splitlines() if r[:2] == "X,"
    ]
    expected = ModelSource(model).error_um([[float(r[1]), 0.0, 0.0] for r in rows])[:, 0]
    assert [float(r[2]) for r in rows] == pytest.approx(expected.tolist(), abs=1e-5)
    code = cli.main(
        ["export", str(path), "--format", "csv", "--out", str(out), "--identification", "x"]
    )
    assert code == 1 and "no identification named 'x'" in capsys.readouterr().err
