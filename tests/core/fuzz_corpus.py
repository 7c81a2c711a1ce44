"""The fuzz harness of the readers, shared by tests/core/test_io_fuzz.py (a few hundred cases per
format, a few seconds) and benchmarks/bench_fuzz.py (a longer run that reports counts and peak
memory).

Seeds are real files: the demo logs (resources/demo/logs), the hand-written samples
(tests/data/io) and, when present, the real measurements in ../shared/realdata (read in place,
never copied into the repository). Each seed carries the reader (and options) that accept it
unchanged. Mutations, drawn from a seeded ``random.Random``:

- truncation at any byte, byte and bit flips, inserted tokens, deleted, duplicated and swapped
  lines (the mutations of a damaged file);
- swapped columns, in one row or in every row and the header (a file whose columns moved);
- header-count and size attacks: the counts a header claims (Target-count, Run-count, Sample
  count, CYCLES, POSITIONS) set to 0, −1, off by one, 10⁵…10¹², and rows repeated;
- value attacks: a number replaced by one that overflows once converted (±1e308, 1e306), one no
  laser produces (1e300), a denormal, ``nan``/``inf``, or a loose number Python's ``float``
  accepts (``1_000``, Arabic-Indic or full-width digits, non-breaking spaces).

The outcome of a case is "clean error" (a :class:`~volucal.core.userror.UserError`: one line,
naming the file), "accepted" (then every value must lie within the readers' limits), or "other"
(any other exception, or an accepted file holding an impossible value: a bug).
"""

from __future__ import annotations

import random
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from volucal.core.io.capture import capture_line_data, read_capture, write_capture
from volucal.core.io.iso_table import read_iso_table
from volucal.core.io.limits import (
    MAX_ABS_DEVIATION,
    MAX_ABS_POSITION_MM,
    MAX_READINGS,
    MIN_TARGET_SPACING_MM,
)
from volucal.core.io.plan import import_plan, load_plan
from volucal.core.io.rtl import read_rtl
from volucal.core.io.table import ColumnMap, TableFormat, read_table
from volucal.core.io.units import DEVIATION_FACTOR
from volucal.core.measurement import LineData
from volucal.core.userror import FormatError, UserError

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "tests" / "data" / "io"
DEMO_LOGS = REPO / "resources" / "demo" / "logs"
REALDATA_CANDIDATES = (REPO.parent / "shared" / "realdata", Path("/work/shared/realdata"))

TOKENS = [b"", b"0", b"-1", b"1e999", b"nan", b"inf", b"x", b"99999999999999999999", b"::",
          b":", b'"', b"[", b"]", b"=", b",", b";", b"\t", b"  ", b"\n", b"\r", b"\x00",
          b"\xff\xfe", b"2.5.1", b"-0", b"1,5", b"+", b"TGT_DATA[1]=", b"Data:", b"EOF::",
          b"HEADER::", b"[[line]]", b"\xc3\xa9", b":START", b"#", b"\xc2\xa0"]
HUGE_VALUES = [b"1e308", b"-1e308", b"1e306", b"1e307", b"1e300", b"-1e300", b"4.9e-324",
               b"nan", b"inf", b"-inf", b"1_000", "\u0661\u0662".encode(),
               "\uff11\uff12".encode(), "\u00a012".encode(), b"1e999", b"0x10"]
COUNT_KEYS = re.compile(rb"(Target-count\s*:\s*|Run-count\s*:\s*|Sample count\s*:\s*|"
                        rb"CYCLES\s*=\s*|POSITIONS\s*=\s*)(\d+)")
COUNT_VALUES = [b"0", b"-1", b"100000", b"1000000", b"1000000000", b"1000000000000",
                b"99999999999999999999"]
NUMBER = re.compile(rb"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?(?![\w.])")
MUTATIONS = ("truncate", "byte", "bit", "token", "delete", "duplicate", "swap_lines",
             "swap_fields", "swap_columns", "count", "value", "repeat_rows")


