"""Siemens SINUMERIK 840D: leadscrew error tables (``%_N_AX_EEC_INI``) and sag / cross-axis
tables (``%_N_NC_CEC_INI``).

Leadscrew / measuring system error compensation (Function Manual Extended Functions, K3,
"Interpolatory compensation", example ``%_N_AX_EEC_INI``): ``$AA_ENC_COMP[0,N,AXn]`` per
interpolation point in mm, ``$AA_ENC_COMP_STEP``, ``_MIN``, ``_MAX``, ``_IS_MODULO``, ``M17``. The
control modifies the axis' *actual value* by the compensation value: a positive value moves the
axis negative, so the table holds the error E at each node. It should be zero at the reference
point (no jump when compensation activates after referencing); volucal shifts the table to zero
there and reports the shift. Points are limited by MD38000 $MA_MM_ENC_COMP_MAX_POINTS.

Sag / cross-axis compensation (K3, ``%_N_NC_CEC_INI`` example): ``$AN_CEC[t,N]`` in mm,
``$AN_CEC_INPUT_AXIS[t]``, ``$AN_CEC_OUTPUT_AXIS[t]``, ``$AN_CEC_STEP``, ``_MIN``, ``_MAX``,
``$AN_CEC_DIRECTION[t]`` (0 both, 1 positive, −1 negative travel of the input axis),
``$AN_CEC_MULT_BY_TABLE``, ``$AN_CEC_IS_MODULO``. The value is superimposed on the output axis'
position (a correction, the opposite of the error), interpolated linearly, first/last value held
outside the table. volucal writes one table per (input, output) pair for straightness,
squareness along the axis lines and sag, and — where the source has reversal — two direction
tables per axis (input = output, direction +1 and −1; the manual's position-dependent backlash),
holding each direction's correction minus the mean already in the EEC table. Points per table:
MD18342 $MN_MM_CEC_MAX_POINTS[t].
"""

from __future__ import annotations

import numpy as np

from ..machine import AXES
from .controller import ControllerCompensation, LoadedTable
from .export_common import (
    ExportContext,
    ExporterOutput,
    TableLimitError,
    rounded,
    text_for_file,
    tool_line,
    write_text,
)
from .limits import check_count, check_positions, check_values, point_limit
from .tables import equidistant_spacing

CEC_MAX_POINTS = 2000  # MD18342 upper limit on 840D sl (assumed, not confirmed)
DECIMALS = 6  # mm
DEFAULT_NAMES = {"X": "AX1", "Y": "AX2", "Z": "AX3"}


