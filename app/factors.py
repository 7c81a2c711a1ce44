"""The sensitivity view's state: the factor table and what it runs (GUI-free).

Two kinds of problem (paper, section 3; :mod:`volucal.core.sensitivity`):

- ``identified``: the 21 errors of an identification vary by their identification uncertainty.
  Each error is its identified function of position plus a normal deviation; the table shows the
  function's mean over its stroke and the RMS over the stroke of its standard deviation (from the
  covariance, at least the floor). Editing a spread replaces that error's position-dependent
  standard deviation by the value given (``ErrorSpread.spread``).
- ``by_hand``: every error is one random value with the distribution, mean and standard
  deviation of the table; it starts from the paper's Table 2.

For a uniform factor the table's spread is its standard deviation, so the bounds are
mean ± √3·spread; a (symmetric) triangular one has bounds mean ± √6·spread.
"""

from __future__ import annotations

import json
import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from volucal.core.efast import Distribution, Normal, Triangular, Uniform
from volucal.core.errors import ERROR_IDS, ERROR_INFO, ErrorModel
from volucal.core.machine import AXIS_INDEX, PAPER_MACHINE, Machine
from volucal.core.paper import table2_iso
from volucal.core.progress import CancelToken, ProgressCallback
from volucal.core.sensitivity import (
    OUTPUT_NAMES,
    ErrorSpread,
    SensitivityError,
    SensitivityResult,
    analyse,
    analyse_model,
    problem_from_distributions,
    workspace_grid,
)

from .records import json_text

DISTRIBUTIONS = ("normal", "uniform", "triangular")
MODES = ("identified", "by_hand")
#: Grid step of a ranking "averaged over the workspace" (a coarse map: 5 × 5 × 5 points on a
#: 400 mm machine): the indices of the errors where the tool is, weighted by the output variance.
RANKING_GRID_MM = 100.0
#: The floors analyse_model applies by default (µm, µrad).
FLOOR_UM = 0.01
FLOOR_URAD = 0.1
_SAMPLES = 101


@dataclass(frozen=True)
class FactorSetting:
    """One row of the factor table (values in the error's unit: µm or µrad)."""

    id: str
    distribution: str
    mean: float
    spread: float
    unit: str
    overridden: bool = False

    def to_distribution(self) -> Distribution:
        if self.distribution == "normal":
            return Normal(self.mean, self.spread)
        if self.distribution == "uniform":
            half = math.sqrt(3.0) * self.spread
            return Uniform(self.mean - half, self.mean + half)
        if self.distribution == "triangular":
            half = math.sqrt(6.0) * self.spread
            return Triangular(self.mean - half, self.mean, self.mean + half)
        raise SensitivityError(
            f"{self.id}: unknown distribution {self.distribution!r}; use "
            f"{', '.join(DISTRIBUTIONS)}"
        )


