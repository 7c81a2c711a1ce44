"""How controllers apply compensation tables, simulated so a compensation can be verified.

A controller holds tables (:class:`LoadedTable`), each giving a value for one output axis as a
function of one input axis, and turns a nominal position into the command its drives receive.
The rules implemented, per the controllers' documentation (REFERENCE.md §6, docs/compensation.md):

- *linear, by command* — LinuxCNC joint COMP_FILE, Heidenhain .COM, Beckhoff/ISG tables, the
  generic tables and Siemens sag/cross tables (CEC): the value is interpolated linearly between
  nodes at the commanded (nominal) position of the input axis, end values are held outside the
  table, and added to the output axis' command. LinuxCNC picks the forward or the reverse column by
  the sign of the joint's velocity; a table with ``direction`` +1 or −1 applies only while the
  input axis moves that way (Siemens ``$AN_CEC_DIRECTION``).
- *linear, by actual position* — Siemens leadscrew error compensation (EEC): the table holds the
  error at the measured axis position and the controller corrects the actual value, so the axis
  settles where ``c + v(c) = n`` — solved here by fixed-point iteration.
- *step* — Fanuc pitch error compensation: the compensation pulses of an interval are output when
  the axis reaches the next compensation point, so the correction is the absolute value at the
  last compensation point passed in the direction of travel (a staircase); end values held.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..machine import AXES, AXIS_INDEX
from .source import approach_array
from .tables import CompensationTables

FloatArray = NDArray[np.float64]
UM_PER_MM = 1e3

INTERPOLATIONS = ("linear", "step")
INDEXING = ("command", "actual")


@dataclass(frozen=True, eq=False)
class LoadedTable:
    """One table as a controller holds it.

    value_um : for ``indexed_by="command"`` the correction added to the output axis' command;
        for ``indexed_by="actual"`` the error subtracted (Siemens EEC).
    direction : 0 both directions, +1 only while the input axis moves positive, −1 negative.
    """

    input_axis: str
    output_axis: str
    position_mm: FloatArray
    value_um: FloatArray
    direction: int = 0
    indexed_by: str = "command"
    interpolation: str = "linear"

    def __post_init__(self) -> None:
        if self.interpolation not in INTERPOLATIONS or self.indexed_by not in INDEXING:
            raise ValueError(f"unknown table rule {self.interpolation}/{self.indexed_by}")
        if self.direction not in (-1, 0, 1):
            raise ValueError("direction must be -1, 0 or +1")
        if self.indexed_by == "actual" and self.input_axis != self.output_axis:
            raise ValueError("a table indexed by the actual position corrects its own axis only")

    def value_at(self, position_mm: FloatArray, approach: FloatArray) -> FloatArray:
        """Table value (µm) at input-axis positions, with the input axis' approach signs."""
        nodes = self.position_mm
        if self.interpolation == "linear":
            value = np.interp(position_mm, nodes, self.value_um)
        else:
            value = step_value(nodes, self.value_um, position_mm, approach)
        if self.direction != 0:
            value = np.where(approach == self.direction, value, 0.0)
        return np.asarray(value, dtype=float)


def step_value(
    nodes_mm: FloatArray, value_um: FloatArray, position_mm: FloatArray, approach: FloatArray
) -> FloatArray:
    """Fanuc-style staircase: value at the last node passed in the direction of travel.

    Moving positive (approach +1) the value of the largest node ≤ q applies; moving negative,
    that of the smallest node ≥ q. Outside the nodes the end value is held.
    """
    q = np.asarray(position_mm, dtype=float)
    eps = 1e-9 * max(1.0, float(np.max(np.abs(nodes_mm))))
    below = np.clip(np.searchsorted(nodes_mm, q + eps, side="right") - 1, 0, len(nodes_mm) - 1)
    above = np.clip(np.searchsorted(nodes_mm, q - eps, side="left"), 0, len(nodes_mm) - 1)
    return np.where(approach > 0, value_um[below], value_um[above])


@dataclass(frozen=True, eq=False)
class ControllerCompensation:
    """A set of loaded tables and the rule to turn nominal positions into commands."""

    name: str
    tables: tuple[LoadedTable, ...]

    def command_mm(self, nominal_mm: ArrayLike, approach: ArrayLike) -> FloatArray:
        """Commanded positions (n, 3) mm the controller sends for nominal positions (n, 3)."""
        n = np.atleast_2d(np.asarray(nominal_mm, dtype=float))
        signs = approach_array(approach, len(n))
        command = n.copy()
        actual_tables = []
        for table in self.tables:
            i = AXIS_INDEX[table.input_axis]
            if table.indexed_by == "actual":
                actual_tables.append(table)
                continue
            o = AXIS_INDEX[table.output_axis]
            command[:, o] += table.value_at(n[:, i], signs[:, i]) / UM_PER_MM
        for axis in AXES:
            own = [t for t in actual_tables if t.output_axis == axis]
            if not own:
                continue
            k = AXIS_INDEX[axis]
            target = command[:, k].copy()
            c = target.copy()
            # The position loop settles where the corrected actual value equals the command.
            for _ in range(20):
                previous = c
                c = target - sum(t.value_at(c, signs[:, k]) for t in own) / UM_PER_MM
                if np.max(np.abs(c - previous), initial=0.0) < 1e-12:
                    break
            command[:, k] = c
        return command


def axis_compensation(
    tables: CompensationTables, include_cross: bool = False, name: str = "axis tables"
) -> ControllerCompensation:
    """Linear, command-indexed tables from :func:`build_tables` (the generic controller).

    Own-axis tables are bidirectional where the source has reversal; ``include_cross`` adds the
    cross-axis tables (straightness, squareness along the axis lines, sag).
    """
    loaded: list[LoadedTable] = []
    for axis, table in tables.axis.items():
        if table.bidirectional:
            loaded.append(
                LoadedTable(axis, axis, table.position_mm, table.correction_forward_um, direction=1)
            )
            loaded.append(
                LoadedTable(axis, axis, table.position_mm, table.correction_backward_um, -1)
            )
        else:
            loaded.append(LoadedTable(axis, axis, table.position_mm, table.correction_mean_um))
    if include_cross:
        loaded.extend(
            LoadedTable(t.input_axis, t.output_axis, t.position_mm, t.correction_um)
            for t in tables.cross
        )
    return ControllerCompensation(name, tuple(loaded))


def reversal_compensation(
    tables: CompensationTables, name: str = "reversal tables"
) -> ControllerCompensation:
    """Direction-dependent part only: per bidirectional axis, the forward and backward
    corrections minus their mean, applied while the axis moves that way. Added to a
    direction-free compensation (a volumetric grid) it restores the reversal correction."""
    loaded: list[LoadedTable] = []
    for axis, table in tables.axis.items():
        if not table.bidirectional:
            continue
        mean = table.correction_mean_um
        loaded.append(
            LoadedTable(axis, axis, table.position_mm, table.correction_forward_um - mean, 1)
        )
        loaded.append(
            LoadedTable(axis, axis, table.position_mm, table.correction_backward_um - mean, -1)
        )
    return ControllerCompensation(name, tuple(loaded))
