"""Export compensation for a controller: the one entry point the CLI and the GUI call.

:func:`export_model` computes the tables of an error source, writes the files of the chosen
format, writes a manifest (``volucal_export.json``: files, units, sign convention, tool offset,
flags, predicted rates) and verifies the export as the controller will apply it, predicting the
compensation rates on the source itself. :func:`compensation_report` gives the ``compensation``
keys of report.json.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ErrorModel
from ..names import file_in_folder
from ..progress import CancelToken, ProgressCallback, check, report
from ..project_lock import pid_alive
from ..userror import UserError
from . import (
    export_fanuc,
    export_generic,
    export_heidenhain,
    export_isg,
    export_linuxcnc,
    export_siemens,
)
from .export_common import (
    ExportContext,
    ExporterOutput,
    ExportOptions,
    table_kinds_values,
    write_text,
)
from .limits import check_axis_names, check_sizes, limits_of, point_limit
from .ncprogram import rewrite_file
from .plausibility import AppliedValues, check_limit, check_plausible, table_values
from .source import ErrorSource, as_source, table_extents
from .tables import CompensationTables, build_tables
from .verify import (
    Compensation,
    ExactCompensation,
    VerificationResult,
    VerifyRequest,
    defined,
    standard_compensations,
    verify,
)

MANIFEST = "volucal_export.json"


def _export_gcode(context: ExportContext) -> ExporterOutput:
    options = context.options
    if options.program is None:
        raise UserError(
            "the gcode format rewrites an NC program: give the program to rewrite with "
            "--program FILE.ngc"
        )
    program = Path(options.program)
    out = file_in_folder(
        context.out_dir,
        f"{program.stem}_volucal{program.suffix or '.ngc'}",
        "the rewritten program's name (from --program)",
    )
    rewrite = options.rewrite
    if options.tool_offset_mm is not None:
        rewrite = dataclasses.replace(rewrite, tool_offset_mm=options.tool_offset_mm)
    result = rewrite_file(context.source, program, out, rewrite)
    applied: tuple[AppliedValues, ...] = ()
    if result.max_correction_at_mm is not None:
        applied = (
            table_values(
                f"{program.name} line {result.max_correction_line}",
                "",
                [result.max_correction_at_mm],
                [result.max_correction_um],
            ),
        )
    return ExporterOutput(
        files=(out,),
        convention=(
            "rewritten RS274/NGC program: every target point replaced by the command that lands "
            "the tool on it; feed moves split, arcs linearised",
        ),
        notes=result.notes + result.flags,
        compensation=ExactCompensation(context.source, result.tool_offset_mm),
        details={"rewrite": result.to_json()},
        applied=applied,
    )


Exporter = Callable[[ExportContext], ExporterOutput]

FORMATS: Mapping[str, Exporter] = {
    "linuxcnc": export_linuxcnc.export,
    "siemens": export_siemens.export,
    "fanuc": export_fanuc.export,
    "heidenhain": export_heidenhain.export,
    "isg": export_isg.export,
    "csv": export_generic.export_csv,
    "json": export_generic.export_json,
    "gcode": _export_gcode,
}

FORMAT_HELP = {
    "linuxcnc": "LinuxCNC joint COMP_FILEs (type 0 or 1) and a comp.ini snippet",
    "siemens": "Siemens 840D %_N_AX_EEC_INI leadscrew and %_N_NC_CEC_INI cross-axis tables",
    "fanuc": "Fanuc pitch error compensation parameters 3620-3627 and incremental data",
    "heidenhain": "Heidenhain .COM tables and a .CMA assignment",
    "isg": "Beckhoff/ISG volumetric compensation CSV (and bilateral reversal lists)",
    "csv": "generic CSV tables (axis, cross-axis, volumetric grid)",
    "json": "generic JSON document with every table",
    "gcode": "an RS274/NGC program rewritten for volumetric compensation (--program)",
}

#: The computed tables each format carries, judged for plausibility before it is written.
CARRIED = {
    "linuxcnc": ("axis",),
    "siemens": ("axis", "cross"),
    "fanuc": ("axis",),
    "heidenhain": ("axis", "cross"),
    "isg": ("axis", "grid"),
    "csv": ("axis", "cross", "grid"),
    "json": ("axis", "cross", "grid"),
    "gcode": (),
}
STAGING = ".volucal-export-"


@dataclass(frozen=True, eq=False)
class ExportResult:
    """What an export wrote and what it is predicted to achieve."""

    format: str
    out_dir: Path
    files: tuple[Path, ...]
    tool_offset_mm: tuple[float, float, float]
    convention: tuple[str, ...]
    notes: tuple[str, ...]
    flags: tuple[str, ...]
    tables: CompensationTables
    verification: VerificationResult
    details: Mapping[str, object] = field(default_factory=dict)
    #: The export as the controller applies it (``command_mm(nominal, approach)``), to apply
    #: to a virtual machine and re-measure; None where the export is not a compensation.
    compensation: Compensation | None = None

    def to_json(self) -> dict[str, object]:
        from volucal import __version__

        return {
            "volucal_version": __version__,
            "format": self.format,
            "files": [p.name for p in self.files],
            "tool_offset_mm": list(self.tool_offset_mm),
            "axis_lines_through_mm": list(self.tables.line_mm),
            "units_and_signs": list(self.convention),
            "notes": list(self.notes),
            "flags": list(self.flags),
            "predicted": self.verification.to_json(),
            "details": dict(self.details),
        }


def export_model(
    source: ErrorSource | ErrorModel,
    format: str,
    out_dir: str | Path,
    options: ExportOptions | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
) -> ExportResult:
    """Compute, write and verify a compensation export.

    Parameters
    ----------
    source : ErrorSource or ErrorModel
        The identified errors (a model is wrapped in a :class:`ModelSource`).
    format : str
        One of :data:`FORMATS`.
    out_dir : path
        Folder for the files (created if missing; files of the same name are replaced, all of
        them only once every check has passed).
    options : ExportOptions, optional
        Spacing, tool offset, axis names, limits, program to rewrite, ...

    Returns
    -------
    ExportResult
        Files, conventions, notes, flags (positions beyond the measured range) and the
        predicted rates of the export as the controller applies it, next to the volumetric
        grid, NC rewriting and per-axis tables.

    Raises
    ------
    LargeCorrectionError
        A correction beyond ``options.max_correction_um`` (:mod:`.plausibility`), with the
        offending points; nothing is written.
    TableLimitError
        A table beyond the controller's limits (:mod:`.limits`); nothing is written.
    UserError
        Options the format cannot take (axis names, point limit, sizes), unwritable folders.
    """
    if format not in FORMATS:
        raise UserError(f"unknown export format {format!r}; use one of {', '.join(FORMATS)}")
    options = options or ExportOptions()
    error_source = as_source(source)
    _check_options(format, error_source, options)
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{out}: cannot create the output folder ({exc.strerror})") from None
    report(progress, 0.0, "computing tables")
    tables = build_tables(error_source, options.table_request(), cancel=cancel)
    kinds = tuple(
        k
        for k in CARRIED.get(format, ("axis", "cross", "grid"))
        if k != "cross" or options.include_cross
    )
    check_plausible(format, table_kinds_values(tables, kinds), options.max_correction_um)
    written = tables
    if format == "fanuc":
        # Fanuc's points sit at the reference plus whole intervals and may reach past the
        # stroke; the comparison methods keep the evenly spaced tables.
        nodes = export_fanuc.table_nodes(error_source, options)
        written = build_tables(error_source, options.table_request(nodes), cancel=cancel)
    check(cancel)
    report(progress, 0.4, f"writing {format} files")
    # Files are written into a staging folder and moved into place only once every check has
    # passed: a refused export leaves the folder as it was.
    staging = _staging_folder(out)
    try:
        context = ExportContext(error_source, written, staging, options)
        output = FORMATS[format](context)
        check_plausible(format, output.applied_values(), options.max_correction_um)
        check(cancel)
        report(progress, 0.6, "verifying the export")
        methods = standard_compensations(error_source, tables)
        if output.compensation is not None:
            methods = {
                "export": (
                    f"the {format} export as the controller applies it",
                    output.compensation,
                ),
                **methods,
            }
        verification = verify(
            error_source,
            methods,
            VerifyRequest(
                grid_spacing_mm=options.grid_spacing_mm, tool_offset_mm=tables.tool_offset_mm
            ),
            cancel=cancel,
        )
        result = ExportResult(
            format=format,
            out_dir=out,
            files=tuple(out / p.name for p in output.files),
            tool_offset_mm=written.tool_offset_mm,
            convention=output.convention,
            notes=output.notes,
            flags=written.flags,
            tables=written,
            verification=verification,
            details=output.details,
            compensation=output.compensation,
        )
        manifest = write_text(staging / MANIFEST, json.dumps(result.to_json(), indent=1) + "\n")
        check(cancel)
        _publish((*output.files, manifest), out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    report(progress, 1.0, "export done")
    return dataclasses.replace(result, files=(*result.files, out / MANIFEST))


def _check_options(format: str, source: ErrorSource, options: ExportOptions) -> None:
    """Everything the options alone can be judged on, before any table is computed."""
    limits_of(format)
    point_limit(format, options.max_points)
    check_axis_names(format, options.axis_names)
    check_limit(options.max_correction_um)
    extents = table_extents(source, options.range_mm)
    check_sizes(extents, options.spacing_mm, options.grid_spacing_mm)


def _staging_folder(out: Path) -> Path:
    for old in out.glob(f"{STAGING}*"):
        # left by an export that was killed: its process no longer runs
        match = re.match(rf"{re.escape(STAGING)}(\d+)-", old.name)
        if match and not pid_alive(int(match.group(1))):
            shutil.rmtree(old, ignore_errors=True)
    try:
        return Path(tempfile.mkdtemp(prefix=f"{STAGING}{os.getpid()}-", dir=out))
    except OSError as exc:
        raise UserError(f"{out}: cannot write into the output folder ({exc.strerror})") from None


def _publish(staged: tuple[Path, ...], out: Path) -> None:
    for path in staged:
        target = file_in_folder(out, path.name)
        try:
            os.replace(path, target)
        except OSError as exc:
            raise UserError(f"{target}: cannot write the file ({exc.strerror})") from None


#: Methods that invert the model exactly: their rate predicted on that same model is 100 % by
#: construction and carries no information.
SELF_EXACT_METHODS = ("nc_rewriting",)


def compensation_report(
    source: ErrorSource | ErrorModel,
    files: tuple[str | Path, ...] = (),
    verification: VerificationResult | None = None,
    grid_spacing_mm: float = 25.0,
) -> dict[str, object]:
    """The ``compensation`` keys of report.json (DESIGN.md contract), predicted on the source.

    ``rate_percent.volumetric`` is the volumetric grid (with reversal tables where the source has
    reversal), ``rate_percent.axis_tables`` the per-axis positioning tables alone; both RMS-based.
    """
    error_source = as_source(source)
    if verification is None:
        tables = build_tables(error_source)
        verification = verify(
            error_source,
            standard_compensations(error_source, tables),
            VerifyRequest(grid_spacing_mm=grid_spacing_mm),
        )
    methods = verification.methods
    volumetric_name = (
        "volumetric_grid_and_reversal"
        if "volumetric_grid_and_reversal" in methods
        else "volumetric_grid"
    )
    return {
        "files": [str(Path(f).name) for f in files],
        "rate_percent": {
            "volumetric": defined(methods[volumetric_name].rates.rms_percent),
            "axis_tables": defined(methods["axis_tables"].rates.rms_percent),
        },
        "rate_definition": (
            f"{verification.rate_definition}; volumetric = {volumetric_name}, axis_tables = "
            "per-axis positioning tables only; predicted on the identified model"
        ),
        # NC-program rewriting applies the model's own inverse: on the model it is exact by
        # construction (100 %), which says nothing about the machine. Only a re-measurement can
        # rate it, so it has no predicted row.
        "methods": {
            name: {
                "description": m.description,
                "rms_percent": defined(m.rates.rms_percent),
                "range_percent": defined(m.rates.range_percent),
            }
            for name, m in methods.items()
            if name not in SELF_EXACT_METHODS
        },
        "not_predicted": {
            name: "the model's own inverse: exact on the model by construction; rated only by "
            "re-measuring the machine"
            for name in methods
            if name in SELF_EXACT_METHODS
        },
        "tool_offset_mm": list(verification.tool_offset_mm),
    }
