"""What every view of the main window shares: the document, a task runner, lazy refresh."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from PySide6.QtGui import QCloseEvent, QShowEvent
from PySide6.QtWidgets import QPushButton, QWidget
from volucal.core.display_units import DisplayUnits
from volucal.core.userror import UserError

from . import settings
from .dialogs import show_bug, show_error
from .document import ProjectDocument
from .tasks import CoreCall, Task, TaskRunner


class View(QWidget):
    """A view of the project. Subclasses implement :meth:`refresh` (rebuild from the document)
    and may implement :meth:`select` (show one item: a line, a result name).

    A view refreshes only while shown: a change to the document while it is hidden marks it
    stale and the refresh happens when it is shown again.
    """

    title = ""

    def __init__(self, document: ProjectDocument, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.document = document
        self.runner = TaskRunner(self)
        self.units = settings.display_units()
        self._stale = True
        document.changed.connect(self._document_changed)

    def set_units(self, units: DisplayUnits) -> None:
        """Show values in other units (View ▸ Units): redraw from the document."""
        self.units = units
        self._document_changed()

    # ---- the document ----------------------------------------------------------------------

    def set_document(self, document: ProjectDocument) -> None:
        """Show another project (File ▸ Open, New): running tasks of the old one are dropped."""
        self.runner.cancel_all()
        self.document.changed.disconnect(self._document_changed)
        self.document = document
        document.changed.connect(self._document_changed)
        self._document_changed()

    def _document_changed(self) -> None:
        self._stale = True
        if self.isVisible():
            self._refresh_now()

    def _refresh_now(self) -> None:
        self._stale = False
        self.refresh()

    def ensure_fresh(self) -> None:
        """Refresh now if the document changed while the view was hidden (before an action
        that reads the view's controls)."""
        if self._stale:
            self._refresh_now()

    def showEvent(self, event: QShowEvent) -> None:
        super().showEvent(event)
        if self._stale:
            self._refresh_now()

    def refresh(self) -> None:
        raise NotImplementedError

    def select(self, name: str | None) -> None:
        """Show the item ``name`` (a line, a result); the default view has one subject."""

    # ---- tasks -------------------------------------------------------------------------------

    def cancel_control(self, on_busy: Callable[[bool], object]) -> QPushButton:
        """The view's Cancel button (enabled while its runner is busy); ``on_busy`` also hears
        the runner's busy state, to disable the view's own action buttons meanwhile."""
        cancel = QPushButton("Cancel")
        cancel.setEnabled(False)
        cancel.clicked.connect(self.runner.cancel_all)
        self.runner.busyChanged.connect(cancel.setEnabled)
        self.runner.busyChanged.connect(on_busy)
        return cancel

    def run_task(self, title: str, call: CoreCall, on_success: Callable[[Any], object],
                 on_cancel: Callable[[], object] | None = None) -> Task:
        """Start ``call`` in a worker; one computation per view at a time."""
        if self.runner.busy:
            raise UserError(f"{self.title}: a computation is already running; wait for it or "
                            "cancel it")
        return self.runner.run(title, call, on_success, self.task_failed, self.task_crashed,
                               on_cancel)

    def task_failed(self, message: str) -> None:
        show_error(self, f"{self.title}: cannot complete", message)
        self.task_ended()

    def task_crashed(self, text: str) -> None:
        show_bug(self, f"{self.title}: internal error", text)
        self.task_ended()

    def task_ended(self) -> None:
        """Called after a failure; views re-enable their controls here."""

    def closeEvent(self, event: QCloseEvent) -> None:
        self.runner.shutdown()
        super().closeEvent(event)
