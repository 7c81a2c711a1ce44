"""The workbench's long jobs as plain functions (GUI-free): request in, result out.

Each job takes ``progress`` and ``cancel`` like the core steps it calls, so that a
:class:`~volucal.app.tasks.Task` runs it on a worker thread and a test can call it directly.
"""

from __future__ import annotations

import hashlib
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from volucal.core.calibrate import CalibrationRequest, calibrate
from volucal.core.compensation import ExportOptions, ExportResult, ModelSource, export_model
from volucal.core.compensation.export import compensation_report
from volucal.core.compensation.source import ErrorSource
from volucal.core.effects import Effect
from volucal.core.identify import (
    CrossValidation,
    Identification,
    IdentifyOptions,
    UncertaintyBudget,
    cross_validate,
    identify,
)
from volucal.core.loop_periodic import reported_taken_out
from volucal.core.measurement import Measurement
from volucal.core.progress import CancelToken, ProgressCallback, check, report
from volucal.core.project import Project
from volucal.core.readings import flatten
from volucal.core.residuals import LoopOptions, LoopResult, close_loop
from volucal.core.resources import demo_plan
from volucal.core.result_trees import loop_result_trees, stored_source
from volucal.core.squareness_map import identification_squareness

from .factors import RANKING_GRID_MM, SensitivitySetup, sensitivity_tree
from .records import (
    IdentificationRecord,
    Live,
    LoopRecord,
    identification_result_tree,
    json_text,
    loop_identifiability,
    stored_model,
)


def _sub(progress: ProgressCallback | None, start: float, stop: float) -> ProgressCallback | None:
    if progress is None:
        return None
    return lambda f, m: progress(start + (stop - start) * f, m)


def budget_of(project: Project) -> UncertaintyBudget:
    """The plan's uncertainty budget, as ``volucal calibrate`` uses it."""
    return UncertaintyBudget.from_mapping(project.uncertainty) if project.uncertainty else \
        UncertaintyBudget()


# --------------------------------------------------------------------------------------------
# Identification and the loop
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Identified:
    """An identification with what the window stores and shows of it, made where it was
    computed (a worker process): the GUI thread only files them."""

    identification: Identification
    options: IdentifyOptions
    record: IdentificationRecord
    stored: dict[str, Any]

    def tree(self) -> dict[str, Any]:
        return self.stored


def without_system(identification: Identification) -> Identification:
    """The identification without its linear system (the normal equations of every line: tens
    of megabytes for a 49-line plan), which the workbench never reads once the records and
    trees are made: what a worker process sends back to the window is then small."""
    return replace(identification, system=None)  # type: ignore[arg-type]


def run_identification(measurement: Measurement, options: IdentifyOptions,
                       progress: ProgressCallback | None = None,
                       cancel: CancelToken | None = None, name: str = "main") -> Identified:
    identification = identify(measurement, options, progress=progress, cancel=cancel)
    squareness = identification_squareness(identification)  # once, for tree and record
    return Identified(
        without_system(identification), options,
        IdentificationRecord.from_identification(name, identification, options,
                                                 squareness_map=squareness),
        identification_result_tree(identification, options, squareness_map=squareness))


