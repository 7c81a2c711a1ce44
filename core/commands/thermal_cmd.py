"""``volucal thermal FILE...``: model thermal errors from temperature sensors, validate, export.

FILE is a thermal test table (CSV, semicolon, tab or whitespace separated; one row per sample):
one or more error columns (spindle drift, tilt, the positioning error at a target…) and any number
of temperature columns. Units are declared, on the command line or in the header
(``"drift [um]"``, ``"T1 (°C)"``); a missing unit is an error that asks for one.

For each error channel the command chooses a model on the first ``--train-fraction`` of the
record — the sensors (at most ``--max-sensors``), first-order lags where the static model leaves
lag, and squared terms, all by cross-validation that respects time (rolling origin, never random
rows) — fits it, and reports its coefficients with their uncertainty and its error on the rest of
the record, held out, beside the error left uncompensated, a static fit on all sensors and the best
single sensor. ``--export DIR`` writes the model for LinuxCNC (a HAL snippet) and as JSON/CSV
tables; ``--project P.h5`` stores the record and its models under ``/thermal/<name>``.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path
from typing import Any

from ..compensation.export_thermal import ThermalExportOptions, export_thermal
from ..io.thermal_table import ErrorColumn, ThermalTableFormat, read_thermal_table
from ..io.units import TIME_FACTOR, normalise_unit
from ..thermal import ThermalMeasurement
from ..thermal_fit import ThermalFitOptions, ThermalFitRequest, ThermalFitResult, fit_thermal
from ..userror import UserError

_DURATION = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*([A-Za-zµ]+)\s*$")


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "thermal",
        help="thermal error model from temperature sensors: choose, validate, export",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    parser.add_argument("files", nargs="+", type=Path, metavar="FILE")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    read = parser.add_argument_group("reading the table")
    read.add_argument(
        "--error",
        action="append",
        metavar="COLUMN[=UNIT]",
        required=True,
        help="an error column and its unit unless the header gives it, e.g. "
        '"delta L=um" (um, mm, nm, urad, arcsec…); repeat for several channels',
    )
    read.add_argument(
        "--sign",
        type=int,
        choices=(1, -1),
        default=1,
        help="+1 (default): the error columns hold measured − nominal; -1 flips them",
    )
    read.add_argument(
        "--temperatures",
        metavar="COLUMNS",
        help="comma-separated temperature columns (names or 1-based numbers); "
        "default: every column that is not time or an error",
    )
    read.add_argument(
        "--temperature-unit",
        metavar="UNIT",
        help="unit of the temperature columns unless the header gives it: C, K or F",
    )
    read.add_argument(
        "--time", metavar="COLUMN", help="the time column (default: a column named time, if any)"
    )
    read.add_argument(
        "--time-unit",
        metavar="UNIT",
        help="unit of a numeric time column unless the header gives it: s, min, h, ms",
    )
    read.add_argument(
        "--interval",
        metavar="DURATION",
        help="time between rows when the table has no time column, with its unit, e.g. 60s or 1min",
    )
    model = parser.add_argument_group("choosing the model")
    model.add_argument(
        "--channel",
        action="append",
        metavar="NAME",
        help="model only this error channel (repeatable; default: all)",
    )
    model.add_argument(
        "--train-fraction",
        type=float,
        default=0.5,
        metavar="F",
        help="the model is chosen and fitted on the first F of the record and "
        "tested on the rest (default %(default)s; 1 uses all, with no held-out "
        "test)",
    )
    model.add_argument(
        "--max-sensors",
        type=int,
        default=6,
        metavar="N",
        help="at most N sensors in the model (default %(default)s)",
    )
    model.add_argument(
        "--sensors",
        metavar="NAMES",
        help="comma-separated sensors the model may use (default: all usable)",
    )
    model.add_argument(
        "--blocks",
        type=int,
        default=10,
        metavar="N",
        help="blocks of the rolling-origin cross-validation (default %(default)s)",
    )
    model.add_argument("--static", action="store_true", help="no first-order lags (a static model)")
    model.add_argument("--linear", action="store_true", help="no squared terms")
    out = parser.add_argument_group("output")
    out.add_argument(
        "--export",
        type=Path,
        metavar="DIR",
        help="write the model for LinuxCNC (.hal) and as .json/.csv tables here",
    )
    out.add_argument(
        "--hal-period",
        metavar="DURATION",
        default="1ms",
        help="period of the HAL thread the snippet runs in (default %(default)s)",
    )
    out.add_argument(
        "--hal-thread",
        default="servo-thread",
        help="HAL thread the snippet adds its functions to (default %(default)s)",
    )
    out.add_argument(
        "--hal-axis",
        choices=("x", "y", "z"),
        help="also write <name>-eoffset.hal, which applies the compensation as "
        "LinuxCNC's external offset of this axis (needs [AXIS_L]OFFSET_AV_RATIO)",
    )
    out.add_argument(
        "--hal-loaded",
        metavar="COMPONENTS",
        help="HAL components your configuration loads already (e.g. "
        "lowpass,scale,not): the snippet lists its names for your own loadrt line "
        "instead of loading them again",
    )
    out.add_argument(
        "--project",
        type=Path,
        metavar="P.h5",
        help="store the record and its models in this project (created if missing) "
        "under /thermal/<name>",
    )
    out.add_argument("--name", help="name in the project (default: the file's stem)")
    parser.set_defaults(handler=run)


def parse_duration(text: str, what: str) -> float:
    """``"60s"``, ``"1 min"``, ``"0.5h"`` → seconds; a bare number is an error asking for a
    unit."""
    match = _DURATION.match(text)
    if not match:
        raise UserError(f"{what} {text!r}: give a number with its unit, e.g. 60s, 1min, 0.5h, 1ms")
    unit = normalise_unit(match.group(2))
    if unit not in TIME_FACTOR:
        raise UserError(
            f"{what} {text!r}: unit {match.group(2)!r} is not one of {', '.join(TIME_FACTOR)}"
        )
    return float(match.group(1)) * TIME_FACTOR[unit]


def table_format(args: argparse.Namespace) -> ThermalTableFormat:
    errors = []
    for item in args.error:
        column, equals, unit = item.rpartition("=") if "=" in item else (item, "", "")
        name = column.strip()
        errors.append(
            ErrorColumn(
                int(name) if name.isdigit() else name,
                unit.strip() or None if equals else None,
                sign=args.sign,
            )
        )
    temperatures = None
    if args.temperatures:
        temperatures = tuple(
            int(t) if t.strip().isdigit() else t.strip()
            for t in args.temperatures.split(",")
            if t.strip()
        )
    interval = parse_duration(args.interval, "--interval") if args.interval else None
    time_column = int(args.time) if args.time and args.time.isdigit() else args.time
    try:
        return ThermalTableFormat(
            errors=tuple(errors),
            temperatures=temperatures,
            temperature_unit=args.temperature_unit,
            time=time_column,
            time_unit=args.time_unit,
            sample_interval_s=interval,
        )
    except ValueError as exc:
        raise UserError(str(exc)) from None


def fit_options(args: argparse.Namespace) -> ThermalFitOptions:
    sensors = None
    if args.sensors:
        sensors = tuple(s.strip() for s in args.sensors.split(",") if s.strip())
    return ThermalFitOptions(
        train_fraction=args.train_fraction,
        max_sensors=args.max_sensors,
        blocks=args.blocks,
        dynamic=not args.static,
        quadratic=not args.linear,
        sensors=sensors,
    )


def run(args: argparse.Namespace) -> int:
    fmt = table_format(args)
    options = fit_options(args)
    export_options = None
    if args.export is not None:
        loaded = tuple(c.strip() for c in (args.hal_loaded or "").split(",") if c.strip())
        export_options = ThermalExportOptions(
            thread=args.hal_thread,
            period_s=parse_duration(args.hal_period, "--hal-period"),
            axis=args.hal_axis,
            loaded=loaded,
        )
    if args.name and len(args.files) > 1:
        raise UserError("--name names one record: give one FILE with it")
    entries = []
    project = None
    if args.project is not None:
        from ..project import Project

        project = Project.open(args.project) if args.project.exists() else Project.create()
    for path in args.files:
        measurement = read_thermal_table(path, fmt, name=args.name)
        channels = args.channel or [c.name for c in measurement.errors]
        results = [
            fit_thermal(ThermalFitRequest(measurement, channel, options)) for channel in channels
        ]
        exported: list[str] = []
        if export_options is not None:
            for result in results:
                if result.unit != "um":
                    continue
                folder = args.export if len(args.files) == 1 else args.export / measurement.name
                written = export_thermal(result, folder, export_options)
                exported += [str(f) for f in written.files]
        stored = None
        if project is not None:
            from ..thermal_store import store_thermal

            stored = store_thermal(project, measurement.name, measurement, results)
        entries.append((path, measurement, results, exported, stored))
    if project is not None:
        project.save(args.project)
    if args.json:
        from ..thermal_store import jsonable

        content = {"files": [_entry_json(*entry) for entry in entries]}
        json.dump(jsonable(content), sys.stdout, indent=2, ensure_ascii=False)
        print()
        return 0
    for k, entry in enumerate(entries):
        if k:
            print()
        print(render(*entry))
    return 0


def _entry_json(
    path: Path,
    measurement: ThermalMeasurement,
    results: list[ThermalFitResult],
    exported: list[str],
    stored: str | None,
) -> dict[str, Any]:
    return {
        "file": str(path),
        "name": measurement.name,
        "samples": measurement.samples,
        "duration_s": measurement.duration_s,
        "sample_interval_s": measurement.sample_interval_s,
        "time_source": measurement.time_source,
        "error_channels": [
            {"name": c.name, "unit": c.unit, "raw_unit": c.raw_unit, "sign": c.sign}
            for c in measurement.errors
        ],
        "temperature_unit": "degC",
        "sensors": list(measurement.sensor_names),
        "excluded": [{"name": e.name, "reason": e.reason} for e in measurement.excluded],
        "warnings": list(measurement.warnings),
        "channels": [r.to_json() for r in results],
        "exported": exported,
        "stored_as": stored,
    }


def _hours(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 7200 else f"{seconds / 60:.0f} min"


def _f(value: float | None) -> str:
    return (
        "—"
        if value is None or (isinstance(value, float) and math.isnan(value))
        else (f"{value:.3f}")
    )


def render(
    path: Path,
    measurement: ThermalMeasurement,
    results: list[ThermalFitResult],
    exported: list[str],
    stored: str | None,
) -> str:
    """What the command prints for one file."""
    m = measurement
    out = [
        f"{path}: {m.samples} samples over {_hours(m.duration_s)} ({m.time_source}); "
        f"{len(m.errors)} error channel(s), {len(m.temperatures)} temperature sensor(s)"
        + (f", {len(m.excluded)} excluded" if m.excluded else ""),
    ]
    out += [f"  warning: {w}" for w in m.warnings]
    for r in results:
        sym = r.symbol
        out.append("")
        split = (
            f"chosen and fitted on the first {100 * r.options.train_fraction:g} % "
            f"({r.train_samples} samples, {_hours(r.split_time_s)}), tested on the "
            f"{r.test_samples} samples after"
            if r.test_samples
            else f"chosen and fitted on all {r.train_samples} samples (no held-out test)"
        )
        out.append(f"{r.channel} ({sym}): {split}")
        kind = "dynamic (first-order lags)" if r.model.dynamic else "static"
        out.append(
            f"  model: {len(r.model.sensors)} sensor(s) ({', '.join(r.model.sensors)}), {kind}"
        )
        out.append(f"    {r.model.formula()}")
        out.append(f"    {'term':<28}{'coefficient':>13}{'std':>10}  unit")
        out.append(
            f"    {'constant':<28}{r.model.intercept:13.4f}{r.model.intercept_std:10.4f}  {sym}"
        )
        for term, c, s in zip(
            r.model.terms, r.model.coefficients, r.model.coefficient_std, strict=True
        ):
            out.append(
                f"    {term.label() + f' − {term.reference_c:.2f} °C':<28}{c:13.4f}"
                f"{s:10.4f}  {term.unit(r.unit)}"
            )
        out.append("  choice (" + r.cv_description.split(":")[0] + "):")
        out += [f"    {d}" for d in r.decisions]
        out.append(f"  RMS error, {sym}:{'train':>25}{'CV':>9}{'test':>9}")
        for b in r.baselines:
            label = (
                b.name
                if b.name != "best single sensor by cross-validation"
                else (f"best single sensor ({b.sensors[0]})")
            )
            if b.name.startswith("all sensors"):
                label = f"all {len(b.sensors)} sensors, static"
            out.append(f"    {label:<30}{_f(b.train_rms):>9}{_f(b.cv_rms):>9}{_f(b.test_rms):>9}")
        out.append(
            f"    {'volucal model':<30}{_f(r.train_rms):>9}{_f(r.cv_rms):>9}{_f(r.test_rms):>9}"
        )
        if r.outliers:
            out.append(f"  {len(r.outliers)} sample(s) leave the smooth trend (flagged, kept):")
            out += [f"    {f.reason}" for f in r.outliers]
        else:
            out.append("  no sample leaves the smooth trend (outlier screen)")
        out.append(f"  sign: {r.channel} = measured − nominal; compensation = −prediction")
        out.append(f"  chosen and validated in {r.elapsed_s:.2f} s")
    if exported:
        out.append("")
        out.append("exported: " + ", ".join(exported))
    if stored:
        out.append(f"stored as {stored}")
    return "\n".join(out)
