"""Errors a user can act on: they reach the user as one message, never as a traceback."""

from __future__ import annotations


class UserError(Exception):
    """Base class for errors caused by input (files, plan values, options)."""


class FormatError(UserError):
    """A file that cannot be read. The message names the file and, where known, the line."""

    def __init__(self, path: object, message: str, line: int | None = None) -> None:
        self.path = str(path)
        self.line = line
        self.reason = message
        where = f"{self.path}, line {line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")
