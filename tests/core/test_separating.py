"""The lines volucal names to tell apart surfaces the plan cannot place, checked on machines of
the blind generator (tests/blind): measured there, the machine reads as the surface of its own
place and not as the one the loop kept."""

import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "independent"))

from score_blind import true_tool_error  # noqa: E402

from tests.blind.scenarios import build_scenario, write_scenario  # noqa: E402


def _left(difference: np.ndarray, travel: np.ndarray) -> float:
    """Peak of a difference along a line once its constant and slope are removed (µm)."""
    design = np.stack([np.ones_like(travel), travel - travel.mean()], axis=1)
    coefficients, *_ = np.linalg.lstsq(design, difference, rcond=None)
    return float(np.max(np.abs(difference - design @ coefficients)))


@pytest.mark.parametrize("seed", [50086, 55053])
def test_the_lines_named_to_tell_rival_surfaces_apart_read_the_machine_s_own(seed: int) -> None:
    # direct plan, one surface: 50086 EX over X×Z kept as EZ over Y×Z, 55053 EZ over X×Z kept
    # as EZ over X×Y (beside a cycle and a reversal of X); each plan line reads both alike
    from volucal.core.effects import CrossAxis
    from volucal.core.identify import IdentifyOptions, identify
    from volucal.core.io.plan import import_plan, load_plan
    from volucal.core.loop_source import LoopSource
    from volucal.core.machine import AXIS_INDEX
    from volucal.core.residuals import close_loop
    from volucal.core.separating import SAMPLES

    with tempfile.TemporaryDirectory(prefix="volucal-blind-") as tmp:
        plan, truth = write_scenario(seed, tmp)
        measurement = import_plan(load_plan(plan)).measurement
    result = close_loop(measurement)
    report = result.to_report()
    (injected,) = [e for e in truth["effects"] if e["kind"] == "cross_axis"]
    place = (injected["axis"], set(injected["depends_on"]))
    (kept,) = [e for e in report["effects"] if e["kind"] == "cross_axis"]
    assert (kept["axis"], set(kept["parameters"]["depends_on"])) != place
    rivals = kept["rivals"]
    (own,) = [
        r["parameters"]
        for r in rivals["effects"]
        if r["kind"] == "cross_axis" and (r["axis"], set(r["parameters"]["depends_on"])) == place
    ][:1]
    separated = rivals["separated_by"]
    assert separated["lines"]
    # the kept surface and the machine's place are told apart
    for pair in separated["not_told_apart"]:
        assert kept["label"] not in pair
    (warning,) = [w for w in report["warnings"] if "cannot tell which direction and pair" in w]
    assert "tell them apart" in warning and "times the noise of one reading" in warning

    # the fit with the surface of the machine's own place, beside the other effects kept
    machine = result.final.model.machine
    surface = CrossAxis(
        injected["axis"], *own["depends_on"], machine, own["order"], own["lever_terms"]
    )
    rest = [e for e in result.final.effects if not isinstance(e, CrossAxis)]
    right = identify(
        measurement,
        result.identify_options(IdentifyOptions()),
        [*rest, surface],
        readings=result.final.readings,
        initial=result.final.model,
    )
    scenario = build_scenario(seed)
    specs = [line.spec for line in result.final.readings.lines]
    noise = separated["noise_um"]
    off_kept = []
    for line in separated["lines"]:
        k = AXIS_INDEX[line["along"]]
        travel = np.linspace(*machine.stroke(line["along"]), SAMPLES)
        q = np.zeros((SAMPLES, 3))
        q[:, k] = travel
        for axis, value in line["at_mm"].items():
            q[:, AXIS_INDEX[axis]] = value
        along = [s for s in specs if abs(s.direction[k]) > 1 - 1e-6]
        tool = np.asarray((along or specs)[0].reflector_mm, dtype=float)
        j = AXIS_INDEX[line["reads"]]
        reads = true_tool_error(scenario, tool, q)[:, j]
        kept_reads = LoopSource(result.final).error_um(q, None, tool)[:, j]
        right_reads = LoopSource(right).error_um(q, None, tool)[:, j]
        # the machine, measured on the named line, reads as the surface of its own place ...
        assert _left(reads - right_reads, travel) < 2.0 * noise
        off_kept.append(_left(reads - kept_reads, travel))
    # ... and far from the kept one on at least one of them
    assert max(off_kept) > 20.0 * noise


def test_fits_that_read_alike_on_every_line_are_told_apart_by_none() -> None:
    # the same fit twice: no line the plan lacks reads them apart, and none is named
    from volucal.core.identify import identify
    from volucal.core.io.plan import import_plan, load_plan
    from volucal.core.separating import separating_lines

    with tempfile.TemporaryDirectory(prefix="volucal-blind-") as tmp:
        plan, _ = write_scenario(50086, tmp)
        measurement = import_plan(load_plan(plan)).measurement
    fit = identify(measurement)
    assert separating_lines([fit], ["kept"]) is None
    assert separating_lines([fit, fit], ["kept", "rival"]) is None
