"""The lock that keeps two writers off one project, and the recovery after a crash.

A writer holds ``<project>.lock`` from the moment it reads the project to the moment its save is
renamed into place, so no other writer can save a copy made before that save (a lost update).

Where the system has ``fcntl`` (Linux, macOS), the lock is an OS lock (``flock``) on that file:
the kernel releases it when its process ends, however it ends (SIGKILL, power loss of a remote
client aside). A lock file whose OS lock can be taken therefore belongs to a process that is
gone: it is *stale*, and it is cleared with a message on the ``volucal.project`` logger (printed
on stderr by the command line). The file holds the owner's pid, for messages only. A lock file
of an older volucal (a bare pid, no OS lock) is judged by whether that pid still runs. Without
``fcntl`` (Windows) a lock is the bare pid, judged the same way.

Temporary files ``<project>.tmp-<pid>`` are what a killed save leaves. Only a save makes them and
a save holds the lock, so whoever takes the lock fresh removes those of other processes; opening
a project does that when the lock is free.
"""

from __future__ import annotations

import logging
import os
import re
import threading
import time
from pathlib import Path

from .userror import UserError

try:  # POSIX
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

log = logging.getLogger("volucal.project")

#: How long a writer waits for a lock held by another process before refusing (s): long enough
#: for another process' save or its check at opening, short enough not to hang a command.
WAIT_S = 1.0
_MARK = "volucal-flock"
_TEMPORARY = re.compile(r"\.tmp-(\d+)$")

_HELD: dict[str, tuple[int, int | None]] = {}  # lock key -> (count, fd of the OS lock)
_GUARD = threading.RLock()


