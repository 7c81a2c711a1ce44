"""The project's thermal records in the main window: pick a record and a channel, see its model.

A record is stored by ``volucal thermal FILE --project P.h5`` (core/thermal_store.py) with the
model it was given; this view shows it as fitted (:class:`~volucal.app.thermal_view.ThermalView`)
and never fits again.
"""

from __future__ import annotations

from PySide6.QtWidgets import QComboBox, QHBoxLayout, QLabel, QVBoxLayout, QWidget
from volucal.core.thermal_store import load_thermal, load_thermal_result, thermal_names
from volucal.core.userror import UserError

from .document import ProjectDocument
from .thermal_view import ThermalView
from .view_base import View


class ThermalRecordsView(View):
    title = "Thermal"

    def __init__(self, document: ProjectDocument, parent: QWidget | None = None) -> None:
        super().__init__(document, parent)
        self.record = QComboBox()
        self.record.setObjectName("thermalRecord")
        self.channel = QComboBox()
        self.channel.setObjectName("thermalChannel")
        self.record.currentTextChanged.connect(self._record_chosen)
        self.channel.currentTextChanged.connect(self._show)
        self.note = QLabel()
        self.note.setWordWrap(True)
        self.view = ThermalView()
        top = QHBoxLayout()
        top.addWidget(QLabel("Record"))
        top.addWidget(self.record, 1)
        top.addWidget(QLabel("Channel"))
        top.addWidget(self.channel, 1)
        layout = QVBoxLayout(self)
        layout.addLayout(top)
        layout.addWidget(self.note)
        layout.addWidget(self.view, 1)

    def refresh(self) -> None:
        names = thermal_names(self.document.project)
        current = self.record.currentText()
        self.record.blockSignals(True)
        self.record.clear()
        self.record.addItems(names)
        if current in names:
            self.record.setCurrentText(current)
        self.record.blockSignals(False)
        if not names:
            self.note.setText(
                "The project holds no thermal record. Fit one with `volucal thermal FILE "
                "--project` (error and temperature channels over time); it shows here."
            )
            self.channel.clear()
            self.view.set_result(None)
            return
        self.note.setText("")
        self._record_chosen(self.record.currentText())

    def select(self, name: str | None) -> None:
        if name and name in thermal_names(self.document.project):
            self.record.setCurrentText(name)

    def _record_chosen(self, name: str) -> None:
        self.channel.blockSignals(True)
        self.channel.clear()
        if name:
            try:
                self.channel.addItems(list(load_thermal(self.document.project, name).results))
            except UserError as exc:
                self.note.setText(str(exc))
        self.channel.blockSignals(False)
        self._show()

    def _show(self, *_: object) -> None:
        name, channel = self.record.currentText(), self.channel.currentText()
        if not name or not channel:
            self.view.set_result(None)
            return
        try:
            result = load_thermal_result(self.document.project, name, channel)
        except UserError as exc:
            self.note.setText(str(exc))
            self.view.set_result(None)
            return
        self.view.set_result(result)
