"""The thermal page of the PDF report: the time-series plot, drawn with QPainter.

:func:`draw_thermal_plot` draws a :class:`volucal.core.thermal_report.ThermalPlot` into a
rectangle of a page, as :mod:`volucal.app.report_plots` draws the other plots (device units, a
``scale`` of device units per point): above, the measured error (grey) and the model's prediction
(blue) against time in hours, the training/test split as a dashed line; below, the residual
(measured − predicted), what compensation leaves. To put it in the report, the report layout
places a ``ThermalPlot`` block ``THERMAL_PLOT_HEIGHT_MM`` high and calls this function.

:func:`write_thermal_pdf` renders thermal sections on their own (A4 pages, the report's fonts and
style), for a thermal test's own report and for testing the page without the full report.
"""

from __future__ import annotations

import html
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PySide6.QtCore import QMarginsF, QPointF, QRectF, Qt
from PySide6.QtGui import (
    QColor,
    QFont,
    QFontMetricsF,
    QPageLayout,
    QPageSize,
    QPainter,
    QPdfWriter,
    QPen,
    QPolygonF,
    QTextDocument,
)
from volucal.core.report_content import Paragraph, Section, Table
from volucal.core.thermal_report import ThermalPlot
from volucal.core.userror import UserError

from .report_plots import nice_ticks, tick_text

THERMAL_PLOT_HEIGHT_MM = 95.0
INK = QColor("#1b1b1b")
GRID = QColor("#d9d9d9")
MEASURED = QColor("#7f7f7f")
PREDICTED = QColor("#1f77b4")
RESIDUAL = QColor("#d62728")
UNIT_TEXT = {"um": "µm", "urad": "µrad"}


def _font(size_pt: float, bold: bool = False) -> QFont:
    font = QFont()
    font.setPointSizeF(size_pt)
    font.setBold(bold)
    for tag in ("liga", "clig"):  # extracted text reads as typed (see report.report_font)
        font.setFeature(QFont.Tag(tag), 0)
    return font


