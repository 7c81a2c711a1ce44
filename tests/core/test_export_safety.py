"""Nothing unsafe reaches a machine (issues 16 and 17): absurd corrections are refused for every
format unless overridden, tables keep each controller's limits, names cannot escape the output
folder or inject lines, sizes asked for by arguments are checked before anything is allocated,
and a refused export leaves the folder as it was.

The projects are real HDF5 projects read by the command (``volucal export PROJECT.h5``).
"""

from __future__ import annotations

import math
import re
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from compensation_models import paper_like_model
from volucal.core.cli import main
from volucal.core.compensation import (
    FORMATS,
    LIMITS,
    ExportOptions,
    LargeCorrectionError,
    ModelSource,
    TableLimitError,
    build_tables,
    export_model,
)
from volucal.core.compensation.limits import MAX_GRID_POINTS, node_count
from volucal.core.errors import ErrorFunction, ErrorModel
from volucal.core.machine import Machine
from volucal.core.names import check_name, file_in_folder, printable_ascii, safe_file_name
from volucal.core.project import Project, error_model_to_tree
from volucal.core.userror import UserError

PROGRAM = "G0 X10 Y10 Z100\nG1 Z5 F300\nG1 X200 Y150\nM2\n"


def absurd_model() -> ErrorModel:
    """The issue's project: squareness EC0Y of 1e9 µrad."""
    model = paper_like_model(seed=1)
    return ErrorModel(model.machine, model.functions, {**model.squareness_urad, "EC0Y": 1e9})


def project_file(tmp_path: Path, model: ErrorModel, name: str = "p.h5") -> Path:
    project = Project.create(model.machine)
    project.put_result("identifications", "main", {"model": error_model_to_tree(model)})
    return project.save(tmp_path / name)


def export_args(project: Path, fmt: str, out: Path, program: Path, *extra: str) -> list[str]:
    args = ["export", str(project), "--format", fmt, "--out", str(out), *extra]
    return args + (["--program", str(program)] if fmt == "gcode" else [])


@pytest.fixture
def program(tmp_path: Path) -> Path:
    path = tmp_path / "part.ngc"
    path.write_text(PROGRAM)
    return path


# ---- plausibility -----------------------------------------------------------------------------


@pytest.mark.parametrize("fmt", sorted(FORMATS))
def test_absurd_project_is_refused_for_every_format(tmp_path, capsys, program, fmt) -> None:
    project = project_file(tmp_path, absurd_model())
    out = tmp_path / "out"
    assert main(export_args(project, fmt, out, program)) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    # which point, how much, why, and how to override
    assert re.search(r"correction of [+-][\d,]+\.\d µm at [XYZ]", err), err
    assert "plausibility limit of 200 µm" in err and "--max-correction-um" in err
    assert not list(out.iterdir())  # nothing written, not even the manifest


def test_override_writes_what_the_controller_can_take(tmp_path, capsys, program) -> None:
    project = project_file(tmp_path, absurd_model())
    out = tmp_path / "csv"
    assert main(export_args(project, "csv", out, program, "--allow-large-corrections")) == 0
    grid = np.loadtxt(out / "volumetric_grid.csv", delimiter=",", comments="#", skiprows=4)
    assert np.max(np.abs(grid[:, 6:])) > 5e5  # the 588,123 µm, written as asked
    # a limit large enough is the other way to override
    assert main(export_args(project, "json", tmp_path / "json", program,
                            "--max-correction-um", "1e7")) == 0
    assert main(export_args(project, "json", tmp_path / "j2", program,
                            "--max-correction-um", "-5")) == 1
    assert "--max-correction-um must be a positive number" in capsys.readouterr().err


def test_limit_is_exact_against_the_tables(tmp_path) -> None:
    """The largest correction of the LinuxCNC tables, computed independently from the tables,
    is refused 1 % below and accepted 1 % above."""
    model = paper_like_model(seed=3).scaled(20.0)
    tables = build_tables(ModelSource(model))
    largest = max(
        float(np.max(np.abs(np.concatenate([t.correction_forward_um, t.correction_backward_um]))))
        for t in tables.axis.values()
    )
    assert 50 < largest < 1000
    with pytest.raises(LargeCorrectionError) as caught:
        export_model(model, "linuxcnc", tmp_path / "a", ExportOptions(max_correction_um=largest
                                                                       * 0.99))
    error = caught.value
    assert error.limit_um == pytest.approx(largest * 0.99)
    assert abs(error.corrections[0].value_um) == pytest.approx(largest, rel=1e-6)
    assert error.count >= 1 and len(error.corrections) >= 1
    export_model(model, "linuxcnc", tmp_path / "b", ExportOptions(max_correction_um=largest * 1.01))


