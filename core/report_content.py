"""What the calibration report says, gathered from a project (GUI-free).

:func:`build_report` reads a project (and, where they are, the compensation files and the
report.json of the run) and returns a :class:`ReportContent`: sections made of paragraphs,
tables, error curves with their uncertainty band and bar charts. The PDF writer
(:mod:`volucal.app.report`) only lays these out on pages; ``volucal report --json`` prints them.

Sources, per section:

- machine and plan: ``/machine``, ``/plan`` and ``/measurements/<line>`` (LineSpec, data);
- traceability: each line's provenance (source file, format, sign convention, corrections),
  the log's user text (machine, serial number, operator, location), its times and environment,
  and the SHA-256 of the file's bytes kept in the project;
- ISO 230-2: :func:`volucal.core.iso230_2.evaluate` on the corrected readings of every linear
  and angular line; ISO 230-1 straightness of the mean profile of every straightness line;
- errors with uncertainty: ``parameters_json`` of ``/identifications/loop`` (the final model;
  ``main`` when there is no loop), band ±2·std (k = 2);
- closed loop, sensitivity, compensation: the ``report_json`` of ``/loops/main``,
  ``/sensitivity/main`` and ``/compensation/main`` (report.json's blocks);
- verified compensation rates: the compensation result's ``verified_on_virtual_machine``, or the
  same block of the run's report.json when its loop results are those of the project;
- conformance: :mod:`volucal.core.conformance` when a tolerance is given.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from .certificate import Certificate
from .conformance import (
    QUANTITIES,
    Conformance,
    accuracy_conformance,
    budget_from,
    volumetric_conformance,
)
from .display_units import DisplayUnits
from .errors import AXIS_ERROR_IDS, ERROR_IDS, ERROR_INFO, SQUARENESS_IDS, error_label
from .identify import UncertaintyBudget
from .iso230_2 import evaluate, straightness
from .machine import AXES
from .measurement import Line
from .project import Project, error_model_from_tree
from .remeasurement import compare
from .report_acceptance import (
    certificate_section,
    iso_graphs_section,
    remeasurement_section,
    signature_section,
    tolerance_section,
    tolerance_summary,
)
from .report_blocks import (
    BarChart,
    Block,
    Curve,
    CurveGrid,
    IsoGraphs,
    Paragraph,
    Section,
    Signatures,
    Table,
)
from .squareness_map import place_text
from .tolerances import Tolerances
from .userror import UserError

#: How many errors each sensitivity table and chart shows (by total index).
TOP_SENSITIVITY = 8
#: The uncertainty budget's terms (:class:`volucal.core.identify.UncertaintyBudget`): unit and
#: meaning; standard uncertainties unless said otherwise.
BUDGET_TERMS = {
    "laser_ppm": ("ppm", "laser wavelength accuracy (±, rectangular)"),
    "air_temp_sensor_c": ("°C", "air temperature sensor (±, rectangular)"),
    "material_temp_sensor_c": ("°C", "material temperature sensor (±, rectangular)"),
    "expansion_coeff_ppm": ("ppm/°C", "expansion coefficient of the scale (±, rectangular)"),
    "material_offset_c": ("°C", "typical |material temperature − 20 °C| in the session"),
    "dead_path_mm": ("mm", "dead path of the laser"),
    "air_temp_change_c": ("°C", "air temperature change during a line"),
    "cosine_urad": ("µrad", "beam misalignment angle"),
    "abbe_mm": ("mm", "Abbe offset of the optics not accounted for"),
    "straightness_pct": ("%", "straightness optics accuracy, of the reading"),
}


@dataclass(frozen=True)
class ReportContent:
    """The whole report: title lines, sections, and the conformance decision if asked for."""

    title: str
    subtitle: str
    generated: str
    sections: tuple[Section, ...]
    conformance: Conformance | None = None
    sources: Mapping[str, str] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """Plain JSON: every section's blocks with a ``type`` key."""
        return {
            "title": self.title,
            "subtitle": self.subtitle,
            "generated": self.generated,
            "sources": dict(self.sources),
            "conformance": None if self.conformance is None else self.conformance.to_json(),
            "sections": [
                {
                    "title": s.title,
                    "blocks": [{"type": type(b).__name__} | _plain(asdict(b)) for b in s.blocks],
                }
                for s in self.sections
            ],
        }

    def text(self) -> str:
        """Every word of the report (titles, paragraphs, table cells), one item per line."""
        out = [self.title, self.subtitle]
        for section in self.sections:
            out.append(section.title)
            for block in section.blocks:
                if isinstance(block, Paragraph):
                    out.append(block.text)
                elif isinstance(block, Table):
                    out += [block.caption, " ".join(block.header)]
                    out += [" ".join(row) for row in block.rows]
                elif isinstance(block, CurveGrid):
                    out += [c.title for c in block.curves]
                elif isinstance(block, IsoGraphs):
                    out += [g for graph in block.graphs for g in (graph.title, graph.caption)]
                elif isinstance(block, Signatures):
                    out += [f"{role}: {name}" for role, name in block.roles]
                else:
                    out.append(block.title)
        return "\n".join(t for t in out if t)


