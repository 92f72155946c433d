"""``models``: the scene written as MJCF into models/ (or, ``--check``, a list of the files that
drifted from what the code writes; exit status 1 if any).

    python -m corrections_sim.run models --check
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from corrections_sim.cli.command import Command


class Drifted(RuntimeError):
    """``models --check`` found files that differ from what the code writes."""


def run_models(args: argparse.Namespace) -> list[Path]:
    """Write models/ (or another ``--out``), or with ``--check`` only compare."""
    from corrections_sim.scene.models import MODELS_DIR, drift, write

    folder = MODELS_DIR if args.out is None else Path(args.out)
    if args.check:
        stale = drift(folder)
        for name in stale:
            print(f"differs from the code: {folder / name}", file=sys.stderr)
        if stale:
            raise Drifted(f"{len(stale)} file(s) in {folder} differ from the code")
        return []
    return write(folder)


COMMAND = Command(
    name="models",
    run=run_models,
    help="write the scene as MJCF into models/ (--check: only list the files that drifted)",
    options=("out", "check"),
    option_help={"out": "folder (default: the repository's models/)"},
    nothing_kept=lambda args: "models stopped before it had written every file; run it again",
)
