"""How a forward step of the closed loop chooses among the candidates that pass: the simplest
that predicts as well, the rivals that fit as well and how the 21 errors move to them, and
the errors an effect shares its columns with."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from .effects import AbbeOffset, Cosine, CrossAxis, Cyclic, Effect, Reversal, ThermalDrift
from .errors import ERROR_INFO, SQUARENESS_IDS
from .identify import Identification
from .identify_system import SHARE_NAMED
from .loop_compare import Trial, held_out_group
from .loop_judge import SET_UP_TIE
from .loop_records import EffectKey, Finding, FloatArray, LoopOptions, effect_entry
from .loop_state import State
from .loop_tester import exchange, in_words
from .separating import Separation, separating_lines

#: A surface of another place is refitted as a kept one's possible rival where the diagnosis
#: gives it at least this share of the kept one's gain (:func:`untried_places`); so is a set-up
#: error of another line (:func:`_untried_lines`).
RIVAL_GAIN_SHARE = 0.95


def nearly_as_strong(finding: Finding, gain: float, options: LoopOptions) -> bool:
    """Whether ``finding`` passes the loop's false-alarm level with at least
    :data:`RIVAL_GAIN_SHARE` of ``gain``, a kept effect's: a possible rival of it."""
    return (
        finding.log10_false_alarm < np.log10(options.alpha)
        and finding.gain >= RIVAL_GAIN_SHARE * gain
    )


@dataclass(frozen=True)
class Shared:
    """What of a kept effect the plan reads exactly as a change of the 21 errors (the fit leaves
    it to them): its shape functions involved (for a surface, each whose column-scaled weight
    in a shared direction reaches :data:`SHARE_NAMED` of that direction's largest; otherwise
    the effect's label), the identified errors that carry it, and the number of independent
    combinations shared (0: nothing is)."""

    terms: tuple[str, ...] = ()
    errors: tuple[str, ...] = ()
    count: int = 0


def shared_of(fit: Identification, index: int) -> Shared:
    """:class:`Shared` of the fit's effect ``index``."""
    reduction = fit.system.reduction
    parts = [p for p in reduction.shared if p.effect == index] if reduction else []
    identified = set(fit.identifiability.identified_ids)
    errors = tuple(dict.fromkeys(e for p in parts for e in p.errors if e in identified))
    if not errors:
        return Shared()
    effect = fit.effects[index]
    assert isinstance(effect, Effect)
    if not isinstance(effect, CrossAxis):
        return Shared((effect.label,), errors, len(parts))
    weight = np.max([np.abs(p.direction) / np.abs(p.direction).max() for p in parts], axis=0)
    names = effect.term_names
    terms = tuple(n for n, w in zip(names, weight, strict=True) if w >= SHARE_NAMED)
    return Shared(terms, errors, len(parts))


def shared_warnings(fit: Identification, shared: Sequence[Shared]) -> list[str]:
    """A warning per kept effect of which a part reads on every line exactly as a change of the
    21 errors: the fit leaves that part to them, so the errors reported carry it."""
    out = []
    for effect, part in zip(fit.effects, shared, strict=True):
        assert isinstance(effect, Effect)
        if not part.count:
            continue
        terms = part.terms
        if not isinstance(effect, CrossAxis):
            what = "a part of it reads"
        elif part.count == 1 and len(terms) == 1:
            what = f"its term {terms[0]} reads"
        elif part.count == 1:
            what = f"a combination of its terms {in_words(terms)} reads"
        else:
            named = in_words(terms) if len(terms) <= 4 else f"{len(terms)} of its terms"
            what = f"{part.count} combinations of {named} read"
        out.append(
            f"{effect.label}: {what} on every line measured exactly as a change of "
            f"{in_words(part.errors)} does, so this plan cannot tell the two apart: the fit leaves "
            "it to those errors, and their reported values carry it. Lines that read those "
            "errors directly, or the same error at other offsets, would tell them apart"
        )
    return out


class _Doubt(NamedTuple):
    """What the plan leaves open about a kept effect (:func:`alike`, :func:`unsettled`,
    :func:`interchangeable`, :func:`which_set_up`)."""

    #: the warning, or None when nothing is left open
    text: str | None
    #: the differences of the errors' parameters to the rivals that move them, one per row
    moves: FloatArray
    #: rivals of another place (a surface's direction and pair, a set-up's line or kind) that
    #: fit as well: each may be the effect the machine has
    rivals: tuple[Trial, ...] = ()
    #: the move of a kept surface's own coefficients to the rival of its place whose move of
    #: the 21 errors is taken (:func:`unsettled`), None where there is none
    surface_move: FloatArray | None = None
    #: the lines the plan lacks on which the kept fit and its rivals read apart
    #: (:func:`~volucal.core.separating.separating_lines`), None where none reads two apart
    separation: Separation | None = None


