"""The compensation view: preview, and an export identical to ``volucal export``'s."""

import json

import pytest
from PySide6.QtWidgets import QMessageBox
from volucal.core.cli import main


@pytest.mark.parametrize("fmt", ["linuxcnc", "siemens"])
def test_exporting_writes_the_files_the_cli_writes(qtbot, window, small_project, tmp_path,
                                                   wait_idle, fmt):
    view = window.views["compensation"]
    window.show_view("compensation")
    view.set_format(fmt)
    assert view.identification_box.currentText() == "loop"  # what the CLI picks
    gui = tmp_path / "gui"
    view.export_to(gui)
    wait_idle(view)
    cli = tmp_path / "cli"
    assert main(["export", str(small_project), "--format", fmt, "--out", str(cli)]) == 0
    gui_files = sorted(p.name for p in gui.iterdir())
    assert gui_files == sorted(p.name for p in cli.iterdir())
    assert len(gui_files) >= 3
    for name in gui_files:
        assert (gui / name).read_bytes() == (cli / name).read_bytes(), name
    # the project records the export, and it is undoable
    tree = window.document.tree("compensation", fmt)
    assert tree["out_dir"] == str(gui) and tree["identification"] == "loop"
    assert json.loads(tree["export_json"])["format"] == fmt
    window.document.undo_stack.undo()
    assert window.document.results("compensation") == []


def test_preview_shows_the_tables_files_and_predicted_rates(qtbot, window, wait_idle):
    view = window.views["compensation"]
    window.show_view("compensation")
    view.set_format("linuxcnc")
    view.linuxcnc_type.setCurrentIndex(1)
    view.spacing.setValue(25.0)
    window.compensation()
    wait_idle(view)
    preview = view.preview
    assert preview is not None
    result = preview.result
    assert window.document.results("compensation") == []  # a preview writes nothing
    table = result.tables.axis["X"]
    assert view.table.rowCount() == len(table.position_mm)
    assert float(view.table.item(0, 0).text()) == pytest.approx(table.position_mm[0])
    assert set(preview.texts) == {p.name for p in result.files}
    assert "COMP_FILE_TYPE = 1" in preview.texts["comp.ini"]
    assert view.rates.rowCount() == len(result.verification.methods)
    export_rate = result.verification.methods["export"].rates.rms_percent["X"]
    assert view.rates.item(0, 1).text() == f"{export_rate:.1f}"


def test_bad_options_show_a_message(qtbot, window):
    view = window.views["compensation"]  # not shown: it refreshes before reading its form
    view.axis_names.setText("X=0,Q=1")
    view.run_preview()
    dialogs = [w for w in window.findChildren(QMessageBox) if w.isVisible()]
    assert [d.text() for d in dialogs] == ["axis names: expected X=NAME,Y=NAME,Z=NAME, got 'Q=1'"]
    assert not view.runner.busy
    dialogs[0].close()
