"""The HDF5 project: exact round trips, clear errors for bad files, locking, migrations and the
checked-in file of format version 1."""

import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from volucal.core import project as project_module
from volucal.core.errors import ErrorModel, PolynomialBasis
from volucal.core.io.plan import import_plan, load_plan
from volucal.core.machine import PAPER_MACHINE
from volucal.core.project import (
    FORMAT_VERSION,
    Project,
    ProjectLock,
    error_model_from_tree,
    error_model_to_tree,
)
from volucal.core.userror import UserError

DATA = Path(__file__).resolve().parents[1] / "data"
PLAN = DATA / "io" / "plan.toml"
V1 = DATA / "projects" / "format_v1.h5"


def imported_project():
    result = import_plan(load_plan(PLAN))
    project = Project.create(result.plan.machine)
    project.add_lines(result.plan, result.measurement, result.source_bytes, result.raw,
                      provenance={line.name: line.provenance() for line in result.lines})
    return project, result


def same(a, b) -> bool:
    """Exact equality of result trees, including types (list vs array, int vs float)."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(map(same, a, b))
    if isinstance(a, np.ndarray):
        return (isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape
                and np.array_equal(a, b, equal_nan=a.dtype.kind == "f"))
    return type(a) is type(b) and a == b


TREE = {
    "rms_um": 0.4512345678901234,
    "converged": True,
    "iterations": 7,
    "method": "leave-one-line-out",
    "nothing": None,
    "position_mm": np.linspace(0, 400, 9),
    "flags": np.array([True, False, True]),
    "counts": np.arange(5, dtype=np.int64),
    "labels": np.array(["EXX", "EYX"]),
    "matrix": np.arange(12.0).reshape(3, 4),
    "unidentifiable": ["EAX", "EBZ"],
    "empty": [],
    "values_um": [1.5, -2.25, 3.0],
    "ranks": [1, 2, 3],
    "loop": [
        {"step": 1, "effect": {"kind": "reversal", "axis": "X", "parameters": {"b_um": 2.1}},
         "kept": True},
        {"step": 2, "effect": {"kind": "cyclic", "axis": None, "parameters": {}}, "kept": False},
    ],
    "mixed": [1, "two", None, [3.0, 4.0], {"five": 5}],
    "nested": {"deeper": {"deepest": np.array([np.nan, 1.0])}},
}


def test_round_trip_of_lines_and_results(tmp_path):
    project, result = imported_project()
    project.put_result("loops", "run-1", TREE)
    model = ErrorModel.zero(PAPER_MACHINE, lambda axis, eid: PolynomialBasis(
        *PAPER_MACHINE.stroke(axis), degree=3))
    rng = np.random.default_rng(1)
    model = model.with_parameters(rng.normal(0, 1, model.parameter_count))
    project.put_result("identifications", "first", {"model": error_model_to_tree(model),
                                                    "rms_um": 0.3})
    path = project.save(tmp_path / "p.h5")
    assert not list(tmp_path.glob("p.h5.tmp-*")) and not (tmp_path / "p.h5.lock").exists()

    back = Project.open(path)
    assert back.machine == result.plan.machine
    assert back.plan_toml == PLAN.read_text()
    assert back.uncertainty == {"laser_ppm": 0.5, "air_temp_sensor_c": 0.1}
    assert back.results("loops") == ["run-1"] and back.results("sensitivity") == []
    assert same(back.result("loops", "run-1"), TREE)
    model_back = error_model_from_tree(back.result("identifications", "first")["model"],
                                       back.machine)
    np.testing.assert_array_equal(model_back.parameters, model.parameters)
    assert model_back.functions["EXX"].basis.describe() == model.functions["EXX"].basis.describe()

    original = result.measurement
    loaded = back.measurement()
    assert [line.name for line in loaded.lines] == [line.name for line in original.lines]
    for a, b in zip(original.lines, loaded.lines, strict=True):
        assert a.spec == b.spec
        for key in ("targets_mm", "deviations", "run_direction", "times_s", "air_temp_c",
                    "material_temp_c"):
            x, y = getattr(a.data, key), getattr(b.data, key)
            assert (x is None and y is None) or np.array_equal(x, y, equal_nan=True), key
        assert a.data.start_time == b.data.start_time
        # where the file put its first target, which tables and graphs of a file alone show
        assert a.data.origin_mm is not None and a.data.origin_mm == b.data.origin_mm
        assert a.data.environment == b.data.environment
        assert dict(a.data.metadata) == dict(b.data.metadata)
    for line in result.lines:
        assert back.raw_bytes(line.name) == (DATA / "io" / Path(line.spec.file).name).read_bytes()
        raw = back.raw_data(line.name)
        assert np.array_equal(raw.deviations, line.raw.deviations, equal_nan=True)
        info = back.provenance(line.name)
        assert info["raw_unit"] == line.raw_unit and info["format"] == line.format
        assert info["corrections"] == list(line.corrections)
    with h5py.File(path) as handle:
        assert handle.attrs["format_version"] == FORMAT_VERSION
        assert handle.attrs["creator"].startswith("volucal ")
        group = handle["measurements/z_linear"]
        assert group["raw/deviations"].attrs["unit"] == "nm"
        assert group["corrected/deviations"].attrs["unit"] == "um"
        assert group["source"].attrs["filename"] == "z_linear_hand.txt"
        assert handle["loops/run-1/position_mm"].attrs["unit"] == "mm"
        assert handle["loops/run-1"].attrs["volucal_unit:rms_um"] == "um"


def test_adding_lines_twice_needs_replace(tmp_path):
    project, result = imported_project()
    with pytest.raises(UserError, match="already has line"):
        project.add_lines(result.plan, result.measurement, result.source_bytes, result.raw)
    project.add_lines(result.plan, result.measurement, result.source_bytes, result.raw,
                      replace=True)
    other = Project.create(PAPER_MACHINE)
    with pytest.raises(UserError, match="differs from the project's"):
        other.add_lines(result.plan, result.measurement, result.source_bytes, result.raw)


def test_result_names_and_values_are_checked():
    project = Project.create()
    with pytest.raises(ValueError, match="kind"):
        project.put_result("misc", "a", {})
    with pytest.raises(ValueError, match="name"):
        project.put_result("loops", "a/b", {})
    with pytest.raises(ValueError, match="result key"):
        project.put_result("loops", "a", {"x/y": 1})
    with pytest.raises(TypeError, match="cannot be stored"):
        project.put_result("loops", "a", {"x": object()})
    with pytest.raises(KeyError):
        project.result("loops", "absent")


# ---- opening bad files ------------------------------------------------------------------------


def test_open_errors(tmp_path):
    with pytest.raises(UserError, match="no such project file"):
        Project.open(tmp_path / "absent.h5")
    text = tmp_path / "text.h5"
    text.write_text("not hdf5")
    with pytest.raises(UserError, match="not an HDF5 file"):
        Project.open(text)
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as handle:
        handle["x"] = np.arange(3)
    with pytest.raises(UserError, match="not a volucal project"):
        Project.open(foreign)
    newer = tmp_path / "newer.h5"
    with h5py.File(newer, "w") as handle:
        handle.attrs["format_version"] = FORMAT_VERSION + 1
        handle.attrs["creator"] = "volucal 9.0"
    with pytest.raises(UserError, match="newer volucal .*update volucal"):
        Project.open(newer)


def test_damaged_file_gives_a_message_not_a_traceback(tmp_path):
    project, _ = imported_project()
    path = project.save(tmp_path / "p.h5")
    data = path.read_bytes()
    for fraction in (0.3, 0.6, 0.9):
        cut = tmp_path / f"cut{fraction}.h5"
        cut.write_bytes(data[: int(len(data) * fraction)])
        with pytest.raises(UserError, match="damaged|not an HDF5"):
            Project.open(cut)
    # random byte damage: projects are written with checksummed HDF5 metadata, so damage is
    # reported instead of being read as garbage (or hanging the HDF5 library)
    rng = np.random.default_rng(7)
    outcomes = set()
    for trial in range(30):
        damaged = bytearray(V1.read_bytes())
        for index in rng.integers(0, len(damaged), size=int(rng.integers(1, 12))):
            damaged[index] = int(rng.integers(0, 256))
        target = tmp_path / f"damaged{trial}.h5"
        target.write_bytes(bytes(damaged))
        try:
            loaded = Project.open(target)
            loaded.measurement()
            outcomes.add("read")
        except UserError:
            outcomes.add("refused")
    assert "refused" in outcomes
    incomplete = tmp_path / "incomplete.h5"
    with h5py.File(incomplete, "w") as handle:
        handle.attrs["format_version"] = 1
        handle.attrs["creator"] = "volucal 0.1"
    with pytest.raises(UserError, match="damaged or incomplete"):
        Project.open(incomplete)


# ---- locking ----------------------------------------------------------------------------------


def test_live_lock_names_its_holder(tmp_path):
    path = tmp_path / "p.h5"
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        Path(str(path) + ".lock").write_text(str(holder.pid))
        with pytest.raises(UserError, match=f"locked by process {holder.pid}"):
            Project.create(PAPER_MACHINE).save(path)
    finally:
        holder.kill()
        holder.wait()


def test_stale_lock_is_taken_over(tmp_path):
    path = tmp_path / "p.h5"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    lock = Path(str(path) + ".lock")
    lock.write_text(str(dead.pid))
    (tmp_path / f"p.h5.tmp-{dead.pid}").write_bytes(b"half a file")
    Project.create(PAPER_MACHINE).save(path)
    assert Project.open(path).machine == PAPER_MACHINE
    assert not lock.exists()
    assert not (tmp_path / f"p.h5.tmp-{dead.pid}").exists()


def test_lock_is_reentrant_within_a_process(tmp_path):
    path = tmp_path / "p.h5"
    with ProjectLock(path) as lock:
        assert lock.path.read_text().split()[0] == str(os.getpid())
        Project.create(PAPER_MACHINE).save(path)  # takes the same lock again
        assert lock.path.exists()
    assert not lock.path.exists()


# ---- versions ---------------------------------------------------------------------------------


def test_checked_in_format_v1_file_loads():
    project = Project.open(V1)
    assert project.creator.startswith("volucal ")
    assert project.machine.name == "VMC-400"
    names = [line.name for line in project.measurement().lines]
    assert names == ["z_linear", "z_iso", "x_y0_z0", "y_straightness_x", "x_pitch_hand"]
    x = project.measurement().line("x_y0_z0").data
    np.testing.assert_array_equal(x.deviations[1], [-1.8, 0.3, 2.5, 3.7, 6.2])
    assert x.origin_mm is None  # written before the file's first position was kept
    assert project.raw_bytes("x_y0_z0") == (DATA / "io" / "x_axis_hand.rtl").read_bytes()
    tree = project.result("loops", "example")
    assert tree["steps"][0]["effect"]["kind"] == "reversal"
    np.testing.assert_array_equal(tree["position_mm"], [0.0, 100.0, 200.0])
    model = error_model_from_tree(project.result("identifications", "example")["model"],
                                  project.machine)
    assert model.squareness_urad["EC0Y"] == -118.0


def test_migrations_run_in_order(monkeypatch):
    calls = []

    def to_two(document):
        calls.append(document.attrs["format_version"])
        document.attrs["format_version"] = 2
        return document

    monkeypatch.setattr(project_module, "FORMAT_VERSION", 2)
    monkeypatch.setitem(project_module.MIGRATIONS, 1, to_two)
    project = Project.open(V1)
    assert calls == [1]
    assert project.machine.name == "VMC-400"
