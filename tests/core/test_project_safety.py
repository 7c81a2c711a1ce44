"""A project never reads beyond itself and never loses what was saved (issue 17).

Crafted files are built with h5py from a real saved project; each must be refused in under a
second with one line that names the file and echoes none of the content it points at.
"""

import logging
import os
import shutil
import stat
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from volucal.core.cli import main
from volucal.core.io.plan import import_plan, load_plan
from volucal.core.machine import PAPER_MACHINE
from volucal.core.project import Project, ProjectChangedError, ProjectLock
from volucal.core.userror import UserError

DATA = Path(__file__).resolve().parents[1] / "data"
PLAN = DATA / "io" / "plan.toml"
SECRET = "volucal-test-secret-line"


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    result = import_plan(load_plan(PLAN))
    project = Project.create(result.plan.machine)
    project.add_lines(result.plan, result.measurement, result.source_bytes, result.raw,
                      provenance={line.name: line.provenance() for line in result.lines})
    return project.save(tmp_path_factory.mktemp("saved") / "p.h5")


def crafted(saved, tmp_path, change):
    path = tmp_path / "crafted.h5"
    shutil.copy(saved, path)
    with h5py.File(path, "a") as handle:
        change(handle, tmp_path)
    return path


def refused_quickly(path, match):
    start = time.perf_counter()
    with pytest.raises(UserError, match=match) as caught:
        Project.open(path)
    elapsed = time.perf_counter() - start
    message = str(caught.value)
    assert elapsed < 1.0, f"took {elapsed:.2f} s"
    assert "\n" not in message and str(path) in message
    assert SECRET not in message
    return message


def secret_file(tmp_path):
    target = tmp_path / "secret.txt"
    target.write_text(f"{SECRET}\n" * 20)
    return target


# ---- reading beyond the project ---------------------------------------------------------------


