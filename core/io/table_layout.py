"""Where a table's header and data are, how its fields split, and which column holds what.

Used by :mod:`.table` (tables of readings) and :mod:`.capture` (CSV captures). The rules, each
failing loudly with the file and the line rather than guessing:

- The header is the first non-comment line, unless a ``data_marker`` is given: then it is the
  first non-comment line after the marker when that line is not numbers, else the last text line
  before the marker. A file whose header is all numbers has no header (columns by number).
- Fields split on the delimiter (comma, semicolon, tab: detected from the header, or given) or on
  blanks; double quotes keep a name with spaces or delimiters together (``"Lower Data"``). In a
  blank-separated file a header with more names than the rows have fields is split again on tabs
  and runs of two or more spaces, so that ``Position     Lower Data     Temperature`` names three
  columns; if that does not give the rows' count either, the file is refused.
- Every data row has as many fields as the header (or as the first row, without a header). In a
  file with a delimiter (comma, semicolon, tab) a row may end early, leaving out empty trailing
  cells, as vendor exports do ("Out of spec." with nothing in it), as long as the columns read are
  there; in a blank-separated file, where a name with a space shifts every column, the counts
  must be equal.
- Names match case-insensitively, ignoring spaces, ``_`` and ``-`` and a unit written as
  ``[mm]``, ``(mm)`` or a ``_mm`` suffix; the standard columns also answer to the names vendors
  use (``AirTemp``, ``MatTemp``, ``Pressure``, ``Air Hmd`` …). A name given in a column map must
  match one column exactly; a standard name that matches two columns must be mapped.
"""

from __future__ import annotations

import csv
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields

from .source import BLANKS, SourceText, is_number
from .units import (
    DEVIATION_FACTOR,
    POSITION_FACTOR,
    PRESSURE_FACTOR_KPA,
    TEMPERATURE_UNITS,
    TIME_FACTOR,
    normalise_unit,
)

ColumnRef = str | int | None

#: Names (as :func:`name_key` forms them) each standard column answers to.
STANDARD_NAMES: dict[str, tuple[str, ...]] = {
    "position": ("position", "pos", "target", "targetposition"),
    "deviation": ("deviation", "dev"),
    "run": ("run", "cycle", "pass"),
    "direction": ("direction", "dir"),
    "time": ("time", "timestamp"),
    "air_temp": ("airtemp", "airtemperature", "air"),
    "material_temp": (
        "materialtemp",
        "materialtemperature",
        "mattemp",
        "material",
        "mattemp1",
        "mt1temp",
        "mt1",
    ),
    "pressure": ("pressure", "airpressure", "airpress", "airprs", "press"),
    "humidity": ("humidity", "airhumidity", "airhumid", "airhmd", "rh", "relativehumidity"),
}
#: What each column is, for messages.
DESCRIPTION = {
    "position": "position",
    "deviation": "deviation",
    "run": "run",
    "direction": "direction",
    "time": "time",
    "air_temp": "air temperature",
    "material_temp": "material temperature",
    "pressure": "air pressure",
    "humidity": "humidity",
}
ENVIRONMENT_COLUMNS = ("air_temp", "material_temp", "pressure", "humidity")
#: Deviation column names that say the values are angles.
ANGULAR_NAMES = ("yaw", "pitch", "roll", "angle", "angular", "tilt")
HUMIDITY_UNITS = ("%", "pct", "%rh", "rh", "percent")

_UNIT_IN_NAME = re.compile(r"^(?P<name>.*?)\s*(?:\[(?P<b>[^\]]*)\]|\((?P<p>[^)]*)\))\s*$")
_KNOWN_SUFFIXES = (
    set(DEVIATION_FACTOR)
    | set(POSITION_FACTOR)
    | set(TIME_FACTOR)
    | set(PRESSURE_FACTOR_KPA)
    | set(TEMPERATURE_UNITS)
    | {"pct"}
)
_MARKER_LIKE = re.compile(r"^:[A-Z][A-Z_]*$")
_KIND_LINE = re.compile(
    r"^\s*(test\s*type|file\s*type|measurement\s*type)\s*:\s*(?P<value>[A-Za-z]+)", re.IGNORECASE
)
_BLANK_RUN = re.compile(r"[ \t\r\n\f\v]+")
_SPACED = re.compile(r"\t|[ ]{2,}")
_BLANK_FIELDS = re.compile(r'"([^"]*)"|([^ \t"]+)')
#: A header name as it may be quoted in a message: what column names look like. A "header" that
#: does not look like names (a line of some other file) is not echoed.
_NAME_LIKE = re.compile(r"^[\w .()\[\]/%°µμ#+\-*'\"]{1,40}$")


