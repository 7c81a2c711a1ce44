"""Plot conventions shared by the views (pyqtgraph): light background, one palette, bands.

Importing this module sets pyqtgraph's global options once: every plot of the workbench is
drawn black on white with antialiasing, like a printed calibration report.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyqtgraph as pg
from numpy.typing import ArrayLike, NDArray
from PySide6.QtCore import QPointF, Qt
from PySide6.QtGui import QAction, QColor, QPainterPath, QPolygonF
from PySide6.QtWidgets import QFileDialog, QGraphicsPathItem, QWidget
from volucal.core.userror import UserError

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
#: Tick labels never carry more decimals than this (a degenerate range has a tiny spacing).
MAX_DECIMALS = 9


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


def plain_axis(axis: pg.AxisItem) -> pg.AxisItem:
    """Ticks in the unit of the axis label, exactly: never rescaled, never "-0.000".

    pyqtgraph rescales ticks by an SI factor (showing "(x0.001)" only when the label has no
    unit), and ``enableAutoSIPrefix(False)`` freezes whatever factor the range had at that
    moment instead of resetting it: a residual plot drawn after a periodogram showed µm × 1000.
    The factor is therefore pinned to 1 for good.
    """
    def no_prefix() -> None:
        axis.autoSIPrefixScale = 1.0
        axis.labelUnitPrefix = ""
        axis._updateLabel()

    def tick_strings(values: Sequence[float], scale: float, spacing: float) -> list[str]:
        if axis.logMode:  # decades: pyqtgraph's own labels
            return list(axis.logTickStrings(values, scale, spacing))
        return tick_texts(values, spacing * scale, scale)

    axis.autoSIPrefix = False
    axis.updateAutoSIPrefix = no_prefix  # type: ignore[method-assign]
    axis.tickStrings = tick_strings  # type: ignore[method-assign]
    no_prefix()
    return axis


def tick_texts(values: Sequence[float], spacing: float, scale: float = 1.0) -> list[str]:
    """Tick labels with just the digits the spacing needs; a rounding zero is "0", never
    "-0.00"."""
    if spacing <= 0 or not math.isfinite(spacing):
        places = 0
    else:
        places = max(0, math.ceil(-math.log10(spacing) - 1e-9))
        if abs(spacing * 10**places - round(spacing * 10**places)) > 1e-6:
            places += 1  # 0.25-type spacings
        places = min(places, MAX_DECIMALS)
    out = []
    for value in values:
        text = f"{value * scale:.{places}f}"
        if float(text) == 0.0:
            text = text.lstrip("-")
        out.append(text)
    return out


def style(plot: pg.PlotItem, title: str | None = None, x: str | None = None,
          y: str | None = None) -> pg.PlotItem:
    """Grid, labels and title in the workbench's style; the axes show plain values in the
    unit of their label (:func:`plain_axis`) and the plot's menu saves it (:func:`add_export`)."""
    plot.showGrid(x=True, y=True, alpha=0.25)
    for side in ("left", "bottom"):
        axis = plot.getAxis(side)
        if not getattr(axis, "_volucal_plain", False):
            plain_axis(axis)
            axis._volucal_plain = True
    add_export(plot)
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


def add_legend(plot: pg.PlotItem, columns: int = 4) -> pg.LegendItem:
    """A legend in a row below the plot, off the data (items added with ``name=`` join it)."""
    legend = pg.LegendItem(offset=None, colCount=columns, labelTextSize="8pt",
                           verSpacing=-4)
    plot.layout.addItem(legend, 4, 1)
    plot.legend = legend
    return legend


# --------------------------------------------------------------------------------------------
# Saving a plot: the picture (PNG, SVG) and its data (CSV)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PlottedSeries:
    """One drawn series: its name and its x, y values in the units of the axis labels (and
    ``value``, the colour of a heat map's pixel at x, y)."""

    name: str
    x: NDArray[np.float64]
    y: NDArray[np.float64]
    value: NDArray[np.float64] | None = None


def axis_label(plot: pg.PlotItem, side: str) -> str:
    return str(plot.getAxis(side).labelText or "")


