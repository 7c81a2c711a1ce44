"""The project tree: machine, measurements, identifications, loops, sensitivity, compensation,
thermal records.

Selecting an item asks the main window to show its view (``itemChosen(kind, name)``); the
context menu removes a line or a result (undoable).
"""

from __future__ import annotations

from PySide6.QtCore import QPoint, Qt, Signal
from PySide6.QtWidgets import QMenu, QTreeWidget, QTreeWidgetItem, QWidget
from volucal.core.userror import UserError

from .dialogs import show_error
from .document import ProjectDocument

#: (kind, group label); the kind is also the project's result group, except machine and lines.
GROUPS = (
    ("measurements", "Measurements"),
    ("identifications", "Identifications"),
    ("loops", "Loops"),
    ("sensitivity", "Sensitivity"),
    ("compensation", "Compensation"),
    ("thermal", "Thermal records"),
)
ROLE_KIND = Qt.ItemDataRole.UserRole
ROLE_NAME = Qt.ItemDataRole.UserRole + 1


class ProjectTree(QTreeWidget):
    itemChosen = Signal(str, str)  # kind, name ("" for a group)

    def __init__(self, document: ProjectDocument, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("projectTree")
        self.setHeaderHidden(True)
        self.setContextMenuPolicy(Qt.ContextMenuPolicy.CustomContextMenu)
        self.customContextMenuRequested.connect(self._menu)
        self.itemSelectionChanged.connect(self._chosen)
        self.document = document
        document.changed.connect(self.rebuild)
        self.rebuild()

    def set_document(self, document: ProjectDocument) -> None:
        self.document.changed.disconnect(self.rebuild)
        self.document = document
        document.changed.connect(self.rebuild)
        self.rebuild()

    def rebuild(self) -> None:
        selected = self.current()
        self.blockSignals(True)
        self.clear()
        p = self.document.project
        machine = p.machine.name if p.machine is not None else "no machine yet"
        top = QTreeWidgetItem([f"Machine: {machine}"])
        top.setData(0, ROLE_KIND, "machine")
        top.setData(0, ROLE_NAME, "")
        self.addTopLevelItem(top)
        for kind, label in GROUPS:
            if kind == "measurements":
                names = list(p.lines)
                details = {n: p.lines[n].spec.quantity for n in names}
            else:
                names = p.results(kind)
                details = {}
            group = QTreeWidgetItem([f"{label} ({len(names)})"])
            group.setData(0, ROLE_KIND, kind)
            group.setData(0, ROLE_NAME, "")
            for name in names:
                text = f"{name}  [{details[name]}]" if name in details else name
                child = QTreeWidgetItem([text])
                child.setData(0, ROLE_KIND, kind)
                child.setData(0, ROLE_NAME, name)
                child.setToolTip(0, text)
                group.addChild(child)
            self.addTopLevelItem(group)
            group.setExpanded(kind != "measurements" or len(names) <= 30)
        self.blockSignals(False)
        if selected is not None:
            self.choose(*selected, emit=False)

    def current(self) -> tuple[str, str] | None:
        items = self.selectedItems()
        if not items:
            return None
        return str(items[0].data(0, ROLE_KIND)), str(items[0].data(0, ROLE_NAME))

    def choose(self, kind: str, name: str = "", emit: bool = True) -> bool:
        """Select the item of ``kind`` and ``name`` (its group when the name is empty)."""
        for i in range(self.topLevelItemCount()):
            group = self.topLevelItem(i)
            if group is None:
                continue
            candidates = [group] + [group.child(j) for j in range(group.childCount())]
            for item in candidates:
                if item is not None and item.data(0, ROLE_KIND) == kind and \
                        item.data(0, ROLE_NAME) == name:
                    self.blockSignals(not emit)
                    self.setCurrentItem(item)
                    self.blockSignals(False)
                    return True
        return False

    def _chosen(self) -> None:
        current = self.current()
        if current is not None:
            self.itemChosen.emit(*current)

    def _menu(self, point: QPoint) -> None:
        item = self.itemAt(point)
        if item is None or not item.data(0, ROLE_NAME):
            return
        kind, name = str(item.data(0, ROLE_KIND)), str(item.data(0, ROLE_NAME))
        menu = QMenu(self)
        action = menu.addAction(f"Remove {name}")
        chosen = menu.exec(self.viewport().mapToGlobal(point))
        if chosen is action:
            self.remove(kind, name)

    def remove(self, kind: str, name: str) -> None:
        try:
            if kind == "measurements":
                self.document.remove_line(name)
            else:
                self.document.remove_result(kind, name)
        except UserError as exc:
            show_error(self, "Remove", str(exc))
