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
from volucal.core.conformance import QUANTITIES
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
    written = write_report(
        args.project,
        args.output,
        tolerance_um=args.tolerance_um,
        tolerance_on=args.tolerance_on,
        compensation_dir=args.compensation,
        report_json=args.report_json,
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


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser(
        "report",
        help="write the calibration report of a project as a PDF",
        description=(
            "Write the calibration report of PROJECT.h5 as a PDF: the machine, the measurement "
            "plan, ISO 230-2 values per line, the identified errors with their uncertainty, the "
            "closed loop's steps, the sensitivity ranking, the compensation files with their "
            "checksums and the predicted and verified rates, traceability from the logs, the "
            "uncertainty statement and, with --tolerance-um, a conformance decision in the "
            "manner of ISO 14253-1. Needs the gui extra (Qt writes the PDF)."
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
    parser.add_argument("--json", action="store_true",
                        help="print the report's content (every section, table and curve, the "
                             "sources and the conformance decision) as JSON")
    parser.set_defaults(handler=handle)
