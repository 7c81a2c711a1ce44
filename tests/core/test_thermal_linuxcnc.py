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
import re
import shutil
import signal
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


def test_hal_snippet_computes_the_model(halrun: list[str], one_session: None) -> None:
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


EOFFSET_DISPLAY = textwrap.dedent(
    '''\
    #!/usr/bin/python3
    """Display program of the test: home, move, set the temperatures, read the offset."""
    import json
    import subprocess
    import time

    import hal
    import linuxcnc

    setup = json.load(open("setup.json"))
    result = {}
    try:
        probe = hal.component("volucal_probe")
        probe.ready()
        stat = linuxcnc.stat()
        command = linuxcnc.command()

        def wait(predicate, timeout=30.0):
            start = time.time()
            while time.time() - start < timeout:
                stat.poll()
                if predicate():
                    return
                time.sleep(0.02)
            raise RuntimeError("timed out waiting for LinuxCNC")

        command.state(linuxcnc.STATE_ESTOP_RESET)
        command.wait_complete()
        command.state(linuxcnc.STATE_ON)
        command.wait_complete()
        command.mode(linuxcnc.MODE_MANUAL)
        command.wait_complete()
        command.home(-1)
        command.wait_complete()
        wait(lambda: all(stat.homed[:3]))
        command.mode(linuxcnc.MODE_MDI)
        command.wait_complete()
        command.mdi("G0 X100 Y100 Z100")
        command.wait_complete(60)
        wait(lambda: stat.interp_state == linuxcnc.INTERP_IDLE and stat.inpos)
        for signal, value in setup["temperatures"].items():
            subprocess.run(["halcmd", "sets", signal, repr(value)], check=True)
        # wait until the requested offset is non-zero and reached (external offsets ramp in
        # within the axis' OFFSET_AV_RATIO share of velocity and acceleration)
        start = time.time()
        while time.time() - start < 30:
            request = hal.get_value("axis.z.eoffset-request")
            if request != 0 and abs(hal.get_value("axis.z.eoffset") - request) < 1e-6:
                break
            time.sleep(0.05)
        time.sleep(0.1)
        result = {name: hal.get_value(name) for name in setup["read"]}
    except Exception as exc:
        result["error"] = repr(exc)
    with open("result.json", "w") as handle:
        json.dump(result, handle)
    '''
)


#: A machine without hardware in a few lines (LinuxCNC's basic_sim.tcl loads lowpass and scale
#: itself, which is the case the ``loaded`` option is for: here the configuration loads lowpass
#: with its own instance and the names the snippet asks it to add).
SIM_HAL = textwrap.dedent(
    """\
    loadrt [KINS]KINEMATICS
    loadrt [EMCMOT]EMCMOT servo_period_nsec=[EMCMOT]SERVO_PERIOD num_joints=[KINS]JOINTS
    loadrt lowpass names=spindle-mass,{lag_names}
    addf motion-command-handler servo-thread
    addf motion-controller servo-thread
    addf spindle-mass servo-thread
    net j0 joint.0.motor-pos-cmd => joint.0.motor-pos-fb
    net j1 joint.1.motor-pos-cmd => joint.1.motor-pos-fb
    net j2 joint.2.motor-pos-cmd => joint.2.motor-pos-fb
    net estop-loop iocontrol.0.user-enable-out => iocontrol.0.emc-enable-in
    net tool-prep-loop iocontrol.0.tool-prepare => iocontrol.0.tool-prepared
    net tool-change-loop iocontrol.0.tool-change => iocontrol.0.tool-changed
    """
)


def _eoffset_ini(halfiles: list[str]) -> str:
    lines = [
        "[EMC]", "VERSION = 1.1", "MACHINE = volucal-thermal-test",
        "[DISPLAY]", "DISPLAY = ./display.py",
        "[TASK]", "TASK = milltask", "CYCLE_TIME = 0.001",
        "[RS274NGC]", "PARAMETER_FILE = sim.var",
        "[EMCMOT]", "EMCMOT = motmod", "SERVO_PERIOD = 1000000", "COMM_TIMEOUT = 1.0",
        "[EMCIO]", "EMCIO = io", "CYCLE_TIME = 0.100",
        "[HAL]", *(f"HALFILE = {name}" for name in halfiles),
        "[TRAJ]", "COORDINATES = XYZ", "LINEAR_UNITS = mm", "ANGULAR_UNITS = degree",
        "MAX_LINEAR_VELOCITY = 200",
        "[KINS]", "JOINTS = 3", "KINEMATICS = trivkins coordinates=XYZ",
    ]
    for index, axis in enumerate("XYZ"):
        limits = ["MIN_LIMIT = -1", "MAX_LIMIT = 401", "MAX_VELOCITY = 200",
                  "MAX_ACCELERATION = 2000"]
        lines += [f"[AXIS_{axis}]", *limits]
        if axis == "Z":
            lines.append("OFFSET_AV_RATIO = 0.2")
        lines += [f"[JOINT_{index}]", "TYPE = LINEAR", "HOME_SEQUENCE = 0", *limits]
    return "\n".join(lines) + "\n"


