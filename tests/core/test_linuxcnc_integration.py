"""Proof with a real controller: LinuxCNC loads our COMP_FILEs and runs our rewritten programs.

A simulated 3-axis LinuxCNC machine (Debian package linuxcnc-uspace, no hardware) is started with
an INI whose joints point at volucal's exported COMP_FILEs (X and Z type 0, Y type 1). A small
display program of our own, run by LinuxCNC in place of a GUI, homes the machine, commands moves
in both directions through the ``linuxcnc`` Python module, and reads each joint's HAL pins
``pos-cmd``, ``motor-pos-cmd`` and ``backlash-corr`` (the compensation LinuxCNC applies). They
must carry our compensation values, interpolated as LinuxCNC does (linear, end values held,
forward/reverse column by the direction of the last motion), within 0.1 µm. Nothing listens on
the network: the display talks to LinuxCNC through its shared memory.

Then LinuxCNC's own G-code interpreter (``rs274 -g``) runs a program rewritten by volucal: it
must accept it and reach exactly the points we wrote; with an error-free source the rewritten
arcs must lie on the arcs LinuxCNC itself interprets from the original program.

LinuxCNC's realtime part refuses to run as root: as root the test runs LinuxCNC as the user
``volucal-lcnc`` (created if missing). It skips when LinuxCNC is not installed, unless the
environment variable CI is set (then ``.ci/install-linuxcnc.sh`` must have installed it).
"""

from __future__ import annotations

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
from compensation_models import paper_like_model
from volucal.core.compensation import (
    ExportOptions,
    ModelSource,
    ReversalSource,
    export_model,
    rewrite_program,
)
from volucal.core.errors import ErrorModel

pytestmark = pytest.mark.linuxcnc

USER = "volucal-lcnc"
TOOLS = ("linuxcnc", "halcmd", "rs274")
TIMEOUT_S = 120


@pytest.fixture(scope="module")
def linuxcnc_available() -> None:
    missing = [tool for tool in TOOLS if shutil.which(tool) is None]
    if missing:
        if os.environ.get("CI"):
            pytest.fail(
                f"CI is set but LinuxCNC is not installed ({', '.join(missing)} missing): "
                ".ci/install-linuxcnc.sh should have installed linuxcnc-uspace"
            )
        pytest.skip(
            f"LinuxCNC is not installed ({', '.join(missing)} missing); install the Debian "
            "package linuxcnc-uspace (.ci/install-linuxcnc.sh) to run this test"
        )


def _source() -> ReversalSource:
    """The paper-like machine with reversal on X (constant) and Y (growing along Y)."""
    return ReversalSource(
        ModelSource(paper_like_model(seed=3)),
        {"X": 4.0, "Y": lambda y: 2.0 + 0.005 * np.asarray(y)},
    )


def _run_as() -> list[str]:
    """Command prefix that runs LinuxCNC as a non-root user."""
    if os.geteuid() != 0:
        return []
    try:
        pwd.getpwnam(USER)
    except KeyError:
        subprocess.run(
            ["useradd", "--create-home", "--shell", "/bin/sh", USER], check=True, timeout=30
        )
    return ["runuser", "-u", USER, "--"]


DISPLAY = textwrap.dedent(
    '''\
    #!/usr/bin/python3
    """Display program for the volucal test: run the moves, read the HAL pins, exit."""
    import json
    import sys
    import time

    import hal
    import linuxcnc

    result = {"readings": []}
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
        for line in json.load(open("moves.json")):
            command.mdi(line)
            command.wait_complete(60)
            wait(lambda: stat.interp_state == linuxcnc.INTERP_IDLE and stat.inpos)
            time.sleep(0.05)
            joints = []
            for j in range(3):
                joints.append({
                    pin: hal.get_value(f"joint.{j}.{pin}")
                    for pin in ("pos-cmd", "motor-pos-cmd", "backlash-corr")
                })
            result["readings"].append({"mdi": line, "joints": joints})
    except Exception as exc:
        result["error"] = repr(exc)
    with open("result.json", "w") as handle:
        json.dump(result, handle)
    '''
)