@dataclass(frozen=True)
class ReportRequest:
    """What to report on.

    compensation_dir : where the compensation files are (default: the folder the GUI recorded,
        else ``<project folder>/compensation`` when it exists).
    report_json : the run's report.json, for the verified rates (default:
        ``<project folder>/report.json`` when it exists and belongs to this project).
    tolerance_um, tolerance_on : the conformance decision (``accuracy`` or ``volumetric``).
    certificate : fields that replace those the project keeps (``/report/certificate``, over
        what the logs say).
    tolerances : the ISO 230-2 limits per axis (default: those the project keeps).
    remeasurement_path : a project of the same lines measured again on the compensated machine.
    units : the units deviations and angles are shown in.
    """

    project_path: Path
    compensation_dir: Path | None = None
    report_json: Path | None = None
    tolerance_um: float | None = None
    tolerance_on: str = "accuracy"
    certificate: Certificate | None = None
    tolerances: Tolerances | None = None
    remeasurement_path: Path | None = None
    units: DisplayUnits = field(default_factory=DisplayUnits)


# --------------------------------------------------------------------------------------------
# Building the report
# --------------------------------------------------------------------------------------------


def thermal_sections(project: Project) -> list[Section]:
    """One page per thermal record and channel the project holds (core/thermal_report.py)."""
    from .thermal_report import sections_for_project  # it builds on this module's blocks

    return sections_for_project(project)


def build_report(request: ReportRequest) -> ReportContent:
    """Gather the report of a project (module notes give the sources)."""
    if request.tolerance_on not in QUANTITIES:
        raise UserError(
            f"tolerance on {request.tolerance_on!r}: use one of {', '.join(QUANTITIES)}"
        )
    path = Path(request.project_path)
    project = Project.open(path)
    if project.machine is None or not project.lines:
        raise UserError(f"{path}: the project has no measured lines yet; import a plan first")
    from volucal import __version__

    results = _Results(project)
    measurement = project.measurement()
    budget = budget_from(project.uncertainty)
    conformance = None
    if request.tolerance_um is not None:
        if request.tolerance_on == "accuracy":
            conformance = accuracy_conformance(measurement.lines, budget, request.tolerance_um)
        else:
            tree = results.identification_tree()
            if tree is None:
                raise UserError(
                    f"{path}: no identification in the project; the volumetric "
                    "error cannot be decided on (run volucal identify first)"
                )
            model = error_model_from_tree(tree["model"], project.machine)
            conformance = volumetric_conformance(
                model, tree["covariance"], budget, request.tolerance_um
            )
    compensation_dir = request.compensation_dir or results.compensation_dir(path)
    verification, verification_source = _verification(results, path, request.report_json)
    certificate = Certificate.of_project(project)
    if request.certificate is not None:
        certificate = certificate.with_values(**request.certificate.to_json())
    if not certificate.get("issued"):  # issued when written, unless the user dated it
        certificate = certificate.with_values(issued=datetime.now(UTC).strftime("%Y-%m-%d"))
    tolerances = (
        request.tolerances if request.tolerances is not None else Tolerances.of_project(project)
    )
    comparison = None
    if request.remeasurement_path is not None:
        again = Project.open(request.remeasurement_path)
        if not again.lines:
            raise UserError(f"{request.remeasurement_path}: the re-measurement has no lines")
        comparison = compare(measurement.lines, again.measurement().lines)
    units = request.units
    sources = {
        "project": str(path),
        "project_sha256": _sha256_file(path),
        "compensation_dir": str(compensation_dir) if compensation_dir else "",
        "verification": verification_source,
        "remeasurement": str(request.remeasurement_path or ""),
        "units": f"{units.symbol('um')}, {units.symbol('urad')}",
    }
    tolerance_text = tolerance_summary(measurement.lines, tolerances, budget)
    sections = [
        certificate_section(certificate),
        _summary(project, results, conformance, verification, tolerance_text),
        _machine(project),
        _plan(project, measurement.lines, results),
        _traceability(project, path, measurement.lines),
        _iso230_2(measurement.lines, units),
        iso_graphs_section(measurement.lines, units),
        tolerance_section(measurement.lines, tolerances, budget, units),
        _errors(results, units),
        _loop(results),
        _sensitivity(results),
        _compensation(results, compensation_dir, verification, verification_source),
        remeasurement_section(comparison, Path(request.remeasurement_path or "").name, units),
        _uncertainty(project, budget, results),
        *thermal_sections(project),
    ]
    if conformance is not None:
        sections.append(_conformance(conformance))
    sections.append(signature_section(certificate))
    return ReportContent(
        title="Calibration report",
        subtitle=f"{project.machine.name} — volucal {__version__}",
        generated=datetime.now(UTC).isoformat(timespec="seconds"),
        sections=tuple(s for s in sections if s.blocks),
        conformance=conformance,
        sources=sources,
    )


def default_compensation_dir(project: Project, project_path: Path) -> Path | None:
    """Where the compensation files of the project are expected: the folder the workbench
    recorded for its last export, else ``compensation`` beside the project."""
    return _Results(project).compensation_dir(Path(project_path))


