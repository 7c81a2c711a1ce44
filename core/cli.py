"""The ``volucal`` command.

Each sub-command lives in its own module in ``volucal.core.commands`` and exposes
``register(subparsers)``; other packages add theirs through the ``volucal.commands`` entry point
group (the workbench's ``gui`` and ``report``). This module finds them, parses the arguments and
turns every
:class:`volucal.core.userror.UserError` into one clear message on stderr with a non-zero exit
code (``--debug`` shows the traceback).
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence
from importlib import metadata

from . import commands
from .userror import UserError


def build_parser() -> argparse.ArgumentParser:
    from volucal import __version__

    parser = argparse.ArgumentParser(
        prog="volucal",
        description=(
            "Volumetric calibration of 3-axis CNC machine tools: import laser-interferometer logs, "
            "identify the 21 geometric errors, close the loop on what they cannot explain, rank "
            "the errors by EFAST sensitivity and export compensation tables."
        ),
    )
    parser.add_argument("--version", action="version", version=f"volucal {__version__}")
    parser.add_argument("--debug", action="store_true", help="show a traceback on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    modules = [
        importlib.import_module(f"{commands.__name__}.{m.name}")
        for m in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name)
    ]
    for entry in sorted(metadata.entry_points(group="volucal.commands"), key=lambda e: e.name):
        try:
            modules.append(entry.load())
        except ImportError:
            # an extension whose package is not installed here: its commands are not offered
            continue
    for module in modules:
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        result = args.handler(args)
    except UserError as exc:
        if args.debug:
            raise
        print(f"volucal: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("volucal: interrupted", file=sys.stderr)
        return 130
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
