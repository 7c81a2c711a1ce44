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

from .project import Project
from .thermal import (
    ErrorChannel,
    ExcludedSensor,
    TemperatureChannel,
    ThermalMeasurement,
)
from .thermal_fit import ThermalFitResult
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


def thermal_tree(measurement: ThermalMeasurement,
                 results: Sequence[ThermalFitResult] = ()) -> dict[str, Any]:
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
        "errors": [{"name": c.name, "unit": c.unit, "raw_unit": c.raw_unit, "sign": c.sign,
                    "values": np.asarray(c.values, dtype=float)} for c in m.errors],
        "temperature_names": [t.name for t in m.temperatures],
        "temperatures_c": m.temperature_matrix(),
        "excluded": [{"name": e.name, "reason": e.reason} for e in m.excluded],
        "warnings": list(m.warnings),
        "source": np.frombuffer(m.source_bytes, dtype=np.uint8).copy(),
        "models": [
            {"channel": r.channel,
             "model_json": json.dumps(jsonable(r.model.to_json())),
             "result_json": json.dumps(jsonable(r.to_json()), ensure_ascii=False),
             "predicted": np.asarray(r.predicted, dtype=float)}
            for r in results
        ],
    }
    return tree


def store_thermal(project: Project, name: str, measurement: ThermalMeasurement,
                  results: Sequence[ThermalFitResult] = ()) -> str:
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
        raise UserError(f"the project has no thermal record {name!r}; it has "
                        f"{', '.join(thermal_names(project)) or 'none'}") from None
    version = int(tree.get("format_version", 0))
    if version > FORMAT_VERSION:
        raise UserError(f"thermal record {name!r} was written by a newer volucal (format "
                        f"{version}); update volucal")
    temperatures = np.asarray(tree["temperatures_c"], dtype=float)
    names = list(tree["temperature_names"])
    source = str(tree.get("source_file") or "")
    start = tree.get("start_time")
    measurement = ThermalMeasurement(
        name=str(tree["name"]),
        time_s=np.asarray(tree["time_s"], dtype=float),
        errors=tuple(ErrorChannel(str(e["name"]), str(e["unit"]),
                                  np.asarray(e["values"], dtype=float), str(e["raw_unit"]),
                                  int(e["sign"])) for e in tree["errors"]),
        temperatures=tuple(TemperatureChannel(n, temperatures[:, k])
                           for k, n in enumerate(names)),
        excluded=tuple(ExcludedSensor(str(e["name"]), str(e["reason"]))
                       for e in tree.get("excluded", [])),
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