class _Results:
    """The project's stored results as report.json blocks (None when a step was not run)."""

    def __init__(self, project: Project) -> None:
        self.project = project
        self.loop = self._report_json("loops", "main")
        self.sensitivity = self._report_json("sensitivity", "main")
        self.compensation_name = self._compensation_name()
        self.compensation = (
            self._report_json("compensation", self.compensation_name)
            if self.compensation_name
            else None
        )
        tree = self.identification_tree()
        self.parameters = json.loads(tree["parameters_json"]) if tree else None
        # projects written before the identification kept its squareness map have none
        self.squareness_map = json.loads(str(tree.get("squareness_map_json", "{}"))) if tree else {}
        # the plan's identifiability is that of the 21-error fit ("main"): the loop's refits
        # skip the per-line redundancy test
        plan_tree = (
            self.project.result("identifications", "main")
            if "main" in self.project.results("identifications")
            else None
        )
        if plan_tree is None or "identifiability_json" not in plan_tree:
            plan_tree = tree
        self.identifiability = json.loads(plan_tree["identifiability_json"]) if plan_tree else None

    def _report_json(self, kind: str, name: str) -> dict[str, Any] | None:
        if name not in self.project.results(kind):
            return None
        tree = self.project.result(kind, name)
        return json.loads(str(tree["report_json"])) if "report_json" in tree else None

    def _compensation_name(self) -> str | None:
        names = self.project.results("compensation")
        if "main" in names:
            return "main"
        return names[-1] if names else None

    def identification_name(self) -> str | None:
        """The final identification: "loop", else "main", else the last one stored; only
        identification trees (with the parameters block) count."""
        names = [
            n
            for n in self.project.results("identifications")
            if "parameters_json" in self.project.result("identifications", n)
        ]
        for name in ("loop", "main"):
            if name in names:
                return name
        return names[-1] if names else None

    def identification_tree(self) -> dict[str, Any] | None:
        name = self.identification_name()
        return None if name is None else self.project.result("identifications", name)

    def compensation_dir(self, project_path: Path) -> Path | None:
        if self.compensation_name:
            tree = self.project.result("compensation", self.compensation_name)
            recorded = str(tree.get("out_dir", ""))
            if recorded and Path(recorded).is_dir():
                return Path(recorded)
        beside = project_path.parent / "compensation"
        return beside if beside.is_dir() else None


