"""Measurement view: one line's deviations by run and direction with the ISO 230-2 figures.

The plot shows every run (forward blue, backward red), the mean of each direction, the
bidirectional mean and the ISO 230-2 band x̄ ± 2s of both directions; beside it the figures A, E,
R, B, M and their unidirectional forms (ISO 230-2 clause 2, :mod:`volucal.core.iso230_2`); below
it the environment logged during the line, against time.
"""

from __future__ import annotations

import math

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QComboBox,
    QHBoxLayout,
    QLabel,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)
from volucal.core.iso230_2 import Iso230Result, evaluate
from volucal.core.measurement import LineData

from . import plots
from .document import ProjectDocument
from .view_base import View

FIGURES = (
    ("A", "accuracy A"), ("E", "systematic positioning error E"), ("R", "repeatability R"),
    ("B", "reversal value B"), ("M", "mean bidirectional positioning error M"),
    ("A_up", "accuracy A↑"), ("A_down", "accuracy A↓"), ("E_up", "systematic E↑"),
    ("E_down", "systematic E↓"), ("R_up", "repeatability R↑"), ("R_down", "repeatability R↓"),
    ("mean_reversal", "mean reversal B̄"),
)


class MeasurementView(View):
    title = "Measurement"

    def __init__(self, document: ProjectDocument, parent: QWidget | None = None) -> None:
        super().__init__(document, parent)
        self.setObjectName("measurementView")
        self.line_box = QComboBox()
        self.line_box.setObjectName("lineBox")
        self.line_box.setMinimumContentsLength(18)
        self.values_box = QComboBox()
        self.values_box.addItems(["corrected (µm / µrad, measured − nominal)",
                                  "raw (as in the file)"])
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
        self.plot.addLegend(offset=(10, 10))
        self.env_plot = plots.make_plot("Environment", "time since the line's start (min)",
                                        "temperature (°C)")
        self.env_plot.addLegend(offset=(10, 10))
        self.env_text = QLabel()
        self.env_text.setWordWrap(True)
        self.figures = QTableWidget(len(FIGURES), 2)
        self.figures.setObjectName("isoFigures")
        self.figures.setHorizontalHeaderLabels(["ISO 230-2", "value"])
        self.figures.verticalHeader().setVisible(False)
        self.figures.horizontalHeader().setStretchLastSection(True)
        self.figures.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.info = QLabel()
        self.info.setObjectName("lineInfo")
        self.info.setWordWrap(True)
        self.info.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.info.setAlignment(Qt.AlignmentFlag.AlignTop)

        side = QWidget()
        side_layout = QVBoxLayout(side)
        side_layout.setContentsMargins(0, 0, 0, 0)
        side_layout.addWidget(self.figures, 3)
        side_layout.addWidget(self.info, 2)
        upper = QSplitter(Qt.Orientation.Horizontal)
        upper.addWidget(self.plot)
        upper.addWidget(side)
        upper.setStretchFactor(0, 3)
        upper.setStretchFactor(1, 1)
        env = QWidget()
        env_layout = QVBoxLayout(env)
        env_layout.setContentsMargins(0, 0, 0, 0)
        env_layout.addWidget(self.env_plot, 1)
        env_layout.addWidget(self.env_text)
        splitter = QSplitter(Qt.Orientation.Vertical)
        splitter.addWidget(upper)
        splitter.addWidget(env)
        splitter.setStretchFactor(0, 3)
        splitter.setStretchFactor(1, 1)
        layout = QVBoxLayout(self)
        layout.addLayout(top)
        layout.addWidget(splitter, 1)
        self.result: Iso230Result | None = None

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
        if not name or name not in self.document.project.lines:
            self.figures.clearContents()
            self.info.setText("No line: import log files with File ▸ Import logs…")
            self.env_text.clear()
            return
        stored = self.document.project.lines[name]
        raw = self.values_box.currentIndex() == 1
        data = stored.raw if raw else stored.corrected
        unit = stored.raw_unit if raw else stored.spec.unit
        self.result = evaluate(data, unit)
        self._plot_runs(data, self.result, unit, stored.spec.quantity)
        self._fill_figures(self.result, unit)
        self._fill_info(name)
        self._plot_environment(data)

    def _plot_runs(self, data: LineData, result: Iso230Result, unit: str, quantity: str) -> None:
        item = self.plot.getPlotItem()
        label = plots.unit_label(unit)
        what = {"linear": "positioning deviation", "straightness": "straightness deviation",
                "angular": "angular deviation"}[quantity]
        item.setTitle(f"{what} — {self.line_box.currentText()}", size="10pt")
        item.setLabel("left", f"deviation ({label})")
        x = data.targets_mm
        up = result.mean_up + 2 * result.s_up
        down = result.mean_down + 2 * result.s_down
        high = np.fmax(up, down)
        low = np.fmin(result.mean_up - 2 * result.s_up, result.mean_down - 2 * result.s_down)
        plots.add_band(item, x, low, high)
        for run in range(data.runs):
            forward = data.run_direction[run] > 0
            colour = plots.FORWARD if forward else plots.BACKWARD
            item.addItem(pg.PlotDataItem(x, data.deviations[run], pen=plots.pen(colour, 0.8,
                                                                                 alpha=110)))
        item.addItem(pg.PlotDataItem(x, result.mean_up, pen=plots.pen(plots.FORWARD, 2.2),
                                     name=f"mean ↑ ({result.runs_up} runs)"))
        item.addItem(pg.PlotDataItem(x, result.mean_down, pen=plots.pen(plots.BACKWARD, 2.2),
                                     name=f"mean ↓ ({result.runs_down} runs)"))
        item.addItem(pg.PlotDataItem(x, result.mean, pen=plots.pen("#000000", 1.6, dashed=True),
                                     name="bidirectional mean"))
        legend_band = pg.PlotDataItem([], [], pen=plots.pen(plots.BAND, 6, alpha=80),
                                      name="x̄ ± 2s band")
        item.addItem(legend_band)

    def _fill_figures(self, result: Iso230Result, unit: str) -> None:
        label = plots.unit_label(unit)
        for row, (key, text) in enumerate(FIGURES):
            value = getattr(result, f"{key}_um")
            self.figures.setItem(row, 0, QTableWidgetItem(text))
            shown = "—" if not math.isfinite(value) else f"{value:.3f} {label}"
            cell = QTableWidgetItem(shown)
            cell.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
            self.figures.setItem(row, 1, cell)
        self.figures.resizeColumnToContents(0)

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
