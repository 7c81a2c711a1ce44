"""Workbench tests: offscreen Qt, PySide6 for pyqtgraph, isolated settings, no stray threads.

The environment is set before anything imports Qt. Every test gets its own settings folder
(QSettings' user scope) and Qt's test mode for standard paths (caches under ~/.qttest), and
fails if it leaves a worker thread running.
"""

import os

os.environ["QT_QPA_PLATFORM"] = "offscreen"
os.environ["PYQTGRAPH_QT_LIB"] = "PySide6"

import dataclasses  # noqa: E402
import shutil  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
from PySide6.QtCore import QSettings, QStandardPaths  # noqa: E402
from volucal.app import jobs, tasks  # noqa: E402
from volucal.app.document import ProjectDocument  # noqa: E402
from volucal.app.factors import RANKING_GRID_MM, SensitivitySetup, sensitivity_tree  # noqa: E402
from volucal.app.main import application  # noqa: E402
from volucal.core import plans  # noqa: E402
from volucal.core.identify import IdentifyOptions  # noqa: E402
from volucal.core.io.plan import import_plan, load_plan  # noqa: E402
from volucal.core.project import Project  # noqa: E402
from volucal.core.residuals import LoopOptions  # noqa: E402
from volucal.core.simulate import LaserSetup, demo_machine, write_session  # noqa: E402

#: The offscreen platform cannot resize a native window to its size hints and says so for
#: every dock and dialog; it is a limitation of the test platform, not a fault of the app.
OFFSCREEN_NOISE = "This plugin does not support propagateSizeHints"
#: The small plan of the GUI tests: the classic nine lines, with the demo machine's reversal on
#: X and screw cycle on Y, two runs per direction, a target every 10 mm.
SMALL_LAYOUT = "nine-line"
SMALL_STEP_MM = 10.0
SMALL_SPACING_MM = 50.0
SMALL_LOOP_STEPS = 2


def pytest_collection_modifyitems(items):
    here = Path(__file__).resolve().parent
    for item in items:
        if here in Path(str(item.fspath)).resolve().parents:
            item.add_marker(pytest.mark.qt_log_ignore(OFFSCREEN_NOISE))


@pytest.fixture(autouse=True)
def isolated_settings(tmp_path, qapp):
    """Settings of this test only; the application named as the workbench names it."""
    application()
    QStandardPaths.setTestModeEnabled(True)
    QSettings.setPath(QSettings.Format.IniFormat, QSettings.Scope.UserScope,
                      str(tmp_path / "settings"))
    yield tmp_path / "settings"


@pytest.fixture(autouse=True)
def no_thread_left(qapp):
    """Fail a test that leaves a worker thread running (and stop it, for the next test)."""
    yield
    running = [t for t in tasks.live_tasks() if t.running]
    if running:
        for task in running:
            task.drop()
        tasks.wait_for_all(60_000)
        qapp.processEvents()
        pytest.fail(f"worker thread(s) still running after the test: "
                    f"{', '.join(t.title for t in running)}")
    qapp.processEvents()


@pytest.fixture(scope="session")
def small_plan(tmp_path_factory) -> Path:
    """plan.toml and .rtl logs of a small simulated session (written once)."""
    vm = demo_machine()
    vm = dataclasses.replace(vm, laser=LaserSetup(noise_um=0.15, runs_per_direction=2))
    lines = plans.layout(SMALL_LAYOUT, vm.machine, SMALL_STEP_MM, 2.0)
    folder = tmp_path_factory.mktemp("small_session")
    return write_session(vm.measure(lines), folder)


def _small_loop_options() -> LoopOptions:
    return LoopOptions(identify=IdentifyOptions(spacing_mm=SMALL_SPACING_MM),
                       max_steps=SMALL_LOOP_STEPS)


@pytest.fixture
def small_loop_options() -> LoopOptions:
    """The loop settings of the small session (what the GUI tests set in the views)."""
    return _small_loop_options()


