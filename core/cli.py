"""The ``volucal`` command.

Each sub-command lives in its own module in ``volucal.core.commands`` and exposes
``register(subparsers)``; this module finds them, parses the arguments and turns every
:class:`volucal.core.userror.UserError` into one clear message on stderr with a non-zero exit
code (``--debug`` shows the traceback).
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence

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
    modules = sorted(m.name for m in pkgutil.iter_modules(commands.__path__))
    for name in modules:
        module = importlib.import_module(f"{commands.__name__}.{name}")
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
