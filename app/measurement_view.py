"""Measurement view: one line's deviations by run and direction with the ISO 230-2 figures.

The plot shows every run (forward blue, backward red), the mean of each direction, the
bidirectional mean and the ISO 230-2 band x̄ ± 2s of both directions; beside it the figures A, E,
R, B, M and their unidirectional forms (ISO 230-2 clause 2, :mod:`volucal.core.iso230_2`) with the
axis' tolerances and their pass/fail (:mod:`volucal.core.tolerances`), the per-target table and
where the values came from; below it the environment logged during the line, against time.
Deviations are shown in the chosen units (View ▸ Units).
"""

from __future__ import annotations

import math

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtGui import QColor
from PySide6.QtWidgets import (
    QComboBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QScrollArea,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)
from volucal.core.conformance import CONFORMS
from volucal.core.iso230_2 import Iso230Result, evaluate
from volucal.core.measurement import Line, LineData, TargetPositions, target_positions
from volucal.core.tolerances import ToleranceCheck, Tolerances, check_line

from . import jobs, plots
from .document import ProjectDocument
from .view_base import View

FIGURES = (
    ("A", "accuracy A"), ("E", "systematic positioning error E"), ("R", "repeatability R"),
    ("B", "reversal value B"), ("M", "mean bidirectional error M"),
    ("A_up", "accuracy A↑"), ("A_down", "accuracy A↓"), ("E_up", "systematic E↑"),
    ("E_down", "systematic E↓"), ("R_up", "repeatability R↑"), ("R_down", "repeatability R↓"),
    ("mean_reversal", "mean reversal B̄"),
)
FIGURE_COLUMNS = ("ISO 230-2", "value", "limit", "result")
TARGET_COLUMNS = ("target mm", "x̄↑", "x̄↓", "x̄", "s↑", "s↓", "B", "R")
PASS_COLOR = "#1e7b34"
FAIL_COLOR = "#b3261e"


