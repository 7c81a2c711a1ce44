"""Core computations off the GUI thread, observed through the core's progress and cancel objects.

A core step is a plain function that takes an optional ``progress(fraction, message)`` callback
and a :class:`~volucal.core.progress.CancelToken` (DESIGN.md, "Data flow"). :class:`Task` runs one
such call on its own QThread: the callback, called on the worker thread, is turned into a Qt
signal (throttled, so that a tight loop cannot flood the event loop) and the result or the error
comes back as a signal delivered on the GUI thread. The worker never touches a widget. A
:class:`~volucal.app.engine.ProcessCall` runs in a worker process instead (core code that holds
Python's interpreter lock would otherwise freeze the window, :mod:`volucal.app.engine`); the
thread then only waits for its messages.

Results never arrive at a closed widget: every task has an *owner*; when the owner is destroyed
or its :class:`TaskRunner` is shut down (the owner closed), the task is dropped — its token is
cancelled and whatever the thread still returns is discarded. A task object lives in a module
registry until its thread has finished, so that no QThread is ever destroyed while running.
"""

from __future__ import annotations

import logging
import time
import traceback
from collections.abc import Callable
from typing import Any

import shiboken6
from PySide6.QtCore import QObject, QThread, Signal
from volucal.core.progress import Cancelled, CancelToken, ProgressCallback, throttled
from volucal.core.userror import UserError

from . import engine
from .engine import ProcessCall

#: Minimum time between two progress signals of one task (s): 20 updates a second are plenty
#: for a progress bar and leave the event loop free.
PROGRESS_INTERVAL_S = 0.05

CoreCall = Callable[[ProgressCallback, CancelToken], Any]

log = logging.getLogger("volucal.app")

_LIVE: set[Task] = set()


class _WorkerThread(QThread):
    """Runs the call; its signals are emitted on the worker thread and queued to the GUI."""

    progressed = Signal(float, str)
    returned = Signal(object)
    raised = Signal(str, str)  # kind ("user", "cancelled", "bug"), message or traceback

    def __init__(self, call: CoreCall, token: CancelToken) -> None:
        super().__init__()
        self._call = call
        self._token = token

    def run(self) -> None:
        progress = throttled(self.progressed.emit, PROGRESS_INTERVAL_S)

        try:
            if isinstance(self._call, ProcessCall):
                result = engine.run(self._call, progress, self._token)
            else:
                result = self._call(progress, self._token)
        except Cancelled:
            self.raised.emit("cancelled", "cancelled by the user")
        except UserError as exc:
            self.raised.emit("user", str(exc))
        except Exception:  # a bug: shown with its traceback instead of killing the GUI thread
            self.raised.emit("bug", traceback.format_exc())
        else:
            if self._token.cancelled:
                self.raised.emit("cancelled", "cancelled by the user")
            else:
                self.returned.emit(result)


