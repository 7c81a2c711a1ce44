"""Small dialogs: errors, the About box, preferences.

Errors are shown with :meth:`QMessageBox.open` (window-modal, non-blocking), never ``exec``: the
event loop keeps running, a worker's result can still arrive, and tests can read the dialog.
"""

from __future__ import annotations

import logging
import platform
import sys
from importlib import metadata

from PySide6 import QtCore
from PySide6.QtWidgets import (
    QCheckBox,
    QDialog,
    QDialogButtonBox,
    QDoubleSpinBox,
    QFormLayout,
    QMessageBox,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from .settings import Preferences

log = logging.getLogger("volucal.app")


def show_error(parent: QWidget | None, title: str, message: str, details: str | None = None
               ) -> QMessageBox:
    """The core's message in a dialog (a traceback only under "Show Details…", for bugs)."""
    box = QMessageBox(QMessageBox.Icon.Warning, title, message, QMessageBox.StandardButton.Ok,
                      parent)
    box.setObjectName("errorDialog")
    box.setTextInteractionFlags(QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
    if details:
        box.setDetailedText(details)
    box.setAttribute(QtCore.Qt.WidgetAttribute.WA_DeleteOnClose)
    box.open()
    log.warning("%s: %s", title, message)
    return box


def show_bug(parent: QWidget | None, title: str, traceback_text: str) -> QMessageBox:
    return show_error(
        parent, title,
        "volucal met an internal error. The project is unchanged. Please report it with the "
        "details below.",
        traceback_text,
    )


def versions() -> dict[str, str]:
    """Versions of volucal and of what it runs on, for the About box and bug reports."""
    from PySide6 import __version__ as pyside_version
    from PySide6.QtCore import qVersion

    out = {"volucal": _version("volucal"), "Python": platform.python_version()}
    for name in ("numpy", "scipy", "h5py", "numba", "pyqtgraph"):
        out[name] = _version(name)
    out["PySide6"] = pyside_version
    out["Qt"] = qVersion()
    out["platform"] = f"{platform.system()} {platform.release()} ({sys.platform})"
    return out


def _version(name: str) -> str:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "not installed"


def about_box(parent: QWidget | None) -> QMessageBox:
    rows = "".join(f"<tr><td>{k}</td><td>&nbsp;{v}</td></tr>" for k, v in versions().items())
    text = (
        "<h3>volucal</h3>"
        "<p>Volumetric calibration of 3-axis CNC machine tools: laser-log import, "
        "identification of the 21 geometric errors, closed-loop residual analysis, EFAST "
        "sensitivity and controller compensation tables.</p>"
        f"<table>{rows}</table>"
    )
    box = QMessageBox(QMessageBox.Icon.Information, "About volucal", text,
                      QMessageBox.StandardButton.Ok, parent)
    box.setObjectName("aboutBox")
    box.setTextFormat(QtCore.Qt.TextFormat.RichText)
    box.setAttribute(QtCore.Qt.WidgetAttribute.WA_DeleteOnClose)
    box.open()
    return box


class PreferencesDialog(QDialog):
    """Edit ▸ Preferences: defaults of the identification, loop, sensitivity and export."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle("Preferences")
        self.setObjectName("preferencesDialog")
        prefs = Preferences.load()
        form = QFormLayout()
        self.spacing = _double(prefs.identify_spacing_mm, 5.0, 1000.0, " mm")
        self.spacing.setToolTip("knot spacing of the cubic B-splines of every error function")
        self.margin = _double(100 * prefs.loop_margin, 0.0, 100.0, " %")
        self.margin.setToolTip("cross-validated improvement an effect must bring to be kept")
        self.steps = QSpinBox()
        self.steps.setRange(1, 20)
        self.steps.setValue(prefs.loop_max_steps)
        self.drop = QCheckBox("leave out readings flagged as outliers on import")
        self.drop.setChecked(prefs.drop_outliers)
        self.n = QSpinBox()
        self.n.setRange(65, 20000)
        self.n.setSingleStep(100)
        self.n.setValue(prefs.sensitivity_n)
        self.n.setToolTip("EFAST samples per search curve (the paper: 1400)")
        self.map_step = _double(prefs.map_step_mm, 5.0, 500.0, " mm")
        self.export_spacing = _double(prefs.export_spacing_mm, 0.5, 500.0, " mm")
        self.recent = QSpinBox()
        self.recent.setRange(1, 30)
        self.recent.setValue(prefs.max_recent)
        form.addRow("B-spline knot spacing", self.spacing)
        form.addRow("loop: keep an effect above", self.margin)
        form.addRow("loop: at most steps", self.steps)
        form.addRow("import", self.drop)
        form.addRow("EFAST samples N", self.n)
        form.addRow("workspace map step", self.map_step)
        form.addRow("compensation table spacing", self.export_spacing)
        form.addRow("recent projects kept", self.recent)
        buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Ok
                                   | QDialogButtonBox.StandardButton.Cancel)
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(buttons)

    def preferences(self) -> Preferences:
        return Preferences(
            identify_spacing_mm=self.spacing.value(),
            loop_margin=self.margin.value() / 100.0,
            loop_max_steps=self.steps.value(),
            drop_outliers=self.drop.isChecked(),
            sensitivity_n=self.n.value(),
            map_step_mm=self.map_step.value(),
            export_spacing_mm=self.export_spacing.value(),
            max_recent=self.recent.value(),
        )

    def accept(self) -> None:
        self.preferences().save()
        super().accept()


def _double(value: float, low: float, high: float, suffix: str) -> QDoubleSpinBox:
    box = QDoubleSpinBox()
    box.setRange(low, high)
    box.setDecimals(2)
    box.setSuffix(suffix)
    box.setValue(value)
    return box