def alike(chosen: Trial, trials: list[Trial], tie: float) -> _Doubt:
    """A warning when the kept surface has rivals of another direction or pair of axes that
    predict the held-out data as well (within ``tie``), passing or refused only for showing on
    one line: the plan cannot tell which of them the machine has. Each trial's score is its
    cross-validated error over the readings its comparison with the step's model ran on.

    Returned with it, as :func:`interchangeable`, the differences of the errors' parameters to
    every rival that moves an error fitted beside it by more than :data:`UNSETTLED_RATIO` of its
    stated standard uncertainties (one per row): each may be the machine's surface."""
    effect = chosen.finding.effect
    delta = np.zeros_like(chosen.refit.model.parameters)
    if not isinstance(effect, CrossAxis):
        return _Doubt(None, delta)
    place = surface_place(effect)
    rivals = _as_well(
        chosen,
        trials,
        tie,
        lambda other: isinstance(other, CrossAxis) and surface_place(other) != place,
    )
    if not rivals:
        return _Doubt(None, delta)
    trial, beyond, deltas = _rival_moves(chosen, rivals)
    # every one named: each may be the machine's
    named = [t.finding.effect.label for t in rivals]
    separation = separating_lines(
        [chosen.refit, *(t.refit for t in rivals)], [effect.label, *named]
    )
    advice = (
        separation.sentence()
        if separation is not None
        else "Lines along the pair's axes at other offsets would tell them apart"
    )
    text = (
        f"{_kept_but(chosen, rivals, tie)}: this plan cannot tell which direction and pair of "
        "axes the surface belongs to; away from the lines measured they differ"
        f"{_moves_said(trial, beyond)}. {advice}"
    )
    return _Doubt(text, deltas, tuple(rivals), separation=separation)


def _as_well(
    chosen: Trial,
    trials: list[Trial],
    tie: float,
    admits: Callable[[Effect], bool],
    by_lines: bool = False,
) -> list[Trial]:
    """The trials other than ``chosen`` whose effect ``admits`` accepts, that pass or are refused
    only for showing on one line, and predict the held-out data as well (within ``tie``), best
    first; with ``by_lines``, every one the plan does not rank below ``chosen``
    (:func:`_not_ranked`: also worse over all, but not unit by unit)."""
    return sorted(
        (
            trial
            for trial in trials
            if trial is not chosen
            and admits(trial.finding.effect)
            and (trial.ok or trial.uncorroborated)
            and (_not_ranked(trial, chosen, tie) if by_lines else trial.ties(chosen, tie))
        ),
        key=lambda trial: trial.score,
    )


def rival_report(trial: Trial) -> dict[str, object]:
    """A rival of a kept effect as report.json lists it: its kind, axis, label and parameters
    as fitted in its trial, and its cross-validated RMS over the readings the step's candidates
    were ranked on (every line, angular readings on the displacement scale)."""
    return {
        **effect_entry(trial.finding.effect, trial.parameters),
        "cv_rms_all_lines": trial.score,
    }


def _rival_moves(
    chosen: Trial, rivals: list[Trial]
) -> tuple[Trial, list[tuple[float, str, float]], FloatArray]:
    """How the rivals of the kept fit move the errors fitted beside it (:func:`_moved_errors`):
    the rival that moves one most, the errors it moves by more than :data:`UNSETTLED_RATIO` of
    their stated standard uncertainties (largest first), and the differences of the errors'
    parameters to every rival that moves one so far, one per row."""
    bands = {eid: chosen.refit.band(eid) for eid in chosen.refit.identifiability.identified_ids}
    moves = [(sorted(_moved_errors(bands, trial.refit), reverse=True), trial) for trial in rivals]
    moved, trial = max(moves, key=lambda m: m[0][0][0] if m[0] else 0.0)
    rows = np.array(
        [
            other.refit.model.parameters - chosen.refit.model.parameters
            for errors, other in moves
            if errors and errors[0][0] > UNSETTLED_RATIO
        ]
    ).reshape(-1, chosen.refit.model.parameters.size)
    return trial, [m for m in moved if m[0] > UNSETTLED_RATIO], rows


#: The clause of a set-up doubt whose rival moves no error beyond its uncertainty.
AGREE = "; the errors fitted beside them agree within their uncertainties"


