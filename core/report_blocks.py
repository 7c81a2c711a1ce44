"""The blocks a calibration report is made of (GUI-free): paragraphs, tables, error curves with
their uncertainty band, bar charts, ISO 230-2 graphs and a signature block.

:mod:`volucal.core.report_content` fills them from a project; the PDF writer
(:mod:`volucal.app.report`) lays them out; ``volucal report --json`` prints them.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Paragraph:
    """Text; ``kind`` is "body", "note" (smaller), "verdict" (emphasised, in the colour of the
    conformance decision), "pass" or "fail" (emphasised, green or red)."""

    text: str
    kind: str = "body"


@dataclass(frozen=True)
class Table:
    """A table; ``align`` has one letter per column (l, r, c); an empty header makes a
    two-column key/value list."""

    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    align: str = ""
    caption: str = ""


@dataclass(frozen=True)
class Curve:
    """An error function over its axis stroke with its expanded uncertainty (k = 2)."""

    title: str
    unit: str
    axis: str
    position_mm: tuple[float, ...]
    value: tuple[float, ...]
    expanded_uncertainty: tuple[float, ...]


@dataclass(frozen=True)
class CurveGrid:
    """Error curves laid out ``columns`` per row."""

    curves: tuple[Curve, ...]
    columns: int = 2


@dataclass(frozen=True)
class BarChart:
    """Grouped bars: per category one bar per series; ``errors`` (same shape) are ±1 std
    whiskers, or empty."""

    title: str
    categories: tuple[str, ...]
    series: tuple[str, ...]
    values: tuple[tuple[float, ...], ...]  # [series][category]
    errors: tuple[tuple[float, ...], ...] = ()
    y_label: str = ""


@dataclass(frozen=True)
class IsoGraph:
    """The ISO 230-2 graph of one line: the mean deviation of each direction with its ±2s
    band per target, and the bidirectional mean (values in ``unit``)."""

    title: str
    unit: str
    #: the targets' positions on the line's axis (the plan's start plus the distance)
    positions_mm: tuple[float, ...]
    #: the title of their axis ("X (mm)", …: :attr:`TargetPositions.axis_title`)
    position_title: str
    mean_up: tuple[float, ...]
    mean_down: tuple[float, ...]
    s_up: tuple[float, ...]
    s_down: tuple[float, ...]
    caption: str = ""


@dataclass(frozen=True)
class IsoGraphs:
    """ISO 230-2 graphs laid out ``columns`` per row."""

    graphs: tuple[IsoGraph, ...]
    columns: int = 1


@dataclass(frozen=True)
class Signatures:
    """A signature block: per role the name printed, with room for the date and signature."""

    roles: tuple[tuple[str, str], ...]  # (role, name)


Block = Paragraph | Table | CurveGrid | BarChart | IsoGraphs | Signatures


@dataclass(frozen=True)
class Section:
    title: str
    blocks: tuple[Block, ...]
