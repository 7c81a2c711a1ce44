"""The command-line reference (docs/cli.md), generated from the argument parser so that it cannot
drift from what ``volucal --help`` says.

``python docs/make_cli_docs.py`` writes the page; tests/core/test_cli_docs.py fails when the page
in the repository differs from :func:`cli_reference`.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterator
from contextlib import contextmanager

from .cli import build_parser

#: Help text is wrapped at this width whatever the terminal, so the page is reproducible.
WIDTH_COLUMNS = 100

HEADER = """# Command-line reference

Generated from volucal's argument parser by `python docs/make_cli_docs.py`: do not edit by hand
(tests/core/test_cli_docs.py fails when this page and the parser differ). Every command that
prints results takes `--json`; an error is one line on stderr naming the file (and line) with exit
code 1, and `volucal --debug COMMAND …` shows the traceback instead. `volucal COMMAND --help`
prints the same text as below.
"""


@contextmanager
def _columns(width: int) -> Iterator[None]:
    # argparse wraps help to $COLUMNS (else the terminal's width)
    before = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(width)
    try:
        yield
    finally:
        if before is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = before


def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The sub-command parsers of ``parser`` by name, in the order they were added."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def cli_reference() -> str:
    """docs/cli.md: the main help, then every sub-command's help, in code blocks."""
    with _columns(WIDTH_COLUMNS):
        parser = build_parser()
        parts = [HEADER, "## volucal\n", "```text", parser.format_help().rstrip(), "```", ""]
        for name, sub in subcommands(parser).items():
            parts += [f"## volucal {name}\n", "```text", sub.format_help().rstrip(), "```", ""]
    return "\n".join(parts)
