"""Vector plots of the calibration report, drawn with QPainter straight onto the PDF page.

Two kinds: an error curve with its expanded-uncertainty band (:func:`draw_curve`) and grouped
bars with whiskers (:func:`draw_bars`). Both take the rectangle to fill in device units and a
``scale`` (device units per point) so that lines and fonts keep their size at any resolution.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QBrush, QColor, QFont, QFontMetricsF, QPainter, QPen, QPolygonF
from volucal.core.report_blocks import BarChart, Curve, IsoGraph, Signatures

INK = QColor("#1b1b1b")
GRID = QColor("#d9d9d9")
LINE = QColor("#1d3557")
BAND = QColor(69, 123, 157, 90)
SERIES = (QColor("#457b9d"), QColor("#e63946"), QColor("#8ac926"), QColor("#ffb703"))


def nice_ticks(low: float, high: float, count: int = 5) -> list[float]:
    """Round tick values (1, 2, 2.5, 5 × 10ⁿ steps) with about ``count`` intervals; the first
    is at or below ``low`` and the last at or above ``high``, so the ticks span the data."""
    if not (math.isfinite(low) and math.isfinite(high)):
        return [0.0]
    if high <= low:
        low, high = low - 1.0, high + 1.0
    raw = (high - low) / count
    magnitude = 10.0 ** math.floor(math.log10(raw))
    step = next(m * magnitude for m in (1, 2, 2.5, 5, 10) if m * magnitude >= raw * 0.999)
    first = math.floor(low / step + 1e-9)
    last = math.ceil(high / step - 1e-9)
    return [0.0 if k == 0 else k * step for k in range(first, last + 1)]


def tick_text(value: float, ticks: Sequence[float]) -> str:
    step = abs(ticks[1] - ticks[0]) if len(ticks) > 1 else 1.0
    digits = max(0, -math.floor(math.log10(step) + 1e-9)) if step > 0 else 0
    scaled = step * 10**digits
    if abs(scaled - round(scaled)) > 1e-6:  # 2.5-type steps need one more digit
        digits += 1
    return f"{value:.{digits}f}".replace("-", "−")


def _font(size_pt: float, bold: bool = False) -> QFont:
    font = QFont()
    font.setPointSizeF(size_pt)
    font.setBold(bold)
    for tag in ("liga", "clig"):  # extracted text reads as typed (see report.report_font)
        font.setFeature(QFont.Tag(tag), 0)
    return font


class _Frame:
    """Maps data coordinates into a plot rectangle and draws its axes and grid."""

    def __init__(self, painter: QPainter, rect: QRectF, scale: float, title: str,
                 x_ticks: list[float], y_ticks: list[float], y_label: str,
                 x_labels: Sequence[str] | None = None) -> None:
        self.painter = painter
        self.scale = scale
        label_font = _font(6.5)
        metrics = QFontMetricsF(label_font, painter.device())
        title_font = _font(7.5, bold=True)
        title_height = QFontMetricsF(title_font, painter.device()).height()
        y_texts = [tick_text(v, y_ticks) for v in y_ticks]
        left = max(metrics.horizontalAdvance(t) for t in y_texts) + 4 * scale + metrics.height()
        self.plot = QRectF(rect.left() + left, rect.top() + title_height + 3 * scale,
                           rect.width() - left - 4 * scale,
                           rect.height() - title_height - 3 * scale - 2.4 * metrics.height())
        self.x_range = (x_ticks[0], x_ticks[-1])
        self.y_range = (y_ticks[0], y_ticks[-1])
        painter.setFont(title_font)
        painter.setPen(INK)
        painter.drawText(QRectF(rect.left(), rect.top(), rect.width(), title_height),
                         Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignVCenter, title)
        painter.setFont(label_font)
        grid = QPen(GRID, 0.4 * scale)
        for value, text in zip(y_ticks, y_texts, strict=True):
            y = self.y(value)
            painter.setPen(grid)
            painter.drawLine(QPointF(self.plot.left(), y), QPointF(self.plot.right(), y))
            painter.setPen(INK)
            painter.drawText(QRectF(rect.left(), y - metrics.height() / 2,
                                    self.plot.left() - rect.left() - 3 * scale, metrics.height()),
                             Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter, text)
        if x_labels is None:
            for value in x_ticks:
                x = self.x(value)
                painter.setPen(grid)
                painter.drawLine(QPointF(x, self.plot.top()), QPointF(x, self.plot.bottom()))
                painter.setPen(INK)
                painter.drawText(QRectF(x - 20 * scale, self.plot.bottom() + 1.5 * scale,
                                        40 * scale, metrics.height()),
                                 Qt.AlignmentFlag.AlignHCenter, tick_text(value, x_ticks))
        painter.setPen(QPen(INK, 0.6 * scale))
        painter.setBrush(Qt.BrushStyle.NoBrush)
        painter.drawRect(self.plot)
        painter.save()
        painter.translate(rect.left(), self.plot.center().y())
        painter.rotate(-90)
        painter.drawText(QRectF(-self.plot.height() / 2, 0, self.plot.height(), metrics.height()),
                         Qt.AlignmentFlag.AlignHCenter, y_label)
        painter.restore()
        self.label_height = metrics.height()

    def x(self, value: float) -> float:
        low, high = self.x_range
        return self.plot.left() + (value - low) / (high - low) * self.plot.width()

    def y(self, value: float) -> float:
        low, high = self.y_range
        return self.plot.bottom() - (value - low) / (high - low) * self.plot.height()

    def x_label(self, text: str) -> None:
        self.painter.setPen(INK)
        self.painter.drawText(
            QRectF(self.plot.left(), self.plot.bottom() + 1.2 * self.label_height,
                   self.plot.width(), self.label_height),
            Qt.AlignmentFlag.AlignHCenter, text)


def draw_curve(painter: QPainter, rect: QRectF, curve: Curve, scale: float) -> None:
    """An error function (line) with its ±U band (shaded) and the zero line (dashed)."""
    x = np.asarray(curve.position_mm, dtype=float)
    value = np.asarray(curve.value, dtype=float)
    band = np.asarray(curve.expanded_uncertainty, dtype=float)
    high = value + band
    low = value - band
    y_min = min(0.0, float(np.nanmin(low))) if low.size else -1.0
    y_max = max(0.0, float(np.nanmax(high))) if high.size else 1.0
    pad = 0.08 * (y_max - y_min) if y_max > y_min else 1.0
    frame = _Frame(painter, rect, scale, curve.title, nice_ticks(float(x[0]), float(x[-1])),
                   nice_ticks(y_min - pad, y_max + pad, 4), curve.unit)
    painter.save()
    painter.setClipRect(frame.plot)
    outline = [QPointF(frame.x(a), frame.y(b)) for a, b in zip(x, high, strict=True)]
    outline += [QPointF(frame.x(a), frame.y(b)) for a, b in zip(x[::-1], low[::-1], strict=True)]
    painter.setPen(Qt.PenStyle.NoPen)
    painter.setBrush(QBrush(BAND))
    painter.drawPolygon(QPolygonF(outline))
    painter.setPen(QPen(INK, 0.4 * scale, Qt.PenStyle.DashLine))
    painter.drawLine(QPointF(frame.plot.left(), frame.y(0.0)),
                     QPointF(frame.plot.right(), frame.y(0.0)))
    painter.setPen(QPen(LINE, 1.0 * scale))
    painter.setBrush(Qt.BrushStyle.NoBrush)
    painter.drawPolyline(QPolygonF([QPointF(frame.x(a), frame.y(b))
                                    for a, b in zip(x, value, strict=True)]))
    painter.restore()
    frame.x_label(f"{curve.axis} mm")


def draw_bars(painter: QPainter, rect: QRectF, chart: BarChart, scale: float) -> None:
    """Grouped bars, one group per category, with ±1 std whiskers and a legend."""
    values = np.asarray(chart.values, dtype=float)
    errors = np.asarray(chart.errors, dtype=float) if chart.errors else np.zeros_like(values)
    top = float(np.nanmax(values + errors)) if values.size else 1.0
    bottom = min(0.0, float(np.nanmin(values - errors))) if values.size else 0.0
    y_ticks = nice_ticks(bottom, top * 1.08 if top > 0 else 1.0, 4)
    frame = _Frame(painter, rect, scale, chart.title, [0.0, float(len(chart.categories))],
                   y_ticks, chart.y_label, x_labels=chart.categories)
    groups = len(chart.categories)
    count = len(chart.series)
    slot = frame.plot.width() / max(groups, 1)
    width = slot * 0.75 / max(count, 1)
    metrics = QFontMetricsF(painter.font(), painter.device())
    for g, category in enumerate(chart.categories):
        left = frame.plot.left() + g * slot + slot * 0.125
        for s in range(count):
            value = values[s, g]
            color = SERIES[s % len(SERIES)]
            x0 = left + s * width
            y0, y1 = frame.y(max(value, 0.0)), frame.y(min(value, 0.0))
            painter.fillRect(QRectF(x0, y0, width * 0.92, max(y1 - y0, 0.2 * scale)), color)
            if errors[s, g] > 0:
                centre = x0 + width * 0.46
                painter.setPen(QPen(INK, 0.5 * scale))
                painter.drawLine(QPointF(centre, frame.y(value - errors[s, g])),
                                 QPointF(centre, frame.y(value + errors[s, g])))
        painter.setPen(INK)
        painter.drawText(QRectF(frame.plot.left() + g * slot, frame.plot.bottom() + 1.5 * scale,
                                slot, metrics.height()),
                         Qt.AlignmentFlag.AlignHCenter, category)
    legend_x = frame.plot.right() - 4 * scale
    for s in reversed(range(count)):
        text = chart.series[s]
        advance = metrics.horizontalAdvance(text)
        legend_x -= advance
        painter.setPen(INK)
        painter.drawText(QPointF(legend_x, frame.plot.top() + 3 * scale + metrics.ascent()),
                         text)
        legend_x -= 8 * scale
        painter.fillRect(QRectF(legend_x, frame.plot.top() + 3 * scale + metrics.ascent() * 0.2,
                                6 * scale, metrics.ascent() * 0.8), SERIES[s % len(SERIES)])
        legend_x -= 6 * scale


def draw_iso_graph(painter: QPainter, rect: QRectF, graph: IsoGraph, scale: float) -> None:
    """The ISO 230-2 graph of a line: x̄↑ and x̄↓ with their ±2s bands, the bidirectional mean
    (dashed), over the targets' positions on the line's axis; a legend under the plot, off the
    data."""
    x = np.asarray(graph.positions_mm, dtype=float)
    up = np.asarray(graph.mean_up, dtype=float)
    down = np.asarray(graph.mean_down, dtype=float)
    s_up = np.asarray(graph.s_up, dtype=float)
    s_down = np.asarray(graph.s_down, dtype=float)
    bands = {"↑": (up - 2 * s_up, up + 2 * s_up), "↓": (down - 2 * s_down, down + 2 * s_down)}
    values = np.concatenate([v for pair in bands.values() for v in pair])
    finite = values[np.isfinite(values)]
    y_min = min(0.0, float(finite.min())) if finite.size else -1.0
    y_max = max(0.0, float(finite.max())) if finite.size else 1.0
    pad = 0.08 * (y_max - y_min) if y_max > y_min else 1.0
    metrics = QFontMetricsF(_font(6.5), painter.device())
    legend_height = 1.6 * metrics.height()
    plot_rect = QRectF(rect.left(), rect.top(), rect.width(), rect.height() - legend_height)
    frame = _Frame(painter, plot_rect, scale, graph.title,
                   nice_ticks(float(np.nanmin(x)), float(np.nanmax(x))),
                   nice_ticks(y_min - pad, y_max + pad, 4), f"deviation ({graph.unit})")
    series = (("x̄↑ ± 2s (forward)", up, bands["↑"], SERIES[0]),
              ("x̄↓ ± 2s (backward)", down, bands["↓"], SERIES[1]))
    painter.save()
    painter.setClipRect(frame.plot)
    for _label, mean, (low, high), colour in series:
        keep = np.isfinite(mean) & np.isfinite(low) & np.isfinite(high)
        if keep.sum() < 2:
            continue
        band = QColor(colour)
        band.setAlpha(60)
        outline = [QPointF(frame.x(a), frame.y(b)) for a, b in zip(x[keep], high[keep],
                                                                   strict=True)]
        outline += [QPointF(frame.x(a), frame.y(b)) for a, b in zip(x[keep][::-1],
                                                                    low[keep][::-1], strict=True)]
        painter.setPen(Qt.PenStyle.NoPen)
        painter.setBrush(QBrush(band))
        painter.drawPolygon(QPolygonF(outline))
        painter.setPen(QPen(colour, 1.0 * scale))
        painter.setBrush(Qt.BrushStyle.NoBrush)
        painter.drawPolyline(QPolygonF([QPointF(frame.x(a), frame.y(b))
                                        for a, b in zip(x[keep], mean[keep], strict=True)]))
    both = np.isfinite(up) & np.isfinite(down)
    if both.sum() >= 2:
        painter.setPen(QPen(INK, 0.7 * scale, Qt.PenStyle.DashLine))
        painter.drawPolyline(QPolygonF([QPointF(frame.x(a), frame.y(0.5 * (b + c)))
                                        for a, b, c in zip(x[both], up[both], down[both],
                                                           strict=True)]))
    painter.setPen(QPen(INK, 0.4 * scale, Qt.PenStyle.DotLine))
    painter.drawLine(QPointF(frame.plot.left(), frame.y(0.0)),
                     QPointF(frame.plot.right(), frame.y(0.0)))
    painter.restore()
    frame.x_label(graph.position_title)
    # the legend, in a row under the plot
    painter.setFont(_font(6.5))
    left = frame.plot.left()
    top = rect.bottom() - legend_height + 0.3 * metrics.height()
    entries = [(label, colour, Qt.PenStyle.SolidLine) for label, _m, _b, colour in series]
    entries.append(("bidirectional mean x̄", INK, Qt.PenStyle.DashLine))
    for label, colour, style in entries:
        painter.setPen(QPen(colour, 1.4 * scale, style))
        y = top + metrics.height() / 2
        painter.drawLine(QPointF(left, y), QPointF(left + 10 * scale, y))
        painter.setPen(INK)
        painter.drawText(QPointF(left + 13 * scale, top + metrics.ascent()), label)
        left += 13 * scale + metrics.horizontalAdvance(label) + 12 * scale


def draw_signatures(painter: QPainter, rect: QRectF, block: Signatures, scale: float) -> None:
    """One column per role: the role, the name printed, and lines for the date and signature."""
    painter.save()
    font = _font(7.5)
    bold = _font(7.5, bold=True)
    metrics = QFontMetricsF(font, painter.device())
    count = max(len(block.roles), 1)
    gap = 10 * scale
    width = (rect.width() - gap * (count - 1)) / count
    for k, (role, name) in enumerate(block.roles):
        left = rect.left() + k * (width + gap)
        y = rect.top() + metrics.ascent()
        painter.setFont(bold)
        painter.setPen(INK)
        painter.drawText(QPointF(left, y), role)
        painter.setFont(font)
        y += 1.6 * metrics.height()
        painter.drawText(QPointF(left, y), f"Name: {name}" if name else "Name:")
        for label in ("Date:", "Signature:"):
            y += 2.4 * metrics.height()
            painter.drawText(QPointF(left, y), label)
            start = left + metrics.horizontalAdvance("Signature:") + 4 * scale
            painter.setPen(QPen(INK, 0.5 * scale))
            line_y = y + 1.5 * scale
            painter.drawLine(QPointF(start, line_y), QPointF(left + width, line_y))
            painter.setPen(INK)
    painter.restore()
