"""What the closed loop is asked and what it records: its options, the findings of its
diagnosis, the steps it took and what stayed unexplained (core/residuals.py runs it)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .effects import Effect, Plausibility
from .errors import ERROR_INFO
from .identify import Identification, IdentifyOptions
from .machine import AXES
from .readings import Readings

FloatArray = NDArray[np.float64]


IntArray = NDArray[np.int64]


EffectKey = tuple[str, str | None, str]


#: Why a machine effect that one line alone shows is not kept (loop_judge ``_uncorroborated``).
ONE_LINE_CANNOT_TELL = "one line cannot tell a machine effect from an artefact of its own set-up"


def effect_entry(effect: Effect, parameters: dict[str, object]) -> dict[str, object]:
    """An effect as report.json names it wherever it lists one (a kept effect, a rival, a step's
    candidate): its kind, axis, label and ``parameters``."""
    return {
        "kind": effect.kind,
        "axis": effect.axis,
        "label": effect.label,
        "parameters": parameters,
    }


@dataclass(frozen=True)
class LoopOptions:
    """Thresholds of the loop.

    alpha : family-wise false-alarm level for proposing an effect (Bonferroni over all tests).
    margin : relative improvement of the cross-validated RMS an effect must bring to be kept
        (and must still bring in the backward pass to stay); a richer variant of one structure
        must bring it over the leaner variant too.
    generalisation : share of the fitted mean-square gain the held-out data must confirm.
    candidates_per_step : how many of the strongest findings are refitted together; the best
        one that passes is kept. Where surfaces alone fill them, a set-up effect whose gain ties
        the strongest's is refitted beside them (:data:`SET_UP_TIE`).
    max_refits_per_step : when a batch is refused, further proposals of the same step are tried
        up to this many refits before the loop stops: the strongest machine effect of each kind
        no refit of the step has tried, whatever its share of the strongest, not the next
        variants of the refused structure (a weaker effect of another kind behind them is not
        lost with them); set-up effects only ever among the strongest.
    retry_factor : a refused candidate is refitted again once its F statistic has grown by this
        factor (the model around it changed); one refused for a size that varied
        (:data:`SPOILED_BY_THE_REST`), or a set-up effect refused as implausible or short of the
        margin, or taken out by the final audit, once another effect has been kept.
    contender_share : a proposal is refitted in a step's first batch only when the residual sum
        of squares it would remove is at least this share of the strongest proposal's.
    tie : candidates whose cross-validated RMS is within this share of the best are equal; the
        one that leaves the model fewer effects is kept, then the one adding fewer parameters.
    repeatability_log10, repeatability_spread : a candidate whose size, fitted run by run within
        a line and an approach direction (line by line in the final audit, block by block of
        targets along its line for a set-up effect), varies beyond the noise at this false-alarm
        level (log10) and by more than this share of what the readings see of it is refused
        (:class:`Sizes`); the share tolerates a shape that fits the structure imperfectly.
    repeatability_spread_setup : the share for a set-up effect (Abbe offset, cosine
        misalignment) run by run, whose shape is exact.
    time_constants_s : the range over which a time-driven drift's τ is estimated.
    cross_axis_orders, cross_axis_lever_orders : the total degrees tried for a cross-axis
        surface without and with lever-arm terms (:class:`CrossAxis`; chosen by cross-validation).
    spacings_mm : the breakpoint spacings (mm) of the 21 errors' cubic B-spline basis that the
        loop chooses among by cross-validation once it has chosen the effects (at the
        identification's own ``identify.spacing_mm``, always among them). Empty: that one alone.
    """

    alpha: float = 1e-4
    margin: float = 0.03
    generalisation: float = 0.5
    candidates_per_step: int = 3
    max_refits_per_step: int = 6
    max_steps: int = 8
    retry_factor: float = 2.0
    contender_share: float = 0.25
    tie: float = 0.01
    repeatability_log10: float = -4.0
    repeatability_spread: float = 0.3
    repeatability_spread_setup: float = 0.1
    time_constants_s: tuple[float, float] = (300.0, 7 * 86400.0)
    cross_axis_orders: tuple[int, ...] = (4, 5, 6, 8)
    cross_axis_lever_orders: tuple[int, ...] = (3, 4)
    spacings_mm: tuple[float, ...] = (50.0, 75.0, 100.0, 150.0)
    plausibility: Plausibility = field(default_factory=Plausibility)
    identify: IdentifyOptions = field(default_factory=IdentifyOptions)


@dataclass(frozen=True, eq=False)
class Finding:
    """A diagnostic result: an effect that would explain part of the residual."""

    effect: Effect
    f_statistic: float
    log10_false_alarm: float  # log10 of the false-alarm level, corrected for the trials
    trials: int
    magnitude_um: float
    detectability: float  # share of the effect's signal the current model cannot absorb
    where: str
    #: drop of the weighted residual sum of squares (in units of σ²) the effect would bring
    gain: float = 0.0
    #: for a searched cycle: the periods the targets cannot tell from its own (mm), if any
    alias_mm: tuple[float, ...] = ()

    def evidence(self) -> dict[str, object]:
        return {
            "statistic": "F",
            "F": round(self.f_statistic, 3),
            "log10_false_alarm": round(self.log10_false_alarm, 2),
            "trials": self.trials,
            "magnitude_um": round(self.magnitude_um, 4),
            "detectability": round(self.detectability, 3),
            "chi2_gain": round(self.gain, 2),
            "where": self.where,
        }


@dataclass(frozen=True)
class Step:
    """One refit of the loop: a candidate tried (``stage`` "forward"), a kept effect's searched
    quantity estimated again ("refine") or a kept effect taken out again ("backward", "audit")."""

    step: int
    finding: Finding
    kept: bool
    reason: str
    rms_before: float
    rms_after: float
    cv_before: float
    cv_after: float
    parameters: dict[str, object]
    per_group_before: dict[str, float]
    per_group_after: dict[str, float]
    stage: str = "forward"
    #: the decision in a few words (:data:`VERDICTS`); ``reason`` gives it in full
    verdict: str = "kept"
    #: for a machine effect refused as one line alone shows it: that line
    alone_on: str = ""
    #: the share by which the candidate bettered the held-out error, as the margin judges it
    #: (every line, angular readings on the displacement scale; NaN where the step does not
    #: state it), and where: "" over the plan, else over the readings it acts on (the words
    #: of the step's reason)
    improvement: float = float("nan")
    improvement_over: str = ""


@dataclass(frozen=True)
class SpacingChoice:
    """The breakpoint spacing of the 21 errors' B-spline basis and how it was chosen: per
    spacing tried (mm), the cross-validated RMS over the displacement lines (µm) and over every
    line with angular readings on the displacement scale (what the choice is judged by), each
    over the readings both it and ``reference_mm`` predict (:func:`choose_spacing`)."""

    spacing_mm: float
    reference_mm: float
    cv_rms_um: dict[float, float]
    cv_rms_all_lines: dict[float, float]
    method: str
    #: spacings that predict better but leave these lines a systematic residual the reference
    #: spacing explains
    refused: dict[float, tuple[str, ...]] = field(default_factory=dict)
    #: moves of the 21 errors' parameters (rows, in the chosen basis) to the fits of spacings
    #: that predict as well: what the plan does not settle about the basis
    doubt: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    #: moves (rows, in the chosen basis) of each function by what the chosen basis misses of
    #: its shape against the finest spacing tried, beyond the noise (:func:`_shape_missed`),
    #: which widen its covariance; per such function the RMS of that miss (µm or µrad over
    #: its stroke); and that finest spacing (mm)
    shape_missed: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    shape_missed_rms: dict[str, float] = field(default_factory=dict)
    finest_mm: float | None = None

    def report(self) -> dict[str, object]:
        return {
            "spacing_mm": self.spacing_mm,
            "chosen_by": "cross-validation" if len(self.cv_rms_um) > 1 else "set",
            "method": self.method,
            "reference_spacing_mm": self.reference_mm,
            "tried": [
                {
                    "spacing_mm": k,
                    "cv_rms_um": v,
                    "cv_rms_all_lines": self.cv_rms_all_lines[k],
                    **({"leaves_structure_on": list(self.refused[k])} if k in self.refused else {}),
                }
                for k, v in sorted(self.cv_rms_um.items())
            ],
            **(
                {
                    "shape_missed": {
                        "against_spacing_mm": self.finest_mm,
                        "rms": dict(sorted(self.shape_missed_rms.items())),
                        "unit": "µm for a translation, µrad for a rotation, over the stroke",
                    }
                }
                if self.shape_missed_rms
                else {}
            ),
        }


@dataclass(frozen=True)
class Move:
    """How far one error moves when a line is left out, against its stated standard uncertainty
    before that move widened it (µm for a displacement function, RMS over its stroke; µrad for an
    angular function or a squareness)."""

    error_id: str
    move: float
    stated_std: float

    @property
    def ratio(self) -> float:
        return self.move / self.stated_std if self.stated_std > 0 else float("inf")

    @property
    def unit(self) -> str:
        return "µm" if ERROR_INFO[self.error_id].unit == "um" else "µrad"

    def text(self) -> str:
        return (
            f"{self.error_id} by {self.move:.3g} {self.unit} ({self.ratio:.3g} times its standard "
            "uncertainty before this doubt)"
        )

    def to_json(self) -> dict[str, object]:
        return {
            "error": self.error_id,
            "move": self.move,
            "unit": self.unit,
            "std_before": self.stated_std,
        }


@dataclass(frozen=True, eq=False)
class TemperatureDoubt:
    """The doubt on an axis' positioning error from its material warming or cooling between the
    session's first reading and the lines that measured its scale, where no kept drift refers
    the scale back (:func:`~volucal.core.loop_scale.temperature_doubts`)."""

    axis: str
    error_id: str
    #: the line moving the axis alone whose material temperature is nearest the first
    #: reading's, its mean difference (°C) and its mid-time (min from the session's first reading)
    line: str
    change_c: float
    minutes: float
    #: the expansion coefficient its file states (ppm/°C), and the half-width of the scale
    #: doubt (ppm): |ΔT| times that coefficient, or times how far the readings say the scale may
    #: follow the temperature where that is less
    expansion_ppm_per_c: float
    half_width_ppm: float
    #: |κ| + 2u(κ) of the scale's following the temperature by what the readings read
    #: (ppm/°C), None where no line's temperature tells it
    followed_ppm_per_c: float | None
    #: the standard uncertainty added (µm, RMS over the stroke) and the stated one before it
    move: float
    stated_std: float
    #: the move of the model's parameters whose outer product widens the covariance
    delta: FloatArray = field(repr=False)

    def to_json(self) -> dict[str, object]:
        return {
            "error": self.error_id,
            "axis": self.axis,
            "line": self.line,
            "material_change_c": float(self.change_c),
            "minutes": float(self.minutes),
            "expansion_ppm_per_c": float(self.expansion_ppm_per_c),
            "followed_ppm_per_c": (
                None if self.followed_ppm_per_c is None else float(self.followed_ppm_per_c)
            ),
            "half_width_ppm": float(self.half_width_ppm),
            "distribution": "rectangular",
            "move": float(self.move),
            "unit": "µm",
            "std_before": float(self.stated_std),
        }


@dataclass(frozen=True, eq=False)
class ScaleDoubt:
    """What an unexplained line's runs read of its axis' scale apart from the model, and the
    doubt that puts on the axis' positioning error."""

    axis: str
    error_id: str
    line: str
    #: the lowest and highest scale a pass of the line reads relative to the model (ppm; a pass:
    #: a run out and the run back, or a run alone)
    scale_ppm: tuple[float, float]
    #: the pass reading the one farthest from the model: its runs' numbers (from 1) and its
    #: mid-time (min from the session's first reading)
    runs: tuple[int, ...]
    minutes: float
    #: the false-alarm level of the line's scale (of its mean, else of its course in time)
    false_alarm: float
    #: the standard uncertainty added (µm, RMS over the stroke) and the stated one before it
    move: float
    stated_std: float
    #: the move of the model's parameters whose outer product widens the covariance
    delta: FloatArray = field(repr=False)

    @property
    def half_width_ppm(self) -> float:
        return max(abs(self.scale_ppm[0]), abs(self.scale_ppm[1]))

    def to_json(self) -> dict[str, object]:
        return {
            "error": self.error_id,
            "axis": self.axis,
            "line": self.line,
            "scale_ppm": [float(v) for v in self.scale_ppm],
            "half_width_ppm": float(self.half_width_ppm),
            "runs": list(self.runs),
            "minutes": float(self.minutes),
            "move": float(self.move),
            "unit": "µm",
            "std_before": float(self.stated_std),
        }


@dataclass(frozen=True)
class Unexplained:
    """Structure no effect explains: where, how large, and what it follows.

    ``correlates_with`` holds the shares (0–1) of the line's residual sum of squares that follow
    the target position (the same in every run), the approach direction, and time (a drift over
    the runs, as an offset or a scale); the rest is noise.
    """

    where: str
    description: str
    magnitude_um: float
    correlates_with: dict[str, float] = field(default_factory=dict)
    #: the line whose systematic residual along its targets it is ("" for anything else)
    line: str = ""
    #: the axis whose linear lines read different scales over the session ("" for anything else)
    axis: str = ""
    #: machine effects the loop refused only because this line alone shows them, each by the
    #: last step that tried it (:func:`~volucal.core.loop_unexplained.with_one_line_effects`)
    one_line_effects: tuple[Step, ...] = ()
    #: the errors that move beyond their stated uncertainty when this line is left out, and
    #: those it alone determines (:func:`~volucal.core.loop_reach.reach_of_lines`)
    moves: tuple[Move, ...] = ()
    rests_on: tuple[str, ...] = ()
    #: the scale of its axis this line's runs read apart from the model, and the doubt it puts
    #: on the axis' positioning error (:func:`~volucal.core.loop_scale.scale_doubts`)
    scale: ScaleDoubt | None = None
    #: an error periodic in time along one machine direction: its report entry
    #: (:meth:`~volucal.core.loop_periodic.PeriodicInTime.to_json`; empty for anything else)
    periodic: dict[str, object] = field(default_factory=dict)

    @property
    def strongest(self) -> str | None:
        if not self.correlates_with:
            return None
        return max(self.correlates_with, key=lambda k: self.correlates_with[k])


def line_group(readings: Readings, index: int) -> str:
    """ "X", "Y", "Z" for a line whose reading is along one machine axis, "diagonal", "angular"."""
    spec = readings.lines[index].spec
    if spec.quantity == "angular":
        return "angular"
    axis = np.asarray(spec.direction if spec.quantity == "linear" else spec.sensitive, float)
    k = int(np.argmax(np.abs(axis)))
    return AXES[k] if abs(axis[k]) > 0.999 else "diagonal"


def group_rms(identification: Identification) -> dict[str, float]:
    readings = identification.readings
    groups: dict[str, list[FloatArray]] = {}
    for index in range(len(readings.lines)):
        groups.setdefault(line_group(readings, index), []).append(
            identification.residual[readings.line == index]
        )
    return {g: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for g, v in sorted(groups.items())}


#: The verdict of a step that estimated a kept effect's searched quantity again (a cycle's period,
#: a drift's time constant; stage "refine"): the effect stays, placed where it fits better.
ESTIMATED_AGAIN = "estimated again"