def _moves_said(trial: Trial, beyond: list[tuple[float, str, float]], none_moved: str = "") -> str:
    """The clause of a warning that names the errors ``trial`` moves beyond their uncertainty
    (``none_moved`` when it moves none)."""
    if not beyond:
        return none_moved
    return (
        f"; the errors fitted beside {trial.finding.effect.label} differ: "
        f"{_moved_text(beyond)}, and the stated uncertainties of the errors include the "
        "differences"
    )


def surface_place(effect: Effect) -> tuple[str, frozenset[str]] | None:
    """A surface's direction and pair of axes (None for any other effect)."""
    if not isinstance(effect, CrossAxis):
        return None
    return effect.direction, frozenset((effect.along, effect.across))


#: A kept surface's shape is *unsettled* (and said so) when a rival surface of the same direction
#: and pair that predicts the held-out data as well moves an error fitted beside it by more than
#: this many of its stated standard uncertainties (RMS over its stroke).
UNSETTLED_RATIO = 3.0


def unsettled(chosen: Trial, trials: list[Trial], tie: float) -> _Doubt:
    """What the kept surface's shape leaves open: its rivals of the same direction and pair
    (another order, with or without lever-arm terms) that pass and predict the held-out data as
    well (within ``tie``, or not worse by :func:`_worse_on_lines`) are fits the plan cannot rank
    below it.

    Returned: a warning when the 21 errors fitted beside the rival that moves them most differ
    from the kept fit's by more than :data:`UNSETTLED_RATIO` stated standard uncertainties, and
    that difference of the errors' parameters (zeros without a rival). The two fits are equally
    good descriptions, so the errors' covariance gains half its outer product (the spread of an
    even choice between them about the kept one): the bands then say what the plan settles.
    With it, the move of the surface's own coefficients to that rival's
    (:func:`_surface_move`)."""
    effect = chosen.finding.effect
    delta = np.zeros_like(chosen.refit.model.parameters)
    if not isinstance(effect, CrossAxis):
        return _Doubt(None, delta)
    place = surface_place(effect)
    rivals = [
        trial
        for trial in trials
        if trial is not chosen
        and trial.ok
        and surface_place(trial.finding.effect) == place
        and _not_ranked(trial, chosen, tie)
    ]
    if not rivals:
        return _Doubt(None, delta)
    trial, beyond, _ = _rival_moves(chosen, rivals)
    delta = trial.refit.model.parameters - chosen.refit.model.parameters
    surface = _surface_move(chosen, trial)
    if not beyond:
        return _Doubt(None, delta, surface_move=surface)
    # a rival better than the kept fit is a richer variant refused by the margin
    if trial.score < chosen.score:
        compared = "better, by less than the margin a richer variant must earn, than"
    elif trial.ties(chosen, tie):
        compared = "as well as"
    else:
        compared = "worse over all, but not unit by unit held out (paired t below 2), than"
    text = (
        f"{trial.finding.effect.label} predicts the held-out data {compared} the kept "
        f"{effect.label} (cross-validated RMS {trial.score:.4g} and {chosen.score:.4g}), and the "
        f"errors fitted beside the two differ: {_moved_text(beyond)}. This plan does not settle "
        "the surface's shape; the stated uncertainties of the errors include that difference"
    )
    separation = separating_lines(
        [chosen.refit, trial.refit], [effect.label, trial.finding.effect.label]
    )
    if separation is not None:
        text += f". {separation.sentence()}"
    return _Doubt(text, delta, surface_move=surface)


#: A rival predicts the held-out data worse than the kept fit where the mean of its excess of
#: held-out mean square, per unit cross-validation held out (a line, or a block of a line's
#: targets), stands this many standard errors above nothing (:func:`_worse_on_lines`).
WORSE_T = 2.0


#: ... and in any case where its held-out error over all readings is more than this share above
#: the kept fit's (twice the margin a richer variant earns its place by): a rival far worse on a
#: few units only is worse, whatever the spread of the rest.
NOT_RANKED_SHARE = 0.06


