"""Thermal measurements and their models in the HDF5 project, under ``/thermal/<name>``.

One group per thermal record, a result tree (:func:`volucal.core.project.tree_to_group`):

    /thermal/<name>       attrs kind ("thermal measurement"), format_version (1), name,
                          source_file, source_sha256, time_source, start_time (POSIX s or
                          empty), samples
        time_s            seconds since the first sample (unit attribute "s")
        errors/<k>        name, unit ("um" or "urad"), raw_unit, sign, values (in unit)
        temperature_names the usable sensors, in column order of
        temperatures_c    samples × sensors, °C (unit attribute "degC")
        excluded/<k>      name, reason: the sensors left out (stuck)
        warnings          what the import warned about
        source            the source file's bytes (uint8), exactly as read
        models/<k>        channel, model_json (the ThermalModel), result_json (the fit's summary:
                          sensors, CV, held-out error, baselines, decisions; as ``--json``),
                          predicted (the model over the record, in the channel's unit)

The measurement is kept exactly as imported (values converted to µm/µrad and °C once, the source
bytes beside them), so a model can be refitted or checked later without the original file.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .outliers import SeriesFlag
from .project import Project
from .thermal import (
    ErrorChannel,
    ExcludedSensor,
    TemperatureChannel,
    ThermalMeasurement,
)
from .thermal_fit import Baseline, SubsetScore, ThermalFitOptions, ThermalFitResult
from .thermal_model import ThermalModel
from .userror import UserError

KIND = "thermal"
FORMAT_VERSION = 1


@dataclass(frozen=True, eq=False)
class StoredThermal:
    """A thermal record read back from a project, with its models by channel."""

    measurement: ThermalMeasurement
    models: Mapping[str, ThermalModel]
    results: Mapping[str, dict[str, Any]]


def jsonable(value: Any) -> Any:
    """Plain JSON: NaN and infinities become null, numpy values plain numbers."""
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.floating | float):
        number = float(value)
        return number if np.isfinite(number) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def thermal_tree(
    measurement: ThermalMeasurement, results: Sequence[ThermalFitResult] = ()
) -> dict[str, Any]:
    """The result tree of a thermal record and its fitted models (module notes)."""
    m = measurement
    tree: dict[str, Any] = {
        "kind": "thermal measurement",
        "format_version": FORMAT_VERSION,
        "name": m.name,
        "source_file": m.source.name if m.source else "",
        "source_sha256": hashlib.sha256(m.source_bytes).hexdigest(),
        "time_source": m.time_source,
        "start_time": m.start_time,
        "samples": m.samples,
        "time_s": np.asarray(m.time_s, dtype=float),
        "errors": [
            {
                "name": c.name,
                "unit": c.unit,
                "raw_unit": c.raw_unit,
                "sign": c.sign,
                "values": np.asarray(c.values, dtype=float),
            }
            for c in m.errors
        ],
        "temperature_names": [t.name for t in m.temperatures],
        "temperatures_c": m.temperature_matrix(),
        "excluded": [{"name": e.name, "reason": e.reason} for e in m.excluded],
        "warnings": list(m.warnings),
        "source": np.frombuffer(m.source_bytes, dtype=np.uint8).copy(),
        "models": [
            {
                "channel": r.channel,
                "model_json": json.dumps(jsonable(r.model.to_json())),
                "result_json": json.dumps(jsonable(r.to_json()), ensure_ascii=False),
                "predicted": np.asarray(r.predicted, dtype=float),
            }
            for r in results
        ],
    }
    return tree


def store_thermal(
    project: Project,
    name: str,
    measurement: ThermalMeasurement,
    results: Sequence[ThermalFitResult] = (),
) -> str:
    """Put the record (and its models) in the project, replacing one of the same name; returns
    the group's path. The caller saves the project."""
    try:
        project.put_result(KIND, name, thermal_tree(measurement, results))
    except ValueError as exc:
        raise UserError(f"cannot store thermal record {name!r}: {exc}") from None
    return f"/{KIND}/{name}"


def thermal_names(project: Project) -> list[str]:
    """Names of the thermal records in the project."""
    return project.results(KIND)