class Task(QObject):
    """One core call on a worker thread.

    Signals (delivered on the GUI thread, and only while the owner is alive and not shut down):
    ``progressed(fraction, message)``, then exactly one of ``succeeded(result)``,
    ``failed(message)`` (a :class:`UserError`: a message for the user), ``crashed(traceback)``
    (a bug) or ``cancelled()``; then ``ended()``.
    """

    progressed = Signal(float, str)
    succeeded = Signal(object)
    failed = Signal(str)
    crashed = Signal(str)
    cancelled = Signal()
    ended = Signal()

    def __init__(self, title: str, call: CoreCall, owner: QObject) -> None:
        # No parent: the task must outlive an owner destroyed while the thread still runs.
        super().__init__()
        self.title = title
        self.token = CancelToken()
        self.fraction = 0.0
        self.message = ""
        #: How it ended, for the status bar: "finished", "cancelled", "failed" or
        #: "internal error" ("" while running).
        self.outcome = ""
        self._owner = owner
        self._dropped = False
        self._thread = _WorkerThread(call, self.token)
        self._thread.progressed.connect(self._on_progress)
        self._thread.returned.connect(self._on_returned)
        self._thread.raised.connect(self._on_raised)
        self._thread.finished.connect(self._on_finished)
        owner.destroyed.connect(self.drop)

    # ---- control ---------------------------------------------------------------------------

    def start(self) -> Task:
        _LIVE.add(self)
        log.info("%s: started", self.title)
        self._thread.start()
        return self

    def cancel(self) -> None:
        """Ask the computation to stop at its next check; ``cancelled`` follows."""
        self.token.cancel()

    def drop(self) -> None:
        """Cancel and deliver nothing more (the owner is gone or closed)."""
        self._dropped = True
        self.token.cancel()

    @property
    def running(self) -> bool:
        return shiboken6.isValid(self._thread) and self._thread.isRunning()

    def wait(self, timeout_ms: int = 30_000) -> bool:
        """Block until the thread has finished (tests and shutdown only)."""
        if not shiboken6.isValid(self._thread):
            return True
        return bool(self._thread.wait(timeout_ms))

    # ---- delivery on the GUI thread ----------------------------------------------------------

    def _deliverable(self) -> bool:
        return not self._dropped and shiboken6.isValid(self._owner)

    def _on_progress(self, fraction: float, message: str) -> None:
        self.fraction, self.message = fraction, message
        if self._deliverable() and not self.token.cancelled:
            self.progressed.emit(fraction, message)

    def _on_returned(self, result: object) -> None:
        if not self._deliverable():
            return
        self.outcome = "finished"
        log.info("%s: done", self.title)
        self.succeeded.emit(result)

    def _on_raised(self, kind: str, text: str) -> None:
        if not self._deliverable():
            return
        self.outcome = {"cancelled": "cancelled", "user": "failed"}.get(kind, "internal error")
        if kind == "cancelled":
            log.info("%s: cancelled", self.title)
            self.cancelled.emit()
        elif kind == "user":
            log.warning("%s: %s", self.title, text)
            self.failed.emit(text)
        else:
            log.error("%s: internal error\n%s", self.title, text)
            self.crashed.emit(text)

    def _on_finished(self) -> None:
        # ``finished`` is emitted just before the thread returns: wait for that instant so that
        # deleting the QThread below never meets a running thread.
        self._thread.wait()
        if self._deliverable():
            self.ended.emit()
        _LIVE.discard(self)
        self._thread.deleteLater()
        self.deleteLater()


class TaskRunner(QObject):
    """The tasks of one owner widget: starts them, cancels them, drops them when it closes.

    ``started(task)`` lets the main window show every task's progress in its status bar.
    """

    started = Signal(object)
    busyChanged = Signal(bool)

    def __init__(self, owner: QObject) -> None:
        super().__init__(owner)
        self._owner = owner
        self._tasks: list[Task] = []
        self._closed = False

    def run(
        self,
        title: str,
        call: CoreCall,
        on_success: Callable[[Any], object],
        on_failure: Callable[[str], object] | None = None,
        on_crash: Callable[[str], object] | None = None,
        on_cancel: Callable[[], object] | None = None,
    ) -> Task:
        """Start ``call(progress, cancel)``; the callbacks run on the GUI thread."""
        if self._closed:
            raise RuntimeError("this view is closed; it starts no more tasks")
        task = Task(title, call, self._owner)
        task.succeeded.connect(on_success)
        if on_failure is not None:
            task.failed.connect(on_failure)
        if on_crash is not None:
            task.crashed.connect(on_crash)
        if on_cancel is not None:
            task.cancelled.connect(on_cancel)
        task.ended.connect(lambda: self._forget(task))
        self._tasks.append(task)
        self.started.emit(task)
        self.busyChanged.emit(True)
        return task.start()

    def _forget(self, task: Task) -> None:
        if task in self._tasks:
            self._tasks.remove(task)
        if not self._tasks:
            self.busyChanged.emit(False)

    @property
    def busy(self) -> bool:
        return bool(self._tasks)

    @property
    def tasks(self) -> tuple[Task, ...]:
        return tuple(self._tasks)

    def cancel_all(self) -> None:
        for task in self._tasks:
            task.cancel()

    def shutdown(self) -> None:
        """The owner closes: drop every task (nothing will be delivered any more)."""
        self._closed = True
        for task in self._tasks:
            task.drop()
        self._tasks.clear()
        self.busyChanged.emit(False)


def live_tasks() -> tuple[Task, ...]:
    """Tasks whose thread has not finished yet."""
    return tuple(_LIVE)


def wait_for_all(timeout_ms: int = 30_000) -> bool:
    """Block until every task's thread has finished; True when they all did in time."""
    deadline = time.monotonic() + timeout_ms / 1000.0
    for task in list(_LIVE):
        remaining = max(0, int(1000 * (deadline - time.monotonic())))
        if not task.wait(remaining):
            return False
    return True
