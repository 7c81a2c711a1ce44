"""The import wizard: files → preview → plan → import.

1. Files: log files (.rtl, .rta, tables, captures) and/or a plan.toml, added with the buttons or
   dropped on the page.
2. Preview: every file is read with the core's readers (in a worker): targets, runs by
   direction, environment and the problems found (outlier flags, notes). A file the core cannot
   read shows the core's message (file and line); the wizard goes no further until it is removed.
3. Plan: the machine and, for each file, where the line was measured (start, direction,
   quantity, sensitive direction, reflector offset, sign), with a three-view sketch of the lines
   in the workspace; a plan.toml can be loaded or saved here.
4. Import: :func:`volucal.core.io.plan.import_plan` in a worker; the result goes to the project
   only when the wizard is finished (one undoable edit).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtGui import QDragEnterEvent, QDropEvent
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QListWidget,
    QMessageBox,
    QProgressBar,
    QPushButton,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
    QWizard,
    QWizardPage,
)
from volucal.core.io.plan import (
    ImportResult,
    LineImport,
    OutsideFolderError,
    import_line,
    import_plan,
    load_plan,
    write_plan,
)
from volucal.core.machine import AXES, Machine, MachineError
from volucal.core.measurement import LineSpec, Plan, PlanError, target_positions
from volucal.core.progress import CancelToken, ProgressCallback, check, report
from volucal.core.userror import UserError

from . import plots
from .dialogs import show_bug, show_error
from .plan_rows import LineRow, guess_spec, unique_names
from .plan_sketch import PlanSketch, SketchLine
from .settings import Preferences, last_folder, set_last_folder
from .tasks import TaskRunner

LOG_FILTER = ("Laser logs and tables (*.rtl *.rta *.rtx *.csv *.txt *.dat *.tsv *.prn *.iso);;"
              "Plans (*.toml);;All files (*)")
PLAN_SUFFIX = ".toml"


@dataclass(frozen=True, eq=False)
class FilePreview:
    """One file as the core reads it, or the core's message when it cannot."""

    path: Path
    spec: LineSpec
    line: LineImport | None
    error: str | None


def preview_files(specs: Sequence[LineSpec], progress: ProgressCallback | None = None,
                  cancel: CancelToken | None = None) -> list[FilePreview]:
    """Read every file with its (proposed) plan entry; a file that fails keeps its message."""
    out = []
    for index, spec in enumerate(specs):
        check(cancel)
        report(progress, index / max(len(specs), 1), f"reading {Path(spec.file or '').name}")
        try:
            out.append(FilePreview(Path(spec.file or ""), spec, import_line(spec), None))
        except UserError as exc:
            out.append(FilePreview(Path(spec.file or ""), spec, None, str(exc)))
    report(progress, 1.0, "read")
    return out


def read_plan(parent: QWidget, path: Path, use: Callable[[Plan], None]) -> None:
    """Read a plan.toml and hand it to ``use``. A plan whose files lie outside its own folder is
    read only once the user allows the folder that holds them (the command line's
    ``--files-root``): a plan from elsewhere must not make volucal read any file it names."""

    def attempt(root: Path | None) -> None:
        try:
            plan = load_plan(path, files_root=root)
        except OutsideFolderError as exc:
            own = Path(path).resolve().parent
            folder = Path(os.path.commonpath([own, exc.real.parent]))
            if root is not None and folder == root:
                show_error(parent, "Cannot read the plan", str(exc))
                return
            box = QMessageBox(
                QMessageBox.Icon.Question, "Files outside the plan's folder",
                f"The plan {Path(path).name} reads {exc.real}, outside its own folder {own}.\n\n"
                "volucal reads a plan's files only from the plan's folder unless you allow "
                f"another. Allow the files under {folder}?",
                QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.No, parent,
            )
            box.setObjectName("outsideFolderDialog")
            box.setDefaultButton(QMessageBox.StandardButton.No)

            def answered(_: int) -> None:
                if box.clickedButton() is box.button(QMessageBox.StandardButton.Yes):
                    attempt(folder)

            box.finished.connect(answered)
            box.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
            box.open()
            return
        except UserError as exc:
            show_error(parent, "Cannot read the plan", str(exc))
            return
        use(plan)

    attempt(None)


