"""The loop suite's plans moved onto machines of other sizes and chains (benchmarks/machines.py),
and the loop on them: every scenario the suite had run was on the paper's 400 × 400 × 350 mm
machine."""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests" / "independent"))

from machines import MACHINES, write_plans  # noqa: E402
from volucal.core.io.plan import load_plan  # noqa: E402

from tests.blind.laser import line_length, read_plan  # noqa: E402
from tests.blind.scenarios import PLANS  # noqa: E402


def _ends(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each line's first and last point inside the strokes (the generator's own reading)."""
    spec = read_plan(path)
    return {
        line.name: (
            line.start_mm,
            line.start_mm + line_length(line, spec.stroke_mm) * line.direction,
        )
        for line in spec.lines
    }


@pytest.mark.parametrize("size", sorted(MACHINES))
def test_a_moved_plan_keeps_every_line_at_its_place_relative_to_the_strokes(tmp_path, size) -> None:
    machine = MACHINES[size]
    moved = write_plans(tmp_path, machine, list(PLANS))
    for source, path in moved.items():
        plan = load_plan(path)  # volucal reads it as a user's plan
        assert plan.machine.stroke("X") == machine.stroke_mm["X"]
        assert plan.machine.chain == machine.chain == read_plan(path).chain
        document = tomllib.loads(path.read_text(encoding="utf-8"))
        assert document["machine"]["screw_lead"] == machine.screw_lead_mm
        assert document["machine"]["tool_offset"] == [0.0, 0.0, machine.tool_mm]
        old = read_plan(ROOT / source)
        old_ends, new_ends = _ends(ROOT / source), _ends(path)
        assert set(old_ends) == set(new_ends)
        for name, (first, last) in old_ends.items():
            # both ends of every line, diagonals included, are the old ones scaled axis by axis
            for old_point, new_point in zip((first, last), new_ends[name], strict=True):
                for i, axis in enumerate("XYZ"):
                    lo, hi = old.stroke_mm[axis]
                    new_lo, new_hi = machine.stroke_mm[axis]
                    ratio = (new_hi - new_lo) / (hi - lo)
                    expected = new_lo + (old_point[i] - lo) * ratio
                    # each length is floored to 0.01 mm, the old one then scaled by the ratio
                    tolerance = 0.02 * max(1.0, ratio)
                    assert new_point[i] == pytest.approx(expected, abs=tolerance), (
                        source,
                        name,
                        axis,
                    )
        for old_line, new_line in zip(old.lines, read_plan(path).lines, strict=True):
            # the optics keep their place beside the tool, the lever arms scaled by ``lever``
            lever = old_line.reflector_mm - old.tool_offset_mm
            assert np.allclose(
                new_line.reflector_mm, [0.0, 0.0, machine.tool_mm] + machine.lever * lever
            )
            if old_line.sensitive is not None:
                assert np.array_equal(new_line.sensitive, old_line.sensitive)


def _loop_on(size: str, seed: int, tmp_path: Path):  # type: ignore[no-untyped-def]
    """The blind scenario ``seed`` on its plan moved onto ``size``, through volucal's import."""
    from volucal.core.io.plan import import_plan
    from volucal.core.residuals import close_loop

    from tests.blind.scenarios import draw_plan_and_category, write_scenario

    plans = write_plans(tmp_path / "plans", MACHINES[size], list(PLANS))
    plan = str(plans[draw_plan_and_category(seed)[0]])
    path, truth = write_scenario(seed, tmp_path / "scenario", plan=plan)
    return close_loop(import_plan(load_plan(path)).measurement).to_report(), truth


def test_a_cycle_of_a_third_of_a_small_machines_stroke_is_kept_at_its_period(tmp_path) -> None:
    # blind 97141 on the 250 × 200 × 150 mm machine: a 3.6 µm cycle of Y of 58.8 mm, 3.4
    # periods over the 200 mm stroke, at 0.37 µm noise. The period search stopped at a quarter
    # of the stroke (50 mm): a finer Y function took the cycle first, then a 42.1 mm cycle
    # what was left.
    report, truth = _loop_on("small", 97141, tmp_path)
    (cycle,) = [e for e in truth["effects"] if e["kind"] == "cyclic"]
    assert (cycle["axis"], cycle["parameters"]["period_mm"]) == (
        "Y",
        pytest.approx(58.79, abs=0.01),
    )
    (kept,) = report["effects"]
    assert kept["kind"] == "cyclic" and kept["axis"] == "Y"
    # the stroke's frequency resolution at this period is 58.8² / 200 = 17 mm
    assert kept["parameters"]["period_mm"] == pytest.approx(58.79, abs=1.0)
    assert kept["parameters"]["amplitude_um"] == pytest.approx(3.61, abs=0.2)


def test_a_cosine_error_of_a_gantrys_line_is_kept_on_that_line_not_on_its_twin(tmp_path) -> None:
    # blind 97047 on the 2000 × 3000 × 500 mm gantry (chain WFYXZT), twelve-line plan: a cosine
    # error of x_lin_1 (−3.96 ppm) at 0.07 µm noise. X's yaw does not act through y there, so
    # x_lin_1 and x_lin_2, 3000 mm apart along Y, read the same errors: the 21 errors split the
    # cosine error between them and x_lin_2 read 3.96 ppm long. Its cosine error was refused as
    # implausible, x_lin_1's was never refitted, and a surface EX over X×Y was kept instead.
    report, truth = _loop_on("gantry", 97047, tmp_path)
    (cosine,) = truth["effects"]
    assert (cosine["kind"], cosine["line"]) == ("cosine", "x_lin_1")
    (kept,) = report["effects"]
    assert (kept["kind"], kept["parameters"]["line"]) == ("cosine", "x_lin_1")
    # fitted to 0.006 ppm (one standard uncertainty): 0.05 ppm is eight of them
    assert kept["parameters"]["scale_ppm"] == pytest.approx(
        cosine["parameters"]["scale_ppm"], abs=0.05
    )
    assert report["unexplained"] == []
