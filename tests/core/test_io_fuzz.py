"""Fuzzing the readers with mutated and truncated samples: whatever the bytes, the only exception
that escapes is FormatError, and it names the file and the line."""

import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from volucal.core.io.capture import read_capture, write_capture
from volucal.core.io.iso_table import read_iso_table
from volucal.core.io.plan import load_plan
from volucal.core.io.rtl import read_rtl
from volucal.core.io.table import ColumnMap, TableFormat, read_table
from volucal.core.userror import FormatError

DATA = Path(__file__).resolve().parents[1] / "data" / "io"
EXAMPLES = 350  # per reader: a few thousand cases in all
WORK = Path(tempfile.mkdtemp(prefix="volucal-fuzz-"))

TOKENS = [b"", b"0", b"-1", b"1e999", b"nan", b"inf", b"x", b"99999999999999999999", b"::",
          b":", b'"', b"[", b"]", b"=", b",", b";", b"\t", b"  ", b"\n", b"\r", b"\x00",
          b"\xff\xfe", b"2.5.1", b"-0", b"1,5", b"+", b"TGT_DATA[1]=", b"Data:", b"EOF::",
          b"HEADER::", b"[[line]]", b"\xc3\xa9"]


@st.composite
def mutated(draw: st.DrawFn, original: bytes) -> bytes:
    data = bytearray(original)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["truncate", "byte", "token", "delete", "duplicate", "swap"]))
        size = max(len(data), 1)
        at = draw(st.integers(0, size - 1))
        if kind == "truncate":
            data = data[:at]
        elif kind == "byte" and data:
            data[at] = draw(st.integers(0, 255))
        elif kind == "token":
            end = min(len(data), at + draw(st.integers(0, 6)))
            data[at:end] = draw(st.sampled_from(TOKENS))
        else:
            lines = bytes(data).split(b"\n")
            i = draw(st.integers(0, len(lines) - 1))
            j = draw(st.integers(0, len(lines) - 1))
            if kind == "delete":
                del lines[i]
            elif kind == "duplicate":
                lines.insert(j, lines[i])
            else:
                lines[i], lines[j] = lines[j], lines[i]
            data = bytearray(b"\n".join(lines))
    return bytes(data)


def check(reader: Callable[[Path], object], name: str, content: bytes, *,
          needs_line: bool = True) -> None:
    path = WORK / name
    path.write_bytes(content)
    try:
        reader(path)
    except FormatError as error:
        assert error.path == str(path)
        if needs_line:
            assert isinstance(error.line, int) and error.line >= 1, str(error)
        assert str(error).startswith(str(path))


def capture_sample() -> bytes:
    path = WORK / "sample.rtx"
    rng = np.random.default_rng(0)
    write_capture(path, rng.normal(0, 1, 40), sample_rate_hz=100.0,
                  position_mm=np.linspace(0, 10, 40))
    return path.read_bytes()


def capture_csv_sample() -> bytes:
    path = WORK / "sample.csv"
    write_capture(path, np.arange(30.0), sample_rate_hz=10.0, binary=False)
    return path.read_bytes()


CASES = {
    "rtl": (read_rtl, "f.rtl", (DATA / "x_axis_hand.rtl").read_bytes()),
    "rta": (read_rtl, "f.rta", (DATA / "x_pitch_hand.rta").read_bytes()),
    "csv": (read_table, "f.csv", (DATA / "y_straightness_hand.csv").read_bytes()),
    "whitespace": (lambda p: read_table(p, TableFormat(columns=ColumnMap(position=1,
                                                                         deviation=2))),
                   "f.txt", (DATA / "z_linear_hand.txt").read_bytes()),
    "semicolon": (lambda p: read_table(p, TableFormat(columns=ColumnMap(deviation="Abweichung",
                                                                        run="Lauf"))),
                  "f.csv", (DATA / "x_semicolon_hand.csv").read_bytes()),
    "iso_ecmc": (read_iso_table, "f.dat", (DATA / "ecmc_hand.dat").read_bytes()),
    "iso_columns": (read_iso_table, "f.txt", (DATA / "z_iso_hand.txt").read_bytes()),
    "capture_binary": (read_capture, "f.rtx", capture_sample()),
    "capture_csv": (lambda p: read_capture(p, chunk_bytes=40), "f.csv", capture_csv_sample()),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_reader_fuzz(case):
    reader, name, original = CASES[case]

    @settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(content=mutated(original))
    def run(content: bytes) -> None:
        check(reader, name, content)

    run()


def test_plan_fuzz():
    original = (DATA / "plan.toml").read_bytes()
    for item in DATA.iterdir():
        if item.is_file() and item.suffix != ".toml":
            (WORK / item.name).write_bytes(item.read_bytes())

    @settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow])
    @given(content=mutated(original))
    def run(content: bytes) -> None:
        check(load_plan, "plan.toml", content)

    run()


def test_truncation_at_every_line_of_the_rtl_sample():
    """Exhaustive over the cut point: no prefix of a log is ever partly imported."""
    original = (DATA / "x_axis_hand.rtl").read_bytes()
    lines = original.split(b"\n")
    assert lines[-2].strip() == b"EOF::" and lines[-1] == b""
    for count in range(len(lines) - 1):  # every prefix that stops before EOF::
        content = b"\n".join(lines[:count])
        path = WORK / "cut.rtl"
        path.write_bytes(content)
        with pytest.raises(FormatError) as info:
            read_rtl(path)
        assert info.value.line is not None
