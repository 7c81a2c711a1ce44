"""Thermal measurements: error channels and temperature channels sampled over time.

A thermal test (ISO 230-3) records, while a machine warms up, runs or cools down, one or more
*error channels* — the drift of the spindle nose in X, Y or Z, a tilt, or the positioning error at a
few targets — together with any number of *temperature channels*. Here such a record is one
:class:`ThermalMeasurement`: a common time base in seconds since the first sample, each error
channel in µm (translations) or µrad (rotations) and each temperature in °C, converted once at
import from the units the file declares.

Sign: an error channel holds ``measured − nominal`` as the file gives it (after the channel's
optional ``sign``): a positive spindle drift in Z is a tool that moved +Z relative to the workpiece.
A compensation applies the opposite (``compensation = −predicted error``).

The checks a model relies on are made here, once: a time base that increases strictly, finite
values in every channel (the reader names the file, column and row of a gap or a NaN), and
sensors that do not move at all (a stuck sensor: constant over the whole record) are excluded with
a warning rather than fitted — a constant column carries no information and would only make the
fit singular.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .userror import UserError

FloatArray = NDArray[np.float64]

#: Error channel units after import: translations in µm, rotations in µrad.
ERROR_UNITS = ("um", "urad")
UNIT_SYMBOL = {"um": "µm", "urad": "µrad"}
#: A temperature channel whose whole record spans no more than this is stuck (°C). Real sensors
#: read with some noise; a channel that repeats one value for the whole test is not reading.
STUCK_SPAN_C = 1e-9
#: A sample interval this many times the median interval is a gap in the record (a warning: the
#: temperatures between are unknown to a dynamic model).
GAP_FACTOR = 10.0


@dataclass(frozen=True, eq=False)
class ErrorChannel:
    """One measured error over time (``values`` in ``unit``: µm or µrad, measured − nominal)."""

    name: str
    unit: str
    values: FloatArray
    #: the unit the file gave (``"mm"``, ``"um"``, ``"arcsec"``…), for the record
    raw_unit: str = ""
    sign: int = 1

    @property
    def symbol(self) -> str:
        return UNIT_SYMBOL[self.unit]


@dataclass(frozen=True, eq=False)
class TemperatureChannel:
    """One temperature sensor over time, °C."""

    name: str
    values_c: FloatArray


@dataclass(frozen=True)
class ExcludedSensor:
    """A temperature channel that is not used, and why (shown to the user as a warning)."""

    name: str
    reason: str


@dataclass(frozen=True, eq=False)
class ThermalMeasurement:
    """A thermal test: error and temperature channels on one time base.

    ``time_s`` starts at 0 and increases strictly; ``start_time`` is the POSIX time of the first
    sample when the file gives one. ``temperatures`` holds the usable sensors only; ``excluded``
    the ones left out (stuck sensors) with the reason.
    """

    name: str
    time_s: FloatArray
    errors: tuple[ErrorChannel, ...]
    temperatures: tuple[TemperatureChannel, ...]
    excluded: tuple[ExcludedSensor, ...] = ()
    warnings: tuple[str, ...] = ()
    time_source: str = ""
    start_time: float | None = None
    source: Path | None = None
    source_bytes: bytes = field(default=b"", repr=False)

    def __post_init__(self) -> None:
        where = self.source or self.name
        time = np.asarray(self.time_s, dtype=float)
        if time.ndim != 1 or time.size < 2:
            raise UserError(f"{where}: a thermal record needs at least two samples")
        bad = np.flatnonzero(~np.isfinite(time))
        if bad.size:
            raise UserError(f"{where}: time of sample {bad[0] + 1} is not a number")
        steps = np.diff(time)
        back = np.flatnonzero(steps <= 0)
        if back.size:
            k = int(back[0]) + 1
            raise UserError(
                f"{where}: time does not increase at sample {k + 1} ({time[k - 1]:g} s, then "
                f"{time[k]:g} s); sort the record by time or check the time column"
            )
        if not self.errors:
            raise UserError(f"{where}: no error channel; name the column(s) that hold the error")
        names = [c.name for c in self.errors] + [c.name for c in self.temperatures]
        duplicate = {n for n in names if names.count(n) > 1}
        if duplicate:
            raise UserError(f"{where}: channel name(s) used twice: {', '.join(sorted(duplicate))}")
        for channel in self.errors:
            if channel.unit not in ERROR_UNITS:
                raise UserError(
                    f"{where}: error channel {channel.name!r} has unit "
                    f"{channel.unit!r}; volucal keeps errors in µm or µrad"
                )
            _check_series(where, channel.name, channel.values, time.size)
        for temperature in self.temperatures:
            _check_series(where, temperature.name, temperature.values_c, time.size)
        object.__setattr__(self, "time_s", time)

    @property
    def samples(self) -> int:
        return int(self.time_s.size)

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    @property
    def sample_interval_s(self) -> float:
        """The median interval between samples."""
        return float(np.median(np.diff(self.time_s)))

    @property
    def sensor_names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.temperatures)

    def error(self, name: str | None = None) -> ErrorChannel:
        """The error channel ``name`` (the only one when None)."""
        if name is None:
            if len(self.errors) > 1:
                raise UserError(
                    f"{self.name}: several error channels "
                    f"({', '.join(c.name for c in self.errors)}); name one"
                )
            return self.errors[0]
        for channel in self.errors:
            if channel.name == name:
                return channel
        raise UserError(
            f"{self.name}: no error channel {name!r}; the record has "
            f"{', '.join(repr(c.name) for c in self.errors)}"
        )

    def temperature_map(self) -> dict[str, FloatArray]:
        """Sensor name → values in °C (usable sensors only)."""
        return {t.name: t.values_c for t in self.temperatures}

    def temperature_matrix(self, names: Sequence[str] | None = None) -> FloatArray:
        """(samples, sensors) in °C, columns in the order of ``names`` (all usable sensors when
        None)."""
        table = self.temperature_map()
        chosen = list(table) if names is None else list(names)
        missing = [n for n in chosen if n not in table]
        if missing:
            raise UserError(
                f"{self.name}: no usable temperature channel {', '.join(repr(n) for n in missing)}"
            )
        if not chosen:
            return np.empty((self.samples, 0))
        return np.column_stack([table[n] for n in chosen])


def _check_series(where: object, name: str, values: FloatArray, count: int) -> None:
    array = np.asarray(values, dtype=float)
    if array.shape != (count,):
        raise UserError(f"{where}: channel {name!r} has {array.size} values for {count} samples")
    bad = np.flatnonzero(~np.isfinite(array))
    if bad.size:
        raise UserError(
            f"{where}: channel {name!r} has no value at sample {bad[0] + 1} (NaN or "
            "a gap); fill the gap or leave the channel out"
        )


def split_stuck_sensors(
    temperatures: Sequence[TemperatureChannel], span_c: float = STUCK_SPAN_C
) -> tuple[tuple[TemperatureChannel, ...], tuple[ExcludedSensor, ...]]:
    """Usable sensors and the stuck ones (constant over the whole record), in input order."""
    usable: list[TemperatureChannel] = []
    excluded: list[ExcludedSensor] = []
    for channel in temperatures:
        values = np.asarray(channel.values_c, dtype=float)
        span = float(np.ptp(values)) if values.size else 0.0
        if span <= span_c:
            excluded.append(
                ExcludedSensor(
                    channel.name,
                    f"temperature {channel.name!r} is stuck at {values[0]:g} °C for the whole "
                    "record (a sensor that does not read); it is left out of the model",
                )
            )
        else:
            usable.append(channel)
    return tuple(usable), tuple(excluded)


def time_gaps(time_s: FloatArray, factor: float = GAP_FACTOR) -> list[str]:
    """Warnings for intervals much longer than the usual one (the record stopped and resumed)."""
    steps = np.diff(time_s)
    usual = float(np.median(steps))
    out = []
    for k in np.flatnonzero(steps > factor * usual):
        out.append(
            f"a gap of {steps[k]:g} s between samples {k + 1} and {k + 2} (the usual interval is "
            f"{usual:g} s): the temperatures in between are unknown to a dynamic model"
        )
    return out


def thermal_measurement(
    name: str,
    time_s: Sequence[float] | FloatArray,
    errors: Mapping[str, Sequence[float] | FloatArray],
    temperatures_c: Mapping[str, Sequence[float] | FloatArray],
    *,
    error_unit: str = "um",
    source: Path | None = None,
) -> ThermalMeasurement:
    """A measurement from arrays (already in µm or µrad and °C); stuck sensors are excluded with
    a warning, as on import. For tests, simulations and scripts."""
    time = np.asarray(time_s, dtype=float)
    channels = tuple(
        ErrorChannel(n, error_unit, np.asarray(v, dtype=float), error_unit)
        for n, v in errors.items()
    )
    temps = tuple(
        TemperatureChannel(n, np.asarray(v, dtype=float)) for n, v in temperatures_c.items()
    )
    usable, excluded = split_stuck_sensors(temps)
    warnings = tuple(e.reason for e in excluded) + tuple(time_gaps(time)) if time.size > 1 else ()
    return ThermalMeasurement(
        name=name,
        time_s=time - time[0] if time.size else time,
        errors=channels,
        temperatures=usable,
        excluded=excluded,
        warnings=warnings,
        time_source="given",
        source=source,
    )
