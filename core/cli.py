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
import os
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


#: Exit status when the reader of our output went away (``volucal … | head -1``): the shell's
#: 128 + SIGPIPE, as if the default signal action had ended the process.
EXIT_BROKEN_PIPE = 141


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        result = args.handler(args)
        # flushed here, not at exit, so that a closed pipe is caught below
        sys.stdout.flush()
    except BrokenPipeError:
        return _closed_pipe()
    except UserError as exc:
        if args.debug:
            raise
        print(f"volucal: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("volucal: interrupted", file=sys.stderr)
        return 130
    return int(result or 0)


def _closed_pipe() -> int:
    """The reader of stdout is gone: exit quietly (Python's documented recipe, "Note on
    SIGPIPE"): point stdout at devnull so that the flush at interpreter exit cannot raise
    again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        # stdout without a file descriptor (captured): nothing is left to flush
        pass
    return EXIT_BROKEN_PIPE


if __name__ == "__main__":
    sys.exit(main())
