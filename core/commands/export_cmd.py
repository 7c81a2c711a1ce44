"""``volucal export PROJECT.h5 --format F --out DIR``: compensation files for a controller.

Everything except reading the project is :func:`volucal.core.compensation.export_model`; this
module parses the options, loads the identified model from the project and prints the result.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..compensation import (
    DEFAULT_MAX_CORRECTION_UM,
    FORMATS,
    ExportOptions,
    ExportResult,
    export_model,
)
from ..compensation.export import FORMAT_HELP, SELF_EXACT_METHODS
from ..compensation.ncprogram import WORK_OFFSETS, RewriteOptions
from ..compensation.source import ErrorSource
from ..compensation.verify import rate_text
from ..machine import AXES
from ..userror import UserError


def add_correction_limit(parser: argparse.ArgumentParser) -> None:
    """The plausibility limit of exported corrections and its explicit override (shared by
    ``export``, ``calibrate`` and ``demo``)."""
    large = parser.add_mutually_exclusive_group()
    large.add_argument(
        "--max-correction-um",
        type=float,
        default=DEFAULT_MAX_CORRECTION_UM,
        metavar="UM",
        help="refuse to export a correction larger than this, um (default %(default)g): a "
        "larger one points to a wrong identification",
    )
    large.add_argument(
        "--allow-large-corrections",
        action="store_true",
        help="export corrections of any size (the machine really needs more than "
        "--max-correction-um)",
    )


def correction_limit(args: argparse.Namespace) -> float | None:
    """The limit the options ask for (None: no limit)."""
    return None if args.allow_large_corrections else args.max_correction_um


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "export",
        help="write compensation tables for a controller (or rewrite an NC program)",
        description=(
            "Write compensation for a controller from a project's identification (the closed "
            "loop's, else the latest): its 21 errors with the loop's kept machine effects, the "
            "same tables as volucal calibrate --export writes. Formats: "
            + "; ".join(f"{name}: {text}" for name, text in FORMAT_HELP.items())
            + ". Every export also writes volucal_export.json (units, signs, tool offset, flags, "
            "predicted compensation rates). Every table is checked against the controller's "
            "limits and every correction against --max-correction-um before anything is "
            "written; a refused export leaves DIR as it was."
        ),
    )
    parser.add_argument("project", type=Path, help="the volucal project (.h5)")
    parser.add_argument("--format", required=True, choices=sorted(FORMATS), dest="format")
    parser.add_argument("--out", required=True, type=Path, help="output folder (created)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument("--identification", help="which identification of the project (latest)")
    parser.add_argument("--spacing", type=float, default=10.0, help="table spacing, mm (10)")
    parser.add_argument(
        "--tool-offset",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="tool offset the tables are for, mm (default: the machine's)",
    )
    parser.add_argument(
        "--grid-spacing",
        type=float,
        default=25.0,
        help="volumetric grid and verification grid spacing, mm (25)",
    )
    parser.add_argument(
        "--axis-names",
        metavar="X=NAME,Y=NAME,Z=NAME",
        help="the controller's names of the axes (LinuxCNC joint numbers, Siemens AX1, Fanuc "
        "axis numbers, ISG logical axis numbers, Heidenhain keys)",
    )
    parser.add_argument(
        "--max-points",
        type=int,
        help="the controller's point limit where it differs from the documented one (a "
        "configured MD38000, a larger ISG list); never beyond a fixed limit (LinuxCNC and "
        "Heidenhain 256, Fanuc point numbers 0..1023)",
    )
    add_correction_limit(parser)
    parser.add_argument(
        "--no-cross", action="store_true", help="leave out cross-axis tables (Siemens, Heidenhain)"
    )
    parser.add_argument(
        "--linuxcnc-type",
        type=int,
        choices=(0, 1),
        default=0,
        help="LinuxCNC COMP_FILE_TYPE (0: actual positions, 1: offsets)",
    )
    parser.add_argument(
        "--detection-unit", type=float, default=1.0, help="Fanuc detection unit, um (1)"
    )
    parser.add_argument("--program", type=Path, help="gcode: the RS274/NGC program to rewrite")
    parser.add_argument(
        "--correction-tolerance",
        type=float,
        default=0.1,
        help="gcode: split feed moves to follow the correction within this, um",
    )
    parser.add_argument(
        "--arc-tolerance",
        type=float,
        default=0.001,
        help="gcode: chord tolerance when linearising arcs, mm",
    )
    parser.add_argument(
        "--work-offset",
        action="append",
        default=[],
        metavar="G54=X,Y,Z",
        help="gcode: a work offset of the machine, mm (repeat for each one used)",
    )
    parser.add_argument(
        "--pass-unknown",
        action="store_true",
        help="gcode: copy unsupported lines unchanged (flagged) instead of refusing",
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    options = ExportOptions(
        spacing_mm=args.spacing,
        tool_offset_mm=tuple(args.tool_offset) if args.tool_offset else None,
        grid_spacing_mm=args.grid_spacing,
        axis_names=_axis_names(args.axis_names),
        max_points=args.max_points,
        include_cross=not args.no_cross,
        linuxcnc_type=args.linuxcnc_type,
        fanuc_detection_unit_um=args.detection_unit,
        program=args.program,
        rewrite=RewriteOptions(
            correction_tolerance_um=args.correction_tolerance,
            arc_tolerance_mm=args.arc_tolerance,
            work_offsets_mm=_work_offsets(args.work_offset),
            unknown="pass" if args.pass_unknown else "refuse",
        ),
        max_correction_um=correction_limit(args),
    )
    source = load_source(args.project, args.identification)
    result = export_model(source, args.format, args.out, options)
    if args.json:
        document = result.to_json()
        document["files"] = [str(p) for p in result.files]
        print(json.dumps(document, indent=1))
    else:
        print(_text(result))
    return 0


def load_source(path: Path, identification: str | None = None) -> ErrorSource:
    """Identification ``identification`` of a project (the loop's, else the latest) as the
    error source ``volucal calibrate --export`` used (:func:`~volucal.core.result_trees.
    stored_source`): its 21 errors with the loop's kept machine effects, over its measured
    range."""
    try:
        from .. import project as project_module
    except ImportError:
        raise UserError(
            f"{path}: reading projects needs volucal.core.project, which this installation lacks"
        ) from None
    project = project_module.Project.open(path)
    names = list(project.results("identifications"))
    if not names:
        raise UserError(
            f"{path}: the project has no identification yet; run `volucal identify {path}` first"
        )
    # The closed loop's final identification ("loop") when there is one: it has the kept
    # effects; otherwise the latest.
    name = identification or ("loop" if "loop" in names else names[-1])
    if name not in names:
        raise UserError(
            f"{path}: no identification named {name!r}; the project has {', '.join(names)}"
        )
    if project.machine is None:
        raise UserError(f"{path}: the project has no machine; import a plan first")
    from ..result_trees import stored_source

    try:
        return stored_source(project, name)
    except UserError as exc:
        raise UserError(f"{path}: {exc}") from None


def _axis_names(text: str | None) -> dict[str, str] | None:
    if not text:
        return None
    names = {}
    for item in text.split(","):
        axis, _, name = item.partition("=")
        axis = axis.strip().upper()
        if axis not in AXES or not name.strip():
            raise UserError(f"--axis-names: expected X=NAME,Y=NAME,Z=NAME, got {item!r}")
        names[axis] = name.strip()
    return names


def _work_offsets(items: list[str]) -> dict[str, tuple[float, float, float]]:
    offsets = {}
    for item in items:
        code, _, values = item.partition("=")
        code = code.strip().upper()
        parts = values.split(",")
        if code not in WORK_OFFSETS or len(parts) != 3:
            raise UserError(f"--work-offset: expected G54=X,Y,Z (G54..G59), got {item!r}")
        try:
            x, y, z = (float(p) for p in parts)
        except ValueError:
            raise UserError(f"--work-offset: {item!r} has a value that is not a number") from None
        offsets[code] = (x, y, z)
    return offsets


def _text(result: ExportResult) -> str:
    t = result.tool_offset_mm
    lines = [f"{result.format} export in {result.out_dir}:"]
    lines += [f"  {p.name}" for p in result.files]
    lines.append(f"tool offset assumed: {t[0]:g} {t[1]:g} {t[2]:g} mm")
    lines += [f"convention: {c}" for c in result.convention]
    lines.append("predicted compensation rates (RMS-based, % per direction X / Y / Z):")
    for name, method in result.verification.methods.items():
        if name in SELF_EXACT_METHODS:
            # the model's inverse against the model: 100 % by construction, no prediction
            lines.append(
                f"  {name:<30} {'not predicted':<21}   {method.description} (the model's own "
                "inverse: exact on the model by construction; rated only by re-measuring)"
            )
            continue
        rates = method.rates.rms_percent
        values = " / ".join(rate_text(rates[a]) for a in AXES)
        lines.append(f"  {name:<30} {values}   {method.description}")
    lines += [f"note: {n}" for n in result.notes]
    lines += [f"flag: {f}" for f in result.flags]
    return "\n".join(lines)
