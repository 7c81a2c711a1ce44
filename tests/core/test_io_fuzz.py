"""Fuzzing the readers (tests/core/fuzz_corpus.py): mutated demo logs, hand-written samples and
real files — truncations, byte flips, swapped columns, header-count, size and value attacks.
Whatever the bytes, the only exception that escapes is the project's own (UserError, one line,
naming the file) and nothing accepted holds a value no measurement produces.

Seeded: the same cases on every run. benchmarks/bench_fuzz.py runs many more and reports the
counts by outcome and the peak memory."""

import random
import tempfile
from pathlib import Path

import pytest
from fuzz_corpus import mutate, run_case, seeds
from volucal.core.io.rtl import read_rtl
from volucal.core.userror import FormatError

CASES = {"rtl": 300, "rta": 200, "table": 300, "iso230-2": 300, "capture": 300, "plan": 150}
WORK = Path(tempfile.mkdtemp(prefix="volucal-fuzz-"))
SEEDS = seeds(WORK)
DATA = Path(__file__).resolve().parents[1] / "data" / "io"


@pytest.mark.parametrize("kind", sorted(CASES))
def test_reader_fuzz(kind):
    corpus = SEEDS[kind]
    assert corpus, kind
    for seed in corpus:  # every seed is accepted as it is
        assert run_case(seed, seed.content, WORK).kind == "accepted", seed.origin
    rng = random.Random(f"volucal-fuzz-{kind}")
    outcomes = {"clean error": 0, "accepted": 0}
    for case in range(CASES[kind]):
        seed = corpus[case % len(corpus)]
        content, applied = mutate(seed.content, rng)
        outcome = run_case(seed, content, WORK)
        assert outcome.kind != "other", (seed.origin, applied, case, outcome.detail)
        outcomes[outcome.kind] += 1
    assert outcomes["clean error"] > CASES[kind] // 4  # the mutations do reach the checks


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


def test_binary_capture_cut_at_every_byte_of_its_tail():
    """A capture one byte short (or more) never reads the newline before EOF:: as data."""
    seed = next(s for s in SEEDS["capture"] if s.name.endswith(".rtx"))
    for cut in range(1, 64):
        content = seed.content[:-cut - 7] + seed.content[-7:]  # bytes lost before "\nEOF::\n"
        outcome = run_case(seed, content, WORK)
        assert outcome.kind == "clean error", (cut, outcome)
