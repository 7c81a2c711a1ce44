"""The main window: files, recent projects, undo/redo, settings, About, the gui command, and
the worker rules (results never reach a closed widget)."""

import sys
import threading
from dataclasses import replace
from pathlib import Path

import pytest
from PySide6.QtCore import QObject
from PySide6.QtWidgets import QLabel, QMessageBox
from volucal.app import settings, tasks
from volucal.app.dialogs import PreferencesDialog, versions
from volucal.app.mainwindow import MainWindow
from volucal.core.cli import main
from volucal.core.project import Project
from volucal.core.userror import UserError


def test_edit_undo_redo_save_and_reopen(qtbot, window, tmp_path):
    document = window.document
    assert not window.isWindowModified()
    view = window.show_view("machine")
    view.name.setText("VMC-400 bay 3")
    view.tool[2].setValue(150.0)
    view.apply()
    assert document.machine.name == "VMC-400 bay 3"
    assert document.machine.tool_offset_mm == (0.0, 0.0, 150.0)
    assert window.isWindowModified()
    assert window.tree.topLevelItem(0).text(0) == "Machine: VMC-400 bay 3"
    window.undo_action.trigger()
    assert document.machine.name != "VMC-400 bay 3"
    assert not window.isWindowModified()
    window.redo_action.trigger()
    assert document.machine.name == "VMC-400 bay 3"

    target = tmp_path / "saved.h5"
    assert window.save_as(target)
    assert not window.isWindowModified()
    assert settings.recent_projects()[0] == target.resolve()
    assert Project.open(target).machine.name == "VMC-400 bay 3"

    window.tree.remove("measurements", "x_lin_1")
    assert "x_lin_1" not in document.line_names()
    window.tree.remove("sensitivity", "main")
    assert document.results("sensitivity") == []
    window.undo_action.trigger()
    window.undo_action.trigger()
    assert "x_lin_1" in document.line_names() and document.results("sensitivity") == ["main"]

    other = MainWindow()
    qtbot.addWidget(other)
    assert other.open_project(settings.recent_projects()[0])
    assert other.document.machine.tool_offset_mm == (0.0, 0.0, 150.0)


def test_the_machine_geometry_of_a_measured_project_cannot_change(window):
    machine = window.document.machine
    with pytest.raises(UserError, match="cannot change"):
        window.document.set_machine(replace(machine, stroke_mm={**machine.stroke_mm,
                                                                "X": (0.0, 500.0)}))
    assert window.document.machine == machine
    assert window.document.undo_stack.count() == 0


def test_tree_selection_shows_the_item(qtbot, window):
    assert window.tree.choose("measurements", "y_lin_2")
    assert window.stack.currentWidget() is window.views["measurement"]
    assert window.views["measurement"].line_box.currentText() == "y_lin_2"
    result = window.views["measurement"].result
    assert result is not None and result.runs_up == 2 and result.runs_down == 2
    assert window.tree.choose("identifications", "main")
    assert window.views["identification"].record.name == "main"
    assert window.tree.choose("loops", "main")
    assert window.stack.currentWidget() is window.views["loop"]


def test_shortcuts_switch_views(qtbot, window):
    actions = {a.shortcut().toString(): a for a in window.actions()}
    actions["Ctrl+4"].trigger()
    assert window.stack.currentWidget() is window.views["loop"]
    assert "F5" in actions and "F6" in actions and "Ctrl+I" in actions


def test_preferences_are_saved_in_the_isolated_settings(qtbot, window, isolated_settings):
    dialog = window.preferences()
    assert isinstance(dialog, PreferencesDialog)
    dialog.n.setValue(800)
    dialog.margin.setValue(5.0)
    dialog.accept()
    prefs = settings.Preferences.load()
    assert prefs.sensitivity_n == 800 and prefs.loop_margin == pytest.approx(0.05)
    assert any(p.suffix == ".ini" for p in Path(isolated_settings).rglob("*"))


def test_about_box_lists_the_versions(qtbot, window):
    from volucal.app.dialogs import about_box

    box = about_box(window)
    text = box.text()
    for name, version in versions().items():
        assert name in text and version in text
    assert versions()["Python"] == ".".join(map(str, sys.version_info[:3]))
    box.close()


def test_the_gui_command(qtbot, tmp_path, monkeypatch, capsys):
    assert main(["gui", "--smoke", "--empty"]) == 0
    assert main(["gui", str(tmp_path / "missing.h5")]) == 1
    assert "missing.h5: no such project file" in capsys.readouterr().err
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "PySide6" else real(name, *a))
    assert main(["gui", "--empty"]) == 1
    assert "the GUI needs the gui extra: pip install 'volucal[gui]'" in capsys.readouterr().err


def test_the_gui_command_opens_a_project(qtbot, small_project):
    assert main(["gui", "--smoke", str(small_project)]) == 0


def test_results_never_reach_a_closed_widget(qtbot):
    owner = QLabel()
    runner = tasks.TaskRunner(owner)
    release = threading.Event()
    received = []
    task = runner.run("wait", lambda progress, cancel: release.wait(10) and "result",
                      received.append)
    assert task.running
    owner.close()
    runner.shutdown()  # what a view's closeEvent does
    release.set()
    assert tasks.wait_for_all(10_000)
    qtbot.wait(50)
    assert received == []
    with pytest.raises(RuntimeError, match="closed"):
        runner.run("again", lambda p, c: None, received.append)


