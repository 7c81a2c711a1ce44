"""Plot conventions shared by the views (pyqtgraph): light background, one palette, bands.

Importing this module sets pyqtgraph's global options once: every plot of the workbench is
drawn black on white with antialiasing, like a printed calibration report.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pyqtgraph as pg
from numpy.typing import ArrayLike
from PySide6.QtCore import Qt
from PySide6.QtGui import QColor

pg.setConfigOptions(antialias=True, background="w", foreground="k")

#: Colour per series (the matplotlib "tab10" palette: distinct in print and for most colour
#: vision deficiencies).
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
           "#7f7f7f", "#bcbd22", "#17becf")
FORWARD = "#1f77b4"
BACKWARD = "#d62728"
BAND = "#2ca02c"
QUANTITY_COLOR = {"linear": "#1f77b4", "straightness": "#2ca02c", "angular": "#ff7f0e"}
UNIT_LABEL = {"um": "µm", "urad": "µrad", "mm": "mm"}


def color(index: int) -> str:
    return PALETTE[index % len(PALETTE)]


def pen(colour: str, width: float = 1.5, dashed: bool = False, alpha: int = 255) -> pg.QtGui.QPen:
    q = QColor(colour)
    q.setAlpha(alpha)
    p = pg.mkPen(q, width=width)
    if dashed:
        p.setStyle(Qt.PenStyle.DashLine)
    p.setCosmetic(True)
    return p


def brush(colour: str, alpha: int = 60) -> pg.QtGui.QBrush:
    q = QColor(colour)
    q.setAlpha(alpha)
    return pg.mkBrush(q)


def style(plot: pg.PlotItem, title: str | None = None, x: str | None = None,
          y: str | None = None) -> pg.PlotItem:
    """Grid, labels and title in the workbench's style."""
    plot.showGrid(x=True, y=True, alpha=0.25)
    for side in ("left", "bottom"):
        # units are in the labels; a silent "(x0.001)" rescaling would change them
        plot.getAxis(side).enableAutoSIPrefix(False)
    if title is not None:
        plot.setTitle(title, size="10pt")
    if x is not None:
        plot.setLabel("bottom", x)
    if y is not None:
        plot.setLabel("left", y)
    return plot


def make_plot(title: str | None = None, x: str | None = None, y: str | None = None
              ) -> pg.PlotWidget:
    widget = pg.PlotWidget()
    style(widget.getPlotItem(), title, x, y)
    return widget


def add_band(plot: pg.PlotItem, x: ArrayLike, low: ArrayLike, high: ArrayLike,
             colour: str = BAND, alpha: int = 60) -> pg.FillBetweenItem | None:
    """A filled band between two curves (NaN stretches are left out)."""
    x = np.asarray(x, dtype=float)
    low = np.asarray(low, dtype=float)
    high = np.asarray(high, dtype=float)
    keep = np.isfinite(x) & np.isfinite(low) & np.isfinite(high)
    if keep.sum() < 2:
        return None
    lower = pg.PlotDataItem(x[keep], low[keep], pen=pen(colour, 0.8, alpha=120))
    upper = pg.PlotDataItem(x[keep], high[keep], pen=pen(colour, 0.8, alpha=120))
    fill = pg.FillBetweenItem(lower, upper, brush=brush(colour, alpha))
    plot.addItem(lower)
    plot.addItem(upper)
    plot.addItem(fill)
    return fill


def add_marker(plot: pg.PlotItem, x: float, label: str, colour: str = "#555555") -> None:
    """A labelled vertical line."""
    line = pg.InfiniteLine(pos=x, angle=90, pen=pen(colour, 1.0, dashed=True),
                           label=label, labelOpts={"position": 0.92, "color": colour})
    plot.addItem(line)


def category_ticks(axis: pg.AxisItem, labels: Sequence[str]) -> None:
    """Label the integer positions 0, 1, … of an axis with ``labels``."""
    axis.setTicks([[(i, text) for i, text in enumerate(labels)], []])


def unit_label(unit: str) -> str:
    return UNIT_LABEL.get(unit, unit)