class MeasurementView(View):
    title = "Measurement"

    def __init__(self, document: ProjectDocument, parent: QWidget | None = None) -> None:
        super().__init__(document, parent)
        self.setObjectName("measurementView")
        self.line_box = QComboBox()
        self.line_box.setObjectName("lineBox")
        self.line_box.setMinimumContentsLength(18)
        self.values_box = QComboBox()
        self.values_box.addItems(["corrected (measured − nominal)", "raw (as in the file)"])
        self.line_box.currentTextChanged.connect(self._show_line)
        self.values_box.currentIndexChanged.connect(lambda _i: self._show_line(
            self.line_box.currentText()))
        top = QHBoxLayout()
        top.addWidget(QLabel("Line"))
        top.addWidget(self.line_box, 1)
        top.addWidget(QLabel("Values"))
        top.addWidget(self.values_box)
        top.addStretch(1)

        self.plot = plots.make_plot("Deviation", "target (mm)", "deviation (µm)")
        self.plot.setObjectName("deviationPlot")
        plots.add_legend(self.plot.getPlotItem())
        self.env_plot = plots.make_plot("Environment", "time since the line's start (min)",
                                        "temperature (°C)")
        plots.add_legend(self.env_plot.getPlotItem())
        self.env_text = QLabel()
        self.env_text.setWordWrap(True)

        self.figures = QTableWidget(len(FIGURES), len(FIGURE_COLUMNS))
        self.figures.setObjectName("isoFigures")
        self.figures.setHorizontalHeaderLabels(list(FIGURE_COLUMNS))
        self.figures.verticalHeader().setVisible(False)
        self.figures.verticalHeader().setDefaultSectionSize(22)
        self.figures.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.figures.setVerticalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.figures.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        header = self.figures.horizontalHeader()
        header.setSectionResizeMode(0, QHeaderView.ResizeMode.Stretch)
        for column in range(1, len(FIGURE_COLUMNS)):
            header.setSectionResizeMode(column, QHeaderView.ResizeMode.ResizeToContents)
        # every value visible at the window's default size: the table is as tall as its rows
        self.figures.setMinimumHeight(22 * len(FIGURES) + header.sizeHint().height() + 4)
        self.verdict = QLabel()
        self.verdict.setObjectName("toleranceVerdict")
        self.verdict.setWordWrap(True)
        self.targets = QTableWidget(0, len(TARGET_COLUMNS))
        self.targets.setObjectName("perTarget")
        self.targets.setHorizontalHeaderLabels(list(TARGET_COLUMNS))
        self.targets.verticalHeader().setVisible(False)
        self.targets.verticalHeader().setDefaultSectionSize(20)
        self.targets.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.info = QLabel()
        self.info.setObjectName("lineInfo")
        self.info.setWordWrap(True)
        self.info.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.info.setAlignment(Qt.AlignmentFlag.AlignTop)
        info_scroll = QScrollArea()
        info_scroll.setWidgetResizable(True)
        info_scroll.setWidget(self.info)

        figures_page = QWidget()
        figures_layout = QVBoxLayout(figures_page)
        figures_layout.setContentsMargins(2, 2, 2, 2)
        figures_layout.addWidget(self.figures)
        figures_layout.addWidget(self.verdict)
        figures_layout.addStretch(1)
        self.side = QTabWidget()
        self.side.setObjectName("measurementTabs")
        self.side.addTab(figures_page, "ISO 230-2")
        self.side.addTab(self.targets, "Per target")
        self.side.addTab(info_scroll, "Source")
        self.side.setMinimumWidth(380)

        left = QSplitter(Qt.Orientation.Vertical)
        left.addWidget(self.plot)
        env = QWidget()
        env_layout = QVBoxLayout(env)
        env_layout.setContentsMargins(0, 0, 0, 0)
        env_layout.addWidget(self.env_plot, 1)
        env_layout.addWidget(self.env_text)
        left.addWidget(env)
        left.setStretchFactor(0, 3)
        left.setStretchFactor(1, 1)
        splitter = QSplitter(Qt.Orientation.Horizontal)
        splitter.addWidget(left)
        splitter.addWidget(self.side)
        splitter.setStretchFactor(0, 1)
        splitter.setStretchFactor(1, 0)
        splitter.setCollapsible(1, False)
        layout = QVBoxLayout(self)
        layout.addLayout(top)
        layout.addWidget(splitter, 1)
        self.result: Iso230Result | None = None
        self.checks: list[ToleranceCheck] = []

    # ---- refresh ---------------------------------------------------------------------------

    def refresh(self) -> None:
        current = self.line_box.currentText()
        names = self.document.line_names()
        self.line_box.blockSignals(True)
        self.line_box.clear()
        self.line_box.addItems(names)
        self.line_box.blockSignals(False)
        if names:
            self.line_box.setCurrentText(current if current in names else names[0])
        self._show_line(self.line_box.currentText())

    def select(self, name: str | None) -> None:
        if name and name in self.document.line_names():
            if self._stale:
                self._refresh_now()
            self.line_box.setCurrentText(name)

    # ---- one line ------------------------------------------------------------------------------

    def _show_line(self, name: str) -> None:
        self.plot.clear()
        self.env_plot.clear()
        self.result = None
        self.checks = []
        self.verdict.clear()
        self.targets.setRowCount(0)
        item = self.plot.getPlotItem()
        if not name or name not in self.document.project.lines:
            self.figures.clearContents()
            item.setTitle("Deviation", size="10pt")
            self.info.setText("No line: import log files with File ▸ Import logs…")
            self.env_text.clear()
            return
        stored = self.document.project.lines[name]
        raw = self.values_box.currentIndex() == 1
        data = stored.raw if raw else stored.corrected
        unit = stored.raw_unit if raw else stored.spec.unit
        self.result = evaluate(data, unit)
        if not raw:
            self.checks = check_line(Line(stored.spec, data),
                                     Tolerances.of_project(self.document.project),
                                     jobs.budget_of(self.document.project), self.result)
        positions = target_positions(data.targets_mm, stored.spec)
        self._plot_runs(data, self.result, unit, stored.spec.quantity, positions)
        self._fill_figures(self.result, unit)
        self._fill_targets(self.result, unit, positions)
        self._fill_info(name)
        self._plot_environment(data)

    def shown_unit(self, unit: str) -> str:
        """The symbol values stored in ``unit`` are shown in (a raw file unit as it is)."""
        return self.units.symbol(unit) if unit in ("um", "urad") else plots.unit_label(unit)

    def shown(self, values: np.ndarray, unit: str) -> np.ndarray:
        return self.units.convert(values, unit) if unit in ("um", "urad") else np.asarray(values)

    def _text(self, value: float, unit: str) -> str:
        if unit in ("um", "urad"):
            return self.units.text(value, unit)
        return "—" if not math.isfinite(value) else f"{value:.4g} {plots.unit_label(unit)}"

    def _plot_runs(self, data: LineData, result: Iso230Result, unit: str, quantity: str,
                   positions: TargetPositions) -> None:
        item = self.plot.getPlotItem()
        what = {"linear": "positioning deviation", "straightness": "straightness deviation",
                "angular": "angular deviation"}[quantity]
        item.setTitle(f"{what} — {self.line_box.currentText()}", size="10pt")
        item.setLabel("left", f"deviation ({self.shown_unit(unit)})")
        item.setLabel("bottom", positions.axis_title)
        x = positions.values_mm
        up = result.mean_up + 2 * result.s_up
        down = result.mean_down + 2 * result.s_down
        high = np.fmax(up, down)
        low = np.fmin(result.mean_up - 2 * result.s_up, result.mean_down - 2 * result.s_down)
        plots.add_band(item, x, self.shown(low, unit), self.shown(high, unit))
        for run in range(data.runs):
            forward = data.run_direction[run] > 0
            colour = plots.FORWARD if forward else plots.BACKWARD
            item.addItem(pg.PlotDataItem(x, self.shown(data.deviations[run], unit),
                                         pen=plots.pen(colour, 0.8, alpha=110)))
        item.addItem(pg.PlotDataItem(x, self.shown(result.mean_up, unit),
                                     pen=plots.pen(plots.FORWARD, 2.2),
                                     name=f"mean ↑ ({result.runs_up} runs)"))
        item.addItem(pg.PlotDataItem(x, self.shown(result.mean_down, unit),
                                     pen=plots.pen(plots.BACKWARD, 2.2),
                                     name=f"mean ↓ ({result.runs_down} runs)"))
        item.addItem(pg.PlotDataItem(x, self.shown(result.mean, unit),
                                     pen=plots.pen("#000000", 1.6, dashed=True),
                                     name="bidirectional mean"))
        legend_band = pg.PlotDataItem([], [], pen=plots.pen(plots.BAND, 6, alpha=80),
                                      name="x̄ ± 2s band")
        item.addItem(legend_band)

    def _fill_figures(self, result: Iso230Result, unit: str) -> None:
        checks = {c.quantity: c for c in self.checks}
        for row, (key, text) in enumerate(FIGURES):
            value = getattr(result, f"{key}_um")
            check = checks.get(key)
            cells = [text, self._text(value, unit),
                     "" if check is None else self._text(check.limit_um, "um"),
                     "" if check is None else check.verdict]
            for column, shown in enumerate(cells):
                cell = QTableWidgetItem(shown)
                if column:
                    cell.setTextAlignment(Qt.AlignmentFlag.AlignRight
                                          | Qt.AlignmentFlag.AlignVCenter)
                if check is not None and column == 3:
                    cell.setForeground(QColor(PASS_COLOR if check.passed else FAIL_COLOR))
                    cell.setToolTip(
                        f"ISO 14253-1 with U = {self._text(check.expanded_uncertainty_um, 'um')}"
                        f" (k = 2): {check.decision}")
                self.figures.setItem(row, column, cell)
        if self.checks:
            failed = [c for c in self.checks if not c.passed]
            axis = self.checks[0].axis
            undecided = [c for c in self.checks if c.decision != CONFORMS]
            line = self.line_box.currentText()
            text = (f"<b style='color:{FAIL_COLOR if failed else PASS_COLOR}'>{line} "
                    f"{'fails' if failed else 'passes'} the tolerances of axis {axis}</b>")
            if undecided and not failed:
                text += (" — by ISO 14253-1 (with the uncertainty U) "
                         + ", ".join(f"{c.quantity}: {c.decision}" for c in undecided))
            elif failed:
                text += " (" + ", ".join(c.quantity for c in failed) + " over the limit)"
            self.verdict.setText(text)
        else:
            self.verdict.setText("No tolerance for this line: set the limits per axis in "
                                 "Edit ▸ Tolerances…" if result.unit == "um" else "")

    def _fill_targets(self, result: Iso230Result, unit: str, positions: TargetPositions) -> None:
        columns = (result.mean_up, result.mean_down, result.mean, result.s_up, result.s_down,
                   result.reversal, result.repeatability)
        symbol = self.shown_unit(unit)
        self.targets.setHorizontalHeaderLabels(
            [positions.label] + [f"{name} {symbol}" for name in TARGET_COLUMNS[1:]])
        self.targets.setRowCount(result.targets_mm.size)
        for row, target in enumerate(positions.values_mm):
            cells = [f"{target:g}"] + [self._text(float(c[row]), unit).rsplit(" ", 1)[0]
                                       for c in columns]
            for column, shown in enumerate(cells):
                cell = QTableWidgetItem(shown)
                cell.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                self.targets.setItem(row, column, cell)
        self.targets.resizeColumnsToContents()

    def _fill_info(self, name: str) -> None:
        stored = self.document.project.lines[name]
        spec = stored.spec
        provenance = self.document.project.provenance(name)

        def vec(v: tuple[float, ...] | None) -> str:
            return "—" if v is None else "(" + ", ".join(f"{x:g}" for x in v) + ")"

        rows = [
            ("quantity", spec.quantity),
            ("start", vec(spec.start_mm) + " mm"),
            ("direction", vec(spec.direction)),
            ("sensitive", vec(spec.sensitive)),
            ("reflector", vec(spec.reflector_mm) + " mm"),
            ("file", str(provenance.get("source_file", spec.file or "—"))),
            ("format", str(provenance.get("format", "—"))),
            ("sign", str(provenance.get("sign_convention", spec.sign))),
        ]
        for key in ("corrections", "notes"):
            for text in provenance.get(key, []) or []:
                rows.append((key[:-1], str(text)))
        html = "".join(f"<tr><td><b>{k}</b></td><td>{v}</td></tr>" for k, v in rows)
        self.info.setText(f"<table>{html}</table>")

    def _plot_environment(self, data: LineData) -> None:
        item = self.env_plot.getPlotItem()
        env = data.environment
        order = np.argsort(data.times_s, axis=None)
        minutes = data.times_s.ravel()[order] / 60.0
        drawn = False
        for values, pair, name, colour in (
            (data.air_temp_c, env.air_temp_c, "air", plots.color(0)),
            (data.material_temp_c, env.material_temp_c[0] if env.material_temp_c else None,
             "material", plots.color(1)),
        ):
            if values is not None:
                y = np.asarray(values, dtype=float).ravel()[order]
            elif pair is not None:
                span = float(np.nanmax(minutes) - np.nanmin(minutes)) or 1.0
                y = pair[0] + (pair[1] - pair[0]) * (minutes - np.nanmin(minutes)) / span
            else:
                continue
            item.addItem(pg.PlotDataItem(minutes, y, pen=plots.pen(colour, 1.8),
                                         name=f"{name} temperature"))
            drawn = True
        parts = []
        if env.air_pressure_kpa is not None:
            parts.append(f"air pressure {env.air_pressure_kpa[0]:.2f} → "
                         f"{env.air_pressure_kpa[1]:.2f} kPa")
        if env.air_humidity_pct is not None:
            parts.append(f"humidity {env.air_humidity_pct[0]:.0f} → "
                         f"{env.air_humidity_pct[1]:.0f} %RH")
        if env.expansion_ppm_per_c is not None:
            parts.append(f"expansion coefficient {env.expansion_ppm_per_c:g} ppm/°C")
        if not drawn:
            parts.insert(0, "no temperatures logged with this file")
        self.env_text.setText("; ".join(parts))