def plotted_series(plot: pg.PlotItem) -> list[PlottedSeries]:
    """What ``plot`` draws, as numbers: curves and points (x, y), bars (position, height),
    the image of a heat map (x, y of each pixel centre and its value)."""
    out: list[PlottedSeries] = []
    for index, item in enumerate(plot.items):
        name = item.name() if isinstance(item, pg.PlotDataItem | pg.ScatterPlotItem) else None
        if isinstance(item, pg.PlotDataItem | pg.ScatterPlotItem):
            x, y = item.getData()
            if x is None or y is None or len(x) == 0:
                continue
            out.append(PlottedSeries(str(name or f"series {index + 1}"), np.asarray(x, float),
                                     np.asarray(y, float)))
        elif isinstance(item, pg.BarGraphItem):
            opts = item.opts
            height = np.atleast_1d(np.asarray(opts.get("height"), float))
            x = opts.get("x")
            if x is None:
                x = np.asarray(opts.get("x0"), float) + 0.5 * np.asarray(opts.get("width"), float)
            out.append(PlottedSeries(str(opts.get("name") or f"bars {index + 1}"),
                                     np.asarray(x, float) * np.ones(height.size), height))
        elif isinstance(item, pg.ImageItem) and item.image is not None:
            image = np.asarray(item.image, float)
            rect = item.mapRectToParent(item.boundingRect())
            nx, ny = image.shape[:2]
            xs = rect.left() + (np.arange(nx) + 0.5) * rect.width() / nx
            ys = rect.top() + (np.arange(ny) + 0.5) * rect.height() / ny
            gx, gy = np.meshgrid(xs, ys, indexing="ij")
            values = image if image.ndim == 2 else image[..., 0]
            out.append(PlottedSeries("image", gx.ravel(), gy.ravel(), values.ravel()))
    return out


def write_csv(plot: pg.PlotItem, path: Path) -> Path:
    """The plotted data of ``plot`` as CSV: one row per point, the series named, the columns
    headed by the axis labels (their units)."""
    x_label = axis_label(plot, "bottom") or "x"
    y_label = axis_label(plot, "left") or "y"
    title = _plain_text(str(plot.titleLabel.text or ""))
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        if title:
            writer.writerow([f"# {title}"])
        series = plotted_series(plot)
        with_value = any(s.value is not None for s in series)
        writer.writerow(["series", x_label, y_label] + (["value"] if with_value else []))
        for item in series:
            values = item.value if item.value is not None else [None] * item.x.size
            for x, y, v in zip(item.x, item.y, values, strict=True):
                row = [item.name, _num(x), _num(y)]
                if with_value:
                    row.append("" if v is None else _num(v))
                writer.writerow(row)
    return path


def export_plot(plot: pg.PlotItem, path: str | Path) -> Path:
    """Save ``plot`` by the file's suffix: ``.png`` (twice the screen size), ``.svg`` or
    ``.csv`` (its data, :func:`write_csv`)."""
    from pyqtgraph.exporters import ImageExporter

    target = Path(path)
    suffix = target.suffix.lower()
    if suffix == ".csv":
        return write_csv(plot, target)
    if suffix == ".svg":
        write_svg(plot, target)
    elif suffix == ".png":
        exporter = ImageExporter(plot)
        width = max(int(plot.sceneBoundingRect().width()) * 2, 800)
        exporter.parameters()["width"] = width
        exporter.export(str(target))
    else:
        raise UserError(f"{target}: save a plot as .png, .svg or .csv")
    if not target.is_file():
        raise UserError(f"{target}: the plot could not be written")
    return target


def write_svg(plot: pg.PlotItem, path: Path) -> Path:
    """The plot as an SVG drawing, by Qt's own SVG generator (pyqtgraph's SVG exporter cannot
    read the paths Qt 6.11 writes): the plot's part of the scene, at its size on screen."""
    from PySide6.QtCore import QRectF, QSize
    from PySide6.QtGui import QPainter
    from PySide6.QtSvg import QSvgGenerator

    source = plot.sceneBoundingRect()
    generator = QSvgGenerator()
    # pyqtgraph caches drawings as QPictures made on the screen; replayed on a device of another
    # resolution they are scaled: draw the SVG at the screen's resolution
    views = plot.scene().views()
    generator.setResolution(views[0].logicalDpiX() if views else 96)
    generator.setFileName(str(path))
    generator.setSize(QSize(int(source.width()), int(source.height())))
    generator.setViewBox(QRectF(0, 0, source.width(), source.height()))
    title = _plain_text(str(plot.titleLabel.text or ""))
    generator.setTitle(title or "volucal plot")
    generator.setDescription("drawn by volucal")
    painter = QPainter()
    if not painter.begin(generator):
        raise UserError(f"{path}: cannot write an SVG file there")
    try:
        plot.scene().render(painter, QRectF(0, 0, source.width(), source.height()), source)
    finally:
        painter.end()
    return path


