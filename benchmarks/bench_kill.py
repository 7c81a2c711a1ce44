"""Kill a project writer with SIGKILL N times; count what survives and what is left behind.

Issue 16: "kills: N survived of N, stale locks left 0". Each round starts a writer that holds the
project's lock (as ``volucal identify`` does from reading to saving) and saves a 1.6 MB result
over and over, kills it at a random moment (most kills land inside a save), then opens the
project as the next volucal would. Counted per round:

- survived: the project opens, and its values are those of one complete save (all values equal
  the save's counter, which is the last save the writer reported or the one after it);
- stale locks left / temporary files left: a ``.lock`` or ``.tmp-<pid>`` file still beside the
  project after that open;
- second writer refused: while the writer lives, a save by this process is refused with the
  writer's pid (checked on the first 10 rounds; each check waits for the lock's 1 s timeout).

Run: ``python benchmarks/bench_kill.py [ROUNDS]`` (100 by default).
"""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from volucal.core.machine import PAPER_MACHINE
from volucal.core.project import Project
from volucal.core.userror import UserError

WRITER = """
import sys
import numpy as np
from volucal.core.machine import PAPER_MACHINE
from volucal.core.project import Project, ProjectLock

path = sys.argv[1]
with ProjectLock(path):
    project = Project.open(path) if len(sys.argv) > 2 else Project.create(PAPER_MACHINE)
    print("ready", flush=True)
    i = 0
    while True:
        i += 1
        project.put_result("loops", "counter", {"i": i, "values": np.full(200_000, float(i))})
        project.save(path)
        print(i, flush=True)
"""


def leftovers(folder: Path) -> tuple[int, int]:
    names = [p.name for p in folder.iterdir()]
    return sum(n.endswith(".lock") for n in names), sum(".tmp-" in n for n in names)


def main(rounds: int = 100) -> None:
    rng = random.Random(16)
    counts = {"survived": 0, "empty": 0, "locks": 0, "temporaries": 0, "refused": 0, "checks": 0}
    with tempfile.TemporaryDirectory() as folder_name:
        folder = Path(folder_name)
        path = folder / "p.h5"
        script = folder / "writer.py"
        script.write_text(WRITER)
        start = time.perf_counter()
        for round_ in range(rounds):
            args = [sys.executable, str(script), str(path)] + (["open"] if path.exists() else [])
            child = subprocess.Popen(args, stdout=subprocess.PIPE, text=True)
            assert child.stdout is not None
            assert child.stdout.readline().strip() == "ready"
            if round_ < 10:
                counts["checks"] += 1
                try:
                    Project.create(PAPER_MACHINE).save(folder / "p.h5")
                except UserError as exc:
                    counts["refused"] += f"locked by process {child.pid}" in str(exc)
            time.sleep(rng.uniform(0.0, 0.3))
            child.send_signal(signal.SIGKILL)
            child.wait()
            completed = [int(v) for v in child.stdout.read().split()]
            child.stdout.close()
            if not path.exists():
                counts["empty"] += 1  # killed before its first save: nothing to survive
                Project.create(PAPER_MACHINE).save(path)
            try:
                project = Project.open(path)
                tree = project.result("loops", "counter") if project.results("loops") else None
                consistent = tree is None or bool(np.all(tree["values"] == float(tree["i"])))
                if tree is not None and completed:
                    consistent &= tree["i"] >= completed[-1]
                counts["survived"] += consistent
            except UserError as exc:
                print(f"round {round_}: {exc}")
            locks, temporaries = leftovers(folder)
            counts["locks"] += locks
            counts["temporaries"] += temporaries
        elapsed = time.perf_counter() - start
    print(f"kills: {counts['survived']} survived of {rounds} "
          f"({counts['empty']} killed before any save)")
    print(f"stale locks left after the next open: {counts['locks']}")
    print(f"temporary files left after the next open: {counts['temporaries']}")
    print(f"second writer refused while the first lived: {counts['refused']} of "
          f"{counts['checks']}")
    print(f"{elapsed:.1f} s in all")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 100)
