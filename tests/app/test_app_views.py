"""What the views show, checked against the stored values: plotted arrays in the unit of the axis
label, a project as ``volucal calibrate`` writes it, stale displays, two projects in a row."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pyqtgraph as pg
import pytest
from PySide6.QtWidgets import (
    QComboBox,
    QLabel,
    QLineEdit,
    QListWidget,
    QMessageBox,
    QTableWidget,
    QTextBrowser,
)
from volucal.app import evidence, plots
from volucal.app.factors import SensitivitySetup
from volucal.app.mainwindow import MainWindow
from volucal.app.records import stored_model
from volucal.core.iso230_2 import evaluate
from volucal.core.project import Project


def data_items(plot):
    item = plot.getPlotItem() if isinstance(plot, pg.PlotWidget) else plot
    return [i for i in item.items if isinstance(i, pg.PlotDataItem | pg.ScatterPlotItem)]


def tick_values(axis):
    """The numbers the axis labels show for its current range (as drawn)."""
    low, high = axis.range
    levels = axis.tickValues(min(low, high), max(low, high), 400)
    values, strings = [], []
    for spacing, ticks in levels:
        values += list(ticks)
        strings += axis.tickStrings(ticks, axis.autoSIPrefixScale * axis.scale, spacing)
    return np.array(values), np.array([float(s) for s in strings])


def assert_plain_axis(plot, side="left"):
    """Tick labels read the plotted values themselves: no hidden SI factor."""
    axis = plot.getPlotItem().getAxis(side)
    assert axis.autoSIPrefixScale == 1.0
    values, shown = tick_values(axis)
    np.testing.assert_allclose(shown, values, atol=1e-9 + 1e-6 * np.max(np.abs(values)))
    assert not any(t.startswith("-0") and float(t) == 0 for t in axis.tickStrings(
        values, 1.0, 1.0))


def test_loop_and_residual_plots_are_in_the_unit_of_their_label(qtbot, window):
    """The evidence and residual plots after the loop (the periodogram, then the reversal):
    what is drawn is the stored residual in µm, and the ticks say so."""
    loop = window.show_view("loop")
    record = window.document.identification("main")
    steps = [loop.steps.item(r, 1).text() for r in range(loop.steps.rowCount())]
    cyclic = next(r for r, s in enumerate(steps) if s.startswith("cyclic"))
    reversal = next(r for r, s in enumerate(steps) if s.startswith("reversal"))
    loop.steps.selectRow(cyclic)  # a log-x plot whose y range is 0…1 first
    qtbot.wait(50)
    loop.steps.selectRow(reversal)
    qtbot.wait(50)
    item = loop.evidence_plot.getPlotItem()
    assert item.getAxis("left").labelText == "forward − backward (µm)"
    expected = evidence.reversal_difference(record.readings, "X")
    drawn = data_items(loop.evidence_plot)
    assert len(drawn) == len(expected.series)
    for shown, series in zip(drawn, expected.series, strict=True):
        np.testing.assert_allclose(shown.getData()[1], series.y)
    # the demo machine's 4 µm reversal, as a 4 µm step (not 4000)
    assert 3.0 < np.median(np.concatenate([s.y for s in expected.series])) < 5.0
    assert_plain_axis(loop.evidence_plot)

    view = window.show_view("identification")
    view.select("loop")
    view.tabs.setCurrentIndex(1)
    view.lines.selectRow(0)
    name = view.lines.item(0, 0).text()
    final = window.document.identification("loop").readings
    index = final.line_names.index(name)
    mask = final.line == index
    drawn = np.concatenate([i.getData()[1] for i in data_items(view.residual_plot)])
    np.testing.assert_allclose(np.sort(drawn), np.sort(final.residual[mask]))
    table_max = float(view.lines.item(0, 4).text())
    assert np.max(np.abs(drawn)) == pytest.approx(table_max, abs=1e-3)
    assert view.residual_plot.getPlotItem().getAxis("left").labelText == "residual (µm)"
    assert_plain_axis(view.residual_plot)

    window.set_units("length", "mm")
    view.lines.selectRow(0)
    drawn_mm = np.concatenate([i.getData()[1] for i in data_items(view.residual_plot)])
    np.testing.assert_allclose(np.sort(drawn_mm), np.sort(final.residual[mask]) / 1000.0)
    assert view.residual_plot.getPlotItem().getAxis("left").labelText == "residual (mm)"
    assert_plain_axis(view.residual_plot)


def test_measurement_view_draws_the_iso_values_and_shows_them_at_the_default_size(
        qtbot, window):
    assert (window.width(), window.height()) == (1400, 900)
    view = window.show_view("measurement")
    view.select("x_lin_1")
    qtbot.wait(50)
    stored = window.document.project.lines["x_lin_1"]
    result = evaluate(stored.corrected, stored.spec.unit)
    means = {i.name(): i.getData()[1] for i in data_items(view.plot) if i.name()}
    np.testing.assert_allclose(means["mean ↑ (2 runs)"], result.mean_up)
    np.testing.assert_allclose(means["mean ↓ (2 runs)"], result.mean_down)
    assert view.plot.getPlotItem().getAxis("left").labelText == "deviation (µm)"
    assert_plain_axis(view.plot)
    # every ISO 230-2 value readable without touching a splitter
    table = view.figures
    viewport = table.viewport().rect()
    for row in range(table.rowCount()):
        rect = table.visualRect(table.model().index(row, 1))
        assert viewport.contains(rect), (row, rect, viewport)
    assert table.item(0, 1).text() == f"{result.A_um:.3f} µm"
    # the per-target table: one row per target at its X (the plan's start plus the distance),
    # x̄↑ in the label's unit; the plot over the same positions
    assert view.targets.rowCount() == result.targets_mm.size
    assert view.targets.horizontalHeaderItem(0).text() == "X mm"
    x = stored.spec.positions(stored.corrected.targets_mm)[:, 0]
    shown = [float(view.targets.item(row, 0).text()) for row in range(x.size)]
    np.testing.assert_allclose(shown, x, atol=1e-3)
    assert view.plot.getPlotItem().getAxis("bottom").labelText == "X (mm)"
    assert float(view.targets.item(3, 1).text()) == pytest.approx(result.mean_up[3], abs=1e-3)
    window.set_units("length", "inch")
    assert view.figures.item(0, 1).text() == f"{result.A_um / 25400:.7f} in"
    assert view.plot.getPlotItem().getAxis("left").labelText == "deviation (in)"


def test_tolerances_give_pass_and_fail_in_the_measurement_view(qtbot, window):
    stored = window.document.project.lines["x_lin_1"]
    a = evaluate(stored.corrected, stored.spec.unit).A_um
    dialog = window.edit_tolerances()
    dialog.set_limit("X", "A", round(a + 5.0, 3))  # passes
    dialog.set_limit("X", "R", 0.001)  # fails
    dialog.accept()
    view = window.show_view("measurement")
    view.select("x_lin_1")
    rows = {view.figures.item(r, 0).text(): r for r in range(view.figures.rowCount())}
    assert view.figures.item(rows["accuracy A"], 3).text() == "pass"
    assert view.figures.item(rows["repeatability R"], 3).text() == "fail"
    assert "fails" in view.verdict.text()
    window.undo_action.trigger()
    view.select("x_lin_1")
    assert view.figures.item(rows["accuracy A"], 3).text() == ""


def _loop_identification_of(qtbot, project):
    """A main window on ``project``, showing the loop's identification: the window and view."""
    window = MainWindow()
    qtbot.addWidget(window, before_close_func=lambda w: w.document.undo_stack.setClean())
    window.show()
    assert window.open_project(project)
    view = window.show_view("identification")
    view.select("loop")
    return window, view