def test_compensation_moves_the_axis_through_external_offsets(halrun: list[str],
                                                              one_session: None) -> None:
    """A whole simulated LinuxCNC machine: the exported snippet and its external-offset wiring
    are HAL files of the INI; with the temperatures set, the Z axis carries the compensation."""
    if shutil.which("linuxcnc") is None:
        pytest.skip("the linuxcnc launcher is not installed")
    # a lag of 20 ms settles within the test; the start-up load sees the signals still at 0
    model = ThermalModel("Z drift", "um", 3.0, (ThermalTerm("spindle", 0.02, 1, 30.0),
                                                ThermalTerm("bed", 0.0, 1, 21.0)),
                         np.array([4.5, -2.0]), np.eye(3) * 0.01)
    temperatures = {"spindle": 36.5, "bed": 22.25}
    error_um = model.predict_steady(temperatures)  # 3 + 29.25 − 2.5 = 29.75 µm
    count_mm = 1e-5
    folder = Path(tempfile.mkdtemp(prefix="volucal-thermal-lcnc-"))
    folder.chmod(0o755)
    process = None
    try:
        export = export_thermal(model, folder, ThermalExportOptions(
            axis="z", count_mm=count_mm, loaded=("lowpass",)))
        snippet = (folder / f"{export.prefix}.hal").read_text()
        assert not re.search(r"^loadrt lowpass", snippet, flags=re.M)
        # follow the snippet's instruction: the lag names go on the configuration's own line
        lag_names = re.search(r"add to its 'loadrt lowpass' line the names (\S+)",
                              snippet).group(1)
        (folder / "sim.hal").write_text(SIM_HAL.format(lag_names=lag_names))
        halfiles = ["sim.hal", f"{export.prefix}.hal", f"{export.prefix}-eoffset.hal"]
        (folder / "linuxcnc.ini").write_text(_eoffset_ini(halfiles))
        (folder / "display.py").write_text(EOFFSET_DISPLAY)
        (folder / "display.py").chmod(0o755)
        (folder / "sim.var").write_text("")
        read = ["axis.z.eoffset", "axis.z.eoffset-request", "joint.2.pos-cmd",
                "joint.2.motor-pos-cmd", "axis.z.pos-cmd", "motion.eoffset-active"]
        (folder / "setup.json").write_text(json.dumps({
            "temperatures": {export.input_signals[s]: v for s, v in temperatures.items()},
            "read": read}))
        prefix = halrun[:-1]
        if prefix:
            subprocess.run(["chown", "-R", USER, str(folder)], check=True, timeout=30)
        with open(folder / "linuxcnc.log", "w") as log:
            process = subprocess.Popen([*prefix, "linuxcnc", "linuxcnc.ini"], cwd=folder,
                                       stdout=log, stderr=subprocess.STDOUT,
                                       start_new_session=True)
            process.wait(timeout=120)
        log_text = (folder / "linuxcnc.log").read_text(errors="replace")
        assert (folder / "result.json").exists(), log_text[-3000:]
        result = json.loads((folder / "result.json").read_text())
        assert "error" not in result, f"{result['error']}\n{log_text[-3000:]}"
        # the offset is the compensation, −error, within one count (truncated toward zero)
        offset = result["axis.z.eoffset"]
        # LinuxCNC's offset planner stops within a fraction of a nanometre of the request
        assert offset == pytest.approx(result["axis.z.eoffset-request"], abs=1e-6)
        assert offset == pytest.approx(-error_um / 1000, abs=count_mm + 1e-6)
        assert abs(offset) <= abs(error_um / 1000) + 1e-6
        # the joint carries the commanded Z plus the compensation
        assert result["axis.z.pos-cmd"] == pytest.approx(100.0, abs=1e-9)
        assert result["joint.2.pos-cmd"] == pytest.approx(100.0 + offset, abs=1e-9)
        assert result["joint.2.motor-pos-cmd"] == pytest.approx(100.0 + offset, abs=1e-9)
    finally:
        if process is not None and process.poll() is None:
            os.killpg(process.pid, signal.SIGTERM)
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait(timeout=20)
        shutil.rmtree(folder, ignore_errors=True)
