"""A source file as the readers see it: its bytes kept unchanged, its text in numbered lines.

Every reader in :mod:`volucal.core.io` reports bad input as
:class:`~volucal.core.userror.FormatError` naming the file and the 1-based line, and never lets
another exception escape: the helpers here turn numbers, integers and dates that cannot be read into
such errors.

Two rules live here so that every reader keeps them:

- **Files are opened safely** (:func:`read_file_bytes`): only a regular file is read (a FIFO, a
  device or a folder is refused before anything blocks or streams), never more than a size limit
  (:mod:`.limits`), and a symbolic-link loop is a clear error.
- **Numbers are strict** (:data:`NUMBER`): ASCII digits, an optional sign, decimal point and
  exponent. Python's ``float`` also accepts ``1_000``, Arabic-Indic or full-width digits, ``nan``,
  ``inf`` and surrounding non-breaking spaces; no laser software writes those, so a file that holds
  them is damaged or not a measurement and is refused.
"""

from __future__ import annotations

import errno
import math
import os
import re
import stat
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from ..userror import FormatError
from .limits import MAX_TEXT_BYTES, size_text

_LINE_BREAK = re.compile(r"\r\n|\r|\n")
#: The number grammar of every reader: ASCII only, no underscores, no nan/inf.
NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
INTEGER = re.compile(r"[+-]?[0-9]+")
#: What :meth:`str.strip` may remove around a token: ASCII blanks only (a non-breaking space is
#: not a separator in any measurement file).
BLANKS = " \t\r\n\f\v"
_QUOTE_MAX = 40


