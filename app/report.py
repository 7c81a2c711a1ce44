"""The calibration report as a PDF, written with Qt's own PDF writer (QPdfWriter).

:func:`write_report` gathers the report of a project (:func:`volucal.core.report_content.
build_report`) and :func:`render_pdf` lays it out on A4 pages: text and tables through
QTextDocument (real text, searchable and copyable), error curves and bar charts as vector
drawings (:mod:`volucal.app.report_plots`). Layout is two passes: the first places every block
(a table too long for the rest of a page continues on the next one with its header repeated, a
heading never ends a page), the second draws the pages with "page n of N" in the footer.

Needs a QGuiApplication (``volucal report`` creates one on the offscreen platform when there is
no display); everything runs in the calling thread.
"""

from __future__ import annotations

import html
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from PySide6.QtCore import QMarginsF, QRectF, Qt
from PySide6.QtGui import (
    QColor,
    QFont,
    QGuiApplication,
    QPageLayout,
    QPageSize,
    QPainter,
    QPdfWriter,
    QTextDocument,
)
from volucal.core.certificate import Certificate
from volucal.core.conformance import CONFORMS, DOES_NOT_CONFORM
from volucal.core.display_units import DisplayUnits
from volucal.core.report_blocks import (
    BarChart,
    Block,
    CurveGrid,
    IsoGraphs,
    Paragraph,
    Signatures,
    Table,
)
from volucal.core.report_content import ReportContent, ReportRequest, build_report
from volucal.core.thermal_report import ThermalPlot
from volucal.core.tolerances import Tolerances
from volucal.core.userror import UserError

from .report_plots import draw_bars, draw_curve, draw_iso_graph, draw_signatures
from .report_thermal import THERMAL_PLOT_HEIGHT_MM, draw_thermal_plot

RESOLUTION_DPI = 300
MARGIN_MM = 16.0
BODY_PT = 9.0
TABLE_PT = 7.0
CURVE_HEIGHT_MM = 46.0
CHART_HEIGHT_MM = 58.0
ISO_GRAPH_HEIGHT_MM = 62.0
SIGNATURE_HEIGHT_MM = 30.0
GAP_MM = 3.0
#: A heading needs this much room below it on the same page, or it starts the next page.
KEEP_WITH_NEXT_MM = 35.0
#: Tables of at most this many rows are kept on one page; longer ones are split, but only where
#: at least MIN_SPLIT_ROWS rows fit.
KEEP_TABLE_ROWS = 12
MIN_SPLIT_ROWS = 3
VERDICT_COLORS = {CONFORMS: "#2a7d2e", DOES_NOT_CONFORM: "#b3261e"}
NO_DECISION_COLOR = "#a05a00"
PASS_COLOR = VERDICT_COLORS[CONFORMS]
FAIL_COLOR = VERDICT_COLORS[DOES_NOT_CONFORM]

CSS = f"""
body {{ font-size: {BODY_PT}pt; color: #1b1b1b; }}
h1 {{ font-size: 20pt; font-weight: bold; color: #1d3557; margin: 0; }}
h2 {{ font-size: 13pt; font-weight: bold; color: #1d3557; margin: 0; }}
p {{ margin: 0; }}
p.note {{ font-size: {BODY_PT - 1}pt; color: #444444; }}
p.caption {{ font-size: {BODY_PT - 1}pt; font-style: italic; color: #444444; }}
p.subtitle {{ font-size: 11pt; color: #444444; }}
table {{ border-collapse: collapse; font-size: {TABLE_PT}pt; }}
th {{ background-color: #e3eaf2; font-weight: bold; }}
td.key {{ font-weight: bold; }}
"""


@dataclass(frozen=True)
class ReportFile:
    """What :func:`write_report` wrote."""

    path: Path
    pages: int
    content: ReportContent