def _worse_on_lines(trial: Trial, chosen: Trial) -> bool:
    """Whether ``trial`` predicts the held-out data worse than ``chosen``: by more than
    :data:`NOT_RANKED_SHARE` over all readings, or unit by unit, the mean over the units
    cross-validation held out (a line, or a block of a line's targets) of the excess of its
    held-out mean square (angular readings on the displacement scale) standing :data:`WORSE_T`
    standard errors above nothing. Without the readings both were compared on, or with fewer
    than three units, a rival is worse unless it ties (the caller's 1 %).

    A few per cent over all readings can come from some lines one fit follows better: a surface
    of order 8 that predicted 36 of 46 held-out lines better than order 6, 3.97 % over all but
    paired t 1.57, swung between the lines along X by 5 µm through the middle of the Z stroke,
    where order 6 was within 0.43 µm of the truth (indep. 5200038). Such a rival is a fit the
    plan does not rank below the kept one."""
    if trial.score > chosen.score * (1.0 + NOT_RANKED_SHARE):
        return True
    if trial.rows is None or chosen.rows is None:
        return True
    readings = chosen.refit.readings
    rows = (
        trial.rows & chosen.rows & np.isfinite(trial.cv.residual) & np.isfinite(chosen.cv.residual)
    )
    blocks = chosen.cv.method.startswith("held-out blocks")
    unit = np.full(len(readings), -1, dtype=np.int64)
    unit[rows] = held_out_group(readings, rows, blocks)
    units = np.unique(unit[rows])
    if units.size < 3:
        return True
    scale = exchange(readings)
    excess = np.array(
        [
            np.mean((trial.cv.residual[on] * scale[on]) ** 2)
            - np.mean((chosen.cv.residual[on] * scale[on]) ** 2)
            for on in (rows & (unit == u) for u in units)
        ]
    )
    spread = float(np.std(excess, ddof=1)) / np.sqrt(excess.size)
    return bool(np.mean(excess) > WORSE_T * spread)


def _not_ranked(trial: Trial, chosen: Trial, tie: float) -> bool:
    """Whether the plan does not rank ``trial`` below ``chosen``: it predicts the held-out data
    as well (within ``tie``), or worse over all but not unit by unit (:func:`_worse_on_lines`)."""
    return trial.ties(chosen, tie) or not _worse_on_lines(trial, chosen)


def _kept_surface(trial: Trial) -> tuple[CrossAxis, FloatArray]:
    """The surface ``trial`` tested, and its fitted coefficients."""
    effect = trial.finding.effect
    assert isinstance(effect, CrossAxis)
    index = next(i for i, e in enumerate(trial.refit.effects) if e is effect)
    return effect, trial.refit.effect_parameters[index]


def _surface_move(chosen: Trial, rival: Trial) -> FloatArray | None:
    """How the kept surface's coefficients move to ``rival``'s (the rival whose 21 errors
    :func:`unsettled` takes the move of, so that both moves are one choice between two fits):
    the rival's surface least-squares in the kept one's terms over a grid of the pair's strokes.
    None where it does not move."""
    effect, values = _kept_surface(chosen)
    assert effect.machine is not None
    grid = effect.grid(effect.machine)
    design = effect.shape(grid)
    other, other_values = _kept_surface(rival)
    difference = other.shape(grid) @ other_values - design @ values
    move = np.asarray(np.linalg.lstsq(design, difference, rcond=None)[0], dtype=float)
    return move if np.any(move) else None


def with_surface_doubt(fit: Identification, moves: dict[EffectKey, FloatArray]) -> Identification:
    """``fit`` with each kept surface's coefficient covariance widened by half the outer product
    of its move to its rival (:func:`_surface_move`), in its covariance and in the fit's normal
    inverse alike, as :func:`with_shape_doubt` widens the 21 errors'."""
    if not moves:
        return fit
    columns = [block.columns for block in fit.system.blocks if block.kind == "effect"]
    if len(columns) != len(fit.effects):  # effects restricted to their separable directions
        columns = []
    covariances = list(fit.effect_covariances)
    normal_inverse = fit.normal_inverse.copy()
    for index, effect in enumerate(fit.effects):
        move = moves.get(effect.key)  # type: ignore[attr-defined]
        if move is None or move.size != covariances[index].shape[0]:
            continue
        widening = 0.5 * np.outer(move, move)
        covariances[index] = covariances[index] + widening
        if columns:
            at = columns[index]
            normal_inverse[at, at] += widening / max(fit.sigma_scale, 1e-300) ** 2
    return replace(fit, effect_covariances=tuple(covariances), normal_inverse=normal_inverse)


#: Two fits read the readings identically when their weighted residual sums of squares agree
#: to this share: the plan spans the same model with either effect (only rounding differs).
SAME_FIT_SHARE = 1e-6


def _chi2(fit: Identification) -> float:
    return float(np.sum((fit.residual / fit.readings.sigma) ** 2))


