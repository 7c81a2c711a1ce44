"""The loop suite's plans moved onto machines of other sizes (issue 12).

Every plan of the blind generator (tests/blind/scenarios.py ``PLANS``) is laid out on the paper's
machine: 400 × 400 × 350 mm, 16 mm screw leads, tool 200 mm below the spindle. A machine of
another size keeps the same lines at the same places relative to its strokes: each coordinate of
a line's start is scaled by its axis' stroke ratio, a diagonal keeps its corners (its direction is
the scaled one, normalised), axis-parallel lines keep their directions, straightness and angular
lines their sensitive directions. The optics stay where the plan puts them relative to the tool:
a reflector at the paper's tool offset moves to the new one, and a lever arm beside it (the 150 mm
offsets) is scaled by the machine's ``lever`` (the optics of a small machine sit closer). A
machine of another chain (the gantry) takes its own: the same lines, multiplied in its order.

    python benchmarks/machines.py DIR     # writes DIR/<machine>/<plan>.toml for inspection
"""

from __future__ import annotations

import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
AXES = ("X", "Y", "Z")


@dataclass(frozen=True)
class MachineSize:
    """A 3-axis machine the plans are moved onto: strokes (mm), screw leads (mm), the tool's
    offset below the spindle (mm) and the scale of the optics' lever arms."""

    name: str
    stroke_mm: dict[str, tuple[float, float]]
    screw_lead_mm: dict[str, float]
    tool_mm: float
    lever: float
    description: str
    chain: str = "WXYFZT"


MACHINES = {
    "large": MachineSize(
        "large",
        {"X": (0.0, 1000.0), "Y": (0.0, 600.0), "Z": (0.0, 500.0)},
        {"X": 20.0, "Y": 10.0, "Z": 10.0},
        250.0,
        1.0,
        "a 1000 × 600 × 500 mm bed mill, 20 mm lead on X, 10 mm on Y and Z, tool 250 mm",
    ),
    "small": MachineSize(
        "small",
        {"X": (0.0, 250.0), "Y": (0.0, 200.0), "Z": (0.0, 150.0)},
        {"X": 5.0, "Y": 5.0, "Z": 4.0},
        120.0,
        0.6,
        "a 250 × 200 × 150 mm bench-top mill, 5 mm leads on X and Y, 4 mm on Z, tool 120 mm",
    ),
    "gantry": MachineSize(
        "gantry",
        {"X": (0.0, 2000.0), "Y": (0.0, 3000.0), "Z": (0.0, 500.0)},
        {"X": 20.0, "Y": 25.0, "Z": 10.0},
        200.0,
        1.5,
        "a 2000 × 3000 × 500 mm gantry mill (chain WFYXZT: the bridge moves along Y and carries "
        "the X carriage, which carries Z), 20 mm lead on X, 25 mm on Y, 10 mm on Z, tool 200 mm",
        "WFYXZT",
    ),
}


def _toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (int, float)):
        return repr(float(value)) if isinstance(value, float) else str(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"cannot write {value!r} to TOML")


def moved_plan(source: Path, machine: MachineSize) -> str:
    """The plan.toml text of ``source`` moved onto ``machine`` (module docstring)."""
    document = tomllib.loads(source.read_text(encoding="utf-8"))
    old = document["machine"]
    old_stroke = {a: tuple(float(v) for v in old["stroke"][a]) for a in AXES}
    old_tool = np.asarray(old.get("tool_offset", [0.0, 0.0, 0.0]), float)
    new_tool = np.array([0.0, 0.0, machine.tool_mm])

    def scaled(point: list[float]) -> list[float]:
        out = []
        for i, axis in enumerate(AXES):
            lo, hi = old_stroke[axis]
            new_lo, new_hi = machine.stroke_mm[axis]
            out.append(round(new_lo + (float(point[i]) - lo) * (new_hi - new_lo) / (hi - lo), 6))
        return out

    def ratio(axis: str) -> float:
        lo, hi = old_stroke[axis]
        new_lo, new_hi = machine.stroke_mm[axis]
        return (new_hi - new_lo) / (hi - lo)

    lines = []
    for entry in document["line"]:
        moved = dict(entry)
        moved["start"] = scaled(entry["start"])
        direction = np.asarray(entry["direction"], float)
        if np.count_nonzero(np.abs(direction) > 1e-12) > 1:
            direction = direction * np.array([ratio(a) for a in AXES])
            direction /= np.linalg.norm(direction)
        moved["direction"] = [round(float(c), 9) for c in direction]
        if "reflector" in entry:
            lever = np.asarray(entry["reflector"], float) - old_tool
            moved["reflector"] = [round(float(c), 6) for c in new_tool + machine.lever * lever]
        lines.append(moved)
    header = {
        "name": f"{old.get('name', source.stem)}, moved onto {machine.description}",
        "chain": machine.chain,
        "stroke": {a: list(machine.stroke_mm[a]) for a in AXES},
        "screw_lead": dict(machine.screw_lead_mm),
        "tool_offset": [float(c) for c in new_tool],
    }
    text = [
        f"# {source.relative_to(ROOT)} moved onto {machine.description}",
        "# (benchmarks/machines.py)",
        "",
        "[machine]",
    ]
    text += [f"{k} = {_toml_value(v)}" for k, v in header.items()]
    for key in old:
        if key not in header:
            raise ValueError(f"{source}: [machine] {key} is not moved by benchmarks/machines.py")
    for key in document:
        if key not in ("machine", "line"):
            raise ValueError(f"{source}: table [{key}] is not moved by benchmarks/machines.py")
    for moved in lines:
        text += ["", "[[line]]"] + [f"{k} = {_toml_value(v)}" for k, v in moved.items()]
    return "\n".join(text) + "\n"


def write_plans(folder: Path, machine: MachineSize, sources: list[str]) -> dict[str, Path]:
    """Each of ``sources`` (paths relative to the repository) moved onto ``machine``, written to
    ``folder``; the written path of each source."""
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for source in sources:
        path = ROOT / source
        name = "demo" if path.parent.name == "demo" else path.stem
        target = folder / f"{name}.toml"
        target.write_text(moved_plan(path, machine), encoding="utf-8")
        out[source] = target
    return out


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    from tests.blind.scenarios import PLANS

    for size in MACHINES.values():
        for source, path in write_plans(Path(sys.argv[1]) / size.name, size, list(PLANS)).items():
            print(f"{source} -> {path}")
