"""The open project: a core :class:`~volucal.core.project.Project` with undo, signals and the live
results of this session.

Views never change the project themselves: they call the document, which applies the change
through the core object, records it on the undo stack and tells every view. A change is applied
*before* its undo command is pushed, so an edit the core refuses (a :class:`UserError`) leaves
the project untouched and never reaches the stack.

Live results are the core objects computed in this session (an ``Identification``, a
``LoopResult``...); the project keeps their trees. Both are part of an undo snapshot.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from PySide6.QtCore import QObject, Signal
from PySide6.QtGui import QUndoCommand, QUndoStack
from volucal.core.io.plan import ImportResult, plan_text
from volucal.core.machine import Machine
from volucal.core.measurement import Measurement
from volucal.core.project import RESULT_KINDS, Project, StoredLine
from volucal.core.userror import UserError

from .factors import SensitivityRecord
from .records import IdentificationRecord, LoopRecord

log = logging.getLogger("volucal.app")


@dataclass(eq=False)
class _State:
    """Everything an edit can change (shallow copies: stored lines and trees are never mutated)."""

    machine: Machine | None
    plan_toml: str | None
    plan_path: str | None
    uncertainty: dict[str, float]
    lines: dict[str, StoredLine]
    results: dict[str, dict[str, Any]]
    live: dict[tuple[str, str], Any] = field(default_factory=dict)


class _Edit(QUndoCommand):
    """An edit already applied: redo restores the state after it, undo the state before."""

    def __init__(self, document: ProjectDocument, text: str, before: _State, after: _State
                 ) -> None:
        super().__init__(text)
        self._document = document
        self._before = before
        self._after = after

    def redo(self) -> None:
        self._document._restore(self._after)

    def undo(self) -> None:
        self._document._restore(self._before)


class ProjectDocument(QObject):
    """The project the main window shows.

    Signals: ``changed()`` after any edit, undo or redo (views refresh); ``pathChanged(path)``
    after open, save-as; ``cleanChanged(bool)`` when the project becomes saved or unsaved.
    """

    changed = Signal()
    pathChanged = Signal(object)
    cleanChanged = Signal(bool)

    def __init__(self, project: Project | None = None, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.project = project if project is not None else Project.create()
        self.live: dict[tuple[str, str], Any] = {}
        self.undo_stack = QUndoStack(self)
        self.undo_stack.cleanChanged.connect(self.cleanChanged)

    # ---- reading ---------------------------------------------------------------------------

    @property
    def path(self) -> Path | None:
        return self.project.path

    @property
    def machine(self) -> Machine | None:
        return self.project.machine

    @property
    def is_clean(self) -> bool:
        return self.undo_stack.isClean()

    @property
    def is_empty(self) -> bool:
        return self.project.machine is None and not self.project.lines

    def line_names(self) -> list[str]:
        return list(self.project.lines)

    def measurement(self) -> Measurement:
        return self.project.measurement()

    def results(self, kind: str) -> list[str]:
        return self.project.results(kind)

    def tree(self, kind: str, name: str) -> dict[str, Any]:
        return self.project.result(kind, name)

    def result_token(self, kind: str, name: str) -> int | None:
        """Changes whenever result ``name`` is stored again (an identification run anew):
        views that derived something from a result compare tokens to know it is stale."""
        stored = self.project._results.get(kind, {}).get(name)
        return None if stored is None else id(stored)

    def identification(self, name: str) -> IdentificationRecord:
        live = self.live.get(("identifications", name))
        if live is not None:
            return live.record  # type: ignore[no-any-return]
        return IdentificationRecord.from_tree(name, self.tree("identifications", name))

    def loop(self, name: str) -> LoopRecord:
        live = self.live.get(("loops", name))
        if live is not None:
            return live.record  # type: ignore[no-any-return]
        return LoopRecord.from_tree(name, self.tree("loops", name))

    def sensitivity(self, name: str) -> SensitivityRecord:
        live = self.live.get(("sensitivity", name))
        if live is not None:
            return live.record  # type: ignore[no-any-return]
        return SensitivityRecord.from_tree(name, self.tree("sensitivity", name))

    # ---- undo snapshots ----------------------------------------------------------------------

    def _state(self) -> _State:
        p = self.project
        return _State(
            machine=p.machine,
            plan_toml=p.plan_toml,
            plan_path=p.plan_path,
            uncertainty=dict(p.uncertainty),
            lines=dict(p.lines),
            # The core Project has no API to remove a result, so snapshots copy its result
            # table (read only here and in _restore).
            results={kind: dict(p._results[kind]) for kind in RESULT_KINDS},
            live=dict(self.live),
        )

    def _restore(self, state: _State) -> None:
        p = self.project
        p.machine = state.machine
        p.plan_toml = state.plan_toml
        p.plan_path = state.plan_path
        p.uncertainty = dict(state.uncertainty)
        p.lines = dict(state.lines)
        for kind in RESULT_KINDS:
            p._results[kind] = dict(state.results[kind])
        self.live = dict(state.live)
        self.changed.emit()

    def _edit(self, text: str, change: Callable[[], None]) -> None:
        before = self._state()
        try:
            change()
        except BaseException:
            self._restore(before)
            raise
        self.undo_stack.push(_Edit(self, text, before, self._state()))
        log.info("%s", text)

    # ---- edits ---------------------------------------------------------------------------------

    def import_lines(self, imported: ImportResult, replace: bool = False) -> None:
        """Add the lines of an import; raises UserError (project unchanged) for a plan of
        another machine or line names already in the project (unless ``replace``)."""
        def change() -> None:
            self.project.add_lines(
                imported.plan, imported.measurement, imported.source_bytes, imported.raw,
                provenance={line.name: line.provenance() for line in imported.lines},
                captures={line.name: _capture_arrays(line.capture) for line in imported.lines
                          if line.capture is not None},
                replace=replace,
            )
            if imported.plan.path is None:
                # a plan edited in the wizard has no file: keep its text with the project
                files = [str(Path(s.file).parent) for s in imported.plan.lines if s.file]
                folder = Path(os.path.commonpath(files)) if files else Path.cwd()
                self.project.plan_toml = plan_text(imported.plan, folder)

        self._edit(f"import {len(imported.lines)} line(s)", change)

    def remove_line(self, name: str) -> None:
        if name not in self.project.lines:
            raise UserError(f"no line {name!r} in the project")

        def change() -> None:
            del self.project.lines[name]

        self._edit(f"remove line {name}", change)

    def put_results(self, text: str, trees: Mapping[tuple[str, str], Mapping[str, Any]],
                    live: Mapping[tuple[str, str], Any] | None = None) -> None:
        """Store result trees (and their live objects) as one undoable edit."""
        def change() -> None:
            for (kind, name), tree in trees.items():
                self.project.put_result(kind, name, tree)
                self.live.pop((kind, name), None)
            self.live.update(live or {})

        self._edit(text, change)

    def remove_result(self, kind: str, name: str) -> None:
        if name not in self.project.results(kind):
            raise UserError(f"no {kind} result {name!r} in the project")

        def change() -> None:
            del self.project._results[kind][name]
            self.live.pop((kind, name), None)

        self._edit(f"remove {kind} {name}", change)

    def set_machine(self, machine: Machine) -> None:
        """Replace the machine's description (name, tool offset, screw leads)."""
        old = self.project.machine
        if old is not None and (old.chain, dict(old.stroke_mm), old.reference_mm) != (
                machine.chain, dict(machine.stroke_mm), machine.reference_mm):
            raise UserError("the chain, strokes and reference of a machine with measured lines "
                            "cannot change: start a new project for another machine")

        def change() -> None:
            self.project.machine = machine

        self._edit(f"edit machine {machine.name}", change)

    # ---- files ---------------------------------------------------------------------------------

    def save(self, path: str | Path | None = None) -> Path:
        saved = self.project.save(path)
        self.undo_stack.setClean()
        self.pathChanged.emit(saved)
        log.info("saved %s", saved)
        return saved


def _capture_arrays(capture: Any) -> dict[str, Any]:
    """A dynamic capture's arrays as the project stores them."""
    arrays = {"time_s": capture.time_s, "deviation": capture.deviation}
    if capture.position_mm is not None:
        arrays["position_mm"] = capture.position_mm
    return arrays
