"""Identification view: the 21 error curves with their bands, identifiability, residual per line.

Each error is drawn over its stroke with the band value ± 2·u (u the standard uncertainty of the
identification: covariance and, for the positioning errors, the uncertainty budget; k = 2). An
error the plan cannot determine is drawn grey and named in the identifiability report, with the
combination the plan cannot see (:func:`volucal.core.identify.identifiability`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtGui import QPainterPath
from PySide6.QtWidgets import (
    QComboBox,
    QDoubleSpinBox,
    QGraphicsPathItem,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QPushButton,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QTabWidget,
    QTextBrowser,
    QVBoxLayout,
    QWidget,
)
from volucal.core.errors import AXIS_ERROR_IDS, COMPONENTS, ERROR_INFO, SQUARENESS_IDS, error_label
from volucal.core.machine import AXES
from volucal.core.squareness_map import place_text

from . import evidence, jobs, plots
from .document import ProjectDocument
from .engine import ProcessCall
from .records import IdentificationRecord, Live, identify_options
from .settings import Preferences
from .view_base import View

#: Coverage factor of the drawn band.
K_BAND = 2.0
#: The squareness table: the model's parameter, then the angle between the tool's paths
#: (core/squareness_map.py) at the centre of the measured volume and over it.
SQUARENESS_COLUMNS = ("squareness", "value", "U (k = 2)", "paths at centre ± U",
                      "paths lowest ± U", "paths highest ± U", "tilted by")


class IdentificationView(View):
    title = "Identification"

    def __init__(self, document: ProjectDocument, parent: QWidget | None = None) -> None:
        super().__init__(document, parent)
        self.setObjectName("identificationView")
        self.name_box = QComboBox()
        self.name_box.setObjectName("identificationBox")
        self.name_box.currentTextChanged.connect(self._show)
        self.spacing = QDoubleSpinBox()
        self.spacing.setRange(5.0, 1000.0)
        self.spacing.setSuffix(" mm")
        self.spacing.setValue(Preferences.load().identify_spacing_mm)
        self.spacing.setToolTip("knot spacing of the cubic B-spline of every error function")
        self.run_button = QPushButton("Identify")
        self.run_button.setObjectName("identifyButton")
        self.run_button.setToolTip("identify the 21 errors from the project's lines (F5)")
        self.run_button.clicked.connect(self.run)
        self.cancel_button = self.cancel_control(self._busy)
        self.summary = QLabel()
        self.summary.setObjectName("identificationSummary")
        top = QHBoxLayout()
        top.addWidget(QLabel("Identification"))
        top.addWidget(self.name_box)
        top.addWidget(QLabel("knots every"))
        top.addWidget(self.spacing)
        top.addWidget(self.run_button)
        top.addWidget(self.cancel_button)
        top.addWidget(self.summary, 1)

        self.curves = pg.GraphicsLayoutWidget()
        self.curves.setObjectName("errorCurves")
        self._plots: dict[str, pg.PlotItem] = {}
        self._curve_items: dict[str, tuple[QGraphicsPathItem, pg.PlotDataItem, pg.TextItem]] = {}
        for row, axis in enumerate(AXES):
            for column, component in enumerate(COMPONENTS):
                eid = f"E{component}{axis}"
                plot = self.curves.addPlot(row=row, col=column)
                plots.style(plot)
                plot.getAxis("left").setWidth(40)
                # few, readable ticks in a small plot
                plot.getAxis("left").setStyle(maxTickLevel=0)
                plot.getAxis("bottom").setStyle(maxTickLevel=0)
                self._plots[eid] = plot
                # kept and updated, never rebuilt: 18 plots redraw within a frame
                band = QGraphicsPathItem()
                curve = pg.PlotDataItem([], [])
                note = pg.TextItem("not identified", color="#888888", anchor=(0, 0))
                for item in (band, curve, note):
                    plot.addItem(item)
                note.hide()
                self._curve_items[eid] = (band, curve, note)

        self.squareness = QTableWidget(len(SQUARENESS_IDS), len(SQUARENESS_COLUMNS))
        self.squareness.setObjectName("squarenessTable")
        self.squareness.setHorizontalHeaderLabels(list(SQUARENESS_COLUMNS))
        self.squareness.verticalHeader().setVisible(False)
        self.squareness.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.squareness.horizontalHeader().setSectionResizeMode(
            QHeaderView.ResizeMode.ResizeToContents)
        self.squareness.horizontalHeader().setStretchLastSection(True)
        self.square_note = QLabel()
        self.square_note.setWordWrap(True)
        square_page = QWidget()
        square_layout = QVBoxLayout(square_page)
        square_layout.addWidget(self.squareness, 1)
        square_layout.addWidget(self.square_note)
        # a squareness's angle between the paths over the plane of its two axes, at one of the
        # grid's levels of the third axis
        self.square_id = QComboBox()
        self.square_id.setObjectName("squarenessMapId")
        self.square_id.currentIndexChanged.connect(self._draw_square_map)
        self.square_level = QComboBox()
        self.square_level.setObjectName("squarenessLevel")
        self.square_level.currentIndexChanged.connect(self._draw_square_map)
        self.square_plot = plots.make_plot()
        self.square_plot.setObjectName("squarenessMap")
        self.square_image = pg.ImageItem()
        self.square_plot.addItem(self.square_image)
        self.square_colorbar = pg.ColorBarItem(colorMap=pg.colormap.get("viridis"),
                                               interactive=False, width=12)
        self.square_colorbar.setImageItem(self.square_image,
                                          insert_in=self.square_plot.getPlotItem())
        plots.plain_axis(self.square_colorbar.axis)
        map_page = QWidget()
        map_layout = QVBoxLayout(map_page)
        choice = QHBoxLayout()
        choice.addWidget(QLabel("squareness"))
        choice.addWidget(self.square_id)
        choice.addWidget(QLabel("at"))
        choice.addWidget(self.square_level)
        choice.addStretch(1)
        map_layout.addLayout(choice)
        map_layout.addWidget(self.square_plot, 1)

        self.report = QTextBrowser()
        self.report.setObjectName("identifiabilityReport")
        self.lines = QTableWidget(0, 6)
        self.lines.setObjectName("residualTable")
        self.lines.setHorizontalHeaderLabels(["line", "group", "readings", "RMS", "max |r|",
                                              "unit"])
        self.lines.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.lines.setSelectionBehavior(QTableWidget.SelectionBehavior.SelectRows)
        self.lines.setSortingEnabled(True)
        self.lines.itemSelectionChanged.connect(self._show_line_residual)
        self.residual_plot = plots.make_plot("Residual", "target (mm)", "residual")
        self.residual_plot.setObjectName("residualPlot")
        plots.add_legend(self.residual_plot.getPlotItem(), columns=5)
        self.residual_note = QLabel()
        self.residual_note.setWordWrap(True)
        residual_page = QSplitter(Qt.Orientation.Horizontal)
        residual_page.addWidget(self.lines)
        right = QWidget()
        right_layout = QVBoxLayout(right)
        right_layout.setContentsMargins(0, 0, 0, 0)
        right_layout.addWidget(self.residual_note)
        right_layout.addWidget(self.residual_plot, 1)
        residual_page.addWidget(right)
        residual_page.setSizes([400, 440])
        self.tabs = QTabWidget()
        self.tabs.addTab(self.report, "Identifiability")
        self.tabs.addTab(residual_page, "Residual per line")
        self.tabs.addTab(square_page, "Squareness")
        self.tabs.addTab(map_page, "Squareness map")

        splitter = QSplitter(Qt.Orientation.Vertical)
        splitter.addWidget(self.curves)
        splitter.addWidget(self.tabs)
        splitter.setStretchFactor(0, 3)
        splitter.setStretchFactor(1, 2)
        layout = QVBoxLayout(self)
        layout.addLayout(top)
        layout.addWidget(splitter, 1)
        self.record: IdentificationRecord | None = None
        self.not_identified: set[str] = set()
        self._show_next: str | None = None

    # ---- running ---------------------------------------------------------------------------

    def run(self) -> None:
        """Identify the 21 errors from the project's measurement (in a worker)."""
        self.ensure_fresh()
        document = self.document
        measurement = document.measurement()
        options = replace(identify_options({"spacing_mm": self.spacing.value()}),
                          budget=jobs.budget_of(document.project))
        self.summary.setText("identifying…")
        self.run_task(
            "identification",
            ProcessCall(jobs.run_identification, (measurement, options)),
            self._identified,
            on_cancel=lambda: self.summary.setText("identification cancelled"),
        )

    def _identified(self, result: jobs.Identified) -> None:
        key = ("identifications", "main")
        self._show_next = "main"  # the refresh the edit causes draws it, once
        self.document.put_results("identify the 21 errors", {key: result.tree()},
                                  {key: Live(result.identification, result.record)})
        self.select("main")

    def _busy(self, busy: bool) -> None:
        self.run_button.setEnabled(not busy)

    # ---- showing ---------------------------------------------------------------------------

    def refresh(self, wanted: str | None = None) -> None:
        current = wanted or self._show_next or self.name_box.currentText()
        self._show_next = None
        names = self.document.results("identifications")
        self.name_box.blockSignals(True)  # drawn once, below
        self.name_box.clear()
        self.name_box.addItems(names)
        if names:
            self.name_box.setCurrentText(current if current in names else
                                         ("loop" if "loop" in names else names[0]))
        self.name_box.blockSignals(False)
        self.run_button.setEnabled(bool(self.document.line_names()) and not self.runner.busy)
        self._show(self.name_box.currentText())

    def select(self, name: str | None) -> None:
        if name and name in self.document.results("identifications"):
            if self._stale or name != self.name_box.currentText():
                self._stale = False
                self.refresh(name)
        elif self._stale:
            self._refresh_now()

    def _show(self, name: str) -> None:
        for eid, plot in self._plots.items():
            band, curve, note = self._curve_items[eid]
            band.setPath(QPainterPath())
            curve.setData([], [])
            note.hide()
            plot.setTitle(None)
        self.squareness.clearContents()
        self.square_note.clear()
        self.square_image.clear()
        self.square_plot.setTitle(None)
        self.not_identified = set()
        self.lines.setRowCount(0)
        self.residual_plot.clear()
        plots.style(self.residual_plot.getPlotItem(), "Residual", "target (mm)", "residual")
        self.residual_note.clear()
        if not name or name not in self.document.results("identifications"):
            self.record = None
            self.summary.setText("no identification yet: press Identify" if
                                 self.document.line_names() else "import lines first")
            self.report.setHtml("")
            return
        record = self.document.identification(name)
        self.record = record
        self._draw_curves(record)
        self._fill_report(record)
        self._fill_lines(record)
        rank = record.identifiability
        um, urad = record.residual_rms()
        rms = "" if math.isnan(um) else f", residual RMS {self.units.text(um, 'um')}"
        rms += "" if math.isnan(urad) else f" / {self.units.text(urad, 'urad')}"
        self.summary.setText(f"rank {rank.get('rank')} of {rank.get('unknowns')} unknowns, "
                             f"σ₀ {record.sigma_scale:.3f}{rms}")

    def _draw_curves(self, record: IdentificationRecord) -> None:
        for eid in AXIS_ERROR_IDS:
            plot = self._plots[eid]
            entry = record.parameters[eid]
            identified = record.identified(eid)
            info = ERROR_INFO[eid]
            unit = self.units.symbol(info.unit)
            plot.setTitle(f"{eid} {info.paper} ({unit})", size="8pt",
                          color="#000000" if identified else "#999999")
            x = np.asarray(entry["position_mm"], dtype=float)
            value = self.units.convert(entry["value"], info.unit)
            std = self.units.convert(entry["std"], info.unit)
            colour = plots.color(COMPONENTS.index(info.component)) if identified else "#aaaaaa"
            band, curve, note = self._curve_items[eid]
            band.setPath(plots.band_path(x, value - K_BAND * std, value + K_BAND * std))
            plots.style_band(band, colour, 50)
            curve.setData(x, value)
            curve.setPen(plots.pen(colour, 1.8, dashed=not identified))
            if not identified:
                self.not_identified.add(eid)
                # inside the plot, so that the column keeps its width
                note.setPos(float(x[0]), float(np.max(value + K_BAND * std)))
                note.show()
        for row, eid in enumerate(SQUARENESS_IDS):
            entry = record.parameters[eid]
            value = float(entry["value"][0])
            expanded = K_BAND * float(entry["std"][0])
            identified = record.identified(eid)
            if not identified:
                self.not_identified.add(eid)
            cells = [error_label(eid) + ("" if identified else ", not identified"),
                     self.units.text(value, "urad"), self.units.text(expanded, "urad"),
                     *self._paths_cells(record.squareness_map.get(eid))]
            tips = [ERROR_INFO[eid].description] * 3 + [self._paths_tip(
                record.squareness_map.get(eid))] * 4
            for column, (text, tip) in enumerate(zip(cells, tips, strict=True)):
                cell = QTableWidgetItem(text)
                cell.setToolTip(tip)
                if 0 < column < len(cells) - 1:  # the numbers; names left
                    cell.setTextAlignment(Qt.AlignmentFlag.AlignRight
                                          | Qt.AlignmentFlag.AlignVCenter)
                if not identified:
                    cell.setForeground(Qt.GlobalColor.gray)
                self.squareness.setItem(row, column, cell)
        self.squareness.resizeColumnsToContents()
        self._draw_square_map()
        self.square_note.setText(
            "Value: the angle between the axes (ISO 230-1 signs). Paths: the angle between the "
            "tool point's least-squares paths along the two axes, as a square would read it, at "
            "the centre of the measured volume and lowest and highest over 5 × 5 × 5 places in "
            "it; tilted by: a kept effect that bends a path. U is the expanded uncertainty, "
            "k = 2. View ▸ Units shows them in arcsec.")

    def _draw_square_map(self) -> None:
        """The angle between the tool's paths of the chosen squareness over the plane of its
        two axes, at the chosen level of the third axis (the grid's places, as mapped)."""
        self.square_image.clear()
        mapped = self.record.squareness_map if self.record is not None else {}
        ids = [sid for sid in SQUARENESS_IDS if sid in mapped]
        _set_items(self.square_id, ids, 0)
        if not ids:
            self.square_level.clear()
            self.square_plot.setTitle("this plan maps no squareness between the tool's paths",
                                      size="9pt")
            return
        sid = self.square_id.currentText()
        entry = mapped[sid]
        first, second = entry["axes"]
        third = next(axis for axis in AXES if axis not in (first, second))
        places = np.asarray(entry["places"]["place_mm"], dtype=float)
        angle = self.units.convert(entry["places"]["angle_urad"], "urad")
        k1, k2, k3 = (AXES.index(a) for a in (first, second, third))
        levels = np.unique(places[:, k3])
        _set_items(self.square_level, [f"{third} = {v:g} mm" for v in levels], len(levels) // 2)
        on = places[:, k3] == levels[self.square_level.currentIndex()]
        u, v = np.unique(places[on, k1]), np.unique(places[on, k2])
        plane = np.full((u.size, v.size), np.nan)
        plane[np.searchsorted(u, places[on, k1]), np.searchsorted(v, places[on, k2])] = angle[on]
        self.square_image.setImage(plane, autoLevels=False)
        self.square_colorbar.setLevels((float(np.nanmin(plane)), float(np.nanmax(plane))))
        du = (u[-1] - u[0]) / max(u.size - 1, 1)
        dv = (v[-1] - v[0]) / max(v.size - 1, 1)
        self.square_image.setRect(float(u[0] - du / 2), float(v[0] - dv / 2),
                                  float(u[-1] - u[0] + du), float(v[-1] - v[0] + dv))
        plots.style(self.square_plot.getPlotItem(), None, f"{first} (mm)", f"{second} (mm)")
        self.square_plot.setTitle(
            f"{sid}: angle between the tool's {first} and {second} paths through each place "
            f"({self.units.symbol('urad')})", size="9pt")

    def _paths_cells(self, entry: dict | None) -> tuple[str, ...]:
        """The angle between the tool's paths at the centre, lowest and highest, each ± U and
        with where, and the kept effects that tilt a path."""
        if not entry:
            return ("—",) * 4
        return (self._pm(entry, "at_centre"),
                f"{self._pm(entry, 'lowest')} at {place_text(entry['lowest_at_mm'])}",
                f"{self._pm(entry, 'highest')} at {place_text(entry['highest_at_mm'])}",
                ", ".join(entry["tilted_by"]) or "—")

    def _pm(self, entry: dict, key: str) -> str:
        u = self.units
        return (f"{u.text(entry[f'{key}_urad'], 'urad', False)} ± "
                f"{u.text(K_BAND * entry[f'{key}_std_urad'], 'urad')}")

    def _paths_tip(self, entry: dict | None) -> str:
        if not entry:
            return ("not mapped: the plan identifies this squareness and both straightness "
                    "functions of its axes only together, or the project predates the map")
        least = entry["least_certain_at_mm"]
        return (f"the angle between the tool's paths over {_volume(entry['volume_mm'])}, at "
                f"5 × 5 × 5 places; U (k = 2) is largest at {place_text(least)}: "
                f"{self._pm(entry, 'least_certain')}")

    def _fill_report(self, record: IdentificationRecord) -> None:
        ident = record.identifiability
        parts = [f"<p><b>Rank {ident.get('rank')}</b> of {ident.get('unknowns')} unknowns "
                 f"(coefficients of the 21 errors after the gauges, plus line offsets and "
                 f"slopes).</p>"]
        missing = ident.get("unidentifiable", []) or []
        if missing:
            parts.append("<p><b>Not identified by this plan:</b></p><ul>")
            parts += [f"<li>{text}</li>" for text in missing]
            parts.append("</ul>")
        else:
            parts.append("<p>Every error is identified by this plan.</p>")
        redundant = list(ident.get("redundant_lines", []) or [])
        source = ident.get("redundancy_from")
        names = self.document.results("identifications")
        if not redundant and source is None and record.effects and "main" in names and \
                record.name != "main":
            # a loop refit stored before the trees carried the plan's redundancy: the plan's is
            # that of the 21-error fit
            redundant = list(self.document.identification("main").identifiability.get(
                "redundant_lines", []) or [])
            source = "the 21-error fit 'main'"
        lines = len(self.document.line_names())
        origin = f" (tested on {source})" if source else ""
        if redundant and len(redundant) == lines:
            parts.append(f"<p><b>Every one of the {lines} lines is redundant</b>{origin}: the "
                         "plan stays identifiable without any one of them, so cross-validation "
                         "leaves one line out at a time.</p>")
        elif redundant:
            parts.append(f"<p><b>Redundant lines</b>{origin} ({len(redundant)} of {lines}: the "
                         f"plan stays identifiable without each of them; leave-one-line-out "
                         f"cross-validation uses them): {', '.join(redundant)}</p>")
        else:
            parts.append("<p>No line is redundant: cross-validation holds out blocks of "
                         "targets.</p>")
        if record.effects:
            parts.append("<p><b>Effects fitted with the 21 errors:</b></p><ul>")
            for effect in record.effects:
                values = ", ".join(f"{k} {_short(v)}" for k, v in
                                   (effect.get("parameters") or {}).items())
                parts.append(f"<li>{effect.get('label')}: {values}</li>")
            parts.append("</ul>")
        options = record.options
        if options:
            parts.append(f"<p>Cubic B-splines with knots every {options.get('spacing_mm')} mm; "
                         f"σ₀ = {record.sigma_scale:.4g} (a posteriori standard deviation of unit "
                         f"weight).</p>")
        self.report.setHtml("".join(parts))

    def _fill_lines(self, record: IdentificationRecord) -> None:
        if record.readings is None:
            self.residual_note.setText(
                "This identification was stored without its residuals (by an older volucal, "
                "which kept only the model): press Identify to compute them.")
            return
        self.residual_note.setText("Select a line to see its residual by run.")
        rows = record.readings.line_summary()
        self.lines.setSortingEnabled(False)
        self.lines.setRowCount(len(rows))
        for r, row in enumerate(rows):
            unit = row["unit"]
            cells = [row["line"], row["group"], row["readings"],
                     round(self.units.value(row["rms"], unit), self.units.unit(unit).decimals + 1),
                     round(self.units.value(row["max_abs"], unit),
                           self.units.unit(unit).decimals + 1),
                     self.units.symbol(unit)]
            for c, value in enumerate(cells):
                item = QTableWidgetItem()
                if isinstance(value, float):
                    item.setData(Qt.ItemDataRole.DisplayRole, value)
                elif isinstance(value, int):
                    item.setData(Qt.ItemDataRole.DisplayRole, value)
                else:
                    item.setText(str(value))
                self.lines.setItem(r, c, item)
        self.lines.setSortingEnabled(True)
        self.lines.resizeColumnsToContents()

    def _show_line_residual(self) -> None:
        self.residual_plot.clear()
        items = self.lines.selectedItems()
        if not items or self.record is None or self.record.readings is None:
            return
        cell = self.lines.item(items[0].row(), 0)
        if cell is None:
            return
        name = cell.text()
        result = evidence.line_residual(self.record.readings, name)
        item = self.residual_plot.getPlotItem()
        plots.style(item, result.title, result.x_label, result.y_axis(self.units))
        for index, series in enumerate(result.series):
            item.addItem(pg.PlotDataItem(series.x, result.y_shown(series.y, self.units),
                                         pen=plots.pen(plots.color(index), 1.2),
                                         name=series.name))


def _short(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list):
        return "[" + ", ".join(_short(v) for v in value) + "]"
    return str(value)



def _volume(volume: dict[str, list[float]]) -> str:
    return ", ".join(f"{axis} {a:g}…{b:g}" for axis, (a, b) in volume.items()) + " mm"


def _set_items(box: QComboBox, texts: list[str], default: int) -> None:
    """Give ``box`` these items, keeping its choice when they are the same (no signal)."""
    if [box.itemText(i) for i in range(box.count())] == texts:
        return
    box.blockSignals(True)
    box.clear()
    box.addItems(texts)
    box.setCurrentIndex(default if texts else -1)
    box.blockSignals(False)
