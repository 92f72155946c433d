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
from corrections_sim.cli.study_files import STUDY_DB, check_study, open_study

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
    """Serve a protocol to several participants at once until Ctrl-C: the links on the
    standard output (one a line, for a lab to keep), what the server does on stderr."""
    from corrections_sim.pages.server import AddressError, open_server, stop
    from corrections_sim.pages.study import StudyServer
    from corrections_sim.session.log import StudyError

    db = db_of(args)
    codes = _codes(args.enroll)
    host = args.host or "127.0.0.1"
    loaded = check_study(args)
    if db.is_file():  # a used code serves nothing and enrolls nobody
        _check_unused(codes, db)
    # The address before the log: a busy port or an unusable host makes no file.
    try:
        server = open_server(host, args.port or 8080)
    except AddressError as exc:
        raise UsageError(str(exc)) from None
    try:
        run = open_study(args, db, loaded)
    except BaseException:
        stop(server)
        raise
    study = None
    try:
        if host not in ("127.0.0.1", "localhost", "::1"):
            print(
                f"warning: serving on {host}: anyone who can reach it may open the page; each "
                "participant gets only their own link's page, the experimenter's needs its "
                "secret",
                file=sys.stderr,
            )
        t0 = time.perf_counter()
        held = run.read_plans()  # read now, not at the first participants' submits
        if held:
            print(f"read {held:,} stored plans between atlas nodes in "
                  f"{time.perf_counter() - t0:.1f} s", file=sys.stderr)  # fmt: skip
        study = StudyServer(server, run, host=host, speed=args.speed or 1.0)
        args.serving = True  # for an interrupt's message
        for code in codes:
            try:
                link = study.enroll(code)
            except StudyError as exc:
                raise UsageError(str(exc)) from None
            print(f"participant {code}: {link}", flush=True)
        print(f"experimenter: {study.experimenter_link()}", flush=True)
        print(
            f"study {run.protocol.description or ''} ({db}): serving; the links are on the "
            "standard output (the experimenter's enrolls more); Ctrl-C stops the server "
            "(every step is logged)",
            file=sys.stderr,
            flush=True,
        )
        while True:
            time.sleep(POLL)
    finally:
        if study is not None:
            study.settle()  # a push still learning is logged before the log closes
        stop(server)
        run.log.close()


def _check_unused(codes: list[str], db: Path) -> None:
    from corrections_sim.session.log import LogError, StudyLog

    try:
        with StudyLog(db) as log:
            used = [code for code in codes if log.participant(code) is not None]
    except LogError as exc:
        raise UsageError(str(exc).splitlines()[0]) from None
    if used:
        raise UsageError(
            f"--enroll {used[0]}: already used in {db} (a returning participant resumes "
            "through their link; give a new code, or a new link from the experimenter's page)"
        )


def db_of(args: argparse.Namespace) -> Path:
    return Path(args.db) if args.db else STUDY_DB


def nothing_kept(args: argparse.Namespace) -> str:
    """What a stopped study server leaves: every step taken, in its log."""
    if not getattr(args, "serving", False):
        return (
            f"serve-study stopped while starting; a participant it enrolled is in {db_of(args)}"
            " with the link it printed"
        )
    return (
        f"serve-study stopped serving; every step participants took is in {db_of(args)} "
        "(serve it again to go on: their links still work, a returning participant waits "
        "for the experimenter's Let continue)"
    )


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
    nothing_kept=nothing_kept,
)
