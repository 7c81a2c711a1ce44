"""Before/after view: a re-measurement of the compensated machine beside the original.

File ▸ Open a re-measurement… reads another project (the same lines measured again once the
compensation is loaded) without changing the open one. The view pairs the lines
(:func:`volucal.core.remeasurement.compare`), draws the chosen line's bidirectional mean and
±2s band before and after, lists its ISO 230-2 values before and after with the improvement, and
gives per axis the compensation rates of the measured lines.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QComboBox,
    QFileDialog,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QPushButton,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)
from volucal.core.measurement import target_positions
from volucal.core.project import Project
from volucal.core.remeasurement import KEYS, Comparison, LinePair, compare
from volucal.core.userror import UserError

from . import plots
from .dialogs import show_error
from .document import ProjectDocument
from .settings import last_folder, set_last_folder
from .view_base import View

AFTER = "#2ca02c"
BEFORE = "#1f77b4"
AXIS_COLUMNS = ("axis", "lines", "RMS of x̄: before → after", "rate %",
                "range of x̄: before → after", "rate %", "A: before → after", "rate %")
SHORT_NAMES = {"A": "A (accuracy)", "E": "E (systematic)", "R": "R (repeatability)",
               "B": "B (reversal)", "M": "M (mean bidirectional)"}


class ComparisonView(View):
    title = "Before/after"

    def __init__(self, document: ProjectDocument, parent: QWidget | None = None) -> None:
        super().__init__(document, parent)
        self.setObjectName("comparisonView")
        self.after_project: Project | None = None
        self.after_path: Path | None = None
        self.comparison: Comparison | None = None
        self.source = QLabel()
        self.source.setObjectName("remeasurementSource")
        self.open_button = QPushButton("Open a re-measurement…")
        self.open_button.setObjectName("openRemeasurement")
        self.open_button.clicked.connect(self.open_dialog)
        self.line_box = QComboBox()
        self.line_box.setObjectName("comparisonLine")
        self.line_box.setMinimumContentsLength(18)
        self.line_box.currentTextChanged.connect(self._show_line)
        top = QHBoxLayout()
        top.addWidget(self.open_button)
        top.addWidget(self.source, 1)
        top.addWidget(QLabel("Line"))
        top.addWidget(self.line_box)

        self.plot = plots.make_plot("Before and after compensation", "target (mm)",
                                    "deviation (µm)")
        self.plot.setObjectName("comparisonPlot")
        plots.add_legend(self.plot.getPlotItem())
        self.values = QTableWidget(len(KEYS), 4)
        self.values.setObjectName("comparisonValues")
        self.values.setHorizontalHeaderLabels(["ISO 230-2", "before", "after", "improvement"])
        self.values.verticalHeader().setVisible(False)
        self.values.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.values.horizontalHeader().setSectionResizeMode(0, QHeaderView.ResizeMode.Stretch)
        self.values.setMinimumWidth(380)
        self.axes = QTableWidget(0, len(AXIS_COLUMNS))
        self.axes.setObjectName("comparisonRates")
        self.axes.setHorizontalHeaderLabels(list(AXIS_COLUMNS))
        self.axes.verticalHeader().setVisible(False)
        self.axes.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.rates_plot = plots.make_plot("Compensation rate of the measured lines per axis",
                                          None, "rate (%)")
        self.rates_plot.setObjectName("comparisonRatesPlot")
        plots.add_legend(self.rates_plot.getPlotItem())
        self.note = QLabel()
        self.note.setWordWrap(True)

        upper = QSplitter(Qt.Orientation.Horizontal)
        upper.addWidget(self.plot)
        upper.addWidget(self.values)
        upper.setStretchFactor(0, 3)
        upper.setStretchFactor(1, 1)
        lower = QSplitter(Qt.Orientation.Horizontal)
        lower.addWidget(self.axes)
        lower.addWidget(self.rates_plot)
        lower.setStretchFactor(0, 3)
        lower.setStretchFactor(1, 2)
        splitter = QSplitter(Qt.Orientation.Vertical)
        splitter.addWidget(upper)
        splitter.addWidget(lower)
        splitter.setStretchFactor(0, 3)
        splitter.setStretchFactor(1, 2)
        layout = QVBoxLayout(self)
        layout.addLayout(top)
        layout.addWidget(splitter, 1)
        layout.addWidget(self.note)

    # ---- the re-measurement ----------------------------------------------------------------

    def open_dialog(self) -> None:
        chosen, _ = QFileDialog.getOpenFileName(
            self, "Re-measurement of the compensated machine", last_folder(),
            "volucal projects (*.h5 *.hdf5);;All files (*)")
        if chosen:
            self.open_remeasurement(Path(chosen))

    def open_remeasurement(self, path: Path) -> bool:
        """Read ``path`` as the re-measurement; a project the core refuses shows its message."""
        try:
            project = Project.open(path)
            if not project.lines:
                raise UserError(f"{path}: the project has no measured lines")
        except UserError as exc:
            show_error(self, "Cannot open the re-measurement", str(exc))
            return False
        self.after_project = project
        self.after_path = Path(path)
        set_last_folder(Path(path))
        self._document_changed()
        return True

    def set_document(self, document: ProjectDocument) -> None:
        # a re-measurement belongs to the project it was opened beside
        self.after_project = None
        self.after_path = None
        self.comparison = None
        super().set_document(document)

    # ---- showing -------------------------------------------------------------------------------

    def refresh(self) -> None:
        self.comparison = None
        current = self.line_box.currentText()
        self.line_box.blockSignals(True)
        self.line_box.clear()
        self.line_box.blockSignals(False)
        self.axes.setRowCount(0)
        self.rates_plot.clear()
        if self.after_project is None or not self.document.project.lines:
            self.source.setText("no re-measurement open" if self.document.project.lines else
                                "import the original measurement first")
            self.note.setText("Open the project of the same lines measured again on the "
                              "compensated machine to see both.")
            self._show_line("")
            return
        self.comparison = compare(self.document.measurement().lines,
                                  self.after_project.measurement().lines)
        names = [p.name for p in self.comparison.pairs]
        self.source.setText(f"re-measurement: {self.after_path.name if self.after_path else ''}"
                            f" — {len(names)} line(s) paired")
        self.line_box.blockSignals(True)
        self.line_box.addItems(names)
        self.line_box.blockSignals(False)
        self._fill_axes(self.comparison)
        unmatched = self.comparison.unmatched
        self.note.setText(
            "Lines are paired by place (quantity, start, direction); rates are "
            "100·(1 − after/before) of the measured lines' bidirectional mean deviation x̄."
            + (f" Not in the original: {', '.join(unmatched)}." if unmatched else ""))
        if names:
            self.line_box.setCurrentText(current if current in names else names[0])
        self._show_line(self.line_box.currentText())

    def select(self, name: str | None) -> None:
        if self._stale:
            self._refresh_now()
        if name:
            self.line_box.setCurrentText(name)

    def _show_line(self, name: str) -> None:
        item = self.plot.getPlotItem()
        item.clear()
        self.values.clearContents()
        if self.comparison is None or self.after_project is None or not name:
            item.setTitle("Before and after compensation", size="10pt")
            return
        pair = self.comparison.pair(name)
        unit = pair.before.unit
        symbol = self.units.symbol(unit)
        item.setTitle(f"{name}: bidirectional mean x̄ ± 2s before and after", size="10pt")
        item.setLabel("left", f"deviation ({symbol})")
        # each curve at its own line's positions: the re-measurement may name its lines apart
        specs = (self.document.project.lines[pair.name].spec,
                 self.after_project.lines[pair.after_name].spec)
        for which, result, colour, spec in (("before", pair.before, BEFORE, specs[0]),
                                            ("after", pair.after, AFTER, specs[1])):
            positions = target_positions(result.targets_mm, spec)
            item.setLabel("bottom", positions.axis_title)
            x = positions.values_mm
            s = np.fmax(result.s_up, result.s_down)
            mean = self.units.convert(result.mean, unit)
            spread = self.units.convert(2.0 * s, unit)
            plots.add_band(item, x, mean - spread, mean + spread, colour, 40)
            item.addItem(pg.PlotDataItem(x, mean, pen=plots.pen(colour, 2.2),
                                         name=f"{which}: x̄ ± 2s"))
        self._fill_values(pair)

    def _fill_values(self, pair: LinePair) -> None:
        unit = pair.before.unit
        for row, key in enumerate(KEYS):
            improvement = pair.improvement_percent(key)
            cells = [SHORT_NAMES[key], self.units.text(pair.value(key, "before"), unit),
                     self.units.text(pair.value(key, "after"), unit),
                     "—" if math.isnan(improvement) else f"{improvement:.1f} %"]
            for column, text in enumerate(cells):
                cell = QTableWidgetItem(text)
                if column:
                    cell.setTextAlignment(Qt.AlignmentFlag.AlignRight
                                          | Qt.AlignmentFlag.AlignVCenter)
                self.values.setItem(row, column, cell)

    def _fill_axes(self, comparison: Comparison) -> None:
        self.axes.setRowCount(len(comparison.axes))
        for row, rates in enumerate(comparison.axes):
            cells = [rates.axis, str(len(rates.lines)),
                     self._arrow(rates.rms_before_um, rates.rms_after_um),
                     _percent(rates.rms_percent),
                     self._arrow(rates.range_before_um, rates.range_after_um),
                     _percent(rates.range_percent),
                     self._arrow(rates.accuracy_before_um, rates.accuracy_after_um),
                     _percent(rates.accuracy_percent)]
            for column, text in enumerate(cells):
                cell = QTableWidgetItem(text)
                cell.setToolTip(", ".join(rates.lines))
                self.axes.setItem(row, column, cell)
        self.axes.resizeColumnsToContents()
        item = self.rates_plot.getPlotItem()
        axes = [r.axis for r in comparison.axes]
        x = np.arange(len(axes), dtype=float)
        for k, (label, values) in enumerate((
                ("RMS-based", [r.rms_percent for r in comparison.axes]),
                ("range-based", [r.range_percent for r in comparison.axes]),
                ("accuracy A", [r.accuracy_percent for r in comparison.axes]))):
            item.addItem(pg.BarGraphItem(x=x - 0.27 + 0.27 * k, height=np.nan_to_num(values),
                                         width=0.25, brush=plots.brush(plots.color(k), 190),
                                         name=label))
        plots.category_ticks(item.getAxis("bottom"), axes)


    def _arrow(self, before: float, after: float) -> str:
        return (f"{self.units.text(before, 'um', with_symbol=False)} → "
                f"{self.units.text(after, 'um')}")


def _percent(value: float) -> str:
    return "—" if math.isnan(value) else f"{value:.1f}"
