"""``volucal calibrate PLAN.toml --project OUT.h5 --report OUT.json``: the whole loop."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from ..calibrate import (
    CalibrationRequest,
    CalibrationResult,
    _jsonable,
    calibrate,
    summary_table,
    write_json_atomic,
)
from ..residuals import LoopOptions
from .export_cmd import add_correction_limit, correction_limit
from .progress_bar import ProgressBar

FORMATS = ("linuxcnc", "siemens", "fanuc", "heidenhain", "isg", "csv", "json", "gcode")


def add_run_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--export", metavar="DIR", type=Path, help="write compensation files into DIR/<format>/"
    )
    parser.add_argument(
        "--format",
        dest="formats",
        action="append",
        choices=FORMATS,
        help="compensation format to export (repeat; default: linuxcnc and csv)",
    )
    add_correction_limit(parser)
    parser.add_argument(
        "--files-root",
        type=Path,
        metavar="DIR",
        help="allow the plan's files to lie anywhere under DIR (default: the plan's own folder)",
    )
    parser.add_argument("--no-sensitivity", action="store_true", help="skip the EFAST ranking")
    parser.add_argument(
        "--margin",
        type=float,
        default=LoopOptions().margin,
        help="relative cross-validated improvement an effect must bring to be kept, and a "
        "richer variant of a kept structure (a surface of higher order, ...) over the leaner "
        "one (default %(default)s)",
    )
    parser.add_argument(
        "--spacing",
        type=_spacing,
        metavar="MM",
        help="breakpoint spacing of the 21 errors' cubic B-spline basis, mm (default: the one of "
        f"{', '.join(f'{s:g}' for s in LoopOptions().spacings_mm)} mm that cross-validates best)",
    )
    parser.add_argument(
        "--drop-outliers",
        action="store_true",
        help="leave out readings flagged as outliers (they are only flagged otherwise)",
    )
    parser.add_argument("--json", action="store_true", help="print report.json to stdout")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")


def _spacing(text: str) -> float:
    """``--spacing``: a positive length in mm."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of mm") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"{text} mm: give a spacing above 0 mm, e.g. 50")
    return value


def loop_options(args: argparse.Namespace) -> LoopOptions:
    """The loop's options from the command line: ``--spacing`` fixes the basis."""
    options = LoopOptions(margin=args.margin)
    if args.spacing is None:
        return options
    return replace(
        options, spacings_mm=(), identify=replace(options.identify, spacing_mm=args.spacing)
    )


def run(
    args: argparse.Namespace,
    plan: Path,
    project: Path | None,
    report: Path | None,
    export: Path | None,
    after: Callable[[CalibrationResult], str] | None = None,
) -> int:
    """Calibrate, then ``after`` (the demo's verification) may extend the report and returns
    text to print below the summary."""
    request = CalibrationRequest(
        plan_path=plan,
        project_path=project,
        report_path=report,
        export_dir=export,
        export_formats=tuple(args.formats or ("linuxcnc", "csv")),
        max_correction_um=correction_limit(args),
        files_root=getattr(args, "files_root", None),
        loop=loop_options(args),
        sensitivity=not args.no_sensitivity,
        drop_outliers=args.drop_outliers,
    )
    bar = None if args.quiet or args.json else ProgressBar()
    result = calibrate(request, progress=bar)
    extra = after(result) if after else ""
    if bar:
        bar.close()
    if extra and report is not None:
        write_json_atomic(report, result.report)
    if extra and project is not None:
        store_compensation(project, result.report["compensation"])
    if args.json:
        json.dump(_jsonable(result.report), sys.stdout, indent=2)
        print()
        # stdout is the report; what a user must read still reaches the console
        for warning in result.report.get("warnings", []):
            print(f"warning: {warning}", file=sys.stderr)
    else:
        print(summary_table(result.report))
        if extra:
            print(extra)
        for path, what in (
            (project, "project"),
            (report, "report"),
            (export, "compensation files"),
        ):
            if path is not None:
                print(f"{what}: {path}")
    return 0


def store_compensation(project_path: Path, compensation: dict) -> None:  # type: ignore[type-arg]
    """Replace the project's compensation result (e.g. with the demo's verified rates)."""
    from ..project import Project, ProjectLock

    with ProjectLock(project_path):  # from reading to saving: no other writer's change is lost
        project = Project.open(project_path)
        project.put_result(
            "compensation", "main", {"report_json": json.dumps(_jsonable(compensation))}
        )
        project.save(project_path)


def handle(args: argparse.Namespace) -> int:
    return run(args, args.plan, args.project, args.report, args.export)


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser(
        "calibrate",
        help="import, identify, close the loop, rank and compensate",
        description=(
            "Run the whole job on a plan: import the logs, identify the 21 geometric errors, "
            "close the loop on the residual (effects the 21-error model lacks), rank the errors "
            "by EFAST sensitivity and predict (and optionally export) the compensation."
        ),
    )
    parser.add_argument("plan", type=Path, metavar="PLAN.toml")
    parser.add_argument("--project", type=Path, metavar="OUT.h5", help="write the HDF5 project")
    parser.add_argument("--report", type=Path, metavar="OUT.json", help="write report.json")
    add_run_options(parser)
    parser.set_defaults(handler=handle)
