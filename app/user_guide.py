"""Help ▸ User guide: the documentation of docs/ inside the program.

The pages are the Markdown files that ship with volucal (``volucal/docs``: the repository's
docs/ folder, installed as package data and collected by the desktop build), shown by Qt's own
Markdown renderer with their pictures; links between pages follow inside the window, links to
the web open the browser.
"""

from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import Qt, QUrl
from PySide6.QtGui import QDesktopServices, QImage, QTextDocument
from PySide6.QtWidgets import (
    QDialog,
    QHBoxLayout,
    QListWidget,
    QSplitter,
    QTextBrowser,
    QVBoxLayout,
    QWidget,
)
from volucal.core.userror import UserError

#: The pages in reading order (file, title); the guide starts on the first.
PAGES = (
    ("index.md", "Contents"),
    ("guide.md", "User guide"),
    ("gui.md", "The workbench"),
    ("formats.md", "File formats"),
    ("method.md", "The method"),
    ("sensitivity.md", "Global sensitivity (EFAST)"),
    ("compensation.md", "Compensation"),
    ("plans.md", "Plan presets"),
    ("cli.md", "Command line"),
    ("report_json.md", "report.json"),
    ("hdf5.md", "Project result groups"),
)


def docs_folder() -> Path:
    """Where the documentation is: ``docs`` beside the volucal package."""
    import volucal

    folder = Path(volucal.__file__).resolve().parent / "docs"
    if not (folder / PAGES[0][0]).is_file():
        raise UserError(f"the documentation is not installed ({folder} has no {PAGES[0][0]}); "
                        "it is online with the source code")
    return folder


#: Pictures wider than this (pixels) are shown scaled down to it.
PICTURE_WIDTH = 760


class _GuideText(QTextBrowser):
    """The page; its pictures (screenshots of the whole window) are scaled to fit."""

    def loadResource(self, kind: int, url: QUrl) -> object:
        if kind == int(QTextDocument.ResourceType.ImageResource.value):
            image = QImage(url.toLocalFile() if url.isLocalFile() else
                           str(Path(self.searchPaths()[0]) / url.path()))
            if not image.isNull():
                if image.width() > PICTURE_WIDTH:
                    image = image.scaledToWidth(PICTURE_WIDTH,
                                                Qt.TransformationMode.SmoothTransformation)
                return image
        return super().loadResource(kind, url)


class UserGuide(QDialog):
    """A window with the list of pages and the page shown."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle("volucal user guide")
        self.setObjectName("userGuide")
        self.resize(1100, 800)
        self.folder = docs_folder()
        self.pages = QListWidget()
        self.pages.setObjectName("guidePages")
        self.files = [name for name, _ in PAGES if (self.folder / name).is_file()]
        titles = dict(PAGES)
        self.pages.addItems([titles[name] for name in self.files])
        self.pages.setMaximumWidth(240)
        self.browser = _GuideText()
        self.browser.setObjectName("guideText")
        self.browser.setOpenLinks(False)
        self.browser.anchorClicked.connect(self._follow)
        self.browser.setSearchPaths([str(self.folder)])
        self.pages.currentRowChanged.connect(self._show_row)
        splitter = QSplitter()
        splitter.addWidget(self.pages)
        splitter.addWidget(self.browser)
        splitter.setStretchFactor(1, 1)
        layout = QVBoxLayout(self)
        row = QHBoxLayout()
        row.addWidget(splitter)
        layout.addLayout(row)
        self.pages.setCurrentRow(0)

    def _show_row(self, row: int) -> None:
        if 0 <= row < len(self.files):
            self.show_page(self.files[row])

    def show_page(self, name: str, anchor: str = "") -> None:
        """Show docs/``name`` (a Markdown file), scrolled to ``anchor`` when given."""
        path = self.folder / name
        if not path.is_file():
            raise UserError(f"no page {name!r} in the user guide")
        url = QUrl.fromLocalFile(str(path))
        self.browser.setSource(url, QTextDocument.ResourceType.MarkdownResource)
        if anchor:
            self.browser.scrollToAnchor(anchor)
        if name in self.files:
            self.pages.blockSignals(True)
            self.pages.setCurrentRow(self.files.index(name))
            self.pages.blockSignals(False)

    def page_text(self) -> str:
        return self.browser.toPlainText()

    def _follow(self, url: QUrl) -> None:
        if url.scheme() in ("http", "https", "mailto"):
            QDesktopServices.openUrl(url)
            return
        target = Path(url.toLocalFile()) if url.isLocalFile() else self.folder / url.path()
        if target.suffix == ".md" and target.name in {n for n, _ in PAGES}:
            self.show_page(target.name, url.fragment())
        elif url.fragment() and not url.path():
            self.browser.scrollToAnchor(url.fragment())