def interchangeable(chosen: Trial, trials: list[Trial], tie: float) -> _Doubt:
    """What a kept set-up effect (an Abbe offset, a cosine misalignment) leaves open: the same
    kind of effect on another line that passes and fits the readings identically (the plan's
    21 errors take up one line's set-up as readily as the other's: the lines are tied by the
    errors they read) or predicts the held-out data as well (within ``tie``). The held-out error
    cannot rank such rivals: removing either line frees the other's set-up too.

    Returned as :func:`unsettled`: a warning naming the lines, with the errors fitted beside the
    rival that moves them most where they differ by more than :data:`UNSETTLED_RATIO` stated
    standard uncertainties, and the differences of the errors' parameters to every rival that
    moves one so far (one per row: each line may be the one, and each moves other errors)."""
    effect = chosen.finding.effect
    delta = np.zeros_like(chosen.refit.model.parameters)
    if not isinstance(effect, (AbbeOffset, Cosine)):
        return _Doubt(None, delta)
    chi2 = _chi2(chosen.refit)
    rivals = [
        trial
        for trial in trials
        if trial is not chosen
        and trial.ok
        and type(trial.finding.effect) is type(effect)
        and trial.finding.effect.line != effect.line  # type: ignore[attr-defined]
        and (abs(_chi2(trial.refit) - chi2) <= SAME_FIT_SHARE * chi2 or trial.ties(chosen, tie))
    ]
    if not rivals:
        return _Doubt(None, delta)
    trial, beyond, deltas = _rival_moves(chosen, rivals)
    lines = in_words([t.finding.effect.line_name for t in rivals])  # type: ignore[attr-defined]
    said = _moves_said(trial, beyond, AGREE)
    text = (
        f"{effect.label} was kept, but the same on line{'s' if len(rivals) > 1 else ''} "
        f"{lines} fits the readings as well (cross-validated RMS {chosen.score:.4g} kept, "
        f"{in_words([f'{t.score:.4g}' for t in rivals])}): this plan cannot tell which line's "
        f"set-up it is{said}. Check those lines' set-up, or measure them again"
    )
    return _Doubt(text, deltas, tuple(rivals))


def which_set_up(chosen: Trial, trials: list[Trial], tie: float) -> _Doubt:
    """What a kept set-up effect leaves open about its own line: the other set-up effect of the
    same line (a cosine misalignment for an Abbe offset, or the reverse) that passes and
    predicts the held-out data as well (within ``tie``). A line whose angular errors change
    nearly linearly along it reads a lever arm almost as a scale; the plan cannot tell whether
    its reflector sits off the beam or its beam is tilted.

    Returned as :func:`interchangeable`: a warning naming the rival, with the errors fitted
    beside it where they differ by more than :data:`UNSETTLED_RATIO` stated standard
    uncertainties, and the differences of the errors' parameters (one row, or none)."""
    effect = chosen.finding.effect
    delta = np.zeros_like(chosen.refit.model.parameters)
    if not isinstance(effect, (AbbeOffset, Cosine)):
        return _Doubt(None, delta)
    rivals = [
        trial
        for trial in trials
        if trial is not chosen
        and trial.ok
        and isinstance(trial.finding.effect, (AbbeOffset, Cosine))
        and type(trial.finding.effect) is not type(effect)
        and trial.finding.effect.line == effect.line  # type: ignore[attr-defined]
        and trial.ties(chosen, tie)
    ]
    if not rivals:
        return _Doubt(None, delta)
    trial, beyond, deltas = _rival_moves(chosen, rivals)
    said = _moves_said(trial, beyond, AGREE)
    text = (
        f"{effect.label} was kept, but {trial.finding.effect.label} predicts the held-out data "
        f"as well (cross-validated RMS {chosen.score:.4g} kept, {trial.score:.4g}): this plan "
        f"cannot tell whether the line's optics sit off the beam or its beam is tilted{said}. "
        "Check the line's alignment, or measure it again with the optics at another offset"
    )
    return _Doubt(text, deltas, tuple(rivals))