@dataclass(frozen=True)
class SensitivitySetup:
    """What the sensitivity view runs: the problem's kind, its factors and EFAST settings.

    ``not_identified``: in identified mode, the errors the identification's plan cannot see;
    what they vary by was not measured, and every ranking marks them.
    """

    mode: str
    factors: tuple[FactorSetting, ...]
    n: int = 1400
    seed: int = 0
    outputs: tuple[str, ...] = OUTPUT_NAMES
    identification: str | None = None
    not_identified: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise SensitivityError(f"unknown sensitivity mode {self.mode!r}")
        for factor in self.factors:
            if not (math.isfinite(factor.spread) and factor.spread > 0):
                raise SensitivityError(
                    f"{factor.id}: the spread must be a positive standard deviation "
                    f"({factor.unit}), got {factor.spread:g}"
                )

    # ---- construction ----------------------------------------------------------------------

    @classmethod
    def identified(cls, model: ErrorModel, covariance: ArrayLike | None, n: int = 1400,
                   seed: int = 0, identification: str | None = None,
                   not_identified: Collection[str] = ()) -> SensitivitySetup:
        """The factor table of an identification: means over the strokes, RMS spreads;
        ``not_identified`` the errors its plan cannot see (its ``unidentifiable_ids``)."""
        spread = ErrorSpread(model, None if covariance is None else np.asarray(covariance, float),
                             FLOOR_UM, FLOOR_URAD)
        machine = model.machine
        means: dict[str, float] = {}
        sds: dict[str, float] = {}
        for axis in AXIS_INDEX:
            low, high = machine.stroke(axis)
            points = np.tile(np.asarray(machine.reference_mm, dtype=float), (_SAMPLES, 1))
            points[:, AXIS_INDEX[axis]] = np.linspace(low, high, _SAMPLES)
            mean, sd = spread.mean_sd(points)
            for column, eid in enumerate(ERROR_IDS):
                if ERROR_INFO[eid].axis in (axis, None) and eid not in means:
                    means[eid] = float(np.mean(mean[:, column]))
                    sds[eid] = float(np.sqrt(np.mean(sd[:, column] ** 2)))
        factors = tuple(
            FactorSetting(eid, "normal", means[eid], sds[eid], ERROR_INFO[eid].unit)
            for eid in ERROR_IDS
        )
        return cls("identified", factors, n, seed, OUTPUT_NAMES, identification,
                   tuple(not_identified))

    @classmethod
    def paper_table2(cls, n: int = 1400, seed: int = 0) -> SensitivitySetup:
        """By hand, starting from the paper's Table 2 (ISO ids, µm and µrad)."""
        table = table2_iso()
        factors = tuple(
            FactorSetting(eid, "normal", table[eid][0], table[eid][1], ERROR_INFO[eid].unit)
            for eid in ERROR_IDS
        )
        return cls("by_hand", factors, n, seed)

    def factor(self, eid: str) -> FactorSetting:
        for item in self.factors:
            if item.id == eid:
                return item
        raise KeyError(eid)

    def with_factor(self, eid: str, **changes: Any) -> SensitivitySetup:
        """A copy with one factor changed; in identified mode a changed spread is an override
        and the distribution and mean stay those of the identification."""
        if self.mode == "identified":
            unknown = set(changes) - {"spread"}
            if unknown:
                raise SensitivityError(
                    f"{eid}: an identified error is its identified function with a normal "
                    f"deviation; only its spread can be set (not {', '.join(sorted(unknown))})"
                )
            changes["overridden"] = True
        factors = tuple(replace(f, **changes) if f.id == eid else f for f in self.factors)
        return replace(self, factors=factors)

    def spread_overrides(self) -> dict[str, float]:
        return {f.id: f.spread for f in self.factors if f.overridden}

    # ---- running -----------------------------------------------------------------------------

    def run(
        self,
        model: ErrorModel | None,
        covariance: ArrayLike | None,
        map_step_mm: float | None = None,
        machine: Machine | None = None,
        progress: ProgressCallback | None = None,
        cancel: CancelToken | None = None,
    ) -> SensitivityResult:
        """EFAST S1 and ST of Ex, Ey, Ez, ET; a workspace map when ``map_step_mm`` is given
        (one analysis per grid point), else with X, Y, Z as design factors."""
        if self.mode == "identified":
            if model is None:
                raise SensitivityError("identify the errors first: the identified problem needs "
                                       "an identification")
            return analyse_model(
                model, covariance, output=self.outputs, map_step_mm=map_step_mm, n=self.n,
                seed=self.seed, spread=self.spread_overrides(), floor_um=FLOOR_UM,
                floor_urad=FLOOR_URAD, not_identified=self.not_identified, progress=progress,
                cancel=cancel,
            )
        target = machine or (model.machine if model is not None else PAPER_MACHINE)
        positions: Any = "design" if map_step_mm is None else workspace_grid(target, map_step_mm)
        problem = problem_from_distributions(
            {f.id: f.to_distribution() for f in self.factors}, positions, target, name="by hand",
        )
        return analyse(problem, self.outputs, n=self.n, seed=self.seed, progress=progress,
                       cancel=cancel)

    # ---- storage -----------------------------------------------------------------------------

    def to_json(self) -> dict[str, Any]:
        return {
            "mode": self.mode,
            "n": self.n,
            "seed": self.seed,
            "outputs": list(self.outputs),
            "identification": self.identification,
            "not_identified": list(self.not_identified),
            "factors": [
                {"id": f.id, "distribution": f.distribution, "mean": f.mean,
                 "spread": f.spread, "unit": f.unit, "overridden": f.overridden}
                for f in self.factors
            ],
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> SensitivitySetup:
        factors = tuple(
            FactorSetting(str(f["id"]), str(f["distribution"]), float(f["mean"]),
                          float(f["spread"]), str(f["unit"]), bool(f.get("overridden", False)))
            for f in data["factors"]
        )
        identification = data.get("identification")
        return cls(str(data["mode"]), factors, int(data["n"]), int(data["seed"]),
                   tuple(data.get("outputs", OUTPUT_NAMES)),
                   None if identification is None else str(identification),
                   tuple(str(v) for v in data.get("not_identified", ())))


def sensitivity_tree(result: SensitivityResult, setup: SensitivitySetup) -> dict[str, Any]:
    """The project tree of a sensitivity run: the core's arrays plus the factor table."""
    tree = result.to_tree()
    tree["setup_json"] = json_text(setup.to_json())
    return tree


@dataclass(frozen=True, eq=False)
class SensitivityRecord:
    """A sensitivity result as the view shows it.

    ``indices[output][kind][id]`` with kind S1, ST, S1_std, ST_std (workspace values for maps).
    ``result`` holds the arrays (None for projects that kept only the report, as
    older ``volucal calibrate`` wrote them); ``setup`` the factor table it was run with.
    """

    name: str
    indices: Mapping[str, Mapping[str, Mapping[str, float | None]]]
    result: SensitivityResult | None = None
    setup: SensitivitySetup | None = None

    @classmethod
    def from_result(cls, name: str, result: SensitivityResult,
                    setup: SensitivitySetup | None) -> SensitivityRecord:
        return cls(name, result.to_report(), result, setup)

    @classmethod
    def from_tree(cls, name: str, tree: Mapping[str, Any]) -> SensitivityRecord:
        report = json.loads(str(tree["report_json"]))
        result = SensitivityResult.from_tree(tree) if "S1" in tree else None
        setup = SensitivitySetup.from_json(json.loads(str(tree["setup_json"]))) if \
            "setup_json" in tree else None
        return cls(name, report, result, setup)

    @property
    def outputs(self) -> tuple[str, ...]:
        return tuple(self.indices)

    @property
    def is_map(self) -> bool:
        return self.result is not None and self.result.positions_mm is not None and \
            len(self.result.positions_mm) > 1

    @property
    def not_identified(self) -> frozenset[str]:
        """The errors the analysed identification does not (fully) identify, as stored with the
        result: what they varied by was in part not measured, and every ranking marks them."""
        ids: set[str] = set()
        for entry in self.indices.values():
            ids.update(entry.get("not_identified", ()))  # type: ignore[arg-type]
        return frozenset(ids)

    def ranked(self, output: str, kind: str = "S1") -> list[tuple[str, float, float]]:
        """(id, S1, ST) sorted by ``kind`` (largest first); missing values count as 0."""
        entry = self.indices[output]
        rows = []
        for eid in ERROR_IDS:
            if eid not in entry["S1"]:
                continue
            s1 = entry["S1"].get(eid)
            st = entry["ST"].get(eid)
            rows.append((eid, 0.0 if s1 is None else float(s1), 0.0 if st is None else float(st)))
        column = 1 if kind == "S1" else 2
        return sorted(rows, key=lambda row: -row[column])
