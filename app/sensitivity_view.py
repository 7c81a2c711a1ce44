"""Sensitivity view: ranked EFAST indices, the editable factor table and a workspace map.

Bars: first-order (S1) and total (ST) indices of the chosen output (Ex, Ey, Ez or ET = |E|,
paper eqs. 5–7) for each of the 21 errors, sorted by S1 or ST, the top k shown. The factor table
is the problem (:mod:`volucal.app.factors`); editing it and pressing Run analyses again. The map
runs one analysis per point of a workspace grid (long: a worker, with progress and cancel) and
shows a slice at a chosen Z as a heat map.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import replace

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QComboBox,
    QDoubleSpinBox,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSlider,
    QSpinBox,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)
from volucal.core.errors import ERROR_INFO, error_label
from volucal.core.result_trees import unidentified_ids
from volucal.core.sensitivity import OUTPUT_NAMES, SensitivityResult, not_identified_note
from volucal.core.userror import UserError

from . import plots
from .document import ProjectDocument
from .engine import ProcessCall
from .factors import (
    DISTRIBUTIONS,
    FLOOR_UM,
    FLOOR_URAD,
    RANKING_GRID_MM,
    SensitivityRecord,
    SensitivitySetup,
    sensitivity_tree,
)
from .records import Live, stored_model
from .settings import Preferences
from .view_base import View

BY_HAND = "by hand (from the paper's Table 2)"
COLUMNS = ("error", "distribution", "mean", "spread (1σ)", "unit", "edited")
SPREAD_COLUMN = 3
MEAN_COLUMN = 2
DISTRIBUTION_COLUMN = 1
STD_OUTPUT = "standard deviation of the output (µm)"
NOT_IDENTIFIED = not_identified_note(FLOOR_UM, FLOOR_URAD)
#: Where the output barely varies its indices are ratios of noise to almost nothing: not shown.
QUIET_VARIANCE = 1e-6
POSITIONS = (
    ("grid", "averaged over a workspace grid"),
    ("design", "X, Y, Z as design factors"),
)


class SensitivityView(View):
    title = "Sensitivity"

    def __init__(self, document: ProjectDocument, parent: QWidget | None = None) -> None:
        super().__init__(document, parent)
        self.setObjectName("sensitivityView")
        prefs = Preferences.load()
        self.setup: SensitivitySetup | None = None
        #: The identification result the factor table was built from (document.result_token).
        self._setup_token: int | None = None
        self._centre_slice = False
        self._map_key: tuple[str, int, int, int] = ("", 0, 0, 0)
        self.record: SensitivityRecord | None = None
        self.map_record: SensitivityRecord | None = None
        self._filling = False

        self.problem_box = QComboBox()
        self.problem_box.setObjectName("problemBox")
        self.problem_box.setToolTip("which errors vary, and how")
        self.problem_box.activated.connect(lambda _i: self._new_setup())
        self.positions_box = QComboBox()
        self.positions_box.setObjectName("positionsBox")
        for key, text in POSITIONS:
            self.positions_box.addItem(text, key)
        self.positions_box.setToolTip(
            "grid: the errors' indices at fixed points of a coarse grid, averaged with the "
            "output variance as weight (what the errors explain where the tool is); design: X, "
            "Y, Z vary with the errors (their share of the output's variation over the "
            "workspace is then part of the analysis, as in the paper)")
        self.n_box = QSpinBox()
        self.n_box.setRange(65, 20000)
        self.n_box.setSingleStep(100)
        self.n_box.setValue(prefs.sensitivity_n)
        self.n_box.setToolTip("EFAST samples per search curve (the paper: 1400)")
        self.run_button = QPushButton("Run")
        self.run_button.setObjectName("runSensitivityButton")
        self.run_button.clicked.connect(self.run)
        self.cancel_button = self.cancel_control(self._busy)
        self.status = QLabel()
        self.status.setObjectName("sensitivityStatus")
        top = QHBoxLayout()
        top.addWidget(QLabel("Problem"))
        top.addWidget(self.problem_box, 1)
        top.addWidget(QLabel("positions"))
        top.addWidget(self.positions_box)
        top.addWidget(QLabel("N"))
        top.addWidget(self.n_box)
        top.addWidget(self.run_button)
        top.addWidget(self.cancel_button)
        top.addWidget(self.status, 2)

        self.output_box = QComboBox()
        self.output_box.setObjectName("outputBox")
        self.output_box.addItems(OUTPUT_NAMES)
        self.output_box.setCurrentText("ET")
        self.sort_box = QComboBox()
        self.sort_box.setObjectName("sortBox")
        self.sort_box.addItems(["S1", "ST"])
        self.top_k = QSpinBox()
        self.top_k.setObjectName("topK")
        self.top_k.setRange(1, 21)
        self.top_k.setValue(10)
        for box in (self.output_box, self.sort_box):
            box.currentIndexChanged.connect(lambda _i: self._draw())
        self.top_k.valueChanged.connect(lambda _v: self._draw_bars())
        show = QHBoxLayout()
        show.addWidget(QLabel("Output"))
        show.addWidget(self.output_box)
        show.addWidget(QLabel("sort by"))
        show.addWidget(self.sort_box)
        show.addWidget(QLabel("top"))
        show.addWidget(self.top_k)
        show.addStretch(1)

        self.bars = plots.make_plot("EFAST indices", "index", None)
        self.bars.setObjectName("sensitivityBars")
        self.bars.getPlotItem().invertY(True)
        plots.add_legend(self.bars.getPlotItem())
        self.table = QTableWidget(0, len(COLUMNS))
        self.table.setObjectName("factorTable")
        self.table.setHorizontalHeaderLabels(list(COLUMNS))
        self.table.verticalHeader().setVisible(False)
        self.table.itemChanged.connect(self._cell_edited)
        self.table_note = QLabel()
        self.table_note.setWordWrap(True)
        factors = QWidget()
        factors_layout = QVBoxLayout(factors)
        factors_layout.setContentsMargins(0, 0, 0, 0)
        factors_layout.addWidget(self.table, 1)
        factors_layout.addWidget(self.table_note)

        self.map_step = QDoubleSpinBox()
        self.map_step.setObjectName("mapStep")
        self.map_step.setRange(5.0, 500.0)
        self.map_step.setSuffix(" mm")
        self.map_step.setValue(prefs.map_step_mm)
        self.map_button = QPushButton("Compute map")
        self.map_button.setObjectName("mapButton")
        self.map_button.clicked.connect(self.run_map)
        self.map_what = QComboBox()
        self.map_what.setObjectName("mapWhat")
        self.map_what.currentIndexChanged.connect(lambda _i: self._draw_map())
        self.slice = QSlider(Qt.Orientation.Horizontal)
        self.slice.setObjectName("zSlider")
        self.slice.valueChanged.connect(lambda _v: self._draw_map())
        self.slice_label = QLabel()
        map_controls = QHBoxLayout()
        map_controls.addWidget(QLabel("step"))
        map_controls.addWidget(self.map_step)
        map_controls.addWidget(self.map_button)
        map_controls.addWidget(QLabel("show"))
        map_controls.addWidget(self.map_what, 1)
        slider_row = QHBoxLayout()
        slider_row.addWidget(QLabel("Z slice"))
        slider_row.addWidget(self.slice, 1)
        slider_row.addWidget(self.slice_label)
        self.map_plot = plots.make_plot("Workspace map", "X (mm)", "Y (mm)")
        self.map_plot.setObjectName("mapPlot")
        self.image = pg.ImageItem()
        self.map_plot.addItem(self.image)
        self.colorbar = pg.ColorBarItem(colorMap=pg.colormap.get("viridis"), interactive=False,
                                        width=12)
        self.colorbar.setImageItem(self.image, insert_in=self.map_plot.getPlotItem())
        plots.plain_axis(self.colorbar.axis)
        map_box = QGroupBox("Workspace map (one EFAST analysis per grid point)")
        map_layout = QVBoxLayout(map_box)
        map_layout.addLayout(map_controls)
        map_layout.addWidget(self.map_plot, 1)
        map_layout.addLayout(slider_row)

        upper = QSplitter(Qt.Orientation.Horizontal)
        upper.addWidget(self.bars)
        upper.addWidget(factors)
        upper.setStretchFactor(0, 3)
        upper.setStretchFactor(1, 2)
        upper.setSizes([760, 560])
        lower = QSplitter(Qt.Orientation.Vertical)
        lower.addWidget(upper)
        lower.addWidget(map_box)
        lower.setStretchFactor(0, 3)
        lower.setStretchFactor(1, 2)
        layout = QVBoxLayout(self)
        layout.addLayout(top)
        layout.addLayout(show)
        layout.addWidget(lower, 1)

    # ---- problem -----------------------------------------------------------------------------

    def _identification_choice(self) -> str | None:
        data = self.problem_box.currentData()
        return data if isinstance(data, str) and data else None

    def _model_and_covariance(self, name: str) -> tuple[object, np.ndarray | None]:
        model = stored_model(self.document.project, name)
        tree = self.document.tree("identifications", name)
        covariance = tree.get("covariance")
        return model, None if covariance is None else np.asarray(covariance, dtype=float)

    def _record_unseen(self, record: SensitivityRecord) -> frozenset[str]:
        """What the identification behind a result does not fully identify: as stored with the
        result or, for a result stored before it was kept, as that identification says."""
        if record.not_identified:
            return record.not_identified
        setup = record.setup
        if setup is not None and setup.mode == "identified" and \
                setup.identification in self.document.results("identifications"):
            return frozenset(self._unidentified(setup.identification))
        return frozenset()

    def _unidentified(self, name: str) -> list[str]:
        """The errors identification ``name``'s plan does not fully identify."""
        return unidentified_ids(self.document.tree("identifications", name))

    def set_document(self, document: ProjectDocument) -> None:
        """Another project: nothing of this one's problem or results may stay."""
        self.setup = None
        self._setup_token = None
        self.record = None
        self.map_record = None
        self.status.clear()
        super().set_document(document)

    def _new_setup(self) -> None:
        """The factor table of the chosen problem, fresh."""
        name = self._identification_choice()
        n = self.n_box.value()
        self._setup_token = None if name is None else self.document.result_token(
            "identifications", name)
        try:
            self.positions_box.setCurrentIndex(self.positions_box.findData(
                "design" if name is None else "grid"))
            if name is None:
                self.setup = SensitivitySetup.paper_table2(n)
            else:
                model, covariance = self._model_and_covariance(name)
                self.setup = SensitivitySetup.identified(
                    model, covariance, n, identification=name,  # type: ignore[arg-type]
                    not_identified=self._unidentified(name))
        except (UserError, KeyError) as exc:
            self.setup = None
            self.table_note.setText(f"cannot set up the problem: {exc}")
            return
        self._fill_table()

    def _fill_table(self) -> None:
        setup = self.setup
        self._filling = True
        self.table.setRowCount(0 if setup is None else len(setup.factors))
        if setup is not None:
            identified = setup.mode == "identified"
            unseen = set(setup.not_identified)
            for row, factor in enumerate(setup.factors):
                name = QTableWidgetItem(_marked(factor.id, unseen))
                name.setData(Qt.ItemDataRole.UserRole, factor.id)
                name.setToolTip(ERROR_INFO[factor.id].description + (
                    f"\n{NOT_IDENTIFIED}" if factor.id in unseen else ""))
                cells = [
                    name,
                    QTableWidgetItem(factor.distribution),
                    QTableWidgetItem(_shown(self.units.value(factor.mean, factor.unit))),
                    QTableWidgetItem(_shown(self.units.value(factor.spread, factor.unit))),
                    QTableWidgetItem(self.units.symbol(factor.unit)),
                    QTableWidgetItem("yes" if factor.overridden else ""),
                ]
                for column, item in enumerate(cells):
                    editable = column == SPREAD_COLUMN or (not identified and column in (
                        MEAN_COLUMN, DISTRIBUTION_COLUMN))
                    flags = item.flags()
                    if not editable:
                        flags &= ~Qt.ItemFlag.ItemIsEditable
                    item.setFlags(flags)
                    self.table.setItem(row, column, item)
            self.table.resizeColumnsToContents()
            if identified:
                self.table_note.setText(
                    "Identified errors: each is its identified function of position plus a "
                    "normal deviation. Mean and spread are over the stroke; set a spread to "
                    "replace that error's uncertainty, then Run." + (
                        f"\n{NOT_IDENTIFIED}" if unseen else ""))
            else:
                self.table_note.setText(
                    f"By hand: each error is one random value ({', '.join(DISTRIBUTIONS)}); "
                    "the spread is the standard deviation. Edit, then Run.")
        self._filling = False

    def _cell_edited(self, item: QTableWidgetItem) -> None:
        if self._filling or self.setup is None:
            return
        row, column = item.row(), item.column()
        eid = self._factor_id(row)
        if eid is None:
            return
        text = item.text().strip()
        try:
            if column == DISTRIBUTION_COLUMN:
                if text not in DISTRIBUTIONS:
                    raise UserError(f"{eid}: distribution {text!r}: use "
                                    f"{', '.join(DISTRIBUTIONS)}")
                self.setup = self.setup.with_factor(eid, distribution=text)
            elif column in (MEAN_COLUMN, SPREAD_COLUMN):
                try:
                    value = float(text)
                except ValueError:
                    raise UserError(f"{eid}: {text!r} is not a number") from None
                key = "mean" if column == MEAN_COLUMN else "spread"
                # typed in the unit the table shows
                unit = self.setup.factor(eid).unit
                self.setup = self.setup.with_factor(eid, **{key: self.units.to_core(value, unit)})
            else:
                return
        except UserError as exc:
            self.table_note.setText(str(exc))
            self._fill_table()
            return
        self._fill_table()
        self.status.setText("factor table edited: press Run to analyse again")

    def set_spread(self, eid: str, spread: float) -> None:
        """Edit one factor's spread through the table, as the user does (in the unit the table
        shows)."""
        for row in range(self.table.rowCount()):
            cell = self.table.item(row, SPREAD_COLUMN)
            if self._factor_id(row) == eid and cell is not None:
                cell.setText(f"{spread:g}")
                return
        raise KeyError(eid)

    def _factor_id(self, row: int) -> str | None:
        cell = self.table.item(row, 0)
        return None if cell is None else cell.data(Qt.ItemDataRole.UserRole)

    # ---- running -----------------------------------------------------------------------------

    def _run_arguments(self) -> tuple[object, np.ndarray | None]:
        name = self._identification_choice()
        if name is None:
            return None, None
        return self._model_and_covariance(name)

    def run(self) -> None:
        """The ranking: indices averaged over a coarse workspace grid, or with the positions
        as design factors (the positions box)."""
        grid = self.positions_box.currentData() == "grid"
        self._start(map_step=RANKING_GRID_MM if grid else None, name="main")

    def run_map(self) -> None:
        """EFAST at every point of a workspace grid (one analysis per point)."""
        self._start(map_step=self.map_step.value(), name="map")

    def _start(self, map_step: float | None, name: str) -> None:
        self.ensure_fresh()
        if self.setup is None:
            self._new_setup()
        if self.setup is None:
            return
        setup = replace(self.setup, n=self.n_box.value())
        self.setup = setup
        try:
            model, covariance = self._run_arguments()
        except (UserError, KeyError) as exc:
            self.task_failed(str(exc))
            return
        machine = self.document.machine
        what = "map" if name == "map" else "ranking"
        self.status.setText(f"EFAST {what} running…")
        self.run_task(
            f"sensitivity {what}",
            ProcessCall(setup.run, (model, covariance, map_step, machine)),
            lambda result: self._analysed(result, setup, name),
            on_cancel=lambda: self.status.setText(f"EFAST {what} cancelled"),
        )

    def _analysed(self, result: SensitivityResult, setup: SensitivitySetup, name: str) -> None:
        record = SensitivityRecord.from_result(name, result, setup)
        key = ("sensitivity", name)
        if name == "map":
            self._centre_slice = True
        self.document.put_results(
            "sensitivity " + ("map" if name == "map" else "ranking"),
            {key: sensitivity_tree(result, setup)}, {key: Live(result, record)})
        self.status.setText(f"EFAST done (N = {setup.n}, seed {setup.seed})")

    def _busy(self, busy: bool) -> None:
        self.run_button.setEnabled(not busy)
        self.map_button.setEnabled(not busy)

    # ---- showing -------------------------------------------------------------------------------

    def refresh(self) -> None:
        names = self.document.results("identifications")
        results = self.document.results("sensitivity")
        self.record = self.document.sensitivity("main") if "main" in results else None
        self.map_record = self.document.sensitivity("map") if "map" in results else None
        if self.map_record is None and self.record is not None and self.record.is_map:
            self.map_record = self.record
        if self.setup is None and self.record is not None and self.record.setup is not None:
            self.setup = self.record.setup
            source = self.setup.identification
            self._setup_token = None if source is None else self.document.result_token(
                "identifications", source)
            if source in names:
                # what the identification cannot see (a setup saved before it was kept, too)
                self.setup = replace(self.setup, not_identified=tuple(
                    self._unidentified(source)))
        if self.setup is not None and self.setup.mode == "identified" and \
                self._setup_token != self.document.result_token(
                    "identifications", self.setup.identification or ""):
            # the identification was run again (or removed): its means and spreads changed
            self.setup = None
            self.status.setText("factor table rebuilt from the current identification")
        default = "loop" if "loop" in names else (names[0] if names else "")
        if self.setup is None:
            wanted = default
        elif self.setup.mode == "by_hand":
            wanted = ""
        else:
            wanted = self.setup.identification or default
        if wanted and wanted not in names:  # the identification it came from was removed
            self.setup = None
            wanted = default
        self.problem_box.blockSignals(True)
        self.problem_box.clear()
        for name in names:
            self.problem_box.addItem(f"identified errors: '{name}'", name)
        self.problem_box.addItem(BY_HAND, "")
        self.problem_box.setCurrentIndex(max(self.problem_box.findData(wanted), 0))
        self.problem_box.blockSignals(False)
        if self.setup is None:
            self._new_setup()
        else:
            self._fill_table()
        self._draw()

    def select(self, name: str | None) -> None:
        if self._stale:
            self._refresh_now()

    def _draw(self) -> None:
        self._draw_bars()
        self._fill_map_choices()
        self._draw_map()

    def ranking(self) -> list[str]:
        """The error ids in the order the bars show them (top first)."""
        if self.record is None:
            return []
        output = self.output_box.currentText()
        if output not in self.record.outputs:
            return []
        rows = self.record.ranked(output, self.sort_box.currentText())
        return [row[0] for row in rows[: self.top_k.value()]]

    def _draw_bars(self) -> None:
        item = self.bars.getPlotItem()
        item.clear()
        record = self.record
        output = self.output_box.currentText()
        if record is None or output not in record.outputs:
            item.setTitle("no sensitivity result yet: press Run", size="10pt")
            return
        kind = self.sort_box.currentText()
        rows = record.ranked(output, kind)[: self.top_k.value()]
        y = np.arange(len(rows), dtype=float)
        s1 = np.array([r[1] for r in rows])
        st = np.array([r[2] for r in rows])
        item.addItem(pg.BarGraphItem(x0=0.0, y=y - 0.19, height=0.36, width=s1,
                                     brush=plots.brush(plots.FORWARD, 200), name="S1 first order"))
        item.addItem(pg.BarGraphItem(x0=0.0, y=y + 0.19, height=0.36, width=st,
                                     brush=plots.brush(plots.color(1), 200), name="ST total"))
        unseen = self._record_unseen(record)
        plots.category_ticks(item.getAxis("left"), [_marked(r[0], unseen) for r in rows])
        values = np.concatenate([s1, st, [0.0]])
        low, high = float(np.min(values)), max(float(np.max(values)), 1e-3)
        item.setXRange(low - 0.05 * (high - low), high * 1.05, padding=0)
        item.setYRange(-0.6, len(rows) - 0.4, padding=0)
        title = f"{output}: EFAST indices sorted by {kind}"
        positions = record.indices[output].get("positions")
        if isinstance(positions, dict):
            shares = ", ".join(f"{a} {_fraction(v)}" for a, v in positions.get("S1", {}).items())
            title += f" — positions are design factors (their S1: {shares})"
        elif record.is_map:
            title += " — workspace average of the map"
        if any(r[0] in unseen for r in rows):
            title += ("<br>* not fully identified by this plan: its indices are not the "
                      "machine's alone")
        item.setTitle(title, size="10pt")

    # ---- map -----------------------------------------------------------------------------------

    def _fill_map_choices(self) -> None:
        record = self.map_record
        current = self.map_what.currentText()
        self.map_what.blockSignals(True)
        self.map_what.clear()
        if record is not None and record.result is not None:
            self.map_what.addItem(STD_OUTPUT)
            unseen = self._record_unseen(record)
            for eid in record.result.factor_ids:
                self.map_what.addItem(
                    f"{self.sort_box.currentText()} of {_marked(eid, unseen)}", eid)
            found = self.map_what.findText(current)
            if found < 0 and self.record is not None and self.ranking():
                found = self.map_what.findData(self.ranking()[0])
            self.map_what.setCurrentIndex(max(found, 0))
        self.map_what.blockSignals(False)

    def map_grid(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """(x, y, z, values[nx, ny, nz]) of the map's current quantity, or None."""
        record = self.map_record
        if record is None or record.result is None or record.result.positions_mm is None:
            return None
        result = record.result
        output = self.output_box.currentText()
        if output not in result.outputs:
            return None
        o = result.outputs.index(output)
        q = result.positions_mm
        x, y, z = (np.unique(q[:, k]) for k in range(3))
        eid = self.map_what.currentData()
        if isinstance(eid, str) and eid in result.factor_ids:
            array = result.s1 if self.sort_box.currentText() == "S1" else result.st
            values = array[o, :, result.factor_ids.index(eid)].copy()
            variance = result.variance_um2[o]
            values[variance < QUIET_VARIANCE * float(np.max(variance, initial=0.0))] = np.nan
        else:
            values = np.sqrt(result.variance_um2[o])
        if values.size != x.size * y.size * z.size:
            return None
        return x, y, z, values.reshape(x.size, y.size, z.size)

    def _draw_map(self) -> None:
        grid = self.map_grid()
        if grid is None:
            self.image.clear()
            self.slice_label.setText("no map yet: press Compute map")
            return
        x, y, z, values = grid
        self.slice.blockSignals(True)
        self.slice.setRange(0, z.size - 1)
        key = (self.map_record.name if self.map_record else "", x.size, y.size, z.size)
        if self._centre_slice or key != self._map_key:
            # a new map opens on its middle slice
            self._centre_slice = False
            self._map_key = key
            self.slice.setValue(z.size // 2)
        self.slice.blockSignals(False)
        k = min(self.slice.value(), z.size - 1)
        plane = values[:, :, k]
        self.image.setImage(plane, autoLevels=False)
        finite = plane[np.isfinite(plane)]
        low = float(finite.min()) if finite.size else 0.0
        high = float(finite.max()) if finite.size else 1.0
        if math.isclose(low, high):
            high = low + 1e-9
        self.colorbar.setLevels((low, high))
        dx = (x[-1] - x[0]) / max(x.size - 1, 1)
        dy = (y[-1] - y[0]) / max(y.size - 1, 1)
        self.image.setRect(float(x[0] - dx / 2), float(y[0] - dy / 2), float(x[-1] - x[0] + dx),
                           float(y[-1] - y[0] + dy))
        self.slice_label.setText(f"Z = {z[k]:g} mm ({k + 1} of {z.size})")
        self.colorbar.setLabel("right", self.map_what.currentText())
        self.map_plot.getPlotItem().setTitle(
            f"{self.output_box.currentText()}: {self.map_what.currentText()} at Z = {z[k]:g} mm",
            size="10pt")


def _marked(eid: str, unseen: Collection[str]) -> str:
    """An error's label, with * when the plan does not identify it."""
    return error_label(eid) + (" *" if eid in unseen else "")


def _fraction(value: object) -> str:
    return "—" if value is None else f"{float(value):.2f}"  # type: ignore[arg-type]


def _shown(value: float) -> str:
    """A table value: six significant digits; a gauge's numerical zero (1e-12) as 0."""
    return "0" if abs(value) < 1e-9 else f"{value:.6g}"