@dataclass(frozen=True)
class ColumnMap:
    """Which column holds what: a header name, a 1-based column number, or None.

    None means "the column with the standard name (the field's name or a vendor's spelling of it)
    if there is one"; a value given explicitly must exist in the file.
    """

    position: ColumnRef = None
    deviation: ColumnRef = None
    run: ColumnRef = None
    direction: ColumnRef = None
    time: ColumnRef = None
    air_temp: ColumnRef = None
    material_temp: ColumnRef = None
    pressure: ColumnRef = None
    humidity: ColumnRef = None

    @classmethod
    def from_mapping(cls, mapping: dict[str, object]) -> ColumnMap:
        """From a plan's ``columns = {position = "X", deviation = 2, ...}``; unknown keys raise
        ValueError naming them."""
        return cls(**column_refs(mapping, sorted(f.name for f in fields(cls)), "column"))


def column_refs(
    mapping: Mapping[str, object], known: Sequence[str], what: str
) -> dict[str, ColumnRef]:
    """A column map's values checked: each key one of ``known``, each value a header name or a
    1-based column number; otherwise ValueError naming the key (``what``: "column", "grid
    column")."""
    unknown = sorted(set(mapping) - set(known))
    if unknown:
        raise ValueError(f"unknown {what} key(s) {', '.join(unknown)}; use {', '.join(known)}")
    values: dict[str, ColumnRef] = {}
    for key, value in mapping.items():
        if isinstance(value, bool) or not isinstance(value, str | int):
            raise ValueError(f"column {key}: expected a header name or a column number")
        if isinstance(value, int) and value < 1:
            raise ValueError(f"column {key}: column numbers start at 1, got {value}")
        if isinstance(value, str) and not value.strip():
            raise ValueError(f"column {key}: the name is empty")
        values[key] = value
    return values


@dataclass
class Layout:
    """A table's header (names, the line it is on), its first data line and its delimiter."""

    header: tuple[str, ...]
    header_line: int | None
    first_data_line: int
    delimiter: str | None
    field_count: int
    #: "angle" or "length" when a preamble line says what was measured (``TestType : Angular``),
    #: with that line's number
    kind: tuple[str, int] | None = None


def is_comment(text: str, comment: str = "#") -> bool:
    stripped = text.strip(BLANKS)
    return not stripped or stripped.startswith(comment) or stripped.startswith("//")


def detect_delimiter(text: str) -> str | None:
    for candidate in (",", ";", "\t"):
        if candidate in text:
            return candidate
    return None


def split_fields(text: str, delimiter: str | None) -> list[str]:
    """The fields of a line: on ``delimiter``, or on blanks (spaces and tabs) when None; double
    quotes keep a field together. Only ASCII blanks separate or are stripped."""
    if delimiter is None:
        if '"' not in text:
            return [t for t in _BLANK_RUN.split(text) if t]
        return [a if a or not b else b for a, b in _BLANK_FIELDS.findall(text)]
    if '"' not in text:
        return [part.strip(BLANKS) for part in text.split(delimiter)]
    row = next(csv.reader([text], delimiter=delimiter, quotechar='"', skipinitialspace=True), [])
    return [part.strip(BLANKS) for part in row]


def split_unit(name: str) -> tuple[str, str | None]:
    """``"Position [mm]"`` → ("position", "mm"); ``"deviation_um"`` → ("deviation", "um")."""
    text = name.strip(BLANKS)
    match = _UNIT_IN_NAME.match(text)
    if match:
        return plain(match.group("name")), normalise_unit(match.group("b") or match.group("p"))
    simple = plain(text)
    base, _, suffix = simple.rpartition("_")
    if base and suffix in _KNOWN_SUFFIXES:
        return base, normalise_unit(suffix)
    return simple, None


