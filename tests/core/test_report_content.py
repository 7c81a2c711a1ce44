"""The calibration report's content, gathered without Qt (volucal.core.report_content), on the
checked-in format-1 project: five hand-made lines from four file formats, no results yet."""

import hashlib
import json
import shutil
from pathlib import Path

import pytest
from volucal.core.iso230_2 import evaluate
from volucal.core.project import Project
from volucal.core.report_content import Paragraph, ReportRequest, Table, build_report
from volucal.core.userror import UserError

V1 = Path(__file__).resolve().parents[1] / "data" / "projects" / "format_v1.h5"


@pytest.fixture
def project(tmp_path) -> Path:
    path = tmp_path / "v1.h5"
    shutil.copyfile(V1, path)
    return path


def _section(content, title):
    return next(s for s in content.sections if s.title.startswith(title))


def _tables(section):
    return [b for b in section.blocks if isinstance(b, Table)]


def test_traceability_names_files_checksums_operator_and_serial(project):
    content = build_report(ReportRequest(project))
    stored = Project.open(project)
    section = _section(content, "Traceability")
    facts = dict(_tables(section)[0].rows)
    assert facts["Operators"] == "J. Smith"
    assert facts["Serial numbers in the logs"] == "1234"
    assert facts["Instrument (log format)"] == "iso230-2, rta, rtl, table"
    assert hashlib.sha256(project.read_bytes()).hexdigest() in facts["Project file"]
    logs = {row[0]: row for row in _tables(section)[1].rows}
    for name in stored.lines:
        digest = hashlib.sha256(stored.raw_bytes(name)).hexdigest()
        assert logs[name][-1] == digest[:16]
    assert logs["x_y0_z0"][5].startswith("2016-12-12") and "(log: 12/12/2016)" in logs["x_y0_z0"][5]
    assert logs["z_iso"][5] == "no date in the log"  # an ISO table carries no time


def test_iso_230_2_table_has_each_positioning_line_and_straightness_apart(project):
    content = build_report(ReportRequest(project))
    stored = Project.open(project)
    positioning, straight = _tables(_section(content, "Positioning"))
    rows = {row[0]: row for row in positioning.rows}
    assert set(rows) == {"z_linear", "z_iso", "x_y0_z0", "x_pitch_hand"}
    expected = evaluate(stored.lines["z_iso"].corrected)
    # in the report's units (µm by default), to the tenth of a micrometre's hundredth
    assert rows["z_iso"][3] == f"{expected.A_um:.3f}"
    assert rows["z_iso"][7] == f"{expected.R_um:.3f}"
    assert rows["z_linear"][3] == "—"  # one run each way: no standard deviation, no A
    assert rows["x_pitch_hand"][1] == "µrad"
    assert [row[0] for row in straight.rows] == ["y_straightness_x"]


def test_missing_results_are_said_not_left_out(project):
    content = build_report(ReportRequest(project))
    titles = [s.title for s in content.sections]
    assert "Identified errors" not in titles  # no identification tree in this project
    for title, text in (("Closed loop", "not run"), ("Sensitivity", "not run"),
                        ("Compensation", "No compensation")):
        paragraphs = [b.text for b in _section(content, title).blocks
                      if isinstance(b, Paragraph)]
        assert any(text in p for p in paragraphs)
    json.dumps(content.to_json(), allow_nan=False)


def test_conformance_is_added_only_with_a_tolerance(project):
    assert build_report(ReportRequest(project)).conformance is None
    content = build_report(ReportRequest(project, tolerance_um=100.0))
    assert content.conformance is not None
    assert content.conformance.quantity == "accuracy"
    # the decision closes the report, before the signatures
    assert [s.title for s in content.sections][-2:] == ["Conformance (ISO 14253-1)",
                                                         "Signatures"]
    with pytest.raises(UserError, match="no identification"):
        build_report(ReportRequest(project, tolerance_um=10.0, tolerance_on="volumetric"))
    with pytest.raises(UserError, match="tolerance on"):
        build_report(ReportRequest(project, tolerance_um=10.0, tolerance_on="flatness"))


def test_a_report_json_of_another_run_is_refused(project, tmp_path):
    other = tmp_path / "report.json"
    other.write_text(json.dumps({"residual_rms_um": {"before_loop": 1.0, "after_loop": 0.5}}))
    with pytest.raises(UserError, match="not of the project's run"):
        build_report(ReportRequest(project, report_json=other))
    # found beside the project by default, it is silently not used
    content = build_report(ReportRequest(project))
    assert content.sources["verification"] == ""


def test_errors_name_the_file(tmp_path):
    with pytest.raises(UserError, match="no such project file"):
        build_report(ReportRequest(tmp_path / "missing.h5"))
    empty = tmp_path / "empty.h5"
    Project.create().save(empty)
    with pytest.raises(UserError, match="no measured lines"):
        build_report(ReportRequest(empty))


def test_compensation_checksums_read_only_the_files_the_run_recorded(tmp_path):
    """The compensation folder is named by the project, and a project is data: the report reads
    the recorded names in that folder and its format folders, never what else is there, a link
    out of it or a name that climbs out."""
    from volucal.core.report_content import compensation_file_blocks

    folder = tmp_path / "compensation"
    (folder / "linuxcnc").mkdir(parents=True)
    (folder / "linuxcnc" / "joint0_X.comp").write_text("0 0 0\n")
    (folder / "unrecorded.bin").write_bytes(b"x" * 100)
    secret = tmp_path / "secret.txt"
    secret.write_text("not ours")
    (folder / "link.comp").symlink_to(secret)
    table = compensation_file_blocks(["joint0_X.comp", "link.comp", "../secret.txt"], folder)[0]
    rows = {row[0]: row for row in table.rows}
    digest = hashlib.sha256(b"0 0 0\n").hexdigest()
    assert rows["linuxcnc/joint0_X.comp"] == ("linuxcnc/joint0_X.comp", "6", digest)
    assert rows["link.comp"][2] == "not in the folder"
    assert rows["../secret.txt"][2].startswith("not read")
    assert not any("unrecorded" in row[0] for row in table.rows)
    secret_digest = hashlib.sha256(b"not ours").hexdigest()
    assert all(secret_digest not in row[2] for row in table.rows)


def test_iso_graphs_are_drawn_over_the_axis_positions_of_the_targets(project):
    from volucal.core.display_units import DisplayUnits
    from volucal.core.report_acceptance import iso_graphs_section
    from volucal.core.report_blocks import IsoGraphs

    # z_iso runs along +Z from Z = -180 mm: its graph is over Z -180 … 0, as ISO 230-2 draws
    # positions, not over the distances 0 … 180 from its first target
    z_iso = Project.open(project).measurement().line("z_iso")
    section = iso_graphs_section([z_iso], DisplayUnits())
    graphs = next(b for b in section.blocks if isinstance(b, IsoGraphs)).graphs
    assert [g.title for g in graphs] == ["Axis Z: positioning deviation (z_iso)"]
    assert graphs[0].position_title == "Z (mm)"
    assert graphs[0].positions_mm == (-180.0, -120.0, -60.0, 0.0)


def test_the_notes_at_import_name_their_lines(project):
    # each correction or note once, with the lines it was made on: a note of one line (z_linear's
    # nm, x_pitch_hand's…) reads as that line's, not as the session's
    section = _section(build_report(ReportRequest(project)), "Traceability")
    (paragraph,) = [
        b for b in section.blocks
        if isinstance(b, Paragraph) and b.text.startswith("Corrections and notes at import")
    ]
    assert "deviations converted from nm to um (z_linear)" in paragraph.text
