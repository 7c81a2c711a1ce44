"""The log panel: what the workbench did, in order (opened, imported, identified, errors...).

A :class:`logging.Handler` on the ``volucal`` logger forwards records through a Qt signal, so a
record logged on a worker thread is appended on the GUI thread.
"""

from __future__ import annotations

import logging
import time

import shiboken6
from PySide6.QtCore import QObject, Signal
from PySide6.QtGui import QFont
from PySide6.QtWidgets import QPlainTextEdit, QWidget

LOGGER = "volucal"
MAX_BLOCKS = 5000


class _Relay(QObject):
    record = Signal(str, int)


class _QtHandler(logging.Handler):
    def __init__(self, relay: _Relay) -> None:
        super().__init__(logging.INFO)
        self.relay = relay

    def emit(self, record: logging.LogRecord) -> None:
        if not shiboken6.isValid(self.relay):
            return
        stamp = time.strftime("%H:%M:%S", time.localtime(record.created))
        self.relay.record.emit(f"{stamp}  {record.levelname.lower():<7}  {record.getMessage()}",
                               record.levelno)


class LogPanel(QPlainTextEdit):
    """Read-only, newest at the bottom, warnings in orange and errors in red."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("logPanel")
        self.setReadOnly(True)
        self.setMaximumBlockCount(MAX_BLOCKS)
        font = QFont("monospace")
        font.setStyleHint(QFont.StyleHint.TypeWriter)
        self.setFont(font)
        self._relay = _Relay(self)
        self._relay.record.connect(self._append)
        self._handler = _QtHandler(self._relay)
        logger = logging.getLogger(LOGGER)
        logger.addHandler(self._handler)
        if logger.level == logging.NOTSET or logger.level > logging.INFO:
            logger.setLevel(logging.INFO)
        handler = self._handler
        self.destroyed.connect(lambda: logging.getLogger(LOGGER).removeHandler(handler))

    def detach(self) -> None:
        """Stop listening (the window closes)."""
        logging.getLogger(LOGGER).removeHandler(self._handler)

    def _append(self, text: str, level: int) -> None:
        colour = "#c00000" if level >= logging.ERROR else "#b86e00" if level >= logging.WARNING \
            else None
        escaped = text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
        if colour:
            self.appendHtml(f"<span style='color:{colour}'>{escaped}</span>")
        else:
            self.appendHtml(f"<span>{escaped}</span>")
