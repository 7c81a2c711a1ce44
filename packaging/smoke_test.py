"""Smoke test of the frozen build: run the bundled ``volucal`` as a user would.

    python packaging/smoke_test.py [BUNDLE]      (default: packaging/dist/volucal)

Checks, each timed: ``--version`` (the package metadata's version, also in VERSION), ``--help``,
``demo`` (the whole job on the embedded data: project, report.json and compensation files),
``report`` (a PDF from the demo project), ``gui --smoke --empty`` (the workbench opens and
quits, offscreen), and that the bundle carries its resources and THIRD_PARTY_LICENSES.txt.
Exit code 1 and the failing step's output on the first failure.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

DEFAULT_BUNDLE = Path(__file__).resolve().parent / "dist" / "volucal"
#: Generous limits: the demo takes one to three minutes on two cores.
TIMEOUT_S = {"demo": 900.0}


class SmokeFailure(Exception):
    """A step of the smoke test failed; the message has its command and output."""


def run(bundle: Path, *args: str, step: str, env: dict[str, str] | None = None) -> str:
    command = [str(bundle / "volucal"), *args]
    done = subprocess.run(command, capture_output=True, text=True, env=env,
                          timeout=TIMEOUT_S.get(step, 300.0), check=False)
    if done.returncode != 0:
        raise SmokeFailure(f"{step}: {' '.join(command)} exited with {done.returncode}\n"
                           f"{done.stdout}\n{done.stderr}")
    return done.stdout


def check(condition: bool, message: str) -> None:
    if not condition:
        raise SmokeFailure(message)


def smoke(bundle: Path, work: Path) -> list[tuple[str, float]]:
    """Run every step in ``work``; returns (step, seconds) or raises :class:`SmokeFailure`."""
    bundle = bundle.resolve()
    check((bundle / "volucal").is_file(), f"{bundle}: no volucal executable (build it first)")
    offscreen = dict(os.environ, QT_QPA_PLATFORM="offscreen")

    def version() -> None:
        expected = (bundle / "VERSION").read_text(encoding="utf-8").strip()
        out = run(bundle, "--version", step="version")
        check(out.strip() == f"volucal {expected}", f"--version printed {out!r}, VERSION "
                                                    f"says {expected!r}")
        check("unknown" not in expected, "the bundle has no package metadata for volucal")

    def help_text() -> None:
        out = run(bundle, "--help", step="help")
        for command in ("calibrate", "demo", "export", "report", "gui"):
            check(command in out, f"--help does not list {command}")

    def demo() -> None:
        run(bundle, "demo", "--out", str(work / "demo"), "--quiet", step="demo")
        for name in ("demo.h5", "report.json", "compensation/linuxcnc/comp.ini"):
            check((work / "demo" / name).is_file(), f"the frozen demo did not write {name}")

    def report() -> None:
        pdf = work / "report.pdf"
        run(bundle, "report", str(work / "demo" / "demo.h5"), "-o", str(pdf), step="report",
            env=offscreen)
        check(pdf.read_bytes()[:5] == b"%PDF-", "the frozen report is not a PDF")

    def gui() -> None:
        run(bundle, "gui", "--smoke", "--empty", step="gui", env=offscreen)

    def contents() -> None:
        internal = bundle / "_internal" / "volucal" / "resources"
        for name in ("demo/plan.toml", "plans/full.toml", "icons/volucal.svg",
                     "volucal.desktop"):
            check((internal / name).is_file(), f"the bundle lacks resources/{name}")
        licences = (bundle / "THIRD_PARTY_LICENSES.txt").read_text(encoding="utf-8")
        for name in ("numpy", "scipy", "h5py", "numba", "PySide6", "Python"):
            check(name in licences, f"THIRD_PARTY_LICENSES.txt does not name {name}")

    steps: list[tuple[str, Callable[[], None]]] = [
        ("version", version), ("help", help_text), ("contents", contents), ("demo", demo),
        ("report", report), ("gui", gui),
    ]
    timings = []
    for name, step in steps:
        start = time.perf_counter()
        step()
        timings.append((name, time.perf_counter() - start))
    return timings


def main() -> int:
    bundle = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_BUNDLE
    with tempfile.TemporaryDirectory(prefix="volucal-smoke-") as work:
        try:
            timings = smoke(bundle, Path(work))
        except SmokeFailure as exc:
            print(f"smoke test FAILED: {exc}", file=sys.stderr)
            return 1
    for name, seconds in timings:
        print(f"  {name:<10} {seconds:7.1f} s")
    print(f"smoke test passed: {bundle}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
