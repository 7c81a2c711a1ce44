"""``volucal iso230-2 FILE...``: ISO 230-2 positioning values of measured lines.

FILE is a log (.rtl, .rta, an ISO 230-2 table, a CSV/whitespace table) or a plan.toml, whose
lines are all evaluated as imported (sign, units and environment correction of the plan). Prints,
per line, A, E, R (both directions and bidirectional), M and B, and the per-target means and
spreads at the targets' positions (on the machine axis for a plan's line along one axis, where
the file puts them for a file alone); ``--json`` prints the same with the keys of DESIGN.md
(``A_um``, ``A_up_um``, …), the positions as ``positions_mm`` (``positions_of``: "X", "Y", "Z",
"file" or "line", the distance from the line's start) beside ``targets_mm`` (the distances), and
the import's ``notes`` of a line.
Straightness lines of a plan (and every line with ``--straightness``) also get their ISO 230-1
straightness by the least-squares, minimum-zone and end-point reference lines.
``--exclude-outliers`` leaves out the readings the outlier screening flags and lists them.

A table must say its deviation unit (in its header, or ``--unit``): volucal assumes none.
"""

from __future__ import annotations

import argparse
import json
import math
import unicodedata
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..io.iso_table import is_iso_table, read_iso_table
from ..io.plan import import_plan, load_plan
from ..io.rtl import read_rtl
from ..io.source import SourceText
from ..io.table import ColumnMap, TableFormat, read_table
from ..io.units import DEVIATION_FACTOR, choices, describe, is_angle, normalise_unit
from ..iso230_2 import STRAIGHTNESS_METHODS, Iso230Result, evaluate, evaluate_straightness
from ..measurement import LineData, LineSpec, position_label, target_positions
from ..outliers import OutlierFlag, drop, screen
from ..userror import UserError


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "iso230-2",
        help="ISO 230-2 accuracy, repeatability and reversal of measured lines",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument("files", nargs="+", type=Path, metavar="FILE")
    parser.add_argument("--json", action="store_true", help="print the values as JSON")
    parser.add_argument(
        "--sign",
        type=int,
        choices=(1, -1),
        default=1,
        help="+1 (default): the file's deviations are measured − nominal; -1 "
        "flips them (logs only; a plan sets sign per line)",
    )
    parser.add_argument(
        "--unit",
        help="deviation unit of a table that does not state it "
        "(um, nm, mm, inch; urad, mrad, arcsec, deg); required then, and it must "
        "agree with a unit the file states",
    )
    parser.add_argument(
        "--position-unit",
        help="position unit of a table that does not state "
        "it (mm, um, m, inch); required then (a plan's tables are in mm, the "
        "plan.toml contract)",
    )
    parser.add_argument(
        "--columns",
        help="column map of a table, e.g. "
        "position=Position,deviation=Flat (names or 1-based numbers)",
    )
    parser.add_argument("--data-marker", help="a table's data start after this line (e.g. :START)")
    parser.add_argument(
        "--straightness",
        action="store_true",
        help="give every line's ISO 230-1 straightness of the mean profile "
        "(least-squares, minimum-zone and end-point reference lines); "
        "straightness lines of a plan always get it",
    )
    parser.add_argument(
        "--exclude-outliers",
        action="store_true",
        help="leave out the readings (or runs) the outlier screening flags "
        "(5 σ of the run-to-run spread, docs/formats.md) and list them",
    )
    parser.add_argument(
        "--files-root",
        type=Path,
        metavar="DIR",
        help="a plan may read files under DIR (default: only its own folder)",
    )
    parser.set_defaults(handler=run)


@dataclass(frozen=True, eq=False)
class _Line:
    name: str
    file: Path
    quantity: str
    unit: str  # "um" or "urad"
    data: LineData
    notes: tuple[str, ...] = field(default=())
    #: the plan's line (a file read without a plan has none)
    spec: LineSpec | None = None