def write_report(
    project_path: str | Path,
    pdf_path: str | Path,
    tolerance_um: float | None = None,
    tolerance_on: str = "accuracy",
    compensation_dir: str | Path | None = None,
    report_json: str | Path | None = None,
    certificate: Certificate | None = None,
    tolerances: Tolerances | None = None,
    remeasurement: str | Path | None = None,
    units: DisplayUnits | None = None,
) -> ReportFile:
    """Write the calibration report of a project as a PDF.

    Parameters
    ----------
    project_path : the HDF5 project.
    pdf_path : the PDF to write (replaced if it exists; written through a temporary file).
    tolerance_um, tolerance_on : the ISO 14253-1 conformance decision (``accuracy``: ISO 230-2
        A of each linear line; ``volumetric``: the largest |E|); none without a tolerance.
    compensation_dir, report_json : where the compensation files and the run's report.json are,
        when not beside the project (see :class:`volucal.core.report_content.ReportRequest`).
    certificate, tolerances : certificate fields and ISO 230-2 limits per axis that replace the
        project's.
    remeasurement : a project of the lines measured again on the compensated machine.
    units : the units deviations and angles are shown in (µm and µrad by default).
    """
    content = build_report(ReportRequest(
        project_path=Path(project_path),
        compensation_dir=None if compensation_dir is None else Path(compensation_dir),
        report_json=None if report_json is None else Path(report_json),
        tolerance_um=tolerance_um,
        tolerance_on=tolerance_on,
        certificate=certificate,
        tolerances=tolerances,
        remeasurement_path=None if remeasurement is None else Path(remeasurement),
        units=units or DisplayUnits(),
    ))
    return write_content(content, pdf_path)


def write_content(content: ReportContent, pdf_path: str | Path) -> ReportFile:
    """Render gathered report content to a PDF (atomically). Call it on the GUI thread in a
    running application: Qt's text layout is not safe to use from a worker thread."""
    target = Path(pdf_path)
    if target.parent and not target.parent.is_dir():
        raise UserError(f"{target}: the folder {target.parent} does not exist")
    temporary = target.with_name(f".{target.name}.tmp-{os.getpid()}")
    try:
        pages = render_pdf(content, temporary)
        os.replace(temporary, target)
    except OSError as exc:
        raise UserError(f"{target}: cannot write the report ({exc.strerror or exc})") from None
    finally:
        temporary.unlink(missing_ok=True)
    return ReportFile(target, pages, content)


def ensure_application() -> QGuiApplication:
    """The running Qt application, or a new QGuiApplication (offscreen without a display)."""
    app = QGuiApplication.instance()
    if app is None:
        if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
        app = QGuiApplication(["volucal"])
    return app  # type: ignore[return-value]


# --------------------------------------------------------------------------------------------
# Layout
# --------------------------------------------------------------------------------------------


@dataclass
class _Placed:
    page: int
    top: float
    height: float
    draw: Callable[[QPainter, QRectF], None]


