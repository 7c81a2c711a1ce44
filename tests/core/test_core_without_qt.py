"""volucal.core imports and runs with no Qt at all (the library and CLI install, `pip install
volucal` without the gui extra)."""

import subprocess
import sys
import textwrap

BLOCK_QT = textwrap.dedent(
    """
    import importlib.abc, sys

    class NoQt(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in ("PySide6", "shiboken6", "pyqtgraph"):
                raise ImportError(f"{name} is blocked: the core must not need it")
            return None

    sys.meta_path.insert(0, NoQt())
    """
)


def run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", BLOCK_QT + textwrap.dedent(code)],
        capture_output=True, text=True, timeout=300,
    )


def test_every_core_module_imports_without_qt() -> None:
    out = run(
        """
        import importlib, pkgutil, sys
        import volucal.core
        names = [m.name for m in pkgutil.walk_packages(volucal.core.__path__, "volucal.core.")]
        for name in names:
            importlib.import_module(name)
        assert not any(m.startswith(("PySide6", "pyqtgraph", "volucal.app.")) for m in sys.modules
                       if m != "volucal.app.commands" and not m.startswith("volucal.app.commands."))
        print(len(names))
        """
    )
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.strip()) > 30


def test_the_cli_works_and_the_gui_commands_say_what_is_missing() -> None:
    out = run(
        """
        from volucal.core.cli import build_parser, main
        build_parser()
        code = main(["gui", "--smoke"])
        print("exit", code)
        """
    )
    assert out.returncode == 0, out.stderr
    assert "exit 1" in out.stdout
    assert "pip install 'volucal[gui]'" in out.stderr
    assert "Traceback" not in out.stderr
