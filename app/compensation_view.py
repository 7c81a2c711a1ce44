"""Compensation view: choose the controller and options, preview the tables, export.

Preview writes the export to a temporary folder with
:func:`volucal.core.compensation.export_model` (the function ``volucal export`` calls) and shows
the axis tables, the files as the controller will read them and the predicted before/after of
every compensation method on the identified model. Export writes the same files into a folder:
for the same project, identification and options they are identical to the CLI's.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtGui import QFont
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
    QPlainTextEdit,
    QPushButton,
    QSpinBox,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)
from volucal.core.compensation import ExportOptions, LargeCorrectionError
from volucal.core.compensation.export import FORMAT_HELP
from volucal.core.machine import AXES
from volucal.core.userror import UserError

from . import jobs, plots
from .document import ProjectDocument
from .records import default_identification
from .settings import Preferences, last_folder, set_last_folder
from .view_base import View

SOURCES = (
    ("effects", "21 errors + the loop's effects, as volucal export: forward/backward tables "
                "from the reversal"),
    ("model", "21 errors alone, direction-free, over the strokes"),
)
LINUXCNC_TYPES = ("type 0: actual positions reached (LinuxCNC adds nominal − actual)",
                  "type 1: offsets added to the command")


class CompensationView(View):
    title = "Compensation"

    def __init__(self, document: ProjectDocument, parent: QWidget | None = None) -> None:
        super().__init__(document, parent)
        self.setObjectName("compensationView")
        prefs = Preferences.load()
        self.preview: jobs.ExportPreview | None = None
        self.large_dialog: QMessageBox | None = None

        self.identification_box = QComboBox()
        self.identification_box.setObjectName("exportIdentification")
        self.source_box = QComboBox()
        self.source_box.setObjectName("sourceBox")
        for key, text in SOURCES:
            self.source_box.addItem(text, key)
        self.format_box = QComboBox()
        self.format_box.setObjectName("formatBox")
        for name, text in FORMAT_HELP.items():
            self.format_box.addItem(name, name)
            self.format_box.setItemData(self.format_box.count() - 1, text,
                                        Qt.ItemDataRole.ToolTipRole)
        self.format_box.currentIndexChanged.connect(self._format_changed)
        for box in (self.identification_box, self.source_box):
            box.activated.connect(lambda _i: self.clear_preview())
        self.format_help = QLabel()
        self.format_help.setWordWrap(True)
        self.format_help.setMinimumWidth(200)
        self.linuxcnc_type = QComboBox()
        self.linuxcnc_type.setObjectName("linuxcncType")
        self.linuxcnc_type.addItems(LINUXCNC_TYPES)
        for box in (self.source_box, self.linuxcnc_type, self.identification_box,
                    self.format_box):
            box.setSizeAdjustPolicy(QComboBox.SizeAdjustPolicy.AdjustToMinimumContentsLengthWithIcon)
            box.setMinimumContentsLength(16)
        self.spacing = _spin(prefs.export_spacing_mm, 0.5, 500.0, " mm")
        self.spacing.setObjectName("tableSpacing")
        self.grid_spacing = _spin(25.0, 1.0, 500.0, " mm")
        self.tool = [_spin(0.0, -2000.0, 2000.0, " mm") for _ in range(3)]
        self.tool_default = QCheckBox("the machine's")
        self.tool_default.setChecked(True)
        self.tool_default.toggled.connect(self._tool_default_toggled)
        self._tool_default_toggled(True)
        self.axis_names = QLineEdit()
        self.axis_names.setPlaceholderText("X=0,Y=1,Z=2 (controller default)")
        self.include_cross = QCheckBox("cross-axis tables where the controller has them")
        self.include_cross.setChecked(True)
        self.detection_unit = _spin(1.0, 0.001, 10.0, " µm")
        self.max_points = QSpinBox()
        self.max_points.setRange(0, 100000)
        self.max_points.setSpecialValueText("controller's limit")
        self.program = QLineEdit()
        self.program.setPlaceholderText("RS274/NGC program to rewrite (gcode)")
        browse = QPushButton("…")
        browse.clicked.connect(self._browse_program)
        program_row = QHBoxLayout()
        program_row.addWidget(self.program, 1)
        program_row.addWidget(browse)
        tool_row = QHBoxLayout()
        for t in self.tool:
            tool_row.addWidget(t)
        tool_row.addWidget(self.tool_default)

        form = QFormLayout()
        form.addRow("identification", self.identification_box)
        form.addRow("error source / directions", self.source_box)
        form.addRow("controller", self.format_box)
        form.addRow("", self.format_help)
        form.addRow("LinuxCNC convention", self.linuxcnc_type)
        form.addRow("table spacing", self.spacing)
        form.addRow("verification grid", self.grid_spacing)
        form.addRow("tool offset", tool_row)
        form.addRow("axis names", self.axis_names)
        form.addRow("", self.include_cross)
        form.addRow("Fanuc detection unit", self.detection_unit)
        form.addRow("max points", self.max_points)
        form.addRow("NC program", program_row)
        self.preview_button = QPushButton("Preview")
        self.preview_button.setObjectName("previewButton")
        self.preview_button.clicked.connect(self.run_preview)
        self.export_button = QPushButton("Export…")
        self.export_button.setObjectName("exportButton")
        self.export_button.clicked.connect(self.choose_and_export)
        self.cancel_button = self.cancel_control(self._busy)
        buttons = QHBoxLayout()
        buttons.addWidget(self.preview_button)
        buttons.addWidget(self.export_button)
        buttons.addWidget(self.cancel_button)
        self.status = QLabel()
        self.status.setObjectName("compensationStatus")
        self.status.setWordWrap(True)
        options_box = QGroupBox("Controller and options")
        options_box.setMaximumWidth(520)
        options_layout = QVBoxLayout(options_box)
        options_layout.addLayout(form)
        options_layout.addLayout(buttons)
        options_layout.addWidget(self.status)
        options_layout.addStretch(1)

        self.axis_box = QComboBox()
        self.axis_box.addItems(AXES)
        self.axis_box.currentIndexChanged.connect(lambda _i: self._show_table())
        self.table = QTableWidget(0, 5)
        self.table.setObjectName("axisTable")
        self.table.setHorizontalHeaderLabels(["position mm", "correction ↑ µm",
                                              "correction ↓ µm", "error ↑ µm", "error ↓ µm"])
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.table_plot = plots.make_plot("Axis table", "position (mm)", "correction (µm)")
        plots.add_legend(self.table_plot.getPlotItem())
        tables_page = QWidget()
        tables_layout = QVBoxLayout(tables_page)
        axis_row = QHBoxLayout()
        axis_row.addWidget(QLabel("axis"))
        axis_row.addWidget(self.axis_box)
        axis_row.addStretch(1)
        tables_layout.addLayout(axis_row)
        split = QSplitter(Qt.Orientation.Horizontal)
        split.addWidget(self.table)
        split.addWidget(self.table_plot)
        split.setStretchFactor(1, 2)
        tables_layout.addWidget(split, 1)

        self.files = QListWidget()
        self.files.setObjectName("exportFiles")
        self.files.currentTextChanged.connect(self._show_file)
        self.file_text = QPlainTextEdit()
        self.file_text.setReadOnly(True)
        self.file_text.setLineWrapMode(QPlainTextEdit.LineWrapMode.NoWrap)
        font = QFont("monospace")
        font.setStyleHint(QFont.StyleHint.TypeWriter)
        self.file_text.setFont(font)
        files_page = QSplitter(Qt.Orientation.Horizontal)
        files_page.addWidget(self.files)
        files_page.addWidget(self.file_text)
        files_page.setStretchFactor(1, 3)

        self.rates = QTableWidget(0, 4)
        self.rates.setObjectName("predictedRates")
        self.rates.setHorizontalHeaderLabels(["method", "X %", "Y %", "Z %"])
        self.rates.verticalHeader().setVisible(False)
        self.rates.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.rms_plot = plots.make_plot("Predicted RMS error per direction", None, "RMS (µm)")
        self.rms_plot.setObjectName("predictedPlot")
        plots.add_legend(self.rms_plot.getPlotItem(), columns=3)
        predicted_page = QSplitter(Qt.Orientation.Vertical)
        predicted_page.addWidget(self.rates)
        predicted_page.addWidget(self.rms_plot)
        predicted_page.setStretchFactor(1, 2)

        self.notes = QPlainTextEdit()
        self.notes.setReadOnly(True)
        self.tabs = QTabWidget()
        self.tabs.addTab(predicted_page, "Predicted before/after")
        self.tabs.addTab(tables_page, "Tables")
        self.tabs.addTab(files_page, "Files")
        self.tabs.addTab(self.notes, "Conventions and notes")

        splitter = QSplitter(Qt.Orientation.Horizontal)
        splitter.addWidget(options_box)
        splitter.addWidget(self.tabs)
        splitter.setStretchFactor(0, 1)
        splitter.setStretchFactor(1, 3)
        splitter.setSizes([430, 970])
        layout = QVBoxLayout(self)
        layout.addWidget(splitter)
        self._format_changed()

    # ---- options -------------------------------------------------------------------------------

    def _format_changed(self) -> None:
        self.clear_preview()
        name = self.format_box.currentData()
        self.format_help.setText(FORMAT_HELP.get(name, ""))
        self.linuxcnc_type.setEnabled(name == "linuxcnc")
        self.detection_unit.setEnabled(name == "fanuc")
        self.program.setEnabled(name == "gcode")
        self.include_cross.setEnabled(name in ("siemens", "heidenhain"))

    def _tool_default_toggled(self, default: bool) -> None:
        for box in self.tool:
            box.setEnabled(not default)

    def _browse_program(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "NC program to rewrite", last_folder(),
                                              "NC programs (*.ngc *.nc *.gcode *.tap);;All (*)")
        if path:
            self.program.setText(path)

    def options(self) -> ExportOptions:
        """The export options the form describes (the CLI's defaults when untouched)."""
        names = None
        text = self.axis_names.text().strip()
        if text:
            names = {}
            for item in text.split(","):
                axis, _, value = item.partition("=")
                axis = axis.strip().upper()
                if axis not in AXES or not value.strip():
                    raise UserError(f"axis names: expected X=NAME,Y=NAME,Z=NAME, got {item!r}")
                names[axis] = value.strip()
        program = self.program.text().strip()
        return ExportOptions(
            spacing_mm=self.spacing.value(),
            tool_offset_mm=None if self.tool_default.isChecked() else tuple(
                t.value() for t in self.tool),  # type: ignore[arg-type]
            grid_spacing_mm=self.grid_spacing.value(),
            axis_names=names,
            max_points=self.max_points.value() or None,
            include_cross=self.include_cross.isChecked(),
            linuxcnc_type=self.linuxcnc_type.currentIndex(),
            fanuc_detection_unit_um=self.detection_unit.value(),
            program=Path(program) if program else None,
        )

    def set_format(self, name: str) -> None:
        self.format_box.setCurrentIndex(self.format_box.findData(name))

    def _source(self) -> tuple[Any, str, bool]:
        self.ensure_fresh()
        name = self.identification_box.currentText()
        if not name:
            raise UserError("identify the errors first: there is nothing to compensate")
        with_effects = self.source_box.currentData() == "effects"
        source = jobs.export_source(self.document.project, name, with_effects)
        return source, name, with_effects

    # ---- running -------------------------------------------------------------------------------

    def run_preview(self, allow_large: bool = False) -> None:
        try:
            source, name, effects = self._source()
            options = self._with_limit(self.options(), allow_large)
        except (UserError, ValueError) as exc:
            self.task_failed(str(exc))
            return
        fmt = self.format_box.currentData()
        self.status.setText(f"computing the {fmt} tables…")
        self.run_task(
            f"{fmt} preview",
            _large_as_value(lambda progress, cancel: jobs.preview_export(
                source, fmt, options, progress, cancel)),
            lambda preview: self._ask_large(preview, lambda: self.run_preview(True))
            or self._previewed(preview, name, effects, None),
            on_cancel=lambda: self.status.setText("preview cancelled"),
        )

    def choose_and_export(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "Export compensation into", last_folder())
        if folder:
            self.export_to(Path(folder))

    def export_to(self, folder: Path, allow_large: bool = False) -> None:
        """Write the export into ``folder`` (in a worker) and record it in the project.

        Corrections beyond the plausibility limit are written only after the user confirms
        them (:meth:`_ask_large`), which exports again with ``allow_large``.
        """
        try:
            source, name, effects = self._source()
            options = self._with_limit(self.options(), allow_large)
        except (UserError, ValueError) as exc:
            self.task_failed(str(exc))
            return
        fmt = self.format_box.currentData()
        self.status.setText(f"writing the {fmt} files…")
        self.run_task(
            f"{fmt} export",
            _large_as_value(lambda progress, cancel: jobs.write_export(
                source, fmt, folder, options, progress, cancel)),
            lambda preview: self._ask_large(preview, lambda: self.export_to(folder, True))
            or self._previewed(preview, name, effects, folder),
            on_cancel=lambda: self.status.setText("export cancelled"),
        )

    @staticmethod
    def _with_limit(options: ExportOptions, allow_large: bool) -> ExportOptions:
        return dataclasses.replace(options, max_correction_um=None) if allow_large else options

    def _ask_large(self, outcome: object, again: Any) -> bool:
        """When the export was refused for large corrections, ask whether to write it anyway
        (``again`` does); True when it was refused."""
        if not isinstance(outcome, LargeCorrectionError):
            return False
        self.status.setText("not exported: corrections beyond the plausibility limit")
        points = "\n".join(f"  {c}" for c in outcome.corrections[:5])
        box = QMessageBox(
            QMessageBox.Icon.Warning, f"{self.title}: large corrections",
            f"The {outcome.format} export would apply corrections larger than "
            f"{outcome.limit_um:g} µm at {outcome.count:,} point(s), the largest:\n{points}\n\n"
            "A machine tool rarely needs that much: check the identification first. "
            "Export these corrections anyway?",
            QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.No, self,
        )
        box.setObjectName("largeCorrectionsDialog")
        box.setDefaultButton(QMessageBox.StandardButton.No)
        box.setDetailedText("\n".join(str(c) for c in outcome.corrections))

        def answered(_: int) -> None:
            if box.clickedButton() is box.button(QMessageBox.StandardButton.Yes):
                again()

        box.finished.connect(answered)
        self.large_dialog = box
        box.open()
        return True

    def _previewed(self, preview: jobs.ExportPreview, identification: str, with_effects: bool,
                   folder: Path | None) -> None:
        self.preview = preview
        result = preview.result
        if folder is not None:
            set_last_folder(folder)
            tree = jobs.compensation_tree(preview, identification, with_effects, folder)
            self.document.put_results(f"export {result.format} to {folder}",
                                      {("compensation", result.format): tree})
            self.status.setText(f"wrote {len(result.files)} file(s) into {folder}")
        else:
            self.status.setText(f"preview of the {result.format} export: {len(result.files)} "
                                "file(s), not written yet")
        self._show_preview()

    def _busy(self, busy: bool) -> None:
        self.preview_button.setEnabled(not busy)
        self.export_button.setEnabled(not busy)

    # ---- showing -------------------------------------------------------------------------------

    def set_document(self, document: ProjectDocument) -> None:
        self.clear_preview()
        self.status.clear()
        super().set_document(document)

    def refresh(self) -> None:
        current = self.identification_box.currentText()
        names = self.document.results("identifications")
        self.identification_box.clear()
        self.identification_box.addItems(names)
        wanted = current if current in names else default_identification(names)
        if wanted:
            self.identification_box.setCurrentText(wanted)
        self.preview_button.setEnabled(bool(names) and not self.runner.busy)
        self.export_button.setEnabled(bool(names) and not self.runner.busy)
        if not names:
            self.status.setText("identify the errors first: there is nothing to compensate yet")
        if self.preview is not None:  # shown again in the current units
            self._show_table()
            self._show_rates()

    def select(self, name: str | None) -> None:
        if self._stale:
            self._refresh_now()
        if name and name in self.document.results("compensation"):
            tree = self.document.tree("compensation", name)
            self.set_format(name)
            ident = str(tree.get("identification", ""))
            if ident:
                self.identification_box.setCurrentText(ident)
            folder = str(tree.get("out_dir", ""))
            self.status.setText(f"last {name} export: {folder or 'not written'} — press "
                                "Preview to see it")

    def clear_preview(self) -> None:
        """Forget the shown preview: it was of other options, identification or project."""
        if self.preview is None:
            return
        self.preview = None
        for widget in (self.files, self.file_text, self.notes):
            widget.clear()
        self.table.setRowCount(0)
        self.table_plot.clear()
        self.table_plot.getPlotItem().setTitle("Axis table", size="10pt")
        self.rates.setRowCount(0)
        self.rms_plot.clear()
        self.status.setText("press Preview to see the tables of these options")

    def _show_preview(self) -> None:
        preview = self.preview
        if preview is None:
            return
        result = preview.result
        self.files.clear()
        self.files.addItems(list(preview.texts))
        if self.files.count():
            self.files.setCurrentRow(0)
        self._show_table()
        self._show_rates()
        lines = [f"{result.format} export, tool offset {result.tool_offset_mm} mm", ""]
        lines += [f"convention: {c}" for c in result.convention]
        lines += [f"note: {n}" for n in result.notes]
        lines += [f"flag: {f}" for f in result.flags]
        self.notes.setPlainText("\n".join(lines))

    def _show_file(self, name: str) -> None:
        if self.preview is not None and name in self.preview.texts:
            self.file_text.setPlainText(self.preview.texts[name])

    def _show_table(self) -> None:
        self.table.setRowCount(0)
        self.table_plot.clear()
        if self.preview is None:
            return
        axis = self.axis_box.currentText()
        table = self.preview.result.tables.axis.get(axis)
        if table is None:
            return
        units = self.units
        symbol = units.symbol("um")
        self.table.setHorizontalHeaderLabels(
            ["position mm", f"correction ↑ {symbol}", f"correction ↓ {symbol}",
             f"error ↑ {symbol}", f"error ↓ {symbol}"])
        stored_um = (table.correction_forward_um, table.correction_backward_um,
                     table.error_forward_um, table.error_backward_um)
        columns = (table.position_mm, *(units.convert(values, "um") for values in stored_um))
        self.table.setRowCount(len(table.position_mm))
        for row in range(len(table.position_mm)):
            for column in range(len(columns)):
                text = (f"{table.position_mm[row]:g}" if column == 0 else
                        units.text(float(stored_um[column - 1][row]), "um", False, 1))
                item = QTableWidgetItem(text)
                item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                if table.beyond_range[row]:
                    item.setToolTip("beyond the measured range: the end value is held")
                    item.setForeground(Qt.GlobalColor.gray)
                self.table.setItem(row, column, item)
        item = self.table_plot.getPlotItem()
        item.setTitle(f"{axis} axis table ({self.preview.result.format})", size="10pt")
        item.setLabel("left", f"correction ({symbol})")
        item.addItem(pg.PlotDataItem(table.position_mm, columns[1],
                                     pen=plots.pen(plots.FORWARD, 2), name="correction ↑"))
        item.addItem(pg.PlotDataItem(table.position_mm, columns[2],
                                     pen=plots.pen(plots.BACKWARD, 1.5, dashed=True),
                                     name="correction ↓"))
        low, high = table.measured_range_mm
        item.addItem(pg.LinearRegionItem((low, high), movable=False,
                                         brush=plots.brush("#999999", 25)))

    def _show_rates(self) -> None:
        assert self.preview is not None
        methods = self.preview.result.verification.methods
        self.rates.setRowCount(len(methods))
        for row, (name, method) in enumerate(methods.items()):
            label = QTableWidgetItem(name)
            label.setToolTip(method.description)
            self.rates.setItem(row, 0, label)
            for column, axis in enumerate(AXES, start=1):
                value = method.rates.rms_percent[axis]
                text = "—" if not math.isfinite(value) else f"{value:.1f}"
                cell = QTableWidgetItem(text)
                cell.setToolTip(f"RMS E{axis}: {method.rates.rms_before_um[axis]:.3f} → "
                                f"{method.rates.rms_after_um[axis]:.3f} µm")
                self.rates.setItem(row, column, cell)
        self.rates.resizeColumnsToContents()
        item = self.rms_plot.getPlotItem()
        item.clear()
        first = next(iter(methods.values()))
        before = [self.units.value(first.rates.rms_before_um[a], "um") for a in AXES]
        item.setLabel("left", f"RMS ({self.units.symbol('um')})")
        x = np.arange(3, dtype=float)
        width = 0.8 / (len(methods) + 1)
        item.addItem(pg.BarGraphItem(x=x - 0.4 + width / 2, height=before, width=width,
                                     brush=plots.brush("#555555", 200), name="uncompensated"))
        for k, (name, method) in enumerate(methods.items(), start=1):
            after = [self.units.value(method.rates.rms_after_um[a], "um") for a in AXES]
            item.addItem(pg.BarGraphItem(x=x - 0.4 + width * (k + 0.5), height=after,
                                         width=width, brush=plots.brush(plots.color(k - 1), 200),
                                         name=name))
        plots.category_ticks(item.getAxis("bottom"), [f"E{a}" for a in AXES])
        item.setYRange(0.0, 1.08 * max(max(before), 1e-6), padding=0)


def _large_as_value(call: Any) -> Any:
    """The worker hands a LargeCorrectionError back as a result (the view asks the user), every
    other error as an error."""
    def run(progress: Any, cancel: Any) -> Any:
        try:
            return call(progress, cancel)
        except LargeCorrectionError as exc:
            return exc

    return run


def _spin(value: float, low: float, high: float, suffix: str) -> QDoubleSpinBox:
    box = QDoubleSpinBox()
    box.setRange(low, high)
    box.setDecimals(3)
    box.setSuffix(suffix)
    box.setValue(value)
    return box