def run(args: argparse.Namespace) -> int:
    entries = []
    for path in args.files:
        for line in _lines(path, args):
            entries.append(
                evaluate_line(
                    line, straightness=args.straightness, exclude_outliers=args.exclude_outliers
                )
            )
    if args.json:
        print(json.dumps({"lines": [e for e, _ in entries]}, indent=2, ensure_ascii=False))
    else:
        print("\n\n".join(render(entry, result) for entry, result in entries))
    return 0


def evaluate_line(
    line: _Line, *, straightness: bool = False, exclude_outliers: bool = False
) -> tuple[dict[str, Any], Iso230Result]:
    """The JSON entry and the ISO 230-2 result of one line."""
    data = line.data
    flags: list[OutlierFlag] = []
    if exclude_outliers:
        flags = screen(data, line=line.name, unit=line.unit)
        data = drop(data, flags) if flags else data
    result = evaluate(data, line.unit)
    positions = target_positions(result.targets_mm, line.spec, data.origin_mm)
    entry: dict[str, Any] = {
        "name": line.name,
        "file": str(line.file),
        "quantity": line.quantity,
        **result.to_json(),
        "positions_mm": [float(v) for v in positions.values_mm],
        "positions_of": positions.of,
    }
    if exclude_outliers:
        entry["excluded"] = [flag.to_json() for flag in flags]
    if line.notes:
        entry["notes"] = list(line.notes)
    if line.quantity != "angular" and (straightness or line.quantity == "straightness"):
        with np.errstate(all="ignore"):
            profile = np.nanmean(data.deviations, axis=0)
        try:
            values = evaluate_straightness(data.targets_mm, profile)
        except ValueError as exc:
            raise UserError(f"{line.file}: {line.name}: {exc}") from None
        u = line.unit
        entry["straightness"] = {"profile": "mean of all runs at each target", **values.to_json(u)}
        entry[f"straightness_ls_{u}"] = values.least_squares
        entry[f"straightness_mz_{u}"] = values.minimum_zone
        entry[f"straightness_ep_{u}"] = values.end_point
    return entry, result


def _lines(path: Path, args: argparse.Namespace) -> list[_Line]:
    """Every line of a file, in µm/µrad with the chosen sign."""
    if path.suffix.lower() == ".toml":
        imported = import_plan(load_plan(path, files_root=args.files_root))
        return [
            _Line(
                line.name,
                Path(line.spec.file or path),
                line.spec.quantity,
                line.spec.unit,
                line.corrected,
                notes=line.notes,
                spec=line.spec,
            )
            for line in imported.lines
        ]
    unit = normalise_unit(args.unit) if args.unit else None
    if unit is not None and unit not in DEVIATION_FACTOR:
        raise UserError(
            f"--unit {args.unit!r} is not a deviation unit; use one of "
            f"{choices(tuple(DEVIATION_FACTOR))}"
        )
    suffix = path.suffix.lower()
    if suffix in (".rtl", ".rta"):
        log = read_rtl(path, sign=args.sign)
        if unit is not None and unit != log.unit:
            raise UserError(
                f"{path}: a Renishaw {suffix} log is in {describe(log.unit)} by "
                f"definition, but --unit says {describe(unit)}; leave --unit out"
            )
        return [_Line(path.stem, path, "angular" if log.angular else "linear", log.unit, log.data)]
    if is_iso_table(SourceText.read(path)):
        table = read_iso_table(path, unit)
        data, unit = table.data, table.unit
    else:
        fmt = TableFormat(
            columns=_columns(args.columns),
            deviation_unit=unit,
            position_unit=args.position_unit,
            data_marker=args.data_marker,
            environment=False,
        )
        table_file = read_table(path, fmt)
        data, unit = table_file.data, table_file.unit
    angular = is_angle(unit)
    converted = replace(data, deviations=data.deviations * DEVIATION_FACTOR[unit] * args.sign)
    notes = () if unit in ("um", "urad") else (f"deviations converted from {describe(unit)}",)
    return [
        _Line(
            path.stem,
            path,
            "angular" if angular else "linear",
            "urad" if angular else "um",
            converted,
            notes,
        )
    ]


