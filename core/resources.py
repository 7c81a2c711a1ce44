"""Where the installed resources (demo data set, plan presets, icons) are."""

from __future__ import annotations

from pathlib import Path

import volucal


def resources_dir() -> Path:
    return Path(volucal.__file__).resolve().parent / "resources"


def demo_plan() -> Path:
    return resources_dir() / "demo" / "plan.toml"


def plan_presets() -> dict[str, Path]:
    return {p.stem: p for p in sorted((resources_dir() / "plans").glob("*.toml"))}