def plain(name: str) -> str:
    return "_".join(name.strip(BLANKS).lower().split())


def name_key(name: str) -> str:
    """A name without case, spaces, ``_`` or ``-``: ``"Air Temp"`` and ``"air_temp"`` match."""
    return re.sub(r"[\s_\-.]", "", name.lower())


def shown_names(header: tuple[str, ...]) -> str:
    """The header's names for a message, or a neutral phrase when they do not look like names
    (a line of a file that is not a table is never echoed)."""
    if header and len(header) <= 64 and all(_NAME_LIKE.match(h) for h in header):
        return "the header has " + ", ".join(repr(h) for h in header)
    return "the first line is not a row of column names"


def find_layout(
    source: SourceText, *, delimiter: str | None, data_marker: str | None, comment: str = "#"
) -> Layout:
    """The header, first data line and delimiter of a table (module notes)."""
    whitespace = delimiter is not None and delimiter.lower() in ("whitespace", "space", " ")
    fixed = None if whitespace else delimiter
    header_line: int | None
    if data_marker is not None:
        marker = next(
            (n for n, text in source.numbered() if text.strip(BLANKS) == data_marker.strip()), None
        )
        if marker is None:
            raise source.error(
                f"the data marker line {data_marker!r} was not found; check "
                "data_marker (--data-marker)",
                source.last_line,
            )
        after = _next_text(source, marker + 1, comment)
        before = next(
            (n for n in range(marker - 1, 0, -1) if not is_comment(source.lines[n - 1], comment)),
            None,
        )
        if after is not None and not _all_numbers(source.lines[after - 1], fixed, whitespace):
            header_line, first_data = after, after + 1
        else:
            header_line, first_data = before, marker + 1
    else:
        first = _next_text(source, 1, comment)
        if first is None:
            raise source.error("the file holds no data rows", source.last_line)
        _refuse_unmarked_preamble(source, comment)
        if _all_numbers(source.lines[first - 1], fixed, whitespace):
            header_line, first_data = None, first
        else:
            header_line, first_data = first, first + 1
    probe_line = header_line or _next_text(source, first_data, comment)
    probe = source.lines[probe_line - 1] if probe_line else ""
    chosen = fixed if (whitespace or fixed) else detect_delimiter(probe)
    data_line = _next_text(source, first_data, comment)
    if data_line is None:
        raise source.error("the file holds no data rows", source.last_line)
    row_count = len(split_fields(source.lines[data_line - 1], chosen))
    header: tuple[str, ...] = ()
    if header_line is not None:
        header = tuple(split_fields(source.lines[header_line - 1], chosen))
        if chosen is None and len(header) > row_count:
            respaced = tuple(
                p
                for p in _SPACED.split(source.lines[header_line - 1].strip(BLANKS))
                if p.strip(BLANKS)
            )
            if len(respaced) == row_count:
                header = tuple(p.strip(BLANKS) for p in respaced)
        short_rows = chosen is not None and len(header) > row_count  # empty trailing cells
        if len(header) != row_count and not short_rows:
            raise source.error(
                f"the header (line {header_line}) has {len(header)} name(s) but the data rows "
                f"have {row_count} field(s) (line {data_line}): quote names that hold spaces "
                '("Lower Data"), separate columns with tabs or two spaces, or give '
                "data_marker (--data-marker) when the data start below other text",
                header_line,
            )
        empty = [i + 1 for i, name in enumerate(header) if not name]
        if empty:
            raise source.error(f"column {empty[0]} of the header has no name", header_line)
    return Layout(
        header,
        header_line,
        first_data,
        chosen,
        len(header) or row_count,
        _declared_kind(source, header_line or first_data),
    )


def row_fits(layout: Layout, fields_in_row: int, needed: int) -> bool:
    """Whether a row has the header's count of fields (or, with a delimiter, ends early after
    the ``needed`` columns read)."""
    if fields_in_row == layout.field_count:
        return True
    return layout.delimiter is not None and needed <= fields_in_row < layout.field_count


def _next_text(source: SourceText, start: int, comment: str) -> int | None:
    for number in range(start, len(source.lines) + 1):
        if not is_comment(source.lines[number - 1], comment):
            return number
    return None