def test_a_calibrate_project_opens_with_every_pane_filled(qtbot, demo_project):
    """`volucal calibrate` stores the residuals, the effects tried and the sensitivity arrays."""
    window, view = _loop_identification_of(qtbot, demo_project)
    assert view.lines.rowCount() == 49
    assert "Every one of the 49 lines is redundant" in view.report.toPlainText()
    view.select("main")
    assert "Every one of the 49 lines is redundant" in view.report.toPlainText()
    loop = window.show_view("loop")
    loop.steps.selectRow(0)
    assert data_items(loop.evidence_plot)
    loop.residual_box.setCurrentIndex(1)  # after the loop
    assert data_items(loop.evidence_plot)
    cells = [loop.rms_table.item(r, c).text() for r in range(loop.rms_table.rowCount())
             for c in (1, 2)]
    assert cells and "—" not in cells
    assert loop.effects.count() >= 2 and loop.refit_button.isEnabled()
    sensitivity = window.show_view("sensitivity")
    assert sensitivity.record is not None and sensitivity.record.result is not None


def test_stale_displays_are_cleared(qtbot, window, wait_idle, monkeypatch, tmp_path):
    compensation = window.show_view("compensation")
    compensation.set_format("linuxcnc")
    compensation.run_preview()
    wait_idle(compensation)
    assert compensation.files.count() > 0
    compensation.set_format("siemens")
    assert compensation.files.count() == 0 and compensation.preview is None

    identification = window.show_view("identification")
    identification.tabs.setCurrentIndex(1)
    identification.lines.selectRow(0)
    assert identification.residual_plot.getPlotItem().titleLabel.text.startswith("Residual of")
    assert window.save_as(tmp_path / "first.h5")
    assert "first.h5" in window.status_text.text()

    sensitivity = window.show_view("sensitivity")
    sensitivity.n_box.setValue(100)
    sensitivity.map_step.setValue(20.0)
    sensitivity.run_map()
    qtbot.wait(300)
    window.cancel_tasks()
    wait_idle(sensitivity)
    assert window.status_text.text() == "sensitivity map: cancelled"

    window.new_project()
    assert window.status_text.text() == ""
    identification = window.show_view("identification")
    assert identification.residual_plot.getPlotItem().titleLabel.text == "Residual"
    assert identification.lines.rowCount() == 0


