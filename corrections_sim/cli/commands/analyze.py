"""``analyze``: a study log's tidy CSVs, mixed model, paired comparisons, plots and report.

python -m corrections_sim.run analyze results/study/study.sqlite
"""

from __future__ import annotations

import argparse
from pathlib import Path

from corrections_sim.cli.command import Command
from corrections_sim.cli.errors import UsageError


def run_analyze(args: argparse.Namespace) -> list[Path]:
    """Tidy CSVs, the mixed model, paired comparisons, plots and a report of a study log."""
    from corrections_sim.session.log import LogError
    from corrections_sim.userstudy.report import analyze

    if not args.study_file:
        raise UsageError("analyze: give the study log, e.g. analyze results/study/study.sqlite")
    db = Path(args.study_file)
    out = Path(args.out) if args.out else db.parent / "analysis"
    try:
        return analyze(db, out)
    except (LogError, ValueError) as exc:
        raise UsageError(str(exc).splitlines()[0]) from None


COMMAND = Command(
    name="analyze",
    run=run_analyze,
    help="a study log's tidy CSVs, mixed model, paired comparisons, plots and report",
    options=("study_file", "out"),
    file="LOG",
    option_help={
        "study_file": "the study log (SQLite) a protocol's study wrote",
        "out": "where the tables, plots and report go (default: LOG's folder/analysis)",
    },
    nothing_kept=lambda args: (
        "analyze stopped before it finished (it only reads the log); run it again"
    ),
)