def _columns(text: str | None) -> ColumnMap:
    if not text:
        return ColumnMap()
    mapping: dict[str, object] = {}
    for part in text.split(","):
        key, equals, value = part.partition("=")
        if not equals:
            raise UserError(f"--columns: expected key=name pairs, got {part!r}")
        value = value.strip()
        mapping[key.strip()] = int(value) if value.isascii() and value.isdigit() else value
    try:
        return ColumnMap.from_mapping(mapping)
    except ValueError as exc:
        raise UserError(f"--columns: {exc}") from None


def _fmt(value: float | None) -> str:
    return (
        "—"
        if value is None or (isinstance(value, float) and math.isnan(value))
        else (f"{value:.3f}")
    )


def _table(header: list[str], rows: list[list[str]], *, first_left: bool = False) -> list[str]:
    """Rows of cells aligned in columns as wide as their widest cell (two spaces apart), so
    that columns never run together whatever the size of the values."""
    widths = [max(_width(row[i]) for row in [header, *rows]) for i in range(len(header))]
    out = []
    for row in [header, *rows]:
        cells = []
        for i, cell in enumerate(row):
            pad = " " * (widths[i] - _width(cell))
            cells.append(cell + pad if (first_left and i == 0) else pad + cell)
        out.append("  " + "  ".join(cells).rstrip())
    return out


def _width(text: str) -> int:
    """Columns a text takes on a terminal: combining marks (the bar of x̄) take none."""
    return sum(0 if unicodedata.combining(c) else 1 for c in text)


def render(entry: dict[str, Any], result: Iso230Result) -> str:
    """The standard's table for one line: values per direction, then per target."""
    u = result.unit
    symbol = "µrad" if u == "urad" else "µm"
    out = [
        f"{entry['name']} ({entry['file']}): {entry['quantity']}, {symbol}; "
        f"{result.targets_mm.size} targets, {result.runs_up} run(s) ↑, {result.runs_down} "
        "run(s) ↓",
    ]
    out += [f"  note: {text}" for text in entry.get("notes", [])]
    if "excluded" in entry:
        excluded = entry["excluded"]
        if excluded:
            out.append(f"  excluded as outliers (--exclude-outliers), {len(excluded)}:")
            out += [f"    {flag['reason']}" for flag in excluded]
        else:
            out.append("  excluded as outliers (--exclude-outliers): none")
    rows = (
        ("A  accuracy", result.A_up_um, result.A_down_um, result.A_um),
        ("E  systematic deviation", result.E_up_um, result.E_down_um, result.E_um),
        ("R  repeatability", result.R_up_um, result.R_down_um, result.R_um),
        ("M  mean deviation", None, None, result.M_um),
        ("B  reversal value", None, None, result.B_um),
        ("   mean reversal value", None, None, result.mean_reversal_um),
    )
    out += _table(
        ["", "↑", "↓", "bidirectional"],
        [
            [
                label,
                _fmt(up) if up is not None else "",
                _fmt(down) if down is not None else "",
                _fmt(both),
            ]
            for label, up, down, both in rows
        ],
        first_left=True,
    )
    if "straightness" in entry:
        values = entry["straightness"]
        out.append(f"  straightness of the {values['profile']}:")
        out += _table(
            ["method", symbol],
            [
                [STRAIGHTNESS_METHODS[key], _fmt(values[f"{key}_{u}"])]
                for key in ("least_squares", "minimum_zone", "end_point")
            ],
            first_left=True,
        )
    per_target = []
    for i, target in enumerate(entry["positions_mm"]):
        values = (
            result.mean_up[i],
            result.mean_down[i],
            result.mean[i],
            result.s_up[i],
            result.s_down[i],
            result.reversal[i],
            result.repeatability[i],
        )
        per_target.append([f"{target:.3f}"] + [_fmt(float(v)) for v in values])
    heading = position_label(entry["positions_of"])
    out += _table([heading, "x̄↑", "x̄↓", "x̄", "s↑", "s↓", "B_i", "R_i"], per_target)
    return "\n".join(out)
