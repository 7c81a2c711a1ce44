"""The frozen (PyInstaller) build runs: ``volucal --help``, ``volucal demo``, ``volucal report``
and the workbench's smoke start, from packaging/smoke_test.py.

Skipped unless VOLUCAL_FROZEN_TEST=1: building numpy, scipy, numba and PySide6 into a bundle takes
minutes. The bundle in packaging/dist/volucal is used when it exists (``make package`` builds it;
VOLUCAL_FROZEN_REBUILD=1 forces a new build), else it is built there first.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [
    pytest.mark.frozen,
    pytest.mark.skipif(os.environ.get("VOLUCAL_FROZEN_TEST") != "1",
                       reason="set VOLUCAL_FROZEN_TEST=1 to build and run the frozen app"),
]

PACKAGING = Path(__file__).resolve().parents[2] / "packaging"
BUNDLE = PACKAGING / "dist" / "volucal"


@pytest.fixture(scope="module")
def bundle() -> Path:
    if (BUNDLE / "volucal").is_file() and os.environ.get("VOLUCAL_FROZEN_REBUILD") != "1":
        return BUNDLE
    pytest.importorskip("PyInstaller", reason="pip install pyinstaller (the dev extra)")
    subprocess.run(
        [sys.executable, "-m", "PyInstaller", "--noconfirm", "--clean",
         "--distpath", str(PACKAGING / "dist"), "--workpath", str(PACKAGING / "build"),
         str(PACKAGING / "volucal.spec")],
        check=True, timeout=1800,
    )
    return BUNDLE


@pytest.mark.timeout(2400)
def test_frozen_app_runs_the_demo_and_writes_a_report(bundle, tmp_path):
    from smoke_test import smoke

    timings = dict(smoke(bundle, tmp_path))
    assert set(timings) == {"version", "help", "contents", "demo", "report", "gui"}