@dataclass(frozen=True, eq=False)
class LoopRun:
    """A closed loop with its project trees and view records (made in the worker)."""

    loop: LoopResult
    options: LoopOptions
    stored: dict[tuple[str, str], dict[str, Any]]
    records: dict[tuple[str, str], Any]

    @classmethod
    def of(cls, loop: LoopResult, options: LoopOptions) -> LoopRun:
        identify_options = options.identify
        # once each, for trees and records
        maps = {"main": identification_squareness(loop.base),
                "loop": identification_squareness(loop.final)}
        trees = loop_result_trees(loop, identify_options, maps)
        records = {
            ("identifications", "main"): IdentificationRecord.from_identification(
                "main", loop.base, identify_options, squareness_map=maps["main"]),
            ("identifications", "loop"): IdentificationRecord.from_identification(
                "loop", loop.final, loop.identify_options(identify_options),
                loop_identifiability(loop), maps["loop"]),
            ("loops", "main"): LoopRecord.from_loop("main", loop),
        }
        light = replace(loop, base=without_system(loop.base), final=without_system(loop.final))
        return cls(light, options, trees, records)

    def trees(self) -> dict[tuple[str, str], dict[str, Any]]:
        """The project results of a loop: the identifications before and after, the report."""
        return self.stored

    def live(self) -> dict[tuple[str, str], Any]:
        """The same results as the document's live objects (core object and view record)."""
        values = {("identifications", "main"): self.loop.base,
                  ("identifications", "loop"): self.loop.final, ("loops", "main"): self.loop}
        return {key: Live(values[key], record) for key, record in self.records.items()}


def run_loop(measurement: Measurement, options: LoopOptions,
             progress: ProgressCallback | None = None,
             cancel: CancelToken | None = None) -> LoopRun:
    return LoopRun.of(close_loop(measurement, options, progress, cancel), options)


@dataclass(frozen=True, eq=False)
class Refit:
    """The 21 errors refitted with the effects the user accepted, with the record and tree of
    the identification it replaces (``name``)."""

    identification: Identification
    cross_validation: CrossValidation
    options: IdentifyOptions
    accepted: tuple[str, ...]
    rejected: tuple[str, ...]
    record: IdentificationRecord
    stored: dict[str, Any]


def refit_with_effects(
    measurement: Measurement,
    effects: Sequence[Effect],
    options: IdentifyOptions,
    initial: Any,
    redundant_lines: Sequence[str],
    rejected: Sequence[str] = (),
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
    name: str = "loop",
    periodic: Mapping[str, Any] | None = None,
) -> Refit:
    """Identify again with exactly ``effects`` (the loop's refit: no redundancy analysis, the
    previous model as the linearisation point) and cross-validate as the loop does; of the
    readings less the error periodic in time the loop took out of them (``periodic``, its
    report entry ``unexplained[].periodic``), where it took one out."""
    refit_options = replace(options, redundancy=False, max_iterations=3)
    readings = flatten(measurement)
    if periodic is not None:
        readings = reported_taken_out(readings, periodic)
    result = identify(measurement, refit_options, effects=list(effects), progress=_sub(
        progress, 0.0, 0.8), cancel=cancel, initial=initial, readings=readings)
    check(cancel)
    report(progress, 0.85, "cross-validating")
    cv = cross_validate(result.system, result.readings, list(redundant_lines))
    # the plan's redundant lines, as the loop's own final identification carries them
    identifiability = dict(result.identifiability.to_json())
    identifiability["redundant_lines"] = list(redundant_lines)
    identifiability["redundancy_from"] = "the 21-error fit before the loop"
    report(progress, 1.0, "refitted")
    squareness = identification_squareness(result)  # once, for tree and record
    return Refit(without_system(result), cv, options, tuple(e.label for e in effects),
                 tuple(rejected),
                 IdentificationRecord.from_identification(name, result, options, identifiability,
                                                          squareness),
                 identification_result_tree(result, options, identifiability, squareness))


# --------------------------------------------------------------------------------------------
# The demo project
# --------------------------------------------------------------------------------------------


def demo_project_path(cache_dir: Path) -> Path:
    """Where the demo project of this volucal version and demo data set is cached."""
    from volucal import __version__

    digest = hashlib.sha256(demo_plan().read_bytes() + __version__.encode()).hexdigest()[:12]
    return Path(cache_dir) / f"demo-{digest}.h5"


@dataclass(frozen=True, eq=False)
class DemoProject:
    path: Path
    loop: LoopRun
    sensitivity: Any