class ImportWizard(QWizard):
    """File ▸ Import logs… ``imported`` holds the ImportResult once the wizard is finished."""

    def __init__(self, machine: Machine | None = None, paths: Sequence[Path] = (),
                 parent: QWidget | None = None, existing_lines: Sequence[str] = ()) -> None:
        super().__init__(parent)
        self.setObjectName("importWizard")
        self.setWindowTitle("Import laser logs")
        self.setWizardStyle(QWizard.WizardStyle.ClassicStyle)
        self.setOption(QWizard.WizardOption.NoBackButtonOnLastPage, True)
        self.resize(1100, 760)
        self.project_machine = machine
        #: Lines the project already has: a name among them is refused on the Plan page unless
        #: the user chooses to replace them.
        self.existing_lines = frozenset(existing_lines)
        self.runner = TaskRunner(self)
        self.base_plan: Plan | None = None
        self.specs: dict[str, LineSpec] = {}
        self.previews: list[FilePreview] = []
        self.plan: Plan | None = None
        self.imported: ImportResult | None = None
        self.files_page = FilesPage()
        self.preview_page = PreviewPage()
        self.plan_page = PlanPage()
        self.import_page = ImportPage()
        for page in (self.files_page, self.preview_page, self.plan_page, self.import_page):
            self.addPage(page)
        if paths:
            self.files_page.add_paths(list(paths))

    @property
    def default_machine(self) -> Machine:
        if self.base_plan is not None:
            return self.base_plan.machine
        return self.project_machine or Machine()

    def load_plan_file(self, path: Path, done: Callable[[Plan], None] | None = None) -> None:
        """Use a plan.toml: its machine and its lines (and their files); ``done`` follows once
        it is read (after the user allowed a folder, if the plan reads files outside its own)."""

        def use(plan: Plan) -> None:
            self.base_plan = plan
            for spec in plan.lines:
                self.specs[str(Path(spec.file or "").resolve())] = spec
            set_last_folder(Path(path))
            if done is not None:
                done(plan)

        read_plan(self, path, use)

    def add_log(self, path: Path) -> None:
        key = str(path.resolve())
        if key not in self.specs:
            self.specs[key] = guess_spec(path, self.default_machine)

    def remove_file(self, key: str) -> None:
        self.specs.pop(key, None)

    def done(self, result: int) -> None:
        # closing the wizard (finished or cancelled) drops whatever is still being read
        self.runner.shutdown()
        super().done(result)


# --------------------------------------------------------------------------------------------
# 1. Files
# --------------------------------------------------------------------------------------------


class FilesPage(QWizardPage):
    def __init__(self) -> None:
        super().__init__()
        self.setTitle("Files")
        self.setSubTitle("Add the laser logs to import, or a plan.toml that lists them (drop "
                         "files here too).")
        self.setAcceptDrops(True)
        self.list = QListWidget()
        self.list.setObjectName("fileList")
        self.list.setSelectionMode(QListWidget.SelectionMode.ExtendedSelection)
        self.plan_label = QLabel("No plan: each file's place in the machine is set on the "
                                 "Plan page.")
        self.plan_label.setWordWrap(True)
        add = QPushButton("Add log files…")
        add.clicked.connect(self._add_dialog)
        plan = QPushButton("Load plan.toml…")
        plan.clicked.connect(self._plan_dialog)
        remove = QPushButton("Remove")
        remove.clicked.connect(self._remove_selected)
        buttons = QHBoxLayout()
        for b in (add, plan, remove):
            buttons.addWidget(b)
        buttons.addStretch(1)
        layout = QVBoxLayout(self)
        layout.addLayout(buttons)
        layout.addWidget(self.list, 1)
        layout.addWidget(self.plan_label)

    def wizard(self) -> ImportWizard:  # type: ignore[override]
        return super().wizard()  # type: ignore[return-value]

    def add_paths(self, paths: Sequence[Path]) -> None:
        """Add files; a .toml among them is loaded as the plan."""
        wizard = self.wizard()
        for path in paths:
            path = Path(path)
            if path.suffix.lower() == PLAN_SUFFIX:

                def shown(plan: Plan, path: Path = path) -> None:
                    self.plan_label.setText(f"Plan: {path} ({len(plan.lines)} lines)")
                    self._fill()

                wizard.load_plan_file(path, shown)
            elif path.is_file():
                wizard.add_log(path)
                set_last_folder(path)
            else:
                show_error(self, "Cannot add the file", f"{path}: no such file")
        self._fill()

    def _fill(self) -> None:
        self.list.clear()
        for key in self.wizard().specs:
            self.list.addItem(key)
        self.completeChanged.emit()

    def _add_dialog(self) -> None:
        paths, _ = QFileDialog.getOpenFileNames(self, "Laser logs", last_folder(), LOG_FILTER)
        self.add_paths([Path(p) for p in paths])

    def _plan_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Plan", last_folder(), "Plans (*.toml)")
        if path:
            self.add_paths([Path(path)])

    def _remove_selected(self) -> None:
        for item in self.list.selectedItems():
            self.wizard().remove_file(item.text())
        self._fill()

    def isComplete(self) -> bool:
        return bool(self.wizard() and self.wizard().specs)

    def dragEnterEvent(self, event: QDragEnterEvent) -> None:
        if event.mimeData().hasUrls():
            event.acceptProposedAction()

    def dropEvent(self, event: QDropEvent) -> None:
        self.add_paths([Path(u.toLocalFile()) for u in event.mimeData().urls()
                        if u.isLocalFile()])
        event.acceptProposedAction()


