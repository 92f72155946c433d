"""``pilot``: simulated participants through a protocol into a log, then its analysis.

python -m corrections_sim.run pilot experiments/protocol.toml --participants 12
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from corrections_sim.cli.command import Command
from corrections_sim.cli.errors import UsageError
from corrections_sim.cli.study_files import open_study


def run_pilot(args: argparse.Namespace) -> list[Path]:
    """N simulated participants through the protocol into a log, then its analysis."""
    from corrections_sim.userstudy.cohort import simulate_cohort
    from corrections_sim.userstudy.report import analyze

    out = Path(args.out) if args.out else Path("results") / "pilot"
    db = Path(args.db) if args.db else out / "study.sqlite"
    count = args.participants or 12
    run = open_study(args, db)
    try:
        if run.protocol.simulation is None:
            raise UsageError(f"{args.study_file}: no [simulation] table (the population)")
        started = time.perf_counter()

        def progress(done: int, total: int) -> None:
            print(f"pilot: {done}/{total} simulated participants", file=sys.stderr, flush=True)

        simulate_cohort(run, range(count), progress)
        print(f"pilot: {time.perf_counter() - started:.0f} s", file=sys.stderr)
    except ValueError as exc:
        raise UsageError(str(exc).splitlines()[0]) from None
    finally:
        run.log.close()
    return [db, *analyze(db, out / "analysis")]


COMMAND = Command(
    name="pilot",
    run=run_pilot,
    help="simulated participants through a protocol, then its analysis",
    options=("study_file", "out", "db", "participants"),
    file="PROTOCOL",
    option_help={
        "study_file": "the protocol (TOML) with its [simulation] population",
        "db": "the pilot's log (default OUT/study.sqlite)",
        "out": "the pilot's folder (default results/pilot)",
    },
    nothing_kept=lambda args: (
        "pilot stopped; the participants simulated so far are kept in its log "
        "(run it again to go on from them)"
    ),
)