def set_up_or_machine(chosen: Trial, trials: list[Trial], tie: float) -> _Doubt:
    """What a kept set-up effect leaves open when a machine effect explains its line as well: the
    machine effects that pass, or are refused only for showing on one line, and predict the
    held-out data as well (within ``tie``). A surface seen on one line alone takes any shape
    there, the set-up error's too (blind 29039: an Abbe offset of diag_yz_pp, the direct plan's
    one line that moves Y and Z together, and three places of a surface within 0.6 % of it); a
    drift that settles after the session's first line reads there as that line's short scale
    (blind 30100: a cosine error of x_linear kept, a drift of X 0.2 % behind). The tie rule keeps
    the set-up error for its fewer parameters, but the plan cannot rule the others out. Nor can
    it a rival that predicts worse over all but not line by line held out (:func:`_not_ranked`,
    as :func:`unsettled`'s): where one line alone shows the structure, the machine effect is
    estimated held out that line from lines it barely reaches, and its excess sits on that one
    unit (blind 55102: a drift of X, 11.4 ppm/K over 0.35 K, τ 3.9 h, that only x_linear shows
    beyond the 21 errors; a cosine error of x_linear kept, the drift 1.7 % behind, fitted at
    4.0 ppm and τ 3.7 h, the truth 4.0 ppm and 3.9 h).

    Returned as :func:`interchangeable`: a warning naming them, the errors fitted beside the
    rival that moves them most where they differ by more than :data:`UNSETTLED_RATIO` stated
    standard uncertainties, and the differences of the errors' parameters to every rival that
    moves one so far (one per row); report.json names them as the kept effect's rivals."""
    effect = chosen.finding.effect
    delta = np.zeros_like(chosen.refit.model.parameters)
    if not isinstance(effect, (AbbeOffset, Cosine)):
        return _Doubt(None, delta)
    rivals = _as_well(chosen, trials, tie, lambda other: other.line_index is None, by_lines=True)
    if not rivals:
        return _Doubt(None, delta)
    trial, beyond, deltas = _rival_moves(chosen, rivals)
    text = (
        f"{_kept_but(chosen, rivals, tie)}: this plan cannot tell line {effect.line_name}'s "
        "set-up from an error of the machine that shows mostly there"
        f"{_moves_said(trial, beyond, AGREE)}. Check the line's set-up and measure it again"
    )
    return _Doubt(text, deltas, tuple(rivals))


def which_axis(chosen: Trial, trials: list[Trial], tie: float) -> _Doubt:
    """What a kept drift leaves open about its axis: a drift of another axis, passing or refused
    only for showing on one line, that the plan does not rank below it (:func:`_not_ranked`).
    Where the lines that read the drift move two axes alike, either axis' scale drifting reads
    the same (blind 50193, the plan of the demo: a drift of Y of 11.1 ppm/K over 1.9 K, τ 57
    min, that only diag_xy_pp shows beyond the 21 errors; a drift of X was kept at 21 ppm and
    τ 56 min, the drift of Y 2.8 % behind and not worse line by line, and nothing said so).

    Returned as :func:`interchangeable`: a warning naming the rivals, the errors fitted beside
    the rival that moves them most where they differ by more than :data:`UNSETTLED_RATIO` stated
    standard uncertainties, and the differences of the errors' parameters to every rival that
    moves one so far (one per row); report.json names them as the kept drift's rivals."""
    effect = chosen.finding.effect
    delta = np.zeros_like(chosen.refit.model.parameters)
    if not isinstance(effect, ThermalDrift):
        return _Doubt(None, delta)
    rivals = _as_well(
        chosen,
        trials,
        tie,
        lambda other: isinstance(other, ThermalDrift) and other.axis != effect.axis,
        by_lines=True,
    )
    if not rivals:
        return _Doubt(None, delta)
    trial, beyond, deltas = _rival_moves(chosen, rivals)
    axes = sorted({str(effect.axis), *(str(t.finding.effect.axis) for t in rivals)})
    text = (
        f"{_kept_but(chosen, rivals, tie)}: this plan cannot tell which axis' scale drifts"
        f"{_moves_said(trial, beyond, AGREE)}. Lines along {in_words(axes)} alone, measured while "
        "the drift changes, would tell them apart"
    )
    return _Doubt(text, deltas, tuple(rivals))


def _kept_but(chosen: Trial, rivals: list[Trial], tie: float) -> str:
    """A doubt's warning up to what it leaves open: the kept effect, its rivals, none ranked below
    it (:func:`_not_ranked`), and their cross-validated errors beside its. They predict the
    held-out data "as well", unless one is worse over all by more than ``tie``."""
    as_well = (
        "as well"
        if all(t.ties(chosen, tie) for t in rivals)
        else "as well or, line by line held out, not significantly worse (paired t below 2)"
    )
    return (
        f"{chosen.finding.effect.label} was kept, but "
        f"{in_words([t.finding.effect.label for t in rivals])} "
        f"predict{'s' if len(rivals) == 1 else ''} the held-out data {as_well} (cross-validated "
        f"RMS {chosen.score:.4g} kept, {in_words([f'{t.score:.4g}' for t in rivals])})"
    )


def _moved_text(beyond: list[tuple[float, str, float]]) -> str:
    """The three errors :func:`_moved_errors` moves most, in words, and how many more."""
    listed = ", ".join(
        f"{eid} by {difference:.3g} {'µrad' if ERROR_INFO[eid].unit == 'urad' else 'µm'}"
        f"{'' if eid in SQUARENESS_IDS else ' RMS'} ({ratio:.2g} times its standard "
        "uncertainty before this doubt)"
        for ratio, eid, difference in beyond[:3]
    )
    return listed + (f" and {len(beyond) - 3} more" if len(beyond) > 3 else "")


