"""The acceptance parts of the calibration report (GUI-free): the certificate, the ISO 230-2 graph
of each axis, the tolerances with their pass/fail, the re-measurement of the compensated machine
and the signature block.

Each function returns a :class:`~volucal.core.report_blocks.Section` (empty when there is nothing
to say); :func:`volucal.core.report_content.build_report` puts them in order. Values are shown in
the report's :class:`~volucal.core.display_units.DisplayUnits`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .certificate import Certificate
from .display_units import DisplayUnits
from .identify import UncertaintyBudget
from .iso230_2 import evaluate
from .machine import AXES
from .measurement import Line, target_positions
from .remeasurement import KEYS, Comparison
from .report_blocks import Block, IsoGraph, IsoGraphs, Paragraph, Section, Signatures, Table
from .tolerances import QUANTITIES, Tolerances, axis_verdicts, check_lines, line_axis


def certificate_section(certificate: Certificate) -> Section:
    return Section("Certificate", (Table((), tuple(certificate.rows()), "ll"),))


def iso_graphs_section(lines: Sequence[Line], units: DisplayUnits) -> Section:
    """Per machine axis, the ISO 230-2 graph of its first linear line in the plan (the others
    are in the ISO 230-2 table)."""
    graphs = []
    for axis in AXES:
        along = [line for line in lines if line_axis(line) == axis]
        if not along:
            continue
        line = along[0]
        r = evaluate(line.data, line.spec.unit)
        positions = target_positions(r.targets_mm, line.spec)
        unit = "um"
        others = (
            f"; {len(along) - 1} more line(s) along {axis} in the table" if len(along) > 1 else ""
        )
        caption = (
            f"{line.name}: "
            + ", ".join(
                f"{key} {units.text(getattr(r, f'{key}_um'), unit)}"
                for key in ("A", "E", "R", "B", "M")
            )
            + f" ({r.runs_up} runs ↑, {r.runs_down} runs ↓{others})"
        )
        graphs.append(
            IsoGraph(
                title=f"Axis {axis}: positioning deviation ({line.name})",
                unit=units.symbol(unit),
                positions_mm=_floats(positions.values_mm),
                position_title=positions.axis_title,
                mean_up=_floats(units.convert(r.mean_up, unit)),
                mean_down=_floats(units.convert(r.mean_down, unit)),
                s_up=_floats(units.convert(r.s_up, unit)),
                s_down=_floats(units.convert(r.s_down, unit)),
                caption=caption,
            )
        )
    if not graphs:
        return Section("ISO 230-2 graphs per axis", ())
    return Section(
        "ISO 230-2 graphs per axis",
        (
            Paragraph(
                "Mean positioning deviation of each direction of approach (↑ forward, ↓ "
                "backward) with the band x̄ ± 2s, per target, as ISO 230-2 draws it."
            ),
            IsoGraphs(tuple(graphs)),
        ),
    )


def tolerance_section(
    lines: Sequence[Line], tolerances: Tolerances, budget: UncertaintyBudget, units: DisplayUnits
) -> Section:
    """Every linear line along an axis against the axis' limits (pass/fail and ISO 14253-1)."""
    if tolerances.empty:
        return Section("Tolerances (ISO 230-2)", ())
    checks = check_lines(lines, tolerances, budget)
    limits = tuple(
        (
            axis,
            *[
                units.text(tolerances.limit(axis, key), "um")
                if tolerances.limit(axis, key)
                else "—"
                for key in QUANTITIES
            ],
        )
        for axis in AXES
        if tolerances.limits_um.get(axis)
    )
    verdicts = axis_verdicts(checks)
    summary = (
        "; ".join(f"axis {a}: {v}" for a, v in verdicts.items())
        or "no linear line along an axis with a limit"
    )
    rows = tuple(
        (
            c.line,
            c.axis,
            c.quantity,
            units.text(c.value_um, "um"),
            units.text(c.limit_um, "um"),
            units.text(c.expanded_uncertainty_um, "um"),
            c.verdict,
            c.decision,
        )
        for c in checks
    )
    blocks: list[Block] = [
        Paragraph(f"Result: {summary}.", "fail" if "fail" in verdicts.values() else "pass"),
        Table(
            ("axis", *QUANTITIES),
            limits,
            "l" + "r" * len(QUANTITIES),
            caption="Limits per axis (the user's; an empty cell is not checked).",
        ),
        Paragraph(
            "Each linear line along an axis is checked against that axis' limits: "
            "pass when the value is within its limit; and by ISO 14253-1, with the "
            "expanded uncertainty U (k = 2) of the value from the set-up budget: conforms "
            "when y + U ≤ T, does not conform when y − U > T, no decision in between. A, E "
            "and M take the budget's uncertainty of a positioning error over the line's "
            "travel; R and B compare readings at one target, where the scale terms "
            "cancel."
        ),
    ]
    if rows:
        blocks.append(
            Table(
                (
                    "line",
                    "axis",
                    "ISO 230-2",
                    "value y",
                    "limit T",
                    "U (k = 2)",
                    "result",
                    "ISO 14253-1",
                ),
                rows,
                "llcrrrll",
            )
        )
    return Section("Tolerances (ISO 230-2)", tuple(blocks))


