"""What the calibration report states beyond the measurement: the tolerances per axis and the
certificate fields, each in a dialog that writes them into the project (undoable).

Both dialogs open with :meth:`QDialog.open` (window-modal, the event loop keeps running) and
apply their values on ``accepted``; tests fill the fields and call :meth:`accept`.
"""

from __future__ import annotations

import math
from pathlib import Path

from PySide6.QtWidgets import (
    QComboBox,
    QDialog,
    QDialogButtonBox,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)
from volucal.core.certificate import FIELDS, Certificate
from volucal.core.conformance import QUANTITIES as CONFORMANCE_QUANTITIES
from volucal.core.display_units import DisplayUnits
from volucal.core.machine import AXES
from volucal.core.tolerances import QUANTITIES, Tolerances
from volucal.core.userror import UserError

from .settings import last_folder

CONFORMANCE_CHOICES = (
    ("", "no overall decision"),
    ("accuracy", "accuracy A of every linear line (ISO 230-2)"),
    ("volumetric", "largest volumetric error |E| over the workspace"),
)


class TolerancesDialog(QDialog):
    """Edit ▸ Tolerances: the ISO 230-2 limits per axis (empty: not checked), typed in the
    length unit the views show."""

    def __init__(self, tolerances: Tolerances, units: DisplayUnits,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle("Tolerances per axis (ISO 230-2)")
        self.setObjectName("tolerancesDialog")
        self.units = units
        symbol = units.symbol("um")
        grid = QGridLayout()
        grid.addWidget(QLabel("axis"), 0, 0)
        for column, key in enumerate(QUANTITIES, start=1):
            label = QLabel(f"{key} ({symbol})")
            label.setToolTip(QUANTITIES[key])
            grid.addWidget(label, 0, column)
        self.fields: dict[tuple[str, str], QLineEdit] = {}
        for row, axis in enumerate(AXES, start=1):
            grid.addWidget(QLabel(axis), row, 0)
            for column, key in enumerate(QUANTITIES, start=1):
                edit = QLineEdit()
                edit.setPlaceholderText("—")
                edit.setToolTip(f"limit of the {QUANTITIES[key]} of axis {axis}, {symbol}; "
                                "empty: not checked")
                limit = tolerances.limit(axis, key)
                if limit is not None:
                    edit.setText(units.text(limit, "um", with_symbol=False))
                grid.addWidget(edit, row, column)
                self.fields[(axis, key)] = edit
        note = QLabel("Every linear line along an axis is checked against that axis' limits: "
                      "the value against the limit (pass/fail), and the ISO 14253-1 decision "
                      "with the expanded uncertainty of the value from the plan's budget.")
        note.setWordWrap(True)
        self.error = QLabel()
        self.error.setStyleSheet("color: #c00000")
        buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Ok
                                   | QDialogButtonBox.StandardButton.Cancel)
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        layout = QVBoxLayout(self)
        layout.addLayout(grid)
        layout.addWidget(note)
        layout.addWidget(self.error)
        layout.addWidget(buttons)
        self.result_tolerances: Tolerances | None = None

    def set_limit(self, axis: str, quantity: str, value: float | None) -> None:
        """Type a limit (display unit) as the user does."""
        self.fields[(axis, quantity)].setText("" if value is None else f"{value:g}")

    def tolerances(self) -> Tolerances:
        """The limits typed, in µm; raises UserError naming a field that is not a number."""
        limits: dict[str, dict[str, float]] = {}
        for (axis, key), edit in self.fields.items():
            text = edit.text().strip().replace(",", ".")
            if not text:
                continue
            try:
                value = float(text)
            except ValueError:
                raise UserError(f"{key} of axis {axis}: {text!r} is not a number") from None
            if not (math.isfinite(value) and value > 0):
                raise UserError(f"{key} of axis {axis}: give a positive limit")
            limits.setdefault(axis, {})[key] = self.units.to_core(value, "um")
        return Tolerances(limits)

    def accept(self) -> None:
        try:
            self.result_tolerances = self.tolerances()
        except UserError as exc:
            self.error.setText(str(exc))
            return
        super().accept()


