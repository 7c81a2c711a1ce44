"""What the views show, built from live core results or from a project file (GUI-free).

A view must look the same whether a result was just computed or loaded from an HDF5 project. The
records here are that common form, and their trees are what the workbench stores in the
project's result groups (DESIGN.md "HDF5 project"):

- ``/identifications/<name>``: the keys of :func:`volucal.core.calibrate.identification_tree`
  (``model``, ``covariance``, ``sigma_scale``, ``identifiability_json``, ``parameters_json``), so
  that ``volucal export`` reads it, plus ``readings`` (every reading's context and residual, for
  the residual and evidence plots), ``effects_json`` (the effects fitted with the 21 errors, with
  the constructor fields needed to refit them) and ``options_json`` (how it was identified).
- ``/loops/<name>``: ``report_json`` (the loop blocks of report.json, as ``volucal calibrate``
  writes them) plus ``candidates_json`` (every effect the loop tried, kept or rejected) and the
  names of the identifications before and after the loop.

Projects written by ``volucal calibrate`` lack the extras; the records then say so
(``readings is None``, no candidates) and the views offer to recompute.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from volucal.core import effects as effects_module
from volucal.core.calibrate import identification_tree
from volucal.core.effects import Effect
from volucal.core.errors import ErrorModel
from volucal.core.identify import Identification, IdentifyOptions, parameters_report, residual_rms
from volucal.core.machine import Machine
from volucal.core.measurement import Measurement
from volucal.core.project import Project, error_model_from_tree
from volucal.core.residuals import LoopResult, line_group
from volucal.core.userror import UserError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Points per error curve in the stored parameters (a smooth curve on a 400 mm stroke).
CURVE_POINTS = 101

_EFFECT_CLASSES: dict[str, type[Effect]] = {
    cls.__name__: cls
    for cls in (
        effects_module.Reversal,
        effects_module.Cyclic,
        effects_module.ThermalDrift,
        effects_module.CrossAxis,
        effects_module.LocalDefect,
        effects_module.HigherOrder,
        effects_module.AbbeOffset,
        effects_module.Cosine,
    )
}


def json_safe(value: Any) -> Any:
    """Plain JSON values: NaN and infinities become None, numpy values plain numbers."""
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        number = float(value)
        return number if math.isfinite(number) else None
    return value


def json_text(value: Any) -> str:
    return json.dumps(json_safe(value), allow_nan=False)


# --------------------------------------------------------------------------------------------
# Effects, stored so that they can be refitted
# --------------------------------------------------------------------------------------------


def effect_to_json(effect: Effect) -> dict[str, Any]:
    """The effect's class and constructor fields (the machine is the project's, not stored)."""
    values: dict[str, Any] = {}
    for item in dataclasses.fields(effect):
        if not item.init:
            continue
        value = getattr(effect, item.name)
        if isinstance(value, Machine) or value is None and item.name == "machine":
            continue
        values[item.name] = json_safe(value)
    return {"class": type(effect).__name__, "fields": values, "label": effect.label,
            "kind": effect.kind, "axis": effect.axis}


def effect_from_json(entry: Mapping[str, Any], measurement: Measurement) -> Effect:
    """Rebuild an effect for ``measurement`` (line indexes are looked up again by name)."""
    name = str(entry.get("class", ""))
    if name not in _EFFECT_CLASSES:
        raise UserError(f"unknown effect type {name!r} in the project")
    cls = _EFFECT_CLASSES[name]
    values = dict(entry.get("fields", {}))
    kwargs: dict[str, Any] = {}
    for item in dataclasses.fields(cls):
        if not item.init:
            continue
        if item.name == "machine":
            kwargs["machine"] = measurement.machine
        elif item.name in values:
            value = values[item.name]
            kwargs[item.name] = tuple(value) if isinstance(value, list) else value
    if "line_name" in kwargs:
        names = [line.name for line in measurement.lines]
        if kwargs["line_name"] not in names:
            raise UserError(f"effect {entry.get('label')!r} refers to line "
                            f"{kwargs['line_name']!r}, which the project no longer has")
        kwargs["line"] = names.index(kwargs["line_name"])
    return cls(**kwargs)


# --------------------------------------------------------------------------------------------
# Readings with their residual
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ReadingTable:
    """Every reading of an identification with its residual (measured − model).

    ``line`` indexes ``line_names``; ``quantity`` is 0 linear, 1 straightness, 2 angular;
    ``residual`` and ``value`` are in µm (µrad for angular readings). Per line: ``direction``
    (L, 3) its travel direction, ``projection`` (L, 3) what it reads (the beam direction of a
    linear line, the deviation direction of a straightness line, the rotation axis of an angular
    one) and ``group`` its residual group (X, Y, Z, diagonal, angular).
    """

    line_names: tuple[str, ...]
    group: tuple[str, ...]
    direction: FloatArray
    projection: FloatArray
    line: IntArray
    run: IntArray
    target: IntArray
    position_mm: FloatArray
    target_mm: FloatArray
    approach: FloatArray
    time_s: FloatArray
    material_temp_c: FloatArray
    value: FloatArray
    residual: FloatArray
    quantity: IntArray

    _ARRAYS = ("line", "run", "target", "position_mm", "target_mm", "approach", "time_s",
               "material_temp_c", "value", "residual", "quantity")

    @classmethod
    def from_identification(cls, identification: Identification) -> ReadingTable:
        r = identification.readings
        return cls(
            line_names=tuple(r.line_names),
            group=tuple(line_group(r, i) for i in range(len(r.lines))),
            direction=np.array([line.spec.direction for line in r.lines], dtype=float),
            projection=np.array([line.spec.direction if line.spec.quantity == "linear" else
                                 line.spec.sensitive for line in r.lines], dtype=float),
            line=np.asarray(r.line, dtype=np.int64),
            run=np.asarray(r.run, dtype=np.int64),
            target=np.asarray(r.target, dtype=np.int64),
            position_mm=np.asarray(r.position_mm, dtype=float),
            target_mm=np.asarray(r.target_mm, dtype=float),
            approach=np.asarray(r.approach, dtype=float),
            time_s=np.asarray(r.time_s, dtype=float),
            material_temp_c=np.asarray(r.material_temp_c, dtype=float),
            value=np.asarray(r.value, dtype=float),
            residual=np.asarray(identification.residual, dtype=float),
            quantity=np.asarray(r.quantity, dtype=np.int64),
        )

    def to_tree(self) -> dict[str, Any]:
        tree: dict[str, Any] = {name: getattr(self, name) for name in self._ARRAYS}
        tree["line_names"] = list(self.line_names)
        tree["line_group"] = list(self.group)
        tree["line_direction"] = self.direction
        tree["line_projection"] = self.projection
        return tree

    @classmethod
    def from_tree(cls, tree: Mapping[str, Any]) -> ReadingTable:
        arrays = {name: np.asarray(tree[name]) for name in cls._ARRAYS}
        for name in ("line", "run", "target", "quantity"):
            arrays[name] = arrays[name].astype(np.int64)
        return cls(
            line_names=tuple(str(v) for v in tree["line_names"]),
            group=tuple(str(v) for v in tree["line_group"]),
            direction=np.asarray(tree["line_direction"], dtype=float).reshape(-1, 3),
            projection=np.asarray(tree["line_projection"], dtype=float).reshape(-1, 3),
            **arrays,
        )

    def __len__(self) -> int:
        return int(self.residual.size)

    @property
    def is_angular(self) -> NDArray[np.bool_]:
        return self.quantity == 2

    def line_mask(self, index: int) -> NDArray[np.bool_]:
        return self.line == index

    def group_rms(self) -> dict[str, float]:
        """RMS residual per group of lines (µm; µrad for the angular group)."""
        out: dict[str, float] = {}
        groups = np.asarray(self.group)[self.line] if len(self) else np.empty(0, dtype=str)
        for name in sorted(set(self.group)):
            values = self.residual[groups == name]
            if values.size:
                out[name] = float(np.sqrt(np.mean(values**2)))
        return out

    def line_summary(self) -> list[dict[str, Any]]:
        """Per line: name, group, readings, RMS and max |residual|."""
        out = []
        for index, name in enumerate(self.line_names):
            values = self.residual[self.line == index]
            out.append({
                "line": name,
                "group": self.group[index],
                "unit": "urad" if self.group[index] == "angular" else "um",
                "readings": int(values.size),
                "rms": float(np.sqrt(np.mean(values**2))) if values.size else math.nan,
                "max_abs": float(np.max(np.abs(values))) if values.size else math.nan,
            })
        return out


# --------------------------------------------------------------------------------------------
# Identifications
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class IdentificationRecord:
    """An identification as the views show it (live or loaded)."""

    name: str
    parameters: Mapping[str, Mapping[str, Any]]
    identifiability: Mapping[str, Any]
    sigma_scale: float
    readings: ReadingTable | None = None
    effects: tuple[Mapping[str, Any], ...] = ()
    options: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_identification(
        cls, name: str, identification: Identification, options: IdentifyOptions | None = None
    ) -> IdentificationRecord:
        return cls(
            name=name,
            parameters=json_safe(parameters_report(identification, CURVE_POINTS)),
            identifiability=json_safe(identification.identifiability.to_json()),
            sigma_scale=float(identification.sigma_scale),
            readings=ReadingTable.from_identification(identification),
            effects=tuple(_effect_entries(identification)),
            options=_options_json(options),
        )

    @classmethod
    def from_tree(cls, name: str, tree: Mapping[str, Any]) -> IdentificationRecord:
        readings = tree.get("readings")
        return cls(
            name=name,
            parameters=json.loads(str(tree["parameters_json"])),
            identifiability=json.loads(str(tree["identifiability_json"])),
            sigma_scale=float(tree.get("sigma_scale", math.nan)),
            readings=ReadingTable.from_tree(readings) if isinstance(readings, Mapping) else None,
            effects=tuple(json.loads(str(tree.get("effects_json", "[]")))),
            options=json.loads(str(tree.get("options_json", "{}"))),
        )

    def residual_rms(self) -> tuple[float, float]:
        """(µm over displacement readings, µrad over angular readings); NaN when unknown."""
        if self.readings is None:
            return math.nan, math.nan
        r = self.readings
        um = r.residual[~r.is_angular]
        urad = r.residual[r.is_angular]
        return (float(np.sqrt(np.mean(um**2))) if um.size else math.nan,
                float(np.sqrt(np.mean(urad**2))) if urad.size else math.nan)

    def identified(self, eid: str) -> bool:
        return bool(self.parameters[eid].get("identified", True))


def identification_result_tree(
    identification: Identification, options: IdentifyOptions | None = None
) -> dict[str, Any]:
    """The project tree of an identification (module notes)."""
    tree = identification_tree(identification)
    tree["parameters_json"] = json_text(parameters_report(identification, CURVE_POINTS))
    tree["readings"] = ReadingTable.from_identification(identification).to_tree()
    tree["effects_json"] = json_text(_effect_entries(identification))
    tree["options_json"] = json_text(_options_json(options))
    rms_um, rms_urad = residual_rms(identification)
    tree["residual_rms_um"] = rms_um
    tree["residual_rms_urad"] = rms_urad
    return tree


def _effect_entries(identification: Identification) -> list[dict[str, Any]]:
    out = []
    for effect, values, cov in zip(identification.effects, identification.effect_parameters,
                                   identification.effect_covariances, strict=True):
        if not isinstance(effect, Effect):
            continue
        entry = effect_to_json(effect)
        entry["parameters"] = json_safe(effect.parameters(values, cov))
        out.append(entry)
    return out


def _options_json(options: IdentifyOptions | None) -> dict[str, Any]:
    options = options or IdentifyOptions()
    return {"spacing_mm": options.spacing_mm, "refine": options.refine,
            "max_iterations": options.max_iterations}


def identify_options(stored: Mapping[str, Any], budget: Any = None) -> IdentifyOptions:
    """IdentifyOptions from a record's ``options`` (defaults for what is missing)."""
    defaults = IdentifyOptions()
    kwargs: dict[str, Any] = {
        "spacing_mm": float(stored.get("spacing_mm", defaults.spacing_mm)),
        "refine": bool(stored.get("refine", defaults.refine)),
        "max_iterations": int(stored.get("max_iterations", defaults.max_iterations)),
    }
    if budget is not None:
        kwargs["budget"] = budget
    return IdentifyOptions(**kwargs)


