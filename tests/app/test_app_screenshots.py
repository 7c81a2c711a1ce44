"""Screenshots of every main view (offscreen), for reviewers and the README.

Written to artifacts/screenshots/ (a test artefact, git-ignored) and copied to docs/images/,
which the README shows. Each view is shown with real content: the small simulated session,
looped, ranked, with a workspace map and a compensation preview.
"""

import shutil
from pathlib import Path

from PySide6.QtWidgets import QWizard
from volucal.core.resources import demo_plan

REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO / "artifacts" / "screenshots"
DOC_IMAGES = REPO / "docs" / "images"

VIEWS = ("machine", "measurement", "identification", "loop", "sensitivity", "compensation")


def save(widget, name):
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    DOC_IMAGES.mkdir(parents=True, exist_ok=True)
    path = ARTIFACTS / f"{name}.png"
    assert widget.grab().save(str(path)), path
    shutil.copyfile(path, DOC_IMAGES / path.name)
    return path


def test_screenshots_of_every_view(qtbot, window, wait_idle):
    window.resize(1500, 950)
    sensitivity = window.views["sensitivity"]
    window.show_view("sensitivity")
    sensitivity.n_box.setValue(200)
    sensitivity.map_step.setValue(50.0)
    sensitivity.run_map()
    wait_idle(sensitivity)
    compensation = window.views["compensation"]
    window.show_view("compensation")
    compensation.set_format("linuxcnc")
    compensation.run_preview()
    wait_idle(compensation)
    window.tree.choose("measurements", "x_lin_1")
    window.views["identification"].select("loop")
    loop = window.views["loop"]
    written = []
    for key in VIEWS:
        window.show_view(key)
        if key == "loop":
            loop.steps.selectRow(0)
        qtbot.wait(100)
        written.append(save(window, key))
    for path in written:
        assert path.stat().st_size > 20_000, f"{path.name} looks empty"


def test_screenshot_of_the_import_wizard(qtbot, window):
    wizard = window.import_logs([demo_plan()])
    wizard.resize(1200, 800)
    qtbot.waitUntil(wizard.files_page.isComplete, timeout=60_000)
    wizard.next()
    qtbot.waitUntil(wizard.preview_page.isComplete, timeout=60_000)
    wizard.preview_page.table.selectRow(1)
    qtbot.wait(100)
    save(wizard, "import_preview")
    wizard.next()
    wizard.plan_page.table.selectRow(4)
    qtbot.wait(100)
    save(wizard, "import_plan")
    wizard.button(QWizard.WizardButton.CancelButton).click()