def test_a_destroyed_owner_gets_nothing_either(qtbot):
    owner = QObject()
    release = threading.Event()
    received = []
    task = tasks.Task("wait", lambda progress, cancel: release.wait(10) and 1, owner)
    task.succeeded.connect(received.append)
    task.start()
    owner.deleteLater()
    qtbot.wait(20)
    release.set()
    assert tasks.wait_for_all(10_000)
    qtbot.wait(50)
    assert received == []


def test_task_outcomes_reach_the_owner(qtbot):
    owner = QLabel()
    runner = tasks.TaskRunner(owner)
    outcomes = []

    def failing(progress, cancel):
        progress(0.5, "half way")
        raise UserError("plan.toml, line 3: start: expected three numbers")

    task = runner.run("fails", failing, outcomes.append, outcomes.append)
    with qtbot.waitSignal(task.ended, timeout=10_000):
        pass
    assert outcomes == ["plan.toml, line 3: start: expected three numbers"]

    def cancelled(progress, cancel):
        while not cancel.cancelled:
            cancel.check()
        cancel.check()

    task = runner.run("cancelled", cancelled, outcomes.append,
                      on_cancel=lambda: outcomes.append("cancelled"))
    task.cancel()
    with qtbot.waitSignal(task.ended, timeout=10_000):
        pass
    assert outcomes[-1] == "cancelled"

    crashes = []
    task = runner.run("bug", lambda p, c: 1 / 0, outcomes.append, on_crash=crashes.append)
    with qtbot.waitSignal(task.ended, timeout=10_000):
        pass
    assert "ZeroDivisionError" in crashes[0]


def test_many_qt_calls_keep_none_alive(qtbot):
    """PySide6 6.12.0 loses a reference to None on every void call under Python 3.11 and the
    interpreter aborts after a few thousand (pyproject pins the binding below 6.12)."""
    label = QLabel()
    before = sys.getrefcount(None)
    for _ in range(20_000):
        label.setText("x")
    assert sys.getrefcount(None) >= before - 100


def test_a_failing_save_shows_the_message(qtbot, window, tmp_path):
    blocked = tmp_path / "file"
    blocked.write_text("x")
    assert not window.save_as(blocked / "project.h5")
    dialogs = [w for w in window.findChildren(QMessageBox) if w.isVisible()]
    assert dialogs and "project.h5" in dialogs[0].text()
    dialogs[0].close()


def test_the_report_action_writes_the_pdf(qtbot, window, wait_idle, tmp_path, monkeypatch):
    """File ▸ Report: unsaved changes are saved after asking, the dialog writes the PDF."""
    asked = []
    monkeypatch.setattr(QMessageBox, "question",
                        lambda parent, title, text, *a: asked.append(text)
                        or QMessageBox.StandardButton.Save)
    window.show_view("machine").name.setText("VMC-400 bay 3")
    window.views["machine"].apply()
    assert not window.document.is_clean
    pdf = tmp_path / "report.pdf"
    dialog = window.write_report(pdf)
    assert asked and "Save the project now?" in asked[0] and window.document.is_clean
    dialog.accept()
    wait_idle(window)
    assert pdf.is_file() and pdf.read_bytes().startswith(b"%PDF")
    assert window.status_text.text().startswith("report written: report.pdf")


def test_the_report_is_not_written_when_the_user_does_not_save(qtbot, window, tmp_path,
                                                                 monkeypatch):
    monkeypatch.setattr(QMessageBox, "question",
                        lambda *a: QMessageBox.StandardButton.Cancel)
    window.show_view("machine").name.setText("changed")
    window.views["machine"].apply()
    assert window.write_report(tmp_path / "report.pdf") is None
    assert not window.document.is_clean and not (tmp_path / "report.pdf").exists()


def test_missing_xcb_libraries_are_named_with_the_apt_line(qtbot, monkeypatch, capsys):
    from volucal.app.commands import gui_cmd, qt_libraries

    ldd = ("\tlinux-vdso.so.1 (0x00007ffd)\n"
           "\tlibxcb-icccm.so.4 => not found\n"
           "\tlibxcb-keysyms.so.1 => not found\n"
           "\tlibxcb.so.1 => /lib/x86_64-linux-gnu/libxcb.so.1 (0x00007f)\n")
    assert qt_libraries.missing_from_ldd(ldd) == ["libxcb-icccm.so.4", "libxcb-keysyms.so.1"]
    message = qt_libraries.install_message(["libxcb-icccm.so.4", "libxcb-keysyms.so.1",
                                            "libxcb-cursor.so.0"])
    assert "sudo apt-get install libxcb-icccm4 libxcb-keysyms1 libxcb-cursor0" in message
    assert qt_libraries.packages_for(["libfoo-bar.so.3"]) == ["libfoo-bar3"]
    assert qt_libraries.missing_from_import_error(
        "libEGL.so.1: cannot open shared object file: No such file or directory") == [
        "libEGL.so.1"]
    # on this machine the xcb platform's libraries are all there (or the check names them)
    missing = qt_libraries.missing_xcb_libraries()
    assert all(name.startswith("lib") for name in missing)
    # the command checks before Qt starts, and says what to type
    monkeypatch.setenv("QT_QPA_PLATFORM", "xcb")
    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setattr(gui_cmd, "missing_xcb_libraries",
                        lambda: ["libxcb-icccm.so.4", "libxcb-keysyms.so.1"])
    assert main(["gui", "--empty"]) == 1
    err = capsys.readouterr().err
    assert "sudo apt-get install libxcb-icccm4 libxcb-keysyms1" in err
    assert qt_libraries.uses_xcb({"QT_QPA_PLATFORM": "offscreen"}) is False
    assert qt_libraries.uses_xcb({"DISPLAY": ":0"}) is True