def stored_model(project: Project, name: str) -> ErrorModel:
    """The error model of identification ``name``, exactly as ``volucal export`` reads it."""
    if project.machine is None:
        raise UserError("the project has no machine yet: import a plan first")
    tree = project.result("identifications", name)
    model_tree = tree.get("model", tree)
    return error_model_from_tree(model_tree, project.machine)


def default_identification(names: Sequence[str]) -> str | None:
    """The identification ``volucal export`` uses: the closed loop's ("loop") or the latest."""
    if not names:
        return None
    return "loop" if "loop" in names else names[-1]


# --------------------------------------------------------------------------------------------
# Loops
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class LoopRecord:
    """A closed loop as the loop view shows it.

    ``candidates``: every effect the loop tried — ``{"effect": effect_to_json(...), "label",
    "kind", "axis", "kept", "step"}`` — empty for projects written by ``volucal calibrate``.
    ``decisions``: the user's accept/reject edits (labels) when the loop was refitted by hand.
    """

    name: str
    report: Mapping[str, Any]
    base: str = "main"
    final: str = "loop"
    candidates: tuple[Mapping[str, Any], ...] = ()
    decisions: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_loop(cls, name: str, loop: LoopResult, base: str = "main", final: str = "loop"
                  ) -> LoopRecord:
        return cls(name, json_safe(loop.to_report()), base, final, tuple(loop_candidates(loop)))

    @classmethod
    def from_tree(cls, name: str, tree: Mapping[str, Any]) -> LoopRecord:
        return cls(
            name=name,
            report=json.loads(str(tree["report_json"])),
            base=str(tree.get("base_identification", "main")),
            final=str(tree.get("final_identification", "loop")),
            candidates=tuple(json.loads(str(tree.get("candidates_json", "[]")))),
            decisions=json.loads(str(tree.get("decisions_json", "{}"))),
        )

    def to_tree(self) -> dict[str, Any]:
        return {
            "report_json": json_text(self.report),
            "base_identification": self.base,
            "final_identification": self.final,
            "candidates_json": json_text(list(self.candidates)),
            "decisions_json": json_text(dict(self.decisions)),
        }


def loop_candidates(loop: LoopResult) -> list[dict[str, Any]]:
    """The kept effects (in the final model) and the rejected ones, one entry per label."""
    out: dict[str, dict[str, Any]] = {}
    step_of = {s.finding.effect.label: s.step for s in loop.steps}
    for effect in loop.final.effects:
        if isinstance(effect, Effect):
            out[effect.label] = {"effect": effect_to_json(effect), "label": effect.label,
                                 "kind": effect.kind, "axis": effect.axis, "kept": True,
                                 "step": step_of.get(effect.label)}
    for s in loop.steps:
        effect = s.finding.effect
        if effect.label not in out:
            out[effect.label] = {"effect": effect_to_json(effect), "label": effect.label,
                                 "kind": effect.kind, "axis": effect.axis, "kept": False,
                                 "step": s.step}
    return list(out.values())
