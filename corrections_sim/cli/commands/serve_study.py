"""``serve-study``: a protocol's study served to several participants at once, with the
experimenter's page, until Ctrl-C (every step is logged as it happens).

    python -m corrections_sim.run serve-study experiments/protocol.toml --enroll P01,P02
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from corrections_sim.cli.command import Command
from corrections_sim.cli.errors import UsageError
from corrections_sim.cli.study_files import STUDY_DB, open_study

#: Seconds the study server checks for the end between (Ctrl-C stops it at once).
POLL = 0.5


def _codes(text: str | None) -> list[str]:
    from corrections_sim.session.log import check_participant

    codes = [c.strip() for c in (text or "").split(",") if c.strip()]
    try:
        return [check_participant(c) for c in codes]
    except ValueError as exc:
        raise UsageError(f"--enroll: {exc}") from None


def run_serve_study(args: argparse.Namespace) -> list[Path]:
    """Serve a protocol to several participants at once until Ctrl-C."""
    from corrections_sim.pages.server import AddressError, open_server, stop
    from corrections_sim.pages.study import StudyServer
    from corrections_sim.session.log import StudyError

    db = Path(args.db) if args.db else STUDY_DB
    codes = _codes(args.enroll)
    host = args.host or "127.0.0.1"
    run = open_study(args, db)
    for code in codes:  # before the server: a used code writes nothing and serves nothing
        if run.log.participant(code) is not None:
            run.log.close()
            raise UsageError(
                f"--enroll {code}: already used in {db} (a returning participant resumes "
                "through their link; give a new code, or a new link from the experimenter's page)"
            )
    try:
        server = open_server(host, args.port or 8080)
    except AddressError as exc:
        run.log.close()
        raise UsageError(str(exc)) from None
    if host not in ("127.0.0.1", "localhost", "::1"):
        print(
            f"warning: serving on {host}: anyone who can reach it may open the page; each "
            "participant gets only their own link's page, the experimenter's needs its secret",
            file=sys.stderr,
        )
    try:
        study = StudyServer(server, run, host=host, speed=args.speed or 1.0)
        for code in codes:
            try:
                link = study.enroll(code)
            except StudyError as exc:
                raise UsageError(str(exc)) from None
            print(f"participant {code}: {link}", file=sys.stderr, flush=True)
        print(
            f"study {run.protocol.description or ''} ({db}): experimenter's page "
            f"{study.experimenter_link()} ; Ctrl-C stops the server (every step is logged)",
            file=sys.stderr,
            flush=True,
        )
        while True:
            time.sleep(POLL)
    finally:
        stop(server)
        run.log.close()


COMMAND = Command(
    name="serve-study",
    run=run_serve_study,
    help="serve a protocol's study to several participants at once, with the experimenter's page",
    options=("study_file", "db", "host", "port", "speed", "enroll"),
    file="PROTOCOL",
    option_help={
        "study_file": "the protocol (TOML; experiments/protocol.toml)",
        "db": "the study log (default results/study/study.sqlite; a log belongs to one protocol)",
    },
)
