"""``volucal sensitivity``: EFAST S1 and ST of Ex, Ey, Ez, ET with respect to the 21 errors.

Either an identified project (``volucal sensitivity PROJECT.h5``: the errors vary by their
identification uncertainty; the result is stored in the project under /sensitivity/<name>) or the
paper's Table 2 (``--preset paper``). Positions: one point (``--position X,Y,Z``), a map with one
analysis per grid point about STEP mm apart (``--map STEP``), or, by default, X, Y, Z as design
factors uniform over the strokes (``--positions design``). Positions as noise outside the design
are refused. Prints the six largest workspace indices per output; ``--json`` prints the report.json
``sensitivity`` block (keyed by ISO ids: EB0Z = −Sxz) with the settings and, for maps, the indices
at every point.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ERROR_INFO
from ..machine import PAPER_MACHINE
from ..sensitivity import (
    NOISE_EXPLANATION,
    OUTPUT_NAMES,
    PositionNoiseError,
    SensitivityResult,
    analyse,
    analyse_model,
    not_identified_note,
    paper_problem,
    workspace_grid,
)
from ..userror import UserError


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "sensitivity",
        help="EFAST global sensitivity of the volumetric error to the 21 errors",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument(
        "project",
        nargs="?",
        type=Path,
        metavar="PROJECT.h5",
        help="a project with an identification",
    )
    parser.add_argument(
        "--preset",
        choices=("paper",),
        help="analyse the paper's Table 2 errors instead of a project",
    )
    parser.add_argument(
        "--identification",
        metavar="NAME",
        help="identification to analyse (default: the project's last)",
    )
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--position", metavar="X,Y,Z", help="one fixed NC position, mm")
    where.add_argument(
        "--map",
        type=float,
        metavar="STEP",
        help="a map: one analysis per grid point about STEP mm apart (e.g. 50)",
    )
    where.add_argument(
        "--positions",
        choices=("design", "noise"),
        help="design (the default without --position or --map): X, Y, Z become "
        "factors uniform over the strokes; noise is refused with the reason",
    )
    parser.add_argument(
        "--tool-offset",
        metavar="D1,D2,D3",
        help="tool point relative to the spindle gauge point, mm (default: the machine's)",
    )
    parser.add_argument(
        "--output",
        action="append",
        metavar="NAME",
        help="Ex, Ey, Ez or ET; repeat or separate by commas (default: all)",
    )
    parser.add_argument("--n", type=int, default=1400, help="samples per factor (default 1400)")
    parser.add_argument("--m", type=int, default=4, help="interference factor M (default 4)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random phases")
    parser.add_argument(
        "--repeats",
        type=int,
        default=4,
        help="independent designs; their spread is the uncertainty (default 4)",
    )
    parser.add_argument(
        "--method",
        choices=("tail", "classic"),
        default="tail",
        help="tail (default) or classic (SALib's estimator)",
    )
    parser.add_argument(
        "--name",
        default="sensitivity",
        help="name of the stored result in the project (default: sensitivity)",
    )
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if (args.project is None) == (args.preset is None):
        raise UserError("give either PROJECT.h5 or --preset paper")
    outputs = _outputs(args.output)
    tool = _triple(args.tool_offset, "--tool-offset") if args.tool_offset else None
    if args.preset == "paper":
        if args.identification:
            raise UserError("--identification needs PROJECT.h5, not --preset")
        positions: Any = args.positions or "design"
        if args.position:
            positions = _triple(args.position, "--position")
        elif args.map is not None:
            positions = workspace_grid(PAPER_MACHINE, args.map)
        problem = paper_problem(positions, tool)
        result = analyse(problem, outputs, args.n, args.m, args.seed, args.repeats, args.method)
    else:
        result = _project_analysis(args, outputs, tool)
    if args.json:
        document = _document(result)
        if args.project is not None:
            document["not_identified"] = sorted(result.not_identified)
        print(json.dumps(document, indent=1, allow_nan=False))
    else:
        print(_text(result))
    return 0


def _project_analysis(
    args: argparse.Namespace, outputs: tuple[str, ...], tool: tuple[float, float, float] | None
) -> SensitivityResult:
    """The analysis of the project's identification, stored in the project; it carries the errors
    that identification does not identify."""
    if args.positions == "noise":
        # The preset branch refuses it in the problem; refuse here before any file is read.
        raise PositionNoiseError(NOISE_EXPLANATION)
    try:
        from .. import project as project_module
    except ImportError:
        raise UserError(
            f"{args.project}: project support not available in this installation"
        ) from None
    # Held from reading to saving: another writer meanwhile is refused instead of being
    # overwritten by this command's older copy of the project.
    with project_module.ProjectLock(args.project):
        return _analyse_and_store(project_module, args, outputs, tool)


def _analyse_and_store(
    project_module: Any,
    args: argparse.Namespace,
    outputs: tuple[str, ...],
    tool: tuple[float, float, float] | None,
) -> SensitivityResult:
    project = project_module.Project.open(args.project)
    names = list(project.results("identifications"))
    if not names:
        raise UserError(
            f"{args.project}: the project has no identification yet; run "
            f"`volucal identify {args.project}` first"
        )
    name = args.identification or names[-1]
    if name not in names:
        raise UserError(
            f"{args.project}: no identification named {name!r}; the project has {', '.join(names)}"
        )
    if project.machine is None:
        raise UserError(f"{args.project}: the project has no machine; import a plan first")
    tree = project.result("identifications", name)
    model = project_module.error_model_from_tree(tree.get("model", tree), project.machine)
    covariance = tree.get("covariance")
    position = _triple(args.position, "--position") if args.position else None
    from ..result_trees import unidentified_ids

    result = analyse_model(
        model,
        None if covariance is None else np.asarray(covariance, dtype=float),
        outputs,
        map_step_mm=args.map,
        position_mm=position,
        n=args.n,
        m=args.m,
        seed=args.seed,
        repeats=args.repeats,
        method=args.method,
        tool_offset_mm=tool,
        not_identified=unidentified_ids(tree),
    )
    project.put_result("sensitivity", args.name, {**result.to_tree(), "identification": name})
    project.save()
    return result


def _outputs(values: list[str] | None) -> tuple[str, ...]:
    if not values:
        return OUTPUT_NAMES
    names = [v.strip() for item in values for v in item.split(",") if v.strip()]
    unknown = [v for v in names if v not in OUTPUT_NAMES]
    if unknown:
        raise UserError(f"--output {', '.join(unknown)}: use {', '.join(OUTPUT_NAMES)}")
    return tuple(dict.fromkeys(names))


def _triple(text: str, option: str) -> tuple[float, float, float]:
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise UserError(f"{option}: expected three numbers in mm such as 200,200,175, got {text!r}")
    return values  # type: ignore[return-value]


def _document(result: SensitivityResult) -> dict[str, object]:
    document: dict[str, object] = {
        "sensitivity": result.to_report(),
        "settings": dict(result.settings),
        "positions_mm": None if result.positions_mm is None else result.positions_mm.tolist(),
    }
    if result.positions_mm is not None and len(result.positions_mm) > 1:
        document["map"] = {
            output: {
                kind: [
                    result.indices(output, kind, point) for point in range(len(result.positions_mm))
                ]
                for kind in ("S1", "ST")
            }
            for output in result.outputs
        }
    return _finite(document)


def _finite(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def _label(factor: str) -> str:
    if factor not in ERROR_INFO:
        return f"{factor} (position)"
    info = ERROR_INFO[factor]
    return f"{factor} ({'−' if info.paper_sign < 0 else ''}{info.paper})"


def _text(result: SensitivityResult) -> str:
    """The six largest indices per output; an error the analysed identification does not
    identify (``result.not_identified``) is marked, with what its indices mean."""
    unidentified = set(result.not_identified)
    settings = result.settings
    problem = settings.get("problem", {})
    assert isinstance(problem, dict)
    lines = [
        f"EFAST sensitivity of {problem.get('name', 'the problem')}: N = {settings['n']} per "
        f"factor, M = {settings['m']}, {settings['repeats']} repeat(s), seed {settings['seed']}, "
        f"method {settings['method']}, chain {settings['chain']}",
        f"positions: {problem.get('positions')}; tool offset "
        f"{', '.join(f'{v:g}' for v in problem.get('tool_offset_mm', []))} mm",
    ]
    if result.positions_mm is not None and len(result.positions_mm) > 1:
        lines.append("indices of the workspace-averaged variance (Σ V·S / Σ V over the points)")
    listed: set[str] = set()
    for output in result.outputs:
        ws = result.workspace(output)
        spread = dict(zip(result.factor_ids, ws["S1_std"], strict=True))
        total = dict(zip(result.factor_ids, ws["ST"], strict=True))
        lines.append("")
        lines.append(f"{output}: {'factor':<18}{'S1':>14}{'ST':>9}")
        for factor, value in result.top(output, "S1", 6):
            error = spread[factor]
            shown = f"{value:.3f}" + (f" ± {error:.3f}" if math.isfinite(error) else "")
            mark = "  *" if factor in unidentified else ""
            lines.append(f"    {_label(factor):<18}{shown:>14}{total[factor]:>9.3f}{mark}")
            listed.add(factor)
    if listed & unidentified:
        lines.append("")
        lines.append(not_identified_note())
    return "\n".join(lines)
