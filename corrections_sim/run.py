"""``python -m corrections_sim.run``: the command line (:mod:`corrections_sim.cli.main`)."""

import os
import sys

from corrections_sim.cli.main import main

if __name__ == "__main__":
    status = main()
    if status == 130:
        # The workers are dead already; skip the interpreter's exit-time joins of pools and
        # threads, which an interrupt may have left in any state.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    sys.exit(status)
