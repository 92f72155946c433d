"""What the user study's commands share: where a study's log goes without ``--db``, and the
protocol file a command was given, checked and opened with its log (docs/user-study.md). The
study itself is :mod:`corrections_sim.userstudy.participant`, its analysis
:mod:`corrections_sim.userstudy.report` and :mod:`corrections_sim.userstudy.cohort`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from corrections_sim.cli.errors import UsageError

#: Where a study's log goes without --db.
STUDY_DB = Path("results") / "study" / "study.sqlite"


def protocol_path(args: argparse.Namespace) -> Path:
    if not args.study_file:
        raise UsageError(f"{args.figure}: give the protocol file, e.g. experiments/protocol.toml")
    path = Path(args.study_file)
    if not path.is_file():
        raise UsageError(f"{path}: no such protocol file")
    return path


def check_study(args: argparse.Namespace) -> tuple:
    """The protocol file given and its conditions' study settings, checked, with nothing
    written (:func:`corrections_sim.userstudy.cohort.load`)."""
    from corrections_sim.userstudy.cohort import load

    try:
        return load(protocol_path(args))
    except (ValueError, OSError) as exc:
        raise UsageError(str(exc).splitlines()[0]) from None


def open_study(args: argparse.Namespace, db: Path, loaded: tuple | None = None):
    """The protocol given with its log ``db`` (made if new); ``loaded``: what
    :func:`check_study` gave for it."""
    from corrections_sim.session.log import LogError
    from corrections_sim.userstudy.cohort import open_run

    try:
        return open_run(protocol_path(args), db, loaded)
    except (LogError, ValueError, OSError) as exc:
        raise UsageError(str(exc).splitlines()[0]) from None