def widget_texts(widget):
    """Every text a view shows: labels, tables, lists, boxes, line edits, plot titles and
    legends."""
    out = []
    for label in widget.findChildren(QLabel):
        out.append(label.text())
    for table in widget.findChildren(QTableWidget):
        for r in range(table.rowCount()):
            for c in range(table.columnCount()):
                item = table.item(r, c)
                if item is not None:
                    out.append(item.text())
    for box in widget.findChildren(QComboBox):
        out += [box.itemText(i) for i in range(box.count())]
    for items in widget.findChildren(QListWidget):
        out += [items.item(i).text() for i in range(items.count())]
    for edit in widget.findChildren(QLineEdit):
        out.append(edit.text())
    for browser in widget.findChildren(QTextBrowser):
        out.append(browser.toPlainText())
    for plot in plots.plot_items(widget):
        out.append(str(plot.titleLabel.text))
        for series in plots.plotted_series(plot):
            out.append(series.name)
    return "\n".join(out)


def test_two_projects_in_a_row_keep_nothing_of_the_first(qtbot, demo_project, small_project,
                                                          small_remeasured_file, wait_idle,
                                                          monkeypatch):
    monkeypatch.setattr(QMessageBox, "question",
                        lambda *a, **k: QMessageBox.StandardButton.Discard)
    second = Project.open(small_project)
    second.machine = dataclasses.replace(second.machine, name="bay 7 mill")
    second.save()
    window = MainWindow()
    qtbot.addWidget(window, before_close_func=lambda w: w.document.undo_stack.setClean())
    window.show()

    # the first project, every view used
    assert window.open_project(demo_project)
    window.tree.choose("measurements", "body_ppp")
    identification = window.show_view("identification")
    identification.tabs.setCurrentIndex(1)
    identification.lines.selectRow(3)
    window.show_view("loop").steps.selectRow(1)
    window.show_view("sensitivity")
    compensation = window.show_view("compensation")
    compensation.run_preview()
    wait_idle(compensation)
    assert window.open_remeasurement(demo_project)
    window.show_view("comparison").select("x_linear")
    dialog = window.edit_tolerances()
    dialog.set_limit("X", "A", 9.0)
    dialog.accept()
    first_only = [name for name in window.document.line_names() if "linear" in name
                  or name.startswith("body")] + ["XYTZ vertical mill", "demo.h5"]

    # the second project: nothing of the first may remain anywhere
    assert window.open_project(small_project)
    for key in window.views:
        window.show_view(key)
        qtbot.wait(20)
    window.show_view("comparison")
    texts = widget_texts(window) + "\n" + window.statusBar().currentMessage() + \
        window.status_text.text() + window.windowTitle()
    leftovers = [token for token in first_only if token in texts]
    assert leftovers == []
    assert window.views["comparison"].after_project is None
    assert window.views["compensation"].preview is None
    sensitivity = window.views["sensitivity"]
    expected = SensitivitySetup.identified(
        stored_model(window.document.project, "loop"),
        np.asarray(window.document.tree("identifications", "loop")["covariance"]))
    assert [f.mean for f in sensitivity.setup.factors] == pytest.approx(
        [f.mean for f in expected.factors])
    assert window.views["measurement"].checks == []  # the first one's tolerances are gone

    # and the second one's re-measurement opens beside it
    assert window.open_remeasurement(small_remeasured_file)
    comparison = window.views["comparison"]
    assert comparison.comparison is not None and len(comparison.comparison.pairs) == 9


