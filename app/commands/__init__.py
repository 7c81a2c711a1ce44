"""Commands the workbench adds to the ``volucal`` CLI (``gui``, ``report``).

They are registered through the ``volucal.commands`` entry point group (pyproject.toml), so the
core's CLI finds them without ever importing the GUI package by name. The modules import only
argparse and the core at module level; Qt is imported inside the handlers, and a core-only
install gets a clear message instead.
"""

import importlib.util


def installed(name: str) -> bool:
    """Whether a package can be imported here (a broken or blocked one counts as missing)."""
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False
