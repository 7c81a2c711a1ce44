"""Fanuc pitch error compensation: parameters 3620–3627 and incremental pitch error data.

FANUC parameter manual (Series 0i/16i/18i, "pitch error compensation"; the bidirectional
function in technical report A-77810E): compensation points lie at the reference position plus
whole intervals (parameter 3624); point number n covers the section
``(ref + (n − R − 1)·I, ref + (n − R)·I]`` with R the number of the reference position (3620);
3621/3622 are the numbers of the farthest points on the − and + sides, 3623 the magnification.
The value of a point is the *increment* of the compensation over its section, in detection units
times the magnification, so the absolute compensation at ``ref + k·I`` is the sum of the values
from the reference (zero there) out to that point. The compensation pulses of a section are output
when the axis reaches the point: between points the correction is a staircase. Bidirectional
compensation (3605#0 = 1) adds a table for travel in the negative direction starting at number
3626, and 3627 gives its absolute value at the reference position.

Record format (FANUC parameter manuals, "inputting and outputting parameters": a record starts
and ends with ``%``; axis-type parameters as ``N<number>A<axis>P<value>...``; pitch error data as
``N<10000 + point number>P<value>``). The parameter file does not set the bit parameter 3605
(other bits share it): set 3605#0 by hand for bidirectional compensation. A CSV lists the same
points with their positions for entry on the pitch error screen.

Values are corrections (added to the command), from the iterated inverse.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..machine import AXES
from ..userror import UserError
from .controller import ControllerCompensation, LoadedTable
from .export_common import (
    ExportContext,
    ExporterOutput,
    ExportOptions,
    TableLimitError,
    text_for_file,
    tool_line,
    write_text,
)
from .limits import LIMITS, MAX_TABLE_NODES, check_values, point_limit
from .source import ErrorSource, table_extents

MAX_NUMBER = 1023  # pitch error compensation point numbers 0..1023 (Series 16i/18i/0i)
MAX_VALUE = 127  # per-point setting range -128..127
MAX_MAGNIFICATION = 100
MAX_INTERVAL = 99_999_999  # parameter 3624, eight digits (assumed, not confirmed)
DEFAULT_AXIS_NUMBERS = {"X": "1", "Y": "2", "Z": "3"}


def table_nodes(source: ErrorSource, options: ExportOptions) -> dict[str, tuple[float, ...]]:
    """Compensation points: the reference position plus whole intervals covering the range."""
    unit_mm = _detection_unit_mm(options)
    interval = _interval_mm(options, unit_mm)
    extents = table_extents(source, options.range_mm)
    nodes = {}
    for axis in AXES:
        ref = source.machine.reference(axis)
        low, high = extents[axis]
        below = max(0, math.ceil((ref - low) / interval - 1e-9))
        above = max(0, math.ceil((high - ref) / interval - 1e-9))
        if below + above + 1 > MAX_TABLE_NODES:
            raise TableLimitError(
                f"a {interval:g} mm interval gives {below + above + 1:,} pitch error points on "
                f"{axis}; the control numbers at most {MAX_NUMBER + 1}: use a larger --spacing"
            )
        nodes[axis] = tuple(ref + k * interval for k in range(-below, above + 1))
    return nodes


def _detection_unit_mm(options: ExportOptions) -> float:
    unit_um = options.fanuc_detection_unit_um
    if not (math.isfinite(unit_um) and unit_um > 0):
        raise UserError(f"Fanuc detection unit must be positive, got {unit_um} µm")
    return unit_um / 1e3


def _interval_mm(options: ExportOptions, unit_mm: float) -> float:
    spacing = options.spacing_mm
    if not (math.isfinite(spacing) and spacing > 0):
        raise UserError(f"--spacing must be a positive number of mm, got {spacing}")
    counts = max(1, round(spacing / unit_mm))
    if counts > MAX_INTERVAL:
        raise TableLimitError(
            f"a {spacing:g} mm interval is {counts:,} detection units, more than parameter 3624 "
            f"holds ({MAX_INTERVAL:,}); use a smaller --spacing or a larger --detection-unit"
        )
    return counts * unit_mm


def export(context: ExportContext) -> ExporterOutput:
    options = context.options
    tables = context.tables
    machine = context.source.machine
    unit_um = _detection_unit_mm(options) * 1e3
    limit = point_limit("fanuc", options.max_points)
    bidirectional = any(tables.axis[a].bidirectional for a in AXES)
    plans: dict[str, _PointPlan] = {}
    next_number = 0
    for axis in AXES:
        table = tables.axis[axis]
        nodes = table.position_mm
        zero = int(np.argmin(np.abs(nodes - machine.reference(axis))))
        plan = _PointPlan(
            nodes=nodes, zero=zero, below=zero, above=len(nodes) - 1 - zero, low=next_number
        )
        plans[axis] = plan
        next_number = plan.high + 1
    if bidirectional:
        for axis in AXES:
            plans[axis].low_negative = next_number
            next_number += plans[axis].high - plans[axis].low + 1
    if next_number > limit:
        ceiling = LIMITS["fanuc"].points_ceiling
        raise TableLimitError(
            f"the pitch error tables need {next_number} compensation points but the control "
            f"has {limit} (numbers 0..{limit - 1}); export with a larger --spacing"
            + (
                " or pass the control's count with --max-points"
                if ceiling is not None and limit < ceiling.value
                else ""
            )
        )
    parameters: dict[int, dict[str, int]] = {3620: {}, 3621: {}, 3622: {}, 3623: {}, 3624: {}}
    if bidirectional:
        parameters.update({3626: {}, 3627: {}})
    data: dict[int, int] = {}
    rows = ["number,axis,direction,section_from_mm,section_to_mm,increment,absolute_um"]
    loaded = []
    reference_notes: list[str] = []
    for axis in AXES:
        plan = plans[axis]
        table = tables.axis[axis]
        nodes = plan.nodes
        zero = plan.zero
        interval = float(nodes[1] - nodes[0])
        # Fanuc's compensation is zero at the reference position in the reference-return
        # direction (taken as positive); a non-zero correction there needs a reference shift.
        at_reference = float(table.correction_forward_um[zero])
        if abs(at_reference) > 0.05:
            reference_notes.append(
                f"{axis}: the correction at the reference position ({at_reference:+.2f} um "
                "moving positive) cannot be in the pitch error table, which is zero there; "
                "shift the reference position by it (grid shift) or it stays as an offset"
            )
        forward = table.correction_forward_um - at_reference
        backward = table.correction_backward_um - at_reference
        magnification = _magnification(forward, backward, unit_um, axis)
        quantum = unit_um * magnification
        abs_forward = np.round(forward / quantum).astype(int)
        abs_backward = np.round(backward / quantum).astype(int)
        number = options.axis_name(axis, DEFAULT_AXIS_NUMBERS[axis])
        parameters[3620][number] = plan.reference
        parameters[3621][number] = plan.low
        parameters[3622][number] = plan.high
        parameters[3623][number] = magnification
        parameters[3624][number] = round(interval * 1e3 / unit_um)
        directions = [("+", abs_forward, plan.low, 1)]
        if bidirectional:
            parameters[3626][number] = plan.low_negative
            parameters[3627][number] = int(abs_backward[zero])
            directions.append(("-", abs_backward, plan.low_negative, -1))
        for label, absolute, first, direction in directions:
            increments = _increments(absolute, zero, plan.below, plan.above)
            section_ends = [
                nodes[zero] + (offset - (plan.reference - plan.low)) * interval
                for offset in range(len(increments))
            ]
            check_values(
                "fanuc", f"the {axis} pitch error table ({label})", section_ends, increments
            )
            for offset, value in enumerate(increments):
                n = first + offset
                data[n] = value
                section = offset - (plan.reference - plan.low)  # section index from the ref
                rows.append(
                    f"{n},{axis},{label},{nodes[zero] + (section - 1) * interval:.4f},"
                    f"{nodes[zero] + section * interval:.4f},{value},"
                    f"{_absolute_at(absolute, zero, section) * quantum:.4f}"
                )
            loaded.append(
                LoadedTable(
                    axis,
                    axis,
                    nodes,
                    absolute * quantum,
                    direction=direction if bidirectional else 0,
                    interpolation="step",
                )
            )
    lines = ["%"]
    for parameter, per_axis in parameters.items():
        words = "".join(f"A{a}P{v}" for a, v in per_axis.items())
        lines.append(f"N{parameter:05d}{words}")
    lines += [f"N{10000 + n:05d}P{value}" for n, value in sorted(data.items())]
    lines.append("%")
    files = [
        write_text(context.out_dir / "FANUC_PITCH.TXT", "\n".join(lines) + "\n"),
        write_text(
            context.out_dir / "fanuc_pitch_points.csv",
            f"# volucal pitch error compensation for {text_for_file(machine.name)}; "
            f"{tool_line(tables)}\n"
            f"# increments in detection units ({unit_um:g} um) times parameter 3623\n"
            + "\n".join(rows)
            + "\n",
        ),
    ]
    notes = [
        f"detection unit {unit_um:g} µm; 3624 (interval) is in the same unit",
        "the staircase of Fanuc pitch error compensation leaves up to one interval's change "
        "of the error between points (see the predicted rates)",
    ]
    if bidirectional:
        notes.append("set parameter 3605#0 = 1 on each axis to enable bidirectional compensation")
    notes += reference_notes
    convention = (
        "FANUC_PITCH.TXT: parameters 3620-3624 (3626, 3627 when bidirectional) and pitch error "
        "data N10000+point, incremental correction per section in detection units x 3623",
    )
    return ExporterOutput(
        files=tuple(files),
        convention=convention,
        notes=tuple(notes),
        compensation=ControllerCompensation("Fanuc pitch error compensation", tuple(loaded)),
        details={"parameters": {str(k): v for k, v in parameters.items()}},
    )


@dataclass
class _PointPlan:
    """Where an axis' points sit: nodes, the reference node and the point numbers."""

    nodes: np.ndarray
    zero: int  # index of the reference node
    below: int  # sections on the − side
    above: int  # sections on the + side
    low: int  # first (farthest −) point number, parameter 3621
    low_negative: int = 0  # first point of the negative-direction table, parameter 3626

    @property
    def reference(self) -> int:
        """Parameter 3620: with no − sections the reference's own section is the first."""
        return self.low + max(self.below - 1, 0)

    @property
    def high(self) -> int:
        """Parameter 3622."""
        return self.reference + self.above


