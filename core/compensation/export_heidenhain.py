"""Heidenhain nonlinear axis error compensation: ``.COM`` tables assigned in a ``.CMA`` file.

HEIDENHAIN technical manuals (TNC 407/415/425 "Non-linear axis error compensation";
MANUALplus 620 / TNC 6xx "Entering compensation values", "Assigning the compensation value
tables to the axes"):

- A ``.COM`` table lists compensation points: column ``AXISPOS`` the position of the axis the
  table depends on (machine datum), then one column per axis whose error depends on it, named by
  the axis key, and ``BACKLASH`` for the values of the negative direction of traverse. General
  relationship of the ``.CMA``: [axis of a column in the .COM] = F(axis of the .CMA column in
  which the .COM is entered). At most 256 entries per ``.COM`` (module 9095, error 3).
- The manuals plot and enter the *error* curve (e.g. "Error in Z" for sag as a function of Y),
  starting at 0 at the datum; volucal writes the error (actual − nominal, mm, four decimals:
  0.1 µm) at the commanded position, i.e. minus the iterated correction.
- ``BACKLASH``: volucal writes the difference between the negative and the positive direction
  (position-dependent reversal), and 0 where the source has no reversal. The manual's wording
  ("compensation values measured in the negative direction") leaves open whether the control
  expects this difference or the full negative-direction value: check on the control before use.

Files: ``X.COM``, ``Y.COM``, ``Z.COM`` (each holding the own positioning error and, unless cross
tables are off, the other two axes' errors along that axis) and ``VOLUCAL.CMA`` with one active
line assigning them.
"""

from __future__ import annotations

import numpy as np

from ..machine import AXES
from .controller import ControllerCompensation, LoadedTable
from .export_common import (
    ExportContext,
    ExporterOutput,
    rounded,
    tool_line,
    write_text,
)
from .limits import check_count, check_positions, check_values, point_limit

DECIMALS = 4  # mm: 0.1 µm


def export(context: ExportContext) -> ExporterOutput:
    options = context.options
    tables = context.tables
    names = {a: options.axis_name(a, a) for a in AXES}
    files = []
    loaded: list[LoadedTable] = []
    for axis in AXES:
        table = tables.axis[axis]
        nodes = table.position_mm
        spacing = table.spacing_mm or float(np.max(np.diff(nodes)))
        label = f"the {axis} table"
        limit = point_limit("heidenhain", options.max_points)
        check_count("heidenhain", label, len(nodes), limit, float(nodes[-1] - nodes[0]), spacing)
        check_positions("heidenhain", label, nodes)
        if table.bidirectional:
            own = -table.correction_forward_um
            backlash = table.correction_forward_um - table.correction_backward_um
        else:
            own = -table.correction_mean_um
            backlash = np.zeros_like(own)
        columns = {axis: own}
        if options.include_cross:
            for output in AXES:
                if output != axis:
                    columns[output] = -context.tables.cross_table(axis, output).correction_um
        ordered = [a for a in AXES if a in columns]
        values = {a: rounded(columns[a] / 1e3, DECIMALS) for a in ordered}
        backlash_mm = rounded(backlash / 1e3, DECIMALS)
        for column in (*values.values(), backlash_mm):
            check_values("heidenhain", label, nodes, column)
        header = ["NR", "AXISPOS", "BACKLASH", *[names[a] for a in ordered]]
        width = 12
        lines = [
            f"BEGIN {names[axis]}.COM MM",
            "".join(f"{h:<{width}}" for h in header).rstrip(),
        ]
        for i, position in enumerate(nodes):
            cells = [str(i), _signed(position, DECIMALS), _signed(backlash_mm[i], DECIMALS)]
            cells += [_signed(values[a][i], DECIMALS) for a in ordered]
            lines.append("".join(f"{c:<{width}}" for c in cells).rstrip())
        lines.append("[END]")
        files.append(write_text(context.out_dir / f"{names[axis]}.COM", "\n".join(lines) + "\n"))
        for output in ordered:
            loaded.append(LoadedTable(axis, output, nodes, -values[output] * 1e3))
        if table.bidirectional:
            loaded.append(LoadedTable(axis, axis, nodes, -backlash_mm * 1e3, direction=-1))
    cma_header = ["NR", *[names[a] for a in AXES], "ACTIVE"]
    cma = [
        "BEGIN VOLUCAL.CMA",
        "".join(f"{h:<10}" for h in cma_header).rstrip(),
        "".join(f"{c:<10}" for c in ["0", *[f"{names[a]}.COM" for a in AXES], "*"]).rstrip(),
        "[END]",
    ]
    files.append(write_text(context.out_dir / "VOLUCAL.CMA", "\n".join(cma) + "\n"))
    convention = (
        ".COM: AXISPOS (mm, machine datum), per axis column the error actual - nominal (mm) "
        "as a function of AXISPOS; BACKLASH = negative-direction minus positive-direction error",
        ".CMA: one active line; the .COM in column A holds errors that depend on axis A",
    )
    notes = (
        f"the tables carry no comment field: {tool_line(tables)} (see volucal_export.json)",
        "BACKLASH holds the difference between the directions; confirm on the control that it "
        "expects a difference rather than the full negative-direction values",
    )
    return ExporterOutput(
        files=tuple(files),
        convention=convention,
        notes=notes,
        compensation=ControllerCompensation("Heidenhain .COM/.CMA", tuple(loaded)),
    )


def _signed(value: float, decimals: int) -> str:
    if abs(value) < 0.5 * 10.0**-decimals:
        value = 0.0
    return f"{value:+.{decimals}f}"
