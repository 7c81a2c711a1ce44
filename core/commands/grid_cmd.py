"""``volucal grid FILE...``: planar errors and a 2-D correction table from XY grid measurements.

FILE is an Aerotech Accuracy2D data file (recognised by its 'TestType : Accuracy2D' line; its
'.set' file beside it gives the position unit) or any table of commanded positions and
measured positions or deviations read with --columns (a Heidenhain KGM grid-encoder export,
a CSV). Several files are zones of one stitched calibration: they are fitted together, each with
its own laser zero and mirror rotation.

Prints the grid (nodes, units and where they came from, environment), the set-up's gauge terms,
the planar errors in ISO 230-1 ids (EXX, EYY positioning; EYX, EXY straightness; ECY or ECX yaw
of the upper axis; EC0Y squareness) with their standard uncertainties, the cross-axis surface and
the residuals. --export-cal writes an Aerotech 2-D calibration file, --export-csv a
generic CSV grid (sign: correction = −(measured − commanded), stated in both files);
--compare-cal compares the correction with another .cal at its nodes (the gauge terms both
leave removed); --project stores the grids and the identification in a project.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ..compensation.export_grid2d import (
    SIGN_CONVENTION,
    cal_as_table,
    grid_table,
    read_aerotech_cal,
    write_aerotech_cal,
    write_grid_csv,
)
from ..errors import ERROR_INFO
from ..grid2d import GridMeasurement, common_lattice, describe_grid, remove_gauge_terms, rms
from ..grid2d_fit import GridFitRequest, identify_grid, sample_positions
from ..grid2d_model import ARCSEC_PER_URAD, GridIdentification
from ..grid2d_store import put_grid
from ..grid2d_table import GridColumnMap, GridFormat, read_grid_table
from ..grid2d_vendor import scan_axis_of
from ..io.accuracy2d import PRESET, is_accuracy2d, read_accuracy2d
from ..io.source import SourceText
from ..project import Project, ProjectLock
from ..userror import UserError

PRESETS = (PRESET, "table")


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "grid",
        help="planar errors and a 2-D correction table from XY grid measurements",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("files", nargs="+", type=Path, metavar="FILE")
    read = parser.add_argument_group("reading")
    read.add_argument(
        "--preset",
        choices=PRESETS,
        help="file layout: aerotech-accuracy2d, or table (needs --columns); by "
        "default an Accuracy2D file is recognised by its TestType line",
    )
    read.add_argument(
        "--columns",
        help="column map of a table, e.g. x=X,y=Y,deviation_x=dX,"
        "deviation_y=dY or measured_x=3 (header names or 1-based numbers)",
    )
    read.add_argument(
        "--position-unit",
        help="unit of the commanded and measured positions "
        "when the file does not state it (mm, um, in)",
    )
    read.add_argument("--deviation-unit", help="unit of deviation columns (um, nm, mm)")
    read.add_argument("--temperature-unit", help="unit of temperature columns (C, K)")
    read.add_argument(
        "--pressure-unit", help="unit of a pressure column (Pa, hPa, mbar, kPa, mmHg, inHg)"
    )
    read.add_argument(
        "--delimiter",
        help="column separator of a table (',', ';', tab, whitespace); detected by default",
    )
    read.add_argument("--data-marker", help="a table's data start after this line (e.g. :START)")
    read.add_argument("--comment", default="#", help="comment prefix of a table (default #)")
    read.add_argument(
        "--sign",
        type=int,
        choices=(1, -1),
        default=1,
        help="+1 (default): deviations are measured − commanded; -1 flips them",
    )
    read.add_argument(
        "--axes",
        choices=("XY", "YX"),
        help="Accuracy2D: XY when Axis 1 is X, YX when it is Y (default: from the SerialNum names)",
    )
    read.add_argument(
        "--allow-gaps", action="store_true", help="read grids with nodes that have no reading"
    )
    fit = parser.add_argument_group("identification")
    fit.add_argument(
        "--upper-axis",
        choices=("auto", "X", "Y", "none"),
        default="auto",
        help="the axis mounted on the other (its yaw shows with the other's "
        "position as lever arm); auto: from the file (Accuracy2D TestOrientation)",
    )
    fit.add_argument(
        "--reference",
        metavar="X,Y",
        help="where every error function is zero (mm); default the first node",
    )
    fit.add_argument(
        "--no-surface", action="store_true", help="rigid-body terms only: no cross-axis surface"
    )
    fit.add_argument(
        "--folds",
        type=int,
        default=5,
        help="K of the K-fold cross-validation "
        "that chooses each term's basis and smoothing (default 5)",
    )
    out = parser.add_argument_group("output")
    out.add_argument("--json", action="store_true", help="print the result as JSON")
    out.add_argument(
        "--export-cal", type=Path, metavar="OUT.cal", help="write an Aerotech 2-D calibration file"
    )
    out.add_argument(
        "--export-csv",
        type=Path,
        metavar="OUT.csv",
        help="write the 2-D table as a generic CSV grid",
    )
    out.add_argument(
        "--spacing",
        type=float,
        metavar="MM",
        help="node spacing of the exported table (default: the measured nodes; "
        "half the measured step holds the model's prediction between them)",
    )
    out.add_argument(
        "--cal-axes",
        metavar="X=N,Y=M",
        help="controller axis numbers for the .cal (default: the file's AxisIndex)",
    )
    out.add_argument(
        "--cal-columns",
        choices=("X", "Y"),
        help="axis along the .cal's columns (default: the scan axis, Axis 1 of an "
        "Accuracy2D file, else X)",
    )
    out.add_argument(
        "--compare-cal",
        type=Path,
        metavar="OTHER.cal",
        help="compare the correction with another 2-D .cal at its nodes",
    )
    out.add_argument(
        "--project",
        type=Path,
        metavar="PROJECT.h5",
        help="store the grids and the identification in this project (created "
        "if missing) under /grids/<name>",
    )
    out.add_argument(
        "--replace", action="store_true", help="replace grids of the same name in the project"
    )
    parser.set_defaults(handler=run)


# ---- reading -----------------------------------------------------------------------------


def _column_map(text: str | None) -> GridColumnMap:
    if not text:
        raise UserError(
            "--columns is needed to read a table, e.g. --columns x=X,y=Y,"
            "deviation_x=dX,deviation_y=dY"
        )
    mapping: dict[str, object] = {}
    for part in text.split(","):
        key, equals, value = part.partition("=")
        if not equals or not key.strip() or not value.strip():
            raise UserError(f"--columns: expected key=name pairs, got {part!r}")
        value = value.strip()
        mapping[key.strip()] = int(value) if value.isdigit() else value
    try:
        return GridColumnMap.from_mapping(mapping)
    except ValueError as exc:
        raise UserError(f"--columns: {exc}") from None


def read_grids(args: argparse.Namespace) -> list[GridMeasurement]:
    """The grids named on the command line, each read with its preset or column map."""
    upper = None if args.upper_axis == "none" else args.upper_axis
    grids = []
    for path in args.files:
        preset = args.preset
        if preset is None:
            preset = PRESET if is_accuracy2d(SourceText.read(path)) else "table"
        if preset == PRESET:
            grid = read_accuracy2d(
                path, axes=args.axes, position_unit=args.position_unit, upper_axis=upper
            )
        else:
            fmt = GridFormat(
                columns=_column_map(args.columns),
                position_unit=args.position_unit,
                deviation_unit=args.deviation_unit,
                temperature_unit=args.temperature_unit,
                pressure_unit=args.pressure_unit,
                delimiter=args.delimiter,
                data_marker=args.data_marker,
                comment=args.comment,
                sign=args.sign,
                upper_axis=None if upper == "auto" else upper,
                complete=not args.allow_gaps,
            )
            grid = read_grid_table(path, fmt, metadata={"preset": "table"})
        grids.append(grid)
    names = [g.name for g in grids]
    if len(set(names)) != len(names):
        raise UserError(f"two files have the same name ({', '.join(names)}): rename one")
    return grids


def _reference(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    parts = text.split(",")
    try:
        x, y = (float(p) for p in parts)
    except ValueError:
        raise UserError(f"--reference: expected X,Y in mm, got {text!r}") from None
    return (x, y)


def _cal_axes(text: str | None, grids: list[GridMeasurement]) -> dict[str, int]:
    if text:
        out: dict[str, int] = {}
        for part in text.split(","):
            key, _, value = part.partition("=")
            if key.strip().upper() not in ("X", "Y") or not value.strip().isdigit():
                raise UserError(f"--cal-axes: expected X=N,Y=M, got {text!r}")
            out[key.strip().upper()] = int(value)
        if set(out) != {"X", "Y"}:
            raise UserError(f"--cal-axes: give both X and Y, got {text!r}")
        return out
    found = {a: grids[0].metadata.get(f"axis_number_{a}") for a in ("X", "Y")}
    if not all(found.values()):
        raise UserError(
            "the .cal needs the controller's axis numbers of X and Y: give --cal-axes X=N,Y=M"
        )
    return {a: int(str(v)) for a, v in found.items()}


# ---- the command -------------------------------------------------------------------------


def run(args: argparse.Namespace) -> int:
    grids = read_grids(args)
    upper = None if args.upper_axis == "none" else args.upper_axis
    request = GridFitRequest(
        upper_axis=upper,
        reference_mm=_reference(args.reference),
        surface=not args.no_surface,
        folds=args.folds,
    )
    identification = identify_grid(grids, request)
    lattice = common_lattice(grids)
    result: dict[str, Any] = {
        "grids": [describe_grid(g, lattice) for g in grids],
        "identification": identification.to_json(),
        "files": [],
    }
    if args.export_cal or args.export_csv:
        table = grid_table(identification, args.spacing)
        result["table_at_measured_nodes"] = args.spacing is None
        comments = [f"from {', '.join(Path(g.source_file).name for g in grids)} by volucal grid"]
        if args.export_csv:
            write_grid_csv(args.export_csv, table, comments)
            result["files"].append(
                {"path": str(args.export_csv), "format": "csv", "sign": SIGN_CONVENTION}
            )
        if args.export_cal:
            columns = args.cal_columns or scan_axis_of(grids[0])
            write_aerotech_cal(
                args.export_cal,
                table,
                _cal_axes(args.cal_axes, grids),
                column_axis=columns,
                comments=comments,
            )
            result["files"].append(
                {"path": str(args.export_cal), "format": "aerotech-cal", "sign": SIGN_CONVENTION}
            )
    if args.compare_cal:
        result["comparison"] = compare_with_cal(
            identification, args.compare_cal, _cal_axes(args.cal_axes, grids)
        )
    if args.project:
        fitted = [g.name for g in grids]
        with ProjectLock(args.project):
            created = not args.project.exists()
            project = Project.create() if created else Project.open(args.project)
            for grid in grids:
                put_grid(project, grid, result["identification"], fitted, replace=args.replace)
            project.save(args.project)
        result["project"] = {
            "path": str(args.project),
            "created": created,
            "groups": [f"/grids/{name}" for name in fitted],
        }
    text = (
        json.dumps(result, indent=2, ensure_ascii=False)
        if args.json
        else render(grids, identification, result)
    )
    try:
        print(text)
        sys.stdout.flush()
    except BrokenPipeError:
        # the reader closed the pipe (e.g. | head): not an error of ours
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0


def compare_with_cal(
    identification: GridIdentification, path: Path, axis_numbers: dict[str, int]
) -> dict[str, Any]:
    """RMS and max difference of volucal's correction and a .cal's at the .cal's measured nodes,
    after removing the gauge terms (an offset per direction and one rotation) the two may differ
    by; for the other table taken with its sign and negated (tables differ in sign convention:
    the one with the smaller difference says which the other file uses)."""
    lattice, other = cal_as_table(read_aerotech_cal(path), axis_numbers)
    positions = sample_positions(lattice)
    reference = np.array([identification.reference_mm])
    ours = -(identification.error(positions) - identification.error(reference))
    theirs = np.stack([other[k].ravel() for k in range(2)], axis=1)
    inside = ~identification.beyond_measured(positions)
    out: dict[str, Any] = {"file": str(path), "nodes": int(inside.sum())}
    for key, sign in (("same_sign", 1.0), ("opposite_sign", -1.0)):
        residual, gauge = remove_gauge_terms(
            positions[inside], ours[inside] - sign * theirs[inside]
        )
        out[key] = {
            "rms_um": {"X": rms(residual[:, 0]), "Y": rms(residual[:, 1])},
            "max_um": {
                "X": float(np.nanmax(np.abs(residual[:, 0]))),
                "Y": float(np.nanmax(np.abs(residual[:, 1]))),
            },
            "gauge_removed": gauge.to_json(),
        }
    same = out["same_sign"]["rms_um"]
    opposite = out["opposite_sign"]["rms_um"]
    out["matching_sign"] = (
        "same"
        if same["X"] ** 2 + same["Y"] ** 2 <= opposite["X"] ** 2 + opposite["Y"] ** 2
        else "opposite"
    )
    return out


# ---- text output -------------------------------------------------------------------------


def _range(summary: dict[str, float], unit: str, digits: int = 2) -> str:
    low, high = summary["min"], summary["max"]
    if abs(high - low) < 10**-digits:
        return f"{summary['mean']:.{digits}f} {unit}"
    return f"{low:.{digits}f}–{high:.{digits}f} {unit}"


def _between(choice: dict[str, float]) -> str:
    """How a function goes between its nodes, in words."""
    if choice["degree"] == 1 and choice["carry"] == 1.0:
        return "node values interpolated linearly"
    basis = "node table" if choice["degree"] == 1 else "cubic spline"
    return (
        f"{basis} smoothed {choice['smoothing']:g}, carrying {choice['carry']:.2f} of the "
        "nodes' departures"
    )


def _linear_between(identification: GridIdentification) -> bool:
    """True when the model is the linear interpolation of its node values between them (then
    a table at the measured nodes holds it whole)."""
    return all(
        identification.choices[e]["degree"] == 1 and identification.choices[e]["carry"] == 1.0
        for e in identification.functions
    )


def render(
    grids: list[GridMeasurement], identification: GridIdentification, result: dict[str, Any]
) -> str:
    out = []
    for grid, info in zip(grids, result["grids"], strict=True):
        step = info["step_mm"]
        rx, ry = info["range_mm"]["x"], info["range_mm"]["y"]
        out.append(
            f"{grid.name} ({grid.source_file}): {info['metadata'].get('preset', 'table')}"
            f", {info['nodes']['x']} × {info['nodes']['y']} nodes, step {step['x']:g} × "
            f"{step['y']:g} mm, X {rx[0]:g}…{rx[1]:g} mm, Y {ry[0]:g}…{ry[1]:g} mm, "
            f"{info['readings']} readings"
        )
        out.append("  units: " + "; ".join(f"{k} {v}" for k, v in grid.units.items()))
        for key in ("axes", "upper_axis"):
            if key in grid.metadata:
                out.append(f"  {key.replace('_', ' ')}: {grid.metadata[key]}")
        env = info["environment"]
        parts = [
            f"{label} {_range(env[key], unit)}"
            for key, label, unit in (
                ("air_temp_c", "air", "°C"),
                ("material_temp_c", "material", "°C"),
                ("pressure_kpa", "pressure", "kPa"),
                ("humidity_pct", "humidity", "%RH"),
            )
            if key in env
        ]
        if parts:
            out.append(
                "  environment: " + ", ".join(parts) + " (readings used as the laser "
                "software wrote them)"
            )
        gauge = identification.gauges[grid.name]
        out.append(
            f"  gauge terms of the set-up: zero X {gauge.offset_x_um:+.3f} µm, Y "
            f"{gauge.offset_y_um:+.3f} µm; mirror rotation {gauge.rotation_urad:+.1f} µrad"
        )
    ref = identification.reference_mm
    out.append("")
    out.append(
        f"Planar errors (ISO 230-1 ids; zero at X = {ref[0]:g} mm, Y = {ref[1]:g} mm; "
        "range over the grid, largest standard uncertainty)"
    )
    order = [e for e in ("EXX", "EYY", "EYX", "EXY", "ECY", "ECX") if e in identification.functions]
    for eid in order:
        _, values, std = identification.sampled(eid)
        unit = "µrad" if eid[1] == "C" else "µm"
        lever = "  (lever arm x)" if eid == "ECY" else "  (lever arm y)" if eid == "ECX" else ""
        choice = identification.choices[eid]
        out.append(
            f"  {eid:5} {ERROR_INFO[eid].description + lever:44} {np.ptp(values):9.3f} "
            f"{unit:4} ± {np.max(std):.3f}   between nodes: {_between(choice)}"
        )
    if identification.squareness_urad is not None:
        value = identification.squareness_urad
        spread = identification.squareness_std_urad or 0.0
        mean = identification.squareness_mean_urad
        out.append(
            f"  EC0Y  squareness of Y to X (about Z){'':9} {value:9.1f} µrad ± {spread:.1f} "
            f"({value * ARCSEC_PER_URAD:.1f}″) at the reference"
        )
        if mean is not None and any(e in identification.functions for e in ("ECY", "ECX")):
            out.append(
                f"        from mean slopes over the grid: {mean:.1f} µrad "
                f"({mean * ARCSEC_PER_URAD:.1f}″; Aerotech's orthogonality has the "
                "opposite sign)"
            )
    stats = identification.statistics
    if identification.surface_um is not None:
        s = identification.to_json()["surface"]["rms_um"]
        out.append(
            "  cross-axis surface (beyond the rigid-body terms): RMS "
            + ", ".join(f"{a} {v:.3f} µm" for a, v in s.items())
        )
    between = stats.get("cv_between_lines_rms_um", {})
    for label in ("rows", "columns"):
        if label in between:
            model, lookup = between[label]["model"], between[label]["node_values_interpolated"]
            out.append(
                f"  held-out {label} (cross-validated): the model leaves "
                + ", ".join(f"{a} {v:.3f}" for a, v in model.items())
                + " µm, the node values interpolated "
                "linearly " + ", ".join(f"{a} {v:.3f}" for a, v in lookup.items()) + " µm"
            )
    out.append(
        "  residual RMS: rigid-body terms "
        + ", ".join(f"{a} {v:.3f}" for a, v in stats["rms_um"]["rigid_body"].items())
        + " µm; with the "
        "surface "
        + ", ".join(f"{a} {v:.3f}" for a, v in stats["rms_um"]["with_surface"].items())
        + " µm; cross-validated "
        + ", ".join(f"{a} {v:.3f}" for a, v in stats["cv_rms_um"].items() if a in ("X", "Y"))
        + " µm"
    )
    if "comparison" in result:
        c = result["comparison"]
        out.append("")
        out.append(f"Against {c['file']} at its {c['nodes']} measured nodes, gauge terms removed:")
        for key, label in (
            ("same_sign", "its values as they are"),
            ("opposite_sign", "its values negated"),
        ):
            d = c[key]
            mark = "  <- matches" if key.startswith(c["matching_sign"]) else ""
            out.append(
                f"  {label:24} RMS X {d['rms_um']['X']:.4f} µm, Y "
                f"{d['rms_um']['Y']:.4f} µm; max X {d['max_um']['X']:.4f} µm, Y "
                f"{d['max_um']['Y']:.4f} µm{mark}"
            )
    if result["files"]:
        out.append("")
        for f in result["files"]:
            out.append(
                f"wrote {f['path']} ({f['format']}; sign: correction = −(measured − "
                "commanded), gauge terms removed)"
            )
        if result.get("table_at_measured_nodes") and not _linear_between(identification):
            step = identification.lattice.step_mm
            out.append(
                f"  the table holds the measured nodes, which a controller interpolates "
                f"linearly; the model differs between them: --spacing "
                f"{min(step) / 2:g} writes it at half the measured step"
            )
    if "project" in result:
        p = result["project"]
        out.append(
            f"stored {', '.join(p['groups'])} in {p['path']}"
            + (" (created)" if p["created"] else "")
        )
    return "\n".join(out)
