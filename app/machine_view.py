"""Machine view: the machine's description, the plan's lines in the workspace, the project file.

The chain, strokes and reference define what every stored line and result means, so they are
shown, not edited; the name, tool offset and screw leads can be edited (undoable).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QDoubleSpinBox,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QSplitter,
    QVBoxLayout,
    QWidget,
)
from volucal.core.machine import AXES, Machine
from volucal.core.userror import UserError

from .dialogs import show_error
from .document import ProjectDocument
from .plan_sketch import PlanSketch, SketchLine
from .view_base import View


class MachineView(View):
    title = "Machine"

    def __init__(self, document: ProjectDocument, parent: QWidget | None = None) -> None:
        super().__init__(document, parent)
        self.setObjectName("machineView")
        self.name = QLineEdit()
        self.name.setObjectName("machineName")
        self.chain = QLabel()
        self.strokes = QLabel()
        self.reference = QLabel()
        self.tool = [_spin() for _ in AXES]
        self.leads = [_spin(0.0, 1000.0) for _ in AXES]
        for box in self.leads:
            box.setSpecialValueText("—")
        tool_row = QHBoxLayout()
        lead_row = QHBoxLayout()
        for box in self.tool:
            tool_row.addWidget(box)
        for box in self.leads:
            lead_row.addWidget(box)
        self.apply_button = QPushButton("Apply")
        self.apply_button.setObjectName("applyMachine")
        self.apply_button.clicked.connect(self.apply)
        form = QFormLayout()
        form.addRow("name", self.name)
        form.addRow("chain (workpiece → tool)", self.chain)
        form.addRow("strokes", self.strokes)
        form.addRow("reference (errors are zero here)", self.reference)
        form.addRow("tool offset D1 D2 D3 (mm)", tool_row)
        form.addRow("screw leads X Y Z (mm)", lead_row)
        form.addRow("", self.apply_button)
        machine_box = QGroupBox("Machine")
        machine_box.setLayout(form)
        self.project_info = QLabel()
        self.project_info.setObjectName("projectInfo")
        self.project_info.setWordWrap(True)
        self.project_info.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.project_info.setAlignment(Qt.AlignmentFlag.AlignTop)
        info_box = QGroupBox("Project")
        QVBoxLayout(info_box).addWidget(self.project_info)
        left = QWidget()
        left_layout = QVBoxLayout(left)
        left_layout.setContentsMargins(0, 0, 0, 0)
        left_layout.addWidget(machine_box)
        left_layout.addWidget(info_box, 1)
        self.sketch = PlanSketch()
        splitter = QSplitter(Qt.Orientation.Vertical)
        splitter.addWidget(left)
        splitter.addWidget(self.sketch)
        splitter.setStretchFactor(1, 2)
        layout = QVBoxLayout(self)
        layout.addWidget(splitter)

    def refresh(self) -> None:
        machine = self.document.machine
        enabled = machine is not None
        for widget in (self.name, self.apply_button, *self.tool, *self.leads):
            widget.setEnabled(enabled)
        if machine is None:
            self.name.clear()
            self.chain.setText("—")
            self.strokes.setText("—")
            self.reference.setText("—")
        else:
            self.name.setText(machine.name)
            self.chain.setText(f"{machine.chain} (axes in product order: "
                               f"{' · '.join(machine.axis_order)})")
            self.strokes.setText(", ".join(
                f"{a} {machine.stroke(a)[0]:g} … {machine.stroke(a)[1]:g} mm" for a in AXES))
            self.reference.setText(", ".join(f"{a} {v:g}" for a, v in zip(
                AXES, machine.reference_mm or (), strict=True)) + " mm")
            for box, value in zip(self.tool, machine.tool_offset_mm, strict=True):
                box.setValue(value)
            for box, axis in zip(self.leads, AXES, strict=True):
                box.setValue(machine.screw_lead_mm.get(axis, 0.0))
        self._fill_info()
        self._draw_sketch(machine)

    def _fill_info(self) -> None:
        p = self.document.project
        counts = {kind: len(p.results(kind)) for kind in
                  ("identifications", "loops", "sensitivity", "compensation")}
        rows = [
            ("file", str(p.path) if p.path else "not saved yet"),
            ("created", p.created), ("modified", p.modified), ("creator", p.creator),
            ("plan", p.plan_path or "—"), ("lines", str(len(p.lines))),
        ] + [(k, str(v)) for k, v in counts.items()]
        self.project_info.setText("<table>" + "".join(
            f"<tr><td><b>{k}</b>&nbsp;</td><td>{v}</td></tr>" for k, v in rows) + "</table>")

    def _draw_sketch(self, machine: Machine | None) -> None:
        if machine is None:
            self.sketch.set_plan({}, [])
            return
        lines = []
        for stored in self.document.project.lines.values():
            spec = stored.spec
            targets = stored.corrected.targets_mm
            length = float(np.nanmax(targets)) if targets.size else 0.0
            lines.append(SketchLine(spec.name, spec.quantity, spec.start_mm, spec.direction,
                                    length))
        self.sketch.set_plan(dict(machine.stroke_mm), lines)

    def select(self, name: str | None) -> None:
        if self._stale:
            self._refresh_now()
        self.sketch.select(name)

    def apply(self) -> None:
        machine = self.document.machine
        if machine is None:
            return
        leads = {a: box.value() for a, box in zip(AXES, self.leads, strict=True)
                 if box.value() > 0}
        try:
            edited = replace(machine, name=self.name.text().strip() or machine.name,
                             tool_offset_mm=tuple(b.value() for b in self.tool),
                             screw_lead_mm=leads)
            if edited != machine:
                self.document.set_machine(edited)
        except UserError as exc:
            show_error(self, "Machine", str(exc))


def _spin(low: float = -5000.0, high: float = 5000.0) -> QDoubleSpinBox:
    box = QDoubleSpinBox()
    box.setRange(low, high)
    box.setDecimals(3)
    box.setSuffix(" mm")
    return box