class _Layout:
    """Places blocks top to bottom on pages of the writer's content rectangle."""

    def __init__(self, writer: QPdfWriter, content: ReportContent) -> None:
        self.writer = writer
        self.content = content
        self.mm = writer.resolution() / 25.4
        self.scale = writer.resolution() / 72.0  # device units per point
        self.width = writer.width()
        self.height = writer.height() - 9 * self.mm  # room for the footer
        self.page = 0
        self.y = 0.0
        self.placed: list[_Placed] = []

    # -- measuring ---------------------------------------------------------------------------

    def document(self, body: str) -> QTextDocument:
        doc = QTextDocument()
        doc.documentLayout().setPaintDevice(self.writer)
        doc.setDefaultFont(report_font(BODY_PT))
        doc.setDefaultStyleSheet(CSS)
        doc.setDocumentMargin(0)
        doc.setHtml(f"<html><body>{body}</body></html>")
        doc.setTextWidth(self.width)
        return doc

    # -- placing -----------------------------------------------------------------------------

    def remaining(self) -> float:
        return self.height - self.y

    def new_page(self) -> None:
        self.page += 1
        self.y = 0.0

    def place(self, height: float, draw: Callable[[QPainter, QRectF], None],
              gap: float | None = None) -> None:
        if height > self.remaining() and self.y > 0:
            self.new_page()
        self.placed.append(_Placed(self.page, self.y, height, draw))
        self.y += height + (GAP_MM * self.mm if gap is None else gap)

    def place_html(self, body: str, gap: float | None = None) -> None:
        doc = self.document(body)
        self.place(doc.size().height(), _draw_document(doc), gap)

    def heading(self, title: str) -> None:
        doc = self.document(f"<h2>{html.escape(title)}</h2>")
        height = doc.size().height()
        if self.y > 0 and self.remaining() < height + KEEP_WITH_NEXT_MM * self.mm:
            self.new_page()
        if self.y > 0:
            self.y += 3 * self.mm
        self.place(height, _draw_document(doc), 2 * self.mm)

    def block(self, block: Block) -> None:
        if isinstance(block, Paragraph):
            self.place_html(self.paragraph(block))
        elif isinstance(block, Table):
            self.table(block)
        elif isinstance(block, CurveGrid):
            self.curves(block)
        elif isinstance(block, IsoGraphs):
            self.iso_graphs(block)
        elif isinstance(block, Signatures):
            self.signatures(block)
        elif isinstance(block, ThermalPlot):
            self.place(THERMAL_PLOT_HEIGHT_MM * self.mm,
                       lambda p, r: draw_thermal_plot(p, r, block, self.scale))
        else:
            self.chart(block)

    def paragraph(self, block: Paragraph) -> str:
        text = html.escape(block.text)
        if block.kind in ("verdict", "pass", "fail"):
            verdict = self.content.conformance.verdict if self.content.conformance else ""
            color = {"pass": PASS_COLOR, "fail": FAIL_COLOR}.get(
                block.kind, VERDICT_COLORS.get(verdict, NO_DECISION_COLOR))
            return f'<p style="font-size: 11pt; font-weight: bold; color: {color}">{text}</p>'
        return f'<p class="{block.kind}">{text}</p>'

    def table(self, block: Table) -> None:
        rows = list(block.rows)
        caption = (self.document(f'<p class="caption">{html.escape(block.caption)}</p>')
                   if block.caption else None)
        caption_height = caption.size().height() + self.mm if caption else 0.0
        whole = self.document(_table_html(block, rows)).size().height() + caption_height
        if self.y > 0 and whole > self.remaining():
            # a short table is never split; a long one starts where a few rows fit
            head = self.document(_table_html(block, rows[:MIN_SPLIT_ROWS])).size().height()
            if len(rows) <= KEEP_TABLE_ROWS or caption_height + head > self.remaining():
                self.new_page()
        if caption is not None:
            self.place(caption.size().height(), _draw_document(caption), self.mm)
        while rows:
            count = self._rows_that_fit(block, rows)
            if count == 0:
                self.new_page()
                count = max(1, self._rows_that_fit(block, rows))
            doc = self.document(_table_html(block, rows[:count]))
            self.place(doc.size().height(), _draw_document(doc))
            rows = rows[count:]
            if rows:
                self.new_page()

    def _rows_that_fit(self, block: Table, rows: list[tuple[str, ...]]) -> int:
        room = self.remaining()
        if self.document(_table_html(block, rows)).size().height() <= room:
            return len(rows)
        low, high = 0, len(rows)
        while high - low > 1:  # the most rows that fit, by bisection
            middle = (low + high) // 2
            if self.document(_table_html(block, rows[:middle])).size().height() <= room:
                low = middle
            else:
                high = middle
        return low

    def curves(self, grid: CurveGrid) -> None:
        gap = 4 * self.mm
        cell_width = (self.width - gap * (grid.columns - 1)) / grid.columns
        cell_height = CURVE_HEIGHT_MM * self.mm
        curves = list(grid.curves)
        for start in range(0, len(curves), grid.columns):
            row = curves[start:start + grid.columns]

            def draw(painter: QPainter, rect: QRectF, row=row) -> None:  # type: ignore[no-untyped-def]
                for k, curve in enumerate(row):
                    cell = QRectF(rect.left() + k * (cell_width + gap), rect.top(), cell_width,
                                  rect.height())
                    draw_curve(painter, cell, curve, self.scale)

            self.place(cell_height, draw, 2 * self.mm)

    def iso_graphs(self, block: IsoGraphs) -> None:
        for graph in block.graphs:
            def draw(painter: QPainter, rect: QRectF, graph=graph) -> None:  # type: ignore[no-untyped-def]
                draw_iso_graph(painter, rect, graph, self.scale)

            self.place(ISO_GRAPH_HEIGHT_MM * self.mm, draw, self.mm)
            if graph.caption:
                self.place_html(f'<p class="caption">{html.escape(graph.caption)}</p>')

    def signatures(self, block: Signatures) -> None:
        def draw(painter: QPainter, rect: QRectF) -> None:
            draw_signatures(painter, rect, block, self.scale)

        self.place(SIGNATURE_HEIGHT_MM * self.mm, draw)

    def chart(self, chart: BarChart) -> None:
        def draw(painter: QPainter, rect: QRectF) -> None:
            draw_bars(painter, rect, chart, self.scale)

        self.place(CHART_HEIGHT_MM * self.mm, draw)

    def title(self) -> None:
        c = self.content
        self.place_html(
            f"<h1>{html.escape(c.title)}</h1>"
            f'<p class="subtitle">{html.escape(c.subtitle)}</p>'
            f'<p class="note">Generated {html.escape(c.generated)} from the project '
            f"{html.escape(Path(c.sources.get('project', '')).name)}</p>", 4 * self.mm)

    def run(self) -> int:
        self.title()
        for section in self.content.sections:
            self.heading(section.title)
            for block in section.blocks:
                self.block(block)
        return self.page + 1