def add_export(plot: pg.PlotItem) -> None:
    """"Save plot…" and "Save plot data (CSV)…" in the plot's right-click menu."""
    menu = plot.vb.menu
    if getattr(menu, "_volucal_export", False):
        return
    menu._volucal_export = True
    menu.addSeparator()
    image = QAction("Save plot as PNG or SVG…", menu)
    image.triggered.connect(lambda *_a: save_dialog(plot, "PNG image (*.png);;SVG drawing (*.svg)"))
    data = QAction("Save plot data as CSV…", menu)
    data.triggered.connect(lambda *_a: save_dialog(plot, "CSV (*.csv)"))
    menu.addAction(image)
    menu.addAction(data)


def save_dialog(plot: pg.PlotItem, filters: str, parent: QWidget | None = None) -> Path | None:
    from .settings import last_folder, set_last_folder

    title = _plain_text(str(plot.titleLabel.text or "plot")) or "plot"
    stem = "".join(c if c.isalnum() or c in "-_" else "_" for c in title).strip("_")[:60]
    chosen, selected = QFileDialog.getSaveFileName(parent, "Save the plot",
                                                   str(Path(last_folder()) / stem), filters)
    if not chosen:
        return None
    path = Path(chosen)
    if not path.suffix:
        path = path.with_suffix(".csv" if "csv" in selected.lower() else
                                ".svg" if "svg" in selected.lower() else ".png")
    try:
        written = export_plot(plot, path)
    except (UserError, OSError) as exc:
        from .dialogs import show_error

        show_error(parent, "Save the plot", str(exc))
        return None
    set_last_folder(written)
    return written


def _plain_text(html_text: str) -> str:
    import re

    return re.sub(r"<[^>]+>", "", html_text).strip()


def _num(value: float) -> str:
    return "" if not math.isfinite(float(value)) else f"{float(value):.10g}"


def band_path(x: ArrayLike, low: ArrayLike, high: ArrayLike) -> QPainterPath:
    """The outline of the band between ``low`` and ``high`` (NaN stretches are left out)."""
    x = np.asarray(x, dtype=float)
    low = np.asarray(low, dtype=float)
    high = np.asarray(high, dtype=float)
    keep = np.isfinite(x) & np.isfinite(low) & np.isfinite(high)
    path = QPainterPath()
    if keep.sum() < 2:
        return path
    xs, lows, highs = x[keep], low[keep], high[keep]
    path.addPolygon(QPolygonF([QPointF(a, b) for a, b in zip(xs, highs, strict=True)]
                              + [QPointF(a, b) for a, b in zip(xs[::-1], lows[::-1],
                                                                 strict=True)]))
    path.closeSubpath()
    return path


def style_band(item: QGraphicsPathItem, colour: str = BAND, alpha: int = 60) -> None:
    item.setBrush(brush(colour, alpha))
    item.setPen(pen(colour, 0.8, alpha=120))


def add_band(plot: pg.PlotItem, x: ArrayLike, low: ArrayLike, high: ArrayLike,
             colour: str = BAND, alpha: int = 60) -> QGraphicsPathItem | None:
    """A filled band between two curves (NaN stretches are left out), drawn as one polygon:
    a window with 18 banded curves draws them in one go."""
    path = band_path(x, low, high)
    if path.isEmpty():
        return None
    item = QGraphicsPathItem(path)
    style_band(item, colour, alpha)
    plot.addItem(item)
    return item


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


def plot_items(widget: QWidget) -> list[pg.PlotItem]:
    """Every plot drawn in ``widget`` and its children, in layout order."""
    items: list[pg.PlotItem] = []
    for view in widget.findChildren(pg.GraphicsView):
        scene = view.scene()
        if scene is None:
            continue
        found = [i for i in scene.items() if isinstance(i, pg.PlotItem)]
        found.sort(key=lambda i: (i.scenePos().y(), i.scenePos().x()))
        items += [i for i in found if i not in items]
    return items


def export_view(widget: QWidget, folder: Path, prefix: str = "plot") -> list[Path]:
    """Every plot of ``widget`` that shows data, as PNG, SVG and CSV in ``folder``, named by
    its title."""
    if not folder.is_dir():
        raise UserError(f"{folder}: no such folder")
    written: list[Path] = []
    for index, plot in enumerate(plot_items(widget), start=1):
        if not plotted_series(plot):
            continue
        title = _plain_text(str(plot.titleLabel.text or "")) or f"plot {index}"
        stem = "".join(c if c.isalnum() or c in "-_" else "_" for c in title).strip("_")[:50]
        for suffix in (".png", ".svg", ".csv"):
            written.append(export_plot(plot, folder / f"{prefix}-{index:02d}-{stem}{suffix}"))
    return written
