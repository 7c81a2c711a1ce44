"""The squareness the tool's paths make over the volume (core/squareness_map.py), against a
machine the independent generator (tests/blind) builds and measures with its own kinematics."""

from __future__ import annotations

import io
import json
import sys
from contextlib import redirect_stdout
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "independent"))

from score_blind import true_path_angle  # noqa: E402
from volucal.core.cli import main  # noqa: E402
from volucal.core.errors import SQUARENESS_IDS  # noqa: E402
from volucal.core.io.plan import import_plan, load_plan  # noqa: E402
from volucal.core.loop_source import LoopSource  # noqa: E402
from volucal.core.resources import demo_plan  # noqa: E402
from volucal.core.squareness_map import GRID_PER_AXIS, path_angle  # noqa: E402


@pytest.fixture(scope="module")
def twisted(tmp_path_factory: pytest.TempPathFactory) -> SimpleNamespace:
    # blind 590011 (displacement-only plan, 0.06 µm noise, 200 mm tool): a surface EZ over X×Z,
    # c·u·v + c'·u³·v, turns the X path in Z by an angle that grows with Z: between the X and Z
    # paths the angle runs from about −4 to 63 µrad over the volume, EB0Z being 28
    from tests.blind.scenarios import write_scenario

    folder = tmp_path_factory.mktemp("twisted")
    plan, truth = write_scenario(590011, folder)
    report_path, project_path = folder / "r.json", folder / "p.h5"
    capture = io.StringIO()
    with redirect_stdout(capture):
        code = main(
            ["calibrate", str(plan), "--report", str(report_path), "--project",
             str(project_path), "--no-sensitivity"]
        )
    assert code == 0
    return SimpleNamespace(
        report=json.loads(report_path.read_text()), project=project_path, truth=truth,
        out=capture.getvalue(),
    )


def test_the_squareness_between_the_tool_paths_follows_a_twisting_table_over_the_volume(
    twisted: SimpleNamespace,
) -> None:
    from tests.blind.scenarios import build_scenario

    report, out = twisted.report, twisted.out
    surface = [e for e in report["effects"] if e["kind"] == "cross_axis"]
    assert [e["axis"] for e in surface] == ["Z"]
    mapped = report["squareness_over_volume"]
    assert set(mapped) == set(SQUARENESS_IDS)
    scenario = build_scenario(590011)
    tool = np.asarray(twisted.truth["plan"]["tool_offset_mm"], float)
    for sid, entry in mapped.items():
        ranges = {axis: tuple(entry["volume_mm"][axis]) for axis in "XYZ"}
        assert entry["parameter_urad"] == report["parameters"][sid]["value"][0]
        # at the centre, and where it is lowest and highest, the angle reads as the true paths
        # there within 3 of the standard uncertainties stated there, and within the issue's
        # 2 µrad bound for a squareness
        for key in ("at_centre", "lowest", "highest"):
            place = np.asarray(entry["centre_mm" if key == "at_centre" else f"{key}_at_mm"])
            true = true_path_angle(scenario, tool, sid, place, ranges)
            assert abs(entry[f"{key}_urad"] - true) <= 3.0 * entry[f"{key}_std_urad"], (sid, key)
            assert abs(entry[f"{key}_urad"] - true) <= 2.0
        places = entry["places"]
        assert len(places["place_mm"]) == GRID_PER_AXIS**3
        assert min(places["angle_urad"]) == entry["lowest_urad"]
        assert max(places["std_urad"]) == entry["least_certain_std_urad"]
    twisted_entry = mapped["EB0Z"]
    assert twisted_entry["tilted_by"] == [surface[0]["label"]]
    assert mapped["EC0Y"]["tilted_by"] == [] and mapped["EA0Z"]["tilted_by"] == []
    # the twist is real: over the volume the angle spans far more than its uncertainty
    assert twisted_entry["highest_urad"] - twisted_entry["lowest_urad"] > 40.0
    assert "squareness (µrad): the model's parameter; the angle between the tool's paths" in out
    e = twisted_entry
    assert (
        f"EB0Z {e['parameter_urad']:.2f}; {e['at_centre_urad']:.2f} ± "
        f"{e['at_centre_std_urad']:.2f}; {e['lowest_urad']:.2f} ± {e['lowest_std_urad']:.2f} at "
    ) in out
    assert f"tilted by {surface[0]['label']}" in out