def _verification(
    results: _Results, project_path: Path, report_json: Path | None
) -> tuple[dict[str, Any] | None, str]:
    """The verified rates and where they came from."""
    stored = (results.compensation or {}).get("verified_on_virtual_machine")
    if stored:
        return stored, "project"
    candidate = report_json or project_path.parent / "report.json"
    if not candidate.is_file():
        if report_json is not None:
            raise UserError(f"{report_json}: no such report file")
        return None, ""
    try:
        report = json.loads(candidate.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise UserError(f"{candidate}: not a readable report.json ({exc})") from None
    loop = results.loop or {}
    same_run = (
        isinstance(report, dict)
        and loop
        and report.get("residual_rms_um") == loop.get("residual_rms_um")
        and report.get("cv_rms_um") == loop.get("cv_rms_um")
    )
    if not same_run:
        if report_json is not None:
            raise UserError(
                f"{report_json}: this report.json is not of the project's run (its "
                "loop results differ)"
            )
        return None, ""
    verified = report.get("compensation", {}).get("verified_on_virtual_machine")
    return (verified, str(candidate)) if verified else (None, "")


# --------------------------------------------------------------------------------------------
# Sections
# --------------------------------------------------------------------------------------------


def _summary(
    project: Project,
    results: _Results,
    conformance: Conformance | None,
    verification: Mapping[str, Any] | None,
    tolerances: str = "",
) -> Section:
    machine = project.machine
    assert machine is not None
    readings = sum(int(np.isfinite(s.corrected.deviations).sum()) for s in project.lines.values())
    pairs: list[tuple[str, str]] = [
        ("Machine", machine.name),
        ("Lines measured", f"{len(project.lines)} ({readings} readings)"),
        ("Session", _session_span(project)),
    ]
    ident = results.identifiability
    if ident:
        pairs.append(
            (
                "Identifiability",
                f"rank {ident['rank']} of {ident['unknowns']} unknowns"
                + (
                    f"; not identified: {', '.join(ident['unidentifiable'])}"
                    if ident["unidentifiable"]
                    else "; every error identified"
                ),
            )
        )
    loop = results.loop
    if loop:
        rms = loop["residual_rms_um"]
        cv = loop["cv_rms_um"]
        pairs.append(
            (
                "Residual RMS (closed loop)",
                f"{_f(rms['before_loop'])} → {_f(rms['after_loop'])} µm; cross-validated "
                f"{_f(cv['before_loop'])} → {_f(cv['after_loop'])} µm ({cv['method']})",
            )
        )
        kept = [f"{e['kind']} {e['axis'] or ''}".strip() for e in loop.get("effects", [])]
        pairs.append(("Effects added by the loop", ", ".join(kept) or "none"))
    compensation = results.compensation
    if compensation:
        rate = compensation["rate_percent"]
        pairs.append(
            (
                "Predicted compensation rate (RMS)",
                "volumetric "
                + _xyz(rate["volumetric"], "%")
                + "; axis tables "
                + _xyz(rate["axis_tables"], "%"),
            )
        )
    if verification:
        best = max(
            verification.items(),
            key=lambda kv: np.mean(list(kv[1]["remeasured"]["rms_percent"].values())),
        )
        pairs.append(
            (
                "Verified compensation rate (re-measured, RMS)",
                f"{best[0]}: " + _xyz(best[1]["remeasured"]["rms_percent"], "%"),
            )
        )
    if tolerances:
        pairs.append(("Tolerances per axis (ISO 230-2)", tolerances))
    if conformance is not None:
        pairs.append(
            (
                "Conformance (ISO 14253-1)",
                f"{conformance.verdict}: {conformance.quantity}, "
                f"T = {_f(conformance.tolerance_um)} µm",
            )
        )
    return Section("Summary", (_pairs(pairs),))


def _machine(project: Project) -> Section:
    machine = project.machine
    assert machine is not None
    rows = [("Name", machine.name), ("Chain", f"{machine.chain} (workpiece → tool)")]
    for axis in AXES:
        low, high = machine.stroke(axis)
        lead = machine.screw_lead_mm.get(axis)
        rows.append(
            (
                f"Axis {axis}",
                f"stroke {_f(low, 1)} … {_f(high, 1)} mm"
                + (f", screw lead {_f(lead, 1)} mm" if lead else ""),
            )
        )
    rows.append(("Tool offset", _vec(machine.tool_offset_mm) + " mm"))
    rows.append(("Reference position", _vec(machine.reference_mm) + " mm (every error zero)"))
    return Section("Machine", (_pairs(rows),))


def _plan(project: Project, lines: Sequence[Line], results: _Results) -> Section:
    rows = []
    for line in lines:
        s = line.spec
        up = int(np.sum(line.data.run_direction > 0))
        rows.append(
            (
                s.name,
                s.quantity,
                _vec(s.start_mm),
                _vec(s.direction, 3),
                "" if s.sensitive is None else _vec(s.sensitive, 3),
                _vec(s.reflector_mm),
                str(line.data.targets_mm.size),
                f"{up}/{line.data.runs - up}",
            )
        )
    blocks: list[Block] = [
        Paragraph(
            f"{len(lines)} lines in session order. Plan file: "
            f"{Path(project.plan_path).name if project.plan_path else '(not recorded)'}. "
            "A line reads at start + target · "
            "direction; the reflector is the optics' offset from the spindle gauge point."
        ),
        Table(
            (
                "line",
                "quantity",
                "start mm",
                "direction",
                "sensitive",
                "reflector mm",
                "targets",
                "runs ↑/↓",
            ),
            tuple(rows),
            "llrrrrrr",
        ),
    ]
    ident = results.identifiability
    if ident:
        text = (
            f"Identifiability: rank {ident['rank']} of {ident['unknowns']} unknowns. "
            + (
                "Not identified: " + "; ".join(ident["unidentifiable"]) + ". "
                if ident["unidentifiable"]
                else "Every error is identified by this plan. "
            )
            + _redundancy(ident["redundant_lines"], len(lines))
        )
        blocks.append(Paragraph(text))
    return Section("Measurement plan", tuple(blocks))


def _redundancy(redundant: Sequence[str], count: int) -> str:
    if not redundant:
        return "No line is redundant: every line is needed for the rank."
    if len(redundant) == count:
        return (
            f"Every one of the {count} lines is redundant (the rank holds without it), so "
            "leave-one-line-out cross-validation is possible."
        )
    return "Redundant lines (the rank holds without each): " + ", ".join(redundant) + "."


def _traceability(project: Project, path: Path, lines: Sequence[Line]) -> Section:
    logs = []
    environment = []
    operators: set[str] = set()
    serials: set[str] = set()
    formats: set[str] = set()
    for line in lines:
        stored = project.lines[line.name]
        meta = stored.corrected.metadata
        prov = stored.provenance
        operators.add(str(meta.get("operator", "")).strip())
        serials.add(str(meta.get("serial", "")).strip())
        formats.add(str(prov.get("format", "")))
        digest = hashlib.sha256(stored.source_bytes).hexdigest()
        start, end = _line_times(stored.corrected)
        when = _utc(start) if stored.corrected.start_time else "no date in the log"
        logs.append(
            (
                line.name,
                str(prov.get("source_file", "")),
                str(prov.get("format", "")),
                str(meta.get("serial", "")),
                str(meta.get("operator", "")),
                when + (f" (log: {meta['date']})" if meta.get("date") else ""),
                f"{(end - start) / 60:.0f} min",
                digest[:16],
            )
        )
        env = stored.corrected.environment
        environment.append(
            (
                line.name,
                _pair(env.air_temp_c),
                _pair(env.air_pressure_kpa),
                _pair(env.air_humidity_pct),
                "; ".join(_pair(m) for m in env.material_temp_c) or "–",
                _f(env.expansion_ppm_per_c, 1) if env.expansion_ppm_per_c is not None else "–",
                "yes" if line.spec.env_corrected else "by volucal",
            )
        )
    conventions = sorted(
        {str(project.lines[n.name].provenance.get("sign_convention", "")) for n in lines} - {""}
    )
    # each correction or note once, with the lines it was made on
    noted: dict[str, list[str]] = {}
    for name, stored in project.lines.items():
        for c in [*stored.provenance.get("corrections", []), *stored.provenance.get("notes", [])]:
            noted.setdefault(str(c), []).append(name)
    notes = [f"{c} ({', '.join(sorted(names))})" for c, names in sorted(noted.items())]
    pairs = [
        ("Project file", f"{path.name} (SHA-256 {_sha256_file(path)})"),
        ("Project created / modified", f"{project.created} / {project.modified}"),
        ("Written by", project.creator),
        ("Instrument (log format)", ", ".join(sorted(formats - {""})) or "–"),
        ("Serial numbers in the logs", ", ".join(sorted(serials - {""})) or "–"),
        ("Operators", ", ".join(sorted(operators - {""})) or "–"),
        ("Session", _session_span(project)),
        ("Sign convention", "; ".join(conventions) or "–"),
    ]
    blocks: list[Block] = [
        _pairs(pairs),
        Table(
            (
                "line",
                "file",
                "format",
                "serial no.",
                "operator",
                "start (UTC)",
                "duration",
                "SHA-256 (first 16)",
            ),
            tuple(logs),
            "lllllllll",
            caption="Logs as imported; the bytes of every file are kept in the project.",
        ),
        Table(
            (
                "line",
                "air °C",
                "air kPa",
                "humidity %",
                "material °C",
                "α ppm/°C",
                "env. corrected",
            ),
            tuple(environment),
            "lrrrrrl",
            caption="Environment from the logs (start – end of each line).",
        ),
    ]
    if notes:
        blocks.append(Paragraph("Corrections and notes at import: " + "; ".join(notes), "note"))
    return Section("Traceability", tuple(blocks))


def _iso230_2(lines: Sequence[Line], units: DisplayUnits) -> Section:
    rows = []
    flat = []
    for line in lines:
        if line.spec.quantity == "straightness":
            mean = np.nanmean(line.data.deviations, axis=0)
            ls, ep = straightness(line.data.targets_mm, mean)
            flat.append(
                (
                    line.name,
                    _vec(line.spec.direction, 3),
                    _vec(line.spec.sensitive, 3),
                    units.text(ls, "um", False),
                    units.text(ep, "um", False),
                )
            )
            continue
        r = evaluate(line.data, line.spec.unit)
        rows.append(
            (
                line.name,
                units.symbol(r.unit),
                f"{r.runs_up}/{r.runs_down}",
                *(
                    units.text(getattr(r, f"{key}_um"), r.unit, False)
                    for key in ("A", "A_up", "A_down", "E", "R", "B", "mean_reversal", "M")
                ),
            )
        )
    blocks: list[Block] = [
        Paragraph(
            "Positioning values of ISO 230-2 (clause 2) from the corrected readings of "
            "every linear and angular line: accuracy A (bidirectional, ↑, ↓), systematic "
            "positioning error E, repeatability R, reversal B and mean reversal B̄, mean "
            f"bidirectional positioning error M. Deviations in {units.symbol('um')}, "
            f"angular lines in {units.symbol('urad')}."
        ),
        Table(
            ("line", "unit", "runs ↑/↓", "A", "A↑", "A↓", "E", "R", "B", "B̄", "M"),
            tuple(rows),
            "llrrrrrrrrr",
        ),
    ]
    if flat:
        blocks += [
            Paragraph(
                "Straightness (ISO 230-1) of the mean profile of each straightness line, "
                "about the least-squares and the end-point reference lines."
            ),
            Table(
                (
                    "line",
                    "direction",
                    "sensitive",
                    f"least squares {units.symbol('um')}",
                    f"end point {units.symbol('um')}",
                ),
                tuple(flat),
                "lrrrr",
            ),
        ]
    return Section("Positioning and straightness (ISO 230-2, ISO 230-1)", tuple(blocks))


def _errors(results: _Results, units: DisplayUnits) -> Section:
    parameters = results.parameters
    if not parameters:
        return Section("Identified errors", ())
    curves = []
    for eid in AXIS_ERROR_IDS:
        entry = parameters[eid]
        info = ERROR_INFO[eid]
        std = np.asarray(entry["std"], dtype=float)
        curves.append(
            Curve(
                title=f"{error_label(eid)} — {info.kind}",
                unit=units.symbol(info.unit),
                axis=str(info.axis),
                position_mm=tuple(float(v) for v in entry["position_mm"]),
                value=tuple(float(v) for v in units.convert(entry["value"], info.unit)),
                expanded_uncertainty=tuple(float(v) for v in units.convert(2.0 * std, info.unit)),
            )
        )
    rows = []
    for eid in SQUARENESS_IDS:
        entry = parameters[eid]
        value = float(entry["value"][0])
        u = float(entry["std"][0])
        rows.append(
            (
                error_label(eid),
                ERROR_INFO[eid].description,
                units.text(value, "urad", False),
                units.text(2 * u, "urad", False),
                DisplayUnits(angle="arcsec").text(value, "urad", False),
            )
        )
    name = results.identification_name()
    return Section(
        "Identified errors",
        (
            Paragraph(
                f"The 21 geometric errors (ISO 230-1 ids, the paper's symbols in brackets) of "
                f"the identification '{name}', each over its axis stroke; the band is the "
                "expanded uncertainty U (k = 2): the statistical covariance of the fit and, for "
                "positioning errors, the set-up budget. Zero at the reference position."
            ),
            CurveGrid(tuple(curves), columns=3),
            Table(
                (
                    "squareness",
                    "meaning",
                    f"value {units.symbol('urad')}",
                    f"U {units.symbol('urad')} (k = 2)",
                    "value arcsec",
                ),
                tuple(rows),
                "llrrr",
            ),
            *_paths_squareness(results.squareness_map, units),
        ),
    )


def _paths_squareness(mapped: dict[str, Any], units: DisplayUnits) -> tuple[Any, ...]:
    """The angle between the tool's paths over the measured volume (report.json's
    ``squareness_over_volume``), when the identification holds it."""
    if not mapped:
        return ()
    symbol = units.symbol("urad")

    def pm(entry: dict[str, Any], key: str) -> str:
        value = units.text(entry[f"{key}_urad"], "urad", False)
        return f"{value} ± {units.text(2.0 * entry[f'{key}_std_urad'], 'urad', False)}"

    rows = tuple(
        (
            error_label(sid),
            pm(entry, "at_centre"),
            f"{pm(entry, 'lowest')} at {place_text(entry['lowest_at_mm'])}",
            f"{pm(entry, 'highest')} at {place_text(entry['highest_at_mm'])}",
            ", ".join(entry["tilted_by"]) or "—",
        )
        for sid, entry in mapped.items()
    )
    first = next(iter(mapped.values()))
    volume = ", ".join(f"{axis} {a:g} to {b:g}" for axis, (a, b) in first["volume_mm"].items())
    centre = place_text(first["centre_mm"])
    return (
        Paragraph(
            "What a square or a laser's squareness optics would read on the identified machine: "
            "the angle between the least-squares lines of the tool point's two paths through a "
            "place (ISO 230-1), each over its axis' measured range, with the kept machine "
            f"effects, at the tool offset. Over the measured volume ({volume} mm), at its "
            f"centre {centre} and lowest and highest over 5 × 5 × 5 places in it, each ± U "
            "(k = 2). It differs from the value above by what the angular errors' change draws "
            "through the lever arms of the place and the tool, and by the tilt of a kept "
            "effect (tilted by)."
        ),
        Table(
            (
                "squareness",
                f"at the centre {symbol}",
                f"lowest {symbol}",
                f"highest {symbol}",
                "tilted by",
            ),
            rows,
            "lrrrl",
        ),
    )



def _loop(results: _Results) -> Section:
    loop = results.loop
    if not loop:
        return Section("Closed loop", (Paragraph("The closed loop was not run on this project."),))
    steps = []
    for step in loop["loop"]:
        effect = step["effect"]
        steps.append(
            (
                str(step["step"]),
                effect.get("label", effect["kind"]),
                "kept" if step["kept"] else "rejected",
                _f(step["rms_um"]["before"]),
                _f(step["rms_um"]["after"]),
                _f(step["cv_rms_um"]["before"]),
                _f(step["cv_rms_um"]["after"]),
                str(step.get("reason", "")),
            )
        )
    rms = loop["residual_rms_um"]
    cv = loop["cv_rms_um"]
    steps.append(
        (
            "",
            "whole loop",
            "",
            _f(rms["before_loop"]),
            _f(rms["after_loop"]),
            _f(cv["before_loop"]),
            _f(cv["after_loop"]),
            cv["method"],
        )
    )
    blocks: list[Block] = [
        Paragraph(
            "Each step adds the effect the residual points to, refits, and keeps it only "
            "if the cross-validated RMS improves by a clear margin (docs/method.md §3). "
            "RMS over the displacement readings, µm."
        ),
        Table(
            (
                "step",
                "effect",
                "decision",
                "RMS before",
                "RMS after",
                "CV before",
                "CV after",
                "reason",
            ),
            tuple(steps),
            "llcrrrrl",
        ),
    ]
    groups = _group_rms(loop["loop"])
    if groups:
        names, before, after = groups
        blocks.append(
            BarChart(
                "Residual RMS per group of lines, before and after the loop",
                names,
                ("before", "after"),
                (before, after),
                (),
                "RMS µm (µrad for angular)",
            )
        )
    effects = [
        (e["kind"], e["axis"] or "set-up", _params(e["parameters"]))
        for e in loop.get("effects", [])
    ]
    if effects:
        blocks.append(
            Table(
                ("effect", "axis", "parameters"),
                tuple(effects),
                "lll",
                caption="Effects kept in the final model.",
            )
        )
    for item in loop.get("unexplained", []):
        blocks.append(
            Paragraph(
                f"Unexplained: {item['description']} ({item['where']}, "
                f"{_f(item.get('magnitude_um'))} µm)",
                "note",
            )
        )
    if not loop.get("unexplained"):
        blocks.append(Paragraph("Nothing unexplained is left in the residual.", "note"))
    for warning in loop.get("warnings", []):
        blocks.append(Paragraph(f"Warning: {warning}", "note"))
    return Section("Closed loop", tuple(blocks))


def _group_rms(
    steps: Sequence[Mapping[str, Any]],
) -> tuple[tuple[str, ...], tuple[float, ...], tuple[float, ...]] | None:
    if not steps or "rms_um_by_group" not in steps[0]:
        return None
    before = steps[0]["rms_um_by_group"]["before"]
    kept = [s for s in steps if s["kept"]] or list(steps[:1])
    after = kept[-1]["rms_um_by_group"]["after" if kept[-1]["kept"] else "before"]
    names = tuple(k for k in before if k in after)
    return names, tuple(float(before[k]) for k in names), tuple(float(after[k]) for k in names)


def _sensitivity(results: _Results) -> Section:
    report = results.sensitivity
    if not report:
        return Section(
            "Sensitivity ranking (EFAST)",
            (Paragraph("The sensitivity analysis was not run on this project."),),
        )
    blocks: list[Block] = [
        Paragraph(
            "Global sensitivity by EFAST (paper eqs. 8–18): first-order S1 and total ST indices of "
            "each volumetric error component (Ex, Ey, Ez) and of ET = |E| over the workspace, with "
            "the identified errors as factors. The largest by ST; ± one standard deviation over "
            "independent phase draws."
        )
    ]
    # what an error the plan does not identify varies by was not measured
    unidentified = set((results.identifiability or {}).get("unidentifiable_ids", []))
    shown: set[str] = set()
    for output in ("Ex", "Ey", "Ez", "ET"):
        if output not in report:
            continue
        block = report[output]
        st = block["ST"]
        ranked = sorted(ERROR_IDS, key=lambda e: -_num(st.get(e)))[:TOP_SENSITIVITY]
        shown.update(ranked)
        s1_std = block.get("S1_std", {})
        st_std = block.get("ST_std", {})
        rows = tuple(
            (
                str(k + 1),
                error_label(e) + (" (not identified)" if e in unidentified else ""),
                _pm(block["S1"].get(e), s1_std.get(e)),
                _pm(st.get(e), st_std.get(e)),
            )
            for k, e in enumerate(ranked)
        )
        blocks.append(
            Table(
                ("rank", "error", "S1", "ST"),
                rows,
                "lrrr",
                caption=f"{output}: the {len(ranked)} most influential errors",
            )
        )
        blocks.append(
            BarChart(
                f"{output}: first-order and total indices",
                tuple(ranked),
                ("S1", "ST"),
                (
                    tuple(_num(block["S1"].get(e)) for e in ranked),
                    tuple(_num(st.get(e)) for e in ranked),
                ),
                (
                    tuple(_num(s1_std.get(e)) for e in ranked),
                    tuple(_num(st_std.get(e)) for e in ranked),
                )
                if s1_std
                else (),
                "index",
            )
        )
    if shown & unidentified:
        blocks.insert(
            1,
            Paragraph(
                'Errors marked "not identified" are not seen by this plan, or only in part or in '
                "a combination with others: what they vary by was not all measured (the "
                "analysis' floor of 0.01 µm and 0.1 µrad, or their share of the combination), so "
                "their indices are not the machine's alone. Read the ranking among the "
                "identified errors.",
                "note",
            ),
        )
    return Section("Sensitivity ranking (EFAST)", tuple(blocks))


def _compensation(
    results: _Results,
    folder: Path | None,
    verification: Mapping[str, Any] | None,
    verification_source: str,
) -> Section:
    report = results.compensation
    if not report:
        return Section("Compensation", (Paragraph("No compensation was computed."),))
    blocks: list[Block] = [Paragraph(f"Rate definition: {report['rate_definition']}.", "note")]
    methods = []
    for name, method in report.get("methods", {}).items():
        methods.append(
            (
                name,
                method["description"],
                *_xyz_cells(method["rms_percent"]),
                *_xyz_cells(method["range_percent"]),
            )
        )
    if methods:
        blocks.append(
            Table(
                (
                    "method",
                    "description",
                    "RMS X %",
                    "RMS Y %",
                    "RMS Z %",
                    "range X %",
                    "range Y %",
                    "range Z %",
                ),
                tuple(methods),
                "llrrrrrr",
                caption="Predicted compensation rates on the model.",
            )
        )
    if verification:
        rows = []
        for name, check in verification.items():
            rows.append(
                (
                    name,
                    *_xyz_cells(check["remeasured"]["rms_percent"]),
                    *_xyz_cells(check["remeasured"]["range_percent"]),
                    *_xyz_cells(check.get("true_on_grid", {}).get("rms_percent", {})),
                )
            )
        blocks.append(
            Table(
                (
                    "method",
                    "re-measured RMS X %",
                    "Y %",
                    "Z %",
                    "range X %",
                    "Y %",
                    "Z %",
                    "true grid RMS X %",
                    "Y %",
                    "Z %",
                ),
                tuple(rows),
                "lrrrrrrrrr",
                caption="Verified compensation rates: the plan measured again on the compensated "
                f"machine (source: {_source_name(verification_source)}).",
            )
        )
    else:
        blocks.append(
            Paragraph(
                "No verification measurement of the compensated machine is "
                "recorded; the rates above are predictions.",
                "note",
            )
        )
    blocks += compensation_file_blocks(report.get("files", []), folder)
    return Section("Compensation", tuple(blocks))


#: A compensation file larger than this is listed without a checksum (tables are kilobytes).
CHECKSUM_LIMIT_BYTES = 64 * 1024 * 1024


def compensation_file_blocks(names: Sequence[str], folder: Path | None) -> list[Block]:
    """The run's compensation files with their checksums: only the names the run recorded, found
    in the folder or in its format folders (one level down). The folder comes from the project,
    and a project is data: a name that is not a plain file name, a link, a file outside the
    folder or a huge file is listed, not read."""
    listed = list(dict.fromkeys(names))
    if folder is None or not folder.is_dir():
        return [
            Paragraph(
                f"Compensation files of the run: {', '.join(listed) or 'none'}. Their "
                "folder was not at hand when this report was written, so no checksum "
                "is given.",
                "note",
            )
        ]
    root = folder.resolve()
    rows = []
    for name in listed:
        if Path(name).name != name or name in ("", ".", ".."):
            rows.append((name, "", "not read: not a plain file name"))
            continue
        found = [folder / name] + sorted(
            sub / name for sub in folder.iterdir() if sub.is_dir() and not sub.is_symlink()
        )
        files = [
            f
            for f in found
            if f.is_file() and not f.is_symlink() and f.resolve().is_relative_to(root)
        ]
        if not files:
            rows.append((name, "", "not in the folder"))
        for file in files:
            size = file.stat().st_size
            digest = (
                _sha256_file(file)
                if size <= CHECKSUM_LIMIT_BYTES
                else "not read: larger than 64 MiB"
            )
            rows.append((str(file.relative_to(folder)), f"{size}", digest))
    return [
        Table(
            ("file", "bytes", "SHA-256"),
            tuple(rows),
            "lrl",
            caption=f"Compensation files (folder '{folder.name}'), with the checksums to "
            "compare with what the controller loaded.",
        )
    ]


def _uncertainty(project: Project, budget: UncertaintyBudget, results: _Results) -> Section:
    rows = tuple(
        (
            name,
            _f(float(getattr(budget, name)), 3),
            BUDGET_TERMS.get(name, ("", ""))[0],
            BUDGET_TERMS.get(name, ("", ""))[1],
            "plan" if name in project.uncertainty else "default (not in the plan)",
        )
        for name in budget.__dataclass_fields__
    )
    sigma = ""
    tree = results.identification_tree()
    if tree is not None and "sigma_scale" in tree:
        sigma = (
            f" The a-posteriori standard deviation of unit weight of the fit is "
            f"{_f(float(tree['sigma_scale']), 3)}; the covariance is scaled by it."
        )
    return Section(
        "Uncertainty statement",
        (
            Paragraph(
                "The uncertainties given are expanded uncertainties U = k·u with coverage factor "
                "k = 2 (about 95 % for a normal distribution; GUM, ISO 230-9). The standard "
                "uncertainty u of an identified error combines the statistical covariance of the "
                "weighted least-squares fit (the readings' scatter propagated through the plan) "
                "with the set-up budget below, which acts on positioning errors as a scale error "
                "over the distance from the reference. Rectangular distributions are divided by "
                f"√3. Combined scale uncertainty: {_f(budget.scale_ppm(), 3)} ppm." + sigma
            ),
            Table(
                ("budget term", "value", "unit", "meaning", "from"),
                rows,
                "lrlll",
                caption="Set-up budget: the plan's [uncertainty] table; the terms it does not give "
                "take volucal's defaults.",
            ),
        ),
    )


def _conformance(c: Conformance) -> Section:
    rows = tuple(
        (
            i.name,
            i.where,
            _f(i.value_um),
            _f(i.expanded_uncertainty_um),
            _f(i.value_um + i.expanded_uncertainty_um),
            _f(i.value_um - i.expanded_uncertainty_um),
            i.verdict,
        )
        for i in c.items
    )
    return Section(
        "Conformance (ISO 14253-1)",
        (
            Paragraph(
                f"Decision: the machine {c.verdict} — {c.description}, tolerance "
                f"T = {_f(c.tolerance_um)} µm.",
                "verdict",
            ),
            Paragraph(
                "Rule (ISO 14253-1, upper limit): conformance is proven when y + U ≤ T, "
                "non-conformance when y − U > T; between the two the uncertainty range allows "
                "no decision. " + c.uncertainty_statement + "."
            ),
            Table(("item", "where", "y µm", "U µm", "y + U", "y − U", "decision"), rows, "llrrrrl"),
        ),
    )


# --------------------------------------------------------------------------------------------
# Formatting
# --------------------------------------------------------------------------------------------


def _source_name(source: str) -> str:
    """Where verified rates came from, without a folder path: "project" or the file's name."""
    return source if source in ("", "project") else f"the run's {Path(source).name}"


def _f(value: Any, digits: int = 2) -> str:
    if value is None:
        return "–"
    number = float(value)
    if not math.isfinite(number):
        return "–"
    return f"{number:.{digits}f}".replace("-", "−")


def _num(value: Any) -> float:
    if value is None:
        return 0.0
    number = float(value)
    return number if math.isfinite(number) else 0.0


def _pm(value: Any, std: Any) -> str:
    return _f(value, 3) + ("" if std is None else f" ± {_f(std, 3)}")


def _vec(values: Sequence[float] | None, digits: int = 1) -> str:
    if values is None:
        return ""
    return " ".join(_f(v, digits) for v in values)


def _pair(values: tuple[float, float] | None) -> str:
    if values is None:
        return "–"
    return f"{_f(values[0])} – {_f(values[1])}"


def _xyz(rates: Mapping[str, Any], unit: str) -> str:
    return " ".join(f"{a} {_f(rates.get(a), 1)}{unit}" for a in AXES)


def _xyz_cells(rates: Mapping[str, Any]) -> tuple[str, str, str]:
    return (_f(rates.get("X"), 1), _f(rates.get("Y"), 1), _f(rates.get("Z"), 1))


def _params(parameters: Mapping[str, Any]) -> str:
    parts = []
    for key, value in parameters.items():
        if isinstance(value, float):
            parts.append(f"{key} {value:.4g}")
        elif isinstance(value, int | str):
            parts.append(f"{key} {value}")
        elif isinstance(value, list) and value and all(isinstance(v, str) for v in value):
            parts.append(f"{key} {', '.join(value)}")
    return "; ".join(parts)


def _pairs(pairs: Sequence[tuple[str, str]]) -> Table:
    return Table((), tuple((k, v) for k, v in pairs), "ll")


def _line_times(data: Any) -> tuple[float, float]:
    times = np.asarray(data.times_s, dtype=float)
    start = float(data.start_time) + float(np.nanmin(times))
    end = float(data.start_time) + float(np.nanmax(times))
    return start, end


def _session_span(project: Project) -> str:
    # a log without an absolute start time (start_time 0) has readings but no date
    spans = [_line_times(s.corrected) for s in project.lines.values() if s.corrected.start_time]
    if not spans:
        return "no dates in the logs"
    start = min(s for s, _ in spans)
    end = max(e for _, e in spans)
    return f"{_utc(start)} to {_utc(end)} (UTC, from the logs)"


def _utc(seconds: float) -> str:
    return datetime.fromtimestamp(seconds, UTC).strftime("%Y-%m-%d %H:%M")


def _sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _plain(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
