"""What each controller accepts: one table per format, checked before anything is written.

Every export is checked against its format's limits (:data:`LIMITS`) — points per table, the
highest point count ``--max-points`` may claim, the value range of the file's numbers, node
positions (finite, strictly increasing as written, equidistant where the format needs it) and the
controller's names for the axes. Each limit carries its source; ``confirmed=False`` marks a limit
that volucal assumes but could not confirm in published documentation (docs/compensation.md
lists them). Plausibility (a correction larger than a machine needs) is separate:
:mod:`.plausibility`.

Sizes asked for by arguments are checked here too, before anything is allocated: a volumetric
grid of at most :data:`MAX_GRID_POINTS` nodes and tables of at most :data:`MAX_TABLE_NODES`
nodes per axis.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..names import check_name, safe_file_name
from ..userror import UserError

#: Most nodes of a volumetric grid volucal computes: about 1 KB of memory per node while the
#: grid and its inverse are computed (0.26 GB measured at 265,000 nodes), and the verification
#: takes the cell centres too.
MAX_GRID_POINTS = 500_000
#: Most nodes of one axis table (no controller takes more than a few thousand).
MAX_TABLE_NODES = 100_000


class TableLimitError(UserError):
    """A table does not fit the controller's limits; the message says how to make it fit."""


@dataclass(frozen=True)
class Limit:
    """A number from a controller's documentation, with where it comes from."""

    value: float
    source: str
    confirmed: bool = True


@dataclass(frozen=True)
class AxisNames:
    """What a controller calls an axis: a pattern, in words, and where that comes from."""

    pattern: str
    description: str
    source: str
    low: int | None = None  # numbers: the range allowed
    high: int | None = None
    file_suffix: str | None = None  # the name becomes the file name <name><suffix>


@dataclass(frozen=True)
class FormatLimits:
    """The limits of one export format (module notes)."""

    controller: str
    points: Limit | None  # points per table the controller takes by default
    points_ceiling: Limit | None  # most ``--max-points`` may claim; None: configurable
    value_range: tuple[float, float] | None  # the file's numbers, in ``value_unit``
    value_unit: str
    value_source: str
    equidistant: bool
    axis_names: AxisNames | None
    position_decimals: int | None  # positions as written, for the strictly-increasing check


LIMITS: Mapping[str, FormatLimits] = {
    "linuxcnc": FormatLimits(
        controller="a LinuxCNC COMP_FILE",
        points=Limit(
            256,
            "LinuxCNC motion, EMCMOT_COMP_SIZE = 256 (src/emc/motion/motion.h); "
            "more entries are refused ('too many compensation entries')",
        ),
        points_ceiling=Limit(256, "compiled into LinuxCNC's motion module"),
        value_range=None,
        value_unit="mm",
        value_source="no limit documented; motion stores the offsets as single-precision floats",
        equidistant=False,
        axis_names=AxisNames(
            r"\d+",
            "a joint number from 0 to 15 ([JOINT_n])",
            "EMCMOT_MAX_JOINTS = 16 (src/emc/motion/emcmotcfg.h)",
            0,
            15,
        ),
        position_decimals=6,
    ),
    "siemens": FormatLimits(
        controller="Siemens EEC (MD38000)",
        points=Limit(5000, "MD38000 $MA_MM_ENC_COMP_MAX_POINTS upper limit on 840D sl", False),
        points_ceiling=None,
        value_range=None,
        value_unit="mm",
        value_source="K3 'Interpolatory compensation': 'The size of the compensation value is "
        "not limited' ($AA_ENC_COMP); the sum of CEC tables on an axis is limited by MD32720 "
        "$MA_CEC_MAX_SUM (configurable)",
        equidistant=True,
        axis_names=AxisNames(
            r"[A-Za-z][A-Za-z0-9_]{0,30}",
            "a machine axis name such as AX1 "
            "or X1 (letters, digits and _, starting with a letter, at most 31 "
            "characters)",
            "MD10000 $MN_AXCONF_MACHAX_NAME_TAB",
        ),
        position_decimals=6,
    ),
    "fanuc": FormatLimits(
        controller="Fanuc pitch error compensation",
        points=Limit(
            1024, "point numbers 0 to 1023 (parameters 3620-3622, Series 0i/16i/18i)", False
        ),
        points_ceiling=Limit(
            1024, "point numbers 0 to 1023, parameters 3620-3622 on Series 0i/16i/18i", False
        ),
        value_range=(-128, 127),
        value_unit="detection units x parameter 3623 per point",
        value_source="per-point setting range -128 to 127, magnification 3623 up to 100",
        equidistant=True,
        axis_names=AxisNames(
            r"\d+",
            "a controlled axis number from 1 to 32",
            "the axis number of N<parameter>A<axis>P<value> records",
            1,
            32,
        ),
        position_decimals=None,
    ),
    "heidenhain": FormatLimits(
        controller="a Heidenhain .COM table",
        points=Limit(
            256, "TNC 407/415/425 technical manual, module 9095 error 3: 'more than 256 entries'"
        ),
        points_ceiling=Limit(256, "module 9095 refuses a .COM of more than 256 entries"),
        value_range=None,
        value_unit="mm",
        value_source="no limit found in the manuals consulted; values are written with four "
        "decimals",
        equidistant=False,
        axis_names=AxisNames(
            r"[A-Za-z][A-Za-z0-9_]{0,10}",
            "an axis key such as X or X2 "
            "(letters, digits and _, "
            "starting with a letter, at most 11 characters)",
            "CfgAxes/axisList keys (MANUALplus 620 / TNC 6xx manual)",
            file_suffix=".COM",
        ),
        position_decimals=4,
    ),
    "isg": FormatLimits(
        controller="an ISG leadscrew list",
        points=Limit(1500, "P-COMP-00059 kw.ssfk.max_points default (Beckhoff TF5200)"),
        points_ceiling=None,  # P-COMP-00059 is configurable (UNS32)
        value_range=(-(2**31), 2**31 - 1),
        value_unit="0.1 um",
        value_source="kw.ssfk entries are SGN32 in 0.1 um (Beckhoff TF5200 axis compensation)",
        equidistant=True,
        axis_names=AxisNames(
            r"\d+",
            "a logical axis number (P-AXIS-00016) from 1 to 65535",
            "kopf.log_achs_nr (Beckhoff TF5200)",
            1,
            65535,
        ),
        position_decimals=4,  # 0.1 µm
    ),
    "csv": FormatLimits("generic CSV", None, None, None, "um", "no controller", False, None, 6),
    "json": FormatLimits(
        "generic JSON", None, None, None, "um", "no controller", False, None, None
    ),
    "gcode": FormatLimits(
        "an NC program", None, None, None, "mm", "no controller", False, None, None
    ),
}


