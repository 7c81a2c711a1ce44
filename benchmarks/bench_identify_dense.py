"""Identification of dense plans: time and peak memory (issues 14 and 17).

Targets: the 284-line XY grid identified in < 5 s with 50 mm splines and in < 20 s and < 1 GB
with 10 mm splines; a 1,000-line plan identified in < 1 GB; memory that grows with the number of
unknowns, not with lines × unknowns².

Every case runs in its own Python process, so that its peak resident memory
(``resource.getrusage(RUSAGE_SELF).ru_maxrss``) is its own; the figure includes the interpreter,
numpy and the simulated measurement (printed separately as "baseline" RSS before identifying).

Run: python benchmarks/bench_identify_dense.py [--case NAME ...] [--code DIR] [--cv] [--cli]

``--code DIR`` runs the cases against another checkout of volucal (a folder holding a
``volucal`` package, e.g. ``git archive main | tar -x -C DIR/volucal``) to record the figures of
the code before a change. ``--cv`` also times leave-one-line-out cross-validation. ``--cli``
times ``volucal identify`` and ``volucal calibrate`` on the 200 lines × 400 targets × 10 runs
plan written as a session (logs + plan.toml) in a temporary folder (alone unless cases are named).

Timings depend on how the BLAS library threads: on a machine shared with other work, threaded
BLAS calls wait for cores; ``OPENBLAS_NUM_THREADS=1`` gives the single-core figures.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CASES = {
    # name: (description, plan builder, spacing mm)
    "grid284-50": ("284-line XY grid (71 × 71 targets at 5 mm), 50 mm splines", "grid", 50.0),
    "grid284-10": ("284-line XY grid (71 × 71 targets at 5 mm), 10 mm splines", "grid", 10.0),
    "lines1000": (
        "1,000 axis-parallel lines (17 targets, 4 runs), 50 mm splines",
        "thousand",
        50.0,
    ),
    "dense200": ("200 lines × 400 targets × 10 runs, 50 mm splines", "dense", 50.0),
}


def _rss_mb() -> float:
    """Peak resident set size of this process so far, MB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


# --------------------------------------------------------------------------------------------
# The plans
# --------------------------------------------------------------------------------------------


def grid_plan():  # type: ignore[no-untyped-def]
    """An XY grid cut into line tables, as a 2-D grid measurement with a flat mirror reads it:
    on a 350 × 350 mm plane every 5 mm, each row along X gives a linear (X) and a straightness
    (Y) table, each column along Y a linear (Y) and a straightness (X) table: 71 × 2 × 2 = 284
    lines of 71 targets, one bidirectional run pair each."""
    from volucal.core.machine import Machine
    from volucal.core.measurement import LineSpec
    from volucal.core.plans import PlannedLine, targets
    from volucal.core.simulate import LaserSetup, VirtualMachine, random_truth

    machine = Machine(
        name="XY stage with a grid",
        chain="WXYFZT",
        stroke_mm={"X": (0.0, 350.0), "Y": (0.0, 350.0), "Z": (0.0, 100.0)},
        screw_lead_mm={"X": 10.0, "Y": 10.0, "Z": 10.0},
        tool_offset_mm=(0.0, 0.0, 50.0),
    )
    positions = targets(350.0, 5.0)
    lines = []
    for along in ("X", "Y"):
        u = (1.0, 0.0, 0.0) if along == "X" else (0.0, 1.0, 0.0)
        v = (0.0, 1.0, 0.0) if along == "X" else (1.0, 0.0, 0.0)
        for k, fixed in enumerate(positions):
            start = (0.0, float(fixed), 50.0) if along == "X" else (float(fixed), 0.0, 50.0)
            for quantity in ("linear", "straightness"):
                spec = LineSpec(
                    name=f"{along.lower()}{k:02d}_{'lin' if quantity == 'linear' else 'str'}",
                    quantity=quantity,
                    start_mm=start,
                    direction=u,
                    reflector_mm=(0.0, 0.0, 50.0),
                    sensitive=v if quantity == "straightness" else None,
                )
                lines.append(PlannedLine(spec, positions))
    truth = random_truth(machine, seed=14)
    laser = LaserSetup(runs_per_direction=1, noise_um=0.1, noise_urad=0.1)
    return VirtualMachine(truth, seed=14, laser=laser).measure(lines)


