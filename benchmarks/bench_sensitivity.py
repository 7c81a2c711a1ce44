"""EFAST sensitivity benchmarks against SALib, measured in the same run.

1. The paper's problem at one position (21 normal factors, N = 1400 per factor, M = 4, four
   outputs Ex, Ey, Ez, ET): sample + evaluate + analyse, volucal against SALib's fast_sampler and
   fast.analyze (one call per output). Both evaluate the same exact chain
   (``sensitivity.chain_affine``), so the comparison is of sampling and analysis.
2. A map on an 11 × 11 × 11 grid, four outputs: volucal analyses every point in one pass; SALib
   is looped over a subset of the points (one sample, then per point: evaluate, four analyses)
   and scaled to the whole grid.

SALib's ``analyze`` bootstraps confidence intervals (100 resamples by default); it is timed as
shipped and, as a lower bound, with 2 resamples (the fewest it accepts). Accuracy is the largest
deviation of S1 from the linear answer c_i²σ_i²/Σc_j²σ_j² at the position (the chain is linear in
the errors there to ~1e-6).

Run: ``python benchmarks/bench_sensitivity.py``. Prints the measured numbers.
"""

from __future__ import annotations

import math
import time
import warnings

import numpy as np
from volucal.core.errors import ERROR_IDS
from volucal.core.machine import PAPER_MACHINE
from volucal.core.paper import table2_iso
from volucal.core.sensitivity import analyse, chain_affine, paper_problem

N = 1400
M = 4
POINT = np.array([200.0, 200.0, 175.0])
TOOL = np.array(PAPER_MACHINE.tool_offset_mm)


def timed(function, repeat: int = 5):
    """(best wall time, best CPU time of this process, last value) over ``repeat`` runs.

    CPU time is reported too because the wall time of both sides depends on what else the
    machine runs."""
    best = cpu = math.inf
    value = None
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        value = function()
        best = min(best, time.perf_counter() - start)
        cpu = min(cpu, time.process_time() - start_cpu)
    return best, cpu, value


def table2() -> tuple[np.ndarray, np.ndarray]:
    table = table2_iso()
    return np.array([table[i][0] for i in ERROR_IDS]), np.array([table[i][1] for i in ERROR_IDS])


def linear_truth(point: np.ndarray) -> np.ndarray:
    """(21, 3) shares c_i²σ_i²/Σc_j²σ_j² of Ex, Ey, Ez from central differences of the chain."""
    mean, sd = table2()
    rows = np.repeat(mean[None], 42, axis=0)
    for k in range(21):
        rows[2 * k, k] += 1e-3
        rows[2 * k + 1, k] -= 1e-3
    offset, gain = chain_affine(PAPER_MACHINE, rows, TOOL)
    error = offset + gain @ point
    share = ((error[0::2] - error[1::2]) / 2e-3) ** 2 * sd[:, None] ** 2
    return share / share.sum(axis=0)


def salib_problem() -> dict:
    mean, sd = table2()
    return {"num_vars": 21, "names": list(ERROR_IDS),
            "bounds": [[m, s] for m, s in zip(mean, sd, strict=True)], "dists": ["norm"] * 21}


def outputs(error: np.ndarray) -> list[np.ndarray]:
    return [error[:, 0], error[:, 1], error[:, 2], np.linalg.norm(error, axis=1)]


