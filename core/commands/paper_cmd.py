"""``volucal paper``: the seed paper's sensitivity results beside volucal's.

Runs EFAST on the paper's Table 2 errors (N = 1400 per factor, as the paper) with the positions
fixed on a grid over the strokes (a map, summarised over the workspace), with the positions as
design factors, and with the positions as noise outside the design (the setting volucal refuses,
shown because it explains the paper's figures best), and prints the six largest S1 and ST per
output beside the paper's Figs. 3 and 4, our Table 3 (eq. 19 as published and in a dimensionally
sound form) beside the paper's, the exact assumptions, and the differences that can be shown.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from ..paper import PAPER_N, paper_comparison
from .sensitivity_cmd import _triple


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "paper",
        help="reproduce the paper's sensitivity figures and Table 3 beside volucal's",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument(
        "--n",
        type=int,
        default=PAPER_N,
        help=f"samples per factor (default {PAPER_N}, the paper's)",
    )
    parser.add_argument("--m", type=int, default=4, help="interference factor M (default 4)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random phases")
    parser.add_argument(
        "--repeats",
        type=int,
        default=4,
        help="independent designs; their spread is the uncertainty (default 4)",
    )
    parser.add_argument(
        "--grid-step",
        type=float,
        default=80.0,
        metavar="MM",
        help="spacing of the map's grid points (default 80 mm)",
    )
    parser.add_argument(
        "--tool-offset",
        metavar="D1,D2,D3",
        help="tool point, mm (default 0,0,200: the paper's 200 mm tool)",
    )
    parser.add_argument("--json", action="store_true", help="print the comparison as JSON")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    tool = _triple(args.tool_offset, "--tool-offset") if args.tool_offset else None
    comparison = paper_comparison(args.n, args.m, args.seed, args.repeats, args.grid_step, tool)
    if args.json:
        print(json.dumps(comparison.to_dict(), indent=1, allow_nan=False))
    else:
        print(comparison.format_text())
    return 0