class _Panel:
    """One plot panel: data → device coordinates, grid, ticks and labels."""

    def __init__(self, painter: QPainter, rect: QRectF, scale: float, title: str,
                 x_ticks: list[float], y_ticks: list[float], y_label: str,
                 x_label: str | None) -> None:
        metrics = QFontMetricsF(_font(6.5), painter.device())
        title_height = QFontMetricsF(_font(7.5, True), painter.device()).height()
        y_texts = [tick_text(v, y_ticks) for v in y_ticks]
        left = max(metrics.horizontalAdvance(t) for t in y_texts) + 4 * scale + metrics.height()
        bottom = metrics.height() * (2.4 if x_label else 1.3)
        self.plot = QRectF(rect.left() + left, rect.top() + title_height + 2 * scale,
                           rect.width() - left - 4 * scale,
                           rect.height() - title_height - 2 * scale - bottom)
        self.x_range = (x_ticks[0], x_ticks[-1])
        self.y_range = (y_ticks[0], y_ticks[-1])
        painter.setFont(_font(7.5, True))
        painter.setPen(INK)
        painter.drawText(QRectF(rect.left(), rect.top(), rect.width(), title_height),
                         Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignVCenter, title)
        painter.setFont(_font(6.5))
        grid = QPen(GRID, 0.4 * scale)
        for value, text in zip(y_ticks, y_texts, strict=True):
            y = self.y(value)
            painter.setPen(grid)
            painter.drawLine(QPointF(self.plot.left(), y), QPointF(self.plot.right(), y))
            painter.setPen(INK)
            painter.drawText(QRectF(rect.left(), y - metrics.height() / 2,
                                    self.plot.left() - rect.left() - 3 * scale, metrics.height()),
                             Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter, text)
        for value in x_ticks:
            x = self.x(value)
            painter.setPen(grid)
            painter.drawLine(QPointF(x, self.plot.top()), QPointF(x, self.plot.bottom()))
            painter.setPen(INK)
            painter.drawText(QRectF(x - 20 * scale, self.plot.bottom() + 1.5 * scale,
                                    40 * scale, metrics.height()),
                             Qt.AlignmentFlag.AlignHCenter, tick_text(value, x_ticks))
        if x_label:
            painter.drawText(QRectF(self.plot.left(), self.plot.bottom() + 1.2 * metrics.height(),
                                    self.plot.width(), metrics.height()),
                             Qt.AlignmentFlag.AlignHCenter, x_label)
        painter.setPen(QPen(INK, 0.6 * scale))
        painter.setBrush(Qt.BrushStyle.NoBrush)
        painter.drawRect(self.plot)
        painter.save()
        painter.translate(rect.left(), self.plot.center().y())
        painter.rotate(-90)
        painter.drawText(QRectF(-self.plot.height() / 2, 0, self.plot.height(), metrics.height()),
                         Qt.AlignmentFlag.AlignHCenter, y_label)
        painter.restore()

    def x(self, value: float) -> float:
        low, high = self.x_range
        return self.plot.left() + (value - low) / (high - low) * self.plot.width()

    def y(self, value: float) -> float:
        low, high = self.y_range
        return self.plot.bottom() - (value - low) / (high - low) * self.plot.height()

    def polyline(self, painter: QPainter, x: np.ndarray, y: np.ndarray, pen: QPen) -> None:
        painter.save()
        painter.setClipRect(self.plot)
        painter.setPen(pen)
        painter.drawPolyline(QPolygonF([QPointF(self.x(a), self.y(b))
                                        for a, b in zip(x, y, strict=True)]))
        painter.restore()

    def split(self, painter: QPainter, at: float, scale: float) -> None:
        painter.save()
        painter.setPen(QPen(INK, 0.5 * scale, Qt.PenStyle.DashLine))
        painter.drawLine(QPointF(self.x(at), self.plot.top()),
                         QPointF(self.x(at), self.plot.bottom()))
        painter.setFont(_font(6.0))
        metrics = QFontMetricsF(painter.font(), painter.device())
        painter.drawText(QPointF(self.x(at) - metrics.horizontalAdvance("training ") -
                                 1 * scale, self.plot.top() + metrics.ascent() + scale),
                         "training")
        painter.drawText(QPointF(self.x(at) + 2 * scale, self.plot.top() + metrics.ascent() +
                                 scale), "test (held out)")
        painter.restore()


def _ticks(values: np.ndarray, count: int) -> list[float]:
    finite = values[np.isfinite(values)]
    if not finite.size:
        return [0.0, 1.0]
    low, high = float(finite.min()), float(finite.max())
    pad = 0.05 * (high - low) if high > low else 1.0
    return nice_ticks(low - pad, high + pad, count)


def draw_thermal_plot(painter: QPainter, rect: QRectF, plot: ThermalPlot, scale: float) -> None:
    """Measured and predicted error over time (top), the residual (bottom), the split."""
    t = np.asarray(plot.time_h, dtype=float)
    measured = np.asarray(plot.measured, dtype=float)
    predicted = np.asarray(plot.predicted, dtype=float)
    residual = measured - predicted
    unit = UNIT_TEXT.get(plot.unit, plot.unit)
    x_ticks = nice_ticks(float(t[0]), float(t[-1]), 6)
    top = QRectF(rect.left(), rect.top(), rect.width(), rect.height() * 0.62)
    bottom = QRectF(rect.left(), top.bottom() + 2 * scale, rect.width(),
                    rect.height() - top.height() - 2 * scale)
    upper = _Panel(painter, top, scale, f"{plot.title} (grey measured, blue predicted)",
                   x_ticks, _ticks(np.concatenate([measured, predicted]), 5), unit, None)
    upper.polyline(painter, t, measured, QPen(MEASURED, 0.7 * scale))
    upper.polyline(painter, t, predicted, QPen(PREDICTED, 1.0 * scale))
    lower = _Panel(painter, bottom, scale, "residual: measured − predicted", x_ticks,
                   _ticks(np.concatenate([residual, [0.0]]), 4), unit, "time (h)")
    lower.polyline(painter, t, residual, QPen(RESIDUAL, 0.7 * scale))
    if plot.split_h is not None:
        upper.split(painter, plot.split_h, scale)
        lower.split(painter, plot.split_h, scale)


