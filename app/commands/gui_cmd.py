"""``volucal gui [PROJECT.h5]``: the Qt workbench (needs the ``gui`` extra).

The core never imports Qt: the workbench is imported inside the handler, and a missing PySide6
or pyqtgraph is a message, not a traceback.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from volucal.core.userror import UserError

from . import installed
from .qt_libraries import (
    install_message,
    missing_from_import_error,
    missing_xcb_libraries,
    uses_xcb,
)

GUI_EXTRA = "the GUI needs the gui extra: pip install 'volucal[gui]'"


def handle(args: argparse.Namespace) -> int:
    if not all(installed(name) for name in ("PySide6", "pyqtgraph")):
        raise UserError(GUI_EXTRA)
    project: Path | None = args.project
    if project is not None and not project.is_file():
        raise UserError(f"{project}: no such project file")
    # pyqtgraph must use the binding the workbench is written for, never guess one.
    os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")
    if uses_xcb():
        if not (os.environ.get("DISPLAY") or os.environ.get("QT_QPA_PLATFORM")):
            raise UserError("no display to open the workbench on (DISPLAY is not set); run it "
                            "in a desktop session, or headless with QT_QPA_PLATFORM=offscreen")
        # Qt aborts the process (no exception) when an xcb library is missing: check first
        missing = missing_xcb_libraries()
        if missing:
            raise UserError(install_message(missing))
    try:
        from volucal.app.main import run
    except ImportError as exc:  # a broken Qt installation (missing system libraries)
        libraries = missing_from_import_error(str(exc))
        if libraries:
            raise UserError(install_message(libraries)) from None
        raise UserError(f"{GUI_EXTRA} ({exc})") from None
    return run(project, demo=not args.empty, smoke=args.smoke)


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser(
        "gui",
        help="open the workbench (the demo project when no project is given)",
        description=(
            "Open the volucal workbench on PROJECT.h5. Without a project it opens the demo "
            "project: the embedded demo data, calibrated once and cached."
        ),
    )
    parser.add_argument("project", type=Path, nargs="?", metavar="PROJECT.h5",
                        help="the project to open")
    parser.add_argument("--empty", action="store_true",
                        help="start with a new, empty project instead of the demo")
    parser.add_argument("--smoke", action="store_true",
                        help="open the window (and PROJECT), then quit: a check that the "
                             "installation works; the exit code is 1 when PROJECT cannot be "
                             "opened")
    parser.set_defaults(handler=handle)