def main() -> None:
    from SALib.analyze import fast
    from SALib.sample import fast_sampler

    warnings.simplefilter("ignore")  # SALib warns about its own bootstrap on every call
    problem = salib_problem()
    truth = linear_truth(POINT)

    # ---- one position --------------------------------------------------------------------
    ours_time, ours_cpu, ours = timed(
        lambda: analyse(paper_problem(POINT), n=N, m=M, seed=0, repeats=1)
    )

    def salib_point(resamples: int) -> list[dict]:
        x = fast_sampler.sample(problem, N, M=M, seed=0)
        offset, gain = chain_affine(PAPER_MACHINE, x, TOOL)
        error = offset + gain @ POINT
        return [fast.analyze(problem, y, M=M, num_resamples=resamples) for y in outputs(error)]

    salib_time, salib_cpu, salib = timed(lambda: salib_point(100))
    lean_time, lean_cpu, _ = timed(lambda: salib_point(2))
    ours_error = max(np.abs(ours.s1[k, 0] - truth[:, k]).max() for k in range(3))
    salib_error = max(np.abs(np.asarray(salib[k]["S1"]) - truth[:, k]).max() for k in range(3))
    print("Paper problem at one position (21 factors, N = 1400, M = 4, 4 outputs); wall / CPU")
    print(f"  volucal (tail method, 1 repeat):   {ours_time * 1e3:7.1f} / {ours_cpu * 1e3:6.1f} ms"
          f"   max |S1 - linear| = {ours_error:.4f}")
    print(f"  SALib (100 bootstrap resamples):   {salib_time * 1e3:7.1f} / "
          f"{salib_cpu * 1e3:6.1f} ms   max |S1 - linear| = {salib_error:.4f}   "
          f"S1 sum (Ex) = {np.sum(salib[0]['S1']):.3f}")
    print(f"  SALib (2 resamples):               {lean_time * 1e3:7.1f} / {lean_cpu * 1e3:6.1f} ms")
    print(f"  speed-up, wall: {salib_time / ours_time:.1f}x as shipped, "
          f"{lean_time / ours_time:.1f}x with 2 resamples; CPU: {salib_cpu / ours_cpu:.1f}x, "
          f"{lean_cpu / ours_cpu:.1f}x")
    four_time, _, four = timed(
        lambda: analyse(paper_problem(POINT), n=N, m=M, seed=0, repeats=4), 3
    )
    four_error = max(np.abs(four.s1[k, 0] - truth[:, k]).max() for k in range(3))
    print(f"  volucal, 4 repeats (the default):  {four_time * 1e3:7.1f} ms wall"
          f"   max |S1 - linear| = {four_error:.4f}")

    # ---- a map -----------------------------------------------------------------------------
    axes = [np.linspace(*PAPER_MACHINE.stroke(a), 11) for a in "XYZ"]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    map_time, _, mapped = timed(
        lambda: analyse(paper_problem(grid), n=N, m=M, seed=0, repeats=1), 3
    )
    subset = grid[:: len(grid) // 12][:12]

    def salib_map(points: np.ndarray, resamples: int) -> None:
        x = fast_sampler.sample(problem, N, M=M, seed=0)
        offset, gain = chain_affine(PAPER_MACHINE, x, TOOL)
        for point in points:
            for y in outputs(offset + gain @ point):
                fast.analyze(problem, y, M=M, num_resamples=resamples)

    loop_time, _, _ = timed(lambda: salib_map(subset, 100), 1)
    lean_time, _, _ = timed(lambda: salib_map(subset, 2), 1)
    scale = len(grid) / len(subset)
    print()
    print(f"Map on an 11 x 11 x 11 grid ({len(grid)} points, 4 outputs, N = 1400, M = 4)")
    print(f"  volucal, one pass:                 {map_time:8.2f} s")
    print(f"  SALib looped (100 resamples):      {loop_time * scale:8.1f} s "
          f"(measured {loop_time:.2f} s on {len(subset)} points)")
    print(f"  SALib looped (2 resamples):        {lean_time * scale:8.1f} s "
          f"(measured {lean_time:.2f} s on {len(subset)} points)")
    print(f"  speed-up: {loop_time * scale / map_time:.0f}x (as shipped), "
          f"{lean_time * scale / map_time:.0f}x (2 resamples)")
    centre = int(np.argmin(np.linalg.norm(grid - POINT, axis=1)))
    map_error = max(np.abs(mapped.s1[k, centre] - linear_truth(grid[centre])[:, k]).max()
                    for k in range(3))
    print(f"  map point {grid[centre].tolist()}: max |S1 - linear| = {map_error:.4f}")


if __name__ == "__main__":
    main()