# --------------------------------------------------------------------------------------------
# Standalone pages
# --------------------------------------------------------------------------------------------

CSS = """
body { font-size: 9pt; color: #1b1b1b; }
h2 { font-size: 13pt; font-weight: bold; color: #1d3557; }
p.note { font-size: 8pt; color: #444444; }
p.caption { font-size: 8pt; font-style: italic; color: #444444; }
table { border-collapse: collapse; font-size: 7pt; }
th { background-color: #e3eaf2; font-weight: bold; }
"""


def _html(block: Paragraph | Table) -> str:
    if isinstance(block, Paragraph):
        return f'<p class="{block.kind}">{html.escape(block.text)}</p>'
    align = {"l": "left", "r": "right", "c": "center"}
    letters = (block.align or "").ljust(len(block.header), "l")
    out = [f'<p class="caption">{html.escape(block.caption)}</p>'] if block.caption else []
    out.append('<table width="100%" cellspacing="0" cellpadding="2" border="0.5">')
    out.append("<tr>" + "".join(f'<th align="{align[letters[k]]}">{html.escape(h)}</th>'
                                for k, h in enumerate(block.header)) + "</tr>")
    for row in block.rows:
        out.append("<tr>" + "".join(f'<td align="{align[letters[k]]}">{html.escape(c)}</td>'
                                    for k, c in enumerate(row)) + "</tr>")
    out.append("</table>")
    return "".join(out)


def write_thermal_pdf(sections: Sequence[Section], pdf_path: str | Path) -> int:
    """Write thermal sections as an A4 PDF (atomically); returns the number of pages. Needs a
    running Qt application (``volucal.app.report.ensure_application``)."""
    target = Path(pdf_path)
    temporary = target.with_name(f".{target.name}.tmp-{os.getpid()}")
    writer = QPdfWriter(str(temporary))
    writer.setResolution(300)
    writer.setPageLayout(QPageLayout(QPageSize(QPageSize.PageSizeId.A4),
                                     QPageLayout.Orientation.Portrait,
                                     QMarginsF(16, 16, 16, 16), QPageLayout.Unit.Millimeter))
    writer.setTitle("volucal thermal report")
    mm = writer.resolution() / 25.4
    scale = writer.resolution() / 72.0
    width, height = writer.width(), writer.height()
    painter = QPainter()
    if not painter.begin(writer):
        raise UserError(f"{target}: cannot write a PDF there")
    pages = 1
    y = 0.0
    try:
        for section in sections:
            items: list[tuple[float, object]] = []
            for block in (Paragraph(section.title, "heading"), *section.blocks):
                if isinstance(block, ThermalPlot):
                    items.append((THERMAL_PLOT_HEIGHT_MM * mm, block))
                    continue
                doc = QTextDocument()
                doc.documentLayout().setPaintDevice(writer)
                doc.setDefaultFont(_font(9.0))
                doc.setDefaultStyleSheet(CSS)
                doc.setDocumentMargin(0)
                body = (f"<h2>{html.escape(block.text)}</h2>" if isinstance(block, Paragraph)
                        and block.kind == "heading" else _html(block))  # type: ignore[arg-type]
                doc.setHtml(f"<html><body>{body}</body></html>")
                doc.setTextWidth(width)
                items.append((doc.size().height(), doc))
            for block_height, item in items:
                if y > 0 and y + block_height > height:
                    writer.newPage()
                    pages += 1
                    y = 0.0
                if isinstance(item, ThermalPlot):
                    draw_thermal_plot(painter, QRectF(0, y, width, block_height), item, scale)
                else:
                    painter.save()
                    painter.translate(0, y)
                    item.drawContents(painter)  # type: ignore[attr-defined]
                    painter.restore()
                y += block_height + 3 * mm
    finally:
        painter.end()
    try:
        os.replace(temporary, target)
    except OSError as exc:
        temporary.unlink(missing_ok=True)
        raise UserError(f"{target}: cannot write the report ({exc.strerror or exc})") from None
    return pages
