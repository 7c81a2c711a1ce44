"""The calibration report of the demo, rendered to PDF and read back with poppler's pdftotext and
pdfinfo (Debian poppler-utils; .ci/install-report-tools.sh installs them).

The demo pipeline runs once for the session (the ``demo_run`` fixture: volucal.core.calibrate, then
the demo's verification on the virtual machine, as ``volucal demo`` does), about a minute.
"""

import hashlib
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from volucal.app.report import write_report
from volucal.core import cli
from volucal.core.conformance import CONFORMS, DOES_NOT_CONFORM, NO_DECISION, decide
from volucal.core.errors import ERROR_IDS
from volucal.core.identify import UncertaintyBudget
from volucal.core.iso230_2 import evaluate
from volucal.core.project import Project

DOCS = Path(__file__).resolve().parents[2] / "docs"
TOOLS = ("pdftotext", "pdfinfo")


@pytest.fixture(scope="module")
def poppler():
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if missing:
        pytest.skip(f"{', '.join(missing)} not installed (bash .ci/install-report-tools.sh)")


def pdf_text(path: Path) -> str:
    raw = subprocess.run(["pdftotext", "-layout", str(path), "-"], check=True,
                         capture_output=True, text=True).stdout
    # the report's fonts have ligatures off: "fi" is extracted as two letters, as typed
    assert not set("\ufb00\ufb01\ufb02\ufb03\ufb04") & set(raw), "ligatures in the PDF text"
    return raw


def pdf_pages(path: Path) -> int:
    info = subprocess.run(["pdfinfo", str(path)], check=True, capture_output=True,
                          text=True).stdout
    return int(re.search(r"^Pages:\s+(\d+)", info, re.MULTILINE).group(1))


def test_demo_report_has_every_part_on_its_pages(demo_run, poppler, tmp_path):
    pdf = tmp_path / "report.pdf"
    written = write_report(demo_run / "demo.h5", pdf, tolerance_um=25.0)
    assert pdf_pages(pdf) == written.pages >= 8
    text = pdf_text(pdf)
    for title in ("Calibration report", "Summary", "Machine", "Measurement plan", "Traceability",
                  "Positioning and straightness (ISO 230-2, ISO 230-1)", "Identified errors",
                  "Closed loop", "Sensitivity ranking (EFAST)", "Compensation",
                  "Uncertainty statement", "Conformance (ISO 14253-1)"):
        assert title in text, title
    assert f"page {written.pages} of {written.pages}" in text
    project = Project.open(demo_run / "demo.h5")
    assert project.machine.name in text
    # every line of the plan, and the operator and serial number its log names
    for name in project.lines:
        assert re.search(rf"^\s*{re.escape(name)}\s", text, re.MULTILINE), name
    assert "volucal virtual machine" in text and "VM-XL80-0001" in text
    # the 18 error curves are titled with their ISO id and the paper's symbol
    assert "EXX (δx(x)) — positioning" in text and "ECZ (εz(z)) — roll" in text
    # the loop found the demo's two hidden effects
    assert "reversal X" in text and "cyclic Y 16 mm" in text
    # the plan's identifiability is that of the 21-error fit, which tests every line
    assert "Every one of the 49 lines is redundant" in " ".join(text.split())


def test_the_certificate_prints_the_squareness_between_the_tool_paths(demo_run, poppler,
                                                                        tmp_path):
    # the figures the console and report.json give, each ± U (k = 2), with the places named
    pdf = tmp_path / "report.pdf"
    write_report(demo_run / "demo.h5", pdf)
    text = pdf_text(pdf)
    mapped = json.loads((demo_run / "report.json").read_text())["squareness_over_volume"]
    assert set(mapped) == {"EC0Y", "EB0Z", "EA0Z"}
    for sid, e in mapped.items():
        def pm(key, e=e):
            return f"{e[f'{key}_urad']:.2f} ± {2 * e[f'{key}_std_urad']:.2f}"

        lowest = ", ".join(f"{v:g}" for v in e["lowest_at_mm"])
        highest = ", ".join(f"{v:g}" for v in e["highest_at_mm"])
        row = re.search(rf"^\s*{sid} \(.*$", text.split("What a square")[1], re.MULTILINE)
        assert row is not None, sid
        cells = " ".join(row.group(0).split())
        assert f"{pm('at_centre')} {pm('lowest')} at ({lowest}) mm {pm('highest')} at " \
               f"({highest}) mm —" in cells, cells


def test_demo_report_lists_compensation_files_with_their_checksums(demo_run, poppler,
                                                                   tmp_path):
    pdf = tmp_path / "report.pdf"
    write_report(demo_run / "demo.h5", pdf)
    text = pdf_text(pdf)
    files = sorted(p for p in (demo_run / "compensation").rglob("*") if p.is_file())
    assert files
    for path in files:
        assert hashlib.sha256(path.read_bytes()).hexdigest() in text, path.name
        assert str(path.relative_to(demo_run / "compensation")) in text
    # predicted and verified rates, as report.json has them
    report = json.loads((demo_run / "report.json").read_text())
    predicted = report["compensation"]["methods"]["volumetric_grid"]["rms_percent"]
    verified = report["compensation"]["verified_on_virtual_machine"]["nc_rewriting"]
    row = next(line for line in text.splitlines() if line.strip().startswith("volumetric_grid "))
    assert f"{predicted['X']:.1f}" in row and f"{predicted['Z']:.1f}" in row
    rows = [line for line in text.splitlines() if line.strip().startswith("nc_rewriting")]
    measured = verified["remeasured"]["rms_percent"]
    assert any(f"{measured['X']:.1f}" in r and f"{measured['Y']:.1f}" in r for r in rows)


