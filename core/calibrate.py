"""The whole job: import, identify, close the loop, rank by sensitivity, compensate, report.

``calibrate(CalibrationRequest(...))`` is what ``volucal calibrate`` and ``volucal demo`` run. It
returns the report.json content (DESIGN.md contract) and writes the project, the report and the
compensation files it is asked for.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .compensation.export_common import DEFAULT_MAX_CORRECTION_UM, ExportOptions
from .compensation.verify import RATE_FLOOR_UM, rate_text
from .errors import ERROR_INFO, ErrorModel
from .identify import Identification, UncertaintyBudget, parameters_report
from .loop_source import LoopSource, measured_range, parameter_map
from .measurement import Measurement
from .progress import CancelToken, ProgressCallback, check, report
from .residuals import (
    BOTH_WAYS,
    ESTIMATED_AGAIN,
    PLACED_AGAIN,
    TOGETHER,
    LoopOptions,
    LoopResult,
    close_loop,
)
from .squareness_map import GRID_PER_AXIS, place_text, squareness_report
from .thermal import UNIT_SYMBOL
from .userror import UserError

FloatArray = NDArray[np.float64]


def refined_covariance(identification: Identification, refined: ErrorModel) -> FloatArray:
    """Covariance of ``refined`` (the model with its higher-order refinements folded in, from
    :func:`~volucal.core.effects.refined_model`) over its own parameters.

    A refined function is a node table whose values are the coarse function plus the refinement
    at the nodes; both are linear in the fitted unknowns, so the covariance propagates exactly
    (cross terms included) from the fit's covariance of all its unknowns.
    """
    if refined.parameter_count == identification.model.parameter_count:
        return identification.covariance
    mapping = parameter_map(identification, refined)
    covariance_all = identification.normal_inverse * identification.sigma_scale**2
    return np.asarray(mapping @ covariance_all @ mapping.T)


@dataclass(frozen=True)
class CalibrationRequest:
    plan_path: Path
    project_path: Path | None = None
    report_path: Path | None = None
    export_dir: Path | None = None
    export_formats: tuple[str, ...] = ("linuxcnc", "csv")
    #: plausibility limit of the exported corrections (µm); None exports any size
    max_correction_um: float | None = DEFAULT_MAX_CORRECTION_UM
    #: the folder the plan's files may lie in (None: the plan's own folder)
    files_root: Path | None = None
    loop: LoopOptions = field(default_factory=LoopOptions)
    sensitivity: bool = True
    sensitivity_n: int = 1400
    drop_outliers: bool = False


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    report: dict[str, Any]
    loop: LoopResult
    source: LoopSource
    exports: tuple[Any, ...]
    import_notes: tuple[str, ...]


def calibrate(
    request: CalibrationRequest,
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
) -> CalibrationResult:
    """Run the whole loop on a plan and write what the request asks for."""
    from volucal import __version__

    from .io.plan import import_plan, load_plan

    def sub(start: float, stop: float) -> ProgressCallback | None:
        if progress is None:
            return None
        return lambda f, m: progress(start + (stop - start) * f, m)

    report(progress, 0.0, "reading the plan")
    plan = load_plan(request.plan_path, files_root=request.files_root)
    imported = import_plan(
        plan, drop_outliers=request.drop_outliers, progress=sub(0.0, 0.1), cancel=cancel
    )
    measurement = imported.measurement
    budget = (
        UncertaintyBudget.from_mapping(plan.uncertainty)
        if plan.uncertainty
        else UncertaintyBudget()
    )
    loop_options = replace(request.loop, identify=replace(request.loop.identify, budget=budget))
    check(cancel)
    loop = close_loop(measurement, loop_options, sub(0.1, 0.7), cancel)
    final = loop.final
    source = LoopSource(final, measured_range(final))
    result: dict[str, Any] = {
        "volucal_version": __version__,
        "plan": str(Path(request.plan_path)),
        "machine": {
            "name": measurement.machine.name,
            "chain": measurement.machine.chain,
            "tool_offset_mm": list(measurement.machine.tool_offset_mm),
        },
        "lines": len(measurement.lines),
        "readings": int(len(final.readings)),
        "parameters": parameters_report(final),
        # what the plan can see, with the redundant-line analysis, is the base fit's
        "identifiability": loop.base.identifiability.to_json(),
        "sign_conventions": sorted({line.sign_convention for line in imported.lines}),
        "outlier_flags": [f"line {f.line}: {f.reason}" for f in imported.flags],
        "outliers_dropped": imported.outliers_dropped,
    }
    result["volumetric_error_um"] = volumetric_summary(source)
    result["squareness_over_volume"] = squareness_report(source)
    result |= loop.to_report()
    sensitivity_result = None
    if request.sensitivity:
        from .sensitivity import analyse_model

        check(cancel)
        report(progress, 0.72, "global sensitivity (EFAST)")
        sensitivity_result = analyse_model(
            source.model,
            refined_covariance(final, source.model),
            n=request.sensitivity_n,
            seed=0,
            map_step_mm=100.0,
            not_identified=loop.base.identifiability.unidentifiable_ids,
            progress=sub(0.72, 0.85),
            cancel=cancel,
        )
        result["sensitivity"] = sensitivity_result.to_report()
    exports = []
    files: list[str] = []
    refused: UserError | None = None
    if request.export_dir is not None:
        from .compensation.export import export_model

        options = ExportOptions(max_correction_um=request.max_correction_um)
        try:
            for fmt in request.export_formats:
                check(cancel)
                report(progress, 0.86, f"exporting {fmt}")
                out = export_model(source, fmt, Path(request.export_dir) / fmt, options)
                exports.append(out)
                files += [str(p) for p in out.files]
        except UserError as exc:
            # the identification and the loop are still the user's: saved below, then the
            # refusal is raised
            refused = exc
            result["warnings"] = [*result.get("warnings", []), f"export refused: {exc}"]
    from .compensation.export import compensation_report

    report(progress, 0.93, "predicting the compensation")
    verification = exports[0].verification if exports else None
    result["compensation"] = compensation_report(source, tuple(files), verification)
    result["warnings"] = [*result.get("warnings", []), *_held_axes_warnings(measurement)]
    if request.project_path is not None:
        report(progress, 0.96, "saving the project")
        save_project(
            request.project_path, imported, loop, result, sensitivity_result, loop_options.identify
        )
    if request.report_path is not None:
        write_json_atomic(request.report_path, result)
    if refused is not None:
        saved = [str(p) for p in (request.project_path, request.report_path) if p is not None]
        kept = f" ({', '.join(saved)} written)" if saved else ""
        raise UserError(f"{refused}{kept}") from refused
    report(progress, 1.0, "done")
    notes = tuple(n for line in imported.lines for n in line.notes)
    return CalibrationResult(result, loop, source, tuple(exports), notes)


def volumetric_summary(source: LoopSource, spacing_mm: float = 25.0) -> dict[str, dict[str, float]]:
    """Max |E| and RMS of Ex, Ey, Ez and ET (eq. 7) of the identified machine (21 errors with the
    kept machine effects, both approach directions) on a regular grid of the workspace, µm."""
    axes = [
        np.linspace(low, high, max(2, int(round((high - low) / spacing_mm)) + 1))
        for low, high in (source.machine.stroke(a) for a in "XYZ")
    ]
    grid = np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], axis=-1)
    errors = np.vstack([source.error_um(grid, np.full_like(grid, s)) for s in (1.0, -1.0)])
    components = {
        "Ex": errors[:, 0],
        "Ey": errors[:, 1],
        "Ez": errors[:, 2],
        "ET": np.linalg.norm(errors, axis=1),
    }
    return {
        name: {"max_abs": float(np.max(np.abs(v))), "rms": float(np.sqrt(np.mean(v**2)))}
        for name, v in components.items()
    }


def identification_tree(identification: Identification) -> dict[str, Any]:
    from .project import error_model_to_tree

    return {
        "model": error_model_to_tree(identification.model),
        "covariance": identification.covariance,
        "sigma_scale": identification.sigma_scale,
        "identifiability_json": json.dumps(identification.identifiability.to_json()),
        "parameters_json": json.dumps(parameters_report(identification)),
    }


def _held_axes_warnings(measurement: Measurement) -> list[str]:
    """What calibrating says of the axes no line moved: held at one position (a plan that
    measures X alone) or at several (X lines at two heights of Y)."""
    held = measurement.held_axes()
    once = {axis: at[0] for axis, at in held.items() if len(at) == 1}
    warnings = []
    if once:
        where = ", ".join(f"{axis} = {position:g} mm" for axis, position in once.items())
        warnings.append(
            f"no measured line moved {' or '.join(once)} (every reading at {where}): no "
            "error of their own travel is identified, their compensation tables correct none, "
            "and no rate is predicted along them where the model has no error"
        )
    for axis, at in held.items():
        if len(at) > 1:
            where = ", ".join(f"{position:g}" for position in at)
            warnings.append(
                f"no measured line moved {axis} (its lines held it at {axis} = {where} mm): no "
                f"error of its own travel is identified; along {axis} the model and its tables "
                "hold only what the lines measured at those positions, and nothing was "
                "measured between them"
            )
    return warnings


def save_project(
    path: Path,
    imported: Any,
    loop: LoopResult,
    result: Mapping[str, Any],
    sensitivity_result: Any = None,
    identify_options: Any = None,
) -> None:
    """Write (or overwrite) the project with the measurement and every result of the run."""
    from .project import Project

    project = Project.create(imported.measurement.machine)
    project.add_lines(
        imported.plan,
        imported.measurement,
        imported.source_bytes,
        imported.raw,
        provenance={line.name: line.provenance() for line in imported.lines},
    )
    # the identifications with their residuals, every effect tried and the sensitivity arrays:
    # what the workbench's views draw (result_trees)
    from .result_trees import store_calibration

    store_calibration(
        project,
        loop,
        identify_options,
        sensitivity_result,
        squareness={"loop": result["squareness_over_volume"]},
    )
    project.put_result("compensation", "main", {"report_json": json.dumps(result["compensation"])})
    project.save(path)


def write_json_atomic(path: Path, content: Mapping[str, Any]) -> None:
    """Write JSON through a temporary file and a rename, so a reader never sees half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            json.dump(_jsonable(content), handle, indent=2, allow_nan=False)
            handle.write("\n")
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _jsonable(value: Any) -> Any:
    """Plain JSON: NaN and infinities become null, numpy scalars and arrays plain numbers."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.floating, float)):
        number = float(value)
        return number if np.isfinite(number) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


#: The console lists at most this many outlier flags; report.json holds them all.
OUTLIERS_LISTED = 10


def summary_table(result: Mapping[str, Any]) -> str:
    """The before/after table the CLI prints."""
    lines = []
    lines.append(f"lines {result['lines']}, readings {result['readings']}")
    ident = result["identifiability"]
    lines.append(f"identifiability: rank {ident['rank']} of {ident['unknowns']} unknowns")
    for text in ident["unidentifiable"]:
        lines.append(f"  not identified: {text}")
    flags = result.get("outlier_flags", [])
    if flags:
        how = (
            "set to missing (--drop-outliers)"
            if result.get("outliers_dropped")
            else "kept in the fit (--drop-outliers leaves them out)"
        )
        lines.append(f"{len(flags)} outlier flag(s) at import, {how}:")
        lines += [f"  {text}" for text in flags[:OUTLIERS_LISTED]]
        if len(flags) > OUTLIERS_LISTED:
            lines.append(f"  … and {len(flags) - OUTLIERS_LISTED} more (report.json outlier_flags)")
    volumetric = result.get("volumetric_error_um")
    if volumetric:
        cells = ", ".join(
            f"{k} max {v['max_abs']:.2f} / RMS {v['rms']:.2f}" for k, v in volumetric.items()
        )
        lines.append(f"volumetric error of the identified machine (µm, 25 mm grid): {cells}")
    lines += _squareness_lines(result)
    lines.append("")
    labels = [step["effect"].get("label", step["effect"]["kind"]) for step in result["loop"]]
    width = max([42, *map(len, labels)])  # the label column: every label whole
    pad = " " * (width - 42)
    lines.append(f"{'closed loop':<{width + 5}}RMS µm         CV RMS µm   kept")
    lines.append(f"{pad}                                            before  after   before  after")
    for step, label in zip(result["loop"], labels, strict=True):
        # why not, in a few words; two set-up errors kept in one refit say so
        kept = "yes" if step["kept"] else f"no: {step['verdict']}"
        kept += ", together" if step["verdict"] == TOGETHER else ""
        # a kept effect placed again is no second effect
        kept += f", {ESTIMATED_AGAIN}" if step["verdict"] == ESTIMATED_AGAIN else ""
        lines.append(
            f"{step['step']:>2} {label:<{width}} "
            f"{step['rms_um']['before']:6.3f} {step['rms_um']['after']:6.3f}"
            f"   {step['cv_rms_um']['before']:6.3f} {step['cv_rms_um']['after']:6.3f}"
            f"   {kept}"
        )
    rms = result["residual_rms_um"]
    cv = result["cv_rms_um"]
    lines.append(
        f"   {'whole loop':<{width}} {rms['before_loop']:6.3f} {rms['after_loop']:6.3f}"
        f"   {cv['before_loop']:6.3f} {cv['after_loop']:6.3f}   ({cv['method']})"
    )
    judged = cv.get("all_lines")
    if judged and (judged["before_loop"], judged["after_loop"]) != (
        cv["before_loop"],
        cv["after_loop"],
    ):
        lines.append(
            f"   {'every line, angular at σ exchange':<{width}} {'':6} {'':6}"
            f"   {judged['before_loop']:6.3f} {judged['after_loop']:6.3f}"
        )
    # why an effect the table showed kept was taken out again, why a step kept what did not
    # predict best there (the loop ran on both ways and that route ended better), and a kept
    # drift's time constant a keep moved
    for step, label in zip(result["loop"], labels, strict=True):
        reason = step.get("reason", "")
        if step.get("stage") in ("backward", "audit") and not step["kept"]:
            lines.append(f"   step {step['step']}, {label} taken out: {reason}")
        elif step["kept"] and BOTH_WAYS in reason:
            lines.append(
                f"   step {step['step']}, {label} kept: {reason[reason.index(BOTH_WAYS) :]}"
            )
        elif step["kept"] and PLACED_AGAIN in reason:
            start = reason.rfind("; ", 0, reason.index(PLACED_AGAIN))
            moved = reason[start + 2 :] if start >= 0 else reason
            lines.append(f"   step {step['step']}, {label} kept: {moved}")
    basis = result.get("basis")
    if basis:
        tried = ", ".join(
            f"{t['spacing_mm']:g} mm {t['cv_rms_all_lines']:.3f} / {t['cv_rms_um']:.3f}"
            for t in basis["tried"]
        )
        refused = "".join(
            f"; {t['spacing_mm']:g} mm refused: it leaves a systematic residual on "
            f"{', '.join(t['leaves_structure_on'])}"
            for t in basis["tried"]
            if t.get("leaves_structure_on")
        )
        how = (
            f" (CV RMS µm over the readings each and the {basis['reference_spacing_mm']:g} mm "
            f"basis both predict, every line, angular at σ exchange / lengths alone: "
            f"{tried}{refused})"
            if basis["chosen_by"] == "cross-validation"
            else ""
        )
        lines.append(
            f"basis of the 21 errors: cubic B-splines every {basis['spacing_mm']:g} mm, "
            f"{'chosen by cross-validation' if how else 'as set'}{how}"
        )
        missed = basis.get("shape_missed")
        if missed:
            largest = sorted(missed["rms"].items(), key=lambda kv: -kv[1])
            sizes = ", ".join(
                f"{eid} {value:.3f} {UNIT_SYMBOL[ERROR_INFO[eid].unit]}" for eid, value in largest
            )
            lines.append(
                f"   what it misses of the errors' shape against {missed['against_spacing_mm']:g} "
                f"mm, beyond the noise, is in their uncertainty (RMS over the stroke): {sizes}"
            )
    if result["effects"]:
        lines.append("")
        lines.append("effects kept:")
        for effect in result["effects"]:
            lines.append(
                f"  {effect['kind']} {effect['axis'] or ''}: {_short(effect['parameters'])}"
            )
    for item in result.get("unexplained", []):
        lines.append(f"unexplained: {item['description']}")
    for warning in result.get("warnings", []):
        lines.append(f"warning: {warning}")
    methods = result.get("compensation", {}).get("methods", {})
    if methods:
        lines.append("")
        lines.append(
            "predicted compensation rate on the model (RMS-based, %)         X      Y      Z"
        )
        cells = {
            name: [rate_text(method["rms_percent"].get(axis)) for axis in "XYZ"]
            for name, method in methods.items()
            if method.get("rms_percent")
        }
        for name, row in cells.items():
            lines.append(f"  {name:<60} {'  '.join(row)}")
        if any(cell.strip() == "—" for row in cells.values() for cell in row):
            lines.append(
                f"  —: no error along that direction to compensate (below {RATE_FLOOR_UM * 1e3:g} "
                "nm RMS on the model)"
            )
    return "\n".join(lines)


def _squareness_lines(result: Mapping[str, Any]) -> list[str]:
    """Each squareness as the parameter and as the tool's paths make it over the volume (none
    for a result without the map, e.g. a loop's alone)."""
    entries = result.get("squareness_over_volume")
    if not entries:
        return []
    n = GRID_PER_AXIS
    out = [
        "squareness (µrad): the model's parameter; the angle between the tool's paths (tool "
        f"offset {place_text(result['machine']['tool_offset_mm'])}) through the centre of the "
        f"measured volume, and its lowest … highest over {n}×{n}×{n} places in it, each ± its "
        "standard uncertainty"
    ]
    for sid, e in entries.items():
        tilted = f"; tilted by {', '.join(e['tilted_by'])}" if e["tilted_by"] else ""
        out.append(
            f"  {sid} {e['parameter_urad']:.2f}; {_pm(e, 'at_centre')}; "
            f"{_pm(e, 'lowest')} at {place_text(e['lowest_at_mm'])} … "
            f"{_pm(e, 'highest')} at {place_text(e['highest_at_mm'])}{tilted}"
        )
    return out


def _pm(entry: Mapping[str, Any], key: str) -> str:
    return f"{entry[f'{key}_urad']:.2f} ± {entry[f'{key}_std_urad']:.2f}"


def _short(parameters: Mapping[str, Any]) -> str:
    """An effect's first parameters in a few words; a vector (an Abbe offset in x, y, z) whole."""
    parts = []
    for key, value in parameters.items():
        if isinstance(value, float):
            parts.append(f"{key} {value:.4g}")
        elif isinstance(value, (int, str)):
            parts.append(f"{key} {value}")
        elif isinstance(value, (list, tuple)) and all(isinstance(v, float) for v in value):
            parts.append(f"{key} ({', '.join(f'{v:.4g}' for v in value)})")
    return ", ".join(parts[:5])


def main_report_keys() -> Sequence[str]:
    """The keys report.json always has (DESIGN.md)."""
    return (
        "volucal_version",
        "plan",
        "lines",
        "readings",
        "parameters",
        "identifiability",
        "loop",
        "effects",
        "residual_rms_um",
        "cv_rms_um",
        "unexplained",
        "sensitivity",
        "compensation",
    )
