"""``volucal identify PROJECT.h5``: identify the 21 errors from the project's measurements."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ..calibrate import _jsonable, identification_tree
from ..errors import ERROR_IDS, ERROR_INFO, error_label
from ..identify import IdentifyOptions, identify, parameters_report, residual_rms


def handle(args: argparse.Namespace) -> int:
    from ..project import Project, ProjectLock

    # Held from reading to saving: an import meanwhile is refused instead of being overwritten
    # by this command's older copy of the project.
    with ProjectLock(args.project):
        project = Project.open(args.project)
        measurement = project.measurement()
        result = identify(measurement, IdentifyOptions(spacing_mm=args.spacing))
        project.put_result("identifications", args.name, identification_tree(result))
        project.save(args.project)
    info = result.identifiability
    rms_um, rms_urad = residual_rms(result)
    if args.json:
        content = {
            "lines": len(measurement.lines),
            "readings": len(result.readings),
            "parameters": parameters_report(result),
            "identifiability": info.to_json(),
            "residual_rms_um": rms_um,
            "residual_rms_urad": rms_urad,
            "stored_as": f"/identifications/{args.name}",
        }
        json.dump(_jsonable(content), sys.stdout, indent=2)
        print()
        return 0
    print(
        f"{len(measurement.lines)} lines, {len(result.readings)} readings; "
        f"rank {info.rank} of {info.unknowns} unknowns"
    )
    print(f"{'error':<18} {'unit':<5} {'min':>9} {'max':>9} {'U95 max':>9}  identified")
    for eid in ERROR_IDS:
        _, value, std = result.band(eid)
        unit = "µm" if ERROR_INFO[eid].unit == "um" else "µrad"
        seen = "yes" if result.is_identified(eid) else "NO"
        print(
            f"{error_label(eid):<18} {unit:<5} {np.min(value):9.3f} {np.max(value):9.3f} "
            f"{2 * np.max(std):9.3f}  {seen}"
        )
    for item in info.unidentifiable:
        print(f"not identified: {item.message}")
    print(f"redundant lines: {len(info.redundant_lines)} of {len(measurement.lines)}")
    parts = [
        f"{value:.3f} {unit} ({kind})" if np.isfinite(value) else f"no {kind} line"
        for value, unit, kind in ((rms_um, "µm", "displacement"), (rms_urad, "µrad", "angular"))
    ]
    print(f"residual RMS {', '.join(parts)}")
    print(f"stored in {args.project} as /identifications/{args.name}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser(
        "identify",
        help="identify the 21 geometric errors from a project's measurements",
        description=(
            "Identify the 21 geometric errors (ISO 230-1 ids, µm and µrad) from every line in the "
            "project, with their 95 % uncertainty (U95 = 2 standard uncertainties, statistical and "
            "budget), the rank of the plan and what it cannot see; store the result in the project."
        ),
    )
    parser.add_argument("project", type=Path, metavar="PROJECT.h5")
    parser.add_argument(
        "--spacing",
        type=float,
        default=50.0,
        help="breakpoint spacing of the cubic B-spline basis, mm (default %(default)s)",
    )
    parser.add_argument(
        "--name", default="main", help="result name in the project (default %(default)s)"
    )
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.set_defaults(handler=handle)
