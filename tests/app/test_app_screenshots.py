"""Screenshots of every view at the default size, as docs/make_screenshots.py takes them.

The test writes them to artifacts/screenshots/ (git-ignored, for reviewers); docs/images/ is
refreshed by running the script by hand (``python docs/make_screenshots.py``) and looking at the
pictures. Each view must show real content: a picture of an empty view compresses to a few
kilobytes.
"""

import importlib.util
from pathlib import Path

from PySide6.QtGui import QImage

REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO / "artifacts" / "screenshots"


def load_script():
    spec = importlib.util.spec_from_file_location("make_screenshots",
                                                  REPO / "docs" / "make_screenshots.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_screenshots_of_every_view_at_the_default_size(qtbot, demo_run):
    script = load_script()
    written = script.take(ARTIFACTS, demo_run / "demo.h5")
    names = {p.stem for p in written}
    assert set(script.VIEWS) <= names and {"import_preview", "import_plan"} <= names
    for path in written:
        image = QImage(str(path))
        if path.stem in script.VIEWS:
            assert (image.width(), image.height()) == script.DEFAULT_SIZE, path.name
        assert path.stat().st_size > 30_000, f"{path.name} looks empty"
