"""Import a 1,000,000-sample dynamic capture into a project: wall time and peak memory.

Target (issue 3): under 3 s and under 500 MB peak. The capture is a laser sweeping an axis back
and forth at 50 kHz (time, position and deviation channels), as a binary .rtx and as a CSV export;
the plan bins it every 5 mm. Each case runs ``volucal import`` in a fresh process: the time is the
whole command (start-up included; the part after start-up is shown too) and the peak resident
memory is the whole process (Python, numpy, h5py and the data).

Run: ``python benchmarks/bench_import.py``
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from volucal.core.io.capture import write_capture

SAMPLES = 1_000_000
RATE_HZ = 50_000.0

PLAN = """[machine]
name = "bench"
chain = "WXYFZT"
stroke = {{ X = [0, 400], Y = [0, 400], Z = [0, 350] }}

[[line]]
name = "x_capture"
file = "{file}"
format = "capture"
quantity = "linear"
start = [0, 0, 0]
direction = [1, 0, 0]
capture_step_mm = 5.0
"""

CHILD = """
import resource, sys, time
t0 = time.perf_counter()
from volucal.core.cli import build_parser
args = build_parser().parse_args(["import", sys.argv[1], sys.argv[2], "--json"])
t1 = time.perf_counter()
code = args.handler(args)
t2 = time.perf_counter()
peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(f"RESULT {t2 - t0:.3f} {t2 - t1:.3f} {peak_mb:.1f} {code}", file=sys.stderr)
"""


def make_capture(folder: Path, binary: bool) -> Path:
    time_s = np.arange(SAMPLES) / RATE_HZ
    # two sweeps over 400 mm and back (10 s each way), 1 µm reversal, 0.2 µm noise
    period_s = SAMPLES / RATE_HZ / 2
    phase = (time_s % period_s) / period_s
    position = 400.0 * np.where(phase < 0.5, 2 * phase, 2 - 2 * phase)
    direction = np.where(phase < 0.5, 1.0, -1.0)
    rng = np.random.default_rng(1)
    deviation = 0.02 * position + 0.5 * direction + rng.normal(0, 0.2, SAMPLES)
    if binary:
        path = folder / "capture.rtx"
        write_capture(path, deviation, time_s=time_s, position_mm=position, unit="um")
        return path
    # the precision a laser export prints (µs, 0.1 µm positions, 0.1 nm deviations)
    path = folder / "capture.csv"
    with open(path, "w", encoding="ascii") as handle:
        handle.write("time_s,position_mm,deviation_um\n")
        np.savetxt(handle, np.column_stack([time_s, position, deviation]), delimiter=",",
                   fmt=("%.6f", "%.4f", "%.4f"))
    return path


def run_case(folder: Path, binary: bool) -> dict[str, float]:
    capture = make_capture(folder, binary)
    plan = folder / f"plan_{capture.suffix[1:]}.toml"
    plan.write_text(PLAN.format(file=capture.name))
    project = folder / f"project_{capture.suffix[1:]}.h5"
    child = subprocess.run([sys.executable, "-c", CHILD, str(project), str(plan)],
                           capture_output=True, text=True, check=True)
    line = next(x for x in child.stderr.splitlines() if x.startswith("RESULT"))
    _, elapsed, work, peak, code = line.split()
    summary = json.loads(child.stdout)
    return {
        "file_mb": capture.stat().st_size / 1e6,
        "seconds": float(elapsed),
        "work_seconds": float(work),
        "peak_mb": float(peak),
        "exit": int(code),
        "readings": summary["readings"],
        "project_mb": project.stat().st_size / 1e6,
    }


def main() -> None:
    print(f"import of a {SAMPLES:,}-sample capture into a new project "
          f"(target: < 3 s, < 500 MB peak)")
    with tempfile.TemporaryDirectory() as folder:
        for binary, label in ((True, "binary .rtx"), (False, "CSV (chunked)")):
            start = time.perf_counter()
            result = run_case(Path(folder), binary)
            total = time.perf_counter() - start
            verdict = "ok" if result["seconds"] < 3 and result["peak_mb"] < 500 else "MISSED"
            print(f"  {label:14} file {result['file_mb']:5.1f} MB: `volucal import` "
                  f"{result['seconds']:.2f} s (of which reading, binning, screening and the "
                  f"atomic save {result['work_seconds']:.2f} s; the rest is start-up), peak "
                  f"{result['peak_mb']:.0f} MB; {result['readings']} binned readings, project "
                  f"{result['project_mb']:.1f} MB [{verdict}] (with writing the capture: "
                  f"{total:.1f} s)")
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"  (this driver process peaked at {own:.0f} MB while writing the captures)")


if __name__ == "__main__":
    main()
