"""A one-line progress display on stderr for long commands (not a command itself)."""

from __future__ import annotations

import sys


class ProgressBar:
    """Callable as a core progress callback: ``bar(fraction, message)``."""

    def __init__(self, width: int = 30) -> None:
        self.width = width
        self.tty = sys.stderr.isatty()

    def __call__(self, fraction: float, message: str) -> None:
        filled = int(round(self.width * fraction))
        text = f"[{'#' * filled}{'.' * (self.width - filled)}] {100 * fraction:5.1f} % {message}"
        # Only on a terminal: in a pipe or a log, progress lines would bury the results.
        if self.tty:
            sys.stderr.write("\r" + text[:100].ljust(100))
            sys.stderr.flush()

    def close(self) -> None:
        if self.tty:
            sys.stderr.write("\n")
            sys.stderr.flush()


def register(sub: object) -> None:
    """Not a command: the CLI loads every module of this package, this one registers nothing."""
