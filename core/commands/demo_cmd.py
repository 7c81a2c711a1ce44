"""``volucal demo``: the whole job on the embedded demo data set."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import plans
from ..calibrate import CalibrationResult
from ..resources import demo_plan
from ..simulate import DEMO_JITTER_MM as JITTER_MM
from ..simulate import DEMO_STEP_MM as STEP_MM
from ..simulate import demo_machine
from ..verification import verification_report, verification_table, verify_on_virtual_machine
from .calibrate_cmd import add_run_options, run


def verify_demo(result: CalibrationResult) -> str:
    """Re-measure the demo plan on the virtual machine that made the demo data, compensated by
    each method, and add the rates to the report."""
    machine = demo_machine()
    lines = plans.full(machine.machine, STEP_MM, JITTER_MM)
    checks = verify_on_virtual_machine(machine, lines, result.source, result.exports[0].tables)
    result.report["compensation"]["verified_on_virtual_machine"] = verification_report(checks)
    return "\n" + verification_table(checks)


def handle(args: argparse.Namespace) -> int:
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    print(f"demo plan: {demo_plan()}")
    return run(
        args,
        demo_plan(),
        out / "demo.h5",
        out / "report.json",
        args.export or out / "compensation",
        after=verify_demo,
    )


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
    parser.add_argument(
        "--out", type=Path, default=Path("demo-output"), help="output folder (default: %(default)s)"
    )
    add_run_options(parser)
    parser.set_defaults(handler=handle)
