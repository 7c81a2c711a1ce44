"""Progress reporting and cancellation for long computations.

Every long step takes an optional ``progress`` callback ``(fraction, message)`` and an optional
:class:`CancelToken`. They are plain objects: the GUI and the CLI's progress display observe them,
and a step can run on any thread.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

ProgressCallback = Callable[[float, str], None]


class Cancelled(Exception):
    """Raised inside a computation when its CancelToken was set."""


class CancelToken:
    """A thread-safe flag a caller sets to ask a computation to stop at its next check."""

    def __init__(self) -> None:
        self._event = threading.Event()

    def cancel(self) -> None:
        self._event.set()

    @property
    def cancelled(self) -> bool:
        return self._event.is_set()

    def check(self) -> None:
        """Raise :class:`Cancelled` if cancellation was requested."""
        if self._event.is_set():
            raise Cancelled("cancelled by the user")


def report(progress: ProgressCallback | None, fraction: float, message: str) -> None:
    if progress is not None:
        progress(min(max(fraction, 0.0), 1.0), message)


def check(cancel: CancelToken | None) -> None:
    if cancel is not None:
        cancel.check()


def throttled(send: ProgressCallback, interval_s: float) -> ProgressCallback:
    """``send`` at most once per ``interval_s`` (and always at completion): a computation may
    report thousands of times a second, more than a display or a pipe should carry."""
    last = 0.0

    def progress(fraction: float, message: str) -> None:
        nonlocal last
        now = time.monotonic()
        if now - last >= interval_s or fraction >= 1.0:
            last = now
            send(float(fraction), str(message))

    return progress
