"""What the readers accept: sizes checked before anything is allocated, and the values a laser
measurement can produce. docs/formats.md ("Limits") lists the same table.

A size a file claims (a count in its header) is checked against these limits and against what the
file can hold before an array of that size exists, so that a small damaged or crafted file cannot
exhaust the machine. A value beyond the physical bounds is refused with its file and line; the
bounds are far beyond any real measurement and only reject values that cannot be one (a deviation
of 1e300, a position that overflows to infinity once converted to mm).
"""

from __future__ import annotations

#: A text log (rtl, rta, table, ISO 230-2 table, plan) is read whole: at most this many bytes.
MAX_TEXT_BYTES = 64 << 20
#: A dynamic capture (binary or CSV): at most this many bytes.
MAX_CAPTURE_BYTES = 1 << 30
#: Samples in one capture.
MAX_SAMPLES = 200_000_000
#: Targets of one line, runs of one line, and readings (runs × targets: the grid volucal
#: allocates for a line, 16 MB per array at this size).
MAX_TARGETS = 100_000
MAX_RUNS = 10_000
MAX_READINGS = 2_000_000

#: |position| and |target| in mm (1 km).
MAX_ABS_POSITION_MM = 1e6
#: |deviation| in µm (linear, straightness) or µrad (angular): 1 m, 1 rad.
MAX_ABS_DEVIATION = 1e6
#: Two targets of a line are at least this far apart (mm).
MIN_TARGET_SPACING_MM = 1e-4
#: |time| in seconds from a file's start (about 300 years).
MAX_ABS_TIME_S = 1e10
#: Sample rate of a capture, Hz.
MAX_SAMPLE_RATE_HZ = 1e9

#: Environment values volucal accepts once converted (°C, kPa, %RH, ppm/°C). The pressure and
#: temperature bounds are also what catches a wrong unit (734 mmHg declared as kPa, °F as °C).
AIR_TEMP_RANGE_C = (0.0, 50.0)
MATERIAL_TEMP_RANGE_C = (-10.0, 100.0)
PRESSURE_RANGE_KPA = (50.0, 120.0)
HUMIDITY_RANGE_PCT = (0.0, 100.0)
MAX_ABS_EXPANSION_PPM = 100.0

#: A Renishaw log records what its sensors read, and a sensor that is absent can read 0; these
#: wider bounds only refuse what no sensor produces.
RTL_AIR_TEMP_RANGE_C = (-50.0, 100.0)
RTL_PRESSURE_RANGE_KPA = (0.0, 200.0)
RTL_MATERIAL_TEMP_RANGE_C = (-50.0, 200.0)


def size_text(count: int) -> str:
    """``2_000_000`` → ``"2,000,000"`` for messages."""
    return f"{count:,}"
