"""Exact volumetric error throughput (issue: ≥ 10 M scattered points/s; 1 mm grid < 10 s).

Run: python benchmarks/bench_kinematics.py
"""

from __future__ import annotations

import time

import numpy as np
from volucal.core.kinematics import VolumetricModel, naive_error
from volucal.core.simulate import random_truth


def best_of(fn, repeats: int = 3) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    model = random_truth(seed=1)
    vm = VolumetricModel(model)
    rng = np.random.default_rng(0)
    n = 10_000_000
    points = rng.uniform([0, 0, 0], [400, 400, 350], (n, 3))
    vm.error(points[:1000])  # compile the kernel once
    scattered = best_of(lambda: vm.error(points))
    naive_n = 2000
    naive = best_of(lambda: naive_error(model, points[:naive_n]), repeats=1)
    print(
        f"scattered points: {n / scattered / 1e6:.1f} M points/s "
        f"({n:,} points in {scattered:.2f} s)"
    )
    print(
        f"naive per-point 4x4 loop: {naive_n / naive / 1e3:.1f} k points/s "
        f"-> {naive / naive_n * n / scattered:,.0f}x slower"
    )
    xs, ys, zs = np.arange(0, 401.0), np.arange(0, 401.0), np.arange(0, 351.0)

    def grid() -> None:
        worst = 0.0
        for _, e in vm.grid_error(xs, ys, zs):
            worst = max(worst, float(np.abs(e).max()))

    grid_time = best_of(grid, repeats=2)
    count = xs.size * ys.size * zs.size
    print(
        f"1 mm grid: {count / 1e6:.1f} M points in {grid_time:.2f} s "
        f"({count / grid_time / 1e6:.0f} M points/s)"
    )


if __name__ == "__main__":
    main()