def test_external_link_is_refused(saved, tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as handle:
        handle["source"] = np.frombuffer(SECRET.encode(), dtype=np.uint8)

    def change(handle, _):
        line = handle["measurements/x_y0_z0"]
        del line["source"]
        line["source"] = h5py.ExternalLink(str(other), "/source")

    refused_quickly(crafted(saved, tmp_path, change), "external link")


def test_external_storage_is_refused(saved, tmp_path):
    secret = secret_file(tmp_path)

    def change(handle, _):
        line = handle["measurements/x_y0_z0"]
        del line["source"]
        line.create_dataset("source", shape=(secret.stat().st_size,), dtype=np.uint8,
                            external=[(str(secret), 0, h5py.h5f.UNLIMITED)])

    refused_quickly(crafted(saved, tmp_path, change), "external file")


def test_virtual_dataset_is_refused(saved, tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as handle:
        handle["bytes"] = np.frombuffer(SECRET.encode(), dtype=np.uint8)

    def change(handle, _):
        layout = h5py.VirtualLayout(shape=(len(SECRET),), dtype=np.uint8)
        layout[:] = h5py.VirtualSource(str(other), "bytes", shape=(len(SECRET),))
        line = handle["measurements/x_y0_z0"]
        del line["source"]
        line.create_virtual_dataset("source", layout)

    refused_quickly(crafted(saved, tmp_path, change), "virtual dataset")


def test_soft_link_cycle_is_refused(saved, tmp_path):
    def change(handle, _):
        handle["measurements/x_y0_z0/loop"] = h5py.SoftLink("/measurements")

    refused_quickly(crafted(saved, tmp_path, change), "soft link")


def test_hard_link_cycle_is_refused(saved, tmp_path):
    def change(handle, _):
        handle["measurements/x_y0_z0/loop"] = handle["measurements"]

    refused_quickly(crafted(saved, tmp_path, change), "second link")


def test_unwritten_huge_dataset_is_refused_before_reading(saved, tmp_path):
    def change(handle, _):
        # 16 GB declared, nothing written: HDF5 would allocate and fill it on reading
        handle["loops"].create_dataset("huge", shape=(2_000_000_000,), dtype="f8",
                                       chunks=(1 << 20,))

    path = crafted(saved, tmp_path, change)
    assert path.stat().st_size < 10_000_000
    refused_quickly(path, "declares 14.9 GiB")


def test_unwritten_dataset_below_the_size_limit_is_refused(saved, tmp_path):
    def change(handle, _):
        handle["loops"].create_dataset("big", shape=(50_000_000,), dtype="f8",
                                       chunks=(1 << 18,))

    refused_quickly(crafted(saved, tmp_path, change), "stores only")


@pytest.mark.parametrize(("version", "match"), [
    (1.5, "format_version 1.5 is not"),
    (0, "format_version 0 is not"),
    (-1, "format_version -1 is not"),
    ("1", "format_version '1' is not"),
    (2.0 ** 40, "newer volucal"),
])
def test_format_version_must_be_a_whole_version(saved, tmp_path, version, match):
    def change(handle, _):
        handle.attrs["format_version"] = version

    refused_quickly(crafted(saved, tmp_path, change), match)


def test_whole_float_version_reads(saved, tmp_path):
    def change(handle, _):
        handle.attrs["format_version"] = 1.0

    assert Project.open(crafted(saved, tmp_path, change)).machine.name == "VMC-400"


# ---- names ------------------------------------------------------------------------------------


def plan_with_name(tmp_path, name):
    text = PLAN.read_text().replace('name = "x_y0_z0"', f'name = "{name}"')
    for source in DATA.joinpath("io").iterdir():
        if source.suffix != ".toml":
            shutil.copy(source, tmp_path / source.name)
    plan = tmp_path / "plan.toml"
    plan.write_text(text)
    return plan


@pytest.mark.parametrize("name", [r"a\u0000b", r"a\nb", r"a\tb", r"a\u007fb"])
def test_control_characters_in_line_names_are_refused(tmp_path, capsys, name):
    plan = plan_with_name(tmp_path, name)
    assert main(["import", str(tmp_path / "p.h5"), str(plan)]) == 1
    err = capsys.readouterr().err
    assert "line name" in err and "control characters" in err
    assert "Traceback" not in err
    assert not (tmp_path / "p.h5").exists()


def test_nul_in_any_stored_text_is_refused_not_truncated(tmp_path):
    project = Project.create(PAPER_MACHINE)
    project.put_result("loops", "main", {"note": "a\0b"})
    with pytest.raises(UserError, match="NUL"):
        project.save(tmp_path / "p.h5")
    assert not list(tmp_path.iterdir())


def test_result_names_with_control_characters_are_refused():
    project = Project.create(PAPER_MACHINE)
    with pytest.raises(ValueError, match="printable"):
        project.put_result("loops", "a\0b", {})
    with pytest.raises(ValueError, match="printable"):
        project.put_result("loops", "main", {"a\nb": 1})


# ---- write protection and permissions -----------------------------------------------------------


def test_write_protected_project_is_not_overwritten(saved, tmp_path, capsys):
    path = tmp_path / "p.h5"
    shutil.copy(saved, path)
    path.chmod(0o444)
    before = path.read_bytes()
    extra = plan_with_name(tmp_path, "extra")
    assert main(["import", str(path), str(extra), "--replace"]) == 1
    err = capsys.readouterr().err
    assert "write-protected (mode 0444)" in err and "chmod u+w" in err
    assert path.read_bytes() == before
    assert stat.S_IMODE(path.stat().st_mode) == 0o444
    assert sorted(p.name for p in tmp_path.glob("p.h5*")) == ["p.h5"]


def test_save_keeps_the_file_mode(saved, tmp_path):
    path = tmp_path / "p.h5"
    shutil.copy(saved, path)
    path.chmod(0o640)
    project = Project.open(path)
    project.put_result("loops", "main", {"x": 1})
    project.save()
    assert stat.S_IMODE(path.stat().st_mode) == 0o640


def test_unwritable_folder_gives_a_clear_error(tmp_path):
    if os.geteuid() == 0:
        pytest.skip("root writes into read-only folders")
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        with pytest.raises(UserError, match="lock file"):
            Project.create(PAPER_MACHINE).save(folder / "p.h5")
    finally:
        folder.chmod(0o755)


# ---- lost updates -------------------------------------------------------------------------------


def test_save_refuses_when_the_file_changed_since_it_was_opened(saved, tmp_path):
    path = tmp_path / "p.h5"
    shutil.copy(saved, path)
    stale = Project.open(path)
    other = Project.open(path)
    other.put_result("loops", "theirs", {"x": 1})
    other.save()
    stale.put_result("loops", "mine", {"x": 2})
    with pytest.raises(ProjectChangedError, match="changed by another program"):
        stale.save()
    assert Project.open(path).results("loops") == ["theirs"]
    # saving under another name is a new file: allowed
    stale.save(tmp_path / "copy.h5")
    assert Project.open(tmp_path / "copy.h5").results("loops") == ["mine"]


def test_a_project_saved_twice_by_its_owner_is_not_a_conflict(saved, tmp_path):
    path = tmp_path / "p.h5"
    shutil.copy(saved, path)
    project = Project.open(path)
    for i in range(3):
        project.put_result("loops", f"r{i}", {"i": i})
        project.save()
    assert Project.open(path).results("loops") == ["r0", "r1", "r2"]


# ---- stale locks --------------------------------------------------------------------------------


HOLDER = """
import sys, time
from volucal.core.project import ProjectLock
lock = ProjectLock(sys.argv[1])
lock.acquire()
print("locked", flush=True)
time.sleep(60)
"""


def test_lock_of_a_killed_process_is_cleared_with_a_message(saved, tmp_path, caplog):
    path = tmp_path / "p.h5"
    shutil.copy(saved, path)
    child = subprocess.Popen([sys.executable, "-c", HOLDER, str(path)], stdout=subprocess.PIPE,
                             text=True)
    try:
        assert child.stdout.readline().strip() == "locked"
        # a second writer is refused while the first lives
        with pytest.raises(UserError, match=f"locked by process {child.pid}"):
            Project.create(PAPER_MACHINE).save(path)
        Path(f"{path}.tmp-{child.pid}").write_bytes(b"half a file")
        Project.open(path)  # a reader is not blocked, and cleans nothing while the lock lives
        assert Path(f"{path}.tmp-{child.pid}").exists()
    finally:
        child.kill()
        child.wait()
        child.stdout.close()
    lock = Path(f"{path}.lock")
    assert lock.exists()  # killed: it never released its lock
    with caplog.at_level(logging.WARNING, logger="volucal.project"):
        Project.open(path)
    assert not lock.exists()
    assert not Path(f"{path}.tmp-{child.pid}").exists()
    text = caplog.text
    assert f"cleared a stale lock left by process {child.pid}" in text
    assert "temporary file left by an interrupted save" in text


def test_lock_file_of_an_older_volucal_with_a_live_pid_is_respected(tmp_path):
    path = tmp_path / "p.h5"
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        Path(f"{path}.lock").write_text(str(holder.pid))
        with pytest.raises(UserError, match=f"locked by process {holder.pid}"):
            with ProjectLock(path):
                pass
    finally:
        holder.kill()
        holder.wait()
