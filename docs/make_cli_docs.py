"""Write docs/cli.md from volucal's argument parser (``--check``: exit 1 if it is out of date).

    python docs/make_cli_docs.py [--check]
"""

import argparse
import sys
from pathlib import Path

from volucal.core.cli_docs import cli_reference

PAGE = Path(__file__).resolve().parent / "cli.md"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="do not write; exit 1 when docs/cli.md differs from the parser")
    args = parser.parse_args()
    text = cli_reference()
    if args.check:
        current = PAGE.read_text(encoding="utf-8") if PAGE.is_file() else ""
        if current != text:
            print(f"{PAGE} is out of date: run python docs/make_cli_docs.py", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(text, encoding="utf-8")
    print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
