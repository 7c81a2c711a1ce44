"""The import wizard end to end, drag and drop, and bad files (error dialog, project unchanged)."""

import dataclasses
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PySide6.QtCore import QMimeData, QPointF, Qt, QUrl
from PySide6.QtGui import QDropEvent
from PySide6.QtWidgets import QApplication, QMessageBox, QWizard
from volucal.app.mainwindow import MainWindow
from volucal.core.io.plan import import_plan, load_plan
from volucal.core.resources import demo_plan
from volucal.core.userror import UserError


@pytest.fixture
def empty_window(qtbot):
    window = MainWindow()
    qtbot.addWidget(window, before_close_func=lambda w: w.document.undo_stack.setClean())
    window.show()
    return window


def modal_box(name):
    """The message box ``name`` the app has open over its window, or None. Asked of the modal
    widget, not of every top-level widget: the wrappers PySide keeps for widgets Qt made and
    deleted itself (popups, tooltips) can outlive them, and reading one crashes the process."""
    box = QApplication.activeModalWidget()
    if isinstance(box, QMessageBox) and box.objectName() == name and box.isVisible():
        return box
    return None


def error_dialogs():
    box = modal_box("errorDialog")
    return [box] if box is not None else []


def close_dialogs():
    for box in error_dialogs():
        box.close()


def next_page(qtbot, wizard, page):
    qtbot.waitUntil(page.isComplete, timeout=60_000)
    wizard.next()


def test_import_wizard_end_to_end_on_the_demo_logs(qtbot, empty_window):
    window = empty_window
    wizard = window.import_logs([demo_plan()])
    expected = import_plan(load_plan(demo_plan()))
    assert wizard.files_page.list.count() == len(expected.lines) == 49
    next_page(qtbot, wizard, wizard.files_page)

    preview = wizard.preview_page
    qtbot.waitUntil(preview.isComplete, timeout=60_000)
    assert preview.table.rowCount() == 49
    assert not error_dialogs()
    texts = [preview.table.item(r, 0).text() for r in range(preview.table.rowCount())]
    assert "x_linear.rtl" in texts and "x_angle_y.rta" in texts
    row = texts.index("x_linear.rtl")
    assert preview.table.item(row, 1).text() == "rtl"
    assert preview.table.item(row, 4).text() == "5 / 5"  # runs forward / backward
    assert "air 20.30 °C" in preview.table.item(row, 5).text()
    wizard.next()

    plan_page = wizard.plan_page
    assert plan_page.table.rowCount() == 49
    assert plan_page.isComplete()
    assert len(plan_page.sketch.lines) == 49
    # the plan is the file's, unchanged: the project keeps its path and text
    assert plan_page.build_plan() is wizard.base_plan
    wizard.next()

    import_page = wizard.import_page
    qtbot.waitUntil(import_page.isComplete, timeout=60_000)
    assert "49 line(s)" in import_page.summary.text()
    wizard.button(QWizard.WizardButton.FinishButton).click()

    document = window.document
    assert sorted(document.line_names()) == sorted(line.name for line in expected.lines)
    stored = document.project.lines["x_linear"]
    reference = next(line for line in expected.lines if line.name == "x_linear")
    np.testing.assert_array_equal(stored.corrected.deviations, reference.corrected.deviations)
    assert stored.source_bytes == Path(reference.spec.file).read_bytes()
    assert document.project.plan_toml == demo_plan().read_text(encoding="utf-8")
    assert not document.is_clean

    document.undo_stack.undo()
    assert document.line_names() == [] and document.machine is None
    document.undo_stack.redo()
    assert len(document.line_names()) == 49


