"""``study-status``: who is where in a study log (it may be served meanwhile).

python -m corrections_sim.run study-status --db results/study/study.sqlite
"""

from __future__ import annotations

import argparse
from pathlib import Path

from corrections_sim.cli.command import Command
from corrections_sim.cli.errors import UsageError
from corrections_sim.cli.study_files import STUDY_DB


def run_study_status(args: argparse.Namespace) -> list[Path]:
    """Who is where in a study log (it may be served meanwhile)."""
    from corrections_sim.session.log import LogError, StudyLog
    from corrections_sim.userstudy.report import protocol_of

    db = Path(args.db) if args.db else STUDY_DB
    if not db.is_file():
        raise UsageError(f"--db {db}: no such study log")
    try:
        with StudyLog(db) as log:
            protocol = protocol_of(log)
            for person in log.participants():
                steps = protocol.steps(int(person["index"]))
                done = {r["position"] for r in log.steps(person["code"]) if r["finished"]}
                position = next((i for i in range(len(steps)) if i not in done), len(steps) - 1)
                state = " (withdrawn)" if person["withdrawn"] else ""
                kind = " simulated" if person["simulated"] else ""
                print(
                    f"{person['code']}{kind}: step {position + 1}/{len(steps)} "
                    f"{steps[position].key}{state}"
                )
    except (LogError, ValueError) as exc:
        raise UsageError(str(exc).splitlines()[0]) from None
    return []


COMMAND = Command(
    name="study-status",
    run=run_study_status,
    help="who is where in a study log",
    options=("db",),
    option_help={"db": "the study log (default results/study/study.sqlite)"},
    nothing_kept=lambda args: "study-status stopped; it only reads the log",
)
