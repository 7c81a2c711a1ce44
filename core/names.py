"""Names from users and projects: checked before they become HDF5 names, file names or text in a
controller's file.

Three checks, one per use:

- :func:`check_name` — any name volucal stores or prints (line names, result names, axis names):
  a non-empty string without control characters. HDF5 cuts a name at a NUL ("a\\0b" would be
  stored as "a") and a newline would inject a line into a controller's file, so both are refused
  rather than cleaned.
- :func:`safe_file_name` — a name that becomes *one* file name inside a folder: additionally no
  path separator, not ``.`` or ``..``, no character Windows forbids, no Windows device name, no
  trailing dot or space, at most 255 bytes. ``--axis-names X=../../escaped`` is refused here.
- :func:`file_in_folder` — the path of such a file in its folder; every exporter builds its file
  paths through it.
"""

from __future__ import annotations

import unicodedata
from pathlib import Path

from .userror import UserError

#: Characters Windows refuses in file names (and the POSIX separator); a file written on Linux
#: must still copy to the controller's PC or a USB stick formatted FAT/NTFS.
FORBIDDEN_IN_FILE_NAMES = frozenset('/\\:*?"<>|')
WINDOWS_DEVICES = frozenset(
    {"CON", "PRN", "AUX", "NUL"}
    | {f"COM{i}" for i in range(1, 10)}
    | {f"LPT{i}" for i in range(1, 10)}
)
MAX_FILE_NAME_BYTES = 255  # ext4, NTFS (in UTF-16 units), FAT long names


def _control(character: str) -> bool:
    # Cc: C0/C1 controls, DEL; Cs: lone surrogates (cannot be encoded); Zl/Zp: line and
    # paragraph separators, which some editors treat as line breaks.
    return unicodedata.category(character) in ("Cc", "Cs", "Zl", "Zp")


def check_name(name: object, what: str) -> str:
    """``name`` if it is a non-empty string without control characters, else :class:`UserError`.

    Parameters
    ----------
    name : object
        The candidate.
    what : str
        What the name is, for the message (e.g. ``"line name"``, ``"--axis-names value for X"``).
    """
    if not isinstance(name, str) or not name:
        raise UserError(f"{what}: expected a non-empty name, got {name!r}")
    bad = [c for c in name if _control(c)]
    if bad:
        shown = ", ".join(sorted({f"U+{ord(c):04X}" for c in bad}))
        raise UserError(
            f"{what} {name!r} contains control characters ({shown}); use printable characters "
            "only (no NUL, tab, newline or other control character)"
        )
    return name


def safe_file_name(name: object, what: str) -> str:
    """``name`` if it can be used as one file name inside a folder, else :class:`UserError`."""
    text = check_name(name, what)
    forbidden = sorted({c for c in text if c in FORBIDDEN_IN_FILE_NAMES})
    if forbidden:
        raise UserError(
            f"{what} {text!r} becomes a file name and cannot contain {' '.join(forbidden)} "
            "(no folders, no characters Windows refuses)"
        )
    if text in (".", "..") or text != text.rstrip(". ") or text != text.lstrip():
        raise UserError(
            f"{what} {text!r} becomes a file name: it cannot be '.' or '..', start with a space "
            "or end with a dot or a space"
        )
    if text.split(".", 1)[0].upper() in WINDOWS_DEVICES:
        raise UserError(f"{what} {text!r} becomes a file name that Windows reserves for a device")
    if len(text.encode("utf-8")) > MAX_FILE_NAME_BYTES:
        raise UserError(f"{what}: the name is longer than {MAX_FILE_NAME_BYTES} bytes")
    return text


def file_in_folder(folder: str | Path, name: str, what: str = "file name") -> Path:
    """The path of file ``name`` directly inside ``folder``, after :func:`safe_file_name`."""
    return Path(folder) / safe_file_name(name, what)


def printable_ascii(text: object) -> str:
    """``text`` for a comment in a controller's ASCII file: non-ASCII and control characters
    escaped (``\\xc4``, ``\\n``), so a machine name can neither break the encoding nor start a
    new line."""
    escaped = str(text).encode("ascii", "backslashreplace").decode("ascii")
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in escaped)