def test_log_files_without_a_plan_are_placed_in_the_plan_editor(qtbot, empty_window, tmp_path):
    logs = demo_plan().parent / "logs"
    files = [logs / "x_linear.rtl", logs / "y_linear.rtl"]
    wizard = empty_window.import_logs(files)
    next_page(qtbot, wizard, wizard.files_page)
    next_page(qtbot, wizard, wizard.preview_page)
    page = wizard.plan_page
    rows = {r.name: i for i, r in enumerate(page.rows())}
    assert set(rows) == {"x_linear", "y_linear"}
    assert page.rows()[rows["y_linear"]].direction == "0, 1, 0"  # guessed from the name
    page.set_cell(rows["y_linear"], "start", "400, 0, 0")
    page.set_cell(rows["y_linear"], "direction", "0, 1")
    assert not page.isComplete()
    assert "direction: expected three numbers" in page.error.text()
    page.set_cell(rows["y_linear"], "direction", "0, 1, 0")
    assert page.isComplete()
    page.save(tmp_path / "edited.toml")
    saved = load_plan(tmp_path / "edited.toml", files_root=logs)
    assert {s.name: s for s in saved.lines}["y_linear"].start_mm == (400.0, 0.0, 0.0)
    wizard.next()
    qtbot.waitUntil(wizard.import_page.isComplete, timeout=60_000)
    wizard.button(QWizard.WizardButton.FinishButton).click()
    project = empty_window.document.project
    assert project.lines["y_linear"].spec.start_mm == (400.0, 0.0, 0.0)
    # an edited plan has no file of its own: the project keeps its text
    assert (
        'name = "y_linear"' in project.plan_toml
        and "start = [400.0, 0.0, 0.0]" in project.plan_toml
    )


def test_a_broken_log_shows_the_core_message_and_the_project_is_unchanged(qtbot, window, tmp_path):
    source = demo_plan().parent / "logs" / "x_linear.rtl"
    broken = tmp_path / "x_broken.rtl"
    lines = source.read_text(encoding="utf-8").splitlines()
    row = next(i for i, text in enumerate(lines) if text.strip().startswith("1    5 "))
    lines[row] = "   1    5    not-a-number"
    broken.write_text("\n".join(lines) + "\n", encoding="utf-8")
    before = sorted(window.document.line_names())

    wizard = window.import_logs([broken])
    next_page(qtbot, wizard, wizard.files_page)
    preview = wizard.preview_page
    qtbot.waitUntil(lambda: bool(error_dialogs()), timeout=60_000)
    message = error_dialogs()[0].text()
    assert str(broken) in message and f"line {row + 1}" in message
    assert "Traceback" not in message
    assert not preview.isComplete()
    assert preview.table.item(0, 6).text() == message
    close_dialogs()
    wizard.reject()
    assert sorted(window.document.line_names()) == before
    assert window.document.is_clean


def test_a_damaged_project_file_shows_an_error_and_keeps_the_open_project(qtbot, window, tmp_path):
    damaged = tmp_path / "damaged.h5"
    damaged.write_bytes(b"this is not HDF5")
    path = window.document.path
    assert not window.open_project(damaged)
    message = error_dialogs()[0].text()
    assert str(damaged) in message and "not an HDF5 file" in message
    assert window.document.path == path
    close_dialogs()


def test_lines_the_project_has_already_are_refused_whole(qtbot, window, small_plan):
    """Refused on the Plan page, where the names are chosen, in the workbench's words."""
    before = sorted(window.document.line_names())
    wizard = window.import_logs([small_plan])
    next_page(qtbot, wizard, wizard.files_page)
    next_page(qtbot, wizard, wizard.preview_page)
    page = wizard.plan_page
    assert not page.isComplete()
    assert "already has 9 line(s) of these names" in page.error.text()
    assert "volucal import" not in page.error.text()
    # renaming them in the table lets them in as new lines
    for row in range(page.table.rowCount()):
        page.set_cell(row, "name", f"{page.table.item(row, 0).text()}_again")
    assert page.isComplete() and page.error.text() == ""
    wizard.next()
    qtbot.waitUntil(wizard.import_page.isComplete, timeout=60_000)
    wizard.button(QWizard.WizardButton.FinishButton).click()
    assert sorted(window.document.line_names()) == sorted(
        before + [f"{name}_again" for name in before]
    )
    window.undo_action.trigger()
    assert sorted(window.document.line_names()) == before