def test_the_comparison_view_shows_both_measurements(qtbot, window, small_remeasured_file):
    from volucal.core.remeasurement import compare

    assert window.open_remeasurement(small_remeasured_file)
    view = window.views["comparison"]
    expected = compare(window.document.measurement().lines,
                       Project.open(small_remeasured_file).measurement().lines)
    x_axis = next(r for r in expected.axes if r.axis == "X")
    row = next(r for r in range(view.axes.rowCount()) if view.axes.item(r, 0).text() == "X")
    assert view.axes.item(row, 3).text() == f"{x_axis.rms_percent:.1f}"
    assert x_axis.rms_percent > 20.0  # the compensation removed most of the X error
    view.select("x_lin_1")
    pair = expected.pair("x_lin_1")
    means = {i.name(): i.getData()[1] for i in data_items(view.plot) if i.name()}
    np.testing.assert_allclose(means["before: x̄ ± 2s"], pair.before.mean)
    np.testing.assert_allclose(means["after: x̄ ± 2s"], pair.after.mean)
    # each curve at the X of its own line's targets (its plan's start plus the distance)
    xs = {i.name(): i.getData()[0] for i in data_items(view.plot) if i.name()}
    for which, project, name in (("before", window.document.project, pair.name),
                                 ("after", Project.open(small_remeasured_file), pair.after_name)):
        stored = project.lines[name]
        x = stored.spec.positions(stored.corrected.targets_mm)[:, 0]
        np.testing.assert_allclose(xs[f"{which}: x̄ ± 2s"], x)
    assert view.plot.getPlotItem().getAxis("bottom").labelText == "X (mm)"
    assert view.values.item(0, 1).text() == f"{pair.before.A_um:.3f} µm"


