"""``volucal iso230-2 FILE...``: ISO 230-2 positioning values of measured lines.

FILE is a log (.rtl, .rta, an ISO 230-2 table, a CSV/whitespace table) or a plan.toml, whose
lines are all evaluated as imported (sign, units and environment correction of the plan). Prints,
per line, A, E, R (both directions and bidirectional), M and B, and the per-target means and
spreads; ``--json`` prints the same with the keys of DESIGN.md (``A_um``, ``A_up_um``, …).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..io.iso_table import is_iso_table, read_iso_table
from ..io.plan import import_plan, load_plan
from ..io.rtl import read_rtl
from ..io.source import SourceText
from ..io.table import ColumnMap, TableFormat, read_table
from ..io.units import DEVIATION_FACTOR, is_angle, normalise_unit
from ..iso230_2 import Iso230Result, evaluate, straightness
from ..measurement import LineData
from ..userror import UserError


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "iso230-2",
        help="ISO 230-2 accuracy, repeatability and reversal of measured lines",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument("files", nargs="+", type=Path, metavar="FILE")
    parser.add_argument("--json", action="store_true", help="print the values as JSON")
    parser.add_argument("--sign", type=int, choices=(1, -1), default=1,
                        help="+1 (default): the file's deviations are measured − nominal; -1 "
                        "flips them (logs only; a plan sets sign per line)")
    parser.add_argument("--unit", help="deviation unit of a table that does not state it "
                        "(default um; e.g. mm, nm, urad, arcsec)")
    parser.add_argument("--columns", help="column map of a table, e.g. "
                        "position=Position,deviation=Flat (names or 1-based numbers)")
    parser.add_argument("--data-marker", help="a table's data start after this line (e.g. :START)")
    parser.add_argument("--straightness", action="store_true",
                        help="also give the ISO 230-1 straightness of the mean profile against "
                        "the least-squares and end-point reference lines")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    entries = []
    for path in args.files:
        for name, quantity, unit, data in _lines(path, args):
            result = evaluate(data, unit)
            entry: dict[str, Any] = {"name": name, "file": str(path), "quantity": quantity,
                                     **result.to_json()}
            if args.straightness:
                with np.errstate(all="ignore"):
                    profile = np.nanmean(data.deviations, axis=0)
                ls, ep = straightness(data.targets_mm, profile)
                entry[f"straightness_ls_{unit}"] = ls
                entry[f"straightness_ep_{unit}"] = ep
            entries.append((entry, result))
    if args.json:
        print(json.dumps({"lines": [e for e, _ in entries]}, indent=2, ensure_ascii=False))
    else:
        print("\n\n".join(render(entry, result) for entry, result in entries))
    return 0


def _lines(path: Path, args: argparse.Namespace) -> list[tuple[str, str, str, LineData]]:
    """(name, quantity, unit, data in µm/µrad with the chosen sign) for every line of a file."""
    if path.suffix.lower() == ".toml":
        imported = import_plan(load_plan(path))
        return [(line.name, line.spec.quantity, line.spec.unit, line.corrected)
                for line in imported.lines]
    suffix = path.suffix.lower()
    if suffix in (".rtl", ".rta"):
        log = read_rtl(path, sign=args.sign)
        return [(path.stem, "angular" if log.angular else "linear", log.unit, log.data)]
    if is_iso_table(SourceText.read(path)):
        table = read_iso_table(path)
        data, unit = table.data, table.unit
    else:
        columns = _columns(args.columns)
        fmt = TableFormat(columns=columns, data_marker=args.data_marker)
        table_file = read_table(path, fmt)
        data, unit = table_file.data, table_file.unit or normalise_unit(args.unit or "um")
    if unit not in DEVIATION_FACTOR:
        raise UserError(f"{path}: deviation unit {unit!r} is not supported")
    angular = is_angle(unit)
    converted = LineData(
        targets_mm=data.targets_mm,
        deviations=data.deviations * DEVIATION_FACTOR[unit] * args.sign,
        run_direction=data.run_direction,
        times_s=data.times_s,
        start_time=data.start_time,
        environment=data.environment,
    )
    return [(path.stem, "angular" if angular else "linear", "urad" if angular else "um",
             converted)]


def _columns(text: str | None) -> ColumnMap:
    if not text:
        return ColumnMap()
    mapping: dict[str, object] = {}
    for part in text.split(","):
        key, equals, value = part.partition("=")
        if not equals:
            raise UserError(f"--columns: expected key=name pairs, got {part!r}")
        value = value.strip()
        mapping[key.strip()] = int(value) if value.isdigit() else value
    try:
        return ColumnMap.from_mapping(mapping)
    except ValueError as exc:
        raise UserError(f"--columns: {exc}") from None


def _fmt(value: float | None) -> str:
    return "—" if value is None or (isinstance(value, float) and math.isnan(value)) else (
        f"{value:.3f}")


def render(entry: dict[str, Any], result: Iso230Result) -> str:
    """The standard's table for one line: values per direction, then per target."""
    u = result.unit
    symbol = "µrad" if u == "urad" else "µm"
    out = [
        f"{entry['name']} ({entry['file']}): {entry['quantity']}, {symbol}; "
        f"{result.targets_mm.size} targets, {result.runs_up} run(s) ↑, {result.runs_down} "
        "run(s) ↓",
        f"  {'':26}{'↑':>10}{'↓':>10}{'bidirectional':>15}",
    ]
    rows = (
        ("A  accuracy", result.A_up_um, result.A_down_um, result.A_um),
        ("E  systematic deviation", result.E_up_um, result.E_down_um, result.E_um),
        ("R  repeatability", result.R_up_um, result.R_down_um, result.R_um),
        ("M  mean deviation", None, None, result.M_um),
        ("B  reversal value", None, None, result.B_um),
        ("   mean reversal value", None, None, result.mean_reversal_um),
    )
    for label, up, down, both in rows:
        out.append(f"  {label:26}{_fmt(up):>10}{_fmt(down):>10}{_fmt(both):>15}")
    for key in ("straightness_ls", "straightness_ep"):
        if f"{key}_{u}" in entry:
            label = "least-squares" if key.endswith("ls") else "end-point"
            out.append(f"  straightness ({label} line): {_fmt(entry[f'{key}_{u}'])} {symbol}")
    out.append(f"  {'target mm':>11}{'x̄↑':>9}{'x̄↓':>9}{'x̄':>9}{'s↑':>9}{'s↓':>9}{'B_i':>9}"
               f"{'R_i':>9}")
    for i, target in enumerate(result.targets_mm):
        values = (result.mean_up[i], result.mean_down[i], result.mean[i], result.s_up[i],
                  result.s_down[i], result.reversal[i], result.repeatability[i])
        out.append(f"  {target:11.3f}" + "".join(f"{_fmt(float(v)):>9}" for v in values))
    return "\n".join(out)
