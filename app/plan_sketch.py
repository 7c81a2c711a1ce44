"""A three-view sketch of the laser lines in the machine's workspace (top, front, side).

Each line is drawn from its start to its last target in NC coordinates, coloured by quantity
(linear, straightness, angular); a line seen end-on is a dot. The workspace (the strokes) is the
dashed box. The views keep true proportions, so an offset line looks offset by what it is.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Signal
from PySide6.QtGui import QPainterPath, QTransform
from volucal.core.machine import AXES

from . import plots

VIEWS = (("top view (X–Y)", 0, 1), ("front view (X–Z)", 0, 2), ("side view (Y–Z)", 1, 2))


@dataclass(frozen=True)
class SketchLine:
    """What the sketch needs of a line: where it starts, where it goes and how far (mm)."""

    name: str
    quantity: str
    start_mm: tuple[float, float, float]
    direction: tuple[float, float, float]
    length_mm: float

    @property
    def end_mm(self) -> np.ndarray:
        return np.asarray(self.start_mm) + self.length_mm * np.asarray(self.direction)


class PlanSketch(pg.GraphicsLayoutWidget):
    """Three orthogonal views of a plan; ``lineClicked(name)`` when the user clicks a line."""

    lineClicked = Signal(str)

    def __init__(self, parent: object = None) -> None:
        super().__init__(parent)
        self.setObjectName("planSketch")
        self._plots: list[pg.PlotItem] = []
        for column, (title, i, j) in enumerate(VIEWS):
            plot = self.addPlot(row=0, col=column)
            plots.style(plot, title, f"{AXES[i]} (mm)", f"{AXES[j]} (mm)")
            plot.setAspectLocked(True)
            plot.setMenuEnabled(False)
            self._plots.append(plot)
        legend = " ".join(
            f"<span style='color:{c}'>━ {q}</span>" for q, c in plots.QUANTITY_COLOR.items()
        )
        self.addLabel(legend + "&nbsp;&nbsp;● start", row=1, col=0, colspan=3)
        self._lines: list[SketchLine] = []
        self._strokes: dict[str, tuple[float, float]] = {}
        self._selected: str | None = None
        self.setMinimumHeight(220)

    @property
    def lines(self) -> tuple[SketchLine, ...]:
        return tuple(self._lines)

    @property
    def selected(self) -> str | None:
        return self._selected

    def set_plan(self, strokes: Mapping[str, tuple[float, float]], lines: Sequence[SketchLine],
                 selected: str | None = None) -> None:
        self._strokes = {a: (float(v[0]), float(v[1])) for a, v in strokes.items()}
        self._lines = list(lines)
        self._selected = selected
        self._draw()

    def select(self, name: str | None) -> None:
        if name != self._selected:
            self._selected = name
            self._draw()

    def _draw(self) -> None:
        for plot, (_, i, j) in zip(self._plots, VIEWS, strict=True):
            plot.clear()
            if self._strokes:
                (x0, x1), (y0, y1) = self._strokes[AXES[i]], self._strokes[AXES[j]]
                box = pg.PlotDataItem([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0],
                                      pen=plots.pen("#888888", 1.0, dashed=True))
                plot.addItem(box)
            for line in self._lines:
                self._draw_line(plot, line, i, j)
            self._draw_ends(plot, i, j)

    def _colour(self, line: SketchLine) -> str:
        if line.name == self._selected:
            return "#000000"
        return plots.QUANTITY_COLOR.get(line.quantity, "#444444")

    def _draw_line(self, plot: pg.PlotItem, line: SketchLine, i: int, j: int) -> None:
        """The line itself: one clickable curve (its name in the tooltip)."""
        chosen = line.name == self._selected
        start = np.asarray(line.start_mm, dtype=float)
        end = line.end_mm
        item = pg.PlotDataItem([start[i], end[i]], [start[j], end[j]],
                               pen=plots.pen(self._colour(line), 3.5 if chosen else 1.6))
        item.setCurveClickable(True, width=8)
        item.sigClicked.connect(lambda _item, name=line.name: self.lineClicked.emit(name))
        item.setToolTip(line.name)
        plot.addItem(item)

    def _draw_ends(self, plot: pg.PlotItem, i: int, j: int) -> None:
        """Every line's start (a dot) and end (an arrowhead along the line), as two items per
        view: a plan of 50 lines draws as fast as one of 5."""
        starts, ends = [], []
        for line in self._lines:
            chosen = line.name == self._selected
            colour = self._colour(line)
            start = np.asarray(line.start_mm, dtype=float)
            end = line.end_mm
            starts.append({"pos": (start[i], start[j]), "size": 7 if chosen else 5,
                           "brush": plots.brush(colour, 255), "pen": None})
            dx, dy = end[i] - start[i], end[j] - start[j]
            if math.hypot(dx, dy) > 1e-6:
                ends.append({"pos": (end[i], end[j]), "size": 13 if chosen else 10,
                             "symbol": _arrowhead(math.atan2(dy, dx)),
                             "brush": plots.brush(colour, 255), "pen": plots.pen(colour, 1.0)})
        if starts:
            plot.addItem(pg.ScatterPlotItem(spots=starts))
        if ends:
            plot.addItem(pg.ScatterPlotItem(spots=ends))


def _arrowhead(angle_rad: float) -> QPainterPath:
    """A symbol whose tip is at the spot, pointing at ``angle_rad`` in the plot (y up; symbols
    are drawn with y down, hence the sign)."""
    path = QPainterPath()
    path.moveTo(0.0, 0.0)
    path.lineTo(-0.9, -0.35)
    path.lineTo(-0.9, 0.35)
    path.closeSubpath()
    return QTransform().rotateRadians(-angle_rad).map(path)
