"""Verification of a compensation on the virtual machine that produced the data.

Two figures per method, per axis direction (DESIGN.md "Conventions", compensation rates):

- **re-measured**: the plan is measured again on the compensated virtual machine and the rates
  compare what the lines along each axis direction read before and after — what a metrologist
  does on a real machine;
- **true**: the ground-truth error under the compensation on the same grid, which a real machine
  never tells.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .compensation.tables import CompensationTables
from .compensation.verify import (
    VerifyRequest,
    standard_compensations,
    verify,
)
from .loop_source import LoopSource
from .machine import AXES, Machine
from .measurement import Line, Measurement
from .plans import PlannedLine
from .progress import CancelToken, ProgressCallback, check, report
from .readings import flatten
from .residuals import line_group
from .simulate import VirtualMachine

FloatArray = NDArray[np.float64]

#: The methods re-measured by default: volumetric compensation (grid with reversal tables, and NC
#: program rewriting) and the per-axis tables a plain controller loads.
DEFAULT_METHODS = ("volumetric_grid_and_reversal", "nc_rewriting", "axis_tables")


class VirtualMachineSource:
    """The virtual machine's true error (at the session's start) as an error source."""

    def __init__(self, machine: VirtualMachine) -> None:
        self.vm = machine
        self.machine: Machine = machine.machine
        self.model = machine.truth

    def error_um(
        self,
        positions_mm: ArrayLike,
        approach: ArrayLike | None = None,
        tool_offset_mm: ArrayLike | None = None,
    ) -> FloatArray:
        q = np.atleast_2d(np.asarray(positions_mm, dtype=float))
        a = None if approach is None else np.broadcast_to(np.asarray(approach, float), q.shape)
        tool = None if tool_offset_mm is None else np.asarray(tool_offset_mm, float)
        return self.vm.error_um(q, a, None, tool)


@dataclass(frozen=True)
class MethodVerification:
    name: str
    description: str
    true_rates: dict[str, object]
    remeasured_rates: dict[str, object]


def verify_on_virtual_machine(
    machine: VirtualMachine,
    lines: Sequence[PlannedLine],
    identified: LoopSource,
    tables: CompensationTables,
    methods: Sequence[str] = DEFAULT_METHODS,
    grid_spacing_mm: float = 25.0,
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
) -> list[MethodVerification]:
    """Apply each compensation method to the virtual machine, re-measure the plan and report."""
    compensations = standard_compensations(identified, tables)
    extents = identified.measured_range_mm or dict(identified.machine.stroke_mm)
    request = VerifyRequest(grid_spacing_mm=grid_spacing_mm, range_mm=extents)
    true = verify(VirtualMachineSource(machine), compensations, request)
    true_by_name = dict(true.methods)
    # Fresh noise on both sides: "before" is a new session on the uncompensated machine, not the
    # logs the model was fitted to, and every method is re-measured in a session of its own.
    before = machine.measure(lines, realisation=1)
    out = []
    chosen = [m for m in methods if m in compensations]
    for k, name in enumerate(chosen):
        check(cancel)
        report(progress, k / max(len(chosen), 1), f"re-measuring with {name}")
        description, compensation = compensations[name]
        after = machine.measure(lines, compensation=compensation.command_mm, realisation=2 + k)
        out.append(
            MethodVerification(
                name,
                description,
                true_by_name[name].rates.to_json() if name in true_by_name else {},
                line_rates(before, after),
            )
        )
    report(progress, 1.0, "verified")
    return out


def line_rates(before: Measurement, after: Measurement) -> dict[str, object]:
    """Compensation rates per axis direction from the lines themselves.

    Lines whose reading is along one machine axis (linear lines along it, straightness lines
    sensing it) and whose optics sit at the machine's tool offset are grouped by that axis;
    each reading is taken relative to its line's least-squares zero offset (and alignment slope,
    for straightness), as the laser sees it, and the rates compare the RMS and the largest range
    of the run-averaged deviations before and after. Diagonals and angular lines are left out
    (they mix directions or are not lengths).
    """
    stats: dict[str, dict[str, list[float]]] = {
        a: {"rms_b": [], "rms_a": [], "rng_b": [], "rng_a": []} for a in AXES
    }
    flat = flatten(before)
    tool = np.asarray(before.machine.tool_offset_mm)
    for index, (line_b, line_a) in enumerate(zip(before.lines, after.lines, strict=True)):
        group = line_group(flat, index)
        # the compensation is computed for the machine's tool offset: lines whose optics sit
        # elsewhere see the uncompensated lever arms of the angles, as another tool would
        if group not in AXES or not np.allclose(line_b.spec.reflector_mm, tool):
            continue
        for key, line in (("b", line_b), ("a", line_a)):
            mean = _relative_mean(line)
            stats[group][f"rms_{key}"].append(float(np.mean(mean**2)))
            stats[group][f"rng_{key}"].append(float(np.ptp(mean)))
    rms_rate, range_rate, rms_before, rms_after = {}, {}, {}, {}
    for axis, s in stats.items():
        if not s["rms_b"]:
            continue
        rb, ra = float(np.sqrt(np.mean(s["rms_b"]))), float(np.sqrt(np.mean(s["rms_a"])))
        gb, ga = max(s["rng_b"]), max(s["rng_a"])
        rms_before[axis], rms_after[axis] = rb, ra
        rms_rate[axis] = 100.0 * (1.0 - ra / rb) if rb > 0 else float("nan")
        range_rate[axis] = 100.0 * (1.0 - ga / gb) if gb > 0 else float("nan")
    return {
        "rms_percent": rms_rate,
        "range_percent": range_rate,
        "rms_before_um": rms_before,
        "rms_after_um": rms_after,
    }


def _relative_mean(line: Line) -> FloatArray:
    """Run-averaged deviations of a line less its least-squares offset (and slope)."""
    d = line.data
    mean = np.nanmean(d.deviations, axis=0)
    s = d.targets_mm
    columns = [np.ones_like(s)] + ([s] if line.spec.quantity == "straightness" else [])
    basis = np.stack(columns, axis=-1)
    coef, *_ = np.linalg.lstsq(basis, mean, rcond=None)
    return np.asarray(mean - basis @ coef)


def verification_report(results: Sequence[MethodVerification]) -> dict[str, object]:
    return {
        r.name: {
            "description": r.description,
            "remeasured": r.remeasured_rates,
            "true_on_grid": r.true_rates,
        }
        for r in results
    }


def verification_table(results: Sequence[MethodVerification]) -> str:
    lines = [
        "compensation verified on the virtual machine, RMS-based %   re-measured lines     "
        "true error on the grid",
        "                                                              X      Y      Z        "
        "X      Y      Z",
    ]
    for r in results:
        m = r.remeasured_rates.get("rms_percent", {})
        t = r.true_rates.get("rms_percent", {}) if r.true_rates else {}
        cells = "  ".join(f"{m.get(a, float('nan')):5.1f}" for a in AXES)
        truth = "  ".join(f"{t.get(a, float('nan')):5.1f}" for a in AXES)
        lines.append(f"  {r.name:<58} {cells}    {truth}")
    return "\n".join(lines)
