"""A long fuzz run of the readers, and the small-input attacks of issues 16 and 17.

Part 1, fuzz: for every format, N mutants of the corpus of tests/core/fuzz_corpus.py (demo logs,
hand-written samples, the real files of ../shared/realdata when present) are read in a fresh
process; printed per format: the files, the counts by outcome (clean error / accepted / other),
the largest input, the time and the peak resident memory of that process (which bounds the peak
of every single import in it, all inputs being under 1 MB).

Part 2, attacks: each file the issues name is read in its own fresh process: the outcome, its
message, the time and the peak resident memory (and the baseline of a process that only imported
volucal). Targets: every attack refused in one line, in well under a second, and the peak of any
import of a file under 1 MB under 500 MB.

Run: ``python benchmarks/bench_fuzz.py [--cases N] [--formats rtl,table,…]``
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve()
sys.path.insert(0, str(HERE.parents[1] / "tests" / "core"))

FORMATS = ("rtl", "rta", "table", "iso230-2", "capture", "plan")


def peak_mb() -> float:
    """Peak resident memory of this process (ru_maxrss is KiB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


# ---- part 1: the fuzz workers -------------------------------------------------------------------


def fuzz_worker(kind: str, cases: int) -> dict[str, object]:
    work = Path(tempfile.mkdtemp(prefix=f"volucal-bench-fuzz-{kind}-"))
    try:
        return _fuzz(kind, cases, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _fuzz(kind: str, cases: int, work: Path) -> dict[str, object]:
    import random

    from fuzz_corpus import mutate, run_case, seeds

    corpus = seeds(work)[kind]
    baseline = peak_mb()
    rng = random.Random(f"volucal-bench-fuzz-{kind}")
    counts = {"clean error": 0, "accepted": 0, "other": 0}
    others: list[str] = []
    largest = 0
    start = time.perf_counter()
    for case in range(cases):
        seed = corpus[case % len(corpus)]
        content, applied = mutate(seed.content, rng)
        largest = max(largest, len(content))
        outcome = run_case(seed, content, work)
        counts[outcome.kind] += 1
        if outcome.kind == "other" and len(others) < 5:
            others.append(f"{seed.origin} [{applied}]: {outcome.detail[:300]}")
    return {"kind": kind, "seeds": len(corpus), "cases": cases, "counts": counts,
            "others": others, "largest_bytes": largest, "seconds": time.perf_counter() - start,
            "baseline_mb": baseline, "peak_mb": peak_mb()}


# ---- part 2: the attacks ------------------------------------------------------------------------


def _rtl_claiming_a_huge_grid(folder: Path) -> tuple[Path, list[str]]:
    """An 817 KB-class .rtl: 100,000 targets listed, Run-count 1,000 (issue 17)."""
    from fuzz_corpus import DATA

    text = (DATA / "x_axis_hand.rtl").read_text()
    targets = "\n".join(f"{i * 0.01:.2f}" for i in range(100_000))
    text = text.replace("Target-count: 5", "Target-count: 100000").replace(
        "  0.000000  100.000000  200.000000  300.000000  400.000000", targets).replace(
        "Run-count: 4", "Run-count: 1000")
    path = folder / "huge.rtl"
    path.write_text(text)
    return path, ["iso230-2", str(path)]


def _csv_one_run_per_row(folder: Path) -> tuple[Path, list[str]]:
    """A ~170 KB CSV whose every row is its own run (issue 17: 3.35 GB)."""
    rows = "\n".join(f"{i},{i * 0.001:.3f},{i}" for i in range(10_000))
    path = folder / "runs.csv"
    path.write_text("position_mm,deviation_um,run\n" + rows + "\n")
    return path, ["iso230-2", str(path)]


def _capture_spanning_a_kilometre(folder: Path) -> tuple[Path, list[str]]:
    """A 144-byte-class capture whose positions span 1e9 mm (issue 17: 7.45 GiB)."""
    import numpy as np

    values = np.array([0.0, 1.0, 1e9, 2.0, 0.0, 3.0], dtype="<f8")
    head = (b"HEADER::\nSample rate: 10\nSample count: 3\nChannels: position_mm deviation\n"
            b"Units: um\nData:\n")
    path = folder / "span.rtx"
    path.write_bytes(head + values.tobytes() + b"\nEOF::\n")
    return path, _plan(folder, path, 'format = "capture"\ncapture_step_mm = 0.1\n')


def _capture_within_limits_but_wide(folder: Path) -> tuple[Path, list[str]]:
    """Positions 0…900 m binned every 0.1 mm: 9e6 targets, refused before the grid exists."""
    import numpy as np

    values = np.array([0.0, 1.0, 9e5, 2.0, 0.0, 3.0], dtype="<f8")
    head = (b"HEADER::\nSample rate: 10\nSample count: 3\nChannels: position_mm deviation\n"
            b"Units: um\nData:\n")
    path = folder / "wide.rtx"
    path.write_bytes(head + values.tobytes() + b"\nEOF::\n")
    return path, _plan(folder, path, 'format = "capture"\ncapture_step_mm = 0.1\n')


def _capture_claiming_more_samples(folder: Path) -> tuple[Path, list[str]]:
    """A mutated .rtx whose header claims 10⁹ samples (issue 16)."""
    import numpy as np

    head = (b"HEADER::\nSample rate: 10\nSample count: 1000000000\nChannels: time_s position_mm "
            b"deviation\nUnits: um\nData:\n")
    path = folder / "claims.rtx"
    path.write_bytes(head + np.arange(9, dtype="<f8").tobytes() + b"\nEOF::\n")
    return path, _plan(folder, path, 'format = "capture"\ncapture_step_mm = 1\n')


def _capture_one_byte_short(folder: Path) -> tuple[Path, list[str]]:
    """The newline before EOF:: read as data: later values 1.3e294 µm (issue 17)."""
    import numpy as np

    head = (b"HEADER::\nSample rate: 10\nSample count: 3\nChannels: position_mm deviation\n"
            b"Units: um\nData:\n")
    block = np.array([0.0, 1.0, 1.0, 2.0, 2.0, 3.0], dtype="<f8").tobytes()
    path = folder / "short.rtx"
    path.write_bytes(head + block[:-1] + b"\nEOF::\n")
    return path, _plan(folder, path, 'format = "capture"\ncapture_step_mm = 1\n')


def _sparse_file_in_a_plan(folder: Path) -> tuple[Path, list[str]]:
    """A 2 GB sparse file named in a plan (issue 17: read whole)."""
    path = folder / "sparse.csv"
    with open(path, "wb") as handle:
        handle.truncate(2 << 30)
    return path, _plan(folder, path, 'deviation_unit = "um"\n')


def _dev_zero(folder: Path) -> tuple[Path, list[str]]:
    return Path("/dev/zero"), ["iso230-2", "/dev/zero"]


def _fifo_in_a_plan(folder: Path) -> tuple[Path, list[str]]:
    path = folder / "pipe.csv"
    os.mkfifo(path)
    return path, _plan(folder, path, 'deviation_unit = "um"\n')


def _proc_environ_in_a_plan(folder: Path) -> tuple[Path, list[str]]:
    return Path("/proc/self/environ"), _plan(folder, Path("/proc/self/environ"), "")


def _proc_environ_as_a_table(folder: Path) -> tuple[Path, list[str]]:
    return Path("/proc/self/environ"), _plan(folder, Path("/proc/self/environ"),
                                             'format = "table"\ndeviation_unit = "um"\n')


def _overflowing_targets(folder: Path) -> tuple[Path, list[str]]:
    from fuzz_corpus import DATA

    text = (DATA / "x_axis_hand.rtl").read_text().replace("0.000000  100.000000",
                                                          "-1e308  100.000000")
    path = folder / "targets.rtl"
    path.write_text(text)
    return path, ["iso230-2", str(path)]


def _overflowing_positions(folder: Path) -> tuple[Path, list[str]]:
    path = folder / "positions.csv"
    path.write_text("position_m,deviation_um\n0,1\n1e306,2\n")
    return path, ["iso230-2", str(path)]


def _overflowing_deviations(folder: Path) -> tuple[Path, list[str]]:
    path = folder / "deviations.csv"
    path.write_text("position_mm,deviation_mm\n0,1\n5,1e307\n")
    return path, ["iso230-2", str(path)]


def _plan(folder: Path, data: Path, extra: str) -> list[str]:
    plan = folder / f"plan_{data.stem}.toml"
    plan.write_text('[machine]\nstroke = { X = [0, 400], Y = [0, 400], Z = [0, 400] }\n\n'
                    f'[[line]]\nname = "x"\nfile = "{data}"\nquantity = "linear"\n'
                    f'start = [0, 0, 0]\ndirection = [1, 0, 0]\n{extra}')
    return ["import", str(folder / f"{data.stem}.h5"), str(plan), "--files-root", "/"]


def _valid_rtl(folder: Path) -> tuple[Path, list[str]]:
    """A valid log just under 1 MB: 2,000 targets × 20 runs."""
    import numpy as np
    from volucal.core.io.rtl import reading_times, write_rtl
    from volucal.core.measurement import LineData

    runs, count = 20, 2000
    direction = np.tile([1, -1], runs // 2)
    rng = np.random.default_rng(1)
    data = LineData(np.arange(count) * 0.2, np.round(rng.normal(0, 2, (runs, count)), 4),
                    direction, reading_times(runs, count, 3600.0, direction), 1.7e9)
    path = folder / "valid.rtl"
    write_rtl(path, data)
    return path, ["iso230-2", str(path)]


def _valid_table(folder: Path) -> tuple[Path, list[str]]:
    """A valid CSV just under 1 MB: 25 runs × 1,600 targets, one row per reading."""
    rows = []
    for run in range(25):
        targets = range(1600) if run % 2 == 0 else range(1599, -1, -1)
        rows += [f"{run + 1},{'+1' if run % 2 == 0 else '-1'},{t * 0.25:.2f},{(t % 17) * 0.1:.1f}"
                 for t in targets]
    path = folder / "valid.csv"
    path.write_text("run,direction,position_mm,deviation_um\n" + "\n".join(rows) + "\n")
    return path, ["iso230-2", str(path)]


def _valid_capture(folder: Path) -> tuple[Path, list[str]]:
    """A valid binary capture just under 1 MB: 40,000 samples × 3 channels, binned at 1 mm."""
    import numpy as np
    from volucal.core.io.capture import write_capture

    t = np.arange(40_000) / 1000.0
    position = 50.0 * (1 - np.cos(2 * np.pi * t / 20.0))
    path = folder / "valid.rtx"
    write_capture(path, np.sin(position / 7.0), time_s=t, position_mm=position)
    return path, _plan(folder, path, 'format = "capture"\ncapture_step_mm = 1\n')


VALID = {
    "valid .rtl, 2,000 targets × 20 runs": _valid_rtl,
    "valid CSV, 25 runs × 1,600 targets": _valid_table,
    "valid capture, 40,000 samples": _valid_capture,
}
ATTACKS = {
    "rtl claiming 100,000 targets × 1,000 runs": _rtl_claiming_a_huge_grid,
    "CSV with one run per row (10,000 rows)": _csv_one_run_per_row,
    "capture spanning 1e9 mm": _capture_spanning_a_kilometre,
    "capture spanning 9e5 mm at 0.1 mm": _capture_within_limits_but_wide,
    "capture claiming 1e9 samples": _capture_claiming_more_samples,
    "binary capture one byte short": _capture_one_byte_short,
    "2 GB sparse file in a plan": _sparse_file_in_a_plan,
    "iso230-2 /dev/zero": _dev_zero,
    "FIFO in a plan": _fifo_in_a_plan,
    "/proc/self/environ in a plan": _proc_environ_in_a_plan,
    "/proc/self/environ in a plan, declared a table": _proc_environ_as_a_table,
    "targets ±1e308": _overflowing_targets,
    "positions 1e306 m": _overflowing_positions,
    "deviations 1e307 mm": _overflowing_deviations,
}


def attack_worker(name: str) -> dict[str, object]:
    import contextlib
    import io

    from volucal.core.cli import build_parser, main

    build_parser()  # every command module imported before the baseline and the clock
    folder = Path(tempfile.mkdtemp(prefix="volucal-bench-attack-"))
    try:
        path, command = {**ATTACKS, **VALID}[name](folder)
        size = path.stat().st_size if path.is_file() and path.parent == folder else None
        baseline = peak_mb()
        err = io.StringIO()
        start = time.perf_counter()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            status = main(command)
        seconds = time.perf_counter() - start
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return {"name": name, "bytes": size, "status": status, "message": err.getvalue().strip(),
            "seconds": seconds, "baseline_mb": baseline, "peak_mb": peak_mb(),
            "secret_echoed": "PATH=" in err.getvalue()}


# ---- the parent -----------------------------------------------------------------------------


def child(arguments: list[str], timeout: float) -> dict[str, object]:
    result = subprocess.run([sys.executable, str(HERE), *arguments], capture_output=True,
                            text=True, timeout=timeout, check=False)
    if result.returncode != 0:
        return {"error": result.stderr.strip()[-2000:]}
    return json.loads(result.stdout)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=2000, help="mutants per format")
    parser.add_argument("--formats", default=",".join(FORMATS))
    parser.add_argument("--worker")
    parser.add_argument("--attack")
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(fuzz_worker(args.worker, args.cases)))
        return 0
    if args.attack:
        print(json.dumps(attack_worker(args.attack)))
        return 0

    from fuzz_corpus import realdata

    print(f"volucal reader fuzz: {args.cases} mutants per format, real data "
          f"{'included' if realdata() else 'absent'}; each format in a fresh process")
    print(f"{'format':10} {'seeds':>5} {'files':>6} {'clean error':>12} {'accepted':>9} "
          f"{'other':>6} {'largest':>9} {'time s':>7} {'base MB':>8} {'peak MB':>8}")
    worst = 0.0
    failures = 0
    for kind in args.formats.split(","):
        report = child(["--worker", kind, "--cases", str(args.cases)], timeout=3600)
        if "error" in report:
            print(f"{kind:10} worker failed: {report['error']}")
            failures += 1
            continue
        counts = report["counts"]
        worst = max(worst, float(report["peak_mb"]))
        failures += counts["other"]
        print(f"{kind:10} {report['seeds']:>5} {report['cases']:>6} {counts['clean error']:>12} "
              f"{counts['accepted']:>9} {counts['other']:>6} {report['largest_bytes']:>9,} "
              f"{report['seconds']:>7.1f} {report['baseline_mb']:>8.0f} "
              f"{report['peak_mb']:>8.0f}")
        for text in report["others"]:
            print(f"    other: {text}")
    print(f"peak resident memory of any fuzz process: {worst:.0f} MB (target < 500 MB)")

    print("\nattacks (each in a fresh process):")
    for name in ATTACKS:
        report = child(["--attack", name], timeout=600)
        if "error" in report:
            print(f"  {name}: worker failed: {report['error']}")
            failures += 1
            continue
        size = f"{report['bytes']:,} B" if report["bytes"] is not None else "-"
        refused = report["status"] != 0 and report["message"].count("\n") == 0 and report[
            "message"].startswith("volucal: error: ")
        failures += 0 if refused and not report["secret_echoed"] else 1
        worst = max(worst, float(report["peak_mb"]))
        print(f"  {name} ({size}): {'refused' if refused else 'NOT REFUSED'} in "
              f"{report['seconds'] * 1e3:.0f} ms, peak {report['peak_mb']:.0f} MB (baseline "
              f"{report['baseline_mb']:.0f} MB)")
        print(f"      {report['message'][:400]}")
    print("\nvalid files under 1 MB (each in a fresh process):")
    for name in VALID:
        report = child(["--attack", name], timeout=600)
        if "error" in report or report["status"] != 0:
            print(f"  {name}: FAILED {report.get('error') or report['message']}")
            failures += 1
            continue
        worst = max(worst, float(report["peak_mb"]))
        print(f"  {name} ({report['bytes']:,} B): read in {report['seconds'] * 1e3:.0f} ms, peak "
              f"{report['peak_mb']:.0f} MB (baseline {report['baseline_mb']:.0f} MB)")
    print(f"\npeak resident memory of any import of a file under 1 MB: {worst:.0f} MB "
          "(target < 500 MB)")
    print(f"{'all outcomes as required' if failures == 0 else f'{failures} failure(s)'}")
    return 0 if failures == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