def thousand_plan():  # type: ignore[no-untyped-def]
    """1,000 lines on the paper's mill: along each axis, a 10 × 11 grid of start positions
    across the other two axes, each with a linear and two straightness tables (990 lines),
    plus ten face and body diagonals; targets every 25 mm, two bidirectional run pairs."""
    import numpy as np
    from volucal.core.machine import AXES, AXIS_INDEX, PAPER_MACHINE
    from volucal.core.measurement import LineSpec
    from volucal.core.plans import PlannedLine, targets
    from volucal.core.simulate import LaserSetup, VirtualMachine, random_truth

    machine = PAPER_MACHINE
    unit = {a: tuple(float(a == b) for b in AXES) for a in AXES}
    lines = []
    for axis in AXES:
        others = [a for a in AXES if a != axis]
        low, high = machine.stroke(axis)
        grid_a = np.linspace(*machine.stroke(others[0]), 10)
        grid_b = np.linspace(*machine.stroke(others[1]), 11)
        for i, a in enumerate(grid_a):
            for j, b in enumerate(grid_b):
                start = [0.0, 0.0, 0.0]
                start[AXIS_INDEX[axis]] = low
                start[AXIS_INDEX[others[0]]] = float(a)
                start[AXIS_INDEX[others[1]]] = float(b)
                for quantity, sensitive in (
                    ("linear", None),
                    *(("straightness", s) for s in others),
                ):
                    name = f"{axis.lower()}_{i}_{j}_{quantity[:3]}{sensitive or ''}".lower()
                    spec = LineSpec(
                        name=name,
                        quantity=quantity,
                        start_mm=tuple(start),  # type: ignore[arg-type]
                        direction=unit[axis],  # type: ignore[arg-type]
                        reflector_mm=machine.tool_offset_mm,
                        sensitive=unit[sensitive] if sensitive else None,  # type: ignore[arg-type]
                    )
                    lines.append(PlannedLine(spec, targets(high - low, 25.0)))
    lo = np.array([machine.stroke(a)[0] for a in AXES])
    hi = np.array([machine.stroke(a)[1] for a in AXES])
    diagonals = [
        (lo, hi),
        ((hi[0], lo[1], lo[2]), (lo[0], hi[1], hi[2])),
        ((lo[0], hi[1], lo[2]), (hi[0], lo[1], hi[2])),
        ((hi[0], hi[1], lo[2]), (lo[0], lo[1], hi[2])),
        ((lo[0], lo[1], 175.0), (hi[0], hi[1], 175.0)),
        ((lo[0], hi[1], 175.0), (hi[0], lo[1], 175.0)),
        ((lo[0], 200.0, lo[2]), (hi[0], 200.0, hi[2])),
        ((hi[0], 200.0, lo[2]), (lo[0], 200.0, hi[2])),
        ((200.0, lo[1], lo[2]), (200.0, hi[1], hi[2])),
        ((200.0, hi[1], lo[2]), (200.0, lo[1], hi[2])),
    ]
    for k, (s, e) in enumerate(diagonals):
        s, e = np.asarray(s, float), np.asarray(e, float)
        length = float(np.linalg.norm(e - s))
        spec = LineSpec(
            name=f"diagonal_{k}",
            quantity="linear",
            start_mm=tuple(s),  # type: ignore[arg-type]
            direction=tuple((e - s) / length),  # type: ignore[arg-type]
            reflector_mm=machine.tool_offset_mm,
        )
        lines.append(PlannedLine(spec, targets(length, 25.0)))
    truth = random_truth(machine, seed=17)
    laser = LaserSetup(runs_per_direction=2, noise_um=0.1, noise_urad=0.1)
    return VirtualMachine(truth, seed=17, laser=laser).measure(lines)


