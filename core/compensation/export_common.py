"""Shared pieces of the controller exporters: options, what an exporter returns, limits."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..userror import UserError
from .controller import ControllerCompensation
from .ncprogram import RewriteOptions
from .source import ErrorSource
from .tables import CompensationTables, TableRequest
from .verify import Compensation

FloatArray = NDArray[np.float64]
UM_PER_MM = 1e3


class TableLimitError(UserError):
    """A table does not fit the controller's limits; the message says how to make it fit."""


@dataclass(frozen=True)
class ExportOptions:
    """Choices for an export. Every field has a default that suits the controller.

    spacing_mm : node spacing of the axis and cross-axis tables (10 mm unless set).
    tool_offset_mm : tool point the tables are for; the machine's tool offset by default.
    grid_spacing_mm : spacing of the volumetric grid (generic CSV/JSON) and of the verification.
    range_mm : table extent per axis; the measured range by default (nodes beyond it are flagged).
    axis_names : the controller's name for X, Y, Z (LinuxCNC joint numbers, Siemens machine axis
        names such as AX1, Fanuc axis numbers, ISG logical axis numbers, Heidenhain axis keys).
    max_points : override the controller's documented point limit (e.g. a larger MD38000).
    include_cross : also write cross-axis tables where the controller has them (Siemens CEC,
        Heidenhain .COM columns).
    linuxcnc_type : COMP_FILE_TYPE 0 (actual positions) or 1 (offsets).
    fanuc_detection_unit_um : Fanuc detection unit (1 µm for IS-B, 0.1 µm for IS-C).
    program : the NC program to rewrite (format gcode).
    rewrite : options of the NC program rewriting.
    """

    spacing_mm: float = 10.0
    tool_offset_mm: tuple[float, float, float] | None = None
    grid_spacing_mm: float = 25.0
    range_mm: Mapping[str, tuple[float, float]] | None = None
    axis_names: Mapping[str, str] | None = None
    max_points: int | None = None
    include_cross: bool = True
    linuxcnc_type: int = 0
    fanuc_detection_unit_um: float = 1.0
    program: Path | None = None
    rewrite: RewriteOptions = field(default_factory=RewriteOptions)

    def table_request(
        self, nodes_mm: Mapping[str, tuple[float, ...]] | None = None
    ) -> TableRequest:
        return TableRequest(
            spacing_mm=self.spacing_mm,
            nodes_mm=nodes_mm,
            tool_offset_mm=self.tool_offset_mm,
            range_mm=self.range_mm,
            grid_spacing_mm=self.grid_spacing_mm,
        )

    def axis_name(self, axis: str, default: str) -> str:
        if self.axis_names and axis in self.axis_names:
            return str(self.axis_names[axis])
        return default


@dataclass(frozen=True, eq=False)
class ExporterOutput:
    """What one exporter wrote, and how the controller will apply it.

    compensation : the loaded tables and rules, for the verification of this export (None when
        the export is not a table set, e.g. a rewritten program).
    convention : the sign convention and units, one line per file kind.
    """

    files: tuple[Path, ...]
    convention: tuple[str, ...]
    notes: tuple[str, ...] = ()
    compensation: ControllerCompensation | Compensation | None = None
    details: Mapping[str, object] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class ExportContext:
    """Everything an exporter receives."""

    source: ErrorSource
    tables: CompensationTables
    out_dir: Path
    options: ExportOptions


def check_points(
    count: int, limit: int, what: str, controller: str, span_mm: float, spacing_mm: float
) -> None:
    """Raise :class:`TableLimitError` when ``count`` points exceed ``limit``, with the spacing
    that would fit."""
    if count <= limit:
        return
    needed = span_mm / max(1, limit - 1)
    suggestion = math.ceil(needed * 1000.0) / 1000.0
    raise TableLimitError(
        f"{what} needs {count} points at {spacing_mm:g} mm spacing but {controller} accepts at "
        f"most {limit}; export with a spacing of at least {suggestion:g} mm (--spacing), or "
        "raise the controller's limit and pass it with --max-points"
    )


def write_text(path: Path, text: str, newline: str = "\n") -> Path:
    """Write a file in one go (a temporary file renamed into place)."""
    path = Path(path)
    temporary = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        # Controllers read plain ASCII: units are written "um", never with a micro sign.
        with open(temporary, "w", encoding="ascii", newline=newline) as handle:
            handle.write(text)
        os.replace(temporary, path)
    except OSError as exc:
        temporary.unlink(missing_ok=True)
        raise UserError(f"{path}: cannot write the file ({exc.strerror})") from None
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return path


def rounded(values: FloatArray, decimals: int) -> FloatArray:
    """Values rounded to the digits a file carries, without negative zeros ("-0.000")."""
    return np.round(np.asarray(values, dtype=float), decimals) + 0.0


def tool_line(tables: CompensationTables) -> str:
    t = tables.tool_offset_mm
    line = tables.line_mm
    return (
        f"tool offset {t[0]:g} {t[1]:g} {t[2]:g} mm; axis lines through "
        f"X{line[0]:g} Y{line[1]:g} Z{line[2]:g} mm"
    )
