"""The main window: project tree, views, menus, status bar with progress, log panel.

Every action goes through the document (undoable edits) or a view (computations in workers).
Errors the user can fix show the core's message in a dialog and leave the project unchanged.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from pathlib import Path

import shiboken6
from PySide6.QtCore import QStandardPaths, Qt
from PySide6.QtGui import (
    QAction,
    QActionGroup,
    QCloseEvent,
    QDragEnterEvent,
    QDropEvent,
    QKeySequence,
    QUndoGroup,
)
from PySide6.QtWidgets import (
    QDockWidget,
    QFileDialog,
    QLabel,
    QMainWindow,
    QMessageBox,
    QProgressBar,
    QPushButton,
    QStackedWidget,
)
from volucal.core.certificate import Certificate
from volucal.core.project import Project
from volucal.core.tolerances import Tolerances
from volucal.core.userror import UserError

from . import jobs, plots, settings
from .comparison_view import ComparisonView
from .compensation_view import CompensationView
from .dialogs import PreferencesDialog, about_box, show_bug, show_error
from .document import ProjectDocument
from .engine import ProcessCall, prestart
from .factors import SensitivityRecord
from .identification_view import IdentificationView
from .import_wizard import ImportWizard
from .log_panel import LogPanel
from .loop_view import LoopView
from .machine_view import MachineView
from .measurement_view import MeasurementView
from .project_tree import ProjectTree
from .records import Live
from .report_dialog import ReportDialog, TolerancesDialog
from .sensitivity_view import SensitivityView
from .tasks import Task, TaskRunner, wait_for_all
from .thermal_records_view import ThermalRecordsView
from .user_guide import UserGuide
from .view_base import View

log = logging.getLogger("volucal.app")

PROJECT_FILTER = "volucal projects (*.h5 *.hdf5);;All files (*)"
#: Tree kinds → view keys.
KIND_VIEW = {"machine": "machine", "measurements": "measurement",
             "identifications": "identification", "loops": "loop", "sensitivity": "sensitivity",
             "compensation": "compensation", "thermal": "thermal"}
VIEW_ORDER = ("machine", "measurement", "identification", "loop", "sensitivity", "compensation",
              "comparison", "thermal")
LENGTH_CHOICES = (("um", "µm"), ("mm", "mm"), ("inch", "inch"))
ANGLE_CHOICES = (("urad", "µrad"), ("arcsec", "arcsec"), ("um_per_m", "µm/m"))


def _without_checked(slot: Callable[[], object]) -> Callable[..., object]:
    """A slot for ``QAction.triggered(bool)``: Qt hands the action's ``checked`` flag to the
    slot, and no action of the window takes it (``save_as(False)`` would be a path)."""
    def call(*_checked: object) -> object:
        return slot()

    return call


def cache_folder() -> Path:
    return Path(QStandardPaths.writableLocation(QStandardPaths.StandardLocation.CacheLocation))


class MainWindow(QMainWindow):
    def __init__(self, document: ProjectDocument | None = None) -> None:
        super().__init__()
        self.setObjectName("mainWindow")
        self.resize(1400, 900)
        self.setAcceptDrops(True)
        self.document = document or ProjectDocument()
        self.runner = TaskRunner(self)
        self._tasks: list[Task] = []
        self.wizard: ImportWizard | None = None
        self.report_dialog: ReportDialog | None = None
        self.last_report: Path | None = None
        self.undo_group = QUndoGroup(self)
        self.undo_group.addStack(self.document.undo_stack)
        self.undo_group.setActiveStack(self.document.undo_stack)

        self.views: dict[str, View] = {
            "machine": MachineView(self.document),
            "measurement": MeasurementView(self.document),
            "identification": IdentificationView(self.document),
            "loop": LoopView(self.document),
            "sensitivity": SensitivityView(self.document),
            "compensation": CompensationView(self.document),
            "comparison": ComparisonView(self.document),
            "thermal": ThermalRecordsView(self.document),
        }
        self.stack = QStackedWidget()
        for key in VIEW_ORDER:
            self.stack.addWidget(self.views[key])
        self.setCentralWidget(self.stack)

        self.tree = ProjectTree(self.document)
        self.tree.itemChosen.connect(self.show_item)
        tree_dock = QDockWidget("Project", self)
        tree_dock.setObjectName("projectDock")
        tree_dock.setWidget(self.tree)
        self.addDockWidget(Qt.DockWidgetArea.LeftDockWidgetArea, tree_dock)
        self.log_panel = LogPanel()
        log_dock = QDockWidget("Log", self)
        log_dock.setObjectName("logDock")
        log_dock.setWidget(self.log_panel)
        self.addDockWidget(Qt.DockWidgetArea.BottomDockWidgetArea, log_dock)
        self.resizeDocks([tree_dock], [260], Qt.Orientation.Horizontal)
        self.resizeDocks([log_dock], [120], Qt.Orientation.Vertical)
        self.docks = (tree_dock, log_dock)

        self.status_text = QLabel()
        self.progress = QProgressBar()
        self.progress.setObjectName("statusProgress")
        self.progress.setMaximumWidth(240)
        self.progress.setRange(0, 100)
        self.progress.setVisible(False)
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setObjectName("statusCancel")
        self.cancel_button.setVisible(False)
        self.cancel_button.clicked.connect(self.cancel_tasks)
        self.statusBar().addWidget(self.status_text, 1)
        self.statusBar().addPermanentWidget(self.progress)
        self.statusBar().addPermanentWidget(self.cancel_button)
        for runner in [self.runner] + [v.runner for v in self.views.values()]:
            runner.started.connect(self._task_started)

        self._build_menus()
        self._connect_document()
        prestart()  # a worker process for the first long computation, ready when it is asked
        self.show_view("machine")
        self._update_title()

    # ---- menus ---------------------------------------------------------------------------

    def _action(self, text: str, slot: Callable[[], object],
                shortcut: QKeySequence | QKeySequence.StandardKey | None = None,
                tip: str = "") -> QAction:
        action = QAction(text, self)
        if shortcut is not None:
            action.setShortcut(shortcut)
        if tip:
            action.setStatusTip(tip)
        action.triggered.connect(_without_checked(slot))
        self.addAction(action)
        return action

    def _build_menus(self) -> None:
        bar = self.menuBar()
        file = bar.addMenu("&File")
        file.addAction(self._action("&New project", self.new_project, QKeySequence.StandardKey.New))
        file.addAction(self._action("&Open…", self.open_dialog, QKeySequence.StandardKey.Open))
        self.recent_menu = file.addMenu("Open &recent")
        self.recent_menu.aboutToShow.connect(self._fill_recent)
        file.addAction(self._action("Open the &demo project", self.open_demo, None,
                                    "the embedded demo data, calibrated (cached after the "
                                    "first time)"))
        file.addSeparator()
        self.save_action = self._action("&Save", self.save, QKeySequence.StandardKey.Save)
        file.addAction(self.save_action)
        file.addAction(self._action("Save &as…", self.save_as, QKeySequence.StandardKey.SaveAs))
        file.addSeparator()
        file.addAction(self._action("&Import logs…", self.import_logs, QKeySequence("Ctrl+I"),
                                    "import laser logs and/or a plan.toml"))
        file.addAction(self._action("Open a re-&measurement…", self.open_remeasurement, None,
                                    "the same lines measured again on the compensated machine, "
                                    "beside this project"))
        file.addSeparator()
        file.addAction(self._action("&Report (PDF)…", self.write_report, QKeySequence("Ctrl+R"),
                                    "the calibration report of the saved project"))
        file.addAction(self._action("&Export the plots of this view…", self.export_plots,
                                    QKeySequence("Ctrl+E"),
                                    "every plot of the view as PNG, SVG and CSV into a folder"))
        file.addSeparator()
        file.addAction(self._action("&Quit", self.close, QKeySequence.StandardKey.Quit))

        edit = bar.addMenu("&Edit")
        self.undo_action = self.undo_group.createUndoAction(self, "&Undo")
        self.undo_action.setShortcut(QKeySequence.StandardKey.Undo)
        self.redo_action = self.undo_group.createRedoAction(self, "&Redo")
        self.redo_action.setShortcuts([QKeySequence(QKeySequence.StandardKey.Redo),
                                       QKeySequence("Ctrl+Y")])
        edit.addAction(self.undo_action)
        edit.addAction(self.redo_action)
        edit.addSeparator()
        edit.addAction(self._action("&Tolerances per axis…", self.edit_tolerances, None,
                                    "ISO 230-2 limits per axis: pass/fail in the views and the "
                                    "report"))
        edit.addAction(self._action("&Preferences…", self.preferences, QKeySequence("Ctrl+,")))

        run = bar.addMenu("&Run")
        run.addAction(self._action("&Identify the 21 errors", self.identify, QKeySequence("F5")))
        run.addAction(self._action("Close the &loop", self.close_loop, QKeySequence("F6")))
        run.addAction(self._action("&Sensitivity (EFAST)", self.sensitivity, QKeySequence("F7")))
        run.addAction(self._action("&Compensation preview", self.compensation,
                                   QKeySequence("F8")))
        run.addSeparator()
        run.addAction(self._action("&Cancel running tasks", self.cancel_tasks,
                                   QKeySequence("Ctrl+."), "stop every running computation"))

        view = bar.addMenu("&View")
        for number, key in enumerate(VIEW_ORDER, start=1):
            view.addAction(self._action(f"&{number} {self.views[key].title}",
                                        partial(self.show_view, key),
                                        QKeySequence(f"Ctrl+{number}")))
        view.addSeparator()
        units = view.addMenu("&Units")
        current = settings.display_units()
        self.unit_actions: dict[tuple[str, str], QAction] = {}
        for kind, title, choices in (("length", "Deviations in", LENGTH_CHOICES),
                                     ("angle", "Angles in", ANGLE_CHOICES)):
            group = QActionGroup(self)
            group.setExclusive(True)
            units.addSection(title)
            for key, text in choices:
                action = self._action(text, partial(self.set_units, kind, key))
                action.setCheckable(True)
                action.setChecked(getattr(current, kind) == key)
                group.addAction(action)
                units.addAction(action)
                self.unit_actions[(kind, key)] = action
        view.addSeparator()
        for dock in self.docks:
            view.addAction(dock.toggleViewAction())

        help_menu = bar.addMenu("&Help")
        help_menu.addAction(self._action("&User guide", self.user_guide,
                                         QKeySequence(QKeySequence.StandardKey.HelpContents)))
        help_menu.addAction(self._action("&About volucal", lambda: about_box(self)))

    def _fill_recent(self) -> None:
        self.recent_menu.clear()
        recent = settings.recent_projects()
        if not recent:
            action = self.recent_menu.addAction("(none)")
            action.setEnabled(False)
        for path in recent:
            action = self.recent_menu.addAction(str(path))
            action.triggered.connect(lambda _c=False, p=path: self.open_project(p))

    # ---- the document ----------------------------------------------------------------------

    def _connect_document(self) -> None:
        self.document.cleanChanged.connect(self._update_title)
        self.document.pathChanged.connect(self._update_title)
        self.document.changed.connect(self._update_title)

    def set_document(self, document: ProjectDocument) -> None:
        old = self.document
        self.document = document
        for view in self.views.values():
            view.set_document(document)
        self.tree.set_document(document)
        self.undo_group.addStack(document.undo_stack)
        self.undo_group.setActiveStack(document.undo_stack)
        self.undo_group.removeStack(old.undo_stack)
        self._connect_document()
        old.deleteLater()
        self.status_text.clear()
        self._update_title()
        self.show_view("machine")

    def _update_title(self) -> None:
        path = self.document.path
        name = path.name if path is not None else "untitled"
        self.setWindowTitle(f"{name}[*] — volucal")
        self.setWindowModified(not self.document.is_clean)

    def maybe_discard(self) -> bool:
        """True when the current project may be replaced (saved, or the user agrees)."""
        if self.document.is_clean:
            return True
        answer = QMessageBox.question(
            self, "Unsaved changes",
            "The project has changes that are not saved. Save them first?",
            QMessageBox.StandardButton.Save | QMessageBox.StandardButton.Discard
            | QMessageBox.StandardButton.Cancel,
        )
        if answer == QMessageBox.StandardButton.Save:
            return self.save()
        return answer == QMessageBox.StandardButton.Discard

    def new_project(self) -> None:
        if self.maybe_discard():
            self.set_document(ProjectDocument())
            log.info("new project")

    def open_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Open a project", settings.last_folder(),
                                              PROJECT_FILTER)
        if path:
            self.open_project(Path(path))

    def open_project(self, path: Path) -> bool:
        """Open a project file; a file the core refuses shows its message, nothing changes."""
        if not self.maybe_discard():
            return False
        try:
            project = Project.open(path)
        except UserError as exc:
            show_error(self, "Cannot open the project", str(exc))
            if not Path(path).is_file():
                settings.forget_project(Path(path))
            return False
        self.set_document(ProjectDocument(project))
        settings.remember_project(Path(path))
        settings.set_last_folder(Path(path))
        log.info("opened %s (%d lines)", path, len(project.lines))
        return True

    def save(self) -> bool:
        if self.document.path is None:
            return self.save_as()
        return self._save_to(self.document.path)

    def save_as(self, path: Path | None = None) -> bool:
        if path is None:
            chosen, _ = QFileDialog.getSaveFileName(self, "Save the project as",
                                                    settings.last_folder(), PROJECT_FILTER)
            if not chosen:
                return False
            path = Path(chosen)
            if not path.suffix:
                path = path.with_suffix(".h5")
        return self._save_to(Path(path))

    def _save_to(self, path: Path) -> bool:
        try:
            saved = self.document.save(path)
        except (UserError, OSError) as exc:
            show_error(self, "Cannot save the project", str(exc))
            return False
        settings.remember_project(saved)
        settings.set_last_folder(saved)
        self.status_text.setText(f"saved {saved.name}")
        return True

    def write_report(self, pdf_path: Path | None = None) -> ReportDialog | None:
        """File ▸ Report (PDF)…: the report describes the saved project file (it names it with
        its checksum), so unsaved changes are saved first — after asking. The dialog takes the
        certificate fields, the overall decision and where to write; the report is gathered in
        a worker and laid out on the GUI thread (Qt's text layout must run there)."""
        if not self.document.line_names():
            show_error(self, "Calibration report", "The project has no measured lines yet: "
                       "import the logs first (File ▸ Import logs…).")
            return None
        if self.document.path is None or not self.document.is_clean:
            answer = QMessageBox.question(
                self, "Calibration report",
                "The report describes the saved project: it names the file and its checksum. "
                "Save the project now?",
                QMessageBox.StandardButton.Save | QMessageBox.StandardButton.Cancel)
            if answer != QMessageBox.StandardButton.Save or not self.save():
                return None
        project_path = self.document.path
        assert project_path is not None
        from volucal.core.report_content import default_compensation_dir

        dialog = ReportDialog(
            Certificate.of_project(self.document.project),
            Path(pdf_path) if pdf_path is not None else project_path.with_suffix(".pdf"),
            default_compensation_dir(self.document.project, project_path), self)
        dialog.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        dialog.accepted.connect(lambda: self._report_chosen(dialog))
        self.report_dialog = dialog
        dialog.open()
        return dialog

    def _report_chosen(self, dialog: ReportDialog) -> None:
        certificate = dialog.certificate()
        if certificate.to_json() != Certificate.of_project(self.document.project).to_json():
            self.document.put_results("edit the certificate",
                                      {("report", "certificate"): certificate.to_tree()})
            if not self.save():
                return
        project = self.document.path
        assert project is not None
        quantity, tolerance = dialog.conformance()
        comparison = self.views["comparison"]
        assert isinstance(comparison, ComparisonView)
        from volucal.core.report_content import ReportRequest, build_report

        request = ReportRequest(
            project_path=project, compensation_dir=dialog.compensation_dir(),
            tolerance_um=tolerance, tolerance_on=quantity or "accuracy",
            units=settings.display_units(), remeasurement_path=comparison.after_path)
        target = dialog.pdf_path()

        def render(content: object) -> None:
            from .report import write_content

            try:
                written = write_content(content, target)  # type: ignore[arg-type]
            except UserError as exc:
                show_error(self, "Calibration report", str(exc))
                return
            self.last_report = written.path
            self.status_text.setText(f"report written: {written.path.name} "
                                     f"({written.pages} pages)")
            log.info("report written: %s (%d pages)", written.path, written.pages)

        self.runner.run(
            "calibration report",
            lambda progress, cancel: build_report(request),
            render,
            lambda message: show_error(self, "Calibration report", message),
            lambda text: show_bug(self, "Calibration report", text),
        )

    def edit_tolerances(self) -> TolerancesDialog:
        """Edit ▸ Tolerances per axis…: the ISO 230-2 limits, an undoable edit."""
        dialog = TolerancesDialog(Tolerances.of_project(self.document.project),
                                  settings.display_units(), self)
        dialog.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)

        def apply() -> None:
            tolerances = dialog.result_tolerances
            if tolerances is None:
                return
            self.document.put_results("edit the tolerances",
                                      {("report", "tolerances"): tolerances.to_tree()})

        dialog.accepted.connect(apply)
        dialog.open()
        return dialog

    def open_remeasurement(self, path: Path | None = None) -> bool:
        """File ▸ Open a re-measurement…: shown beside this project in the Before/after view."""
        view = self.show_view("comparison")
        assert isinstance(view, ComparisonView)
        if path is None:
            view.open_dialog()
            return view.after_project is not None
        return view.open_remeasurement(Path(path))

    def export_plots(self, folder: Path | None = None) -> list[Path]:
        """File ▸ Export the plots of this view…: PNG, SVG and CSV of each into a folder."""
        if folder is None:
            chosen = QFileDialog.getExistingDirectory(self, "Export the plots into",
                                                      settings.last_folder())
            if not chosen:
                return []
            folder = Path(chosen)
        view = self.stack.currentWidget()
        assert view is not None
        try:
            written = plots.export_view(view, Path(folder), prefix=view.objectName())
        except (UserError, OSError) as exc:
            show_error(self, "Export the plots", str(exc))
            return []
        settings.set_last_folder(Path(folder))
        self.status_text.setText(f"{len(written)} file(s) written into {Path(folder).name}")
        return written

    def set_units(self, kind: str, key: str) -> None:
        """View ▸ Units: the units every view (and the report) shows values in."""
        units = replace(settings.display_units(), **{kind: key})
        settings.set_display_units(units)
        self.unit_actions[(kind, key)].setChecked(True)
        for view in self.views.values():
            view.set_units(units)

    def user_guide(self) -> UserGuide | None:
        try:
            guide = UserGuide(self)
        except UserError as exc:
            show_error(self, "User guide", str(exc))
            return None
        guide.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        guide.show()
        return guide

    # ---- importing -----------------------------------------------------------------------------

    def import_logs(self, paths: list[Path] | None = None) -> ImportWizard:
        """Open the import wizard (on ``paths`` when given)."""
        wizard = ImportWizard(self.document.machine, paths or [], self,
                              existing_lines=self.document.line_names())
        wizard.accepted.connect(lambda: self._apply_import(wizard))
        wizard.finished.connect(lambda _r: wizard.deleteLater())
        self.wizard = wizard
        wizard.open()
        return wizard

    def _apply_import(self, wizard: ImportWizard) -> None:
        result = wizard.imported
        if result is None:
            return
        try:
            self.document.import_lines(result,
                                       replace=wizard.plan_page.replace_existing.isChecked())
        except UserError as exc:
            show_error(self, "Cannot add the lines", str(exc))
            return
        self.status_text.setText(f"imported {len(result.lines)} line(s)")
        self.show_view("measurement")

    def dragEnterEvent(self, event: QDragEnterEvent) -> None:
        if event.mimeData().hasUrls():
            event.acceptProposedAction()

    def dropEvent(self, event: QDropEvent) -> None:
        paths = [Path(u.toLocalFile()) for u in event.mimeData().urls() if u.isLocalFile()]
        event.acceptProposedAction()
        self.open_paths(paths)

    def open_paths(self, paths: list[Path]) -> None:
        """Dropped files: a project is opened, log files and plans go to the import wizard."""
        projects = [p for p in paths if p.suffix.lower() in (".h5", ".hdf5")]
        logs = [p for p in paths if p not in projects]
        if projects:
            self.open_project(projects[0])
        if logs:
            self.import_logs(logs)

    # ---- the demo --------------------------------------------------------------------------------

    def open_demo(self) -> None:
        """Open the demo project, calibrating the embedded demo data first if not cached."""
        path = jobs.demo_project_path(cache_folder())
        if path.is_file():
            self.open_project(path)
            return
        if not self.maybe_discard():
            return
        n = settings.Preferences.load().sensitivity_n
        self.status_text.setText("calibrating the demo data (once; about a minute)…")
        self.runner.run(
            "demo project",
            ProcessCall(jobs.build_demo_project, (path, n)),
            self._demo_built,
            lambda message: show_error(self, "Demo project", message),
            lambda text: show_bug(self, "Demo project", text),
        )

    def _demo_built(self, demo: jobs.DemoProject) -> None:
        try:
            document = ProjectDocument(Project.open(demo.path))
        except UserError as exc:
            show_error(self, "Demo project", str(exc))
            return
        document.live.update(demo.loop.live())
        record = document.sensitivity("main")
        document.live[("sensitivity", "main")] = Live(demo.sensitivity, SensitivityRecord(
            "main", record.indices, demo.sensitivity, record.setup))
        self.set_document(document)
        settings.remember_project(demo.path)
        log.info("demo project ready: %s", demo.path)

    # ---- views -----------------------------------------------------------------------------------

    def show_view(self, key: str, name: str | None = None) -> View:
        view = self.views[key]
        self.stack.setCurrentWidget(view)
        if name is not None:
            view.select(name)
        return view

    def show_item(self, kind: str, name: str) -> None:
        self.show_view(KIND_VIEW.get(kind, "machine"), name or None)

    def _run_in(self, key: str, method: str) -> None:
        view = self.show_view(key)
        try:
            getattr(view, method)()
        except UserError as exc:
            show_error(self, view.title, str(exc))

    def identify(self) -> None:
        self._run_in("identification", "run")

    def close_loop(self) -> None:
        self._run_in("loop", "run")

    def sensitivity(self) -> None:
        self._run_in("sensitivity", "run")

    def compensation(self) -> None:
        self._run_in("compensation", "run_preview")

    def preferences(self) -> PreferencesDialog:
        dialog = PreferencesDialog(self)
        dialog.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        dialog.open()
        return dialog

    # ---- tasks ---------------------------------------------------------------------------------

    def _task_started(self, task: Task) -> None:
        self._tasks.append(task)
        task.progressed.connect(lambda f, m, t=task: self._task_progress(t, f, m))
        task.ended.connect(lambda t=task: self._task_ended(t))
        self._task_progress(task, 0.0, "started")

    def _task_progress(self, task: Task, fraction: float, message: str) -> None:
        self.progress.setVisible(True)
        self.cancel_button.setVisible(True)
        self.progress.setValue(int(round(100 * fraction)))
        self.status_text.setText(f"{task.title}: {message}")

    def _task_ended(self, task: Task) -> None:
        if task in self._tasks:
            self._tasks.remove(task)
        if not self._tasks:
            self.progress.setVisible(False)
            self.cancel_button.setVisible(False)
            if self.status_text.text().startswith(f"{task.title}:"):
                # (a result callback may have written its own message: it stays)
                self.status_text.setText(f"{task.title}: {task.outcome or 'stopped'}")

    @property
    def busy(self) -> bool:
        return bool(self._tasks)

    def cancel_tasks(self) -> None:
        for task in list(self._tasks):
            task.cancel()

    # ---- closing ---------------------------------------------------------------------------------

    def closeEvent(self, event: QCloseEvent) -> None:
        if not self.maybe_discard():
            event.ignore()
            return
        if self.wizard is not None and shiboken6.isValid(self.wizard):
            self.wizard.runner.shutdown()
        for runner in [self.runner] + [v.runner for v in self.views.values()]:
            runner.shutdown()
        self._tasks.clear()
        # Dropped tasks stop at their next cancel check; wait so that no thread outlives the
        # window's objects.
        wait_for_all(30_000)
        self.log_panel.detach()
        super().closeEvent(event)
