"""The thermal view and the thermal report page, on a simulated thermal test."""

import shutil
import subprocess

import numpy as np
import pytest
from PySide6.QtGui import QGuiApplication
from volucal.app.report_thermal import write_thermal_pdf
from volucal.app.thermal_view import ThermalView
from volucal.core.project import Project
from volucal.core.thermal_fit import ThermalFitOptions, ThermalFitRequest, fit_thermal
from volucal.core.thermal_report import ThermalPlot, sections_for_project, thermal_section
from volucal.core.thermal_sim import SimulatedThermalTest, simulate_thermal_test
from volucal.core.thermal_store import store_thermal


@pytest.fixture(scope="module")
def result():
    m = simulate_thermal_test(SimulatedThermalTest(hours=12, seed=3), name="warm-up")
    return fit_thermal(ThermalFitRequest(m))


def test_view_shows_error_prediction_residual_and_weights(qtbot, result) -> None:
    view = ThermalView(result)
    qtbot.addWidget(view)
    view.show()
    hours, measured = view.measured_curve.getData()
    np.testing.assert_allclose(hours, result.time_s / 3600)
    np.testing.assert_allclose(measured, result.measured)
    np.testing.assert_allclose(view.predicted_curve.getData()[1], result.predicted)
    np.testing.assert_allclose(view.residual_curve.getData()[1],
                               result.measured - result.predicted)
    heights = view.weight_bars.opts["height"]
    np.testing.assert_allclose(heights, result.term_spread)
    assert len(heights) == len(result.model.terms)
    assert [p for p, _ in view.split_lines] == [view.error_plot, view.residual_plot]
    assert view.split_lines[0][1].value() == pytest.approx(result.split_time_s / 3600)
    # terms with coefficient and uncertainty, then the RMS table with the baselines
    assert view.terms.rowCount() == 1 + len(result.model.terms)
    assert view.terms.item(1, 0).text() == result.model.terms[0].label()
    assert float(view.terms.item(1, 1).text()) == pytest.approx(result.model.coefficients[0],
                                                                abs=1e-4)
    rows = [view.metrics.item(i, 0).text() for i in range(view.metrics.rowCount())]
    assert rows[0] == "uncompensated" and rows[-1] == "volucal model"
    assert float(view.metrics.item(len(rows) - 1, 3).text()) == pytest.approx(result.test_rms,
                                                                              abs=1e-3)
    assert "measured − nominal" in view.summary.text()


def test_actions(qtbot, result) -> None:
    view = ThermalView(result)
    qtbot.addWidget(view)
    view.show()
    view.copy_formula_action.trigger()
    assert QGuiApplication.clipboard().text() == result.model.formula()
    view.held_out_action.trigger()
    low, high = view.error_plot.getViewBox().viewRange()[0]
    assert low == pytest.approx(result.split_time_s / 3600, abs=0.2)
    view.held_out_action.trigger()
    low, _ = view.error_plot.getViewBox().viewRange()[0]
    assert low < 0.2


def test_switching_and_clearing(qtbot, result) -> None:
    view = ThermalView()
    qtbot.addWidget(view)
    assert not view.copy_formula_action.isEnabled()
    view.set_result(result)
    view.set_result(result)  # no second split line, no second bar set
    assert len(view.split_lines) == 2
    bars = [i for i in view.weights_plot.getPlotItem().items
            if i.__class__.__name__ == "BarGraphItem"]
    assert len(bars) == 1
    whole = fit_thermal(ThermalFitRequest(
        simulate_thermal_test(SimulatedThermalTest(hours=6, seed=4)),
        options=ThermalFitOptions(train_fraction=1.0)))
    view.set_result(whole)
    assert view.split_lines == [] and not view.held_out_action.isEnabled()
    assert "no held-out part" in view.summary.text()
    view.set_result(None)
    assert view.measured_curve.getData()[0] is None or len(view.measured_curve.getData()[0]) == 0
    assert view.terms.rowCount() == 0


def test_report_page(qtbot, result, tmp_path) -> None:
    section = thermal_section(result)
    plot = next(b for b in section.blocks if isinstance(b, ThermalPlot))
    assert len(plot.time_h) <= 1200 and plot.split_h == pytest.approx(result.split_time_s / 3600)
    project = Project.create()
    store_thermal(project, "warm-up", result_measurement(result), [result])
    project.save(tmp_path / "p.h5")
    stored = sections_for_project(Project.open(tmp_path / "p.h5"))
    assert [s.title for s in stored] == [section.title]
    pdf = tmp_path / "thermal.pdf"
    pages = write_thermal_pdf(stored, pdf)
    assert pages >= 1 and pdf.stat().st_size > 5000
    if shutil.which("pdftotext") is None:
        pytest.skip("poppler-utils (pdftotext) is not installed")
    text = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True,
                          text=True, check=True, timeout=60).stdout
    assert "Thermal error: Z drift (warm-up)" in text
    assert f"{result.test_rms:.3f}" in text  # the held-out RMS in the table
    assert "measured − nominal" in text or "measured - nominal" in text
    assert "residual: measured" in text and "time (h)" in text


def result_measurement(result):
    """The measurement the fixture fitted (rebuilt from its seed)."""
    return simulate_thermal_test(SimulatedThermalTest(hours=12, seed=3), name="warm-up")


def test_main_window_shows_the_projects_thermal_records(qtbot, window, tmp_path) -> None:
    """A record stored by `volucal thermal --project` is listed in the tree and shown, as
    fitted, by the window's Thermal view, reached through the View menu."""
    from PySide6.QtGui import QAction

    measurement = simulate_thermal_test(SimulatedThermalTest(hours=12, seed=3), name="warm-up")
    fitted = fit_thermal(ThermalFitRequest(measurement))
    path = tmp_path / "with_thermal.h5"
    project = Project.open(window.document.project.path)
    store_thermal(project, "warm-up", measurement, [fitted])
    project.save(path)
    assert window.open_project(path)
    action = next(a for a in window.findChildren(QAction) if a.text().endswith(" Thermal"))
    action.trigger()
    view = window.views["thermal"]
    assert window.stack.currentWidget() is view
    qtbot.waitUntil(lambda: view.view.result is not None, timeout=10_000)
    assert view.record.currentText() == "warm-up"
    np.testing.assert_allclose(view.view.predicted_curve.getData()[1], fitted.predicted)
