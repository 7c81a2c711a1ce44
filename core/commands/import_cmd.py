"""``volucal import PROJECT.h5 PLAN.toml``: read every line of a plan into a project.

Creates the project when it does not exist, otherwise adds the lines to it. Prints the lines and
readings imported, the sign convention each line was read with, the corrections applied, and every
outlier flag with its reason; flagged readings are kept unless ``--drop-outliers`` is given. The
plan's files are read from its own folder only, unless ``--files-root`` allows another.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from ..io.plan import ImportResult, import_plan, load_plan
from ..project import Project, ProjectLock


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "import",
        help="import the logs of a plan into a project (creates it or adds to it)",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument("project", type=Path, metavar="PROJECT.h5")
    parser.add_argument("plan", type=Path, metavar="PLAN.toml")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.add_argument(
        "--drop-outliers",
        action="store_true",
        help="set the readings (or runs) flagged as outliers to missing; by default they are "
        "kept and only reported",
    )
    parser.add_argument(
        "--replace", action="store_true", help="replace lines the project already has"
    )
    parser.add_argument(
        "--files-root",
        type=Path,
        metavar="DIR",
        help="let the plan read files under DIR (default: only the plan's own folder; a file "
        "outside it, through '..', an absolute path or a symbolic link, is refused)",
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    plan = load_plan(args.plan, files_root=args.files_root)
    result = import_plan(plan, drop_outliers=args.drop_outliers)
    with ProjectLock(args.project):
        created = not args.project.exists()
        project = Project.create(plan.machine) if created else Project.open(args.project)
        project.add_lines(
            plan,
            result.measurement,
            result.source_bytes,
            result.raw,
            provenance={line.name: line.provenance() for line in result.lines},
            captures={
                line.name: _capture_arrays(line)
                for line in result.lines
                if line.capture is not None
            },
            replace=args.replace,
        )
        project.save(args.project)
    summary = summarise(result, args.project, created)
    if args.json:
        print(json.dumps(summary, indent=2, ensure_ascii=False))
    else:
        print(render(summary))
    return 0


def _capture_arrays(line: Any) -> dict[str, Any]:
    capture = line.capture
    arrays = {"time_s": capture.time_s, "deviation": capture.deviation}
    if capture.position_mm is not None:
        arrays["position_mm"] = capture.position_mm
    return arrays


def summarise(result: ImportResult, project: Path, created: bool) -> dict[str, Any]:
    """The command's output as a JSON-ready dict."""
    lines = []
    for line in result.lines:
        lines.append(
            {
                "name": line.name,
                "file": str(line.spec.file),
                "format": line.format,
                "quantity": line.spec.quantity,
                "unit": line.spec.unit,
                "runs": line.corrected.runs,
                "targets": int(line.corrected.targets_mm.size),
                "readings": line.readings,
                "sign": line.spec.sign,
                "sign_convention": line.sign_convention,
                "env_corrected": line.spec.env_corrected,
                "corrections": list(line.corrections),
                "notes": list(line.notes),
                "outliers": len(line.flags),
            }
        )
    return {
        "project": str(project),
        "plan": str(result.plan.path),
        "created": created,
        "lines": lines,
        "line_count": len(lines),
        "readings": sum(line["readings"] for line in lines),
        "outliers": [
            {**flag.to_json(), "dropped": result.outliers_dropped} for flag in result.flags
        ],
        "outliers_dropped": result.outliers_dropped,
    }


def render(summary: dict[str, Any]) -> str:
    verb = "created" if summary["created"] else "updated"
    out = [
        f"{summary['project']}: {verb}; {summary['line_count']} line(s), "
        f"{summary['readings']} readings imported from {summary['plan']}"
    ]
    for line in summary["lines"]:
        unit = "µrad" if line["unit"] == "urad" else "µm"
        out.append(
            f"  {line['name']}: {line['quantity']}, {line['format']}, {line['runs']} runs × "
            f"{line['targets']} targets = {line['readings']} readings ({unit})"
        )
        out.append(f"      {line['sign_convention']}")
        if line["env_corrected"]:
            out.append(
                "      environment: as compensated by the laser software (env_corrected = true)"
            )
        for text in line["corrections"]:
            out.append(f"      corrected: {text}")
        for text in line["notes"]:
            out.append(f"      note: {text}")
    flags = summary["outliers"]
    if flags:
        action = (
            "set to missing (--drop-outliers)"
            if summary["outliers_dropped"]
            else "kept; re-run with --drop-outliers to leave them out"
        )
        out.append(f"{len(flags)} outlier flag(s), {action}:")
        out += [f"  {flag['line']}: {flag['reason']}" for flag in flags]
    else:
        out.append("no outliers flagged")
    return "\n".join(out)