def build_demo_project(path: Path, sensitivity_n: int = 1400,
                       progress: ProgressCallback | None = None,
                       cancel: CancelToken | None = None) -> DemoProject:
    """Run ``volucal calibrate`` on the embedded demo plan and store the workbench's results
    (residuals, effect candidates, the sensitivity ranking over a workspace grid with its arrays)
    with it, at ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.stem + ".partial.h5")
    options = LoopOptions()
    result = calibrate(
        CalibrationRequest(plan_path=demo_plan(), project_path=partial, loop=options,
                           sensitivity=False),
        progress=_sub(progress, 0.0, 0.8), cancel=cancel,
    )
    loop = result.loop
    budget_options = replace(options, identify=replace(options.identify,
                                                       budget=loop.base.budget))
    run = LoopRun.of(loop, budget_options)
    setup = SensitivitySetup.identified(
        result.source.model, loop.final.covariance, n=sensitivity_n, identification="loop",
        not_identified=loop.base.identifiability.unidentifiable_ids)
    check(cancel)
    sensitivity = setup.run(result.source.model, loop.final.covariance, RANKING_GRID_MM,
                            progress=_sub(progress, 0.8, 0.95), cancel=cancel)
    report(progress, 0.96, "saving the demo project")
    project = Project.open(partial)
    for (kind, name), tree in run.trees().items():
        project.put_result(kind, name, tree)
    project.put_result("sensitivity", "main", sensitivity_tree(sensitivity, setup))
    project.save(path)
    partial.unlink(missing_ok=True)
    report(progress, 1.0, "demo project ready")
    return DemoProject(path, run, sensitivity)


# --------------------------------------------------------------------------------------------
# Compensation
# --------------------------------------------------------------------------------------------


def export_source(project: Project, identification: str, with_effects: bool = True
                  ) -> ErrorSource:
    """The error source of an export.

    With effects: the stored identification's 21 errors and the loop's kept machine effects
    (reversal, cycles, ...) over its measured range, read exactly as ``volucal export PROJECT
    --identification NAME`` and ``volucal calibrate --export`` read it (same files), so that
    the tables differ forward and backward. Without: the 21 errors alone, direction-free, as a
    :class:`ModelSource` over the strokes.
    """
    if with_effects:
        return stored_source(project, identification)
    return ModelSource(stored_model(project, identification))


@dataclass(frozen=True, eq=False)
class ExportPreview:
    """An export written to a temporary folder, read back, and what it predicts."""

    result: ExportResult
    texts: dict[str, str]
    report: dict[str, Any]


def preview_export(source: ErrorSource, format: str, options: ExportOptions,
                   progress: ProgressCallback | None = None,
                   cancel: CancelToken | None = None) -> ExportPreview:
    folder = Path(tempfile.mkdtemp(prefix="volucal-preview-"))
    try:
        result = export_model(source, format, folder, options, progress, cancel)
        texts = {}
        for file in result.files:
            data = file.read_bytes()
            texts[file.name] = data.decode("utf-8", errors="replace")
        report_block = compensation_report(source, tuple(result.files), result.verification)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return ExportPreview(result, texts, report_block)


def write_export(source: ErrorSource, format: str, out_dir: Path, options: ExportOptions,
                 progress: ProgressCallback | None = None,
                 cancel: CancelToken | None = None) -> ExportPreview:
    result = export_model(source, format, out_dir, options, progress, cancel)
    texts = {f.name: f.read_bytes().decode("utf-8", errors="replace") for f in result.files}
    return ExportPreview(result, texts, compensation_report(source, tuple(result.files),
                                                            result.verification))


def compensation_tree(preview: ExportPreview, identification: str, with_effects: bool,
                      out_dir: Path | None) -> dict[str, Any]:
    """What the project keeps of an export (the files themselves stay on disk)."""
    return {
        "report_json": json_text(preview.report),
        "export_json": json_text(preview.result.to_json()),
        "identification": identification,
        "with_effects": with_effects,
        "out_dir": "" if out_dir is None else str(out_dir),
    }