def test_the_project_keeps_the_map_and_the_certificate_prints_it(twisted: SimpleNamespace) -> None:
    # what the workbench and `volucal report` read: the identification's tree, not report.json
    from volucal.core.project import Project
    from volucal.core.report_content import ReportRequest, Table, build_report

    mapped = twisted.report["squareness_over_volume"]
    stored = Project.open(twisted.project).result("identifications", "loop")
    assert json.loads(str(stored["squareness_map_json"])) == mapped
    content = build_report(ReportRequest(twisted.project))
    section = next(s for s in content.sections if s.title == "Identified errors")
    table = [b for b in section.blocks if isinstance(b, Table)][-1]
    assert table.header[1] == "at the centre µrad"
    rows = {row[0].split()[0]: row for row in table.rows}
    for sid, entry in mapped.items():
        row = rows[sid]
        assert row[1] == f"{entry['at_centre_urad']:.2f} ± {2 * entry['at_centre_std_urad']:.2f}"
        place = ", ".join(f"{v:g}" for v in entry["highest_at_mm"])
        assert row[3] == (
            f"{entry['highest_urad']:.2f} ± {2 * entry['highest_std_urad']:.2f} at ({place}) mm"
        )
        assert row[4] == (", ".join(entry["tilted_by"]) or "—")


def test_every_place_of_the_grid_reads_as_the_true_paths_there(twisted: SimpleNamespace) -> None:
    # every one of the 5 × 5 × 5 places report.json holds, not only those it names: within the
    # issue's 2 µrad, and within 4 of the standard uncertainties stated there (over the bands
    # benchmark's 512 maps, 64,000 places, the largest |error / uncertainty| of a map was 3.78)
    from tests.blind.scenarios import build_scenario

    scenario = build_scenario(590011)
    tool = np.asarray(twisted.truth["plan"]["tool_offset_mm"], float)
    for sid, entry in twisted.report["squareness_over_volume"].items():
        ranges = {axis: tuple(entry["volume_mm"][axis]) for axis in "XYZ"}
        places = entry["places"]
        assert np.asarray(places["place_mm"]).shape == (GRID_PER_AXIS**3, 3)
        true = np.array(
            [true_path_angle(scenario, tool, sid, np.array(p), ranges) for p in places["place_mm"]]
        )
        misses = np.asarray(places["angle_urad"]) - true
        assert np.max(np.abs(misses)) <= 2.0, sid
        assert np.max(np.abs(misses) / np.asarray(places["std_urad"])) <= 4.0, sid


def test_a_machine_with_only_squareness_errors_has_that_angle_at_every_place() -> None:
    # no other error: whatever the place and the tool's lever, the paths are straight lines
    # at the squareness's angle, in its sign (to the exact chain's second order, θ² ~ 1e-9)
    machine = import_plan(load_plan(demo_plan())).measurement.machine
    from volucal.core.errors import ErrorModel

    for sid, value in zip(SQUARENESS_IDS, (7.0, -11.0, 23.0), strict=True):
        zero = ErrorModel.zero(machine)
        model = ErrorModel(machine, zero.functions, {sid: value})
        fit = SimpleNamespace(model=model, effects=(), effect_parameters=())
        source = LoopSource(fit)  # type: ignore[arg-type]
        for place in ([0.0, 0.0, 0.0], [400.0, 0.0, 350.0], [120.0, 330.0, 40.0]):
            assert path_angle(source, sid, np.array(place)) == pytest.approx(value, abs=1e-6)
            for other in SQUARENESS_IDS:
                if other != sid:
                    assert path_angle(source, other, np.array(place)) == pytest.approx(
                        0.0, abs=1e-6
                    )