# --------------------------------------------------------------------------------------------
# 2. Preview
# --------------------------------------------------------------------------------------------

PREVIEW_COLUMNS = ("file", "format", "quantity", "targets", "runs ↑/↓", "environment",
                   "problems")


class PreviewPage(QWizardPage):
    def __init__(self) -> None:
        super().__init__()
        self.setTitle("Preview")
        self.setSubTitle("What the files hold, as volucal reads them. Files with an error must "
                         "be removed (or fixed) before going on.")
        self.table = QTableWidget(0, len(PREVIEW_COLUMNS))
        self.table.setObjectName("previewTable")
        self.table.setHorizontalHeaderLabels(list(PREVIEW_COLUMNS))
        self.table.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.table.setSelectionBehavior(QTableWidget.SelectionBehavior.SelectRows)
        self.table.verticalHeader().setVisible(False)
        self.table.itemSelectionChanged.connect(self._plot_selected)
        self.plot = plots.make_plot("Deviations as read", "target (mm)", "deviation")
        self.problems = QLabel()
        self.problems.setObjectName("previewProblems")
        self.problems.setWordWrap(True)
        self.problems.setAlignment(Qt.AlignmentFlag.AlignTop | Qt.AlignmentFlag.AlignLeft)
        self.problems.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.progress = QProgressBar()
        self.remove_broken = QPushButton("Remove the files that cannot be read")
        self.remove_broken.setObjectName("removeBroken")
        self.remove_broken.clicked.connect(self._remove_broken)
        self.remove_broken.setEnabled(False)
        splitter = QSplitter(Qt.Orientation.Vertical)
        splitter.addWidget(self.table)
        lower = QWidget()
        lower_layout = QHBoxLayout(lower)
        lower_layout.setContentsMargins(0, 0, 0, 0)
        lower_layout.addWidget(self.plot, 2)
        lower_layout.addWidget(self.problems, 1)
        splitter.addWidget(lower)
        layout = QVBoxLayout(self)
        layout.addWidget(self.progress)
        layout.addWidget(splitter, 1)
        layout.addWidget(self.remove_broken)
        self._done = False

    def wizard(self) -> ImportWizard:  # type: ignore[override]
        return super().wizard()  # type: ignore[return-value]

    def initializePage(self) -> None:
        wizard = self.wizard()
        self._done = False
        self.table.setRowCount(0)
        self.plot.clear()
        self.problems.setText("reading the files…")
        specs = list(wizard.specs.values())
        task = wizard.runner.run(
            "preview of the files",
            lambda progress, cancel: preview_files(specs, progress, cancel),
            self._previewed,
            on_failure=lambda message: show_error(self, "Preview", message),
            on_crash=lambda text: show_bug(self, "Preview", text),
        )
        task.progressed.connect(lambda f, _m: self.progress.setValue(int(100 * f)))

    def cleanupPage(self) -> None:
        self.wizard().runner.cancel_all()

    def _previewed(self, previews: list[FilePreview]) -> None:
        wizard = self.wizard()
        wizard.previews = previews
        self.progress.setValue(100)
        self._done = True
        self.table.setRowCount(len(previews))
        broken = 0
        for row, item in enumerate(previews):
            cells = [item.path.name] + (_preview_cells(item) if item.line is not None else
                                        ["—", item.spec.quantity, "—", "—", "—", item.error or ""])
            for column, text in enumerate(cells):
                cell = QTableWidgetItem(text)
                cell.setToolTip(str(item.path) if column == 0 else text)
                if item.error:
                    cell.setForeground(Qt.GlobalColor.red)
                self.table.setItem(row, column, cell)
            broken += item.error is not None
        self.table.resizeColumnsToContents()
        self.remove_broken.setEnabled(broken > 0)
        if broken:
            self.problems.setText(f"{broken} file(s) cannot be read; select one to see why.")
            first = next(p for p in previews if p.error)
            show_error(self, "A file cannot be read", first.error or "")
        else:
            self.problems.setText(f"{len(previews)} file(s) read. Select one to see it.")
        if previews:
            self.table.selectRow(0)
        self.completeChanged.emit()

    def _remove_broken(self) -> None:
        wizard = self.wizard()
        for item in wizard.previews:
            if item.error is not None:
                wizard.remove_file(str(item.path.resolve()))
        wizard.previews = [p for p in wizard.previews if p.error is None]
        wizard.files_page._fill()
        self._previewed(wizard.previews)

    def _plot_selected(self) -> None:
        self.plot.clear()
        rows = self.table.selectionModel().selectedRows()
        previews = self.wizard().previews
        if not rows or rows[0].row() >= len(previews):
            return
        item = previews[rows[0].row()]
        if item.line is None:
            self.problems.setText(item.error or "")
            return
        data = item.line.raw
        plot = self.plot.getPlotItem()
        unit = plots.unit_label(item.line.raw_unit)
        plot.setTitle(f"{item.path.name}: deviations as in the file", size="10pt")
        plot.setLabel("left", f"deviation ({unit})")
        # where the file puts its targets: the plan's start is not yet this line's
        positions = target_positions(data.targets_mm, origin_mm=data.origin_mm)
        plot.setLabel("bottom", positions.axis_title)
        for run in range(data.runs):
            colour = plots.FORWARD if data.run_direction[run] > 0 else plots.BACKWARD
            plot.addItem(pg.PlotDataItem(positions.values_mm, data.deviations[run],
                                         pen=plots.pen(colour, 1.0)))
        lines = [f"<b>{item.path.name}</b>: {item.line.format}, {item.line.readings} readings"]
        lines += [f"note: {n}" for n in item.line.notes]
        lines += [f"correction: {c}" for c in item.line.corrections]
        lines += [f"outlier: {f.reason} (run {f.run}, target {f.target})"
                  for f in item.line.flags[:20]]
        if len(item.line.flags) > 20:
            lines.append(f"… and {len(item.line.flags) - 20} more outlier flags")
        self.problems.setText("<br>".join(lines))

    def isComplete(self) -> bool:
        wizard = self.wizard()
        return self._done and bool(wizard.previews) and all(
            p.error is None for p in wizard.previews)


