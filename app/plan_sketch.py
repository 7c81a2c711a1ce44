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

    def _draw_line(self, plot: pg.PlotItem, line: SketchLine, i: int, j: int) -> None:
        chosen = line.name == self._selected
        colour = "#000000" if chosen else plots.QUANTITY_COLOR.get(line.quantity, "#444444")
        width = 3.5 if chosen else 1.6
        start = np.asarray(line.start_mm, dtype=float)
        end = line.end_mm
        item = pg.PlotDataItem([start[i], end[i]], [start[j], end[j]], pen=plots.pen(colour, width))
        item.setCurveClickable(True, width=8)
        item.sigClicked.connect(lambda _item, name=line.name: self.lineClicked.emit(name))
        item.setToolTip(line.name)
        plot.addItem(item)
        dot = pg.ScatterPlotItem([start[i]], [start[j]], size=7 if chosen else 5,
                                 brush=plots.brush(colour, 255), pen=None)
        dot.setToolTip(line.name)
        plot.addItem(dot)
        dx, dy = end[i] - start[i], end[j] - start[j]
        if math.hypot(dx, dy) > 1e-6:
            # pyqtgraph's arrow points along +x at angle 180 (its tip is at the position)
            angle = 180.0 - math.degrees(math.atan2(dy, dx))
            arrow = pg.ArrowItem(pos=(end[i], end[j]), angle=angle, headLen=9 if chosen else 7,
                                 pen=plots.pen(colour, 1.0), brush=plots.brush(colour, 255))
            plot.addItem(arrow)
