"""Identification time (issue: full plan, 5 bidirectional runs, 2 mm steps: < 1 s with refinement).

Run: python benchmarks/bench_identify.py
"""

from __future__ import annotations

import time

from volucal.core import plans
from volucal.core.identify import IdentifyOptions, identify
from volucal.core.readings import flatten
from volucal.core.simulate import LaserSetup, VirtualMachine, random_truth


def main() -> None:
    truth = random_truth(seed=2)
    vm = VirtualMachine(truth, seed=2, laser=LaserSetup(noise_um=0.1, noise_urad=0.1))
    lines = plans.full(truth.machine, 2.0)
    measurement = vm.measure(lines)
    readings = flatten(measurement)
    identify(measurement, readings=readings)  # warm up (kernel compilation, caches)
    for redundancy in (False, True):
        options = IdentifyOptions(redundancy=redundancy)
        times = []
        for _ in range(3):
            start = time.perf_counter()
            result = identify(measurement, options, readings=readings)
            times.append(time.perf_counter() - start)
        what = "with the redundant-line analysis" if redundancy else "identification + refinement"
        print(
            f"{len(lines)} lines, {len(readings):,} readings, {result.identifiability.unknowns} "
            f"unknowns, {result.iterations} Gauss-Newton iterations: {what} {min(times):.2f} s"
        )


if __name__ == "__main__":
    main()