def limits_of(format: str) -> FormatLimits:
    if format not in LIMITS:
        raise UserError(f"unknown export format {format!r}; use one of {', '.join(LIMITS)}")
    return LIMITS[format]


# ---- options --------------------------------------------------------------------------------


def point_limit(format: str, max_points: int | None) -> int:
    """The point limit an export must keep: ``max_points`` (checked) or the format's own."""
    limits = limits_of(format)
    if max_points is None:
        return int(limits.points.value) if limits.points else MAX_TABLE_NODES
    if (
        isinstance(max_points, bool)
        or not isinstance(max_points, int | np.integer)
        or max_points < 2
    ):
        raise UserError(
            f"--max-points must be a whole number of at least 2 (a table needs two points), got "
            f"{max_points!r}"
        )
    ceiling = limits.points_ceiling
    if ceiling is not None and max_points > ceiling.value:
        raise UserError(
            f"--max-points {max_points}: {limits.controller} takes at most {int(ceiling.value)} "
            f"points ({ceiling.source}); --max-points can only lower that"
        )
    return int(max_points)


def check_axis_names(format: str, names: Mapping[str, str] | None) -> None:
    """Refuse axis names a format cannot carry (control characters, newlines, non-ASCII,
    characters outside the controller's naming, repeated names)."""
    if not names:
        return
    spec = limits_of(format).axis_names
    seen: dict[str, str] = {}
    for axis, name in names.items():
        what = f"--axis-names {axis}"
        check_name(name, what)
        if spec is not None:
            valid = re.fullmatch(spec.pattern, name) is not None and name.isascii()
            if valid and spec.low is not None:
                valid = spec.low <= int(name) <= (spec.high or spec.low)
            if not valid:
                raise UserError(f"{what}={name!r}: the {format} export needs {spec.description}")
            if spec.file_suffix:
                safe_file_name(name + spec.file_suffix, f"{what}={name!r}:")
        if name in seen:
            raise UserError(
                f"--axis-names: {seen[name]} and {axis} are both {name!r}; each axis "
                "needs its own name"
            )
        seen[name] = axis


def check_sizes(
    extents: Mapping[str, tuple[float, float]],
    spacing_mm: float | Mapping[str, float] | None,
    grid_spacing_mm: float | None,
) -> None:
    """Refuse tables and grids whose size, from the arguments alone, is beyond what volucal
    computes (:data:`MAX_TABLE_NODES`, :data:`MAX_GRID_POINTS`), before anything is allocated."""
    if spacing_mm is not None:
        for axis, (low, high) in extents.items():
            value = spacing_mm[axis] if isinstance(spacing_mm, Mapping) else spacing_mm
            nodes = node_count(low, high, value, "--spacing")
            if nodes > MAX_TABLE_NODES:
                raise UserError(
                    f"--spacing {value:g} mm gives {nodes:,} nodes along {axis}; volucal computes "
                    f"at most {MAX_TABLE_NODES:,} per table: use a spacing of at least "
                    f"{_fit(high - low, MAX_TABLE_NODES):g} mm"
                )
    if grid_spacing_mm is not None:
        counts = [
            node_count(low, high, grid_spacing_mm, "--grid-spacing")
            for low, high in extents.values()
        ]
        total = math.prod(counts)
        if total > MAX_GRID_POINTS:
            raise UserError(
                f"--grid-spacing {grid_spacing_mm:g} mm gives a grid of "
                f"{' x '.join(str(c) for c in counts)} = {total:,} nodes (about "
                f"{total * 1e3 / 1e9:,.1f} GB to compute); volucal computes at most "
                f"{MAX_GRID_POINTS:,}: use a spacing of at least {grid_spacing_fit(extents):g} mm"
            )