def tolerance_summary(
    lines: Sequence[Line], tolerances: Tolerances, budget: UncertaintyBudget
) -> str:
    """One line for the summary: the verdict per axis, or ""."""
    if tolerances.empty:
        return ""
    verdicts = axis_verdicts(check_lines(lines, tolerances, budget))
    return "; ".join(f"{a} {v}" for a, v in verdicts.items())


def remeasurement_section(comparison: Comparison | None, name: str, units: DisplayUnits) -> Section:
    """The compensated machine measured again: rates per axis and ISO values per line."""
    title = "Re-measurement after compensation"
    if comparison is None:
        return Section(title, ())
    axes = tuple(
        (
            r.axis,
            str(len(r.lines)),
            units.text(r.rms_before_um, "um"),
            units.text(r.rms_after_um, "um"),
            _percent(r.rms_percent),
            units.text(r.range_before_um, "um"),
            units.text(r.range_after_um, "um"),
            _percent(r.range_percent),
            units.text(r.accuracy_before_um, "um"),
            units.text(r.accuracy_after_um, "um"),
            _percent(r.accuracy_percent),
        )
        for r in comparison.axes
    )
    rows = []
    for pair in comparison.pairs:
        unit = pair.before.unit
        for key in KEYS:
            rows.append(
                (
                    pair.name,
                    key,
                    units.text(pair.value(key, "before"), unit),
                    units.text(pair.value(key, "after"), unit),
                    _percent(pair.improvement_percent(key)),
                )
            )
    blocks: list[Block] = [
        Paragraph(
            f"The lines measured again on the compensated machine (project {name}), "
            f"paired with the original by place: {len(comparison.pairs)} line(s). Rates "
            "are 100·(1 − after/before) of the measured bidirectional mean deviation x̄: "
            "RMS-based, range-based (the largest M of the axis' lines) and of the accuracy "
            "A."
        ),
        Table(
            (
                "axis",
                "lines",
                "RMS before",
                "after",
                "rate %",
                "range before",
                "after",
                "rate %",
                "A before",
                "after",
                "rate %",
            ),
            axes,
            "lrrrrrrrrrr",
            caption="Measured compensation rates per axis.",
        ),
        Table(
            ("line", "ISO 230-2", "before", "after", "improvement %"),
            tuple(rows),
            "llrrr",
            caption="ISO 230-2 values of every paired line before and after.",
        ),
    ]
    if comparison.unmatched:
        blocks.append(
            Paragraph(
                "Re-measured lines without an original at the same place: "
                + ", ".join(comparison.unmatched)
                + ".",
                "note",
            )
        )
    return Section(title, tuple(blocks))


def signature_section(certificate: Certificate) -> Section:
    return Section(
        "Signatures",
        (
            Paragraph(
                "The results relate only to the machine as measured, at the time and under "
                "the conditions stated."
            ),
            Signatures(
                (
                    ("Calibrated by", certificate.get("operator")),
                    ("Approved by", certificate.get("approver")),
                )
            ),
        ),
    )


def _floats(values: np.ndarray) -> tuple[float, ...]:
    return tuple(float(v) for v in np.asarray(values, dtype=float))


def _percent(value: float) -> str:
    return "–" if not math.isfinite(value) else f"{value:.1f}"
