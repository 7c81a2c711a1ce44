"""Proof with a real controller: LinuxCNC's HAL runs volucal's thermal compensation snippet.

The exported ``.hal`` file is sourced into LinuxCNC's HAL (``halrun``, the uspace realtime
environment of the Debian package linuxcnc-uspace, no hardware) with a 1 ms thread. HAL signals
carry the input temperatures; a HAL ``integ`` of 1 counts the thread's elapsed time exactly, so the
number of filter steps is known. Checks, against volucal's own model evaluation
(:meth:`ThermalModel.predict`, which knows nothing of HAL):

1. after the start-up load, at constant temperatures, the error and compensation signals equal
   the model's steady-state prediction, and the check-point file's values;
2. after a step of every temperature, each ``lowpass`` has moved by exactly the first-order
   response over the elapsed steps, and the error signal equals the model's prediction for the
   record "held at the first state, then stepped".

The model has a lagged linear term, a static term and a lagged squared term, so every HAL path of
the exporter runs. LinuxCNC's realtime part refuses to run as root: as root the test runs
``halrun`` as the user ``volucal-lcnc`` (created if missing). Skips when LinuxCNC is absent, unless
CI is set.
"""

from __future__ import annotations

import csv
import json
import os
import pwd
import shutil
import subprocess
import tempfile
import textwrap
from pathlib import Path

import numpy as np
import pytest
from volucal.core.compensation.export_thermal import ThermalExportOptions, export_thermal
from volucal.core.thermal_model import ThermalModel, ThermalTerm

pytestmark = pytest.mark.linuxcnc

USER = "volucal-lcnc"
PERIOD_S = 0.001


@pytest.fixture(scope="module")
def halrun() -> list[str]:
    if shutil.which("halrun") is None:
        if os.environ.get("CI"):
            pytest.fail("CI is set but LinuxCNC is not installed (halrun missing): "
                        ".ci/install-linuxcnc.sh should have installed linuxcnc-uspace")
        pytest.skip("LinuxCNC is not installed (halrun missing); install the Debian package "
                    "linuxcnc-uspace to run this test")
    if os.geteuid() != 0:
        return ["halrun"]
    try:
        pwd.getpwnam(USER)
    except KeyError:
        subprocess.run(["useradd", "--create-home", "--shell", "/bin/sh", USER], check=True,
                       timeout=30)
    return ["runuser", "-u", USER, "--", "halrun"]


def _model() -> ThermalModel:
    terms = (
        ThermalTerm("spindle nose", 900.0, 1, 31.5),
        ThermalTerm("bed", 0.0, 1, 21.0),
        ThermalTerm("motor", 300.0, 1, 40.0),
        ThermalTerm("motor", 300.0, 2, 40.0),
    )
    return ThermalModel("Z drift", "um", 4.25, terms, np.array([2.5, -1.75, 0.6, 0.045]),
                        np.diag([0.01, 0.04, 0.02, 0.01, 0.001]))


def _run(halrun: list[str], folder: Path, script: str) -> None:
    path = folder / "test.hal"
    path.write_text(script)
    if halrun[0] == "runuser":
        subprocess.run(["chown", "-R", USER, str(folder)], check=True, timeout=30)
    done = subprocess.run([*halrun, "-f", str(path)], capture_output=True, text=True,
                          timeout=120, cwd=folder)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]


READER = textwrap.dedent(
    """\
    import json
    import sys

    import hal

    tag, *names = sys.argv[1:]
    probe = hal.component(f"volucal_probe_{tag}")
    probe.ready()
    with open("values.jsonl", "a") as handle:
        for name in names:
            handle.write(json.dumps([f"{tag}:{name}", hal.get_value(name)]) + "\\n")
    probe.exit()
    """
)


def _values(folder: Path) -> dict[str, float]:
    """What the reader wrote: full-precision values (halcmd prints only 7 digits)."""
    values = {}
    for line in (folder / "values.jsonl").read_text().splitlines():
        key, value = json.loads(line)
        values[key] = float(value)
    return values


def test_hal_snippet_computes_the_model(halrun: list[str]) -> None:
    model = _model()
    folder = Path(tempfile.mkdtemp(prefix="volucal-thermal-hal-"))
    folder.chmod(0o755)
    try:
        export = export_thermal(model, folder, ThermalExportOptions(period_s=PERIOD_S,
                                                                    load_delay_s=0.2))
        hal = folder / f"{export.prefix}.hal"
        first = {"spindle nose": 35.25, "bed": 22.5, "motor": 47.0}
        second = {"spindle nose": 38.0, "bed": 21.75, "motor": 52.5}
        signals = export.input_signals
        watched = [export.error_signal, export.comp_signal, *(
            f"{name}-out" for name in export.lag_instances.values())]

        (folder / "reader.py").write_text(READER)
        python = shutil.which("python3", path="/usr/bin:/bin") or "python3"

        def read(tag: str) -> str:
            return f"loadusr -w {python} reader.py {tag} elapsed.out {' '.join(watched)}"

        script = textwrap.dedent(f"""\
            loadrt threads name1=servo-thread period1={int(PERIOD_S * 1e9)}
            source {hal}
            loadrt integ names=elapsed
            addf elapsed servo-thread
            setp elapsed.in 1
            """)
        script += "".join(f"sets {signals[s]} {v!r}\n" for s, v in first.items())
        script += "start\nloadusr -w sleep 1\nstop\n" + read("a") + "\n"
        script += "".join(f"sets {signals[s]} {v!r}\n" for s, v in second.items())
        script += "start\nloadusr -w sleep 1\nstop\n" + read("b") + "\n"
        _run(halrun, folder, script)
        values = _values(folder)

        # 1. steady state after the start-up load
        steady = model.predict_steady(first)
        assert values[f"a:{export.error_signal}"] == pytest.approx(steady, abs=1e-9)
        assert values[f"a:{export.comp_signal}"] == pytest.approx(-steady / 1000, abs=1e-12)
        check = folder / f"{export.prefix}-check.csv"
        rows = list(csv.reader(line for line in check.read_text().splitlines()
                               if not line.startswith("#")))
        assert float(rows[1][-2]) == pytest.approx(model.intercept)  # at the references

        # 2. the step response: N thread steps of each lowpass, then the weighted sum
        steps = round((values["b:elapsed.out"] - values["a:elapsed.out"]) / PERIOD_S)
        assert steps > 100  # the thread ran
        elapsed_s = steps * PERIOD_S
        for (sensor, tau), name in export.lag_instances.items():
            gain = -np.expm1(-PERIOD_S / tau)
            expected = second[sensor] + (first[sensor] - second[sensor]) * (1 - gain) ** steps
            assert values[f"b:{name}-out"] == pytest.approx(expected, abs=1e-9)
        # volucal's model over the record "held at the first state, then stepped"
        time_s = np.array([0.0, 1e-9, elapsed_s])
        record = {s: np.array([first[s], second[s], second[s]]) for s in first}
        predicted = float(model.predict(time_s, record)[-1])
        assert values[f"b:{export.error_signal}"] == pytest.approx(predicted, abs=1e-6)
        assert values[f"b:{export.comp_signal}"] == pytest.approx(-predicted / 1000, abs=1e-9)
        # the step moved the prediction well beyond the tolerance
        assert abs(predicted - steady) > 1.0
    finally:
        shutil.rmtree(folder, ignore_errors=True)
