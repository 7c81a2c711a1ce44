"""Thermal view: a thermal error model against its record — error and prediction over time, the
residual, and what each sensor carries.

A standalone widget over one :class:`volucal.core.thermal_fit.ThermalFitResult` (``set_result``
shows another): the measured error (grey) and the model's prediction (blue) against time with
the end of the training part marked, the residual (measured − predicted, what compensation leaves),
the sensor weights as bars (the spread of each term's contribution over the record, in µm: how
much of the error the term carries; the coefficient alone depends on how much the sensor moves),
the terms with their coefficients and standard uncertainties, and the RMS error of the model beside
the baselines. Actions: copy the model's formula; show the held-out part only.
"""

from __future__ import annotations

import math

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtGui import QAction, QGuiApplication
from PySide6.QtWidgets import (
    QHBoxLayout,
    QLabel,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QToolBar,
    QVBoxLayout,
    QWidget,
)
from volucal.core.thermal_fit import ThermalFitResult

from . import plots

MEASURED = "#7f7f7f"
PREDICTED = "#1f77b4"
RESIDUAL = "#d62728"


class ThermalView(QWidget):
    """The widget (module notes); ``result`` None shows an empty view."""

    title = "Thermal"

    def __init__(self, result: ThermalFitResult | None = None,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("thermalView")
        self.result: ThermalFitResult | None = None

        self.copy_formula_action = QAction("Copy the model's formula", self)
        self.copy_formula_action.setObjectName("copyThermalFormula")
        self.copy_formula_action.triggered.connect(self._copy_formula)
        self.held_out_action = QAction("Show the held-out part only", self)
        self.held_out_action.setObjectName("showHeldOut")
        self.held_out_action.setCheckable(True)
        self.held_out_action.toggled.connect(self._apply_range)
        toolbar = QToolBar()
        toolbar.addAction(self.copy_formula_action)
        toolbar.addAction(self.held_out_action)

        self.summary = QLabel()
        self.summary.setObjectName("thermalSummary")
        self.summary.setWordWrap(True)
        self.summary.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)

        self.error_plot = plots.make_plot("Error and prediction", "time (h)", "error (µm)")
        self.error_plot.addLegend(offset=(10, 10))
        self.residual_plot = plots.make_plot("Residual: measured − predicted", "time (h)",
                                             "residual (µm)")
        self.residual_plot.setXLink(self.error_plot)
        self.weights_plot = plots.make_plot("Sensor weights: contribution spread", None,
                                            "spread (µm)")
        self.measured_curve = self.error_plot.plot(
            [], [], pen=plots.pen(MEASURED, 1.0), name="measured")
        self.predicted_curve = self.error_plot.plot(
            [], [], pen=plots.pen(PREDICTED, 1.6), name="predicted")
        self.residual_curve = self.residual_plot.plot([], [], pen=plots.pen(RESIDUAL, 1.0))
        self.residual_plot.addItem(pg.InfiniteLine(pos=0.0, angle=0,
                                                   pen=plots.pen("#555555", 0.8, dashed=True)))
        self.split_lines: list[tuple[pg.PlotWidget, pg.InfiniteLine]] = []
        self.weight_bars: pg.BarGraphItem | None = None

        self.terms = QTableWidget(0, 5)
        self.terms.setObjectName("thermalTerms")
        self.terms.setHorizontalHeaderLabels(
            ["term", "coefficient", "std", "unit", "spread (µm)"])
        self.metrics = QTableWidget(0, 4)
        self.metrics.setObjectName("thermalMetrics")
        self.metrics.setHorizontalHeaderLabels(["model", "training RMS", "CV RMS",
                                                "held-out RMS"])
        for table in (self.terms, self.metrics):
            table.verticalHeader().setVisible(False)
            table.horizontalHeader().setStretchLastSection(True)
            table.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)

        series = QSplitter(Qt.Orientation.Vertical)
        series.addWidget(self.error_plot)
        series.addWidget(self.residual_plot)
        series.setSizes([300, 160])
        side = QSplitter(Qt.Orientation.Vertical)
        side.addWidget(self.weights_plot)
        side.addWidget(self.terms)
        side.addWidget(self.metrics)
        body = QSplitter(Qt.Orientation.Horizontal)
        body.addWidget(series)
        body.addWidget(side)
        body.setSizes([640, 360])
        layout = QVBoxLayout(self)
        top = QHBoxLayout()
        top.addWidget(toolbar)
        top.addStretch(1)
        layout.addLayout(top)
        layout.addWidget(self.summary)
        layout.addWidget(body, 1)
        self.set_result(result)

    # ---- showing a result ------------------------------------------------------------------

    def set_result(self, result: ThermalFitResult | None) -> None:
        """Show ``result`` (None: clear the view)."""
        self.result = result
        for plot, line in self.split_lines:
            plot.removeItem(line)
        self.split_lines = []
        if self.weight_bars is not None:
            self.weights_plot.removeItem(self.weight_bars)
            self.weight_bars = None
        self.copy_formula_action.setEnabled(result is not None)
        self.held_out_action.setEnabled(result is not None and result.test_samples > 0)
        if result is None:
            self.summary.setText("No thermal model to show.")
            for curve in (self.measured_curve, self.predicted_curve, self.residual_curve):
                curve.setData([], [])
            self.terms.setRowCount(0)
            self.metrics.setRowCount(0)
            return
        unit = plots.unit_label(result.unit)
        hours = result.time_s / 3600.0
        self.error_plot.setLabel("left", f"{result.channel} ({unit})")
        self.residual_plot.setLabel("left", f"residual ({unit})")
        self.weights_plot.setLabel("left", f"spread ({unit})")
        self.measured_curve.setData(hours, result.measured)
        self.predicted_curve.setData(hours, result.predicted)
        self.residual_curve.setData(hours, result.residual)
        if result.test_samples:
            split = result.split_time_s / 3600.0
            for plot in (self.error_plot, self.residual_plot):
                line = pg.InfiniteLine(pos=split, angle=90,
                                       pen=plots.pen("#555555", 1.0, dashed=True),
                                       label="training | test",
                                       labelOpts={"position": 0.92, "color": "#555555"})
                plot.addItem(line)
                self.split_lines.append((plot, line))
        # short labels under the bars (the table below gives each term in full)
        labels = [t.sensor + ("²" if t.power == 2 else "") for t in result.model.terms]
        spreads = np.asarray(result.term_spread, dtype=float)
        self.weight_bars = pg.BarGraphItem(x=np.arange(len(labels)), height=spreads, width=0.6,
                                           brush=plots.brush(PREDICTED, 200))
        self.weights_plot.addItem(self.weight_bars)
        plots.category_ticks(self.weights_plot.getAxis("bottom"), labels)
        self._fill_terms(result)
        self._fill_metrics(result)
        self.summary.setText(self._summary_text(result))
        self._apply_range(self.held_out_action.isChecked())

    def _summary_text(self, r: ThermalFitResult) -> str:
        kind = "dynamic (first-order lags)" if r.model.dynamic else "static"
        held = (f"held-out RMS {r.test_rms:.3f} {r.symbol} (uncompensated "
                f"{r.uncompensated_test_rms:.3f})" if r.test_rms is not None
                else "no held-out part")
        return (f"{r.measurement} — {r.channel}: {len(r.model.sensors)} sensor(s) "
                f"({', '.join(r.model.sensors)}), {kind}; {held}; CV RMS {r.cv_rms:.3f} "
                f"{r.symbol}.\n{r.model.formula()}\nSign: {r.channel} = measured − nominal; a "
                "compensation applies −prediction.")

    def _fill_terms(self, r: ThermalFitResult) -> None:
        model = r.model
        rows = [("constant", model.intercept, model.intercept_std, r.symbol, math.nan)]
        rows += [(t.label(), float(c), float(s), t.unit(r.unit), w)
                 for t, c, s, w in zip(model.terms, model.coefficients, model.coefficient_std,
                                       r.term_spread, strict=True)]
        self.terms.setRowCount(len(rows))
        for i, (label, value, std, unit, spread) in enumerate(rows):
            cells = [label, f"{value:.4f}", f"{std:.4f}", unit,
                     "" if math.isnan(spread) else f"{spread:.3f}"]
            for j, text in enumerate(cells):
                item = QTableWidgetItem(text)
                if j in (1, 2, 4):
                    item.setTextAlignment(Qt.AlignmentFlag.AlignRight |
                                          Qt.AlignmentFlag.AlignVCenter)
                self.terms.setItem(i, j, item)

    def _fill_metrics(self, r: ThermalFitResult) -> None:
        rows = [(b.name if not b.name.startswith("best single") else
                 f"best single sensor ({b.sensors[0]})", b.train_rms, b.cv_rms, b.test_rms)
                for b in r.baselines]
        rows.append(("volucal model", r.train_rms, r.cv_rms, r.test_rms))
        self.metrics.setRowCount(len(rows))
        for i, row in enumerate(rows):
            for j, value in enumerate(row):
                text = value if isinstance(value, str) else (
                    "—" if value is None or math.isnan(value) else f"{value:.3f}")
                self.metrics.setItem(i, j, QTableWidgetItem(text))

    # ---- actions ---------------------------------------------------------------------------

    def _copy_formula(self) -> None:
        if self.result is not None:
            QGuiApplication.clipboard().setText(self.result.model.formula())

    def _apply_range(self, held_out_only: bool) -> None:
        r = self.result
        if r is None:
            return
        hours = r.time_s / 3600.0
        if held_out_only and r.test_samples:
            low, high = r.split_time_s / 3600.0, float(hours[-1])
        else:
            low, high = float(hours[0]), float(hours[-1])
        self.error_plot.setXRange(low, high, padding=0.01)
        if held_out_only and r.test_samples:
            part = slice(r.train_samples, None)
            values = np.concatenate([r.measured[part], r.predicted[part]])
            self.error_plot.setYRange(float(values.min()), float(values.max()), padding=0.05)
        else:
            self.error_plot.enableAutoRange(axis="y")
