"""Compensation: tables from an error source, controller exports, NC rewriting, verification.

- :mod:`.source` — the :class:`ErrorSource` protocol, :class:`ModelSource`,
  :class:`ReversalSource`;
- :mod:`.inverse` — the command that lands the tool on the nominal position;
- :mod:`.tables` — per-axis, cross-axis and volumetric tables;
- :mod:`.controller` — how controllers apply tables (interpolation, direction, indexing);
- :mod:`.verify` — compensation rates and ISO 230-2 figures before and after;
- :mod:`.selection` — what to compensate from an EFAST ranking, eq. 19 tolerances;
- :mod:`.ncprogram` — RS274/NGC rewriting;
- :mod:`.export` — :func:`export_model`, one module per controller format;
- :mod:`.limits` — what each controller accepts; :mod:`.plausibility` — corrections too large to
  be true.
"""

from .export import FORMATS, ExportResult, compensation_report, export_model
from .export_common import ExportOptions
from .inverse import InverseResult, invert
from .limits import LIMITS, TableLimitError
from .ncprogram import RewriteOptions, RewriteResult, rewrite_file, rewrite_program
from .plausibility import DEFAULT_MAX_CORRECTION_UM, LargeCorrection, LargeCorrectionError
from .selection import CompensationSelection, select_compensation
from .source import ErrorSource, ModelSource, ReversalSource, as_source
from .tables import CompensationTables, TableRequest, build_tables
from .verify import VerificationResult, VerifyRequest, standard_compensations, verify

__all__ = [
    "DEFAULT_MAX_CORRECTION_UM",
    "FORMATS",
    "LIMITS",
    "LargeCorrection",
    "LargeCorrectionError",
    "CompensationSelection",
    "CompensationTables",
    "ErrorSource",
    "ExportOptions",
    "ExportResult",
    "InverseResult",
    "ModelSource",
    "ReversalSource",
    "RewriteOptions",
    "RewriteResult",
    "TableLimitError",
    "TableRequest",
    "VerificationResult",
    "VerifyRequest",
    "as_source",
    "build_tables",
    "compensation_report",
    "export_model",
    "invert",
    "rewrite_file",
    "rewrite_program",
    "select_compensation",
    "standard_compensations",
    "verify",
]