def _ini(stroke: dict[str, tuple[float, float]], comp: dict[int, tuple[str, int]]) -> str:
    lines = [
        "[EMC]",
        "VERSION = 1.1",
        "MACHINE = volucal-test",
        "[DISPLAY]",
        "DISPLAY = ./display.py",
        "[TASK]",
        "TASK = milltask",
        "CYCLE_TIME = 0.001",
        "[RS274NGC]",
        "PARAMETER_FILE = sim.var",
        "[EMCMOT]",
        "EMCMOT = motmod",
        "SERVO_PERIOD = 1000000",
        "COMM_TIMEOUT = 1.0",
        "[EMCIO]",
        "EMCIO = io",
        "CYCLE_TIME = 0.100",
        "[HAL]",
        "HALFILE = LIB:basic_sim.tcl -no_use_hal_manualtoolchange",
        "[TRAJ]",
        "COORDINATES = XYZ",
        "LINEAR_UNITS = mm",
        "ANGULAR_UNITS = degree",
        "MAX_LINEAR_VELOCITY = 200",
        "[KINS]",
        "JOINTS = 3",
        "KINEMATICS = trivkins coordinates=XYZ",
    ]
    for index, axis in enumerate("XYZ"):
        low, high = stroke[axis]
        limits = [
            f"MIN_LIMIT = {low - 1:g}",
            f"MAX_LIMIT = {high + 1:g}",
            "MAX_VELOCITY = 200",
            "MAX_ACCELERATION = 2000",
        ]
        lines += [f"[AXIS_{axis}]", *limits]
        name, file_type = comp[index]
        lines += [
            f"[JOINT_{index}]",
            "TYPE = LINEAR",
            "HOME_SEQUENCE = 0",
            *limits,
            f"COMP_FILE = {name}",
            f"COMP_FILE_TYPE = {file_type}",
        ]
    return "\n".join(lines) + "\n"


MOVES = [
    "G0 X37.5 Y12.25 Z10",
    "G0 X212.3 Y301.7 Z240.2",
    "G0 X101.7 Y150.05 Z125.5",
    "G1 F12000 X399 Y398.5 Z349",
    "G0 X5.2 Y7.7 Z0.4",
    "G0 X250 Y60",
    "G0 X125 Z200",
]


def _expected_um(table, position_mm: float, direction: int) -> float:
    """LinuxCNC's rule, written from its documentation: linear interpolation of the forward or
    reverse column, end values held."""
    column = table.correction_forward_um if direction > 0 else table.correction_backward_um
    return float(np.interp(position_mm, table.position_mm, column))