def _preview_cells(item: FilePreview) -> list[str]:
    assert item.line is not None
    data = item.line.raw
    env = data.environment
    up = int(np.sum(data.run_direction > 0))
    down = int(np.sum(data.run_direction < 0))
    parts = []
    if env.air_temp_c is not None:
        parts.append(f"air {env.air_temp_c[0]:.2f} °C")
    if env.air_pressure_kpa is not None:
        parts.append(f"{env.air_pressure_kpa[0]:.1f} kPa")
    if env.air_humidity_pct is not None:
        parts.append(f"{env.air_humidity_pct[0]:.0f} %RH")
    if env.material_temp_c:
        parts.append(f"material {env.material_temp_c[0][0]:.2f} °C")
    problems = []
    if item.line.flags:
        problems.append(f"{len(item.line.flags)} outlier flag(s)")
    problems += list(item.line.notes)
    # where the file puts its targets, as the preview plot draws them
    positions = target_positions(data.targets_mm, origin_mm=data.origin_mm).values_mm
    span = f"{positions.min():g} … {positions.max():g} mm" if positions.size else "—"
    return [item.line.format, item.spec.quantity, f"{data.targets_mm.size} ({span})",
            f"{up} / {down}", ", ".join(parts) or "not logged", "; ".join(problems) or "none"]