def export(context: ExportContext) -> ExporterOutput:
    options = context.options
    tables = context.tables
    names = {a: options.axis_name(a, DEFAULT_NAMES[a]) for a in AXES}
    header = [
        f"; volucal compensation for {text_for_file(context.source.machine.name)}",
        f"; {tool_line(tables)}",
    ]
    eec = [
        "%_N_AX_EEC_INI",
        *header,
        "; values: error at the node (mm), zero at the reference",
        "CHANDATA(1)",
    ]
    loaded: list[LoadedTable] = []
    notes: list[str] = []
    machine = context.source.machine
    for axis in AXES:
        table = tables.axis[axis]
        nodes, step = _equidistant(table.position_mm, axis)
        label = f"the {axis} leadscrew table"
        limit = point_limit("siemens", options.max_points)
        check_count("siemens", label, len(nodes), limit, float(nodes[-1] - nodes[0]), step)
        check_positions("siemens", label, nodes)
        values = table.error_mean_um
        shift = float(np.interp(machine.reference(axis), nodes, values))
        if abs(shift) > 0.05:
            notes.append(
                f"{axis}: the leadscrew table was shifted by {-shift:+.2f} µm to be zero at the "
                f"reference point {machine.reference(axis):g} mm"
            )
        values_mm = rounded((values - shift) / 1e3, DECIMALS)
        check_values("siemens", label, nodes, values_mm)
        name = names[axis]
        eec += [f"$AA_ENC_COMP[0,{i},{name}]={v:.{DECIMALS}f}" for i, v in enumerate(values_mm)]
        eec += [
            f"$AA_ENC_COMP_STEP[0,{name}]={step:.{DECIMALS}f}",
            f"$AA_ENC_COMP_MIN[0,{name}]={nodes[0]:.{DECIMALS}f}",
            f"$AA_ENC_COMP_MAX[0,{name}]={nodes[-1]:.{DECIMALS}f}",
            f"$AA_ENC_COMP_IS_MODULO[0,{name}]=0",
        ]
        loaded.append(LoadedTable(axis, axis, nodes, values_mm * 1e3, indexed_by="actual"))
    eec.append("M17")
    files = [write_text(context.out_dir / "AX_EEC.INI", "\n".join(eec) + "\n")]

    cec_tables = []
    for axis in AXES:
        table = tables.axis[axis]
        if table.bidirectional:
            mean = table.correction_mean_um
            cec_tables.append(
                (axis, axis, table.position_mm, table.correction_forward_um - mean, 1)
            )
            cec_tables.append(
                (axis, axis, table.position_mm, table.correction_backward_um - mean, -1)
            )
    if options.include_cross:
        cec_tables += [
            (t.input_axis, t.output_axis, t.position_mm, t.correction_um, 0) for t in tables.cross
        ]
    if cec_tables:
        cec = [
            "%_N_NC_CEC_INI",
            *header,
            "; values: correction added to the output axis (mm); cross tables 0 at the reference",
            "CHANDATA(1)",
        ]
        for index, (inp, out, nodes_in, values, direction) in enumerate(cec_tables):
            nodes, step = _equidistant(nodes_in, inp)
            label = f"the {out}=f({inp}) table"
            limit = options.max_points or CEC_MAX_POINTS
            check_count(
                "siemens",
                label + " (Siemens CEC, MD18342)",
                len(nodes),
                limit,
                float(nodes[-1] - nodes[0]),
                step,
            )
            check_positions("siemens", label, nodes)
            values_mm = rounded(values / 1e3, DECIMALS)
            check_values("siemens", label, nodes, values_mm)
            cec += [f"$AN_CEC[{index},{i}]={v:.{DECIMALS}f}" for i, v in enumerate(values_mm)]
            cec += [
                f"$AN_CEC_INPUT_AXIS[{index}]=({names[inp]})",
                f"$AN_CEC_OUTPUT_AXIS[{index}]=({names[out]})",
                f"$AN_CEC_STEP[{index}]={step:.{DECIMALS}f}",
                f"$AN_CEC_MIN[{index}]={nodes[0]:.{DECIMALS}f}",
                f"$AN_CEC_MAX[{index}]={nodes[-1]:.{DECIMALS}f}",
                f"$AN_CEC_DIRECTION[{index}]={direction}",
                f"$AN_CEC_MULT_BY_TABLE[{index}]=0",
                f"$AN_CEC_IS_MODULO[{index}]=0",
            ]
            loaded.append(LoadedTable(inp, out, nodes, values_mm * 1e3, direction=direction))
        cec.append("M17")
        files.append(write_text(context.out_dir / "NC_CEC.INI", "\n".join(cec) + "\n"))
        notes.append(
            f"NC_CEC.INI holds {len(cec_tables)} tables: set MD18342 MM_CEC_MAX_POINTS[t] for "
            "each and enable them with MD32710 CEC_ENABLE and $SN_CEC_TABLE_ENABLE[t]"
        )
    notes.append(
        "AX_EEC.INI: set MD38000 MM_ENC_COMP_MAX_POINTS to at least the table size and enable "
        "with MD32700 ENC_COMP_ENABLE[0] = 1; load while compensation is disabled"
    )
    convention = (
        "AX_EEC.INI: $AA_ENC_COMP = error (actual - nominal) in mm at the node; a positive value "
        "moves the axis negative",
        "NC_CEC.INI: $AN_CEC = correction in mm added to the output axis (minus the error)",
    )
    return ExporterOutput(
        files=tuple(files),
        convention=convention,
        notes=tuple(notes),
        compensation=ControllerCompensation("Siemens EEC + CEC", tuple(loaded)),
    )


def _equidistant(nodes: np.ndarray, axis: str) -> tuple[np.ndarray, float]:
    step = equidistant_spacing(nodes)
    if step is None:
        raise TableLimitError(
            f"the {axis} table has unequal node spacing; Siemens tables need equidistant "
            "interpolation points (export with --spacing)"
        )
    return nodes, step
