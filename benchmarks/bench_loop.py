"""The closed loop on the demo data set (issue: < 10 s).

Run: python benchmarks/bench_loop.py
"""

from __future__ import annotations

import time

from volucal.core.io.plan import import_plan, load_plan
from volucal.core.residuals import close_loop
from volucal.core.resources import demo_plan


def main() -> None:
    measurement = import_plan(load_plan(demo_plan())).measurement
    close_loop(measurement)  # warm up (kernel compilation)
    times = []
    for _ in range(2):
        start = time.perf_counter()
        result = close_loop(measurement)
        times.append(time.perf_counter() - start)
    kept = ", ".join(e.label for e in result.kept)
    print(
        f"demo loop: {min(times):.2f} s ({len(result.steps)} steps; kept: {kept}; "
        f"CV RMS {result.cv_before.rms_um:.3f} -> {result.cv_after.rms_um:.3f} µm)"
    )


if __name__ == "__main__":
    main()
