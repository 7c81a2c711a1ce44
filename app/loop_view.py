"""Loop view: each step of the closed loop with its evidence, before/after, and the user's say.

Steps come from the loop report (DESIGN.md, "The closed loop"): the effect tested, its evidence
(F statistic, false-alarm level, magnitude), the RMS and cross-validated RMS before and after,
whether it was kept. Selecting a step draws the residual's signature of that effect
(:mod:`volucal.app.evidence`) before or after the loop. The effects list lets the user accept or
reject each effect the loop tried and refit the 21 errors with exactly the accepted ones; the
refit replaces the loop's identification (undoable), so compensation and ``volucal export`` use
the user's choice.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from functools import partial
from typing import Any

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QComboBox,
    QDoubleSpinBox,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QListWidget,
    QListWidgetItem,
    QPushButton,
    QSpinBox,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)
from volucal.core.identify import residual_rms
from volucal.core.residuals import ESTIMATED_AGAIN, TOGETHER, LoopOptions
from volucal.core.userror import UserError

from . import evidence, jobs, plots
from .document import ProjectDocument
from .engine import ProcessCall
from .records import (
    IdentificationRecord,
    Live,
    LoopRecord,
    effect_from_json,
    identify_options,
    stored_model,
)
from .settings import Preferences
from .view_base import View

STEP_COLUMNS = ("step", "effect", "F", "log₁₀ false alarm", "magnitude µm", "RMS µm",
                "CV RMS µm", "kept")
GROUP_ORDER = ("X", "Y", "Z", "diagonal", "angular")


class LoopView(View):
    title = "Closed loop"

    def __init__(self, document: ProjectDocument, parent: QWidget | None = None) -> None:
        super().__init__(document, parent)
        self.setObjectName("loopView")
        prefs = Preferences.load()
        self.margin = QDoubleSpinBox()
        self.margin.setRange(0.0, 100.0)
        self.margin.setSuffix(" %")
        self.margin.setValue(100 * prefs.loop_margin)
        self.margin.setToolTip("an effect is kept when it improves the cross-validated RMS by "
                               "at least this much")
        self.max_steps = QSpinBox()
        self.max_steps.setRange(1, 20)
        self.max_steps.setValue(prefs.loop_max_steps)
        self.run_button = QPushButton("Close the loop")
        self.run_button.setObjectName("runLoopButton")
        self.run_button.clicked.connect(self.run)
        self.cancel_button = self.cancel_control(self._busy)
        self.summary = QLabel()
        self.summary.setObjectName("loopSummary")
        top = QHBoxLayout()
        top.addWidget(QLabel("keep above"))
        top.addWidget(self.margin)
        top.addWidget(QLabel("steps at most"))
        top.addWidget(self.max_steps)
        top.addWidget(self.run_button)
        top.addWidget(self.cancel_button)
        top.addWidget(self.summary, 1)

        self.steps = QTableWidget(0, len(STEP_COLUMNS))
        self.steps.setObjectName("loopSteps")
        self.steps.setHorizontalHeaderLabels(list(STEP_COLUMNS))
        self.steps.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.steps.setSelectionBehavior(QTableWidget.SelectionBehavior.SelectRows)
        self.steps.setSelectionMode(QTableWidget.SelectionMode.SingleSelection)
        self.steps.verticalHeader().setVisible(False)
        self.steps.itemSelectionChanged.connect(self._show_evidence)

        self.effects = QListWidget()
        self.effects.setObjectName("loopEffects")
        self.effects.itemChanged.connect(self._effects_edited)
        self.refit_button = QPushButton("Refit with the checked effects")
        self.refit_button.setObjectName("refitButton")
        self.refit_button.clicked.connect(self.refit)
        self.effects_note = QLabel()
        self.effects_note.setWordWrap(True)
        effects_box = QGroupBox("Effects: check to accept, uncheck to reject")
        effects_layout = QVBoxLayout(effects_box)
        effects_layout.addWidget(self.effects, 1)
        effects_layout.addWidget(self.effects_note)
        effects_layout.addWidget(self.refit_button)

        self.unexplained = QListWidget()
        self.unexplained.setObjectName("unexplained")
        self.unexplained.setWordWrap(True)
        unexplained_box = QGroupBox("Still unexplained, and warnings")
        QVBoxLayout(unexplained_box).addWidget(self.unexplained)

        left = QSplitter(Qt.Orientation.Vertical)
        left.addWidget(self.steps)
        left.addWidget(effects_box)
        left.addWidget(unexplained_box)
        left.setStretchFactor(0, 3)
        left.setStretchFactor(1, 2)
        left.setStretchFactor(2, 1)

        self.residual_box = QComboBox()
        self.residual_box.addItems(["residual before the loop (21 errors)",
                                    "residual after the loop (with the kept effects)"])
        self.residual_box.currentIndexChanged.connect(lambda _i: self._show_evidence())
        self.evidence_plot = plots.make_plot("Evidence")
        self.evidence_plot.setObjectName("evidencePlot")
        self.evidence_legend = plots.add_legend(self.evidence_plot.getPlotItem())
        self.evidence_note = QLabel()
        self.evidence_note.setWordWrap(True)
        self.rms_plot = plots.make_plot("RMS residual per group: before and after", None, "RMS")
        plots.add_legend(self.rms_plot.getPlotItem())
        self.rms_table = QTableWidget(0, 4)
        self.rms_table.setObjectName("rmsTable")
        self.rms_table.setHorizontalHeaderLabels(["group", "before", "after", "unit"])
        self.rms_table.verticalHeader().setVisible(False)
        self.rms_table.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.rms_table.setMaximumHeight(170)
        right = QWidget()
        right_layout = QVBoxLayout(right)
        right_layout.setContentsMargins(0, 0, 0, 0)
        right_layout.addWidget(self.residual_box)
        right_layout.addWidget(self.evidence_plot, 3)
        right_layout.addWidget(self.evidence_note)
        rms_row = QHBoxLayout()
        rms_row.addWidget(self.rms_plot, 2)
        rms_row.addWidget(self.rms_table, 1)
        right_layout.addLayout(rms_row, 2)

        splitter = QSplitter(Qt.Orientation.Horizontal)
        splitter.addWidget(left)
        splitter.addWidget(right)
        splitter.setStretchFactor(0, 2)
        splitter.setStretchFactor(1, 3)
        splitter.setSizes([520, 780])
        layout = QVBoxLayout(self)
        layout.addLayout(top)
        layout.addWidget(splitter, 1)
        self.record: LoopRecord | None = None
        self._before: IdentificationRecord | None = None
        self._after: IdentificationRecord | None = None

    # ---- running ---------------------------------------------------------------------------

    def options(self) -> LoopOptions:
        budget = jobs.budget_of(self.document.project)
        spacing = Preferences.load().identify_spacing_mm
        identify = replace(identify_options({"spacing_mm": spacing}), budget=budget)
        return LoopOptions(margin=self.margin.value() / 100.0, max_steps=self.max_steps.value(),
                           identify=identify)

    def run(self) -> None:
        """Identify, then close the loop on the project's measurement (in a worker)."""
        self.ensure_fresh()
        measurement = self.document.measurement()
        options = self.options()
        self.summary.setText("closing the loop…")
        self.run_task(
            "closed loop",
            ProcessCall(jobs.run_loop, (measurement, options)),
            self._looped,
            on_cancel=lambda: self.summary.setText("loop cancelled"),
        )

    def _looped(self, run: jobs.LoopRun) -> None:
        self.document.put_results("close the loop", run.trees(), run.live())
        self.select("main")

    def refit(self) -> None:
        """Refit the 21 errors with exactly the checked effects (in a worker)."""
        self.ensure_fresh()
        record = self.record
        if record is None or not record.candidates:
            return
        measurement = self.document.measurement()
        chosen, rejected = [], []
        try:
            for row in range(self.effects.count()):
                item = self.effects.item(row)
                entry = item.data(Qt.ItemDataRole.UserRole)
                if item.checkState() == Qt.CheckState.Checked:
                    chosen.append(effect_from_json(entry["effect"], measurement))
                else:
                    rejected.append(str(entry["label"]))
            base = self.document.identification(record.base)
            # the loop's own fit: its basis spacing, chosen by cross-validation, and its model
            final = self.document.identification(record.final)
            initial = stored_model(self.document.project, record.final)
        except (UserError, KeyError) as exc:
            self.task_failed(f"cannot refit: {exc}")
            return
        options = replace(identify_options(final.options),
                          budget=jobs.budget_of(self.document.project))
        redundant = list(base.identifiability.get("redundant_lines", []))
        # the readings the loop fitted: less the error periodic in time it took out of them
        periodic = next((u["periodic"] for u in record.report.get("unexplained", [])
                         if u.get("periodic", {}).get("taken_out")), None)
        self.summary.setText("refitting…")
        self.run_task(
            "refit with the accepted effects",
            ProcessCall(partial(jobs.refit_with_effects, name=record.final, periodic=periodic),
                        (measurement, chosen, options, initial, redundant, rejected)),
            self._refitted,
            on_cancel=lambda: self.summary.setText("refit cancelled"),
        )

    def _refitted(self, refit: jobs.Refit) -> None:
        record = self.record
        if record is None:
            return
        final = record.final
        decisions = {
            "accepted": list(refit.accepted),
            "rejected": list(refit.rejected),
            "rms_um_after": residual_rms(refit.identification)[0],
            "cv_rms_um_after": refit.cross_validation.rms_um,
            "cv_method": refit.cross_validation.method,
        }
        candidates = tuple({**c, "kept": c["label"] in refit.accepted} for c in record.candidates)
        new_record = replace(record, candidates=candidates, decisions=decisions)
        trees = {
            ("identifications", final): refit.stored,
            ("loops", record.name): new_record.to_tree(),
        }
        live_loop = self.document.live.get(("loops", record.name))
        live = {
            ("identifications", final): Live(refit.identification, refit.record),
            ("loops", record.name): Live(None if live_loop is None else live_loop.value,
                                         new_record),
        }
        self.document.put_results(
            f"refit with {len(refit.accepted)} accepted effect(s)", trees, live)
        self.select(record.name)

    def _busy(self, busy: bool) -> None:
        self.run_button.setEnabled(not busy)
        self.refit_button.setEnabled(not busy and self._can_refit())

    def _can_refit(self) -> bool:
        return self.record is not None and bool(self.record.candidates)

    # ---- showing ---------------------------------------------------------------------------

    def refresh(self) -> None:
        names = self.document.results("loops")
        self.run_button.setEnabled(bool(self.document.line_names()) and not self.runner.busy)
        self._show(names[0] if names else None)

    def select(self, name: str | None) -> None:
        self._stale = False
        names = self.document.results("loops")
        self._show(name if name in names else (names[0] if names else None))

    def _show(self, name: str | None) -> None:
        self.steps.setRowCount(0)
        self.effects.clear()
        self.unexplained.clear()
        self.evidence_plot.clear()
        self.evidence_plot.getPlotItem().setLogMode(x=False, y=False)
        plots.style(self.evidence_plot.getPlotItem(), "Evidence", "", "")
        self.evidence_note.clear()
        self.rms_plot.clear()
        self.rms_table.setRowCount(0)
        self.record = None
        self._before = self._after = None
        if name is None:
            self.summary.setText("no loop yet: press Close the loop" if
                                 self.document.line_names() else "import lines first")
            self.refit_button.setEnabled(False)
            return
        record = self.document.loop(name)
        self.record = record
        names = self.document.results("identifications")
        self._before = self.document.identification(record.base) if record.base in names else None
        self._after = self.document.identification(record.final) if record.final in names else \
            None
        report = record.report
        self._fill_steps(report.get("loop", []))
        self._fill_effects(record)
        self._fill_unexplained(report)
        self._fill_rms(report)
        rms = report.get("residual_rms_um", {})
        cv = report.get("cv_rms_um", {})
        unit = self.units.symbol("um")

        def um(value: Any) -> str:
            return _num(None if value is None else self.units.value(float(value), "um"))

        text = (f"RMS {um(rms.get('before_loop'))} → {um(rms.get('after_loop'))} {unit}, "
                f"cross-validated {um(cv.get('before_loop'))} → {um(cv.get('after_loop'))} "
                f"{unit} ({cv.get('method', '?')})")
        basis = report.get("basis")
        if basis:
            text += f"; basis every {basis['spacing_mm']:g} mm ({basis['chosen_by']})"
        if record.decisions:
            text += (f"; refitted by hand: RMS {um(record.decisions.get('rms_um_after'))} "
                     f"{unit}, CV {um(record.decisions.get('cv_rms_um_after'))} {unit}")
        self.summary.setText(text)
        self.refit_button.setEnabled(self._can_refit() and not self.runner.busy)
        if self.steps.rowCount():
            self.steps.selectRow(0)

    def _fill_steps(self, steps: list[Mapping[str, Any]]) -> None:
        symbol = self.units.symbol("um")
        self.steps.setHorizontalHeaderLabels(
            [name.replace("µm", symbol) for name in STEP_COLUMNS])
        self.steps.setRowCount(len(steps))

        def um(value: Any) -> str:
            return _num(None if value is None else self.units.value(float(value), "um"))

        for row, step in enumerate(steps):
            effect = step.get("effect", {})
            ev = effect.get("evidence", {})
            rms, cv = step.get("rms_um", {}), step.get("cv_rms_um", {})
            cells = [
                str(step.get("step")), str(effect.get("label", effect.get("kind"))),
                _num(ev.get("F")), _num(ev.get("log10_false_alarm")), um(ev.get("magnitude_um")),
                f"{um(rms.get('before'))} → {um(rms.get('after'))}",
                f"{um(cv.get('before'))} → {um(cv.get('after'))}",
                _kept(step.get("verdict")) if step.get("kept") else _rejected(step.get("verdict")),
            ]
            for column, text in enumerate(cells):
                item = QTableWidgetItem(text)
                item.setToolTip(str(step.get("reason", "")))
                if column == len(cells) - 1:
                    item.setForeground(Qt.GlobalColor.darkGreen if step.get("kept")
                                       else Qt.GlobalColor.darkRed)
                self.steps.setItem(row, column, item)
        self.steps.resizeColumnsToContents()

    def _fill_effects(self, record: LoopRecord) -> None:
        self.effects.blockSignals(True)
        if record.candidates:
            for entry in record.candidates:
                item = QListWidgetItem(str(entry["label"]))
                item.setFlags(item.flags() | Qt.ItemFlag.ItemIsUserCheckable)
                item.setCheckState(Qt.CheckState.Checked if entry.get("kept")
                                   else Qt.CheckState.Unchecked)
                item.setData(Qt.ItemDataRole.UserRole, dict(entry))
                step = entry.get("step")
                item.setToolTip(f"tried at step {step}" if step else "kept by the loop")
                self.effects.addItem(item)
            self.effects_note.setText("Refit identifies the 21 errors again with the checked "
                                      "effects and replaces the loop's identification.")
        else:
            for effect in record.report.get("effects", []):
                self.effects.addItem(f"{effect.get('kind')} {effect.get('axis') or ''} (kept)")
            self.effects_note.setText("This loop was stored without its effect definitions "
                                      "(by an older volucal): close the loop again to accept or "
                                      "reject effects.")
        self.effects.blockSignals(False)

    def _effects_edited(self, _item: QListWidgetItem) -> None:
        self.effects_note.setText("Changed: press Refit to identify with the checked effects.")

    def _fill_unexplained(self, report: Mapping[str, Any]) -> None:
        for item in report.get("unexplained", []):
            self.unexplained.addItem(f"{item.get('where')}: {item.get('description')} "
                                     f"({_num(item.get('magnitude_um'))} µm)")
        for warning in report.get("warnings", []):
            self.unexplained.addItem(f"warning: {warning}")
        if not self.unexplained.count():
            self.unexplained.addItem("nothing: the residual shows no structure left")

    def _fill_rms(self, report: Mapping[str, Any]) -> None:
        before = self._before.readings.group_rms() if self._before and self._before.readings \
            else {}
        after = self._after.readings.group_rms() if self._after and self._after.readings else {}
        if not before:
            steps = report.get("loop", [])
            if steps:
                before = steps[0].get("rms_um_by_group", {}).get("before", {})
                kept = [s for s in steps if s.get("kept")]
                after = (kept[-1] if kept else steps[0]).get("rms_um_by_group", {}).get(
                    "after" if kept else "before", {})
        groups = [g for g in GROUP_ORDER if g in before or g in after]
        self.rms_table.setRowCount(len(groups))
        for row, group in enumerate(groups):
            unit = "urad" if group == "angular" else "um"
            for column, text in enumerate((group,
                                           self.units.text(before.get(group), unit, False, 1),
                                           self.units.text(after.get(group), unit, False, 1),
                                           self.units.symbol(unit))):
                cell = QTableWidgetItem(text)
                if column in (1, 2):
                    cell.setTextAlignment(Qt.AlignmentFlag.AlignRight
                                          | Qt.AlignmentFlag.AlignVCenter)
                self.rms_table.setItem(row, column, cell)
        self.rms_table.resizeColumnsToContents()
        item = self.rms_plot.getPlotItem()
        item.setLabel("left", f"RMS ({self.units.symbol('um')}; angular "
                              f"{self.units.symbol('urad')})")
        shown = [[self.units.value(values.get(g, 0.0) or 0.0, "urad" if g == "angular" else "um")
                  for g in groups] for values in (before, after)]
        x = np.arange(len(groups), dtype=float)
        item.addItem(pg.BarGraphItem(x=x - 0.2, height=shown[0], width=0.38,
                                     brush=plots.brush(plots.BACKWARD, 170),
                                     name="before the loop"))
        item.addItem(pg.BarGraphItem(x=x + 0.2, height=shown[1], width=0.38,
                                     brush=plots.brush(plots.FORWARD, 170),
                                     name="after the loop"))
        plots.category_ticks(item.getAxis("bottom"), groups)

    def _show_evidence(self) -> None:
        self.evidence_plot.clear()
        self.evidence_plot.getPlotItem().setLogMode(x=False, y=False)
        plots.style(self.evidence_plot.getPlotItem(), "Evidence", "", "")
        self.evidence_note.clear()
        rows = self.steps.selectionModel().selectedRows() if self.steps.selectionModel() else []
        if self.record is None or not rows:
            return
        step = self.record.report.get("loop", [])[rows[0].row()]
        use_after = self.residual_box.currentIndex() == 1
        source = self._after if use_after else self._before
        if source is None or source.readings is None or self.document.machine is None:
            self.evidence_note.setText(
                "The residuals of this loop are not in the project (it was written by an older "
                "volucal, which kept only the models): close the loop again to see the evidence "
                "plots.")
            return
        effect = dict(step.get("effect", {}))
        for candidate in self.record.candidates:
            if candidate.get("label") == effect.get("label"):
                effect["effect"] = candidate.get("effect")
        result = evidence.for_effect(source.readings, effect, self.document.machine)
        item = self.evidence_plot.getPlotItem()
        plots.style(item, result.title, result.x_label, result.y_axis(self.units))
        item.setLogMode(x=result.log_x, y=False)
        for index, series in enumerate(result.series):
            colour = plots.color(index)
            y = result.y_shown(series.y, self.units)
            if series.style == "points":
                item.addItem(pg.ScatterPlotItem(series.x, y, size=3, pen=None,
                                                brush=plots.brush(colour, 150),
                                                name=series.name if index < 8 else None))
            else:
                item.addItem(pg.PlotDataItem(series.x, y, pen=plots.pen(colour, 1.4),
                                             name=series.name if index < 8 else None))
        for x, label in result.markers:
            plots.add_marker(item, math.log10(x) if result.log_x else x, label)
        ev = effect.get("evidence", {})
        self.evidence_note.setText(
            f"{result.note}. Step {step.get('step')}: {effect.get('label')} — F = "
            f"{_num(ev.get('F'))}, log₁₀ false alarm {_num(ev.get('log10_false_alarm'))}, "
            f"magnitude {_num(ev.get('magnitude_um'))} µm, where: {ev.get('where', '—')}. "
            f"{step.get('reason', '')}")


def _kept(verdict: Any) -> str:
    """A step kept: two set-up errors kept in one refit say so, and a kept effect placed again
    (a cycle's period, a drift's time constant) is no second effect."""
    return verdict if verdict in (TOGETHER, ESTIMATED_AGAIN) else "kept"


def _rejected(verdict: Any) -> str:
    """A step not kept, with the rule that decided it (projects saved before steps recorded
    their verdict say only "rejected")."""
    return f"rejected: {verdict}" if verdict else "rejected"


def _num(value: Any) -> str:
    if value is None:
        return "—"
    try:
        number = float(value)
    except (TypeError, ValueError):
        return str(value)
    if not math.isfinite(number):
        return "—"
    return f"{number:.4g}"
