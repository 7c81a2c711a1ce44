"""Minimum-zone straightness against an independent linear-programming solution.

Issue 14: on the vendor's flatness file (../shared/realdata/aerotech_flatness_angular/
643630-1-1-X-test_Flatness.dat) least squares gives 1.444 µm (the vendor's "Total Accuracy"),
minimum zone 1.418 µm, within 0.001 µm of a linear-programming check. Then random profiles of
10 to 100,000 points (noise, a tilt, a bow, values rounded to 0.1 µm as logs write them): the
largest difference between :func:`volucal.core.iso230_2.minimum_zone` (convex hull and bisection)
and scipy's HiGHS linear program (minimise w subject to m·x + c ≤ y ≤ m·x + c + w), and the time
of each.

Run: ``python benchmarks/bench_straightness.py``
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import linprog
from volucal.core.io.table import ColumnMap, TableFormat, read_table
from volucal.core.iso230_2 import evaluate_straightness, minimum_zone

REALDATA = (Path(__file__).resolve().parents[2] / "shared" / "realdata",
            Path("/work/shared/realdata"))


def linear_programming_zone(x: np.ndarray, y: np.ndarray) -> float:
    n = x.size
    a_ub = np.vstack([np.c_[x, np.ones(n), np.zeros(n)], np.c_[-x, -np.ones(n), -np.ones(n)]])
    result = linprog([0.0, 0.0, 1.0], A_ub=a_ub, b_ub=np.r_[y, -y],
                     bounds=[(None, None), (None, None), (0, None)], method="highs")
    if not result.success:
        raise RuntimeError(result.message)
    return float(result.fun)


def vendor_file() -> int:
    shared = next((p for p in REALDATA if p.is_dir()), None)
    if shared is None:
        print("vendor file: ../shared/realdata is absent, skipped")
        return 0
    path = shared / "aerotech_flatness_angular" / "643630-1-1-X-test_Flatness.dat"
    fmt = TableFormat(columns=ColumnMap(deviation="Flat"), deviation_unit="mm",
                      position_unit="mm", data_marker=":START", environment=False)
    data = read_table(path, fmt).data
    x, y = data.targets_mm, data.deviations[0] * 1e3
    result = evaluate_straightness(x, y)
    zone = linear_programming_zone(x, y)
    ok = (round(result.least_squares, 3) == 1.444 and round(result.minimum_zone, 3) == 1.418
          and abs(result.minimum_zone - zone) < 1e-3)
    print(f"vendor file ({path.name}, {x.size} points):")
    print(f"  least squares   {result.least_squares:.4f} µm  (vendor: 1.444 µm)")
    print(f"  minimum zone    {result.minimum_zone:.4f} µm  (issue: 1.418 µm)")
    print(f"  linear program  {zone:.4f} µm  |difference| {abs(result.minimum_zone - zone):.2e} "
          "µm (target < 0.001 µm)")
    print(f"  end point       {result.end_point:.4f} µm")
    print(f"  {'as required' if ok else 'NOT as required'}")
    return 0 if ok else 1


def random_profiles() -> int:
    rng = np.random.default_rng(2024)
    print("\nrandom profiles: points, |volucal − linear program| (µm), time volucal, time LP")
    worst = 0.0
    for n in (10, 33, 100, 1_000, 10_000, 100_000):
        differences, ours, theirs = [], 0.0, 0.0
        trials = 20 if n <= 10_000 else 3
        for _ in range(trials):
            x = np.sort(rng.uniform(-500, 500, n))
            y = rng.normal(0, 2, n) + rng.normal(0, 0.01) * x + rng.normal(0, 2e-5) * x**2
            y = np.round(y, 1) if rng.random() < 0.3 else y
            start = time.perf_counter()
            width = minimum_zone(x, y)[0]
            ours += time.perf_counter() - start
            start = time.perf_counter()
            zone = linear_programming_zone(x, y)
            theirs += time.perf_counter() - start
            differences.append(abs(width - zone))
        worst = max(worst, max(differences))
        print(f"  {n:>7,}  {max(differences):.2e}  {ours / trials * 1e3:8.2f} ms  "
              f"{theirs / trials * 1e3:8.2f} ms")
    ok = worst < 1e-6
    print(f"  largest difference {worst:.2e} µm: {'as required' if ok else 'NOT as required'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(vendor_file() | random_profiles())
