"""Screenshots of every view of the workbench at its default size, for docs/images.

    python docs/make_screenshots.py [--project demo-output/demo.h5] [--out docs/images]

The window (1400 × 900, as it opens) shows the demo project — ``demo-output/demo.h5`` as ``make
demo`` writes it, or, when it is missing, the embedded demo data calibrated into a temporary
folder — with a line chosen in every view, a compensation preview, and beside it a re-measurement
of the demo machine compensated with the identified model (simulated on the virtual machine that
made the demo data). Runs on Qt's offscreen platform unless QT_QPA_PLATFORM says otherwise (under
Xvfb: ``QT_QPA_PLATFORM=xcb DISPLAY=:99``).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

DOCS = Path(__file__).resolve().parent
REPO = DOCS.parent
DEFAULT_SIZE = (1400, 900)
VIEWS = ("machine", "measurement", "identification", "loop", "sensitivity", "compensation",
         "comparison", "thermal")


def demo_project(folder: Path) -> Path:
    """The demo project: demo-output/demo.h5, or the demo data calibrated into ``folder``."""
    made = REPO / "demo-output" / "demo.h5"
    if made.is_file():
        return made
    from volucal.core.calibrate import CalibrationRequest, calibrate
    from volucal.core.resources import demo_plan

    path = folder / "demo.h5"
    calibrate(CalibrationRequest(demo_plan(), project_path=path, sensitivity_n=400))
    return path


def remeasure_compensated(project_path: Path, folder: Path) -> Path:
    """The demo plan measured again on the virtual machine, compensated with the project's final
    model (the direction-free 21-error model, as ``volucal export`` writes it), as a project."""
    from volucal.core import plans
    from volucal.core.compensation import ModelSource
    from volucal.core.io.plan import import_plan, load_plan
    from volucal.core.project import Project, error_model_from_tree
    from volucal.core.simulate import DEMO_JITTER_MM, DEMO_STEP_MM, demo_machine, write_session

    project = Project.open(project_path)
    model = error_model_from_tree(project.result("identifications", "loop")["model"],
                                  project.machine)
    source = ModelSource(model)
    vm = demo_machine()

    def command(nominal_mm, approach):  # type: ignore[no-untyped-def]
        return nominal_mm - source.error_um(nominal_mm, approach) / 1000.0

    lines = plans.full(vm.machine, DEMO_STEP_MM, DEMO_JITTER_MM)
    after = vm.measure(lines, compensation=command, realisation=5)
    plan = write_session(after, folder / "remeasured")
    imported = import_plan(load_plan(plan))
    again = Project.create(imported.measurement.machine)
    again.add_lines(imported.plan, imported.measurement, imported.source_bytes, imported.raw,
                    provenance={line.name: line.provenance() for line in imported.lines})
    return again.save(folder / "remeasured.h5")


def settle(app, seconds: float = 0.3) -> None:  # type: ignore[no-untyped-def]
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        app.processEvents()
        time.sleep(0.01)


def take(out: Path, project: Path | None = None) -> list[Path]:
    """Write one PNG per view (and the import wizard's two pages) into ``out``."""
    from PySide6.QtCore import QSettings, QStandardPaths
    from PySide6.QtWidgets import QWizard
    from volucal.app.main import application
    from volucal.app.mainwindow import MainWindow
    from volucal.core.resources import demo_plan

    app = application()
    scratch = Path(tempfile.mkdtemp(prefix="volucal-screenshots-"))
    QStandardPaths.setTestModeEnabled(True)
    QSettings.setPath(QSettings.Format.IniFormat, QSettings.Scope.UserScope, str(scratch))
    project = project or demo_project(scratch)
    after = remeasure_compensated(project, scratch)
    out.mkdir(parents=True, exist_ok=True)
    window = MainWindow()
    window.resize(*DEFAULT_SIZE)
    window.show()
    if not window.open_project(project):
        raise SystemExit(f"cannot open {project}")
    settle(app)

    def wait_idle(view) -> None:  # type: ignore[no-untyped-def]
        while view.runner.busy:
            settle(app, 0.05)

    from volucal.core.tolerances import Tolerances

    # a customer's limits on axis X, to show pass and fail
    limits = Tolerances({"X": {"A": 16.0, "E": 15.0, "R": 6.0, "B": 4.0, "M": 12.0}})
    window.document.put_results("edit the tolerances",
                                {("report", "tolerances"): limits.to_tree()})
    compensation = window.views["compensation"]
    window.show_view("compensation")
    compensation.set_format("linuxcnc")
    compensation.run_preview()
    wait_idle(compensation)
    window.open_remeasurement(after)
    # a thermal record beside the geometric lines: a simulated 12 h warm-up (spindle and column
    # sensors and four that do not drive the error), modelled as `volucal thermal` does
    from volucal.core.thermal_fit import ThermalFitRequest, fit_thermal
    from volucal.core.thermal_sim import SimulatedThermalTest, simulate_thermal_test
    from volucal.core.thermal_store import KIND, thermal_tree

    record = simulate_thermal_test(SimulatedThermalTest(hours=12, seed=3), name="warm-up")
    window.document.put_results("import a thermal record", {
        (KIND, "warm-up"): thermal_tree(record, [fit_thermal(ThermalFitRequest(record))])})
    window.views["thermal"].select("warm-up")
    window.tree.choose("measurements", "x_linear")
    identification = window.views["identification"]
    window.show_view("identification")
    identification.tabs.setCurrentIndex(1)
    identification.lines.selectRow(0)
    written = []
    for key in VIEWS:
        window.show_view(key)
        if key == "loop":
            window.views["loop"].steps.selectRow(0)
        settle(app)
        path = out / f"{key}.png"
        window.grab().save(str(path))
        written.append(path)

    wizard = window.import_logs([demo_plan()])
    wizard.resize(1200, 800)
    while not wizard.files_page.isComplete():
        settle(app, 0.05)
    wizard.next()
    while not wizard.preview_page.isComplete():
        settle(app, 0.05)
    wizard.preview_page.table.selectRow(1)
    settle(app)
    wizard.grab().save(str(out / "import_preview.png"))
    wizard.next()
    wizard.plan_page.table.selectRow(4)
    settle(app)
    wizard.grab().save(str(out / "import_plan.png"))
    written += [out / "import_preview.png", out / "import_plan.png"]
    wizard.button(QWizard.WizardButton.CancelButton).click()
    window.document.undo_stack.setClean()
    window.close()
    return written


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--project", type=Path, help="the project to show (default: the demo)")
    parser.add_argument("--out", type=Path, default=DOCS / "images",
                        help="folder of the PNG files (default: %(default)s)")
    args = parser.parse_args()
    for path in take(args.out, args.project):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