def _all_numbers(text: str, delimiter: str | None, whitespace: bool) -> bool:
    chosen = delimiter if (whitespace or delimiter) else detect_delimiter(text)
    tokens = [t for t in split_fields(text, None if whitespace else chosen) if t]
    return bool(tokens) and all(is_number(t.replace(",", ".")) for t in tokens)


def _refuse_unmarked_preamble(source: SourceText, comment: str) -> None:
    """A file with a ``:START``-like line and no data_marker: say which option reads it, rather
    than failing on its preamble."""
    for number, text in source.numbered():
        stripped = text.strip(BLANKS)
        if _MARKER_LIKE.match(stripped):
            raise source.error(
                f"the data seem to start after line {number} ({stripped!r}): give "
                f'data_marker = "{stripped}" in the plan (--data-marker {stripped} on the '
                "command line)",
                number,
            )


def _declared_kind(source: SourceText, stop: int) -> tuple[str, int] | None:
    for number in range(1, min(stop, len(source.lines) + 1)):
        match = _KIND_LINE.match(source.lines[number - 1])
        if match:
            value = match.group("value").lower()
            if value.startswith("angular") or value in ("angle", "rotary"):
                return ("angle", number)
            if value in ("linear", "flatness", "straightness", "positioning", "accuracy"):
                return ("length", number)
    return None


def resolve_columns(
    source: SourceText,
    layout: Layout,
    columns: ColumnMap,
    wanted: tuple[str, ...],
    required: tuple[str, ...],
) -> tuple[dict[str, int], dict[str, str | None], dict[str, str]]:
    """0-based index, the header's unit and the name (for messages) of each column found.

    ``wanted`` are the ColumnMap fields looked up by their standard names when not mapped;
    ``required`` must be found. A mapped name or number must exist.
    """
    names = [split_unit(h) for h in layout.header]
    keys = [name_key(plain_name) for plain_name, _ in names]
    where = layout.header_line or layout.first_data_line
    index: dict[str, int] = {}
    header_units: dict[str, str | None] = {}
    shown: dict[str, str] = {}
    for f in fields(ColumnMap):
        ref = getattr(columns, f.name)
        if ref is None and f.name not in wanted:
            continue
        if isinstance(ref, int):
            if ref > layout.field_count:
                raise source.error(
                    f"column {f.name} = {ref}, but the rows have {layout.field_count} fields",
                    where,
                )
            found = [ref - 1]
        elif isinstance(ref, str):
            exact = [i for i, h in enumerate(layout.header) if plain(h) == plain(ref)]
            found = exact or [i for i, k in enumerate(keys) if k == name_key(split_unit(ref)[0])]
        else:
            found = [i for i, k in enumerate(keys) if k in STANDARD_NAMES[f.name]]
        if not found:
            if ref is None and f.name not in required:
                continue
            if not layout.header:
                raise source.error(
                    f"the file has no header row: map the {f.name} column by number "
                    f"(e.g. columns = {{ {f.name} = 2 }}, --columns {f.name}=2)",
                    where,
                )
            listed = shown_names(layout.header)
            hint = (
                f'map it with columns = {{ {f.name} = "…" }} (--columns {f.name}=…)'
                if listed.startswith("the header has")
                else "if the table starts below other text, give data_marker (--data-marker): "
                "the line just before its header"
            )
            raise source.error(
                f"no {DESCRIPTION[f.name]} column named {ref or f.name!r}; {listed}; {hint}",
                where,
            )
        if len(found) > 1:
            listed = ", ".join(repr(layout.header[i]) for i in found)
            raise source.error(
                f"{len(found)} columns could be the {DESCRIPTION[f.name]} ({listed}); name one "
                f'with columns = {{ {f.name} = "…" }} (--columns {f.name}=…) or by number',
                where,
            )
        index[f.name] = found[0]
        header_units[f.name] = names[found[0]][1] if names else None
        shown[f.name] = repr(layout.header[found[0]]) if layout.header else f"number {found[0] + 1}"
    taken: dict[int, str] = {}
    for key, column in index.items():
        if column in taken:
            raise source.error(
                f"column {shown[key]} is mapped as both {taken[column]} and "
                f"{key}; map each to its own column",
                where,
            )
        taken[column] = key
    return index, header_units, shown