def read_file_bytes(path: str | Path, limit: int = MAX_TEXT_BYTES) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes, or a FormatError.

    The file is opened without blocking and checked with ``fstat`` on the open descriptor (no race
    between the check and the read): a FIFO, a device, a socket or a folder is refused, and so is
    a file larger than ``limit`` (from its size, before reading; files such as those of /proc that
    report size 0 are read at most ``limit + 1`` bytes).
    """
    path = Path(path)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise FormatError(
            path, "file not found; check the path (relative paths start at the plan file's folder)"
        ) from None
    except OSError as exc:
        raise FormatError(path, f"cannot be read: {_os_reason(exc)}") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise FormatError(path, f"is {_kind(info.st_mode)}, not a measurement file")
        if info.st_size > limit:
            raise FormatError(
                path,
                f"is {size_text(info.st_size)} bytes; volucal reads files of "
                f"up to {size_text(limit)} bytes of this kind (docs/formats.md, "
                "Limits)",
            )
        chunks: list[bytes] = []
        held = 0
        while held <= limit:
            chunk = os.read(fd, min(1 << 20, limit + 1 - held))
            if not chunk:
                break
            chunks.append(chunk)
            held += len(chunk)
        if held > limit:
            raise FormatError(
                path,
                f"holds more than {size_text(limit)} bytes; volucal reads "
                "files of up to that size (docs/formats.md, Limits)",
            )
        return b"".join(chunks)
    except OSError as exc:
        raise FormatError(path, f"cannot be read: {_os_reason(exc)}") from None
    finally:
        os.close(fd)


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _os_reason(exc: OSError) -> str:
    if exc.errno == errno.ELOOP:
        return "a loop of symbolic links"
    if exc.errno in (errno.EACCES, errno.EPERM):
        return "permission denied"
    return exc.strerror or type(exc).__name__


@dataclass(frozen=True, eq=False)
class SourceText:
    """The bytes of a text file and its lines (without line endings), numbered from 1."""

    path: Path
    raw: bytes
    lines: tuple[str, ...]

    @classmethod
    def read(cls, path: str | Path, limit: int = MAX_TEXT_BYTES) -> SourceText:
        path = Path(path)
        return cls.from_bytes(path, read_file_bytes(path, limit))

    @classmethod
    def from_bytes(cls, path: str | Path, raw: bytes) -> SourceText:
        text = decode_text(raw)
        nul = text.find("\x00")
        if nul >= 0:
            # a text log never holds NUL: this is a binary file (nothing of it is quoted)
            line = len(_LINE_BREAK.findall(text, 0, nul)) + 1
            raise FormatError(
                path, "holds binary data (a NUL byte), not the text of a measurement file", line
            )
        return cls(Path(path), raw, tuple(_LINE_BREAK.split(text)))

    def numbered(self) -> Iterator[tuple[int, str]]:
        """(line number, text) for every line."""
        return enumerate(self.lines, start=1)

    def error(self, message: str, line: int | None) -> FormatError:
        return FormatError(self.path, message, line)

    @property
    def last_line(self) -> int:
        """Number of the last line that holds text (where a cut-short file ended)."""
        for number in range(len(self.lines), 0, -1):
            if self.lines[number - 1].strip():
                return number
        return 1


def decode_text(raw: bytes) -> str:
    """UTF-8 (with or without a byte-order mark), UTF-16 with its byte-order mark, else Latin-1.

    Laser software on Windows writes user text in the local code page; Latin-1 maps every byte, so
    a file is never refused for its encoding alone (its numbers are checked field by field).
    """
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            return raw.decode("utf-16")
        except UnicodeDecodeError:
            pass
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def quote(text: str) -> str:
    """A token of a file as an error message shows it: quoted, and cut after 40 characters so
    that a message never dumps a long line of a file."""
    text = text.strip(BLANKS)
    if len(text) > _QUOTE_MAX:
        return repr(text[:_QUOTE_MAX]) + "…"
    return repr(text)


def is_number(token: str) -> bool:
    """True for a token of the strict number grammar (:data:`NUMBER`)."""
    return NUMBER.fullmatch(token.strip(BLANKS)) is not None


def parse_float(token: str, source: SourceText, line: int, what: str) -> float:
    """A finite number of the strict grammar, or a FormatError saying which field of which line
    is wrong."""
    text = token.strip(BLANKS) if isinstance(token, str) else ""
    if NUMBER.fullmatch(text) is None:
        raise source.error(f"{what}: expected a number, found {quote(str(token))}", line)
    value = float(text)
    if not math.isfinite(value):
        raise source.error(f"{what}: {quote(text)} is beyond the range of a number", line)
    return value


def check_range(
    value: float, low: float, high: float, source: SourceText, line: int, what: str, hint: str = ""
) -> float:
    """``value`` when ``low ≤ value ≤ high``, else a FormatError naming the line (and ``hint``)."""
    if not low <= value <= high:
        shown = f"{value:g}" if math.isfinite(value) else "beyond the range of a number"
        raise source.error(
            f"{what} {shown} is outside {low:g}…{high:g}" + (f"; {hint}" if hint else ""), line
        )
    return value


def check_magnitude(value: float, limit: float, source: SourceText, line: int, what: str) -> float:
    """``value`` when ``|value| ≤ limit`` (and finite), else a FormatError: a value no laser
    measurement produces (docs/formats.md, Limits)."""
    if not abs(value) <= limit:
        shown = f"{value:g} is" if math.isfinite(value) else "overflows once converted, far"
        raise source.error(
            f"{what} {shown} beyond ±{limit:g}, which no measurement produces "
            "(docs/formats.md, Limits); the file is damaged or its unit is wrong",
            line,
        )
    return value


def parse_int(token: str, source: SourceText, line: int, what: str) -> int:
    """An integer written with ASCII digits (``3``, ``-2``), or a FormatError."""
    text = token.strip(BLANKS) if isinstance(token, str) else ""
    if INTEGER.fullmatch(text) is None or len(text) > 18:
        raise source.error(f"{what}: expected a whole number, found {quote(str(token))}", line)
    return int(text)


_DATE_FORMATS = (
    "%H:%M %b %d %Y",  # Renishaw: "10:46 Dec 12 2016"
    "%H:%M:%S %b %d %Y",
    "%Y-%m-%d %H:%M:%S",
    "%Y-%m-%d %H:%M",
)


def parse_time(token: str, source: SourceText, line: int, what: str) -> float:
    """POSIX seconds of a date and time.

    Accepts the Renishaw form ``"10:46 Dec 12 2016"`` (with or without seconds) and ISO 8601. A
    time without a zone is taken as UTC: laser logs record the local clock without a zone, and only
    differences between times matter to volucal (run spacing, line order, drift).
    """
    text = token.strip(BLANKS).strip('"').strip(BLANKS)
    if not text.isascii():
        # strptime would take Arabic-Indic or full-width digits: a damaged date
        raise source.error(
            f"{what}: expected a date in ASCII characters, found {quote(token)}", line
        )
    for pattern in _DATE_FORMATS:
        try:
            moment = datetime.strptime(text, pattern)
        except ValueError:
            continue
        return moment.replace(tzinfo=UTC).timestamp()
    try:
        moment = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise source.error(
            f'{what}: expected a date and time such as "10:46 Dec 12 2016" or '
            f'"2016-12-12T10:46:00", found {quote(token)}',
            line,
        ) from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    try:
        return moment.timestamp()
    except (OverflowError, OSError, ValueError):
        raise source.error(f"{what}: date {quote(token)} is out of range", line) from None


def format_time_rtl(posix_s: float) -> str:
    """``"10:46:30 Dec 12 2016"`` (UTC, to the second) for a POSIX time."""
    moment = datetime.fromtimestamp(math.floor(posix_s + 0.5), tz=UTC)
    return moment.strftime("%H:%M:%S %b %d %Y")


def format_time_iso(posix_s: float) -> str:
    """ISO 8601 UTC with microseconds, e.g. ``2026-01-01T00:00:00.000000+00:00``."""
    return datetime.fromtimestamp(posix_s, tz=UTC).isoformat(timespec="microseconds")


def format_number(value: float, decimals: int = 6) -> str:
    """``value`` with ``decimals`` decimals when that is exact, else its shortest exact form.

    Real logs print fixed decimals; values that do not fit them (a jittered target) are printed in
    full so that a file volucal writes reads back to the same float.
    """
    fixed = f"{value:.{decimals}f}"
    return fixed if float(fixed) == value else repr(float(value))