def test_conformance_decision_follows_the_rule_on_iso_230_2_accuracy(demo_run, poppler,
                                                                     tmp_path):
    project = Project.open(demo_run / "demo.h5")
    budget = UncertaintyBudget()
    verdicts = {}
    for line in project.measurement().lines:
        if line.spec.quantity == "linear":
            travel = float(line.data.targets_mm.max() - line.data.targets_mm.min())
            u = float(budget.positioning_std_um([travel])[0])
            verdicts[line.name] = decide(evaluate(line.data).A_um, 2 * u, 25.0)
    expected = (DOES_NOT_CONFORM if DOES_NOT_CONFORM in verdicts.values()
                else CONFORMS if set(verdicts.values()) == {CONFORMS} else NO_DECISION)
    pdf = tmp_path / "report.pdf"
    write_report(demo_run / "demo.h5", pdf, tolerance_um=25.0)
    text = " ".join(pdf_text(pdf).split())
    assert f"Decision: the machine {expected}" in text
    assert "T = 25.00 µm" in text


def test_report_command_writes_the_pdf_and_prints_json(demo_run, poppler, tmp_path, capsys):
    pdf = tmp_path / "cli.pdf"
    code = cli.main(["report", str(demo_run / "demo.h5"), "-o", str(pdf), "--tolerance-um",
                     "40", "--tolerance-on", "volumetric", "--json"])
    assert code == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["pages"] == pdf_pages(pdf)
    conformance = printed["report"]["conformance"]
    assert conformance["quantity"] == "volumetric" and conformance["tolerance_um"] == 40.0
    (item,) = conformance["items"]
    assert conformance["verdict"] == decide(item["value_um"], item["expanded_uncertainty_um"],
                                            40.0)


def test_report_json_docs_name_every_key_the_demo_produces(demo_run):
    """docs/report_json.md documents every key of report.json as produced (error ids, which
    key whole blocks, are documented once as a pattern)."""
    report = json.loads((demo_run / "report.json").read_text())
    documented = set(re.findall(r"`([A-Za-z0-9_]+)`", (DOCS / "report_json.md").read_text()))
    keys: set[str] = set()

    def walk(value):
        if isinstance(value, dict):
            for key, child in value.items():
                if key not in ERROR_IDS:
                    keys.add(key)
                walk(child)
        elif isinstance(value, list):
            for child in value:
                walk(child)

    walk(report)
    assert sorted(keys - documented) == []


def test_report_of_a_workbench_project(small_project, poppler, tmp_path):
    """A project the workbench saved (its own result trees, no compensation yet) reports too."""
    pdf = tmp_path / "small.pdf"
    written = write_report(small_project, pdf)
    text = pdf_text(pdf)
    assert pdf_pages(pdf) == written.pages
    for title in ("Identified errors", "Closed loop", "Sensitivity ranking (EFAST)"):
        assert title in text
    assert "No compensation was computed." in text
    assert "Conformance" not in text  # no tolerance given


def page_images(pdf: Path, folder: Path, dpi: int = 40) -> list[np.ndarray]:
    """Every page rendered by poppler's pdftoppm, as RGB arrays."""
    from PySide6.QtGui import QImage

    subprocess.run(["pdftoppm", "-r", str(dpi), "-png", str(pdf), str(folder / "page")],
                   check=True, capture_output=True)
    images = []
    for path in sorted(folder.glob("page-*.png")):
        image = QImage(str(path)).convertToFormat(QImage.Format.Format_RGB888)
        raw = np.frombuffer(image.constBits(), np.uint8, image.bytesPerLine() * image.height())
        rows = raw.reshape(image.height(), image.bytesPerLine())[:, :3 * image.width()]
        images.append(rows.reshape(image.height(), image.width(), 3).copy())
    return images


def coloured(image: np.ndarray, colour: str, tolerance: int = 40) -> int:
    """Pixels near ``colour`` (#rrggbb)."""
    rgb = np.array([int(colour[k:k + 2], 16) for k in (1, 3, 5)])
    return int(np.sum(np.all(np.abs(image.astype(int) - rgb) < tolerance, axis=-1)))