def test_linuxcnc_applies_exported_comp_files(linuxcnc_available: None, one_session) -> None:
    source = _source()
    options = ExportOptions(spacing_mm=25.0)
    run_dir = Path(tempfile.mkdtemp(prefix="volucal-lcnc-"))
    process = None
    try:
        type0 = export_model(source, "linuxcnc", run_dir / "type0", options)
        type1 = export_model(
            source, "linuxcnc", run_dir / "type1", ExportOptions(spacing_mm=25.0, linuxcnc_type=1)
        )
        shutil.copy(run_dir / "type0" / "joint0_X.comp", run_dir / "joint0_X.comp")
        shutil.copy(run_dir / "type1" / "joint1_Y.comp", run_dir / "joint1_Y.comp")
        shutil.copy(run_dir / "type0" / "joint2_Z.comp", run_dir / "joint2_Z.comp")
        comp = {0: ("joint0_X.comp", 0), 1: ("joint1_Y.comp", 1), 2: ("joint2_Z.comp", 0)}
        (run_dir / "linuxcnc.ini").write_text(_ini(source.machine.stroke_mm, comp))
        (run_dir / "display.py").write_text(DISPLAY)
        (run_dir / "display.py").chmod(0o755)
        (run_dir / "sim.var").write_text("")
        (run_dir / "moves.json").write_text(json.dumps(MOVES))
        prefix = _run_as()
        if prefix:
            subprocess.run(["chown", "-R", USER, str(run_dir)], check=True, timeout=30)
        with open(run_dir / "linuxcnc.log", "w") as log:
            process = subprocess.Popen(
                [*prefix, "linuxcnc", "linuxcnc.ini"],
                cwd=run_dir,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
            process.wait(timeout=TIMEOUT_S)
        result_path = run_dir / "result.json"
        log_text = (run_dir / "linuxcnc.log").read_text(errors="replace")
        assert result_path.exists(), f"LinuxCNC produced no result; its log:\n{log_text[-3000:]}"
        result = json.loads(result_path.read_text())
        assert "error" not in result, f"{result['error']}\n{log_text[-3000:]}"
        assert len(result["readings"]) == len(MOVES)

        tables = type0.tables.axis
        assert np.array_equal(type1.tables.axis["Y"].position_mm, tables["Y"].position_mm)
        last = np.zeros(3)
        direction = np.ones(3)
        seen: set[tuple[int, int]] = set()
        checked = 0
        for reading in result["readings"]:
            for j, axis in enumerate("XYZ"):
                pins = reading["joints"][j]
                nominal = pins["pos-cmd"]
                if abs(nominal - last[j]) > 1e-9:
                    direction[j] = np.sign(nominal - last[j])
                last[j] = nominal
                seen.add((j, int(direction[j])))
                expected_mm = _expected_um(tables[axis], nominal, direction[j]) / 1e3
                # Files carry nanometres; LinuxCNC stores slopes in single precision.
                assert pins["backlash-corr"] == pytest.approx(expected_mm, abs=1e-4), (
                    reading["mdi"],
                    axis,
                )
                assert pins["motor-pos-cmd"] - nominal == pytest.approx(expected_mm, abs=1e-4)
                checked += 1
        assert checked == 3 * len(MOVES)
        # Every joint was checked moving both ways, so both columns (and the X reversal of
        # 4 µm, 40 times the tolerance) were exercised.
        assert seen == {(j, s) for j in range(3) for s in (1, -1)}
    finally:
        if process is not None and process.poll() is None:
            os.killpg(process.pid, signal.SIGTERM)
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait(timeout=20)
        shutil.rmtree(run_dir, ignore_errors=True)


PROGRAM = textwrap.dedent(
    """\
    %
    (volucal rs274 check)
    G21 G90 G17
    G0 X20 Y20 Z30
    G1 Z2 F400
    G1 X180 Y40
    G2 X230 Y90 I0 J50
    G3 X180 Y140 R50
    G91 G1 X-60 Y-10
    G90 G18 G2 X135 Z17 I15 K0
    G19 G3 Y150 Z17 J10 K10
    G17 G92 X0 Y0
    G1 X10 Y5
    G92.1
    G0 Z60
    M2
    %
    """
)


def _canon(text: str, tmp: Path) -> list[tuple[str, list[float]]]:
    program = tmp / "program.ngc"
    program.write_text(text)
    run = subprocess.run(
        ["rs274", "-g", str(program)], capture_output=True, text=True, timeout=60, cwd=tmp
    )
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    calls = []
    for name, args in re.findall(r"(STRAIGHT_FEED|STRAIGHT_TRAVERSE|ARC_FEED)\((.*)\)", run.stdout):
        calls.append((name, [float(a) for a in args.split(",")]))
    return calls


def _written_points(text: str) -> list[list[float]]:
    points = []
    for line in text.splitlines():
        if re.match(r"^(N\S+ )?.*\bG[01] X", line) and "G92" not in line:
            values = dict(re.findall(r"([XYZ])(-?\d+\.\d+)", line))
            points.append([float(values[a]) for a in "XYZ"])
    return points


def test_rs274_runs_rewritten_program(linuxcnc_available: None, tmp_path: Path) -> None:
    result = rewrite_program(ModelSource(paper_like_model(seed=5)), PROGRAM)
    calls = _canon(result.text, tmp_path)
    assert all(name != "ARC_FEED" for name, _ in calls)  # arcs were linearised
    reached = [args[:3] for _, args in calls]
    # G92 is active for one move: LinuxCNC reports that point in the shifted system as we wrote
    # it, so the canonical points are the numbers of our G0/G1 lines, in order.
    np.testing.assert_allclose(reached, _written_points(result.text), atol=1e-4)
    assert len(reached) == result.points_out


def test_rewritten_arcs_lie_on_linuxcnc_arcs(linuxcnc_available: None, tmp_path: Path) -> None:
    """With an error-free source the rewritten program is the original with arcs as chords:
    every chord point lies on the arc LinuxCNC interprets, swept in LinuxCNC's direction."""
    zero = ModelSource(ErrorModel.zero(paper_like_model().machine))
    original = _canon(PROGRAM, tmp_path)
    rewritten = _canon(rewrite_program(zero, PROGRAM).text, tmp_path)
    points = np.array([args[:3] for _, args in rewritten])
    planes = {"G17": (0, 1, 2), "G18": (2, 0, 1), "G19": (1, 2, 0)}
    arc_planes = ["G17", "G17", "G18", "G19"]
    position = np.zeros(3)
    cursor = 0
    arcs = 0
    for name, args in original:
        if name != "ARC_FEED":
            target = np.array(args[:3])
            hit = np.flatnonzero(np.all(np.abs(points[cursor:] - target) < 1e-4, axis=1))
            assert hit.size, f"{name} {args[:3]} not reached by the rewritten program"
            cursor += int(hit[0]) + 1
            position = target
            continue
        a, b, normal = planes[arc_planes[arcs]]
        arcs += 1
        end1, end2, c1, c2, rotation, end3 = args[:6]
        end = np.empty(3)
        end[a], end[b], end[normal] = end1, end2, end3
        hit = np.flatnonzero(np.all(np.abs(points[cursor:] - end) < 1e-4, axis=1))
        assert hit.size, f"arc end {end} not reached"
        chord = points[cursor : cursor + int(hit[0]) + 1]
        radius = np.hypot(position[a] - c1, position[b] - c2)
        distance = np.hypot(chord[:, a] - c1, chord[:, b] - c2)
        np.testing.assert_allclose(distance, radius, atol=1e-4)
        angles = np.unwrap(np.arctan2(chord[:, b] - c2, chord[:, a] - c1))
        assert np.all(np.sign(np.diff(angles)) == np.sign(rotation))
        cursor += int(hit[0]) + 1
        position = end
    assert arcs == 4
