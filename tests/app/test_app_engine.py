"""Long computations in worker processes: results, progress, cancel, errors, crashes — and the
window's event loop stays free while a computation holds Python's interpreter lock."""

import os
import time

import numpy as np
import pytest
from PySide6.QtCore import QTimer
from PySide6.QtWidgets import QLabel
from volucal.app import engine, tasks
from volucal.core.progress import Cancelled
from volucal.core.userror import UserError


def where_am_i(progress=None, cancel=None):
    progress(0.5, "half way")
    return os.getpid()


def fails(progress=None, cancel=None):
    raise UserError("plan.toml, line 3: start: expected three numbers")


def until_cancelled(progress=None, cancel=None):
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        cancel.check()
        time.sleep(0.01)
    return "not cancelled"


def dies(progress=None, cancel=None):
    os._exit(3)


def holds_the_lock(seconds, progress=None, cancel=None):
    """scipy's LAPACK wrappers keep the interpreter lock for the whole call."""
    import scipy.linalg

    a = np.random.default_rng(0).standard_normal((600, 600))
    a = a @ a.T
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        scipy.linalg.eigvalsh(a, check_finite=False)
    return "done"


def test_a_process_call_runs_in_another_process_and_reports_back():
    messages = []
    pid = engine.run(engine.ProcessCall(where_am_i), lambda f, m: messages.append((f, m)),
                     tasks.CancelToken())
    assert pid != os.getpid()
    assert messages == [(0.5, "half way")]
    # called directly it runs here (tests, the command line)
    assert engine.ProcessCall(where_am_i)(lambda f, m: None) == os.getpid()


def test_errors_cancel_and_crashes_come_back_as_such():
    with pytest.raises(UserError, match="line 3"):
        engine.run(engine.ProcessCall(fails), None, tasks.CancelToken())
    token = tasks.CancelToken()
    token.cancel()
    with pytest.raises(Cancelled):
        engine.run(engine.ProcessCall(until_cancelled), None, token)
    with pytest.raises(engine.WorkerCrashed, match="exit code 3"):
        engine.run(engine.ProcessCall(dies), None, tasks.CancelToken())
    # the next call gets a working process
    assert engine.run(engine.ProcessCall(where_am_i), lambda f, m: None,
                      tasks.CancelToken()) != os.getpid()


def test_the_event_loop_keeps_running_while_a_worker_holds_the_lock(qtbot):
    owner = QLabel()
    runner = tasks.TaskRunner(owner)
    ticks = []
    timer = QTimer()
    timer.setInterval(10)
    timer.timeout.connect(lambda: ticks.append(time.perf_counter()))
    engine.run(engine.ProcessCall(where_am_i), lambda f, m: None, tasks.CancelToken())  # warm
    results = []
    timer.start()
    task = runner.run("holds the lock", engine.ProcessCall(holds_the_lock, (3.0,)),
                      results.append)
    with qtbot.waitSignal(task.ended, timeout=60_000):
        pass
    timer.stop()
    assert results == ["done"]
    gaps = np.diff(ticks)
    # (idle, a loaded test machine shows a few tens of ms; a thread would freeze for seconds)
    assert gaps.max() < 0.5, f"longest gap {1000 * gaps.max():.0f} ms"