@pytest.fixture(scope="session")
def small_project_file(small_plan, tmp_path_factory) -> Path:
    """The small session imported, looped and ranked, saved once (tests open copies)."""
    imported = import_plan(load_plan(small_plan))
    project = Project.create(imported.measurement.machine)
    project.add_lines(imported.plan, imported.measurement, imported.source_bytes, imported.raw,
                      provenance={line.name: line.provenance() for line in imported.lines})
    run = jobs.run_loop(imported.measurement, _small_loop_options())
    for (kind, name), tree in run.trees().items():
        project.put_result(kind, name, tree)
    final = run.loop.final
    setup = SensitivitySetup.identified(final.model, final.covariance, n=600,
                                        identification="loop")
    result = setup.run(final.model, final.covariance, map_step_mm=RANKING_GRID_MM)
    project.put_result("sensitivity", "main", sensitivity_tree(result, setup))
    path = tmp_path_factory.mktemp("small_project") / "small.h5"
    project.save(path)
    return path


@pytest.fixture
def small_project(small_project_file, tmp_path) -> Path:
    """A copy of the small project this test may change."""
    path = tmp_path / "small.h5"
    shutil.copyfile(small_project_file, path)
    return path


@pytest.fixture(scope="session")
def small_remeasured_file(small_project_file, tmp_path_factory) -> Path:
    """The small session's lines measured again on the virtual machine compensated with the
    small project's final model (direction-free): the "after" of a before/after comparison."""
    from volucal.core.compensation import ModelSource
    from volucal.core.project import error_model_from_tree

    project = Project.open(small_project_file)
    model = error_model_from_tree(project.result("identifications", "loop")["model"],
                                  project.machine)
    source = ModelSource(model)
    vm = dataclasses.replace(demo_machine(), laser=LaserSetup(noise_um=0.15,
                                                              runs_per_direction=2))
    lines = plans.layout(SMALL_LAYOUT, vm.machine, SMALL_STEP_MM, 2.0)
    after = vm.measure(lines, realisation=3,
                       compensation=lambda q, a: q - source.error_um(q, a) / 1000.0)
    folder = tmp_path_factory.mktemp("small_remeasured")
    imported = import_plan(load_plan(write_session(after, folder)))
    again = Project.create(imported.measurement.machine)
    again.add_lines(imported.plan, imported.measurement, imported.source_bytes, imported.raw,
                    provenance={line.name: line.provenance() for line in imported.lines})
    return again.save(folder / "after.h5")


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory):
    """`volucal demo` in a folder: demo.h5 (as calibrate writes it), report.json (with the rates
    verified on the virtual machine) and compensation/ — about a minute, once per session."""
    from volucal.core.calibrate import CalibrationRequest, calibrate, write_json_atomic
    from volucal.core.commands.demo_cmd import verify_demo
    from volucal.core.resources import demo_plan

    folder = tmp_path_factory.mktemp("demo")
    # fewer EFAST samples than the demo's 1400 per factor: the tests only lay them out
    result = calibrate(CalibrationRequest(
        demo_plan(), project_path=folder / "demo.h5", report_path=folder / "report.json",
        export_dir=folder / "compensation", sensitivity_n=400))
    verify_demo(result)
    write_json_atomic(folder / "report.json", result.report)
    return folder


@pytest.fixture
def demo_project(demo_run, tmp_path) -> Path:
    """A copy of the demo project this test may change."""
    path = tmp_path / "demo.h5"
    shutil.copyfile(demo_run / "demo.h5", path)
    return path


@pytest.fixture
def document(small_project) -> ProjectDocument:
    return ProjectDocument(Project.open(small_project))


@pytest.fixture
def window(qtbot, small_project):
    """The main window on a copy of the small project; closed (without prompts) afterwards."""
    from volucal.app.mainwindow import MainWindow

    win = MainWindow()
    qtbot.addWidget(win, before_close_func=_discard_changes)
    win.show()
    assert win.open_project(small_project)
    return win


@pytest.fixture
def wait_idle(qtbot):
    """``wait_idle(view)``: wait until a view (or the window) has no task running."""
    def wait(widget, timeout=90_000):
        runner = widget.runner
        qtbot.waitUntil(lambda: not runner.busy, timeout=timeout)

    return wait


def _discard_changes(window):
    """Tests close windows with unsaved changes: no "save changes?" question."""
    window.document.undo_stack.setClean()