def test_every_page_has_content_where_it_should(demo_run, poppler, tmp_path):
    """Rendered to pictures: no page is empty, the text block of each page is inked, the ISO
    230-2 graphs draw both directions in their colours, the last page has the signature
    block; the words a user reads carry no command-line options and no folder paths."""
    from volucal.core.certificate import Certificate
    from volucal.core.tolerances import Tolerances

    pdf = tmp_path / "report.pdf"
    written = write_report(
        demo_run / "demo.h5", pdf, tolerance_um=25.0,
        certificate=Certificate({"customer": "ACME Tooling", "certificate_number": "C-17",
                                 "approver": "J. Metrologist"}),
        tolerances=Tolerances({"X": {"A": 20.0, "E": 15.0}, "Z": {"R": 2.0}}))
    images = page_images(pdf, tmp_path)
    assert len(images) == written.pages == pdf_pages(pdf)
    for number, image in enumerate(images, start=1):
        height, width, _ = image.shape
        ink = np.any(image < 200, axis=-1)
        # margins are white; the text area (without the footer) is inked top to bottom
        assert ink[: int(0.04 * height)].sum() == 0, number
        body = ink[int(0.06 * height): int(0.90 * height), int(0.08 * width): int(0.92 * width)]
        assert body.mean() > 0.01, f"page {number} is (nearly) empty"
        assert ink[int(0.93 * height): int(0.97 * height)].sum() > 0, f"page {number}: footer"
    text = pdf_text(pdf)
    pages = text.split("\f")
    graphs = [k for k, page in enumerate(pages) if "Axis X: positioning deviation" in page]
    assert graphs, "no ISO 230-2 graph of axis X"
    forward, backward = "#457b9d", "#e63946"  # the report's series colours
    assert coloured(images[graphs[0]], forward) > 60
    assert coloured(images[graphs[0]], backward) > 60
    assert "Signatures" in pages[-1] or "Signatures" in pages[-2]
    assert "Calibrated by" in text and "Approved by" in text and "J. Metrologist" in text
    assert "ACME Tooling" in text and "C-17" in text
    assert "Result: axis X: fail" in " ".join(text.split())
    assert "--" not in text, "command-line wording in the report"
    for folder in (str(demo_run), "/tmp", "/home", str(Path.home())):
        assert folder not in text, f"a path ({folder}) in the report"


def test_budget_terms_from_the_plan_are_marked_as_such(small_plan, poppler, tmp_path):
    """A plan with an [uncertainty] table: its terms are "plan", the others "default"."""
    import dataclasses as dc

    from volucal.core import plans
    from volucal.core.io.plan import import_plan, load_plan
    from volucal.core.simulate import LaserSetup, demo_machine, write_session

    vm = dc.replace(demo_machine(), laser=LaserSetup(noise_um=0.15, runs_per_direction=2))
    measured = vm.measure(plans.layout("nine-line", vm.machine, 20.0, 2.0))
    plan = write_session(measured, tmp_path / "session",
                         uncertainty={"laser_ppm": 0.2, "dead_path_mm": 35.0})
    imported = import_plan(load_plan(plan))
    project = Project.create(imported.measurement.machine)
    project.add_lines(imported.plan, imported.measurement, imported.source_bytes, imported.raw)
    path = project.save(tmp_path / "budget.h5")
    pdf = tmp_path / "budget.pdf"
    write_report(path, pdf)
    rows = {line.split()[0]: line for line in pdf_text(pdf).splitlines()
            if line.strip() and line.split()[0] in ("laser_ppm", "dead_path_mm", "cosine_urad")}
    assert "plan" in rows["laser_ppm"] and "0.200" in rows["laser_ppm"]
    assert "plan" in rows["dead_path_mm"] and "35.000" in rows["dead_path_mm"]
    assert "default" in rows["cosine_urad"]


def test_report_values_follow_the_chosen_units(demo_run, poppler, tmp_path):
    from volucal.core.display_units import DisplayUnits

    pdf = tmp_path / "mm.pdf"
    write_report(demo_run / "demo.h5", pdf, units=DisplayUnits("mm", "arcsec"))
    text = pdf_text(pdf)
    project = Project.open(demo_run / "demo.h5")
    line = project.lines["x_linear"]
    a_um = evaluate(line.corrected, "um").A_um
    row = next(r for r in text.splitlines() if r.strip().startswith("x_linear ") and " mm " in r)
    assert f"{a_um / 1000:.6f}" in row
    assert "value arcsec" in text and "deviation (mm)" in text


def test_report_has_a_page_per_thermal_record(small_project, poppler, tmp_path):
    """A thermal record in the project (`volucal thermal --project`) gets its page: the model,
    the held-out error and the plot of error and prediction over time."""
    from volucal.core.project import Project
    from volucal.core.thermal_fit import ThermalFitRequest, fit_thermal
    from volucal.core.thermal_sim import SimulatedThermalTest, simulate_thermal_test
    from volucal.core.thermal_store import store_thermal

    measurement = simulate_thermal_test(SimulatedThermalTest(hours=12, seed=3), name="warm-up")
    fitted = fit_thermal(ThermalFitRequest(measurement))
    path = tmp_path / "thermal.h5"
    project = Project.open(small_project)
    store_thermal(project, "warm-up", measurement, [fitted])
    project.save(path)
    pdf = tmp_path / "thermal.pdf"
    written = write_report(path, pdf)
    text = pdf_text(pdf)
    assert pdf_pages(pdf) == written.pages
    assert f"Thermal error: {fitted.channel}" in text
    assert "held" in text.lower()