def dense_plan():  # type: ignore[no-untyped-def]
    """200 lines of 400 targets and 10 runs (5 bidirectional pairs) on the paper's mill: the
    full layout's 49 lines repeated at four heights or offsets (196), plus four face diagonals;
    targets spread evenly over each line."""
    import numpy as np
    from volucal.core import plans
    from volucal.core.machine import PAPER_MACHINE
    from volucal.core.measurement import LineSpec
    from volucal.core.plans import PlannedLine
    from volucal.core.simulate import LaserSetup, VirtualMachine, random_truth

    machine = PAPER_MACHINE
    base = plans.full(machine, 12.0)
    lines = []
    for shift in range(4):
        for planned in base:
            spec = planned.spec
            start = np.asarray(spec.start_mm, float)
            # move the line across its travel, inside the strokes, so the copies differ
            for k, axis in enumerate("XYZ"):
                low, high = machine.stroke(axis)
                if abs(spec.direction[k]) < 1e-12:
                    start[k] = low + (start[k] - low + 37.0 * shift) % (high - low)
            length = float(planned.targets_mm[-1])
            moved = LineSpec(
                name=f"{spec.name}_{shift}",
                quantity=spec.quantity,
                start_mm=tuple(start),  # type: ignore[arg-type]
                direction=spec.direction,
                reflector_mm=spec.reflector_mm,
                sensitive=spec.sensitive,
                deviation_unit=spec.deviation_unit,
            )
            lines.append(PlannedLine(moved, np.linspace(0.0, length, 400)))
    for planned in base[-4:]:
        spec = planned.spec
        lines.append(
            PlannedLine(
                LineSpec(
                    name=f"{spec.name}_extra",
                    quantity=spec.quantity,
                    start_mm=spec.start_mm,
                    direction=spec.direction,
                    reflector_mm=spec.reflector_mm,
                    sensitive=spec.sensitive,
                    deviation_unit=spec.deviation_unit,
                ),
                np.linspace(0.0, float(planned.targets_mm[-1]), 400),
            )
        )
    assert len(lines) == 200, len(lines)
    truth = random_truth(machine, seed=200)
    laser = LaserSetup(runs_per_direction=5, noise_um=0.1, noise_urad=0.1)
    return VirtualMachine(truth, seed=200, laser=laser).measure(lines)


PLANS = {"grid": grid_plan, "thousand": thousand_plan, "dense": dense_plan}


# --------------------------------------------------------------------------------------------
# One case, in this process
# --------------------------------------------------------------------------------------------


def run_case(name: str, cv: bool) -> dict[str, object]:
    from volucal.core.identify import IdentifyOptions, cross_validate, identify
    from volucal.core.readings import flatten

    _, plan, spacing = CASES[name]
    measurement = PLANS[plan]()
    readings = flatten(measurement)
    baseline = _rss_mb()
    start = time.perf_counter()
    result = identify(measurement, IdentifyOptions(spacing_mm=spacing), readings=readings)
    seconds = time.perf_counter() - start
    out: dict[str, object] = {
        "case": name,
        "lines": len(measurement.lines),
        "readings": len(readings),
        "unknowns": result.identifiability.unknowns,
        "rank": result.identifiability.rank,
        "redundant": len(result.identifiability.redundant_lines),
        "iterations": result.iterations,
        "identify_s": seconds,
        "baseline_rss_mb": baseline,
        "peak_rss_mb": _rss_mb(),
    }
    if cv:
        start = time.perf_counter()
        validation = cross_validate(result.system, readings, result.identifiability.redundant_lines)
        out["cv_s"] = time.perf_counter() - start
        out["cv_method"] = validation.method
        out["cv_rms_um"] = validation.rms_um
        out["peak_rss_after_cv_mb"] = _rss_mb()
    return out


