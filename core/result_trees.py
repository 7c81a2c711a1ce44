"""What a project keeps of an identification and a closed loop, for every reader of the file
(GUI-free).

``volucal calibrate`` and the workbench store the same trees, so that a project written by either
shows the same in the workbench's views (residuals per line, the loop's evidence before and
after, the RMS per group of lines) and in ``volucal export`` and ``volucal report``:

- ``/identifications/<name>``: the keys of :func:`volucal.core.calibrate.identification_tree`
  (``model``, ``covariance``, ``sigma_scale``, ``identifiability_json``, ``parameters_json``)
  plus ``readings`` (every reading's context and residual, :class:`ReadingTable`),
  ``effects_json`` (the effects fitted with the 21 errors, with the constructor fields needed to
  refit them and their fitted ``values``, from which :func:`stored_source` rebuilds them),
  ``options_json`` (how it was identified), ``squareness_map_json`` (report.json's
  ``squareness_over_volume`` of this identification) and the residual RMS.
- ``/loops/<name>``: ``report_json`` (the loop blocks of report.json), ``candidates_json``
  (every effect the loop tried, kept or rejected), ``decisions_json`` (a user's accept/reject
  refit) and the names of the identifications before and after the loop.
- ``/sensitivity/<name>``: the arrays of :meth:`SensitivityResult.to_tree` (with its
  ``report_json``).

The loop's refits skip the per-line redundancy test (it is a property of the plan, computed once
on the 21-error fit): the final identification's ``identifiability_json`` carries the base fit's
redundant lines, marked with ``redundancy_from``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import effects as effects_module
from .effects import Effect
from .identify import Identification, IdentifyOptions, parameters_report, residual_rms
from .loop_source import LoopSource, range_of
from .machine import Machine
from .measurement import Measurement
from .residuals import LoopResult, line_group
from .squareness_map import identification_squareness
from .userror import UserError

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
    return {
        "class": type(effect).__name__,
        "fields": values,
        "label": effect.label,
        "kind": effect.kind,
        "axis": effect.axis,
    }


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
            raise UserError(
                f"effect {entry.get('label')!r} refers to line "
                f"{kwargs['line_name']!r}, which the project no longer has"
            )
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

    _ARRAYS = (
        "line",
        "run",
        "target",
        "position_mm",
        "target_mm",
        "approach",
        "time_s",
        "material_temp_c",
        "value",
        "residual",
        "quantity",
    )

    @classmethod
    def from_identification(cls, identification: Identification) -> ReadingTable:
        r = identification.readings
        return cls(
            line_names=tuple(r.line_names),
            group=tuple(line_group(r, i) for i in range(len(r.lines))),
            direction=np.array([line.spec.direction for line in r.lines], dtype=float),
            projection=np.array(
                [
                    line.spec.direction if line.spec.quantity == "linear" else line.spec.sensitive
                    for line in r.lines
                ],
                dtype=float,
            ),
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
            out.append(
                {
                    "line": name,
                    "group": self.group[index],
                    "unit": "urad" if self.group[index] == "angular" else "um",
                    "readings": int(values.size),
                    "rms": float(np.sqrt(np.mean(values**2))) if values.size else math.nan,
                    "max_abs": float(np.max(np.abs(values))) if values.size else math.nan,
                }
            )
        return out


def identification_result_tree(
    identification: Identification,
    options: IdentifyOptions | None = None,
    identifiability: Mapping[str, Any] | None = None,
    squareness_map: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The project tree of an identification (module notes); ``identifiability`` replaces the
    identification's own report (the loop's final fit carries the plan's, see
    :func:`loop_identifiability`); ``squareness_map``, its squareness map when the caller has
    it (:func:`~volucal.core.squareness_map.identification_squareness`)."""
    from .calibrate import identification_tree

    tree = identification_tree(identification)
    if identifiability is not None:
        tree["identifiability_json"] = json_text(identifiability)
    tree["parameters_json"] = json_text(parameters_report(identification, CURVE_POINTS))
    tree["readings"] = ReadingTable.from_identification(identification).to_tree()
    tree["effects_json"] = json_text(effect_entries(identification))
    tree["options_json"] = json_text(options_json(options))
    if squareness_map is None:
        squareness_map = identification_squareness(identification)
    tree["squareness_map_json"] = json_text(squareness_map)
    rms_um, rms_urad = residual_rms(identification)
    tree["residual_rms_um"] = rms_um
    tree["residual_rms_urad"] = rms_urad
    return tree


def unidentified_ids(tree: Mapping[str, Any]) -> list[str]:
    """The errors a stored identification's plan does not fully identify (its
    ``identifiability_json``; none for a tree without one)."""
    identifiability = json.loads(str(tree.get("identifiability_json", "{}")))
    return list(identifiability.get("unidentifiable_ids", ()))


def effect_entries(identification: Identification) -> list[dict[str, Any]]:
    out = []
    for effect, values, cov in zip(
        identification.effects,
        identification.effect_parameters,
        identification.effect_covariances,
        strict=True,
    ):
        if not isinstance(effect, Effect):
            continue
        entry = effect_to_json(effect)
        entry["parameters"] = json_safe(effect.parameters(values, cov))
        # its fitted values as they are, so that an export rebuilds it (stored_source)
        entry["values"] = json_safe(values)
        out.append(entry)
    return out


#: The kinds of effect a compensation carries (LoopSource): reversal, cycles, surfaces and bumps
#: act on the machine, and a finer function is folded into the 21 errors. A drift is reported,
#: not compensated, and a set-up effect describes the measurement.
COMPENSATED_KINDS = ("reversal", "cyclic", "cross_axis", "local", "higher_order")


