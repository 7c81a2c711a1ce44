"""Plausibility: a correction larger than any machine tool needs is refused unless overridden.

A laser calibration of a machine tool corrects micrometres to a few tens of micrometres; a
squareness of 1e9 µrad in a damaged or hand-edited project would make a controller move an axis
by half a metre. Every export is therefore checked for corrections larger than a limit
(:data:`DEFAULT_MAX_CORRECTION_UM`, 200 µm, set with ``ExportOptions.max_correction_um``;
``None`` switches the check off — the CLI's ``--max-correction-um`` and
``--allow-large-corrections``). A refused export raises :class:`LargeCorrectionError`, which
carries every offending point so that a workbench can show them and ask for confirmation.
Values that are not numbers are refused whatever the limit.

What is checked is what the controller will apply: the values of each table an export writes,
in µm (corrections or errors, whichever the format holds), the volumetric grid for the formats
that carry one, and the program points of a rewritten NC program.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..machine import AXES
from ..userror import UserError
from .limits import TableLimitError

FloatArray = NDArray[np.float64]

#: Default plausibility limit (µm): far above what the machines volucal is made for need, far
#: below what a damaged model produces.
DEFAULT_MAX_CORRECTION_UM = 200.0
#: Offending points kept in the error (the largest ones).
KEPT = 20


@dataclass(frozen=True)
class AppliedValues:
    """Values an export makes a controller apply, in µm.

    ``positions_mm`` is (n,) along ``axis`` for a table, or (n, 3) for points of the workspace
    (``axis`` empty); ``values_um`` is (n,) or (n, k) (k components at each point).
    """

    label: str
    axis: str
    positions_mm: FloatArray
    values_um: FloatArray


@dataclass(frozen=True)
class LargeCorrection:
    """One point whose correction exceeds the limit."""

    label: str
    where: str
    value_um: float

    def __str__(self) -> str:
        return f"{self.value_um:+,.1f} µm at {self.where} ({self.label})"


class LargeCorrectionError(UserError):
    """An export would apply corrections beyond the plausibility limit.

    Attributes
    ----------
    format : str
    limit_um : float
    corrections : tuple of LargeCorrection
        The largest offending points, largest first (at most :data:`KEPT`).
    count : int
        How many points exceed the limit in all.
    """

    def __init__(
        self, format: str, limit_um: float, corrections: tuple[LargeCorrection, ...], count: int
    ) -> None:
        self.format = format
        self.limit_um = limit_um
        self.corrections = corrections
        self.count = count
        worst = corrections[0]
        more = f" and at {count - 1:,} more point(s)" if count > 1 else ""
        super().__init__(
            f"the {format} export would make the controller apply a correction of {worst}{more}, "
            f"beyond the plausibility limit of {limit_um:g} µm; a machine tool rarely needs "
            "more than tens of micrometres, so check the identification (an absurd squareness "
            "or angle, a unit mix-up). If the machine really needs it, export again with "
            "--max-correction-um N or --allow-large-corrections"
        )


def check_limit(max_correction_um: float | None) -> float | None:
    """The limit as given, checked: None (no limit) or a positive finite number of µm."""
    if max_correction_um is None:
        return None
    value = max_correction_um
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or value <= 0
    ):
        raise UserError(
            f"--max-correction-um must be a positive number of µm, got {max_correction_um!r} "
            "(--allow-large-corrections removes the limit)"
        )
    return float(value)


def check_plausible(
    format: str, applied: Iterable[AppliedValues], max_correction_um: float | None
) -> None:
    """Raise :class:`TableLimitError` for a value that is not a number, and
    :class:`LargeCorrectionError` for values beyond ``max_correction_um`` (None: no limit)."""
    limit = check_limit(max_correction_um)
    found: list[LargeCorrection] = []
    count = 0
    for item in applied:
        values = np.asarray(item.values_um, dtype=float)
        flat = values.reshape(len(values), -1) if values.ndim else values.reshape(1, 1)
        bad_rows = np.flatnonzero(~np.all(np.isfinite(flat), axis=1))
        if bad_rows.size:
            row = int(bad_rows[0])
            raise TableLimitError(
                f"the {format} export: {item.label} has a value that is not a number at "
                f"{_where(item, row)}; no controller can load it — check the identification"
            )
        if limit is None:
            continue
        size = np.max(np.abs(flat), axis=1)
        rows = np.flatnonzero(size > limit)
        count += rows.size
        for row in rows[np.argsort(-size[rows])][:KEPT]:
            column = int(np.argmax(np.abs(flat[row])))
            found.append(
                LargeCorrection(item.label, _where(item, int(row)), float(flat[row, column]))
            )
    if found and limit is not None:
        found.sort(key=lambda c: -abs(c.value_um))
        raise LargeCorrectionError(format, limit, tuple(found[:KEPT]), count)


def table_values(
    label: str, axis: str, positions_mm: ArrayLike, values_um: ArrayLike
) -> AppliedValues:
    return AppliedValues(
        label, axis, np.asarray(positions_mm, dtype=float), np.asarray(values_um, dtype=float)
    )


def _where(item: AppliedValues, row: int) -> str:
    positions = np.asarray(item.positions_mm, dtype=float)
    if positions.ndim == 1:
        return f"{item.axis} = {positions[row]:g} mm"
    point = positions[row]
    return ", ".join(f"{a} {v:g}" for a, v in zip(AXES, point, strict=False)) + " mm"
