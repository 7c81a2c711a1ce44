"""What the views show, built from live core results or from a project file (GUI-free).

A view must look the same whether a result was just computed or loaded from an HDF5 project. The
records here are that common form; the trees the project stores for them are
:mod:`volucal.core.result_trees`' (written alike by ``volucal calibrate`` and the workbench).
Projects written before the trees carried the residuals lack them; the records then say so
(``readings is None``, no candidates) and the views offer to recompute.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from volucal.core.errors import ErrorModel
from volucal.core.identify import Identification, IdentifyOptions, parameters_report
from volucal.core.project import Project, error_model_from_tree
from volucal.core.residuals import LoopResult
from volucal.core.result_trees import (
    CURVE_POINTS,
    ReadingTable,
    effect_entries,
    effect_from_json,
    effect_to_json,
    identification_result_tree,
    json_safe,
    json_text,
    loop_candidates,
    loop_identifiability,
    loop_tree,
    options_json,
)
from volucal.core.squareness_map import identification_squareness
from volucal.core.userror import UserError

__all__ = [
    "CURVE_POINTS", "IdentificationRecord", "Live", "LoopRecord", "ReadingTable",
    "default_identification", "effect_from_json", "effect_to_json",
    "identification_result_tree", "identify_options", "json_safe", "json_text",
    "loop_candidates", "loop_identifiability", "loop_tree", "stored_model",
]


@dataclass(frozen=True, eq=False)
class Live:
    """A result computed in this session: the core object and the record the views read."""

    value: Any
    record: Any


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
    #: report.json's ``squareness_over_volume`` of this identification (empty in projects
    #: written before the project kept it)
    squareness_map: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_identification(
        cls, name: str, identification: Identification, options: IdentifyOptions | None = None,
        identifiability: Mapping[str, Any] | None = None,
        squareness_map: Mapping[str, Any] | None = None,
    ) -> IdentificationRecord:
        """``identifiability`` replaces the identification's own report (the loop's final fit
        carries the plan's: :func:`loop_identifiability`); ``squareness_map``, when the tree's
        is at hand, saves computing it again."""
        own = identification.identifiability.to_json() if identifiability is None else \
            identifiability
        if squareness_map is None:
            squareness_map = identification_squareness(identification)
        return cls(
            name=name,
            parameters=json_safe(parameters_report(identification, CURVE_POINTS)),
            identifiability=json_safe(own),
            sigma_scale=float(identification.sigma_scale),
            readings=ReadingTable.from_identification(identification),
            effects=tuple(effect_entries(identification)),
            options=options_json(options),
            squareness_map=json_safe(squareness_map),
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
            squareness_map=json.loads(str(tree.get("squareness_map_json", "{}"))),
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
    """The 21 errors of identification ``name`` (without the loop's effects)."""
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
    "kind", "axis", "kept", "step"}`` — empty for projects written by an older volucal.
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
        return cls.from_tree(name, loop_tree(loop, base, final))

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
