"""Time of the calibration report on the demo project: gathering the content (GUI-free,
volucal.core.report_content) and laying it out into a PDF (volucal.app.report, Qt's PDF writer).

    python benchmarks/bench_report.py [PROJECT.h5]

Without a project the demo is calibrated once into a temporary folder first (not timed). The PDF
is compared with Qt's stock paginator (QTextDocument.print_ of the same text and tables, no plots),
the simplest way to get a PDF out of Qt.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

from PySide6.QtGui import QPdfWriter, QTextDocument  # noqa: E402
from volucal.app.report import ensure_application, render_pdf  # noqa: E402
from volucal.core.calibrate import CalibrationRequest, calibrate  # noqa: E402
from volucal.core.report_content import ReportRequest, Table, build_report  # noqa: E402
from volucal.core.resources import demo_plan  # noqa: E402

REPEATS = 3


def best_of(function, repeats: int = REPEATS) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def stock_pdf(content, path: Path) -> None:
    """The same sections' text and tables through QTextDocument.print_ (Qt paginates)."""
    parts = [f"<h1>{content.title}</h1>"]
    for section in content.sections:
        parts.append(f"<h2>{section.title}</h2>")
        for block in section.blocks:
            if isinstance(block, Table):
                rows = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>"
                               for row in block.rows)
                parts.append(f"<table>{rows}</table>")
            elif hasattr(block, "text"):
                parts.append(f"<p>{block.text}</p>")
    doc = QTextDocument()
    doc.setHtml("".join(parts))
    doc.print_(QPdfWriter(str(path)))


def main() -> int:
    ensure_application()
    with tempfile.TemporaryDirectory() as work:
        folder = Path(work)
        if len(sys.argv) > 1:
            project = Path(sys.argv[1])
        else:
            project = folder / "demo.h5"
            print("calibrating the demo once (not timed) …", flush=True)
            calibrate(CalibrationRequest(demo_plan(), project_path=project,
                                         export_dir=folder / "compensation"))
        request = ReportRequest(project, tolerance_um=25.0)
        content = build_report(request)
        gather = best_of(lambda: build_report(request))
        pages = render_pdf(content, folder / "report.pdf")
        render = best_of(lambda: render_pdf(content, folder / "report.pdf"))
        stock = best_of(lambda: stock_pdf(content, folder / "stock.pdf"))
        size_kb = (folder / "report.pdf").stat().st_size / 1024
    print(f"report of {project.name}: {pages} pages, {size_kb:.0f} kB (best of {REPEATS})")
    for label, seconds in (
        ("gather the content (project, ISO 230-2, conformance)", gather),
        ("lay out and write the PDF (text, tables, curves, charts)", render),
        ("Qt's stock paginator: same text and tables, no plots", stock),
    ):
        print(f"  {label:<58} {seconds:6.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