def realdata() -> Path | None:
    """The shared real data folder, or None when it is not on this machine."""
    return next((p for p in REALDATA_CANDIDATES if p.is_dir()), None)


@dataclass(frozen=True)
class Seed:
    """A file that ``read`` accepts unchanged; ``name`` is the name its mutants are written as
    (the extension selects the reader where it matters)."""

    format: str
    origin: str
    name: str
    content: bytes
    read: Callable[[Path], object]


def _table(**options: object) -> Callable[[Path], object]:
    # as a plan reads a table: plan.toml states lengths in mm
    options.setdefault("position_unit_default", "mm")
    fmt = TableFormat(**options)  # type: ignore[arg-type]
    return lambda path: read_table(path, fmt)


def _capture(**options: object) -> Callable[[Path], object]:
    def read(path: Path) -> object:
        capture = read_capture(path, **options)  # type: ignore[arg-type]
        try:
            return capture, capture_line_data(capture, step_mm=1.0, step_s=0.5)
        except ValueError as exc:  # the binning's refusals: a plan names its field
            raise FormatError(path, str(exc)) from None
    return read


def _read_plan(path: Path) -> object:
    return import_plan(load_plan(path))


def seeds(work: Path) -> dict[str, list[Seed]]:
    """The corpus by format. ``work`` is the scratch folder the mutants are written to: the
    capture seeds are written there and the plan's data files copied beside its mutants."""
    for item in DATA.iterdir():
        if item.is_file() and item.suffix != ".toml":
            (work / item.name).write_bytes(item.read_bytes())
    out: dict[str, list[Seed]] = {f: [] for f in ("rtl", "rta", "table", "iso230-2", "capture",
                                                  "plan")}
    for path in sorted(DEMO_LOGS.glob("*.rtl"))[::6] + [DATA / "x_axis_hand.rtl"]:
        out["rtl"].append(Seed("rtl", str(path.relative_to(REPO)), "f.rtl", path.read_bytes(),
                               read_rtl))
    for path in sorted(DEMO_LOGS.glob("*.rta")) + [DATA / "x_pitch_hand.rta"]:
        out["rta"].append(Seed("rta", str(path.relative_to(REPO)), "f.rta", path.read_bytes(),
                               read_rtl))
    out["table"] += [
        Seed("table", "tests/data/io/y_straightness_hand.csv", "f.csv",
             (DATA / "y_straightness_hand.csv").read_bytes(), _table()),
        Seed("table", "tests/data/io/x_semicolon_hand.csv", "f.csv",
             (DATA / "x_semicolon_hand.csv").read_bytes(),
             _table(columns=ColumnMap(deviation="Abweichung", run="Lauf"))),
        Seed("table", "tests/data/io/z_linear_hand.txt", "f.txt",
             (DATA / "z_linear_hand.txt").read_bytes(),
             _table(columns=ColumnMap(position=1, deviation=2), deviation_unit="nm")),
    ]
    out["iso230-2"] += [
        Seed("iso230-2", f"tests/data/io/{name}", "f.dat", (DATA / name).read_bytes(),
             read_iso_table) for name in ("ecmc_hand.dat", "z_iso_hand.txt")
    ]
    out["capture"] += list(_capture_seeds(work))
    out["plan"].append(Seed("plan", "tests/data/io/plan.toml", "plan.toml",
                            (DATA / "plan.toml").read_bytes(), _read_plan))
    shared = realdata()
    if shared is not None:
        _real_seeds(shared, out)
    return out


def _capture_seeds(work: Path) -> Iterator[Seed]:
    rng = np.random.default_rng(0)
    binary = work / "seed.rtx"
    write_capture(binary, rng.normal(0, 1, 40), sample_rate_hz=100.0,
                  position_mm=np.linspace(0, 10, 40))
    yield Seed("capture", "write_capture (binary, position)", "f.rtx", binary.read_bytes(),
               _capture())
    text = work / "seed.csv"
    write_capture(text, np.arange(30.0), sample_rate_hz=10.0, binary=False)
    yield Seed("capture", "write_capture (CSV, time)", "f.csv", text.read_bytes(),
               _capture(chunk_bytes=64))