def test_a_value_that_is_not_a_number_is_refused_whatever_the_limit(tmp_path) -> None:
    model = paper_like_model(seed=2)
    functions = dict(model.functions)
    exx = functions["EXX"]
    coefficients = np.array(exx.coefficients, dtype=float)
    coefficients[3] = np.nan
    functions["EXX"] = ErrorFunction("EXX", exx.basis, coefficients)
    broken = ErrorModel(model.machine, functions, dict(model.squareness_urad))
    for fmt in ("linuxcnc", "siemens", "csv"):
        with pytest.raises(UserError, match="not a number"):
            export_model(broken, fmt, tmp_path / fmt, ExportOptions(max_correction_um=None))
        assert not list((tmp_path / fmt).iterdir())


def test_a_refused_export_leaves_the_previous_one_intact(tmp_path) -> None:
    out = tmp_path / "lcnc"
    export_model(paper_like_model(seed=1), "linuxcnc", out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(LargeCorrectionError):
        export_model(absurd_model(), "linuxcnc", out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


# ---- controller limits ------------------------------------------------------------------------


def test_every_controller_format_has_a_documented_limit_table() -> None:
    docs = (Path(__file__).resolve().parents[2] / "docs" / "compensation.md").read_text()
    # a new export format must state its limits (or that it has none) before it can export
    assert set(FORMATS) == set(LIMITS)
    for fmt, limits in LIMITS.items():
        assert f"`{fmt}`" in docs
        if limits.points is not None:
            assert f"{int(limits.points.value)}" in docs
    assert "not confirmed" in docs


def test_max_points_is_checked(tmp_path, capsys, program) -> None:
    project = project_file(tmp_path, paper_like_model())
    for value in ("-5", "0", "1"):
        assert main(export_args(project, "linuxcnc", tmp_path / "o", program, "--max-points",
                                value)) == 1
        err = capsys.readouterr().err
        assert "--max-points must be a whole number of at least 2" in err and value in err
    assert main(export_args(project, "fanuc", tmp_path / "f", program, "--max-points",
                            "5000", "--spacing", "0.5")) == 1
    assert "takes at most 1024 points" in capsys.readouterr().err


def test_fanuc_point_numbers_never_pass_1023(tmp_path) -> None:
    model = paper_like_model()
    with pytest.raises(UserError, match="at most 1024"):
        export_model(model, "fanuc", tmp_path / "a", ExportOptions(spacing_mm=0.5,
                                                                    max_points=2000))
    with pytest.raises(TableLimitError, match="compensation points"):
        export_model(model, "fanuc", tmp_path / "b", ExportOptions(spacing_mm=1.0))
    # the finest export that fits: every number within 0..1023
    export_model(model, "fanuc", tmp_path / "c", ExportOptions(spacing_mm=1.2))
    numbers = [int(line[1:6]) - 10000 for line in
               (tmp_path / "c" / "FANUC_PITCH.TXT").read_text().splitlines()
               if line.startswith("N1")]
    assert numbers and 0 <= min(numbers) and max(numbers) <= 1023


def test_positions_must_increase_as_written(tmp_path) -> None:
    # 0.00001 mm steps print as equal positions with LinuxCNC's six decimals... refused before
    # LinuxCNC would refuse them ("compensation values must increase")
    model = paper_like_model()
    with pytest.raises(TableLimitError, match="positions must increase"):
        export_model(model, "linuxcnc", tmp_path, ExportOptions(
            range_mm={"X": (0.0, 0.0000021), "Y": (0, 400), "Z": (0, 350)},
            spacing_mm={"X": 0.000001, "Y": 10.0, "Z": 10.0}, grid_spacing_mm=50.0))


# ---- names --------------------------------------------------------------------------------------


def test_axis_names_cannot_escape_the_output_folder(tmp_path, capsys, program) -> None:
    project = project_file(tmp_path, paper_like_model())
    out = tmp_path / "a" / "b" / "out"
    code = main(export_args(project, "heidenhain", out, program,
                            "--axis-names", "X=../../escaped"))
    assert code == 1
    err = capsys.readouterr().err
    assert "--axis-names X='../../escaped'" in err and "Traceback" not in err
    assert not list(tmp_path.rglob("escaped*"))


@pytest.mark.parametrize(("fmt", "names"), [
    ("siemens", "X=AX1\n$AA_ENC_COMP[0,0,AX2]=9.9"),
    ("siemens", "X=AX1 ;"),
    ("linuxcnc", "X=0\n[JOINT_9]"),
    ("linuxcnc", "X=١"),
    ("heidenhain", "X=Ä"),
    ("siemens", "X=Ä"),
    ("fanuc", "X=0"),
    ("isg", "X=1,Y=1"),
    ("heidenhain", "X=CON"),
])
def test_axis_names_outside_the_controller_naming_are_refused(tmp_path, capsys, program, fmt,
                                                              names) -> None:
    project = project_file(tmp_path, paper_like_model())
    out = tmp_path / "out"
    assert main(export_args(project, fmt, out, program, "--axis-names", names)) == 1
    err = capsys.readouterr().err
    assert err.startswith("volucal: error: --axis-names") and "Traceback" not in err
    assert err.count("\n") == 1
    assert not out.exists() or not list(out.iterdir())


def test_valid_axis_names_are_used(tmp_path) -> None:
    model = paper_like_model()
    result = export_model(model, "heidenhain", tmp_path, ExportOptions(
        axis_names={"X": "X1", "Y": "Y_2", "Z": "Z"}))
    assert {"X1.COM", "Y_2.COM", "Z.COM"} <= {p.name for p in result.files}
    siemens = export_model(model, "siemens", tmp_path / "s", ExportOptions(
        axis_names={"X": "MX1", "Y": "MY1", "Z": "MZ1"}))
    text = (tmp_path / "s" / "AX_EEC.INI").read_text()
    assert "$AA_ENC_COMP_STEP[0,MX1]" in text and siemens.files


def test_a_machine_name_cannot_inject_lines_or_break_the_encoding(tmp_path) -> None:
    base = paper_like_model()
    machine = Machine(name="Fräse\nM17\n%_N_EVIL", chain=base.machine.chain,
                      stroke_mm={a: base.machine.stroke(a) for a in "XYZ"},
                      tool_offset_mm=base.machine.tool_offset_mm)
    model = ErrorModel(machine, base.functions, dict(base.squareness_urad))
    for fmt in ("siemens", "linuxcnc", "csv", "isg", "fanuc"):
        result = export_model(model, fmt, tmp_path / fmt)
        for path in result.files:
            lines = path.read_text(encoding="ascii").splitlines()
            assert not any(line.startswith("%_N_EVIL") for line in lines), path
    lines = (tmp_path / "siemens" / "AX_EEC.INI").read_text().splitlines()
    assert lines[1] == r"; volucal compensation for Fr\xe4se\nM17\n%_N_EVIL"
    assert lines.count("M17") == 1 and lines[-1] == "M17"


def test_name_checks() -> None:
    assert check_name("x_y0_z0", "line name") == "x_y0_z0"
    assert safe_file_name("X.COM", "name") == "X.COM"
    for bad in ("", "a\0b", "a\nb", "a\x7fb", "a\u2028b"):
        with pytest.raises(UserError):
            check_name(bad, "name")
    for bad in ("../x", "a/b", "a\\b", "..", ".", "x:y", "nul", "COM1.txt", "x.", " x",
                "x" * 256):
        with pytest.raises(UserError):
            safe_file_name(bad, "name")
    assert file_in_folder("/tmp/out", "a.txt") == Path("/tmp/out/a.txt")
    assert printable_ascii("Ä\n") == r"\xc4\n"


# ---- sizes from arguments ------------------------------------------------------------------


def test_grid_spacing_that_asks_for_gigabytes_is_refused_at_once(tmp_path, capsys,
                                                                 program) -> None:
    project = project_file(tmp_path, paper_like_model())
    args = export_args(project, "csv", tmp_path / "o", program, "--grid-spacing", "0.2")
    tracemalloc.start()
    code = main(args)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1
    assert "--grid-spacing 0.2 mm gives a grid of 2001 x 2001 x 1751" in err
    assert "use a spacing of at least" in err
    assert peak < 50e6  # the 52 GiB the issue saw are never asked for
    start = time.perf_counter()
    assert main(args) == 1
    assert time.perf_counter() - start < 1.0
    capsys.readouterr()
    # the spacing it proposes is the finest that fits, to 0.1 mm
    proposed = float(re.search(r"at least ([\d.]+) mm", err).group(1))
    spans = [400.0, 400.0, 350.0]
    assert math.prod(node_count(0, s, proposed, "") for s in spans) <= MAX_GRID_POINTS
    assert math.prod(node_count(0, s, proposed - 0.1, "") for s in spans) > MAX_GRID_POINTS


def test_table_spacing_that_asks_for_millions_of_nodes_is_refused(tmp_path, capsys,
                                                                  program) -> None:
    project = project_file(tmp_path, paper_like_model())
    for fmt, spacing in (("csv", "1e-6"), ("fanuc", "1e-6"), ("linuxcnc", "nan")):
        assert main(export_args(project, fmt, tmp_path / "o", program, "--spacing",
                                spacing)) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err
        assert "spacing" in err
