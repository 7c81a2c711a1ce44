"""A source file as the readers see it: its bytes kept unchanged, its text in numbered lines.

Every reader in :mod:`volucal.core.io` reports bad input as
:class:`~volucal.core.userror.FormatError` naming the file and the 1-based line, and never lets
another exception escape: the helpers here turn numbers, integers and dates that cannot be read into
such errors.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from ..userror import FormatError

_LINE_BREAK = re.compile(r"\r\n|\r|\n")


@dataclass(frozen=True, eq=False)
class SourceText:
    """The bytes of a text file and its lines (without line endings), numbered from 1."""

    path: Path
    raw: bytes
    lines: tuple[str, ...]

    @classmethod
    def read(cls, path: str | Path) -> SourceText:
        path = Path(path)
        try:
            raw = path.read_bytes()
        except FileNotFoundError:
            raise FormatError(path, "file not found; check the path (relative paths start at the "
                              "plan file's folder)") from None
        except IsADirectoryError:
            raise FormatError(path, "is a folder, not a file") from None
        except OSError as exc:
            raise FormatError(path, f"cannot be read: {exc.strerror or exc}") from None
        return cls.from_bytes(path, raw)

    @classmethod
    def from_bytes(cls, path: str | Path, raw: bytes) -> SourceText:
        return cls(Path(path), raw, tuple(_LINE_BREAK.split(decode_text(raw))))

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
    """UTF-8 (with or without a byte-order mark), else Latin-1.

    Laser software on Windows writes user text in the local code page; Latin-1 maps every byte, so
    a file is never refused for its encoding alone (its numbers are checked field by field).
    """
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def parse_float(token: str, source: SourceText, line: int, what: str) -> float:
    """A finite number, or a FormatError saying which field of which line is wrong."""
    try:
        value = float(token)
    except (TypeError, ValueError):
        raise source.error(f"{what}: expected a number, found {token!r}", line) from None
    if not math.isfinite(value):
        raise source.error(f"{what}: expected a finite number, found {token!r}", line)
    return value


def parse_int(token: str, source: SourceText, line: int, what: str) -> int:
    """An integer written as ``3`` or ``3.0``, or a FormatError."""
    value = parse_float(token, source, line, what)
    if value != int(value):
        raise source.error(f"{what}: expected a whole number, found {token!r}", line)
    return int(value)


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
    text = token.strip().strip('"').strip()
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
            f"{what}: expected a date and time such as \"10:46 Dec 12 2016\" or "
            f"\"2016-12-12T10:46:00\", found {token!r}",
            line,
        ) from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    try:
        return moment.timestamp()
    except (OverflowError, OSError, ValueError):
        raise source.error(f"{what}: date {token!r} is out of range", line) from None


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