def pid_alive(pid: int) -> bool:
    """True when process ``pid`` exists on this machine."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's live process
    except OSError:
        return False
    return True


def temporary_path(target: Path) -> Path:
    """Where a save of ``target`` by this process writes before renaming."""
    return target.with_name(f"{target.name}.tmp-{os.getpid()}")


class ProjectLock:
    """An exclusive, re-entrant (within a process) lock on a project (module notes).

    ``acquire`` raises :class:`UserError` naming the holder when another live process holds it.
    """

    def __init__(self, path: str | Path) -> None:
        self.project = Path(path)
        self.path = Path(str(self.project) + ".lock")
        self._key = os.path.abspath(self.path)

    # ---- public ---------------------------------------------------------------------------

    def acquire(self, wait_s: float = WAIT_S) -> None:
        with _GUARD:
            if self._key in _HELD:
                count, fd = _HELD[self._key]
                _HELD[self._key] = (count + 1, fd)
                return
            deadline = time.monotonic() + wait_s
            while True:
                fd, holder = self._attempt()
                if holder is None:
                    _HELD[self._key] = (1, fd)
                    break
                if time.monotonic() >= deadline:
                    who = f"process {holder}" if holder > 0 else "another process"
                    raise UserError(
                        f"{self.project} is locked by {who} (lock file {self.path}): another "
                        "volucal is changing this project; wait for it to finish and try again"
                    )
                time.sleep(0.02)
        self._remove_temporaries()

    def try_acquire(self) -> bool:
        """Take the lock if it is free right now; False when another process holds it."""
        try:
            self.acquire(wait_s=0.0)
        except UserError:
            return False
        return True

    def release(self) -> None:
        with _GUARD:
            count, fd = _HELD.get(self._key, (0, None))
            if count > 1:
                _HELD[self._key] = (count - 1, fd)
                return
            _HELD.pop(self._key, None)
            # Unlink before unlocking: a waiter that opened this file sees it is no longer the
            # one at the path and starts again with a new file.
            if _pid_in(self._read(fd)) == os.getpid():
                self.path.unlink(missing_ok=True)
            if fd is not None:
                os.close(fd)

    @property
    def held(self) -> bool:
        """True while this process holds the lock."""
        with _GUARD:
            return self._key in _HELD

    def __enter__(self) -> ProjectLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    # ---- one attempt ----------------------------------------------------------------------

    def _attempt(self) -> tuple[int | None, int | None]:
        """(fd, None) when the lock is ours now, (None, holder pid or 0) when someone has it."""
        if fcntl is None:  # pragma: no cover - Windows
            return self._attempt_by_pid()
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
        except OSError as exc:
            raise UserError(
                f"{self.path}: cannot create the lock file ({exc.strerror or exc}); the "
                "project's folder must be writable to change the project"
            ) from None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                holder = _pid_in(self._read(fd))
                os.close(fd)
                return None, holder or 0
            if not _same_file(fd, self.path):
                os.close(fd)  # its holder released it while we opened it: start again
                return self._attempt()
            previous = self._read(fd)
            pid = _pid_in(previous)
            if pid and _MARK not in previous and pid != os.getpid() and pid_alive(pid):
                os.close(fd)  # an older volucal's lock (no OS lock), its process still running
                return None, pid
            if previous.strip():
                log.warning(
                    "note: %s: cleared a stale lock left by %s, which is no longer running",
                    self.path,
                    f"process {pid}" if pid else "a process",
                )
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()} {_MARK}\n".encode("ascii"), 0)
            return fd, None
        except BaseException:
            try:
                os.close(fd)
            except OSError:
                pass
            raise

    def _attempt_by_pid(self) -> tuple[int | None, int | None]:  # pragma: no cover - Windows
        try:
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            holder = _pid_in(self._read(None))
            if holder and holder != os.getpid() and pid_alive(holder):
                return None, holder
            if holder is None:
                return None, 0  # being created right now: its pid is not written yet
            log.warning(
                "note: %s: cleared a stale lock left by process %s, which is no longer running",
                self.path,
                holder,
            )
            self.path.unlink(missing_ok=True)
            return self._attempt_by_pid()
        except OSError as exc:
            raise UserError(
                f"{self.path}: cannot create the lock file ({exc.strerror or exc})"
            ) from None
        os.write(fd, str(os.getpid()).encode("ascii"))
        os.close(fd)
        return None, None

    def _read(self, fd: int | None) -> str:
        try:
            if fd is not None:
                return os.pread(fd, 200, 0).decode("ascii", errors="replace")
            return self.path.read_text(encoding="ascii", errors="replace")
        except OSError:
            return ""

    def _remove_temporaries(self) -> None:
        """Delete other processes' ``<project>.tmp-<pid>``: we hold the lock, so none of them
        is a save in progress."""
        folder = self.project.parent
        try:
            candidates = list(folder.glob(f"{_glob_escape(self.project.name)}.tmp-*"))
        except OSError:
            return
        for candidate in candidates:
            match = _TEMPORARY.search(candidate.name)
            if not match or int(match.group(1)) == os.getpid():
                continue
            try:
                candidate.unlink()
            except FileNotFoundError:
                continue
            except OSError as exc:
                log.warning(
                    "note: %s: cannot remove this temporary file left by an interrupted save (%s)",
                    candidate,
                    exc.strerror or exc,
                )
                continue
            log.warning("note: removed %s, a temporary file left by an interrupted save", candidate)


def recover(project: str | Path) -> None:
    """Clear a stale lock and the temporary files of killed saves, when no one holds the lock.

    Called when a project is opened; does nothing when the folder is read-only or another
    process holds the lock.
    """
    lock = ProjectLock(project)
    if lock.held:
        return
    if not lock.path.exists() and not any(
        Path(project).parent.glob(f"{_glob_escape(Path(project).name)}.tmp-*")
    ):
        return
    try:
        taken = lock.try_acquire()
    except UserError:
        return  # read-only folder: nothing to clean, nothing we could clean
    if taken:
        lock.release()


def _pid_in(text: str) -> int | None:
    first = text.split()[0] if text.split() else ""
    return int(first) if first.isdigit() else None


def _same_file(fd: int, path: Path) -> bool:
    try:
        on_disk = os.stat(path)
    except FileNotFoundError:
        return False
    mine = os.fstat(fd)
    return (mine.st_dev, mine.st_ino) == (on_disk.st_dev, on_disk.st_ino)


def _glob_escape(name: str) -> str:
    return re.sub(r"([*?\[])", r"[\1]", name)