# --------------------------------------------------------------------------------------------
# The command line tools on the 200 × 400 × 10 plan
# --------------------------------------------------------------------------------------------


def run_cli(env: dict[str, str]) -> None:
    """``volucal import`` + ``identify`` + ``calibrate`` on the dense plan written as a session;
    each command's wall time and peak RSS (GNU time is not assumed: a small wrapper reads the
    child's rusage)."""
    with tempfile.TemporaryDirectory(prefix="volucal-dense-") as folder:
        write = (
            "import sys\n"
            "from pathlib import Path\n"
            "sys.path.insert(0, str(Path(sys.argv[2])))\n"
            "from bench_identify_dense import dense_plan\n"
            "from volucal.core.simulate import write_session\n"
            "write_session(dense_plan(), sys.argv[1])\n"
        )
        subprocess.run(
            [sys.executable, "-c", write, folder, str(Path(__file__).parent)], env=env, check=True
        )
        plan = str(Path(folder) / "plan.toml")
        project = str(Path(folder) / "dense.h5")
        for label, argv in (
            ("volucal import", ["import", project, plan]),
            ("volucal identify", ["identify", project]),
            (
                "volucal calibrate",
                ["calibrate", plan, "--quiet", "--report", str(Path(folder) / "r.json")],
            ),
        ):
            seconds, peak, code = _timed_cli(argv, env)
            print(f"{label:<20} {seconds:8.1f} s  peak RSS {peak:8.0f} MB  exit {code}")


def _timed_cli(argv: list[str], env: dict[str, str]) -> tuple[float, float, int]:
    start = time.perf_counter()
    child = subprocess.Popen(
        [sys.executable, "-m", "volucal.core.cli", *argv],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    _, stderr = child.communicate()
    seconds = time.perf_counter() - start
    if child.returncode:
        sys.stderr.write(stderr.decode(errors="replace")[-2000:])
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    return seconds, peak, child.returncode


# --------------------------------------------------------------------------------------------
# Main
# --------------------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", action="append", choices=sorted(CASES), help="cases to run")
    parser.add_argument("--code", type=Path, help="folder holding another volucal package")
    parser.add_argument("--cv", action="store_true", help="also time cross-validation")
    parser.add_argument("--cli", action="store_true", help="time the CLI on the dense plan")
    parser.add_argument("--one", help=argparse.SUPPRESS)  # internal: run one case, print JSON
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_case(args.one, args.cv)))
        return
    env = dict(os.environ)
    if args.code:
        env["PYTHONPATH"] = os.pathsep.join([str(args.code.resolve()), env.get("PYTHONPATH", "")])
    cases = args.case or ([] if args.cli else list(CASES))
    for name in cases:
        command = [sys.executable, __file__, "--one", name] + (["--cv"] if args.cv else [])
        done = subprocess.run(command, env=env, capture_output=True, text=True)
        if done.returncode:
            print(f"{name}: failed (exit {done.returncode})\n{done.stderr[-2000:]}")
            continue
        r = json.loads(done.stdout.strip().splitlines()[-1])
        line = (
            f"{CASES[name][0]}: {r['lines']} lines, {r['readings']:,} readings, "
            f"{r['unknowns']} unknowns (rank {r['rank']}), {r['redundant']} redundant, "
            f"{r['iterations']} iterations\n"
            f"    identify {r['identify_s']:.1f} s, peak RSS {r['peak_rss_mb']:.0f} MB "
            f"(before identifying {r['baseline_rss_mb']:.0f} MB)"
        )
        if "cv_s" in r:
            line += (
                f"\n    cross-validation ({r['cv_method']}) {r['cv_s']:.1f} s, "
                f"CV RMS {r['cv_rms_um']:.4f} µm, peak RSS {r['peak_rss_after_cv_mb']:.0f} MB"
            )
        print(line, flush=True)
    if args.cli:
        run_cli(env)


if __name__ == "__main__":
    main()