def load_thermal(project: Project, name: str) -> StoredThermal:
    """A stored thermal record and its models."""
    try:
        tree = project.result(KIND, name)
    except KeyError:
        raise UserError(
            f"the project has no thermal record {name!r}; it has "
            f"{', '.join(thermal_names(project)) or 'none'}"
        ) from None
    version = int(tree.get("format_version", 0))
    if version > FORMAT_VERSION:
        raise UserError(
            f"thermal record {name!r} was written by a newer volucal (format "
            f"{version}); update volucal"
        )
    temperatures = np.asarray(tree["temperatures_c"], dtype=float)
    names = list(tree["temperature_names"])
    source = str(tree.get("source_file") or "")
    start = tree.get("start_time")
    measurement = ThermalMeasurement(
        name=str(tree["name"]),
        time_s=np.asarray(tree["time_s"], dtype=float),
        errors=tuple(
            ErrorChannel(
                str(e["name"]),
                str(e["unit"]),
                np.asarray(e["values"], dtype=float),
                str(e["raw_unit"]),
                int(e["sign"]),
            )
            for e in tree["errors"]
        ),
        temperatures=tuple(TemperatureChannel(n, temperatures[:, k]) for k, n in enumerate(names)),
        excluded=tuple(
            ExcludedSensor(str(e["name"]), str(e["reason"])) for e in tree.get("excluded", [])
        ),
        warnings=tuple(str(w) for w in tree.get("warnings", [])),
        time_source=str(tree.get("time_source", "")),
        start_time=None if start is None else float(start),
        source=Path(source) if source else None,
        source_bytes=np.asarray(tree["source"], dtype=np.uint8).tobytes(),
    )
    models = {}
    results = {}
    for entry in tree.get("models", []):
        channel = str(entry["channel"])
        models[channel] = ThermalModel.from_json(json.loads(entry["model_json"]))
        results[channel] = json.loads(entry["result_json"])
    return StoredThermal(measurement, models, results)


def load_thermal_result(
    project: Project, name: str, channel: str | None = None
) -> ThermalFitResult:
    """The fit of one channel (None: the first) of a stored record, as :func:`fit_thermal`
    returned it (for the workbench view and the report), without fitting again."""
    stored = load_thermal(project, name)
    if not stored.results:
        raise UserError(f"thermal record {name!r} has no fitted model")
    key = channel if channel is not None else next(iter(stored.results))
    if key not in stored.results:
        raise UserError(
            f"thermal record {name!r} has no model of {key!r}; it has {', '.join(stored.results)}"
        )
    summary = stored.results[key]
    unit = str(summary["unit"])
    tree = project.result(KIND, name)
    predicted = next(
        np.asarray(m["predicted"], dtype=float) for m in tree["models"] if str(m["channel"]) == key
    )
    saved = summary.get("options", {})
    options = ThermalFitOptions(
        train_fraction=float(summary["train_fraction"]),
        max_sensors=int(saved.get("max_sensors", 6)),
        blocks=int(saved.get("blocks", 10)),
        initial_fraction=float(saved.get("initial_fraction", 0.5)),
        dynamic=bool(saved.get("dynamic", True)),
        quadratic=bool(saved.get("quadratic", True)),
        min_improvement=float(saved.get("min_improvement", 0.02)),
    )

    def number(value: Any) -> float | None:
        return None if value is None else float(value)

    return ThermalFitResult(
        measurement=str(summary["measurement"]),
        channel=key,
        unit=unit,
        model=stored.models[key],
        options=options,
        train_samples=int(summary["train_samples"]),
        test_samples=int(summary["test_samples"]),
        split_time_s=float(summary["split_time_s"]),
        cv_description=str(summary["cross_validation"]),
        cv_rms=float(summary[f"cv_rms_{unit}"]),
        train_rms=float(summary[f"train_rms_{unit}"]),
        test_rms=number(summary.get(f"test_rms_{unit}")),
        test_max_abs=number(summary.get(f"test_max_abs_{unit}")),
        uncompensated_test_rms=number(summary.get(f"uncompensated_test_rms_{unit}")),
        static_cv_rms=float(summary[f"static_cv_rms_{unit}"]),
        subsets=tuple(
            SubsetScore(tuple(s["sensors"]), float(s[f"cv_rms_{unit}"])) for s in summary["subsets"]
        ),
        decisions=tuple(summary["decisions"]),
        baselines=tuple(
            Baseline(
                str(b["name"]),
                tuple(b["sensors"]),
                float(b[f"train_rms_{unit}"]),
                number(b[f"cv_rms_{unit}"]),
                number(b[f"test_rms_{unit}"]),
            )
            for b in summary["baselines"]
        ),
        time_s=stored.measurement.time_s,
        measured=stored.measurement.error(key).values,
        predicted=predicted,
        term_spread=tuple(float(w[f"spread_{unit}"]) for w in summary.get("weights", [])),
        outliers=tuple(
            SeriesFlag(
                str(f["channel"]),
                int(f["sample"]),
                float(f["time_s"]),
                float(f["value"]),
                str(f["reason"]),
                float(f["statistic"]),
            )
            for f in summary.get("outliers", [])
        ),
        warnings=tuple(summary.get("warnings", [])),
        elapsed_s=float(summary.get("elapsed_s", 0.0)),
    )
