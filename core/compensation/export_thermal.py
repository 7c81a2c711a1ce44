"""Thermal compensation a controller can run: a LinuxCNC HAL snippet, and the model as JSON/CSV.

The model (:class:`volucal.core.thermal_model.ThermalModel`) is

    e [µm] = c0 + Σ_i c_i · (F_i − R_i)^p_i,    F_i = sensor i through a first-order lag τ_i

with e the error channel as measured (``measured − nominal``: a positive spindle drift in Z is a
tool that moved +Z) and temperatures in °C. The compensation is the opposite, ``−e``.

Files written by :func:`export_thermal` (``<name>`` is the HAL prefix, ``thermal-<channel>``):

- ``<name>.hal``: the model in standard LinuxCNC HAL components (``lowpass`` for each lag, with
  ``gain = 1 − exp(−P/τ)`` for the thread period P; ``sum2`` to centre a temperature, for the
  weighted sum and the constant (a chain) and for the compensation in mm; ``mult2`` for a squared
  term; ``timedelay`` and ``not`` hold every lag at its input for the first
  ``load_delay_s`` so that the filters start at the current temperatures, as the model assumes).
  Inputs are HAL signals in °C, one per sensor (``thermal-<sensor>-degc`` unless renamed): the
  user connects each to the pin that reads that sensor. Outputs: the signal ``<name>-error-um``
  (predicted error, µm) and ``<name>-comp-mm`` (compensation, mm, = −error / 1000), to be wired to
  the machine's external offset of the axis (LinuxCNC ``axis.L.eoffset-*``) or to a custom
  kinematics input.
- ``<name>.json``: the model, its uncertainty and validation, the HAL names, and check points.
- ``<name>.csv``: the same model as a table (one row per term, the constant first), and
- ``<name>-eoffset.hal`` (with ``axis``): the compensation wired to LinuxCNC's external offset
  of that axis (``axis.L.eoffset-counts`` through ``sum2`` and ``conv_float_s32``,
  ``eoffset-scale`` the
  resolution, ``eoffset-enable`` set); the INI needs ``[AXIS_L]OFFSET_AV_RATIO``.
- ``<name>-check.csv``: steady-state check points — temperatures held long enough for every lag
  to settle, and the error and compensation the controller must then output — to test any
  implementation of the model against volucal's.

Every file states its units (µm, °C, s) and the sign convention.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..thermal_fit import ThermalFitResult
from ..thermal_model import ThermalModel, ThermalTerm
from ..userror import UserError
from .export_common import write_text

#: LinuxCNC's HAL_NAME_LEN is 47: instance names stay short enough for ".offset" and friends.
MAX_INSTANCE_NAME = 38
SIGN_CONVENTION = (
    "error = measured - nominal along the channel (e.g. a positive Z drift is a tool that moved "
    "+Z relative to the workpiece); compensation = -error"
)
FILTER_TEXT = (
    "F = temperature through a first-order lag: dF/dt = (T - F)/tau, started at F = T; "
    "in discrete time F += (T - F) * (1 - exp(-period/tau)) (LinuxCNC lowpass); tau = 0: F = T"
)


@dataclass(frozen=True)
class ThermalExportOptions:
    """HAL names and timing of an export.

    prefix : instance and signal prefix (default ``thermal-<channel>``).
    thread : the HAL thread the functions are added to; period_s its period (the lowpass gains
        depend on it: re-export for another period).
    sensor_signals : HAL signal (°C) per sensor name; default ``thermal-<sensor>-degc``.
    load_delay_s : the lags follow their inputs exactly for this long after HAL starts.
    axis : also write ``<name>-eoffset.hal``, which applies the compensation as LinuxCNC's
        external offset of this axis (``x``, ``y`` or ``z``; LinuxCNC 2.8 and later): it needs
        ``OFFSET_AV_RATIO`` (e.g. 0.1) in the axis' INI section and is sourced after motion is
        loaded (a later ``[HAL] HALFILE``). None writes no wiring: connect ``<name>-comp-mm``
        yourself.
    count_mm : the external offset's resolution (``eoffset-scale``), mm per count.
    loaded : components the HAL configuration already loads (HAL loads a component once: the
        simulated configurations of LinuxCNC load ``lowpass`` and ``scale``, many machines
        ``not``): for these the snippet has no ``loadrt`` line but a comment giving the names to
        add to the configuration's own ``loadrt`` line.
    """

    prefix: str | None = None
    thread: str = "servo-thread"
    period_s: float = 0.001
    sensor_signals: Mapping[str, str] = field(default_factory=dict)
    load_delay_s: float = 1.0
    axis: str | None = None
    count_mm: float = 1e-5
    loaded: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.axis is not None and self.axis.lower() not in ("x", "y", "z"):
            raise UserError(f"external offset axis {self.axis!r}: use x, y or z")
        if not (self.count_mm > 0 and math.isfinite(self.count_mm)):
            raise UserError("the external offset resolution must be a positive number of mm")
        if not (self.period_s > 0 and math.isfinite(self.period_s)):
            raise UserError("the HAL thread period must be a positive number of seconds")
        if not (self.load_delay_s > 0 and math.isfinite(self.load_delay_s)):
            raise UserError("the start-up load delay must be a positive number of seconds")
        if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_.-]*", self.thread):
            raise UserError(f"HAL thread name {self.thread!r} is not a HAL name")


@dataclass(frozen=True)
class ThermalExport:
    """What :func:`export_thermal` wrote, and the HAL names a test or a user needs."""

    files: tuple[Path, ...]
    prefix: str
    error_signal: str
    comp_signal: str
    input_signals: Mapping[str, str]
    lag_instances: Mapping[tuple[str, float], str]
    load_signal: str


def hal_name(text: str) -> str:
    """A HAL-safe name: lower case, letters, digits and '-' only."""
    name = re.sub(r"[^a-z0-9]+", "-", text.strip().lower()).strip("-")
    return name or "x"


def export_thermal(
    source: ThermalFitResult | ThermalModel,
    out_dir: str | Path,
    options: ThermalExportOptions | None = None,
) -> ThermalExport:
    """Write the HAL snippet, the JSON and CSV tables and the check points (module notes)."""
    options = options or ThermalExportOptions()
    model = source.model if isinstance(source, ThermalFitResult) else source
    if model.unit != "um":
        raise UserError(
            f"{model.channel}: only translation errors (µm) are compensated through "
            "HAL offsets; this channel is in µrad"
        )
    folder = Path(out_dir)
    if folder.exists() and not folder.is_dir():
        raise UserError(f"{folder}: exists and is not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    prefix = hal_name(options.prefix or f"thermal-{model.channel}")[: MAX_INSTANCE_NAME - 12]
    plan = _HalPlan(model, prefix, options)
    files = [
        write_text(folder / f"{prefix}.hal", plan.text()),
        write_text(
            folder / f"{prefix}.json",
            json.dumps(_json(source, model, plan, options), indent=2, ensure_ascii=True) + "\n",
        ),
        write_text(folder / f"{prefix}.csv", _csv(model)),
        write_text(folder / f"{prefix}-check.csv", _check_csv(model, plan)),
    ]
    if options.axis is not None:
        files.append(write_text(folder / f"{prefix}-eoffset.hal", plan.eoffset_text()))
    return ThermalExport(
        files=tuple(files),
        prefix=prefix,
        error_signal=plan.error_signal,
        comp_signal=plan.comp_signal,
        input_signals=dict(plan.inputs),
        lag_instances=dict(plan.lags),
        load_signal=plan.load_signal,
    )


# --------------------------------------------------------------------------------------------
# HAL
# --------------------------------------------------------------------------------------------


class _HalPlan:
    """Instance names, parameters and nets of the HAL snippet for one model."""

    def __init__(self, model: ThermalModel, prefix: str, options: ThermalExportOptions) -> None:
        self.model = model
        self.prefix = prefix
        self.options = options
        self.inputs = {
            s: options.sensor_signals.get(s, f"thermal-{hal_name(s)}-degc") for s in model.sensors
        }
        for sensor, signal in self.inputs.items():
            if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_.-]*", signal):
                raise UserError(f"HAL signal {signal!r} for sensor {sensor!r} is not a HAL name")
        # one lag and one centring node per (sensor, τ); terms share them
        self.nodes: list[tuple[str, float, float]] = []
        for term in model.terms:
            key = (term.sensor, term.tau_s, term.reference_c)
            if key not in self.nodes:
                self.nodes.append(key)
        self.lags = {
            (s, tau): f"{prefix}-lag{k}" for k, (s, tau, _) in enumerate(self.nodes) if tau > 0
        }
        self.centres = {node: f"{prefix}-dt{k}" for k, node in enumerate(self.nodes)}
        self.squares = {k: f"{prefix}-sq{k}" for k, t in enumerate(model.terms) if t.power == 2}
        self.sums = [f"{prefix}-sum{k}" for k in range(max(1, len(model.terms) - 1))]
        self.comp = f"{prefix}-comp"
        # with an axis, the compensation in offset counts (the conversion to s32 and the axis
        # pins are in the -eoffset file, sourced once motion is loaded)
        self.to_counts = [f"{prefix}-tocounts"] if options.axis is not None else []
        self.eoffset_parts = (f"{prefix}-ready", f"{prefix}-gate", f"{prefix}-counts")
        self.start = f"{prefix}-start"
        self.hold = f"{prefix}-hold"
        self.error_signal = f"{prefix}-error-um"
        self.comp_signal = f"{prefix}-comp-mm"
        self.load_signal = f"{prefix}-load"
        longest = max(
            [
                len(n)
                for n in [
                    *self.lags.values(),
                    *self.centres.values(),
                    *self.squares.values(),
                    *self.sums,
                    self.comp,
                    *self.to_counts,
                ]
            ]
        )
        if longest > MAX_INSTANCE_NAME:
            raise UserError(f"HAL prefix {prefix!r} is too long; choose a shorter --hal-prefix")

    def eoffset_text(self) -> str:
        """The wiring of the compensation to the external offset of one axis (pins of motion,
        which must be loaded first; the components are in the main snippet)."""
        o = self.options
        axis = (o.axis or "z").lower()
        ready, gate, counts = self.eoffset_parts
        return "\n".join(
            [
                f"# volucal thermal compensation of '{_ascii(self.model.channel)}' applied as the "
                f"external offset of axis {axis.upper()}",
                f"# Source after {self.prefix}.hal and after motion is loaded (a later [HAL] "
                "HALFILE).",
                f"# The INI needs [AXIS_{axis.upper()}]OFFSET_AV_RATIO (e.g. 0.1): the share of "
                "the axis' velocity",
                "# and acceleration that external offsets may use.",
                f"# Offset = {self.comp_signal} = -predicted error, in counts of "
                f"{_num(o.count_mm)} mm (truncated",
                "# toward zero: within one count). LinuxCNC applies changes of the counts while "
                "the",
                "# offset is enabled and zeroes its register at each machine start, so the counts "
                "are",
                "# held at 0 until the machine is on and homed, then follow the compensation.",
                "",
                f"net {self.prefix}-machine-on motion.motion-enabled => {ready}.in0",
                f"net {self.prefix}-homed motion.is-all-homed => {ready}.in1",
                f"net {self.prefix}-eoffset-ready {ready}.out => {gate}.sel "
                f"axis.{axis}.eoffset-enable",
                f"net {self.prefix}-eoffset-counts {counts}.out => axis.{axis}.eoffset-counts",
                f"setp axis.{axis}.eoffset-scale {_num(o.count_mm)}",
                "",
            ]
        )

    def loadrt(self, component: str, names: list[str]) -> list[str]:
        """The ``loadrt`` line, or for a component the configuration loads already, what to add
        to its own line."""
        if not names:
            return []
        if component in self.options.loaded:
            return [
                f"# {component} is loaded by your configuration: add to its 'loadrt "
                f"{component}' line the names {','.join(names)}"
            ]
        return [f"loadrt {component} names={','.join(names)}"]

    def gain(self, tau_s: float) -> float:
        return -math.expm1(-self.options.period_s / tau_s)

    def term_signal(self, index: int, term: ThermalTerm) -> str:
        node = self.centres[(term.sensor, term.tau_s, term.reference_c)]
        if term.power == 2:
            return f"{self.squares[index]}-out"
        return f"{node}-out"

    def text(self) -> str:
        m = self.model
        o = self.options
        lines = [
            f"# volucal thermal compensation of '{_ascii(m.channel)}'",
            f"# Sign: {SIGN_CONVENTION}.",
            "# Units: temperatures degC, error um, compensation mm, time constants s.",
            f"# Model: {_ascii(m.formula(8))}",
            f"# {FILTER_TEXT}.",
            f"# The lowpass gains are for a thread period of {o.period_s:g} s ('{o.thread}');",
            "# export again with the period of your thread if it differs.",
            "# Inputs (degC): connect each signal to the pin that reads the sensor, e.g.",
            "#   net <signal> <= <your temperature pin>",
        ]
        lines += [f"#   sensor {_ascii(s)}: signal {sig}" for s, sig in self.inputs.items()]
        lines += [
            f"# Outputs: {self.error_signal} (predicted error, um) and {self.comp_signal}",
            "#   (compensation = -error/1000, mm; wire it to the axis' external offset).",
            f"# For the first {o.load_delay_s:g} s the lags follow their inputs ({self.load_signal}"
            " is TRUE),",
            "# so the filters start at the current temperatures, as the model assumes.",
            "# HAL loads a component once: if your configuration already loads one of these",
            "# components, export again naming it (volucal thermal --hal-loaded lowpass,...):",
            "# its names are then listed here for your own loadrt line.",
            "",
        ]
        loads: list[tuple[str, list[str]]] = [
            ("timedelay", [self.start]),
            ("not", [self.hold]),
            ("lowpass", list(self.lags.values())),
            ("mult2", list(self.squares.values())),
            ("sum2", [*self.centres.values(), *self.sums, self.comp, *self.to_counts]),
        ]
        if self.to_counts:
            ready, gate, counts = self.eoffset_parts
            loads += [("and2", [ready]), ("mux2", [gate]), ("conv_float_s32", [counts])]
        for component, names in loads:
            lines += self.loadrt(component, names)
        lines.append("")
        order = [
            self.start,
            self.hold,
            *self.lags.values(),
            *self.centres.values(),
            *self.squares.values(),
            *self.sums,
            self.comp,
            *self.to_counts,
        ]
        if self.to_counts:
            order += list(self.eoffset_parts)
        lines += [f"addf {name} {o.thread}" for name in order]
        lines += [
            "",
            f"setp {self.start}.in 1",
            f"setp {self.start}.on-delay {_num(o.load_delay_s)}",
            f"setp {self.start}.off-delay 0",
            f"net {self.prefix}-started {self.start}.out => {self.hold}.in",
        ]
        lag_loads = [f"{name}.load" for name in self.lags.values()]
        lines.append(
            f"net {self.load_signal} {self.hold}.out"
            + (f" => {' '.join(lag_loads)}" if lag_loads else "")
        )
        lines.append("")
        for sensor, tau, reference in self.nodes:
            centre = self.centres[(sensor, tau, reference)]
            signal = self.inputs[sensor]
            lines.append(
                f"# {_ascii(sensor)}" + (f", lag tau = {_num(tau)} s" if tau else ", static")
            )
            if tau > 0:
                lag = self.lags[(sensor, tau)]
                lines += [
                    f"setp {lag}.gain {_num(self.gain(tau))}",
                    f"net {signal} => {lag}.in",
                    f"net {lag}-out {lag}.out => {centre}.in0",
                ]
            else:
                lines.append(f"net {signal} => {centre}.in0")
            lines += [
                f"setp {centre}.gain0 1",
                f"setp {centre}.gain1 0",
                f"setp {centre}.offset {_num(-reference)}",
                f"net {centre}-out {centre}.out"
                + "".join(
                    f" => {self.squares[k]}.in0 {self.squares[k]}.in1"
                    for k, t in enumerate(m.terms)
                    if t.power == 2
                    and (t.sensor, t.tau_s, t.reference_c) == (sensor, tau, reference)
                ),
            ]
        for square in self.squares.values():
            lines.append(f"net {square}-out {square}.out")
        lines.append("")
        lines.append(f"# weighted sum: c0 = {_num(m.intercept)} um")
        terms = list(enumerate(m.terms))
        coefficients = [float(c) for c in m.coefficients]
        first = self.sums[0]
        if terms:
            index, term = terms[0]
            lines += [
                f"setp {first}.gain0 {_num(coefficients[0])}",
                f"net {self.term_signal(index, term)} => {first}.in0",
            ]
        else:
            lines.append(f"setp {first}.gain0 0")
        if len(terms) > 1:
            index, term = terms[1]
            lines += [
                f"setp {first}.gain1 {_num(coefficients[1])}",
                f"net {self.term_signal(index, term)} => {first}.in1",
            ]
        else:
            lines.append(f"setp {first}.gain1 0")
        lines.append(f"setp {first}.offset {_num(m.intercept)}")
        previous = first
        for position, (index, term) in enumerate(terms[2:], start=2):
            current = self.sums[position - 1]
            lines += [
                f"net {previous}-out {previous}.out => {current}.in0",
                f"setp {current}.gain0 1",
                f"setp {current}.gain1 {_num(coefficients[position])}",
                f"setp {current}.offset 0",
                f"net {self.term_signal(index, term)} => {current}.in1",
            ]
            previous = current
        lines += [
            f"net {self.error_signal} {previous}.out => {self.comp}.in0",
            f"setp {self.comp}.gain0 -0.001",
            f"setp {self.comp}.gain1 0",
            f"setp {self.comp}.offset 0",
            f"net {self.comp_signal} {self.comp}.out",
        ]
        if self.to_counts:
            to_counts = self.to_counts[0]
            ready, gate, counts = self.eoffset_parts
            lines += [
                f"# the compensation in counts of {_num(o.count_mm)} mm for the external offset "
                f"of axis {o.axis}, 0 until {ready} (machine on and homed: "
                f"{self.prefix}-eoffset.hal) is TRUE",
                f"net {self.comp_signal} => {to_counts}.in0",
                f"setp {to_counts}.gain0 {_num(1.0 / o.count_mm)}",
                f"setp {to_counts}.gain1 0",
                f"setp {to_counts}.offset 0",
                f"net {self.prefix}-counts-f {to_counts}.out => {gate}.in1",
                f"setp {gate}.in0 0",
                f"net {self.prefix}-counts-gated {gate}.out => {counts}.in",
                f"setp {counts}.clamp 1",
            ]
        lines.append("")
        return "\n".join(lines)


def _num(value: float) -> str:
    """The shortest text that reads back as the same double (HAL parses with strtod)."""
    text = repr(float(value))
    return "0" if text in ("0.0", "-0.0") else text


def _ascii(text: str) -> str:
    replaced = (
        text.replace("µ", "u")
        .replace("°", "deg")
        .replace("τ", "tau")
        .replace("−", "-")
        .replace("·", "*")
        .replace("²", "^2")
    )
    return replaced.encode("ascii", "replace").decode("ascii")


# --------------------------------------------------------------------------------------------
# JSON and CSV
# --------------------------------------------------------------------------------------------


def check_points(model: ThermalModel) -> list[dict[str, Any]]:
    """Steady-state states (every sensor held at a temperature) and the error there: at the
    references, and each sensor in turn 1 °C and 5 °C above its reference."""
    references: dict[str, float] = {}
    for term in model.terms:
        references.setdefault(term.sensor, term.reference_c)
    states = [dict(references)]
    for sensor in references:
        for step in (1.0, 5.0):
            state = dict(references)
            state[sensor] = references[sensor] + step
            states.append(state)
    out = []
    for state in states:
        error = model.predict_steady(state)
        out.append(
            {"temperatures_degC": state, "error_um": error, "compensation_mm": -error / 1000.0}
        )
    return out


def _json(
    source: ThermalFitResult | ThermalModel,
    model: ThermalModel,
    plan: _HalPlan,
    options: ThermalExportOptions,
) -> dict[str, Any]:
    from volucal import __version__

    data: dict[str, Any] = {
        "format": "volucal thermal compensation model",
        "format_version": 1,
        "creator": f"volucal {__version__}",
        "channel": model.channel,
        "sign_convention": SIGN_CONVENTION,
        "units": {"error": "um", "temperature": "degC", "time_constant": "s", "compensation": "mm"},
        "formula": _ascii(model.formula(10)),
        "filter": FILTER_TEXT,
        "intercept_um": model.intercept,
        "intercept_std_um": model.intercept_std,
        "terms": [
            {
                "sensor": t.sensor,
                "tau_s": t.tau_s,
                "power": t.power,
                "reference_degC": t.reference_c,
                "coefficient": float(c),
                "coefficient_std": float(s),
                "coefficient_unit": _ascii(t.unit(model.unit)),
            }
            for t, c, s in zip(model.terms, model.coefficients, model.coefficient_std, strict=True)
        ],
        "covariance": model.covariance.tolist(),
        "sensors": list(model.sensors),
        "hal": {
            "file": f"{plan.prefix}.hal",
            "thread": options.thread,
            "period_s": options.period_s,
            "inputs_degC": plan.inputs,
            "error_signal_um": plan.error_signal,
            "compensation_signal_mm": plan.comp_signal,
            "load_signal": plan.load_signal,
            "lowpass_gains": {f"{s} tau {tau:g} s": plan.gain(tau) for (s, tau) in plan.lags},
        },
        "check_points": check_points(model),
    }
    if isinstance(source, ThermalFitResult):
        u = source.unit
        data["validation"] = {
            "measurement": source.measurement,
            "train_samples": source.train_samples,
            "test_samples": source.test_samples,
            "cross_validation": source.cv_description,
            "cv_rms_um": source.cv_rms,
            "train_rms_um": source.train_rms,
            "test_rms_um": source.test_rms,
            "uncompensated_test_rms_um": source.uncompensated_test_rms,
            "unit": u,
        }
    return data


def _csv(model: ThermalModel) -> str:
    lines = [
        f"# volucal thermal compensation model of '{_ascii(model.channel)}'",
        f"# {SIGN_CONVENTION}",
        "# error [um] = intercept + sum over terms of coefficient * (F - reference_degC)^power",
        f"# {FILTER_TEXT}",
        "# coefficient_std: standard uncertainty (Newey-West, autocorrelation-consistent)",
        "term,sensor,tau_s,power,reference_degC,coefficient,coefficient_std,coefficient_unit",
        f"intercept,,,,,{_num(model.intercept)},{_num(model.intercept_std)},um",
    ]
    for k, (term, c, s) in enumerate(
        zip(model.terms, model.coefficients, model.coefficient_std, strict=True), start=1
    ):
        lines.append(
            ",".join(
                [
                    str(k),
                    _csv_text(term.sensor),
                    _num(term.tau_s),
                    str(term.power),
                    _num(term.reference_c),
                    _num(c),
                    _num(s),
                    _ascii(term.unit(model.unit)),
                ]
            )
        )
    return "\n".join(lines) + "\n"


def _check_csv(model: ThermalModel, plan: _HalPlan) -> str:
    points = check_points(model)
    sensors = list(model.sensors)
    lines = [
        f"# steady-state check points of the model of '{_ascii(model.channel)}': every sensor "
        "held at these temperatures (degC)",
        "# long enough for the lags to settle; the controller must then output error_um and "
        "compensation_mm",
        f"# {SIGN_CONVENTION}",
        ",".join([*(_csv_text(f"{s}_degC") for s in sensors), "error_um", "compensation_mm"]),
    ]
    for point in points:
        cells = [_num(point["temperatures_degC"][s]) for s in sensors]
        cells += [_num(point["error_um"]), _num(point["compensation_mm"])]
        lines.append(",".join(cells))
    return "\n".join(lines) + "\n"


def _csv_text(text: str) -> str:
    plain = _ascii(text)
    return f'"{plain}"' if re.search(r'[,"\s]', plain) else plain


__all__ = ["ThermalExport", "ThermalExportOptions", "check_points", "export_thermal", "hal_name"]