def test_every_plot_saves_as_png_svg_and_csv(qtbot, window, tmp_path):
    from PySide6.QtGui import QColor, QImage, QPainter
    from PySide6.QtSvg import QSvgRenderer

    view = window.show_view("measurement")
    view.select("y_lin_1")
    plot = view.plot.getPlotItem()
    written = window.export_plots(tmp_path)
    assert {p.suffix for p in written} == {".png", ".svg", ".csv"}
    stem = next(p for p in written if p.suffix == ".csv" and "positioning" in p.name)
    rows = stem.read_text(encoding="utf-8").splitlines()
    assert rows[1] == "series,Y (mm),deviation (µm)"  # y_lin_1 runs along Y
    stored = window.document.project.lines["y_lin_1"]
    result = evaluate(stored.corrected, stored.spec.unit)
    up = [r.split(",") for r in rows[2:] if r.startswith("mean ↑")]
    np.testing.assert_allclose([float(r[2]) for r in up], result.mean_up, rtol=1e-9)

    png = plots.export_plot(plot, tmp_path / "p.png")
    svg = plots.export_plot(plot, tmp_path / "p.svg")
    renderer = QSvgRenderer(str(svg))
    assert renderer.isValid()
    picture = QImage(str(png)).scaled(renderer.defaultSize())
    drawn = QImage(renderer.defaultSize(), QImage.Format.Format_ARGB32)
    drawn.fill(QColor("white"))
    painter = QPainter(drawn)
    renderer.render(painter)
    painter.end()

    def gray(image):
        image = image.convertToFormat(QImage.Format.Format_Grayscale8)
        width, height = image.width(), image.height()
        raw = np.frombuffer(image.constBits(), np.uint8, image.bytesPerLine() * height)
        return raw.reshape(height, image.bytesPerLine())[:, :width].astype(float)

    # the drawing and the picture agree (curves where the axes say; a misplaced plot area
    # differs by far more)
    difference = np.abs(gray(picture) - gray(drawn))
    assert np.mean(difference) < 12.0
    with pytest.raises(Exception, match="png, .svg or .csv"):
        plots.export_plot(plot, tmp_path / "p.jpg")


def test_the_user_guide_shows_the_docs(qtbot, window):
    guide = window.user_guide()
    assert guide is not None
    assert "volucal documentation" in guide.page_text()
    guide.show_page("gui.md")
    assert "The workbench" in guide.page_text()
    assert guide.pages.currentItem().text() == "The workbench"
    from PySide6.QtCore import QUrl

    guide._follow(QUrl("formats.md"))
    assert guide.pages.currentItem().text() == "File formats"
    guide.close()


def test_a_duplicate_import_is_refused_where_the_names_are_chosen(qtbot, window, small_plan):
    wizard = window.import_logs([small_plan])
    qtbot.waitUntil(wizard.files_page.isComplete, timeout=60_000)
    wizard.next()
    qtbot.waitUntil(wizard.preview_page.isComplete, timeout=60_000)
    wizard.next()
    page = wizard.plan_page
    assert not page.isComplete()
    assert "already has 9 line(s) of these names" in page.error.text()
    assert "--replace" not in page.error.text()
    assert page.replace_existing.isVisible()
    # renaming one line is not enough; replacing is
    page.replace_existing.setChecked(True)
    assert page.isComplete() and page.error.text() == ""
    wizard.next()
    qtbot.waitUntil(wizard.import_page.isComplete, timeout=60_000)
    before = window.document.project.lines["x_lin_1"]
    wizard.accept()
    assert window.document.project.lines["x_lin_1"] is not before
    assert len(window.document.line_names()) == 9
    window.undo_action.trigger()
    assert window.document.project.lines["x_lin_1"] is before


def test_squareness_is_shown_as_numbers_with_units(qtbot, window):
    view = window.show_view("identification")
    view.select("loop")
    record = window.document.identification("loop")
    for row, eid in enumerate(("EC0Y", "EB0Z", "EA0Z")):
        value = float(record.parameters[eid]["value"][0])
        # a squareness the plan does not see is held at zero: shown 0.00, not -0.00
        assert view.squareness.item(row, 1).text() == f"{round(value, 2) + 0.0:.2f} µrad"
    window.set_units("angle", "arcsec")
    for row, eid in enumerate(("EC0Y", "EB0Z", "EA0Z")):
        value = float(record.parameters[eid]["value"][0])
        shown, unit = view.squareness.item(row, 1).text().split()
        assert unit == "arcsec" and float(shown) == pytest.approx(value * 0.206265, abs=2e-3)


