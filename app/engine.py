"""Long computations in worker processes, so that the window never waits for them (GUI-free).

A thread is not enough: parts of the core (and of numpy and scipy) hold Python's global
interpreter lock for hundreds of milliseconds at a time — the per-line rank tests of an
identification, LAPACK calls that scipy does not release — and the GUI thread, which needs the
lock to run at all, freezes meanwhile. A :class:`ProcessCall` runs in a process of its own with
its own interpreter: the GUI thread's only work is to receive the progress messages and the
result.

Worker processes are started with the "spawn" method (a fresh interpreter; forking a process
that runs Qt threads is unsafe) and kept for the next call, one started ahead of time
(:func:`prestart`) so that the first computation does not wait for the imports. Each worker runs
one call at a time: a second call at the same time gets a second worker. Cancelling sets a
shared event the computation's :class:`CancelToken` reads at its next check. A worker that dies
(a crash in native code) is reported as an internal error and replaced.
"""

from __future__ import annotations

import atexit
import multiprocessing
import threading
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from volucal.core.progress import Cancelled, CancelToken, ProgressCallback, throttled
from volucal.core.userror import UserError

#: Minimum time between two progress messages of a worker (s).
PROGRESS_INTERVAL_S = 0.05
#: How often the waiting side looks at the user's Cancel (s).
POLL_S = 0.05

_CONTEXT = multiprocessing.get_context("spawn")


@dataclass(frozen=True)
class ProcessCall:
    """``function(*args, progress=..., cancel=...)`` to run in a worker process. ``function``
    and ``args`` must be picklable (a module-level function or a method of a picklable object);
    so must the result. Called directly, it runs here (tests, the command line)."""

    function: Callable[..., Any]
    args: tuple[Any, ...] = field(default_factory=tuple)

    def __call__(self, progress: ProgressCallback | None = None,
                 cancel: CancelToken | None = None) -> Any:
        return self.function(*self.args, progress=progress, cancel=cancel)


class WorkerCrashed(RuntimeError):
    """The worker process ended without an answer (native crash, killed)."""


class _EventToken(CancelToken):
    """A CancelToken over an event shared with the process that started the call."""

    def __init__(self, event: Any) -> None:
        self._event = event


def _serve(connection: Any, cancel_event: Any) -> None:
    """A worker process: run the calls it receives until it receives None."""
    token = _EventToken(cancel_event)
    while True:
        try:
            job = connection.recv()
        except EOFError:
            return
        if job is None:
            return
        progress = throttled(
            lambda fraction, message: connection.send(("progress", fraction, message)),
            PROGRESS_INTERVAL_S,
        )

        try:
            result = job(progress, token)
        except Cancelled:
            answer: tuple[Any, ...] = ("cancelled",)
        except UserError as exc:
            answer = ("user", str(exc))
        except BaseException:  # noqa: BLE001 -- reported to the user as an internal error
            answer = ("bug", traceback.format_exc())
        else:
            answer = ("result", result)
        try:
            connection.send(answer)
        except Exception:  # noqa: BLE001 -- a result that cannot be pickled is a bug
            connection.send(("bug", traceback.format_exc()))


class _Worker:
    def __init__(self) -> None:
        self.connection, child = _CONTEXT.Pipe()
        self.cancel = _CONTEXT.Event()
        self.process = _CONTEXT.Process(target=_serve, args=(child, self.cancel), daemon=True,
                                        name="volucal-worker")
        self.process.start()
        child.close()

    @property
    def alive(self) -> bool:
        return self.process.is_alive()

    def stop(self) -> None:
        try:
            self.connection.send(None)
        except (OSError, ValueError):
            pass
        self.cancel.set()
        self.process.join(2.0)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(2.0)
        self.connection.close()


_LOCK = threading.Lock()
_IDLE: list[_Worker] = []
_ALL: list[_Worker] = []


def _take() -> _Worker:
    with _LOCK:
        while _IDLE:
            worker = _IDLE.pop()
            if worker.alive:
                return worker
    worker = _Worker()
    with _LOCK:
        _ALL.append(worker)
    return worker


def _give_back(worker: _Worker) -> None:
    with _LOCK:
        if worker.alive:
            _IDLE.append(worker)


def prestart() -> None:
    """Start a worker now (in the background), so that the first call does not wait for it."""
    with _LOCK:
        if _IDLE:
            return
    threading.Thread(target=lambda: _give_back(_take()), daemon=True,
                     name="volucal-worker-start").start()


@atexit.register
def shutdown() -> None:
    """Stop every worker (at exit)."""
    with _LOCK:
        workers = list(_ALL)
        _ALL.clear()
        _IDLE.clear()
    for worker in workers:
        worker.stop()


def run(call: ProcessCall, progress: ProgressCallback | None, cancel: CancelToken) -> Any:
    """Run ``call`` in a worker process and wait for its answer (call it from a worker thread:
    it blocks). Progress messages are passed to ``progress``; ``cancel`` is watched and handed
    on. Raises what the call raised: Cancelled, UserError, or :class:`WorkerCrashed`/RuntimeError
    (with the worker's traceback) for a bug."""
    worker = _take()
    worker.cancel.clear()
    worker.connection.send(call)
    handed_on = False
    answered = False
    try:
        while True:
            if cancel.cancelled and not handed_on:
                worker.cancel.set()
                handed_on = True
            if not worker.connection.poll(POLL_S):
                if not worker.alive:
                    raise WorkerCrashed(
                        f"the computation's process ended unexpectedly (exit code "
                        f"{worker.process.exitcode})")
                continue
            try:
                message = worker.connection.recv()
            except EOFError:
                worker.process.join(5.0)
                raise WorkerCrashed(
                    f"the computation's process ended unexpectedly (exit code "
                    f"{worker.process.exitcode})") from None
            kind = message[0]
            if kind == "progress":
                if progress is not None:
                    progress(message[1], message[2])
                continue
            answered = True
            if kind == "result":
                return message[1]
            if kind == "cancelled":
                raise Cancelled("cancelled by the user")
            if kind == "user":
                raise UserError(message[1])
            raise RuntimeError(f"in the computation's process:\n{message[1]}")
    finally:
        if answered:
            _give_back(worker)
        else:  # still busy with this call (or dead): never hand it another one
            with _LOCK:
                if worker in _ALL:
                    _ALL.remove(worker)
            worker.stop()