def _moved_errors(
    bands: dict[str, tuple[FloatArray, FloatArray, FloatArray]], other: Identification
) -> list[tuple[float, str, float]]:
    """(ratio, id, difference) of every error of ``bands`` (a fit's :meth:`Identification.band`
    per identified error) between that fit and ``other``: the RMS difference over its stroke
    (µm or µrad) and its ratio to the fit's standard uncertainty."""
    out = []
    for eid, (q, value, std) in bands.items():
        if eid in SQUARENESS_IDS:
            values = np.array([other.model.squareness_urad[eid]])
        else:
            values = other.model.functions[eid](q)
        difference = float(np.sqrt(np.mean((value - values) ** 2)))
        spread = float(np.sqrt(np.mean(std**2)))
        if spread > 0:
            out.append((difference / spread, eid, difference))
    return out


def simplest_best(passing: list[Trial], tie: float, margin: float) -> Trial | None:
    """The candidate with the lowest cross-validated error; among those within ``tie`` of it, a
    physical effect before a finer function (short structure is the loop's to name, DESIGN.md:
    a bump a finer spline follows as well is still a bump), then the one that leaves the model
    the fewest effects, then the one that adds the fewest parameters (fitted and searched) to
    it: a drift driven by the logged temperature before one whose time constant had to be
    estimated, when both explain alike. A variant of a kept effect (a surface of another order,
    a cycle's period refined, :func:`kept_with`) replaces it and claims nothing new of the machine:
    ranked on parameters alone, a second surface EZ over X×Y adding two fewer than the kept
    surface's next order was kept beside it, a second claim on Z where the machine had one
    (blind 51162). So a set-up error of one parameter that ties a variant of a kept surface
    gives way to it, where beside a surface of a new place it is kept (:func:`set_up_tied`).

    A richer variant of one structure (:func:`_richer`: a surface of higher order or with
    lever-arm terms, a position-dependent reversal, a drift whose time constant is estimated) is
    kept over a leaner one only when it betters the leaner one's error by ``margin``, as any
    effect must better the model without it: the terms it adds are an effect of their own. Held
    to ``tie`` alone, a surface of order 4 was kept for 1.6 % over one of order 3 and traded a
    squareness by 10 µrad against its extra terms (blind 19167)."""
    earned = [
        t
        for t in passing
        if not any(
            _richer(t, other) and t.score > other.score * (1.0 - margin) for other in passing
        )
    ]
    if not earned:
        return None
    best = min(t.score for t in earned)
    close = [t for t in earned if t.score <= best * (1.0 + tie)]
    return min(
        close,
        key=lambda t: (
            t.finding.effect.kind == "higher_order",
            len(t.refit.effects),
            model_terms(t.refit),
            t.score,
        ),
    )


def _richer(trial: Trial, than: Trial) -> bool:
    """Whether ``trial`` is a richer variant of the structure ``than`` fits (more parameters): a
    surface of the same direction and pair of axes, or a reversal or a thermal drift of the same
    axis."""
    one, other = trial.finding.effect, than.finding.effect
    if isinstance(one, CrossAxis):
        variant = isinstance(other, CrossAxis) and surface_place(one) == surface_place(other)
    else:
        variant = isinstance(one, (Reversal, ThermalDrift)) and (one.kind, one.axis) == (
            other.kind,
            other.axis,
        )
    return variant and complexity(trial) > complexity(than)


def kept_instead(chosen: Trial, trial: Trial, margin: float) -> str:
    """The clause of a passing candidate's reason that names the one kept instead."""
    figures = (
        f"cross-validated RMS {chosen.score:.4g} against {trial.score:.4g} over the readings "
        "every candidate of the step predicts"
    )
    if not _richer(trial, chosen) or chosen.score <= trial.score:
        return f"; {chosen.finding.effect.label} was kept instead ({figures})"
    return (
        f"; {chosen.finding.effect.label} was kept instead: the terms this one adds to it do not "
        f"better its error by the {100 * margin:.0f} % margin ({figures})"
    )


def complexity(trial: Trial) -> int:
    return effect_terms(trial.finding.effect, trial.refit)


def model_terms(fit: Identification) -> int:
    """How many parameters the effects of ``fit`` have together (:func:`effect_terms`). The
    candidates of a step all start from the same kept effects, so this orders them by what each
    adds."""
    fitted = sum(int(values.size) for values in fit.effect_parameters)
    return fitted + sum(effect.searched for effect in fit.effects)


