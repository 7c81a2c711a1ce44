"""Beckhoff TwinCAT CNC / ISG kernel: volumetric compensation from an ISG CSV file, and
bilateral leadscrew error compensation lists for reversal.

Volumetric compensation (Beckhoff TF5280, "ISG CSV format" and "List of parameters supported"):
a whitespace table whose header names the columns, ``//`` line comments, ``#`` starts a new block
with its own header. volucal writes one block of position errors (squareness, ISO 230-1
``C0Y``, ``B0Z``, ``A0Z``) and one block per axis with the argument and its six component errors
(``X EXX EYX EZX EAX EBX ECX``). ISG computes the volumetric correction from these errors with
its own kinematic model, so the file carries the error functions themselves (ISO 230-1 signs,
the error, not the correction). Units: mm and rad — the units of the Etalon exchange format the
same function accepts; check the control's unit setting before use.

Reversal (Beckhoff TF5200 axis compensation, leadscrew error compensation lists ``kw.ssfk.*``,
P-COMP-00017…00024): where the source has reversal, one list per axis with
``kw.ssfk.bilateral 1``, equidistant points (``interval``, ``kw_startpos``) in 0.1 µm and
``table[i].pos`` / ``table[i].neg`` in 0.1 µm. The manual's example enters the measured value
minus the set point (the error); volucal enters each direction's error minus the mean of both, so
the lists add to the volumetric compensation without counting positioning twice.
"""

from __future__ import annotations

import numpy as np

from ..errors import (
    SQUARENESS_IDS,
    ErrorFunction,
    ErrorModel,
    NodeTableBasis,
    axis_error_ids,
)
from ..machine import AXES
from ..userror import UserError
from .controller import ControllerCompensation, LoadedTable
from .export_common import (
    ExportContext,
    ExporterOutput,
    loaded_values,
    table_kinds_values,
    text_for_file,
    tool_line,
    write_text,
)
from .limits import check_count, check_finite, check_positions, check_values, point_limit
from .source import ModelSource, rigid_model
from .verify import ExactCompensation, SumCompensation

ISG_SQUARENESS = {"EC0Y": "C0Y", "EB0Z": "B0Z", "EA0Z": "A0Z"}
DEFAULT_LOGICAL = {"X": "1", "Y": "2", "Z": "3"}
TENTH_UM = 0.1


