"""``volucal demo``: the whole job on the embedded demo data set."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..resources import demo_plan
from .calibrate_cmd import add_run_options, run


def handle(args: argparse.Namespace) -> int:
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    print(f"demo plan: {demo_plan()}")
    return run(args, demo_plan(), out / "demo.h5", out / "report.json", args.export or out / "compensation")


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser(
        "demo",
        help="run the whole job on the embedded demo data",
        description=(
            "Calibrate the embedded demo machine (the paper's XYTZ mill, simulated with a 4 µm "
            "reversal on X and a 1.2 µm screw cycle on Y that the 21-error model lacks) and write "
            "the project, report.json and compensation files into --out."
        ),
    )
    parser.add_argument("--out", type=Path, default=Path("demo-output"),
                        help="output folder (default: %(default)s)")
    add_run_options(parser)
    parser.set_defaults(handler=handle)