def test_dropping_files_opens_projects_and_the_import_wizard(
    qtbot, empty_window, small_project, tmp_path
):
    log = tmp_path / "x_linear.rtl"
    shutil.copyfile(demo_plan().parent / "logs" / "x_linear.rtl", log)
    for path in (small_project, log):
        data = QMimeData()
        data.setUrls([QUrl.fromLocalFile(str(path))])
        event = QDropEvent(
            QPointF(50, 50),
            Qt.DropAction.CopyAction,
            data,
            Qt.MouseButton.LeftButton,
            Qt.KeyboardModifier.NoModifier,
        )
        empty_window.dropEvent(event)
    assert empty_window.document.path == small_project
    wizard = empty_window.wizard
    assert wizard is not None and wizard.isVisible()
    assert wizard.files_page.list.item(0).text() == str(log.resolve())
    wizard.reject()


def test_a_plan_reading_files_elsewhere_asks_for_that_folder(qtbot, empty_window, tmp_path):
    """A plan whose files lie outside its folder is read only once the user allows the folder
    that holds them (the command line's --files-root); refusing reads nothing."""
    logs = demo_plan().parent / "logs"
    text = demo_plan().read_text(encoding="utf-8")
    elsewhere = tmp_path / "plans" / "plan.toml"
    elsewhere.parent.mkdir()
    relative = Path(os.path.relpath(logs, elsewhere.parent)).as_posix()
    elsewhere.write_text(text.replace('file = "logs/', f'file = "{relative}/'), encoding="utf-8")

    def question():
        # opened over a page of the wizard, which is itself modal: found among its children
        boxes = [
            w
            for w in wizard.findChildren(QMessageBox, "outsideFolderDialog")
            if w.isVisible()
        ]
        return boxes[0] if boxes else None

    wizard = empty_window.import_logs([elsewhere])
    qtbot.waitUntil(lambda: question() is not None, timeout=5_000)
    assert str(logs.resolve()) in question().text()
    question().button(QMessageBox.StandardButton.No).click()
    assert wizard.base_plan is None and wizard.files_page.list.count() == 0

    wizard.files_page.add_paths([elsewhere])
    qtbot.waitUntil(lambda: question() is not None, timeout=5_000)
    question().button(QMessageBox.StandardButton.Yes).click()
    qtbot.waitUntil(lambda: wizard.base_plan is not None, timeout=5_000)
    assert len(wizard.base_plan.lines) == 49
    assert wizard.files_page.list.count() == 49
    assert not error_dialogs()


def test_the_plan_editor_never_states_a_unit_the_user_did_not_choose(tmp_path):
    """A row without a chosen unit leaves it to the file: a table that does not state its unit is
    then refused at import (the message asks for one), never read as µm."""
    from volucal.app.plan_rows import LineRow
    from volucal.core.io.plan import import_line
    from volucal.core.measurement import PlanError

    table = tmp_path / "x.csv"
    table.write_text("position,deviation\n0,0\n100,1.5\n200,2.0\n", encoding="utf-8")
    row = LineRow(
        name="x",
        file=str(table),
        quantity="linear",
        start="0, 0, 0",
        direction="1, 0, 0",
        sensitive="",
        reflector="0, 0, 0",
        reader={"columns": {"position": "position", "deviation": "deviation"}},
    )
    spec = row.to_spec()
    assert not spec.deviation_unit_stated
    with pytest.raises(UserError, match="unit"):
        import_line(spec)
    assert LineRow.from_spec(spec).deviation_unit is None
    stated = dataclasses.replace(row, deviation_unit="mm").to_spec()
    assert stated.deviation_unit_stated and stated.deviation_unit == "mm"
    angular = dataclasses.replace(row, quantity="angular", sensitive="0, 0, 1")
    assert (
        dataclasses.replace(angular, deviation_unit="arcsec").to_spec().deviation_unit == "arcsec"
    )
    with pytest.raises(PlanError, match="does not fit"):
        dataclasses.replace(angular, deviation_unit="um").to_spec()