def export(context: ExportContext) -> ExporterOutput:
    options = context.options
    tables = context.tables
    model = rigid_model(context.source)
    if model is None:
        raise UserError(
            "the Beckhoff/ISG volumetric format carries the 21 error functions, and this error "
            "source does not expose its rigid-body model (.model); export a volumetric grid with "
            "--format csv or json instead"
        )
    machine = model.machine
    lines = [
        f"// volucal volumetric compensation data for {text_for_file(machine.name)}",
        f"// chain {machine.chain} (workpiece to tool); {tool_line(tables)}",
        "// units: mm (translations), rad (rotations); ISO 230-1 error signs",
        " ".join(ISG_SQUARENESS[s] for s in SQUARENESS_IDS),
        " ".join(f"{model.squareness_urad[s] * 1e-6:.9e}" for s in SQUARENESS_IDS),
    ]
    squareness = [model.squareness_urad[s] for s in SQUARENESS_IDS]
    check_finite("the squareness block", [0.0, 0.0, 0.0], squareness)
    for axis in AXES:
        nodes = tables.axis[axis].position_mm
        values = model.axis_values(axis, nodes)
        check_positions("isg", f"the {axis} block", nodes)
        for column in values.T:
            check_finite(f"the {axis} block", nodes, column)
        lines += ["#", " ".join([axis, *axis_error_ids(axis)])]
        for q, row in zip(nodes, values, strict=True):
            translations = [f"{v * 1e-3:.9e}" for v in row[:3]]
            rotations = [f"{v * 1e-6:.9e}" for v in row[3:]]
            lines.append(" ".join([f"{q:.6f}", *translations, *rotations]))
    files = [write_text(context.out_dir / "isg_volcomp.csv", "\n".join(lines) + "\n")]
    notes = [
        "isg_volcomp.csv carries the 21 rigid-body errors; configure the volumetric "
        f"compensation with the machine's chain ({machine.chain}) and tool point, and the "
        "file format ISG CSV"
    ]
    rigid = ModelSource(model)
    beyond = _beyond_rigid(context, rigid)
    loaded_model = ModelSource(_as_loaded(model, {a: tables.axis[a].position_mm for a in AXES}))
    if beyond > 0.1:
        notes.append(
            f"the error source has effects beyond the 21 rigid-body errors (up to {beyond:.2f} "
            "µm on the grid) that the ISG file cannot carry, apart from reversal"
        )
    loaded = []
    for axis in AXES:
        table = tables.axis[axis]
        if not table.bidirectional:
            continue
        nodes = table.position_mm
        step = table.spacing_mm
        assert step is not None
        label = f"the {axis} reversal list"
        limit = point_limit("isg", options.max_points)
        check_count("isg", label, len(nodes), limit, float(nodes[-1] - nodes[0]), step)
        check_positions("isg", label, nodes)
        check_values("isg", label + " (interval, start)", nodes[:2], [step * 1e4, nodes[0] * 1e4])
        mean = table.correction_mean_um
        pos_tenths = -(table.correction_forward_um - mean) / TENTH_UM
        neg_tenths = -(table.correction_backward_um - mean) / TENTH_UM
        check_values("isg", label, nodes, pos_tenths)
        check_values("isg", label, nodes, neg_tenths)
        pos = np.round(pos_tenths).astype(np.int64)
        neg = np.round(neg_tenths).astype(np.int64)
        logical = options.axis_name(axis, DEFAULT_LOGICAL[axis])
        text = [
            f"# volucal reversal compensation of {axis}: each direction's error minus the mean",
            f"# {tool_line(tables)}; values in 0.1 um",
            f"kopf.log_achs_nr                 {logical}",
            f"kopf.log_achs_name               {axis}",
            f"kw.ssfk.interval                 {round(step * 1e4)}",
            f"kw.ssfk.kw_startpos              {round(nodes[0] * 1e4)}",
            f"kw.ssfk.kw_nr_max                {len(nodes)}",
            "kw.ssfk.unit                     1",
            "kw.ssfk.bilateral                1",
            "kw.ssfk.modulo                   0",
        ]
        text += [f"kw.ssfk.table[{i}].pos           {v}" for i, v in enumerate(pos)]
        text += [f"kw.ssfk.table[{i}].neg           {v}" for i, v in enumerate(neg)]
        files.append(write_text(context.out_dir / f"achskw_{axis}.lis", "\n".join(text) + "\n"))
        loaded.append(LoadedTable(axis, axis, nodes, (-pos * TENTH_UM).astype(np.float64), 1))
        loaded.append(LoadedTable(axis, axis, nodes, (-neg * TENTH_UM).astype(np.float64), -1))
    if loaded:
        notes.append("achskw_<axis>.lis: activate with P-AXIS-00175 lr_param.ssfk = 1")
    volumetric = ExactCompensation(loaded_model, tables.tool_offset_mm)
    compensation = (
        SumCompensation(volumetric, ControllerCompensation("ISG reversal lists", tuple(loaded)))
        if loaded
        else volumetric
    )
    convention = (
        "isg_volcomp.csv: error functions (ISO 230-1), mm and rad; the control corrects",
        "achskw_<axis>.lis: bilateral lists, error minus the mean of both directions, 0.1 um",
    )
    # ISG computes the volumetric correction from the error functions itself: judge it on the
    # volumetric grid, and the reversal lists as loaded.
    applied = (*table_kinds_values(tables, ("grid",)), *loaded_values(tuple(loaded)))
    return ExporterOutput(
        files=tuple(files),
        convention=convention,
        notes=tuple(notes),
        compensation=compensation,
        applied=applied,
    )


def _as_loaded(model: ErrorModel, nodes: dict[str, np.ndarray]) -> ErrorModel:
    """The model as the control holds it: each error sampled at the rows of the file and
    interpolated linearly between them."""
    functions = {}
    for axis in AXES:
        basis = NodeTableBasis(tuple(float(q) for q in nodes[axis]))
        values = model.axis_values(axis, nodes[axis])
        for j, eid in enumerate(axis_error_ids(axis)):
            functions[eid] = ErrorFunction(eid, basis, values[:, j])
    return ErrorModel(model.machine, functions, dict(model.squareness_urad))


def _beyond_rigid(context: ExportContext, rigid: ModelSource) -> float:
    grid = context.tables.grid
    if grid is None:
        return 0.0
    points = grid.points_mm
    tool = context.tables.tool_offset_mm
    gap = context.source.error_um(points, None, tool) - rigid.error_um(points, None, tool)
    return float(np.max(np.abs(gap), initial=0.0))
