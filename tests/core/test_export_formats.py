"""Controller exports: limits with their suggestions, semantics as loaded, manifest, report."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from compensation_models import paper_like_model
from volucal.core.compensation import (
    FORMATS,
    ExportOptions,
    ModelSource,
    ReversalSource,
    TableLimitError,
    compensation_report,
    export_model,
)
from volucal.core.userror import UserError


@pytest.fixture(scope="module")
def source() -> ReversalSource:
    return ReversalSource(ModelSource(paper_like_model(seed=1)), {"X": 3.0})


def test_every_format_writes_its_files_and_a_manifest(source, tmp_path: Path) -> None:
    program = tmp_path / "part.ngc"
    program.write_text("G0 X10 Y10 Z100\nG1 Z5 F300\nG1 X200 Y150\nM2\n")
    for fmt in FORMATS:
        result = export_model(source, fmt, tmp_path / fmt, ExportOptions(program=program))
        assert all(p.exists() for p in result.files), fmt
        manifest = json.loads((tmp_path / fmt / "volucal_export.json").read_text())
        assert manifest["format"] == fmt
        assert manifest["tool_offset_mm"] == [0.0, 0.0, 200.0]
        assert manifest["units_and_signs"]
        assert "export" in manifest["predicted"]["methods"]
        for path in result.files:
            path.read_text(encoding="ascii")  # controllers read plain ASCII


def test_linuxcnc_point_limit_names_the_spacing_that_fits(source, tmp_path: Path) -> None:
    with pytest.raises(TableLimitError, match=r"at most 256.*at least 1\.569 mm \(--spacing\)"):
        export_model(source, "linuxcnc", tmp_path, ExportOptions(spacing_mm=1.0))
    # 256 is compiled into LinuxCNC's motion module: --max-points cannot raise it ...
    with pytest.raises(UserError, match=r"--max-points 401: .* at most 256 .*can only lower"):
        export_model(source, "linuxcnc", tmp_path, ExportOptions(spacing_mm=1.0, max_points=401))
    # ... but can lower it, for a table the control keeps smaller.
    with pytest.raises(TableLimitError, match=r"at most 30; .*at least 13\.794 mm"):
        export_model(source, "linuxcnc", tmp_path, ExportOptions(max_points=30))


def test_configurable_limits_can_be_raised(source, tmp_path: Path) -> None:
    with pytest.raises(TableLimitError, match=r"at most 5000.*or raise the controller's limit"):
        export_model(source, "siemens", tmp_path, ExportOptions(spacing_mm=0.07))
    export_model(source, "siemens", tmp_path, ExportOptions(spacing_mm=0.07, max_points=6000))


def test_fanuc_point_numbers_limit(source, tmp_path: Path) -> None:
    with pytest.raises(TableLimitError, match="compensation points"):
        export_model(source, "fanuc", tmp_path, ExportOptions(spacing_mm=1.0))


def test_fanuc_increment_range_sets_the_magnification(tmp_path: Path) -> None:
    big = ModelSource(paper_like_model().scaled(60.0))  # hundreds of µm per interval
    large = {"max_correction_um": None}  # beyond the plausibility limit, on purpose
    result = export_model(big, "fanuc", tmp_path, ExportOptions(spacing_mm=50.0, **large))
    magnification = result.details["parameters"]["3623"]
    assert max(magnification.values()) > 1
    values = [
        int(line.split("P")[1])
        for line in (tmp_path / "FANUC_PITCH.TXT").read_text().splitlines()
        if line.startswith("N1")
    ]
    assert max(abs(v) for v in values) <= 127
    # Beyond 127 × 100 detection units per interval no magnification fits.
    with pytest.raises(TableLimitError, match="smaller"):
        export_model(
            big, "fanuc", tmp_path,
            ExportOptions(spacing_mm=50.0, fanuc_detection_unit_um=0.01, **large),
        )


def test_semantics_as_loaded_match_the_generic_prediction(source, tmp_path: Path) -> None:
    """LinuxCNC applies exactly the generic per-axis rule (linear, held, by direction); the Fanuc
    staircase leaves more, and the Siemens EEC+CEC set reaches the axis-plus-cross result."""

    def rates(fmt: str) -> dict[str, dict[str, float]]:
        result = export_model(source, fmt, tmp_path / fmt)
        return {k: v.rates.rms_percent for k, v in result.verification.methods.items()}

    linuxcnc = rates("linuxcnc")
    for axis in "XYZ":
        assert linuxcnc["export"][axis] == pytest.approx(linuxcnc["axis_tables"][axis], abs=0.01)
    fanuc = rates("fanuc")
    assert all(fanuc["export"][a] < fanuc["axis_tables"][a] for a in "YZ")
    siemens = rates("siemens")
    for axis in "XYZ":
        assert siemens["export"][axis] == pytest.approx(
            siemens["axis_and_cross_tables"][axis], abs=0.05
        )
    isg = rates("isg")
    assert min(isg["export"].values()) > 99.0  # volumetric (21 errors) + reversal lists


def test_isg_needs_the_rigid_model(tmp_path: Path) -> None:
    class Opaque:
        machine = paper_like_model().machine

        def error_um(self, positions_mm, approach=None, tool_offset_mm=None):
            return np.zeros((len(positions_mm), 3))

    with pytest.raises(UserError, match="--format csv"):
        export_model(Opaque(), "isg", tmp_path)


def test_gcode_needs_a_program_and_bad_formats_are_named(source, tmp_path: Path) -> None:
    with pytest.raises(UserError, match="--program"):
        export_model(source, "gcode", tmp_path)
    with pytest.raises(UserError, match="unknown export format 'okuma'"):
        export_model(source, "okuma", tmp_path)


def test_range_beyond_the_measured_one_is_flagged(source, tmp_path: Path) -> None:
    result = export_model(source, "csv", tmp_path, ExportOptions(range_mm={"Y": (-50.0, 450.0)}))
    assert any(flag.startswith("Y table") for flag in result.flags)
    rows = [
        line.split(",")
        for line in (tmp_path / "axis_tables.csv").read_text().splitlines()
        if line.startswith("Y,")
    ]
    flagged = {float(r[1]) for r in rows if r[-1] == "1"}
    assert min(flagged) == -50.0 and max(flagged) == 450.0
    assert all(p < 0 or p > 400 for p in flagged)


def test_compensation_report_has_the_contract_keys(source) -> None:
    report = compensation_report(source, files=("out/joint0_X.comp",))
    assert report["files"] == ["joint0_X.comp"]
    assert set(report["rate_percent"]) == {"volumetric", "axis_tables"}
    assert set(report["rate_percent"]["volumetric"]) == {"X", "Y", "Z"}
    assert "RMS" in report["rate_definition"]
    # The source has reversal: the volumetric rate is the grid with reversal tables.
    assert "volumetric_grid_and_reversal" in report["rate_definition"]
    assert report["rate_percent"]["volumetric"]["X"] > report["rate_percent"]["axis_tables"]["X"]


def test_export_result_carries_the_compensation_to_apply(source, tmp_path: Path) -> None:
    """The lead's virtual machine re-measures with ``result.compensation``; applied to the
    source it must give the rates the manifest predicts."""
    result = export_model(source, "siemens", tmp_path)
    assert result.compensation is not None
    nominal = np.array([[100.0, 200.0, 50.0]])
    command = result.compensation.command_mm(nominal, np.ones(3))
    landed = command + source.error_um(command, np.ones(3)) / 1e3
    before = np.abs(source.error_um(nominal, np.ones(3)))
    assert np.all(np.abs(landed - nominal) * 1e3 < before)
