"""``volucal thermal`` through the user's path: the CLI's main(), files on disk."""

import json
from pathlib import Path

import numpy as np
import pytest
from volucal.core.cli import main
from volucal.core.project import Project
from volucal.core.thermal_sim import SimulatedThermalTest, simulate_thermal_test
from volucal.core.thermal_store import load_thermal


@pytest.fixture
def record(tmp_path: Path) -> Path:
    """A simulated warm-up written as a user's CSV: time in minutes, drift in mm, °C, one stuck
    sensor."""
    m = simulate_thermal_test(SimulatedThermalTest(hours=12, stuck_sensor=True, seed=4))
    names = [*m.sensor_names, "stuck"]
    lines = ["time [min],Z drift [mm]," + ",".join(f"{n} [°C]" for n in names)]
    stuck = np.full(m.samples, 23.5)
    temps = m.temperature_map()
    for k in range(m.samples):
        cells = [f"{m.time_s[k] / 60:g}", f"{m.errors[0].values[k] / 1000:.7f}"]
        cells += [f"{temps[n][k]:.4f}" for n in m.sensor_names] + [f"{stuck[k]:g}"]
        lines.append(",".join(cells))
    path = tmp_path / "warmup.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_json_report_export_and_project(record: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "export"
    project = tmp_path / "p.h5"
    code = main(["thermal", str(record), "--error", "Z drift", "--json", "--export", str(out),
                 "--project", str(project), "--train-fraction", "0.6", "--hal-axis", "z",
                 "--hal-loaded", "lowpass,scale"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    data = json.loads(captured.out)
    entry = data["files"][0]
    assert entry["samples"] == 721 and "stuck" not in entry["sensors"]
    assert entry["excluded"][0]["name"] == "stuck" and "stuck at 23.5" in entry["warnings"][0]
    channel = entry["channels"][0]
    assert channel["unit"] == "um" and channel["train_samples"] == round(0.6 * 721)
    assert channel["test_rms_um"] < 0.5 * channel["baselines"][0]["test_rms_um"]
    assert len(channel["sensors"]) <= 6
    assert "compensation applies −error" in channel["sign_convention"]
    assert {Path(p).name for p in entry["exported"]} == {
        "thermal-z-drift.hal", "thermal-z-drift.json", "thermal-z-drift.csv",
        "thermal-z-drift-check.csv", "thermal-z-drift-eoffset.hal"}
    hal = (out / "thermal-z-drift.hal").read_text()
    assert "\nloadrt sum2 names=" in hal and "\nloadrt lowpass" not in hal
    assert "add to its 'loadrt lowpass' line the names" in hal or "lag" not in hal
    assert "axis.z.eoffset-counts" in (out / "thermal-z-drift-eoffset.hal").read_text()
    assert entry["stored_as"] == "/thermal/warmup"
    stored = load_thermal(Project.open(project), "warmup")
    assert stored.models["Z drift"].sensors == tuple(channel["sensors"])


def test_text_report(record: Path, capsys) -> None:
    assert main(["thermal", str(record), "--error", "Z drift", "--static", "--linear"]) == 0
    text = capsys.readouterr().out
    assert "model:" in text and "static" in text and "RMS error, µm" in text
    assert "volucal model" in text and "all 7 sensors, static" in text
    assert "warning: temperature 'stuck' is stuck" in text
    assert "compensation = −prediction" in text


def test_bad_input_is_one_clear_message(record: Path, tmp_path: Path, capsys) -> None:
    bare = tmp_path / "bare.csv"
    bare.write_text("dz,T1,T2\n0,20,21\n1,21,21.5\n2,22,,\n")
    assert main(["thermal", str(bare), "--error", "dz=um", "--temperature-unit", "C",
                 "--interval", "60s"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("volucal: error: ") and "bare.csv, line 4" in err and "'T2'" in err
    assert "Traceback" not in err
    assert main(["thermal", str(bare), "--error", "dz=um", "--temperature-unit", "C",
                 "--interval", "60"]) == 1
    assert "--interval '60': give a number with its unit" in capsys.readouterr().err
    assert main(["thermal", str(record), "--error", "nope=um"]) == 1
    assert "no error column named 'nope'" in capsys.readouterr().err
