"""The compensation view asks before exporting corrections beyond the plausibility limit."""

from PySide6.QtWidgets import QMessageBox


def test_large_corrections_are_written_only_after_confirmation(qtbot, window, tmp_path,
                                                               wait_idle, monkeypatch):
    """An identification with a squareness of 1e9 µrad: the export stops and asks; "No"
    writes nothing, "Yes" writes the files (issue 16)."""
    from volucal.app import jobs
    from volucal.core.compensation import ModelSource
    from volucal.core.errors import ErrorModel

    real = jobs.export_source

    def absurd(*args, **kwargs):
        model = real(*args, **kwargs).model
        return ModelSource(ErrorModel(model.machine, model.functions,
                                      {**model.squareness_urad, "EC0Y": 1e9}))

    monkeypatch.setattr(jobs, "export_source", absurd)
    view = window.views["compensation"]
    window.show_view("compensation")
    view.set_format("linuxcnc")
    out = tmp_path / "out"
    view.export_to(out)
    wait_idle(view)
    dialog = view.large_dialog
    assert dialog is not None and dialog.isVisible()
    assert "larger than 200 µm" in dialog.text() and " µm at " in dialog.text()
    assert not out.exists() or not list(out.iterdir())
    dialog.button(QMessageBox.StandardButton.No).click()
    wait_idle(view)
    assert not out.exists() or not list(out.iterdir())
    assert window.document.results("compensation") == []

    view.export_to(out)
    wait_idle(view)
    view.large_dialog.button(QMessageBox.StandardButton.Yes).click()
    wait_idle(view)
    assert (out / "comp.ini").exists()
    assert window.document.results("compensation") == ["linuxcnc"]
