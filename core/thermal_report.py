"""The thermal page of the PDF report, as GUI-free content blocks.

:func:`thermal_section` turns one fitted channel — a :class:`~volucal.core.thermal_fit.
ThermalFitResult`, or the same thing read back from a project (:func:`sections_for_project`) —
into a :class:`~volucal.core.report_content.Section`: what was measured, the model as a formula
with its coefficients and their uncertainty, how it was chosen, the RMS error before and after
compensation beside the baselines, the sign convention, and a :class:`ThermalPlot` block (error
and prediction over time with the training/test split, and the residual) that
``volucal.app.report_thermal.draw_thermal_plot`` draws.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .report_content import Paragraph, Section, Table
from .thermal_fit import ThermalFitResult
from .thermal_store import jsonable, load_thermal, thermal_names

UNIT_TEXT = {"um": "µm", "urad": "µrad"}
Series = Sequence[float] | NDArray[np.float64]
#: The plot keeps at most this many points per curve (a PDF does not need 5,000 per line).
PLOT_POINTS = 1200


@dataclass(frozen=True)
class ThermalPlot:
    """Measured and predicted error over time (hours), the residual, and where the training
    part ends (None: no held-out part)."""

    title: str
    unit: str
    time_h: tuple[float, ...]
    measured: tuple[float, ...]
    predicted: tuple[float, ...]
    split_h: float | None

    @property
    def residual(self) -> tuple[float, ...]:
        return tuple(m - p for m, p in zip(self.measured, self.predicted, strict=True))


def thermal_section(result: ThermalFitResult) -> Section:
    """The report section of one fitted channel."""
    return section_from_summary(
        jsonable(result.to_json()), result.time_s, result.measured, result.predicted
    )


def sections_for_project(project: Any) -> list[Section]:
    """One section per stored thermal record and channel (``/thermal/<name>``)."""
    out = []
    for name in thermal_names(project):
        stored = load_thermal(project, name)
        tree = project.result("thermal", name)
        predicted = {
            str(m["channel"]): np.asarray(m["predicted"], dtype=float)
            for m in tree.get("models", [])
        }
        for channel, summary in stored.results.items():
            measured = stored.measurement.error(channel).values
            out.append(
                section_from_summary(
                    summary, stored.measurement.time_s, measured, predicted[channel]
                )
            )
    return out


def section_from_summary(
    summary: Mapping[str, Any], time_s: Series, measured: Series, predicted: Series
) -> Section:
    """The section from a result's JSON summary (``ThermalFitResult.to_json``) and its series."""
    unit = str(summary["unit"])
    sym = UNIT_TEXT.get(unit, unit)
    model = summary["model"]
    channel = str(summary["channel"])
    train = int(summary["train_samples"])
    test = int(summary["test_samples"])
    blocks: list[Any] = []
    split = (
        f"The model was chosen and fitted on the first {train} samples "
        f"({100 * float(summary['train_fraction']):g} % of the record) and tested once on "
        f"the {test} samples after them, which played no part in the choice."
        if test
        else f"The model was chosen and fitted on all {train} samples; there is "
        "no held-out part, so only the cross-validated error is known."
    )
    blocks.append(
        Paragraph(
            f"Thermal record {summary['measurement']}, error channel {channel} ({sym}). {split} "
            f"Cross-validation: {summary['cross_validation']}."
        )
    )
    blocks.append(Paragraph(str(model["formula"]), "note"))
    rows: list[tuple[str, ...]] = [
        ("constant", f"{model['intercept']:.4f}", f"{model['intercept_std']:.4f}", sym)
    ]
    for term, weight in zip(model["terms"], summary.get("weights", []), strict=False):
        rows.append(
            (
                f"{term['label']} (centred on {term['reference_c']:.2f} °C)",
                f"{term['coefficient']:.4f}",
                f"{term['coefficient_std']:.4f}",
                str(term["coefficient_unit"]),
                f"{weight.get(f'spread_{unit}', math.nan):.3f}",
            )
        )
    blocks.append(
        Table(
            ("term", "coefficient", "standard uncertainty", "unit", f"contribution spread ({sym})"),
            tuple(r if len(r) == 5 else (*r, "") for r in rows),
            "lrrlr",
            "Model terms. Uncertainties are autocorrelation-consistent (Newey–West); the "
            "contribution spread is the standard deviation of the term over the record.",
        )
    )
    figures = [("uncompensated", summary["baselines"][0])]
    figures += [(b["name"], b) for b in summary["baselines"][1:]]
    metric = [
        (
            name + (f" ({', '.join(b['sensors'])})" if b["name"].startswith("best single") else ""),
            _f(b.get(f"train_rms_{unit}")),
            _f(b.get(f"cv_rms_{unit}")),
            _f(b.get(f"test_rms_{unit}")),
        )
        for name, b in figures
    ]
    metric.append(
        (
            "volucal model (" + ", ".join(summary["sensors"]) + ")",
            _f(summary.get(f"train_rms_{unit}")),
            _f(summary.get(f"cv_rms_{unit}")),
            _f(summary.get(f"test_rms_{unit}")),
        )
    )
    blocks.append(
        Table(
            (
                "model",
                f"training RMS ({sym})",
                f"cross-validated RMS ({sym})",
                f"held-out RMS ({sym})",
            ),
            tuple(metric),
            "lrrr",
            "Error left after compensation, RMS.",
        )
    )
    blocks.append(
        Paragraph("How the model was chosen: " + "; ".join(summary["decisions"]) + ".", "note")
    )
    split_s = float(summary["split_time_s"]) if test else None
    blocks.append(
        thermal_plot(
            f"{channel}: measured and predicted", unit, time_s, measured, predicted, split_s
        )
    )
    flags = summary.get("outliers", [])
    if flags:
        blocks.append(
            Paragraph(
                f"{len(flags)} sample(s) leave the smooth trend of the record (flagged by the "
                "outlier screen, kept in the fit): "
                + "; ".join(f"sample {f['sample']}" for f in flags)
                + ".",
                "note",
            )
        )
    blocks.append(
        Paragraph(
            f"Sign and units: {channel} is measured − nominal in {sym}, temperatures in °C; a "
            "compensation applies the opposite of the prediction.",
            "note",
        )
    )
    for warning in summary.get("warnings", []):
        blocks.append(Paragraph(f"Warning: {warning}", "note"))
    return Section(f"Thermal error: {channel} ({summary['measurement']})", tuple(blocks))


def thermal_plot(
    title: str,
    unit: str,
    time_s: Series,
    measured: Series,
    predicted: Series,
    split_s: float | None,
) -> ThermalPlot:
    """The plot block, thinned to at most ``PLOT_POINTS`` points (evenly by sample)."""
    t = np.asarray(time_s, dtype=float)
    keep = np.unique(np.linspace(0, t.size - 1, min(PLOT_POINTS, t.size)).round().astype(int))
    return ThermalPlot(
        title,
        unit,
        tuple(float(v) for v in t[keep] / 3600.0),
        tuple(float(v) for v in np.asarray(measured, dtype=float)[keep]),
        tuple(float(v) for v in np.asarray(predicted, dtype=float)[keep]),
        None if split_s is None else split_s / 3600.0,
    )


def _f(value: Any) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    return f"{float(value):.3f}"
