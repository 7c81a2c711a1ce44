"""Two writers on one project: nothing imported is lost, in either order (issue 17).

A slow writer is the real command (``volucal identify``, ``volucal sensitivity``, ``volucal
import``) run in another process with its computation slowed down, so the other command lands
while the first one holds its copy of the project. Whatever the order, every line an import
reports as imported is in the project at the end, and a refused command says so in one line.
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from volucal.core.cli import main
from volucal.core.project import Project

DATA = Path(__file__).resolve().parents[1] / "data" / "io"

# The command runs in a child process; `patch` slows the step between reading and saving.
CHILD = """
import sys, time
{patch}
from volucal.core.cli import main
sys.exit(main(sys.argv[1:]))
"""

SLOW = {
    "identify": """
from volucal.core.commands import identify_cmd
real = identify_cmd.identify
def slow(*args, **kwargs):
    print("computing", flush=True)
    time.sleep(2.0)
    return real(*args, **kwargs)
identify_cmd.identify = slow
""",
    "sensitivity": """
from volucal.core.commands import sensitivity_cmd
real = sensitivity_cmd.analyse_model
def slow(*args, **kwargs):
    print("computing", flush=True)
    time.sleep(2.0)
    return real(*args, **kwargs)
sensitivity_cmd.analyse_model = slow
""",
    "import": """
from volucal.core.project import Project
real = Project.add_lines
def slow(self, *args, **kwargs):
    print("computing", flush=True)
    time.sleep(2.0)
    return real(self, *args, **kwargs)
Project.add_lines = slow
""",
}


def folder_with_project(tmp_path):
    for source in DATA.iterdir():
        shutil.copy(source, tmp_path / source.name)
    plan = (tmp_path / "plan.toml").read_text()
    first, _, rest = plan.partition("[[line]]")
    entries = ["[[line]]" + entry for entry in rest.split("[[line]]")]
    # the base project: every line but the last; extra.toml adds the last one
    (tmp_path / "base.toml").write_text(first + "".join(entries[:-1]))
    (tmp_path / "extra.toml").write_text(first + entries[-1])
    project = tmp_path / "p.h5"
    assert main(["import", str(project), str(tmp_path / "base.toml")]) == 0
    assert main(["identify", str(project)]) == 0
    return project


def command(kind, project, tmp_path):
    if kind == "identify":
        return ["identify", str(project), "--name", "slow"]
    if kind == "sensitivity":
        return ["sensitivity", str(project), "--n", "65", "--repeats", "1", "--name", "slow"]
    return ["import", str(project), str(tmp_path / "extra.toml")]


def start_slow(kind, project, tmp_path):
    script = CHILD.format(patch=SLOW[kind])
    child = subprocess.Popen(
        [sys.executable, "-c", script, *command(kind, project, tmp_path)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    assert child.stdout.readline().strip() == "computing"
    return child


@pytest.mark.parametrize("writer", ["identify", "sensitivity"])
def test_import_while_a_slow_writer_runs_loses_nothing(tmp_path, capsys, writer):
    project = folder_with_project(tmp_path)
    capsys.readouterr()
    child = start_slow(writer, project, tmp_path)
    code = main(command("import", project, tmp_path))
    err = capsys.readouterr().err
    out, child_err = child.communicate(timeout=120)
    assert child.returncode == 0, child_err
    final = Project.open(project)
    names = {line.name for line in final.measurement().lines}
    if code == 0:
        assert "z_iso" in names  # imported: it must still be there after the writer saved
    else:
        assert code == 1 and f"locked by process {child.pid}" in err
        assert err.count("\n") == 1 and "Traceback" not in err
        assert "z_iso" not in names
    kind = "identifications" if writer == "identify" else "sensitivity"
    assert "slow" in final.results(kind)


@pytest.mark.parametrize("writer", ["identify", "sensitivity"])
def test_writer_while_a_slow_import_runs_loses_nothing(tmp_path, capsys, writer):
    project = folder_with_project(tmp_path)
    capsys.readouterr()
    child = start_slow("import", project, tmp_path)
    code = main(command(writer, project, tmp_path))
    err = capsys.readouterr().err
    out, child_err = child.communicate(timeout=120)
    assert child.returncode == 0, child_err
    assert "1 line(s)" in out
    final = Project.open(project)
    assert "z_iso" in {line.name for line in final.measurement().lines}
    kind = "identifications" if writer == "identify" else "sensitivity"
    if code == 0:
        assert "slow" in final.results(kind)
    else:
        assert code == 1 and f"locked by process {child.pid}" in err
        assert "Traceback" not in err
