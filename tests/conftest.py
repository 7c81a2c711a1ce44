"""Shared test settings: Qt runs offscreen, and the shared real data folder is optional."""

import os
from pathlib import Path

import pytest

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


@pytest.fixture
def realdata() -> Path:
    """../shared/realdata (or /work/shared/realdata, for a git worktree) when present; never
    copied into the repository."""
    for path in (SHARED / "realdata", Path("/work/shared/realdata")):
        if path.is_dir():
            return path
    pytest.skip("../shared/realdata is not present on this machine")
