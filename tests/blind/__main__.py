"""``python -m tests.blind SEED FOLDER [--plan P] [--category C]``: write one blind scenario."""

import argparse

from .scenarios import write_scenario


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m tests.blind", description=__doc__)
    parser.add_argument("seed", type=int)
    parser.add_argument("folder")
    parser.add_argument("--plan", help="force a plan, e.g. resources/plans/direct.toml")
    parser.add_argument("--category", choices=["clean", "effects", "outside"])
    parser.add_argument("--kinds", help="comma-separated effect kinds to force, e.g. "
                        "reversal,cosine or time_periodic")
    args = parser.parse_args()
    kinds = args.kinds.split(",") if args.kinds else None
    plan, truth = write_scenario(args.seed, args.folder, args.plan, args.category, kinds)
    effects = ", ".join(
        f"{e['kind']}({e.get('axis') or e.get('line')}, "
        f"visible={e['visibility']['visible_after_rigid_fit']})"
        for e in truth["effects"]) or "none"
    print(f"{plan}: {truth['category']}, plan {truth['plan']['source']}, "
          f"noise {truth['noise']['sigma_um']:.3f} um, effects: {effects}")


main()
