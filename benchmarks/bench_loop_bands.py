"""Are the loop's stated uncertainties honest on machines it was not tuned to? (issue 12)

Each chosen scenario of the blind generator (tests/blind: its own machine, effects, laser and
Renishaw-style files, written without reading volucal's method) is measured again ``--draws``
times: the same machine, effects and session, the readings' noise drawn anew each time. Every
draw is imported and run through ``close_loop`` with the shipped defaults and scored as
``bench_loop_suite.py --generator blind`` scores it. Where the kept effect set is the injected
one, each function's RMS error against the truth (gauge removed, cycles, bumps and surfaces folded
in) is divided by the RMS error its stated covariance predicts, and each squareness error by its
stated standard uncertainty (that of the angle between its axes it is scored as: the
squareness with the slopes of the pair's straightness functions, kept surfaces folded in). The
squareness between the tool's paths that volucal maps over the measured volume
(core/squareness_map.py) is compared with the generator's own paths: at the volume's centre by
the standard uncertainty stated there, at every place of the map the same way, and over the
map's places in µrad.

Honest bands give each quantity a mean square ratio over the draws of 1. A squareness's ratio is
|z| of one Gaussian: beyond 2 in 4.6 % of draws, beyond 3 in 0.27 %; a function's RMS ratio
averages over its stroke and goes beyond them less often. One scenario's worst ratio, picked after
the fact among twenty-odd quantities, says little: the same machine measured again says whether
its bands or its realisation were at fault.

    python benchmarks/bench_loop_bands.py [--seed 590001] [--scenarios 12] [--draws 20]
                                          [--workers 2] [--seeds 57178,56129] [--with-own-noise]

Scenarios are the first ``--scenarios`` seeds from ``--seed`` on whose category is clean or
effects (outside effects have no truth the 21 errors can match), or the ``--seeds`` named. Each
is measured ``--draws`` times with fresh noise, and with ``--with-own-noise`` once more with the
seed's own (the suite's realisation).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import sys
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "independent"))
sys.path.insert(0, str(ROOT))

from volucal.core.errors import SQUARENESS_IDS  # noqa: E402

#: What a squareness's |z| exceeds in this share of draws when its band is honest (Gaussian).
GAUSSIAN_TAIL = {2.0: 0.0455, 3.0: 0.0027}


def _draw(job: tuple[int, int]) -> dict:
    """One scenario measured once: ``job`` is (seed, noise draw; 0 is the seed's own noise)."""
    from score_blind import run_blind

    seed, draw = job
    outcome = run_blind(seed, noise_draw=draw, paths=True)
    ratios = {
        quantity: error / outcome.expected_error[quantity]
        for quantity, error in {**outcome.function_error, **outcome.squareness_error}.items()
        if outcome.expected_error.get(quantity, 0.0) > 0.0
    }
    return {
        "seed": seed,
        "draw": draw,
        "plan": outcome.plan,
        "category": outcome.category,
        "noise_um": outcome.noise,
        "exact": set(outcome.expected) == set(outcome.kept),
        "ratios": ratios,
        "paths": outcome.path_squareness,
        "loop_s": outcome.seconds,
    }


def _chosen(start: int, count: int) -> list[int]:
    """The first ``count`` seeds from ``start`` whose scenario is clean or has catalogue
    effects."""
    from tests.blind.scenarios import build_scenario

    seeds: list[int] = []
    seed = start
    while len(seeds) < count:
        if build_scenario(seed).category != "outside":
            seeds.append(seed)
        seed += 1
    return seeds


def _summary(draws: list[dict]) -> list[str]:
    """Per scenario and pooled: the mean square ratio per quantity and the tails."""
    lines = []
    by_seed: dict[int, list[dict]] = defaultdict(list)
    for d in draws:
        by_seed[d["seed"]].append(d)
    pooled: dict[str, list[float]] = {"squareness": [], "function": []}
    mean_squares: dict[str, list[float]] = {"squareness": [], "function": []}
    for seed, runs in sorted(by_seed.items()):
        first = runs[0]
        exact = [r for r in runs if r["exact"]]
        per_quantity: dict[str, list[float]] = defaultdict(list)
        for r in exact:
            for quantity, ratio in r["ratios"].items():
                per_quantity[quantity].append(ratio)
        squares = {q: float(np.mean(np.square(v))) for q, v in per_quantity.items()}
        for quantity, values in per_quantity.items():
            kind = "squareness" if quantity in SQUARENESS_IDS else "function"
            pooled[kind].extend(values)
            mean_squares[kind].append(squares[quantity])
        worst = sorted(squares.items(), key=lambda kv: -kv[1])[:3]
        own = next((r for r in runs if r["draw"] == 0 and r["exact"]), None)
        own_worst = (
            max(own["ratios"].items(), key=lambda kv: kv[1]) if own is not None else None
        )
        lines.append(
            f"{seed} {first['plan']:<17} {first['category']:<7} noise {first['noise_um']:.3f} "
            f"µm: exact set in {len(exact)} of {len(runs)} draws; mean square ratio, largest: "
            + ", ".join(f"{q} {v:.2f}" for q, v in worst)
            + (
                f"; the seed's own noise: worst {own_worst[0]} {own_worst[1]:.2f}"
                if own_worst is not None
                else ""
            )
        )
    lines.append("")
    for kind in ("squareness", "function"):
        values = np.asarray(pooled[kind])
        squares = np.asarray(mean_squares[kind])
        if not len(values):
            continue
        tails = ", ".join(
            f"beyond {limit:g}: {100 * np.mean(values > limit):.2f} %"
            + (f" (Gaussian {100 * GAUSSIAN_TAIL[limit]:.2f} %)" if kind == "squareness" else "")
            for limit in GAUSSIAN_TAIL
        )
        lines.append(
            f"{kind}: {len(values)} ratios over {len(squares)} quantities; RMS ratio "
            f"{np.sqrt(np.mean(values**2)):.2f}; {tails}; per quantity, mean square ratio over "
            f"the draws: median {np.median(squares):.2f}, above 2 in {int(np.sum(squares > 2))}, "
            f"largest {np.max(squares):.2f}"
        )
    lines += _paths_summary([d for d in draws if d["exact"]])
    return lines


def _paths_summary(draws: list[dict]) -> list[str]:
    """The squareness between the tool's paths (core/squareness_map.py) against the generator's
    paths: at the volume's centre and at every place of the map by the standard uncertainty
    stated there, and over the map's places in µrad."""
    maps = [entry for d in draws for entry in d["paths"].values()]
    if not maps:
        return []
    centre = np.asarray([error / std for error, std, _, _ in maps if std > 0])
    places = np.concatenate([z for _, _, _, z in maps])
    worst_z = np.asarray([np.max(np.abs(z)) for _, _, _, z in maps])
    worst = np.asarray([w for _, _, w, _ in maps])
    return [
        f"squareness between the tool's paths at the volume's centre: {len(centre)} ratios; "
        f"{_ratio_line(centre)}",
        f"  at every place of the {len(maps)} maps: {len(places)} ratios; {_ratio_line(places)}; "
        f"largest |ratio| per map: median {np.median(worst_z):.2f}, 95th percentile "
        f"{np.percentile(worst_z, 95):.2f}, largest {np.max(worst_z):.2f}",
        f"  largest error over the 125 places of each map (µrad): median {np.median(worst):.3f}, "
        f"95th percentile {np.percentile(worst, 95):.3f}, largest {np.max(worst):.3f}; "
        f"within 2 µrad in {int(np.sum(worst <= 2.0))} of {len(worst)}",
    ]


def _ratio_line(ratios: np.ndarray) -> str:
    tails = ", ".join(
        f"beyond {limit:g}: {100 * np.mean(np.abs(ratios) > limit):.2f} %"
        f" (Gaussian {100 * GAUSSIAN_TAIL[limit]:.2f} %)"
        for limit in GAUSSIAN_TAIL
    )
    return f"RMS ratio {np.sqrt(np.mean(ratios**2)):.2f}; {tails}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=590001)
    parser.add_argument("--scenarios", type=int, default=12)
    parser.add_argument("--seeds", type=str, help="comma-separated seeds instead")
    parser.add_argument("--draws", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--with-own-noise",
        action="store_true",
        help="measure each scenario once more with the seed's own noise",
    )
    args = parser.parse_args()
    # one BLAS thread per spawned worker, as bench_loop_suite.py
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    seeds = (
        [int(s) for s in args.seeds.split(",")]
        if args.seeds
        else _chosen(args.seed, args.scenarios)
    )
    first = 0 if args.with_own_noise else 1
    jobs = [(seed, draw) for seed in seeds for draw in range(first, args.draws + 1)]
    started = time.perf_counter()
    spawn = multiprocessing.get_context("spawn")
    draws = []
    with ProcessPoolExecutor(max_workers=args.workers, mp_context=spawn) as pool:
        for d in pool.map(_draw, jobs, chunksize=1):
            draws.append(d)
            worst = max(d["ratios"].items(), key=lambda kv: kv[1], default=("-", 0.0))
            print(
                f"{d['seed']} draw {d['draw']:>2} {d['category']:<7} "
                f"{'exact' if d['exact'] else 'set differs'}; worst ratio {worst[0]} "
                f"{worst[1]:.2f} ({d['loop_s']:.1f} s)",
                flush=True,
            )
    print()
    print("\n".join(_summary(draws)))
    print(
        f"\n{len(seeds)} scenarios × {args.draws + 1 - first} draws on {args.workers} workers in "
        f"{(time.perf_counter() - started) / 60:.1f} min"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