def test_the_squareness_between_the_tool_paths_is_shown_beside_the_parameter(
        qtbot, demo_project, demo_run):
    # a project `volucal calibrate` wrote, opened: the loop's map as report.json has it, as a
    # square would read it, at the centre of the measured volume ± U (k = 2) and its range
    window, view = _loop_identification_of(qtbot, demo_project)
    mapped = window.document.identification("loop").squareness_map
    assert mapped == json.loads((demo_run / "report.json").read_text())["squareness_over_volume"]
    header = [view.squareness.horizontalHeaderItem(c).text() for c in range(7)]
    assert header[3:] == ["paths at centre ± U", "paths lowest ± U", "paths highest ± U",
                          "tilted by"]
    for row, eid in enumerate(("EC0Y", "EB0Z", "EA0Z")):
        e = mapped[eid]
        cells = [view.squareness.item(row, c).text() for c in range(3, 7)]
        lowest = ", ".join(f"{v:g}" for v in e["lowest_at_mm"])
        highest = ", ".join(f"{v:g}" for v in e["highest_at_mm"])
        assert cells == [
            f"{e['at_centre_urad']:.2f} ± {2 * e['at_centre_std_urad']:.2f} µrad",
            f"{e['lowest_urad']:.2f} ± {2 * e['lowest_std_urad']:.2f} µrad at ({lowest}) mm",
            f"{e['highest_urad']:.2f} ± {2 * e['highest_std_urad']:.2f} µrad at ({highest}) mm",
            "—",
        ]
        least = ", ".join(f"{v:g}" for v in e["least_certain_at_mm"])
        assert f"U (k = 2) is largest at ({least}) mm" in view.squareness.item(row, 3).toolTip()
    # the map tab: EB0Z between the X and Z paths at the lowest Y of the grid, place by place
    view.tabs.setCurrentIndex(3)
    view.square_id.setCurrentText("EB0Z")
    view.square_level.setCurrentIndex(0)
    assert view.square_level.currentText() == "Y = 0 mm"
    e = mapped["EB0Z"]
    places = np.asarray(e["places"]["place_mm"])
    on = places[:, 1] == 0.0
    x, z = np.unique(places[on, 0]), np.unique(places[on, 2])
    expected = np.asarray(e["places"]["angle_urad"])[on].reshape(x.size, z.size)  # X slowest
    assert np.array_equal(view.square_image.image, expected)
    assert "EB0Z: angle between the tool's X and Z paths" in view.square_plot.getPlotItem(
        ).titleLabel.text
    window.set_units("angle", "arcsec")
    assert np.allclose(view.square_image.image, expected * 0.206265, atol=1e-3)
    shown = view.squareness.item(1, 3).text()
    assert shown.endswith(" arcsec")
    assert float(shown.split()[0]) == pytest.approx(
        mapped["EB0Z"]["at_centre_urad"] * 0.206265, abs=2e-3)


def test_a_plan_that_cannot_map_the_squareness_says_so(qtbot, window):
    # the nine-line plan measures no straightness: no pair of paths to read an angle between
    view = window.show_view("identification")
    view.select("loop")
    assert window.document.identification("loop").squareness_map == {}
    assert view.squareness.item(0, 3).text() == "—"
    assert view.squareness.item(0, 3).toolTip().startswith("not mapped")
    assert view.square_id.count() == 0 and view.square_image.image is None
    assert "maps no squareness" in view.square_plot.getPlotItem().titleLabel.text


def test_report_dialog_keeps_the_certificate_with_the_project(qtbot, window, wait_idle,
                                                              tmp_path, monkeypatch):
    monkeypatch.setattr(QMessageBox, "question",
                        lambda *a, **k: QMessageBox.StandardButton.Save)
    pdf = tmp_path / "certificate.pdf"
    dialog = window.write_report(pdf)
    assert dialog is not None
    dialog.fields["customer"].setText("ACME Tooling")
    dialog.fields["certificate_number"].setText("C-2026-017")
    dialog.accept()
    wait_idle(window)
    assert pdf.is_file() and window.last_report == pdf
    from volucal.core.certificate import Certificate

    kept = Certificate.of_project(Project.open(window.document.path))
    assert kept.get("customer") == "ACME Tooling" and kept.get("certificate_number") == \
        "C-2026-017"
    assert Path(window.document.path).is_file() and window.document.is_clean
