"""Shared test settings: Qt runs offscreen, and the shared real data folder is optional."""

import fcntl
import os
import tempfile
from pathlib import Path

import pytest

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


@pytest.fixture
def realdata() -> Path:
    """../shared/realdata when present (never copied into the repository)."""
    path = SHARED / "realdata"
    if not path.is_dir():
        pytest.skip("../shared/realdata is not present on this machine")
    return path


#: One HAL session runs per machine: LinuxCNC tests that take this lock never overlap, even across
#: test runs started at the same time (otherwise: "duplicate thread name servo-thread").
LINUXCNC_LOCK = Path(tempfile.gettempdir()) / "volucal-linuxcnc.lock"


@pytest.fixture
def one_session():
    with open(LINUXCNC_LOCK, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)