# --------------------------------------------------------------------------------------------
# 3. Plan
# --------------------------------------------------------------------------------------------

PLAN_COLUMNS = ("name", "file", "quantity", "start (mm)", "direction", "sensitive",
                "reflector (mm)", "sign", "env. corrected")
QUANTITY_COLUMN, SIGN_COLUMN, ENV_COLUMN = 2, 7, 8
TEXT_COLUMNS = {0: "name", 3: "start", 4: "direction", 5: "sensitive", 6: "reflector"}


class PlanPage(QWizardPage):
    def __init__(self) -> None:
        super().__init__()
        self.setTitle("Plan")
        self.setSubTitle("Where each line was measured. Vectors are 'x, y, z'; the reflector is "
                         "the optics position relative to the spindle gauge point.")
        self.name = QLineEdit()
        self.chain = QLineEdit()
        self.stroke = {a: (_spin(), _spin()) for a in AXES}
        self.tool = [_spin() for _ in AXES]
        self.leads = [_spin(0.0, 1000.0) for _ in AXES]
        form = QFormLayout()
        form.addRow("name", self.name)
        form.addRow("chain (workpiece → tool)", self.chain)
        for axis, (low, high) in self.stroke.items():
            row = QHBoxLayout()
            row.addWidget(low)
            row.addWidget(QLabel("to"))
            row.addWidget(high)
            form.addRow(f"stroke {axis}", row)
        tool_row, lead_row = QHBoxLayout(), QHBoxLayout()
        for box in self.tool:
            tool_row.addWidget(box)
        for box in self.leads:
            box.setSpecialValueText("—")
            lead_row.addWidget(box)
        form.addRow("tool offset (mm)", tool_row)
        form.addRow("screw leads X Y Z (mm)", lead_row)
        machine_box = QGroupBox("Machine")
        machine_box.setLayout(form)
        self.table = QTableWidget(0, len(PLAN_COLUMNS))
        self.table.setObjectName("planTable")
        self.table.setHorizontalHeaderLabels(list(PLAN_COLUMNS))
        self.table.verticalHeader().setVisible(False)
        self.table.itemChanged.connect(lambda _i: self._changed())
        self.table.itemSelectionChanged.connect(self._row_selected)
        self.sketch = PlanSketch()
        self.sketch.lineClicked.connect(self._select_row)
        load = QPushButton("Load plan.toml…")
        load.clicked.connect(self._load_dialog)
        save = QPushButton("Save plan.toml…")
        save.clicked.connect(self._save_dialog)
        self.drop_outliers = QCheckBox("leave out readings flagged as outliers")
        self.drop_outliers.setChecked(Preferences.load().drop_outliers)
        self.replace_existing = QCheckBox("replace the project's lines of the same name")
        self.replace_existing.setObjectName("replaceExisting")
        self.replace_existing.setToolTip("their readings are replaced by these; Edit ▸ Undo "
                                         "brings them back")
        self.replace_existing.setVisible(False)
        self.replace_existing.toggled.connect(lambda _c: self._changed())
        self.error = QLabel()
        self.error.setObjectName("planError")
        self.error.setWordWrap(True)
        self.error.setStyleSheet("color: #c00000")
        buttons = QHBoxLayout()
        buttons.addWidget(load)
        buttons.addWidget(save)
        buttons.addWidget(self.drop_outliers)
        buttons.addStretch(1)
        upper = QSplitter(Qt.Orientation.Horizontal)
        upper.addWidget(machine_box)
        upper.addWidget(self.table)
        upper.setStretchFactor(1, 3)
        splitter = QSplitter(Qt.Orientation.Vertical)
        splitter.addWidget(upper)
        splitter.addWidget(self.sketch)
        layout = QVBoxLayout(self)
        layout.addLayout(buttons)
        layout.addWidget(splitter, 1)
        layout.addWidget(self.error)
        layout.addWidget(self.replace_existing)
        for box in (*self.tool, *self.leads, *[b for pair in self.stroke.values() for b in pair]):
            box.valueChanged.connect(lambda _v: self._changed())
        self.name.textChanged.connect(lambda _t: self._changed())
        self.chain.textChanged.connect(lambda _t: self._changed())
        self._filling = False
        self._valid = False

    def wizard(self) -> ImportWizard:  # type: ignore[override]
        return super().wizard()  # type: ignore[return-value]

    # ---- filling -------------------------------------------------------------------------------

    def initializePage(self) -> None:
        wizard = self.wizard()
        self._set_machine(wizard.default_machine)
        rows = [LineRow.from_spec(p.spec) for p in wizard.previews]
        unique_names(rows)
        self._set_rows(rows)
        self._changed()

    def _set_machine(self, machine: Machine) -> None:
        self._filling = True
        self.name.setText(machine.name)
        self.chain.setText(machine.chain)
        for axis, (low, high) in self.stroke.items():
            low.setValue(machine.stroke(axis)[0])
            high.setValue(machine.stroke(axis)[1])
        for box, value in zip(self.tool, machine.tool_offset_mm, strict=True):
            box.setValue(value)
        for box, axis in zip(self.leads, AXES, strict=True):
            box.setValue(machine.screw_lead_mm.get(axis, 0.0))
        self._filling = False

    def _set_rows(self, rows: list[LineRow]) -> None:
        self._filling = True
        self.table.setRowCount(len(rows))
        for r, row in enumerate(rows):
            for column, key in TEXT_COLUMNS.items():
                self.table.setItem(r, column, QTableWidgetItem(getattr(row, key)))
            file_item = QTableWidgetItem(Path(row.file).name)
            file_item.setFlags(file_item.flags() & ~Qt.ItemFlag.ItemIsEditable)
            file_item.setToolTip(row.file)
            file_item.setData(Qt.ItemDataRole.UserRole, row)
            self.table.setItem(r, 1, file_item)
            quantity = QComboBox()
            quantity.addItems(["linear", "straightness", "angular"])
            quantity.setCurrentText(row.quantity)
            quantity.currentTextChanged.connect(lambda _t: self._changed())
            self.table.setCellWidget(r, QUANTITY_COLUMN, quantity)
            sign = QComboBox()
            sign.addItems(["+1", "−1"])
            sign.setCurrentIndex(0 if row.sign > 0 else 1)
            sign.setToolTip("+1: the file's deviation is measured − nominal; −1 flips it")
            sign.currentIndexChanged.connect(lambda _i: self._changed())
            self.table.setCellWidget(r, SIGN_COLUMN, sign)
            env = QTableWidgetItem()
            env.setFlags((env.flags() | Qt.ItemFlag.ItemIsUserCheckable)
                         & ~Qt.ItemFlag.ItemIsEditable)
            env.setCheckState(Qt.CheckState.Checked if row.env_corrected else
                              Qt.CheckState.Unchecked)
            env.setToolTip("checked: the laser software already applied air and material "
                           "temperature compensation")
            self.table.setItem(r, ENV_COLUMN, env)
        self.table.resizeColumnsToContents()
        self._filling = False

    def rows(self) -> list[LineRow]:
        out = []
        for r in range(self.table.rowCount()):
            base: LineRow = self._cell(r, 1).data(Qt.ItemDataRole.UserRole)
            quantity = self.table.cellWidget(r, QUANTITY_COLUMN)
            sign = self.table.cellWidget(r, SIGN_COLUMN)
            assert isinstance(quantity, QComboBox) and isinstance(sign, QComboBox)
            values = {key: self._cell(r, c).text() for c, key in TEXT_COLUMNS.items()}
            out.append(LineRow(
                file=base.file,
                quantity=quantity.currentText(),
                sign=1 if sign.currentIndex() == 0 else -1,
                env_corrected=self._cell(r, ENV_COLUMN).checkState() == Qt.CheckState.Checked,
                deviation_unit=base.deviation_unit,
                reader=base.reader,
                **values,
            ))
        return out

    def _cell(self, row: int, column: int) -> QTableWidgetItem:
        item = self.table.item(row, column)
        assert item is not None, "every cell of the plan table holds an item"
        return item

    def set_cell(self, row: int, field: str, text: str) -> None:
        """Edit a text cell (name, start, direction, sensitive, reflector) as the user does."""
        column = next(c for c, key in TEXT_COLUMNS.items() if key == field)
        self._cell(row, column).setText(text)

    def set_quantity(self, row: int, quantity: str) -> None:
        self.table.cellWidget(row, QUANTITY_COLUMN).setCurrentText(quantity)  # type: ignore[attr-defined]

    # ---- building the plan ---------------------------------------------------------------------

    def machine(self) -> Machine:
        leads = {a: box.value() for a, box in zip(AXES, self.leads, strict=True)
                 if box.value() > 0}
        default = self.wizard().default_machine
        return Machine(
            name=self.name.text().strip() or "machine",
            chain=self.chain.text(),
            stroke_mm={a: (low.value(), high.value()) for a, (low, high) in self.stroke.items()},
            screw_lead_mm=leads,
            tool_offset_mm=tuple(b.value() for b in self.tool),  # type: ignore[arg-type]
            reference_mm=default.reference_mm if _same_strokes(default, self.stroke) else None,
        )

    def build_plan(self) -> Plan:
        """The plan the page describes; raises PlanError/MachineError naming the field."""
        machine = self.machine()
        specs = tuple(row.to_spec() for row in self.rows())
        base = self.wizard().base_plan
        if base is not None and base.machine == machine and specs == base.lines:
            return base
        uncertainty = dict(base.uncertainty) if base is not None else {}
        return Plan(machine, specs, None, uncertainty)

    def _changed(self) -> None:
        if self._filling:
            return
        try:
            plan = self.build_plan()
        except (PlanError, MachineError) as exc:
            self.error.setText(str(exc))
            self._valid = False
            self._draw(None)
        else:
            problem = self.project_conflict(plan)
            self.error.setText(problem)
            self._valid = not problem
            self._draw(plan)
        self.completeChanged.emit()

    def clashes(self, plan: Plan) -> list[str]:
        """Line names of the plan the project already has."""
        existing = self.wizard().existing_lines
        return [spec.name for spec in plan.lines if spec.name in existing]

    def project_conflict(self, plan: Plan) -> str:
        """Why the project cannot take these lines as they are (another machine, names it
        already has and replacing them not chosen), or ""."""
        wizard = self.wizard()
        project_machine = wizard.project_machine
        if project_machine is not None and wizard.existing_lines and \
                project_machine != plan.machine:
            return (f"These lines are of another machine than the project's "
                    f"({project_machine.name!r}: chain, strokes, tool offset and screw leads "
                    "must be the same). Import them into a new project (File ▸ New project).")
        clashes = self.clashes(plan)
        self.replace_existing.setVisible(bool(clashes))
        if clashes and not self.replace_existing.isChecked():
            shown = ", ".join(clashes[:6]) + (" …" if len(clashes) > 6 else "")
            return (f"The project already has {len(clashes)} line(s) of these names: {shown}. "
                    "Rename them in the table (the name column), or check “replace the "
                    "project's lines of the same name”.")
        return ""

    def _draw(self, plan: Plan | None) -> None:
        if plan is None:
            return
        lengths = {p.spec.name: float(np.nanmax(p.line.raw.targets_mm))
                   for p in self.wizard().previews if p.line is not None and
                   p.line.raw.targets_mm.size}
        by_file = {p.spec.file: lengths.get(p.spec.name, 0.0) for p in self.wizard().previews}
        lines = [SketchLine(s.name, s.quantity, s.start_mm, s.direction,
                            by_file.get(s.file, 0.0)) for s in plan.lines]
        self.sketch.set_plan(dict(plan.machine.stroke_mm), lines, self.sketch.selected)

    def _row_selected(self) -> None:
        rows = self.table.selectionModel().selectedRows()
        if rows:
            item = self.table.item(rows[0].row(), 0)
            self.sketch.select(item.text() if item else None)

    def _select_row(self, name: str) -> None:
        for r in range(self.table.rowCount()):
            if self._cell(r, 0).text() == name:
                self.table.selectRow(r)
                return

    def isComplete(self) -> bool:
        return self._valid and self.table.rowCount() > 0

    def validatePage(self) -> bool:
        try:
            plan = self.build_plan()
        except (PlanError, MachineError) as exc:
            self.error.setText(str(exc))
            return False
        problem = self.project_conflict(plan)
        if problem:
            self.error.setText(problem)
            return False
        self.wizard().plan = plan
        return True

    # ---- plan files ----------------------------------------------------------------------------

    def _load_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Plan", last_folder(), "Plans (*.toml)")
        if path:
            self.load(Path(path))

    def load(self, path: Path) -> None:
        """Take the machine and, for the files listed here, the lines of a plan.toml."""
        read_plan(self, path, self._use_plan)

    def _use_plan(self, plan: Plan) -> None:
        wizard = self.wizard()
        wizard.base_plan = plan
        by_file = {str(Path(s.file or "").resolve()): s for s in plan.lines}
        rows = []
        for row in self.rows():
            spec = by_file.get(str(Path(row.file).resolve()))
            rows.append(LineRow.from_spec(spec) if spec is not None else row)
        self._set_machine(plan.machine)
        self._set_rows(rows)
        self._changed()

    def _save_dialog(self) -> None:
        path, _ = QFileDialog.getSaveFileName(self, "Save the plan", last_folder(),
                                              "Plans (*.toml)")
        if path:
            self.save(Path(path))

    def save(self, path: Path) -> None:
        try:
            plan = self.build_plan()
            write_plan(path, plan)
        except (UserError, OSError) as exc:
            show_error(self, "Cannot save the plan", str(exc))


