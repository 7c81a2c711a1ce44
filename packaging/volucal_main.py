"""Entry point of the frozen build: the ``volucal`` command (``volucal gui`` for the workbench)."""

import sys

from volucal.core.cli import main

if __name__ == "__main__":
    sys.exit(main())
