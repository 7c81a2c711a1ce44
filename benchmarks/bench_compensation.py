"""Compensation benchmarks: tables, the inverse against a per-point loop, NC rewriting, exports,
and the predicted compensation rates on a paper-like machine with reversal.

Run: ``python benchmarks/bench_compensation.py``. Prints the measured numbers.
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# The paper-like machine of the tests (smooth errors of a precision 400 mm mill).
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "core"))
from compensation_models import paper_like_model  # noqa: E402
from volucal.core.compensation import (  # noqa: E402
    FORMATS,
    ExportOptions,
    ModelSource,
    ReversalSource,
    build_tables,
    export_model,
    invert,
    rewrite_program,
    standard_compensations,
    verify,
)


def timed(function, repeat: int = 3):
    best = math.inf
    value = None
    for _ in range(repeat):
        start = time.perf_counter()
        value = function()
        best = min(best, time.perf_counter() - start)
    return best, value


def naive_invert(source, nominal: np.ndarray) -> np.ndarray:
    """The obvious loop: one point at a time, fixed-point iteration."""
    out = np.empty_like(nominal)
    for i, n in enumerate(nominal):
        c = n.copy()
        for _ in range(50):
            updated = n - source.error_um(c[None, :])[0] / 1e3
            done = np.max(np.abs(updated - c)) * 1e3 <= 1e-6
            c = updated
            if done:
                break
        out[i] = c
    return out


def program(moves: int, seed: int = 0) -> str:
    rng = np.random.default_rng(seed)
    lines = ["G21 G90 G17", "G0 X10 Y10 Z50", "G1 Z5 F800"]
    x, y = 10.0, 10.0
    for i in range(moves):
        if i % 4 == 3 and x < 360.0:
            lines.append(f"G2 X{x + 20:.3f} Y{y:.3f} I10 J0")
            x += 20
        else:
            x, y = rng.uniform(20, 380, size=2)
            lines.append(f"G1 X{x:.3f} Y{y:.3f}")
    lines.append("M2")
    return "\n".join(lines) + "\n"


def main() -> None:
    model = paper_like_model(seed=0)
    source = ReversalSource(ModelSource(model), {"X": 4.0, "Y": lambda y: 2.0 + 0.005 * y})
    print("volucal compensation benchmarks (paper-like 400 x 400 x 350 mm machine, tool 200 mm)")

    t, tables = timed(lambda: build_tables(source))
    grid = tables.grid
    assert grid is not None
    print(
        f"build_tables (10 mm axis/cross tables, 25 mm grid of {grid.error_um[..., 0].size} "
        f"nodes): {t * 1e3:.1f} ms"
    )

    rng = np.random.default_rng(1)
    big = rng.uniform([0, 0, 0], [400, 400, 350], size=(1_000_000, 3))
    t_fast, result = timed(lambda: invert(source, big, np.ones(3)), repeat=1)
    small = big[:2000]
    t_naive, commanded = timed(lambda: naive_invert(ModelSource(model), small), repeat=1)
    reference = invert(ModelSource(model), small).commanded_mm
    agreement = np.max(np.abs(commanded - reference)) * 1e3
    print(
        f"inverse, 1e6 points: {t_fast:.2f} s ({1e6 / t_fast:,.0f} points/s, "
        f"{result.iterations} iterations, residual {result.residual_um:.1e} um); "
        f"per-point loop: {2000 / t_naive:,.0f} points/s -> speed-up "
        f"{t_naive / 2000 * 1e6 / t_fast:,.0f}x (agreement {agreement:.1e} um)"
    )

    t, verification = timed(
        lambda: verify(source, standard_compensations(source, tables)), repeat=1
    )
    print(
        f"verification ({verification.points} points x {len(verification.approaches)} "
        f"approaches, {len(verification.methods)} methods): {t:.2f} s"
    )
    print("predicted compensation rates, RMS-based % (X / Y / Z):")
    for name, method in verification.methods.items():
        rates = method.rates.rms_percent
        print(f"  {name:<30} {rates['X']:6.1f} {rates['Y']:6.1f} {rates['Z']:6.1f}")

    text = program(2000)
    t, rewritten = timed(lambda: rewrite_program(source, text), repeat=1)
    print(
        f"NC rewriting, {rewritten.moves_in} moves ({len(text.splitlines())} lines): {t:.2f} s "
        f"({rewritten.moves_in / t:,.0f} moves/s), {rewritten.points_out} points written, "
        f"max correction {rewritten.max_correction_um:.1f} um"
    )

    with tempfile.TemporaryDirectory() as folder:
        part = Path(folder) / "part.ngc"
        part.write_text(program(200))
        for fmt in FORMATS:
            t, exported = timed(
                lambda fmt=fmt: export_model(
                    source, fmt, Path(folder) / fmt, ExportOptions(program=part)
                ),
                repeat=1,
            )
            rates = exported.verification.methods["export"].rates.rms_percent
            print(
                f"export {fmt:<10} {t * 1e3:7.1f} ms  as loaded: "
                f"{rates['X']:6.1f} {rates['Y']:6.1f} {rates['Z']:6.1f} % (X / Y / Z)"
            )


if __name__ == "__main__":
    main()