class ReportDialog(QDialog):
    """File ▸ Report (PDF)…: the certificate fields, the overall decision, where the
    compensation files are and the PDF to write."""

    def __init__(self, certificate: Certificate, pdf_path: Path,
                 compensation_dir: Path | None, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle("Calibration report")
        self.setObjectName("reportDialog")
        self.resize(620, 560)
        form = QFormLayout()
        self.fields: dict[str, QLineEdit] = {}
        for key, label in FIELDS:
            edit = QLineEdit(certificate.get(key))
            edit.setObjectName(f"certificate_{key}")
            form.addRow(label, edit)
            self.fields[key] = edit
        certificate_box = QGroupBox("Certificate (kept with the project)")
        certificate_box.setLayout(form)

        self.decision = QComboBox()
        self.decision.setObjectName("conformanceBox")
        for key, text in CONFORMANCE_CHOICES:
            self.decision.addItem(text, key)
        self.tolerance = QDoubleSpinBox()
        self.tolerance.setRange(0.01, 100000.0)
        self.tolerance.setDecimals(2)
        self.tolerance.setSuffix(" µm")
        self.tolerance.setValue(25.0)
        self.tolerance.setEnabled(False)
        self.decision.currentIndexChanged.connect(
            lambda _i: self.tolerance.setEnabled(bool(self.decision.currentData())))
        decision_row = QHBoxLayout()
        decision_row.addWidget(self.decision, 1)
        decision_row.addWidget(QLabel("T"))
        decision_row.addWidget(self.tolerance)
        self.compensation = QLineEdit("" if compensation_dir is None else str(compensation_dir))
        self.compensation.setPlaceholderText("the folder the controller's files were written to")
        browse_folder = QPushButton("…")
        browse_folder.clicked.connect(self._browse_folder)
        folder_row = QHBoxLayout()
        folder_row.addWidget(self.compensation, 1)
        folder_row.addWidget(browse_folder)
        self.output = QLineEdit(str(pdf_path))
        self.output.setObjectName("reportOutput")
        browse_pdf = QPushButton("…")
        browse_pdf.clicked.connect(self._browse_pdf)
        output_row = QHBoxLayout()
        output_row.addWidget(self.output, 1)
        output_row.addWidget(browse_pdf)
        other = QFormLayout()
        other.addRow("overall decision (ISO 14253-1)", decision_row)
        other.addRow("compensation files", folder_row)
        other.addRow("PDF", output_row)
        note = QLabel("The ISO 230-2 tolerances per axis (Edit ▸ Tolerances…) are checked in the "
                      "report; values are shown in the units of View ▸ Units.")
        note.setWordWrap(True)
        self.error = QLabel()
        self.error.setStyleSheet("color: #c00000")
        self.error.setWordWrap(True)
        buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Ok
                                   | QDialogButtonBox.StandardButton.Cancel)
        buttons.button(QDialogButtonBox.StandardButton.Ok).setText("Write the report")
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        layout = QVBoxLayout(self)
        layout.addWidget(certificate_box)
        layout.addLayout(other)
        layout.addWidget(note)
        layout.addWidget(self.error)
        layout.addWidget(buttons)

    def certificate(self) -> Certificate:
        return Certificate({key: edit.text().strip() for key, edit in self.fields.items()
                            if edit.text().strip()})

    def conformance(self) -> tuple[str | None, float | None]:
        """(quantity, tolerance µm) of the overall decision, or (None, None)."""
        key = self.decision.currentData()
        return (str(key), self.tolerance.value()) if key else (None, None)

    def set_conformance(self, quantity: str, tolerance_um: float) -> None:
        if quantity not in CONFORMANCE_QUANTITIES:
            raise UserError(f"conformance on {quantity!r}: use {', '.join(CONFORMANCE_QUANTITIES)}")
        self.decision.setCurrentIndex(self.decision.findData(quantity))
        self.tolerance.setValue(tolerance_um)

    def compensation_dir(self) -> Path | None:
        text = self.compensation.text().strip()
        return Path(text) if text else None

    def pdf_path(self) -> Path:
        path = Path(self.output.text().strip())
        return path if path.suffix.lower() == ".pdf" else path.with_suffix(".pdf")

    def accept(self) -> None:
        folder = self.compensation_dir()
        if folder is not None and not folder.is_dir():
            self.error.setText(f"{folder}: no such folder; leave it empty when the compensation "
                               "files are not at hand (the report then gives no checksums)")
            return
        if not self.output.text().strip():
            self.error.setText("choose where to write the PDF")
            return
        if not self.pdf_path().parent.is_dir():
            self.error.setText(f"{self.pdf_path().parent}: no such folder")
            return
        super().accept()

    def _browse_folder(self) -> None:
        chosen = QFileDialog.getExistingDirectory(self, "Compensation files", last_folder())
        if chosen:
            self.compensation.setText(chosen)

    def _browse_pdf(self) -> None:
        chosen, _ = QFileDialog.getSaveFileName(self, "Write the calibration report",
                                                self.output.text(), "PDF (*.pdf)")
        if chosen:
            self.output.setText(chosen)