def _same_strokes(machine: Machine, boxes: dict[str, tuple[QDoubleSpinBox, QDoubleSpinBox]]
                  ) -> bool:
    return all(math.isclose(machine.stroke(a)[0], low.value()) and
               math.isclose(machine.stroke(a)[1], high.value()) for a, (low, high) in
               boxes.items())


def _spin(low: float = -5000.0, high: float = 5000.0) -> QDoubleSpinBox:
    box = QDoubleSpinBox()
    box.setRange(low, high)
    box.setDecimals(3)
    return box


# --------------------------------------------------------------------------------------------
# 4. Import
# --------------------------------------------------------------------------------------------


class ImportPage(QWizardPage):
    def __init__(self) -> None:
        super().__init__()
        self.setTitle("Import")
        self.setSubTitle("Every line is read, converted to µm/µrad with volucal's sign and, "
                         "where asked, corrected for the environment.")
        self.progress = QProgressBar()
        self.summary = QLabel()
        self.summary.setObjectName("importSummary")
        self.summary.setWordWrap(True)
        self.summary.setAlignment(Qt.AlignmentFlag.AlignTop)
        layout = QVBoxLayout(self)
        layout.addWidget(self.progress)
        layout.addWidget(self.summary, 1)
        self.setFinalPage(True)

    def wizard(self) -> ImportWizard:  # type: ignore[override]
        return super().wizard()  # type: ignore[return-value]

    def initializePage(self) -> None:
        wizard = self.wizard()
        wizard.imported = None
        plan = wizard.plan
        assert plan is not None
        drop = wizard.plan_page.drop_outliers.isChecked()
        self.summary.setText("importing…")
        task = wizard.runner.run(
            "import",
            lambda progress, cancel: import_plan(plan, drop_outliers=drop, progress=progress,
                                                 cancel=cancel),
            self._imported,
            on_failure=self._failed,
            on_crash=lambda text: show_bug(self, "Import", text),
        )
        task.progressed.connect(lambda f, _m: self.progress.setValue(int(100 * f)))

    def cleanupPage(self) -> None:
        self.wizard().runner.cancel_all()
        self.wizard().imported = None

    def _imported(self, result: ImportResult) -> None:
        self.wizard().imported = result
        self.progress.setValue(100)
        readings = sum(line.readings for line in result.lines)
        lines = [f"<b>{len(result.lines)} line(s), {readings} readings</b> ready; press Finish "
                 "to add them to the project (Edit ▸ Undo takes them out again)."]
        lines += [f"{line.name}: {c}" for line in result.lines for c in line.corrections]
        lines += [f"{line.name}: {n}" for line in result.lines for n in line.notes]
        if result.flags:
            lines.append(f"{len(result.flags)} outlier flag(s)" + (
                " applied (readings left out)" if result.outliers_dropped else
                " (readings kept; the Preview page lists them)"))
        self.summary.setText("<br>".join(lines))
        self.completeChanged.emit()

    def _failed(self, message: str) -> None:
        self.summary.setText(f"<span style='color:#c00000'>{message}</span>")
        show_error(self, "Import failed", message)
        self.completeChanged.emit()

    def isComplete(self) -> bool:
        return self.wizard() is not None and self.wizard().imported is not None
