"""The packaging tests: the ``frozen`` marker (registered here, beside the only tests that use
it) and the packaging folder on the import path (it is not a package)."""

import sys
from pathlib import Path

PACKAGING = Path(__file__).resolve().parents[2] / "packaging"
sys.path.insert(0, str(PACKAGING))


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "frozen: builds (or uses) the PyInstaller bundle and runs it; set "
        "VOLUCAL_FROZEN_TEST=1 to run (minutes)")
