"""docs/cli.md is the parser's own help text (volucal.core.cli_docs), never a stale copy."""

from pathlib import Path

from volucal.core.cli import build_parser
from volucal.core.cli_docs import cli_reference, subcommands

PAGE = Path(__file__).resolve().parents[2] / "docs" / "cli.md"


def test_cli_page_is_what_the_parser_generates():
    assert PAGE.read_text(encoding="utf-8") == cli_reference(), (
        "docs/cli.md is out of date: run python docs/make_cli_docs.py"
    )


def test_every_command_and_option_is_on_the_page():
    page = PAGE.read_text(encoding="utf-8")
    commands = subcommands(build_parser())
    assert {"calibrate", "demo", "export", "import", "iso230-2", "report"} <= set(commands)
    for name, parser in commands.items():
        assert f"## volucal {name}\n" in page
        for action in parser._actions:
            for option in action.option_strings:
                assert option in page, f"{name} {option}"