def grid_spacing_fit(extents: Mapping[str, tuple[float, float]]) -> float:
    """The smallest grid spacing, in steps of 0.1 mm, whose grid has at most
    :data:`MAX_GRID_POINTS` nodes."""
    spans = [max(high - low, 0.0) for low, high in extents.values()]
    volume = math.prod(s for s in spans if s > 0) or 1.0
    dimensions = sum(1 for s in spans if s > 0) or 1
    tenths = max(1, math.floor((volume / MAX_GRID_POINTS) ** (1 / dimensions) * 10))
    while (
        math.prod(node_count(0.0, s, tenths / 10, "--grid-spacing") for s in spans)
        > MAX_GRID_POINTS
    ):
        tenths += 1
    return tenths / 10


def node_count(low: float, high: float, spacing_mm: float, option: str) -> int:
    """Nodes of :func:`~.tables.even_nodes` over [low, high], without making them."""
    if not (isinstance(spacing_mm, int | float) and math.isfinite(spacing_mm) and spacing_mm > 0):
        raise UserError(f"{option} must be a positive number of mm, got {spacing_mm}")
    span = float(high) - float(low)
    if not math.isfinite(span):
        raise UserError(f"the table range [{low}, {high}] mm is not finite")
    return max(1, math.ceil(span / spacing_mm - 1e-9)) + 1


def _fit(span: float, count: int) -> float:
    return math.ceil(span / max(1, count - 1) * 1000.0) / 1000.0


# ---- written tables ------------------------------------------------------------------------


def check_positions(format: str, label: str, positions_mm: ArrayLike) -> None:
    """Node positions as the file writes them: finite and strictly increasing."""
    positions = np.asarray(positions_mm, dtype=float)
    limits = limits_of(format)
    bad = np.flatnonzero(~np.isfinite(positions))
    if bad.size:
        raise TableLimitError(f"{label}: position {bad[0]} is {positions[bad[0]]} (not a number)")
    written = (
        positions
        if limits.position_decimals is None
        else np.round(positions, limits.position_decimals)
    )
    steps = np.diff(written)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        i = int(bad[0])
        raise TableLimitError(
            f"{label}: positions must increase, but node {i + 1} ({written[i + 1]:g} mm) does "
            f"not lie beyond node {i} ({written[i]:g} mm) as written; {limits.controller} "
            "refuses such a table (use a larger --spacing)"
        )


def check_finite(label: str, positions_mm: ArrayLike, values: ArrayLike) -> None:
    """Every value a number: no controller loads NaN or infinity."""
    positions = np.asarray(positions_mm, dtype=float)
    v = np.asarray(values, dtype=float)
    bad = np.flatnonzero(~np.isfinite(v))
    if bad.size:
        i = int(bad[0])
        raise TableLimitError(
            f"{label}: the value at {positions[i]:g} mm is {v[i]} (not a number); no controller "
            "can load it — check the identification"
        )


def check_values(format: str, label: str, positions_mm: ArrayLike, values: ArrayLike) -> None:
    """The file's numbers (in the format's ``value_unit``): finite and within its range."""
    limits = limits_of(format)
    positions = np.asarray(positions_mm, dtype=float)
    v = np.asarray(values, dtype=float)
    check_finite(label, positions, v)
    if limits.value_range is None:
        return
    low, high = limits.value_range
    bad = np.flatnonzero((v < low) | (v > high))
    if bad.size:
        i = int(bad[np.argmax(np.abs(v[bad]))])
        raise TableLimitError(
            f"{label}: the value at {positions[i]:g} mm is {v[i]:g} {limits.value_unit}, "
            f"outside the {low:g} to {high:g} that {limits.controller} accepts "
            f"({limits.value_source})"
        )


def check_count(
    format: str, label: str, count: int, limit: int, span_mm: float, spacing_mm: float
) -> None:
    """Raise :class:`TableLimitError` when ``count`` points exceed ``limit``, with the spacing
    that would fit."""
    if count <= limit:
        return
    limits = limits_of(format)
    configurable = limits.points_ceiling is None or limit < limits.points_ceiling.value
    raise TableLimitError(
        f"{label} needs {count} points at {spacing_mm:g} mm spacing but {limits.controller} "
        f"accepts at most {limit}; export with a spacing of at least {_fit(span_mm, limit):g} mm "
        "(--spacing)"
        + (
            ", or raise the controller's limit and pass it with --max-points"
            if configurable
            else ""
        )
    )