def _real_seeds(shared: Path, out: dict[str, list[Seed]]) -> None:
    aerotech = shared / "aerotech_flatness_angular"
    flat = {"data_marker": ":START", "deviation_unit": "mm", "temperature_unit": "C",
            "pressure_unit": "mmHg"}
    for name, column in (("643630-1-1-X-test_Flatness.dat", "Flat"),
                         ("643630-1-1-X_Flatness.dat", "LaserData")):
        if (aerotech / name).is_file():
            out["table"].append(Seed("table", f"realdata/{name}", "f.dat",
                                     (aerotech / name).read_bytes(),
                                     _table(columns=ColumnMap(deviation=column), **flat)))
    for name in ("643630-1-1-X-test_Angular.dat", "643630-1-1-X_Angular.dat"):
        if (aerotech / name).is_file():
            out["table"].append(Seed("table", f"realdata/{name}", "f.dat",
                                     (aerotech / name).read_bytes(),
                                     _table(columns=ColumnMap(deviation="Pitch"),
                                            data_marker=":START", deviation_unit="arcsec",
                                            temperature_unit="C")))
    lower = aerotech / "519742-01-Lower_Flatness.dat"
    if lower.is_file():
        out["table"].append(Seed("table", "realdata/519742-01-Lower_Flatness.dat", "f.dat",
                                 lower.read_bytes(),
                                 _table(columns=ColumnMap(deviation="Lower Data"),
                                        data_marker=":START", deviation_unit="um",
                                        environment=False)))
    for folder in ("psi_ecmc_iso230_2", "ess_ecmc_iso230_2"):
        for path in sorted((shared / folder).glob("*.dat")):
            out["iso230-2"].append(Seed("iso230-2", f"realdata/{path.name}", "f.dat",
                                        path.read_bytes(), read_iso_table))


# ---- mutations -----------------------------------------------------------------------------


def mutate(content: bytes, rng: random.Random, rounds: int | None = None) -> tuple[bytes, str]:
    """A mutant of ``content`` and the names of the mutations applied."""
    data = bytearray(content)
    applied = []
    for _ in range(rounds or rng.randint(1, 3)):
        kind = rng.choice(MUTATIONS)
        applied.append(kind)
        data = bytearray(_apply(kind, bytes(data), rng))
    return bytes(data), "+".join(applied)


def _apply(kind: str, data: bytes, rng: random.Random) -> bytes:
    size = max(len(data), 1)
    at = rng.randrange(size)
    if kind == "truncate":
        return data[:at]
    if kind == "byte" and data:
        return data[:at] + bytes([rng.randrange(256)]) + data[at + 1:]
    if kind == "bit" and data:
        return data[:at] + bytes([data[at] ^ (1 << rng.randrange(8))]) + data[at + 1:]
    if kind == "token":
        end = min(len(data), at + rng.randint(0, 6))
        return data[:at] + rng.choice(TOKENS) + data[end:]
    if kind == "count":
        matches = list(COUNT_KEYS.finditer(data))
        if matches:
            match = rng.choice(matches)
            value = int(match.group(2))
            choice = rng.choice(COUNT_VALUES + [str(value + 1).encode(),
                                                str(max(value - 1, 0)).encode()])
            return data[:match.start(2)] + choice + data[match.end(2):]
        kind = "value"
    if kind == "value":
        matches = list(NUMBER.finditer(data))
        if matches:
            match = rng.choice(matches)
            return data[:match.start()] + rng.choice(HUGE_VALUES) + data[match.end():]
        return data
    lines = data.split(b"\n")
    i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
    if kind == "delete":
        del lines[i]
    elif kind == "duplicate":
        lines.insert(j, lines[i])
    elif kind == "swap_lines":
        lines[i], lines[j] = lines[j], lines[i]
    elif kind == "repeat_rows":
        lines[i:i + 1] = [lines[i]] * rng.choice((2, 10, 1000))
    elif kind == "swap_fields":
        lines[i] = _swap(lines[i], rng, None)
    elif kind == "swap_columns":
        pair = None
        for index, line in enumerate(lines):
            fields = _split(line)[0]
            if len(fields) >= 2:
                pair = pair or tuple(rng.sample(range(len(fields)), 2))
                lines[index] = _swap(line, rng, pair)
    return b"\n".join(lines)


