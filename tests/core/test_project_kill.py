"""A save killed at a random moment (SIGKILL) always leaves a project that opens with its last
completed state: the atomic save never exposes a half-written file."""

import random
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from volucal.core.project import Project

SAVER = """
import sys
import numpy as np
from volucal.core.machine import PAPER_MACHINE
from volucal.core.project import Project

path = sys.argv[1]
project = Project.create(PAPER_MACHINE)
print("ready", flush=True)
i = 0
while True:
    i += 1
    # big enough that a save takes a few milliseconds: kills land inside saves
    project.put_result("loops", "counter", {"i": i, "values": np.full(200_000, float(i))})
    project.save(path)
    print(i, flush=True)
"""

REPETITIONS = 30


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs SIGKILL (POSIX)")
def test_killed_saves_leave_the_last_complete_state(tmp_path):
    rng = random.Random(20240501)
    path = tmp_path / "p.h5"
    script = tmp_path / "saver.py"
    script.write_text(SAVER)
    checked = 0
    for _ in range(REPETITIONS):
        child = subprocess.Popen([sys.executable, str(script), str(path)],
                                 stdout=subprocess.PIPE, text=True)
        assert child.stdout is not None
        assert child.stdout.readline().strip() == "ready"
        time.sleep(rng.uniform(0.0, 0.25))
        child.send_signal(signal.SIGKILL)
        child.wait()
        completed = [int(line) for line in child.stdout.read().split()]
        child.stdout.close()
        if not path.exists():
            assert not completed  # killed before its first save finished
            continue
        project = Project.open(path)
        tree = project.result("loops", "counter")
        values = tree["values"]
        # one consistent state: every value is the counter of the same save
        assert np.all(values == float(tree["i"]))
        if completed:
            # the last save it reported, or the one it finished but could not report
            assert tree["i"] in (completed[-1], completed[-1] + 1)
        checked += 1
    assert checked >= REPETITIONS // 2