def report_font(size_pt: float, bold: bool = False) -> QFont:
    """The report's font. Ligatures are off so that text copied or extracted from the PDF reads
    "fi", "ff" as typed (a search for "identified" finds it)."""
    font = QFont()
    font.setPointSizeF(size_pt)
    font.setBold(bold)
    for tag in ("liga", "clig"):
        font.setFeature(QFont.Tag(tag), 0)
    return font


def _draw_document(doc: QTextDocument) -> Callable[[QPainter, QRectF], None]:
    def draw(painter: QPainter, rect: QRectF) -> None:
        painter.save()
        painter.translate(rect.topLeft())
        doc.drawContents(painter)
        painter.restore()

    return draw


def _table_html(block: Table, rows: list[tuple[str, ...]]) -> str:
    align = {"l": "left", "r": "right", "c": "center"}
    columns = max([len(block.header), *(len(r) for r in rows)] or [1])
    letters = (block.align or "l" * columns).ljust(columns, "l")
    out = ['<table width="100%" cellspacing="0" cellpadding="3" border="0.5" '
           'style="border-color: #b0b0b0; border-style: solid">']
    if block.header:
        out.append("<tr>" + "".join(
            f'<th align="{align[letters[k]]}">{html.escape(h)}</th>'
            for k, h in enumerate(block.header)) + "</tr>")
        for row in rows:
            out.append("<tr>" + "".join(
                f'<td align="{align[letters[k]]}">{html.escape(cell)}</td>'
                for k, cell in enumerate(row)) + "</tr>")
    else:  # key/value pairs
        for row in rows:
            key, *values = row
            out.append(f'<tr><td class="key" width="28%">{html.escape(key)}</td>'
                       + "".join(f"<td>{html.escape(v)}</td>" for v in values) + "</tr>")
    out.append("</table>")
    return "".join(out)


# --------------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------------


def render_pdf(content: ReportContent, pdf_path: str | Path) -> int:
    """Lay out and write ``content`` as an A4 PDF; returns the number of pages."""
    from volucal import __version__

    ensure_application()
    writer = QPdfWriter(str(pdf_path))
    writer.setResolution(RESOLUTION_DPI)
    writer.setPageLayout(QPageLayout(
        QPageSize(QPageSize.PageSizeId.A4), QPageLayout.Orientation.Portrait,
        QMarginsF(MARGIN_MM, MARGIN_MM, MARGIN_MM, MARGIN_MM), QPageLayout.Unit.Millimeter))
    writer.setTitle(f"{content.title} — {content.subtitle}")
    writer.setCreator(f"volucal {__version__}")
    layout = _Layout(writer, content)
    pages = layout.run()
    painter = QPainter()
    if not painter.begin(writer):
        raise UserError(f"{pdf_path}: cannot write a PDF there")
    try:
        for page in range(pages):
            if page:
                writer.newPage()
            for item in layout.placed:
                if item.page == page:
                    item.draw(painter, QRectF(0, item.top, layout.width, item.height))
            _footer(painter, layout, content, page, pages)
    finally:
        painter.end()
    return pages


def _footer(painter: QPainter, layout: _Layout, content: ReportContent, page: int,
            pages: int) -> None:
    painter.setFont(report_font(7.0))
    painter.setPen(QColor("#555555"))
    top = layout.height + 4 * layout.mm
    painter.drawLine(0, int(top - 1.5 * layout.mm), int(layout.width), int(top - 1.5 * layout.mm))
    rect = QRectF(0, top, layout.width, 5 * layout.mm)
    painter.drawText(rect, Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignTop,
                     f"{content.title} — {content.subtitle}")
    painter.drawText(rect, Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignTop,
                     f"page {page + 1} of {pages}")


__all__ = ["ReportFile", "ensure_application", "render_pdf", "write_report"]