def _split(line: bytes) -> tuple[list[bytes], bytes]:
    for delimiter in (b",", b";", b"\t"):
        if delimiter in line:
            return line.split(delimiter), delimiter
    return line.split(), b" "


def _swap(line: bytes, rng: random.Random, pair: tuple[int, int] | None) -> bytes:
    fields, delimiter = _split(line)
    if len(fields) < 2:
        return line
    a, b = pair if pair and max(pair) < len(fields) else rng.sample(range(len(fields)), 2)
    fields[a], fields[b] = fields[b], fields[a]
    return delimiter.join(fields)


# ---- one case ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Outcome:
    kind: str  # "clean error", "accepted" or "other"
    detail: str


def run_case(seed: Seed, content: bytes, folder: Path) -> Outcome:
    """Write the mutant as ``folder/seed.name``, read it, classify what happened."""
    path = folder / seed.name
    path.write_bytes(content)
    try:
        result = seed.read(path)
    except UserError as error:
        text = str(error)
        if "\n" in text:
            return Outcome("other", f"a message of several lines: {text!r}")
        if seed.format != "plan" and str(path) not in text and path.name not in text:
            return Outcome("other", f"a message that does not name the file: {text!r}")
        return Outcome("clean error", text)
    except Exception as error:  # noqa: BLE001 - classifying any escape is the point
        return Outcome("other", f"{type(error).__name__}: {error}")
    problem = impossible_value(result)
    return Outcome("other", problem) if problem else Outcome("accepted", "")


def impossible_value(result: object) -> str | None:
    """A value no measurement produces in an accepted result, or None."""
    for data, unit in _line_data(result):
        targets = data.targets_mm
        if not np.all(np.isfinite(targets)) or np.any(np.abs(targets) > 2 * MAX_ABS_POSITION_MM):
            return f"accepted targets {targets}"
        if targets.size > 1 and np.min(np.diff(targets)) < MIN_TARGET_SPACING_MM * 0.999:
            return f"accepted a target spacing of {np.min(np.diff(targets))} mm"
        if data.deviations.size > MAX_READINGS:
            return f"accepted {data.deviations.size} readings"
        values = data.deviations[np.isfinite(data.deviations)] * DEVIATION_FACTOR.get(unit, 1.0)
        if values.size and np.max(np.abs(values)) > MAX_ABS_DEVIATION * 1.000001:
            return f"accepted a deviation of {np.max(np.abs(values))} ({unit})"
        if np.isinf(data.deviations).any() or not np.all(np.isfinite(data.times_s)
                                                         | np.isnan(data.deviations)):
            return "accepted an infinite deviation or time"
    return None


def _line_data(result: object) -> Iterator[tuple[LineData, str]]:
    if hasattr(result, "lines") and hasattr(result, "measurement"):  # ImportResult
        for line in result.lines:  # type: ignore[attr-defined]
            yield line.corrected, line.spec.unit
        return
    if isinstance(result, tuple):  # capture and its binning
        capture, data = result
        yield data, capture.unit or "um"
        return
    data = getattr(result, "data", None)
    if isinstance(data, LineData):
        yield data, getattr(result, "unit", None) or "um"