def effect_terms(effect: Effect, fit: Identification) -> int:
    """How many parameters ``effect`` has in ``fit``: fitted, and searched (a period, a τ)."""
    index = list(fit.effects).index(effect)
    return int(fit.effect_parameters[index].size) + effect.searched


def other_kinds(proposals: list[Finding], tried: list[Trial], count: int) -> list[Finding]:
    """The strongest proposal of each kind of machine effect no refit of this step has tried,
    up to ``count``. A set-up effect (an Abbe offset, a cosine error) is refitted only among the
    strongest: one line's set-up takes whatever that line alone shows, an effect outside the
    catalogue too, and it has no second line to be refused by."""
    seen = {t.finding.effect.kind for t in tried}
    out: list[Finding] = []
    for finding in proposals:
        kind = finding.effect.kind
        if len(out) == count:
            break
        if finding.effect.line_index is None and kind not in seen:
            seen.add(kind)
            out.append(finding)
    return out


def set_up_tied(proposals: list[Finding], batch: list[Finding], strongest: float) -> list[Finding]:
    """When surfaces alone fill ``batch``: the strongest set-up effect outside it whose gain
    ties the strongest proposal's (:data:`SET_UP_TIE`), as a list of at most one. Where one line
    alone shows what is left, a surface fits it at every direction and pair alike and those
    places fill the batch; an Abbe offset or a cosine error of that line that explains it as
    well, with a parameter or two where the surface has many, must be refitted beside them for
    the tie rule to prefer it. Beside any other effect it waits its turn: a drift that the
    session's first line shows most ties a cosine error of that line in gain, and the tie rule
    would keep the cosine for its one parameter (indep. 3300052), which the audit then takes
    out, the line still drifting, for the next round to keep it again."""
    if not all(isinstance(f.effect, CrossAxis) for f in batch):
        return []
    for finding in proposals:
        if finding in batch or finding.effect.line_index is None:
            continue
        return [finding] if finding.gain >= SET_UP_TIE * strongest else []
    return []


def owed_refit(state: State, finding: Finding, beside: frozenset[EffectKey]) -> bool:
    """Whether ``finding`` is owed a refit: refused for what an effect then missing spoils (a size
    that varied, :data:`SPOILED_BY_THE_REST`, a set-up error too large or short of the margin
    without its neighbour, :func:`set_up_spoiled_by_the_rest`, or a surface's gain on lines it left
    systematic, :func:`gained_through_lines_it_leaves`: blind 45093, a surface EX over X×Z refused
    while a local defect of Z, still missing, left five lines systematic), or taken out by the
    final audit (it waits till then), and another effect kept since. It joins the next step's
    first batch whatever the diagnosis now says of it: the diagnosis holds the kept effects'
    nonlinear parameters where they were fitted without it (a drift's τ, fitted while the first
    line's cosine error was missing, took part of that error; refitted together, τ moves back:
    indep. 3700091)."""
    was = state.refused_beside.get(finding.effect.key)
    return was is not None and was != beside


#: Refusals of a set-up effect that what the model still lacks beside it may cause
#: (:func:`set_up_spoiled_by_the_rest`).
SET_UP_SPOILED_BY_THE_REST = ("implausible", "below margin")


def set_up_spoiled_by_the_rest(trial: Trial) -> bool:
    """Whether ``trial`` refused a set-up effect (Abbe offset, cosine misalignment) as
    implausible, or as short of the margin: the machine effect the model still lacks beside it
    inflates its size as much as its own error does (a surface that tilts the line reads as a
    longer scale), and spoils the held-out lines through which alone a set-up error is confirmed
    (blind 48121: a cosine error of z_linear_side 2.2 % better beside another line's missing
    cosine error, 16.7 % once that was kept), so it is refitted after another effect is kept,
    whatever its F statistic."""
    return (
        trial.verdict in SET_UP_SPOILED_BY_THE_REST and trial.finding.effect.line_index is not None
    )


def distinct(findings: list[Finding]) -> list[Finding]:
    """The findings less those that describe the same structure as a stronger one: cycles on
    one axis whose periods differ by less than 1 % (the lead and the periodogram's peak)."""
    out: list[Finding] = []
    for finding in findings:
        effect = finding.effect
        duplicate = isinstance(effect, Cyclic) and any(
            isinstance(other.effect, Cyclic)
            and other.effect.axis == effect.axis
            and abs(other.effect.period_mm / effect.period_mm - 1.0) < 0.01
            for other in out
        )
        if not duplicate:
            out.append(finding)
    return out