def _magnification(forward: np.ndarray, backward: np.ndarray, unit_um: float, axis: str) -> int:
    steps = np.concatenate([np.abs(np.diff(forward)), np.abs(np.diff(backward))])
    largest = float(np.max(steps, initial=0.0)) / unit_um
    magnification = max(1, math.ceil(largest / MAX_VALUE - 1e-9))
    if magnification > MAX_MAGNIFICATION:
        raise TableLimitError(
            f"the {axis} pitch error changes by {largest * unit_um:.1f} µm over one interval, "
            f"beyond {MAX_VALUE} x {MAX_MAGNIFICATION} detection units; export with a smaller "
            "--spacing"
        )
    return magnification


def _increments(absolute: np.ndarray, zero: int, below: int, above: int) -> list[int]:
    """Values of the points from the farthest − point to the farthest + point."""
    negative = [int(absolute[zero - m + 1] - absolute[zero - m]) for m in range(below, 0, -1)]
    if below == 0:
        negative = [0]  # the reference's own section lies outside the travel
    positive = [int(absolute[zero + k] - absolute[zero + k - 1]) for k in range(1, above + 1)]
    return negative + positive


def _absolute_at(absolute: np.ndarray, zero: int, section: int) -> int:
    index = min(max(zero + section, 0), len(absolute) - 1)
    return int(absolute[index])
