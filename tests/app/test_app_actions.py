"""Every action of the main window, triggered through Qt as a click or a shortcut does it.

The window holds the demo project as ``volucal calibrate`` writes it. Each QAction of every menu
(and tool bar) is triggered with ``action.trigger()`` — so that Qt hands the slot exactly what it
hands it for the user, ``triggered(checked)`` included — file dialogs and questions are answered
by monkeypatched static methods, and the dialogs an action opens are filled and accepted or
closed. Any exception raised in a slot fails the test (pytest-qt's exception capture), and so
does an "internal error" box.
"""

from pathlib import Path

import pytest
from PySide6.QtWidgets import (
    QDialog,
    QFileDialog,
    QMenu,
    QMessageBox,
    QToolBar,
    QWizard,
)
from volucal.app import settings
from volucal.app.dialogs import PreferencesDialog
from volucal.app.mainwindow import MainWindow
from volucal.app.report_dialog import ReportDialog, TolerancesDialog
from volucal.app.user_guide import UserGuide
from volucal.core.project import Project
from volucal.core.tolerances import Tolerances

#: Actions that replace or close the project: triggered last, in this order.
LAST = ("Open recent", "File ▸ Open…", "New project", "Open the demo project", "Quit")
#: A computation longer than this is cancelled (the loop on the 49 demo lines takes minutes).
WAIT_S = 150
CANCEL_AFTER_S = {"Close the loop": 3.0}


def menu_actions(window):
    """(menu path, action) of every action in the menu bar, submenus and tool bars."""
    found = []

    def walk(menu: QMenu, path: str) -> None:
        menu.aboutToShow.emit()  # menus filled when shown (recent projects)
        for action in menu.actions():
            if action.isSeparator():
                continue
            text = action.text().replace("&", "")
            if action.menu() is not None:
                walk(action.menu(), f"{path} ▸ {text}")
            else:
                found.append((f"{path} ▸ {text}", action))

    for top in window.menuBar().actions():
        walk(top.menu(), top.text().replace("&", ""))
    for bar in window.findChildren(QToolBar):
        found += [(f"toolbar ▸ {a.text()}", a) for a in bar.actions() if not a.isSeparator()]

    def order(item):
        path, _action = item
        for rank, text in enumerate(LAST):
            if text in path:
                return 1 + rank
        return 0

    return sorted(found, key=order)


def visible_dialogs(window):
    """The dialogs open over the window. Asked of its children, not of every top-level widget:
    the wrappers PySide keeps for widgets Qt made and deleted itself (popups, tooltips) can
    outlive them, and reading one crashed the process now and then."""
    return [w for w in window.findChildren(QDialog) if w.isVisible()]


@pytest.fixture
def answered(monkeypatch, tmp_path, demo_run):
    """File dialogs and questions answered as a user would; what was asked is recorded."""
    asked = []
    plots = tmp_path / "plots"
    plots.mkdir()

    def save_name(parent, caption, directory="", filters="", *args, **kwargs):
        asked.append(caption)
        name = "report.pdf" if "report" in caption.lower() else "saved-as.h5"
        return str(tmp_path / name), ""

    def open_name(parent, caption, directory="", filters="", *args, **kwargs):
        asked.append(caption)
        if "re-measurement" in caption.lower():
            return str(demo_run / "demo.h5"), ""
        return "", ""  # File ▸ Open… cancelled: the demo project stays

    def folder(parent, caption, directory="", *args, **kwargs):
        asked.append(caption)
        return str(plots)

    def question(parent, title, text, *args, **kwargs):
        asked.append(title)
        return (QMessageBox.StandardButton.Save if title == "Calibration report"
                else QMessageBox.StandardButton.Discard)

    monkeypatch.setattr(QFileDialog, "getSaveFileName", save_name)
    monkeypatch.setattr(QFileDialog, "getOpenFileName", open_name)
    monkeypatch.setattr(QFileDialog, "getExistingDirectory", folder)
    monkeypatch.setattr(QMessageBox, "question", question)
    return asked