def stored_source(project: Any, name: str) -> LoopSource:
    """Identification ``name`` of ``project`` as the compensation source ``volucal calibrate
    --export`` used: its 21 errors with the kept machine effects (each rebuilt from its stored
    fields and fitted values) over the range its readings covered. A project saved before the
    effects' values were stored cannot rebuild the effects it kept: refused, with what to do."""
    from .project import error_model_from_tree

    tree = project.result("identifications", name)
    model = error_model_from_tree(tree.get("model", tree), project.machine)
    # a drift is reported, a set-up effect describes the measurement: neither is compensated
    entries = [
        e for e in json.loads(str(tree.get("effects_json", "[]"))) if e["kind"] in COMPENSATED_KINDS
    ]
    lost = [e["label"] for e in entries if "values" not in e]
    if lost:
        raise UserError(
            f"identification {name!r} of this project kept {', '.join(lost)}, but was saved "
            "before volucal stored the values of the loop's effects, so no export can carry "
            "them: run the loop again (`volucal calibrate` on the plan, or the workbench's "
            "loop) to store them, or export the 21 errors without them (`volucal export "
            "--identification main`, or the workbench's \"21 errors alone\")"
        )
    measurement = project.measurement() if entries else None
    effects = [
        (effect_from_json(e, measurement), np.asarray(e["values"], dtype=float)) for e in entries
    ]
    readings = tree.get("readings")
    measured = None
    if isinstance(readings, Mapping) and "position_mm" in readings:
        measured = range_of(readings["position_mm"])
    return LoopSource.stored(model, effects, measured)


def options_json(options: IdentifyOptions | None) -> dict[str, Any]:
    options = options or IdentifyOptions()
    return {
        "spacing_mm": options.spacing_mm,
        "refine": options.refine,
        "max_iterations": options.max_iterations,
    }


def loop_candidates(loop: LoopResult) -> list[dict[str, Any]]:
    """The kept effects (in the final model) and the rejected ones, one entry per label."""
    out: dict[str, dict[str, Any]] = {}
    step_of = {s.finding.effect.label: s.step for s in loop.steps}
    for effect in loop.final.effects:
        if isinstance(effect, Effect):
            out[effect.label] = {
                "effect": effect_to_json(effect),
                "label": effect.label,
                "kind": effect.kind,
                "axis": effect.axis,
                "kept": True,
                "step": step_of.get(effect.label),
            }
    for s in loop.steps:
        effect = s.finding.effect
        if effect.label not in out:
            out[effect.label] = {
                "effect": effect_to_json(effect),
                "label": effect.label,
                "kind": effect.kind,
                "axis": effect.axis,
                "kept": False,
                "step": s.step,
            }
    return list(out.values())


def loop_identifiability(loop: LoopResult) -> dict[str, Any]:
    """The final fit's identifiability with the plan's redundant lines (module notes): the
    loop's refits skip the per-line test, whose answer depends on the plan, not the effects."""
    own = json_safe(loop.final.identifiability.to_json())
    own["redundant_lines"] = list(loop.base.identifiability.redundant_lines)
    own["redundancy_from"] = "the 21-error fit before the loop"
    return dict(own)


def loop_tree(loop: LoopResult, base: str = "main", final: str = "loop") -> dict[str, Any]:
    """The ``/loops/<name>`` tree of a loop run (module notes)."""
    return {
        "report_json": json_text(loop.to_report()),
        "base_identification": base,
        "final_identification": final,
        "candidates_json": json_text(loop_candidates(loop)),
        "decisions_json": json_text({}),
    }


def loop_result_trees(
    loop: LoopResult,
    options: IdentifyOptions | None = None,
    squareness: Mapping[str, Mapping[str, Any]] | None = None,
) -> dict[tuple[str, str], dict[str, Any]]:
    """Every tree a closed loop stores: the identifications before ("main") and after ("loop")
    with their residuals, and the loop ("main") with every effect it tried. ``options`` are the
    identification's; the loop's own states the basis spacing the loop chose. ``squareness``
    holds the squareness maps the caller has, by identification name."""
    maps = squareness or {}
    return {
        ("identifications", "main"): identification_result_tree(
            loop.base, options, squareness_map=maps.get("main")
        ),
        ("identifications", "loop"): identification_result_tree(
            loop.final,
            loop.identify_options(options or IdentifyOptions()),
            loop_identifiability(loop),
            maps.get("loop"),
        ),
        ("loops", "main"): loop_tree(loop),
    }


def sensitivity_result_tree(result: Any) -> dict[str, Any]:
    """The ``/sensitivity/<name>`` tree of a :class:`~volucal.core.sensitivity.SensitivityResult`:
    its arrays, so that the workbench draws the ranking and its spread as computed."""
    return dict(result.to_tree())


def store_calibration(
    project: Any,
    loop: LoopResult,
    options: IdentifyOptions | None = None,
    sensitivity: Any = None,
    squareness: Mapping[str, Mapping[str, Any]] | None = None,
) -> None:
    """Put the loop's trees (and the sensitivity arrays, when given) into ``project``;
    ``squareness`` as :func:`loop_result_trees` takes it."""
    for (kind, name), tree in loop_result_trees(loop, options, squareness).items():
        project.put_result(kind, name, tree)
    if sensitivity is not None:
        project.put_result("sensitivity", "main", sensitivity_result_tree(sensitivity))
