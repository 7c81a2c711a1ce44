"""Entry point of the frozen build: the ``volucal`` command (``volucal gui`` for the workbench)."""

import multiprocessing
import sys

from volucal.core.cli import main

if __name__ == "__main__":
    # the workbench runs long computations in worker processes (volucal.app.engine): in the
    # frozen program a worker starts here and must not run the command line
    multiprocessing.freeze_support()
    sys.exit(main())
