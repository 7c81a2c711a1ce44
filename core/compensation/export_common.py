"""Shared pieces of the controller exporters: options, what an exporter returns, file writing."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..names import file_in_folder, printable_ascii
from ..userror import UserError
from .controller import ControllerCompensation, LoadedTable
from .limits import TableLimitError
from .ncprogram import RewriteOptions
from .plausibility import DEFAULT_MAX_CORRECTION_UM, AppliedValues, table_values
from .source import ErrorSource
from .tables import CompensationTables, TableRequest
from .verify import Compensation

FloatArray = NDArray[np.float64]
UM_PER_MM = 1e3

__all__ = [
    "AppliedValues",
    "ExportContext",
    "ExportOptions",
    "ExporterOutput",
    "TableLimitError",
    "loaded_values",
    "rounded",
    "table_kinds_values",
    "text_for_file",
    "tool_line",
    "write_text",
]


@dataclass(frozen=True)
class ExportOptions:
    """Choices for an export. Every field has a default that suits the controller.

    spacing_mm : node spacing of the axis and cross-axis tables (10 mm unless set).
    tool_offset_mm : tool point the tables are for; the machine's tool offset by default.
    grid_spacing_mm : spacing of the volumetric grid (generic CSV/JSON) and of the verification.
    range_mm : table extent per axis; the measured range by default (nodes beyond it are flagged).
    axis_names : the controller's name for X, Y, Z (LinuxCNC joint numbers, Siemens machine axis
        names such as AX1, Fanuc axis numbers, ISG logical axis numbers, Heidenhain axis keys).
    max_points : the controller's point limit where it differs from the documented one (e.g. a
        larger MD38000, a smaller configured table); never beyond a fixed limit (LinuxCNC 256,
        Heidenhain 256, Fanuc point numbers 0..1023).
    include_cross : also write cross-axis tables where the controller has them (Siemens CEC,
        Heidenhain .COM columns).
    linuxcnc_type : COMP_FILE_TYPE 0 (actual positions) or 1 (offsets).
    fanuc_detection_unit_um : Fanuc detection unit (1 µm for IS-B, 0.1 µm for IS-C).
    program : the NC program to rewrite (format gcode).
    rewrite : options of the NC program rewriting.
    max_correction_um : plausibility limit of any correction the export applies (200 µm); None
        removes it (:mod:`.plausibility`).
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
    max_correction_um: float | None = DEFAULT_MAX_CORRECTION_UM

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
    applied : what the controller will apply (µm), for the plausibility check; by default the
        tables of ``compensation`` when it is a :class:`ControllerCompensation`.
    """

    files: tuple[Path, ...]
    convention: tuple[str, ...]
    notes: tuple[str, ...] = ()
    compensation: ControllerCompensation | Compensation | None = None
    details: Mapping[str, object] = field(default_factory=dict)
    applied: tuple[AppliedValues, ...] = ()

    def applied_values(self) -> tuple[AppliedValues, ...]:
        if self.applied or not isinstance(self.compensation, ControllerCompensation):
            return self.applied
        return loaded_values(self.compensation.tables)


@dataclass(frozen=True, eq=False)
class ExportContext:
    """Everything an exporter receives."""

    source: ErrorSource
    tables: CompensationTables
    out_dir: Path
    options: ExportOptions


def loaded_values(tables: tuple[LoadedTable, ...]) -> tuple[AppliedValues, ...]:
    """Plausibility input from the tables as a controller holds them."""
    out = []
    for table in tables:
        moving = {1: ", moving +", -1: ", moving -"}.get(table.direction, "")
        label = (
            f"{table.input_axis} table{moving}"
            if table.input_axis == table.output_axis
            else f"{table.output_axis} along {table.input_axis}{moving}"
        )
        out.append(table_values(label, table.input_axis, table.position_mm, table.value_um))
    return tuple(out)


def table_kinds_values(tables: CompensationTables, kinds: tuple[str, ...]) -> list[AppliedValues]:
    """Plausibility input from computed tables: ``"axis"`` (corrections both ways),
    ``"cross"`` and ``"grid"`` (the volumetric correction at the grid's nodes)."""
    out: list[AppliedValues] = []
    if "axis" in kinds:
        for axis, table in tables.axis.items():
            values = np.stack([table.correction_forward_um, table.correction_backward_um], axis=1)
            out.append(table_values(f"{axis} table", axis, table.position_mm, values))
    if "cross" in kinds:
        out += [
            table_values(
                f"{t.output_axis} along {t.input_axis}",
                t.input_axis,
                t.position_mm,
                t.correction_um,
            )
            for t in tables.cross
        ]
    if "grid" in kinds and tables.grid is not None:
        grid = tables.grid
        out.append(
            table_values("volumetric grid", "", grid.points_mm, grid.correction_um.reshape(-1, 3))
        )
    return out


def write_text(path: Path, text: str, newline: str = "\n") -> Path:
    """Write a file in one go (a temporary file renamed into place); its name is checked with
    :func:`volucal.core.names.safe_file_name`."""
    path = file_in_folder(Path(path).parent, Path(path).name)
    temporary = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        # Controllers read plain ASCII: units are written "um", never with a micro sign.
        with open(temporary, "w", encoding="ascii", newline=newline) as handle:
            handle.write(text)
        os.replace(temporary, path)
    except UnicodeEncodeError as exc:
        temporary.unlink(missing_ok=True)
        raise UserError(
            f"{path}: the file would hold {text[exc.start : exc.end]!r}, which a controller's "
            "ASCII file cannot carry; use ASCII names (axis names, program names)"
        ) from None
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


def text_for_file(text: object) -> str:
    """Free text (a machine name) for a comment line: ASCII, one line."""
    return printable_ascii(text)


def tool_line(tables: CompensationTables) -> str:
    t = tables.tool_offset_mm
    line = tables.line_mm
    return (
        f"tool offset {t[0]:g} {t[1]:g} {t[2]:g} mm; axis lines through "
        f"X{line[0]:g} Y{line[1]:g} Z{line[2]:g} mm"
    )
