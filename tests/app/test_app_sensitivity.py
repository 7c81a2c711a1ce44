"""The sensitivity view: ranking, the factor table re-ranks the bars, a responsive long map."""

import json
import time

import numpy as np
from PySide6.QtCore import QTimer
from volucal.core.errors import error_label
from volucal.core.project import error_model_from_tree
from volucal.core.sensitivity import analyse_model, workspace_grid


def test_changing_a_factors_spread_reranks_the_bars(qtbot, window, wait_idle):
    view = window.views["sensitivity"]
    window.show_view("sensitivity")
    view.n_box.setValue(200)
    view.top_k.setValue(21)
    view.output_box.setCurrentText("Ez")
    window.sensitivity()
    wait_idle(view)
    first = view.ranking()
    assert len(first) == 21
    # the straightness of X in Z adds to Ez one for one: with a large spread it must lead
    last = "EZX"
    assert first[0] != last
    view.set_spread(last, 500.0)
    assert view.setup.factor(last).spread == 500.0 and view.setup.factor(last).overridden
    assert view.table.item([view.table.item(r, 0).data(0x0100) for r in range(
        view.table.rowCount())].index(last), 5).text() == "yes"
    view.run()
    wait_idle(view)
    assert view.ranking()[0] == last

    # the bars are the core's numbers for the same problem
    tree = window.document.tree("identifications", "loop")
    model = error_model_from_tree(tree["model"], window.document.machine)
    # the default ranking of identified errors: a 100 mm grid, indices averaged over it
    direct = analyse_model(model, tree["covariance"], output="Ez", map_step_mm=100.0, n=200,
                           seed=0, spread={last: 500.0}, floor_um=0.01, floor_urad=0.1)

    def ranked(kind, count):
        return [eid for eid, _ in direct.top("Ez", kind, count)]

    assert view.ranking() == ranked("S1", 21)
    view.top_k.setValue(5)
    view.sort_box.setCurrentText("ST")
    assert view.ranking() == ranked("ST", 5)


def test_the_event_loop_stays_responsive_during_a_long_map(qtbot, window, wait_idle):
    view = window.views["sensitivity"]
    window.show_view("sensitivity")
    view.n_box.setValue(400)
    view.map_step.setValue(10.0)  # 41 × 41 × 36 points: minutes of work
    ticks = []
    timer = QTimer()
    timer.setInterval(10)
    timer.timeout.connect(lambda: ticks.append(time.perf_counter()))
    timer.start()
    view.run_map()
    assert view.runner.busy
    qtbot.wait(2500)
    assert view.runner.busy, "the map should still be running"
    view.cancel_button.click()
    wait_idle(view)
    timer.stop()
    gaps = np.diff(ticks)
    assert len(ticks) > 100
    assert gaps.max() < 0.100, f"longest gap between timer ticks {1000 * gaps.max():.0f} ms"
    assert "cancelled" in view.status.text()
    assert "map" not in window.document.results("sensitivity")


def test_a_map_slice_follows_the_slider(qtbot, window, wait_idle):
    view = window.views["sensitivity"]
    window.show_view("sensitivity")
    view.n_box.setValue(200)
    view.map_step.setValue(100.0)
    view.run_map()
    wait_idle(view)
    assert "map" in window.document.results("sensitivity")
    view.map_what.setCurrentIndex(0)  # the output's standard deviation
    x, y, z, values = view.map_grid()
    grid = workspace_grid(window.document.machine, 100.0)
    assert (x.size, y.size, z.size) == (5, 5, 5) and len(grid) == 125
    record = window.document.sensitivity("map").result
    o = record.outputs.index(view.output_box.currentText())
    np.testing.assert_allclose(values.ravel(), np.sqrt(record.variance_um2[o]))
    view.slice.setValue(3)
    assert view.slice_label.text().startswith(f"Z = {z[3]:g} mm")
    np.testing.assert_allclose(view.image.image, values[:, :, 3])


def test_errors_the_plan_cannot_see_are_marked_in_the_table_and_the_bars(qtbot, window,
                                                                          wait_idle):
    """The small project's nine lines leave EYX (among others) unidentified: the ranking F7 runs
    varies it by what was not measured, and the table, the bars and the stored result say so."""
    view = window.views["sensitivity"]
    window.show_view("sensitivity")
    view.n_box.setValue(200)
    view.top_k.setValue(21)
    tree = window.document.tree("identifications", "loop")
    unseen = set(json.loads(str(tree["identifiability_json"]))["unidentifiable_ids"])
    assert "EYX" in unseen and "EXX" not in unseen

    def marked_ticks():  # type: ignore[no-untyped-def]
        ticks = view.bars.getPlotItem().getAxis("left")._tickLevels[0]
        return {label[:-2] for _, label in ticks if label.endswith(" *")}

    labels = {error_label(e) for e in unseen}
    # the project's ranking was stored before results kept what they leave unidentified: its
    # bars and its map's choices are marked from the identification it was run on
    assert view.record.not_identified == frozenset()
    assert marked_ticks() == labels
    choices = [view.map_what.itemText(i) for i in range(1, view.map_what.count())]
    assert {c.split(" of ", 1)[1][:-2] for c in choices if c.endswith(" *")} == labels
    actions = {a.shortcut().toString(): a for a in window.actions()}
    actions["F7"].trigger()
    wait_idle(view)

    rows = {view.table.item(r, 0).data(0x0100): view.table.item(r, 0).text()
            for r in range(view.table.rowCount())}
    assert {eid for eid, text in rows.items() if text.endswith(" *")} == unseen
    assert "not fully identified by this plan" in view.table_note.text()
    assert view.record.not_identified == unseen
    assert marked_ticks() == labels
    assert "* not fully identified by this plan: its indices are not the machine's alone" in (
        view.bars.getPlotItem().titleLabel.text)
    # stored: the project's report block lists them for every output
    stored = json.loads(str(window.document.tree("sensitivity", "main")["report_json"]))
    assert all(set(stored[o]["not_identified"]) == unseen for o in stored)
