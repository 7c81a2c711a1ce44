"""Generic, controller-independent exports: CSV tables and one JSON document.

Both carry every table volucal computes, with both conventions side by side so nobody has to
guess a sign: ``error`` = actual − nominal (what a laser measures), ``correction`` = commanded −
nominal (what to add to the command; from the iterated inverse, about minus the error). Units are
in the column names (mm, µm written ``um``). ``beyond_measured_range`` is 1 where a node lies
outside the measured range (the values there are the end values held).

CSV files (comma separated, ``#`` comment lines first, then one header line):
``axis_tables.csv`` (axis, position_mm, error_forward_um, error_backward_um,
correction_forward_um, correction_backward_um, beyond_measured_range),
``cross_axis_tables.csv`` (input_axis, output_axis, position_mm, error_um, correction_um,
beyond_measured_range; zero at the input axis' reference) and ``volumetric_grid.csv`` (x_mm,
y_mm, z_mm, error_x_um … correction_z_um). JSON: ``compensation.json`` with the same content.
"""

from __future__ import annotations

import json

import numpy as np

from ..machine import AXES
from .controller import axis_compensation
from .export_common import ExportContext, ExporterOutput, text_for_file, tool_line, write_text

DECIMALS = 5  # µm: 10 pm, far below any machine's resolution; the files stay exact enough


def _header(context: ExportContext) -> list[str]:
    return [
        f"# volucal compensation tables for {text_for_file(context.source.machine.name)}",
        f"# {tool_line(context.tables)}",
        "# error = actual - nominal; correction = commanded - nominal (add to the command)",
    ]


def _f(value: float) -> str:
    return f"{round(float(value), DECIMALS) + 0.0:.{DECIMALS}f}"


def export_csv(context: ExportContext) -> ExporterOutput:
    tables = context.tables
    rows = [
        "axis,position_mm,error_forward_um,error_backward_um,correction_forward_um,"
        "correction_backward_um,beyond_measured_range"
    ]
    for axis in AXES:
        t = tables.axis[axis]
        for i, q in enumerate(t.position_mm):
            rows.append(
                ",".join(
                    [
                        axis,
                        f"{q:.6f}",
                        _f(t.error_forward_um[i]),
                        _f(t.error_backward_um[i]),
                        _f(t.correction_forward_um[i]),
                        _f(t.correction_backward_um[i]),
                        str(int(t.beyond_range[i])),
                    ]
                )
            )
    files = [
        write_text(context.out_dir / "axis_tables.csv", "\n".join(_header(context) + rows) + "\n")
    ]
    cross = ["input_axis,output_axis,position_mm,error_um,correction_um,beyond_measured_range"]
    for c in tables.cross:
        for i, q in enumerate(c.position_mm):
            cross.append(
                ",".join(
                    [
                        c.input_axis,
                        c.output_axis,
                        f"{q:.6f}",
                        _f(c.error_um[i]),
                        _f(c.correction_um[i]),
                        str(int(c.beyond_range[i])),
                    ]
                )
            )
    files.append(
        write_text(
            context.out_dir / "cross_axis_tables.csv", "\n".join(_header(context) + cross) + "\n"
        )
    )
    if tables.grid is not None:
        grid = tables.grid
        points = grid.points_mm
        error = grid.error_um.reshape(-1, 3)
        correction = grid.correction_um.reshape(-1, 3)
        lines = [
            "x_mm,y_mm,z_mm,error_x_um,error_y_um,error_z_um,correction_x_um,"
            "correction_y_um,correction_z_um"
        ]
        for point, e, corr in zip(points, error, correction, strict=True):
            lines.append(",".join([f"{v:.6f}" for v in point] + [_f(v) for v in (*e, *corr)]))
        files.append(
            write_text(
                context.out_dir / "volumetric_grid.csv", "\n".join(_header(context) + lines) + "\n"
            )
        )
    return ExporterOutput(
        files=tuple(files),
        convention=(
            "error = actual - nominal (um); correction = commanded - nominal (um), add it to "
            "the command; positions in mm",
        ),
        compensation=axis_compensation(tables, include_cross=False, name="generic axis tables"),
    )


def compensation_document(context: ExportContext) -> dict[str, object]:
    """The JSON document of :func:`export_json` (also usable in memory)."""
    tables = context.tables

    def array(values: np.ndarray) -> list[float]:
        return [round(float(v), DECIMALS) for v in np.ravel(values)]

    document: dict[str, object] = {
        "machine": context.source.machine.name,
        "tool_offset_mm": list(tables.tool_offset_mm),
        "axis_lines_through_mm": list(tables.line_mm),
        "convention": {
            "error": "actual - nominal, um",
            "correction": "commanded - nominal, um (add to the command)",
        },
        "axis_tables": {
            axis: {
                "position_mm": array(t.position_mm),
                "error_forward_um": array(t.error_forward_um),
                "error_backward_um": array(t.error_backward_um),
                "correction_forward_um": array(t.correction_forward_um),
                "correction_backward_um": array(t.correction_backward_um),
                "beyond_measured_range": [bool(b) for b in t.beyond_range],
                "measured_range_mm": list(t.measured_range_mm),
            }
            for axis, t in tables.axis.items()
        },
        "cross_axis_tables": [
            {
                "input_axis": t.input_axis,
                "output_axis": t.output_axis,
                "position_mm": array(t.position_mm),
                "error_um": array(t.error_um),
                "correction_um": array(t.correction_um),
                "beyond_measured_range": [bool(b) for b in t.beyond_range],
            }
            for t in tables.cross
        ],
        "flags": list(tables.flags),
    }
    if tables.grid is not None:
        grid = tables.grid
        document["volumetric_grid"] = {
            "x_mm": array(grid.x_mm),
            "y_mm": array(grid.y_mm),
            "z_mm": array(grid.z_mm),
            "spacing_mm": grid.spacing_mm,
            "layout": "error_um and correction_um: [ix][iy][iz][component], C order",
            "error_um": np.round(grid.error_um, DECIMALS).tolist(),
            "correction_um": np.round(grid.correction_um, DECIMALS).tolist(),
        }
    return document


def export_json(context: ExportContext) -> ExporterOutput:
    document = compensation_document(context)
    path = write_text(context.out_dir / "compensation.json", json.dumps(document, indent=1) + "\n")
    return ExporterOutput(
        files=(path,),
        convention=(
            "compensation.json: error = actual - nominal, correction = commanded - "
            "nominal, um; positions mm",
        ),
        compensation=axis_compensation(tables=context.tables, name="generic axis tables"),
    )
