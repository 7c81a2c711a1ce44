"""What the closed loop's forward steps carry from one to the next, and the steps where it
may run on two ways."""

from __future__ import annotations

from dataclasses import dataclass, field

from .effects import Effect
from .identify import CrossValidation, Identification
from .loop_compare import Trial
from .loop_records import EffectKey, Finding, FloatArray, Step


@dataclass
class State:
    """What the loop's forward steps carry from one to the next."""

    current: Identification
    cv: CrossValidation
    kept: list[Effect] = field(default_factory=list)
    steps: list[Step] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    #: F statistic at which a candidate was last refused; infinite for one the audit took out,
    #: which waits until another effect is kept
    refused: dict[EffectKey, float] = field(default_factory=dict)
    #: for a candidate last refused for what an effect still missing spoils, or taken out by
    #: the audit (:func:`owed_refit`), the effects kept when it was
    refused_beside: dict[EffectKey, frozenset[EffectKey]] = field(default_factory=dict)
    #: kept surfaces a rival predicts as well
    ambiguous: dict[EffectKey, list[str]] = field(default_factory=dict)
    #: per kept surface or set-up effect: how the 21 errors' parameters move to each rival that
    #: fits as well, one per row (zero rows where none moves them beyond their uncertainty)
    shape_doubt: dict[EffectKey, FloatArray] = field(default_factory=dict)
    #: per kept surface: how its own coefficients move to the rival of its place whose move of
    #: the 21 errors :func:`unsettled` takes (absent where it has none)
    surface_doubt: dict[EffectKey, FloatArray] = field(default_factory=dict)
    #: per kept effect that has any: its rivals of another place that fit as well (report.json
    #: ``effects[].rivals``: the kept fit's score and :func:`rival_report` of each)
    rivals: dict[EffectKey, dict[str, object]] = field(default_factory=dict)
    #: per kept effect: the findings of its step's candidates that predicted the held-out data
    #: as well (its rivals and other orders), asked again in the final model
    #: (:func:`surface_doubts_at_the_end`)
    tied: dict[EffectKey, list[Finding]] = field(default_factory=dict)
    #: per axis: a kept searched cycle's aliases
    aliased: dict[str, tuple[float, ...]] = field(default_factory=dict)
    number: int = 0
    #: the first step that kept a surface over a line's set-up error that passed every rule
    #: (:func:`other_route`); None where none did, or on the route that took the set-up
    fork: Fork | None = None
    #: the first step that kept a surface over its other family of as many terms within ``tie``
    #: (:func:`_tied_variant`); None where none did, or on a route forked from another
    variant_fork: Fork | None = None
    #: False on a set-up error's route: it forks no further
    may_fork: bool = True
    #: False on every route but the first: a surface's family forks once per loop
    may_fork_variant: bool = True


@dataclass(frozen=True, eq=False)
class Fork:
    """A step that kept a surface where another candidate passed every rule too (a line's
    set-up error, or the surface's other family of as many terms): the model before it, its
    rows, the other candidate's trial and what the state held then."""

    number: int
    first_row: int
    surface: Trial
    other: Trial
    #: every candidate the step refitted
    tried: list[Trial]
    state: State
