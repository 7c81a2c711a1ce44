"""Regenerate the embedded demo data set: `python resources/demo/make_demo.py`.

The demo machine is the paper's XYTZ mill (400 × 400 × 350 mm, 16 mm screw leads, 200 mm tool)
simulated by volucal's virtual machine with smooth ground-truth errors of realistic size and two
effects the 21-error model lacks: a 4 µm reversal on X and a 1.2 µm screw cycle at the 16 mm lead
on Y. It is measured with a full, redundant plan (direct optics per axis, extra parallel lines,
face, offset and body diagonals; targets about every 6 mm with irregular spacing, 5 bidirectional
runs, 0.15 µm noise) and written as Renishaw-style .rtl/.rta logs plus plan.toml.
"""

from pathlib import Path

from volucal.core import plans
from volucal.core.simulate import DEMO_JITTER_MM, DEMO_STEP_MM, demo_machine, write_session

HERE = Path(__file__).resolve().parent


def main() -> None:
    machine = demo_machine()
    lines = plans.full(machine.machine, DEMO_STEP_MM, DEMO_JITTER_MM)
    measurement = machine.measure(lines)
    for old in (HERE / "logs").glob("*.rt?"):
        old.unlink()
    path = write_session(measurement, HERE)
    print(f"wrote {len(lines)} lines and {path}")


if __name__ == "__main__":
    main()
