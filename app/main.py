"""Starting the workbench: ``volucal gui [PROJECT.h5]`` (app/commands/gui_cmd.py) calls
:func:`run`."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

from PySide6.QtCore import QTimer
from PySide6.QtWidgets import QApplication

from . import settings
from .mainwindow import MainWindow


def application() -> QApplication:
    """The QApplication, created once, named so that settings and caches have a home."""
    from volucal import __version__

    existing = QApplication.instance()
    app = existing if isinstance(existing, QApplication) else QApplication(sys.argv[:1])
    app.setOrganizationName(settings.ORGANIZATION)
    app.setApplicationName(settings.APPLICATION)
    app.setApplicationDisplayName("volucal")
    app.setApplicationVersion(__version__)
    return app


def run(project: Path | None = None, demo: bool = True, smoke: bool = False) -> int:
    """Show the main window with ``project``, or the demo project when none is given and
    ``demo``; ``smoke`` opens the window (and the project), then quits: a packaging check whose
    exit code is 1 when the project cannot be opened."""
    app = application()
    if smoke:
        # no one looks at the window: the reason a project does not open goes to stderr
        handler = logging.StreamHandler()
        handler.setLevel(logging.WARNING)
        logging.getLogger("volucal").addHandler(handler)
    window = MainWindow()
    window.show()
    status = 0
    if project is not None:
        if not window.open_project(project):
            status = 1
    elif demo and not smoke:
        window.open_demo()
    if smoke:
        QTimer.singleShot(0, window.close)
        app.exec()
        return status
    return int(app.exec())
