"""``volucal report PROJECT.h5 -o FILE.pdf``: the calibration report as a PDF.

The PDF is written with Qt's own PDF writer, so the command needs the ``gui`` extra (PySide6); the
workbench module is imported inside the handler and a missing Qt is a message, not a traceback.
Without a display Qt runs on its offscreen platform.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from volucal.core.calibrate import _jsonable
from volucal.core.certificate import FIELDS, KEYS, Certificate
from volucal.core.conformance import QUANTITIES
from volucal.core.display_units import ANGLE_UNITS, LENGTH_UNITS, DisplayUnits
from volucal.core.tolerances import Tolerances
from volucal.core.userror import UserError

from . import installed

QT_MISSING = "the PDF report is written with Qt: install the gui extra (pip install 'volucal[gui]')"


def handle(args: argparse.Namespace) -> int:
    if not installed("PySide6"):
        raise UserError(QT_MISSING)
    if args.tolerance_um is not None and not args.tolerance_um > 0:
        raise UserError(f"--tolerance-um {args.tolerance_um}: give a positive number of µm")
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    try:
        from volucal.app.report import write_report
    except ImportError as exc:  # a broken Qt installation (missing system libraries)
        raise UserError(f"{QT_MISSING} ({exc})") from None
    certificate = Certificate({key: getattr(args, key) for key in KEYS
                               if getattr(args, key) is not None})
    written = write_report(
        args.project,
        args.output,
        tolerance_um=args.tolerance_um,
        tolerance_on=args.tolerance_on,
        compensation_dir=args.compensation,
        report_json=args.report_json,
        certificate=certificate,
        tolerances=_tolerances(args.axis_tolerance) if args.axis_tolerance else None,
        remeasurement=args.remeasurement,
        units=DisplayUnits(args.length_unit, args.angle_unit),
    )
    conformance = written.content.conformance
    if args.json:
        json.dump(_jsonable({"pdf": str(written.path), "pages": written.pages,
                             "report": written.content.to_json()}), sys.stdout, indent=2)
        print()
        return 0
    print(f"report: {written.path} ({written.pages} pages)")
    for section in written.content.sections:
        print(f"  {section.title}")
    if conformance is not None:
        print(f"conformance (ISO 14253-1, {conformance.quantity}, T = "
              f"{conformance.tolerance_um:g} µm): {conformance.verdict}")
    return 0


def _tolerances(items: list[str]) -> Tolerances:
    """``AXIS:VALUE=LIMIT`` items (µm), e.g. ``X:A=12``, as tolerances per axis."""
    limits: dict[str, dict[str, float]] = {}
    for item in items:
        where, _, text = item.partition("=")
        axis, _, quantity = where.partition(":")
        try:
            value = float(text)
        except ValueError:
            raise UserError(f"--axis-tolerance {item}: expected AXIS:VALUE=LIMIT in µm, e.g. "
                            "X:A=12") from None
        limits.setdefault(axis.strip().upper(), {})[quantity.strip().upper()] = value
    return Tolerances(limits)


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser(
        "report",
        help="write the calibration report of a project as a PDF",
        description=(
            "Write the calibration report of PROJECT.h5 as a PDF: the machine, the measurement "
            "plan, ISO 230-2 values per line, the identified errors with their uncertainty, the "
            "closed loop's steps, the sensitivity ranking, the compensation files with their "
            "checksums and the predicted and verified rates, traceability from the logs, the "
            "uncertainty statement, the certificate fields and a signature block; the ISO 230-2 "
            "graph of each axis and, with tolerances per axis, their pass/fail; with "
            "--remeasurement the compensated machine measured again; with --tolerance-um, a "
            "conformance decision in the manner of ISO 14253-1. Needs the gui extra (Qt writes "
            "the PDF)."
        ),
    )
    parser.add_argument("project", type=Path, metavar="PROJECT.h5")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="FILE.pdf",
                        help="the PDF to write")
    parser.add_argument("--tolerance-um", type=float, metavar="T",
                        help="decide conformance with this tolerance (µm), ISO 14253-1 rules")
    parser.add_argument("--tolerance-on", choices=QUANTITIES, default="accuracy",
                        help="the quantity the tolerance applies to: accuracy = ISO 230-2 A of "
                             "each linear line, volumetric = the largest |E| over the workspace "
                             "(default: %(default)s)")
    parser.add_argument("--compensation", type=Path, metavar="DIR",
                        help="folder of the compensation files, for their checksums (default: "
                             "the folder recorded in the project, else DIR/compensation beside "
                             "the project)")
    parser.add_argument("--report-json", type=Path, metavar="FILE",
                        help="the run's report.json, for verified compensation rates the "
                             "project does not hold (default: report.json beside the project, "
                             "when it is of the same run)")
    parser.add_argument("--axis-tolerance", action="append", metavar="AXIS:VALUE=LIMIT",
                        help="an ISO 230-2 limit of an axis in µm (VALUE one of A, E, R, B, M), "
                             "e.g. X:A=12; repeat for more; replaces the limits kept in the "
                             "project (the workbench's Edit ▸ Tolerances)")
    parser.add_argument("--remeasurement", type=Path, metavar="AFTER.h5",
                        help="a project of the same lines measured again on the compensated "
                             "machine: its ISO 230-2 values and compensation rates beside the "
                             "original")
    parser.add_argument("--length-unit", choices=tuple(LENGTH_UNITS), default="um",
                        help="unit of the deviations shown (default: %(default)s)")
    parser.add_argument("--angle-unit", choices=tuple(ANGLE_UNITS), default="urad",
                        help="unit of the angles shown (default: %(default)s)")
    certificate = parser.add_argument_group(
        "certificate", "fields of the certificate; each replaces what the project keeps (the "
        "workbench's report dialog) or what the logs say")
    for key, label in FIELDS:
        certificate.add_argument(f"--{key.replace('_', '-')}", dest=key, metavar="TEXT",
                                 help=label.lower())
    parser.add_argument("--json", action="store_true",
                        help="print the report's content (every section, table and curve, the "
                             "sources and the conformance decision) as JSON")
    parser.set_defaults(handler=handle)