def answer_dialogs(qtbot, window, before, messages):
    """Fill and accept (or close) the dialogs the last action opened."""
    for dialog in visible_dialogs(window):
        if dialog in before:
            continue
        if isinstance(dialog, ReportDialog):
            dialog.fields["customer"].setText("ACME Tooling")
            dialog.accept()
        elif isinstance(dialog, TolerancesDialog):
            dialog.set_limit("X", "A", 20.0)
            dialog.set_limit("Y", "E", 15.0)
            dialog.accept()
            kept = Tolerances.of_project(window.document.project)
            assert kept.limit("X", "A") == pytest.approx(20.0)
        elif isinstance(dialog, PreferencesDialog):
            dialog.accept()
        elif isinstance(dialog, UserGuide):
            assert "volucal" in dialog.page_text()
            dialog.close()
        elif isinstance(dialog, QWizard):
            dialog.reject()
        elif isinstance(dialog, QMessageBox):
            messages.append(f"{dialog.windowTitle()}: {dialog.text()}")
            dialog.close()
        else:
            dialog.close()
        qtbot.wait(10)


def wait_for_tasks(qtbot, window, name):
    runners = [window.runner] + [v.runner for v in window.views.values()]
    limit = CANCEL_AFTER_S.get(name.rsplit(" ▸ ", 1)[-1])
    if limit is not None:
        qtbot.wait(int(1000 * limit))
        window.cancel_tasks()
    qtbot.waitUntil(lambda: not any(r.busy for r in runners), timeout=1000 * WAIT_S)


def test_every_action_of_every_menu_runs(qtbot, demo_project, answered, tmp_path,
                                         isolated_settings):
    settings.Preferences(sensitivity_n=200).save()
    window = MainWindow()
    qtbot.addWidget(window, before_close_func=lambda w: w.document.undo_stack.setClean())
    window.show()
    assert window.open_project(demo_project)
    actions = menu_actions(window)
    names = [name for name, _ in actions]
    for expected in ("File ▸ Report (PDF)…", "File ▸ Save as…", "Help ▸ User guide",
                     "Edit ▸ Tolerances per axis…", "View ▸ Units ▸ arcsec",
                     "File ▸ Open a re-measurement…", "File ▸ Export the plots of this view…"):
        assert expected in names, expected
    messages: list[str] = []
    triggered = []
    for name, action in actions:
        if not action.isEnabled() or not window.isVisible():
            continue
        before = visible_dialogs(window)
        with qtbot.captureExceptions() as exceptions:
            action.trigger()
            qtbot.wait(20)
            answer_dialogs(qtbot, window, before, messages)
            wait_for_tasks(qtbot, window, name)
            answer_dialogs(qtbot, window, before, messages)
        assert not exceptions, f"{name}: {exceptions[0][1]!r}"
        triggered.append(name)
    bugs = [m for m in messages if "internal error" in m]
    assert not bugs, bugs
    assert "File ▸ Quit" in triggered and not window.isVisible()

    # what the actions did, checked on their files
    assert (tmp_path / "saved-as.h5").is_file()
    # Save as came first (the report asks to save, and names the saved file)
    pdf = tmp_path / "saved-as.pdf"
    assert pdf.is_file() and pdf.read_bytes().startswith(b"%PDF")
    assert Project.open(tmp_path / "saved-as.h5").lines
    exported = sorted(p.suffix for p in (tmp_path / "plots").iterdir())
    assert {".png", ".svg", ".csv"} <= set(exported)


def test_save_as_and_report_shortcuts_reach_their_dialogs(qtbot, window, answered, tmp_path):
    """Ctrl+Shift+S and Ctrl+R: triggered(bool) never arrives as a path."""
    actions = {a.shortcut().toString(): a for a in window.actions()}
    with qtbot.captureExceptions() as exceptions:
        actions["Ctrl+Shift+S"].trigger()
    assert not exceptions
    assert (tmp_path / "saved-as.h5").is_file()
    assert window.document.path == tmp_path / "saved-as.h5"
    with qtbot.captureExceptions() as exceptions:
        actions["Ctrl+R"].trigger()
    assert not exceptions
    dialog = window.report_dialog
    assert isinstance(dialog, ReportDialog) and dialog.isVisible()
    assert Path(dialog.output.text()) == tmp_path / "saved-as.pdf"
    dialog.reject()
