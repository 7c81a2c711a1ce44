"""LinuxCNC joint screw compensation: one COMP_FILE per joint and a ``comp.ini`` snippet.

Format (LinuxCNC INI documentation, ``[JOINT_n]`` COMP_FILE / COMP_FILE_TYPE; REFERENCE.md §6):
one ``nominal forward reverse`` triplet per line, in machine units (mm here), ascending nominal,
at most 256 lines. The loader stops at the first line that is not three numbers, so the files
carry no header; what they assume is stated in ``comp.ini`` and in the export manifest.

- COMP_FILE_TYPE 0: forward and reverse are the *actual* positions reached when the joint moves
  positive / negative; LinuxCNC adds ``nominal − actual``. volucal writes
  ``actual = nominal − correction``.
- COMP_FILE_TYPE 1: forward and reverse are the offsets added to the command: the correction.

The correction is the iterated inverse at each nominal (LinuxCNC indexes its table by the
commanded joint position). Between lines LinuxCNC interpolates linearly and holds the end values
outside the table; BACKLASH is ignored when a COMP_FILE is set, so reversal goes in the
forward/reverse columns. Joint compensation acts along each joint only: straightness,
squareness and cross-axis errors are left (the export reports how much).
"""

from __future__ import annotations

import numpy as np

from ..machine import AXES
from ..userror import UserError
from .controller import ControllerCompensation, LoadedTable
from .export_common import (
    ExportContext,
    ExporterOutput,
    rounded,
    text_for_file,
    tool_line,
    write_text,
)
from .limits import check_count, check_positions, check_values, point_limit

DECIMALS = 6  # mm: nanometres, below anything LinuxCNC's servo loop resolves
DEFAULT_JOINTS = {"X": "0", "Y": "1", "Z": "2"}  # trivkins


def export(context: ExportContext) -> ExporterOutput:
    options = context.options
    file_type = options.linuxcnc_type
    if file_type not in (0, 1):
        raise UserError(f"LinuxCNC COMP_FILE_TYPE must be 0 or 1, got {file_type}")
    limit = point_limit("linuxcnc", options.max_points)
    files = []
    loaded = []
    ini = [
        f"# volucal joint compensation (COMP_FILE_TYPE {file_type}) for "
        f"{text_for_file(context.source.machine.name)}",
        f"# {tool_line(context.tables)}",
        "# Values in mm. Joint compensation corrects each joint along its own axis only;",
        "# straightness, squareness and cross-axis errors are not corrected by these files.",
    ]
    for axis in AXES:
        table = context.tables.axis[axis]
        nodes = table.position_mm
        spacing = table.spacing_mm or float(np.max(np.diff(nodes)))
        label = f"the {axis} table"
        check_count("linuxcnc", label, len(nodes), limit, float(nodes[-1] - nodes[0]), spacing)
        check_positions("linuxcnc", label, nodes)
        forward = rounded(table.correction_forward_um / 1e3, DECIMALS)
        backward = rounded(table.correction_backward_um / 1e3, DECIMALS)
        if file_type == 0:
            columns = (nodes - forward, nodes - backward)
        else:
            columns = (forward, backward)
        for column in columns:
            check_values("linuxcnc", label, nodes, column)
        lines = [
            f"{n:.{DECIMALS}f} {a:.{DECIMALS}f} {b:.{DECIMALS}f}"
            for n, a, b in zip(nodes, *columns, strict=True)
        ]
        joint = options.axis_name(axis, DEFAULT_JOINTS[axis])
        name = f"joint{joint}_{axis}.comp"
        files.append(write_text(context.out_dir / name, "\n".join(lines) + "\n"))
        ini += ["", f"[JOINT_{joint}]", f"COMP_FILE = {name}", f"COMP_FILE_TYPE = {file_type}"]
        loaded.append(LoadedTable(axis, axis, nodes, forward * 1e3, direction=1))
        loaded.append(LoadedTable(axis, axis, nodes, backward * 1e3, direction=-1))
    files.append(write_text(context.out_dir / "comp.ini", "\n".join(ini) + "\n"))
    convention = (
        "COMP_FILE type 0: nominal, actual position moving positive, actual position moving "
        "negative (mm); LinuxCNC adds nominal - actual"
        if file_type == 0
        else "COMP_FILE type 1: nominal, offset added moving positive, offset added moving "
        "negative (mm)",
        "comp.ini: [JOINT_n] sections naming the files (paste into the machine's INI)",
    )
    notes = (
        "LinuxCNC joint compensation corrects each axis along itself only: straightness, "
        "squareness and cross-axis errors are left (see the predicted rates)",
    )
    return ExporterOutput(
        files=tuple(files),
        convention=convention,
        notes=notes,
        compensation=ControllerCompensation("LinuxCNC joint COMP_FILE", tuple(loaded)),
    )
