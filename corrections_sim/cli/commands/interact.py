"""``interact``: a person corrects the robot in a browser page (or, ``--headless``, the study's
simulated user does); every confirmed correction is logged first, so a session resumes
(``--resume``) where it stopped."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from corrections_sim.cli import output_folder
from corrections_sim.cli.command import Command
from corrections_sim.cli.errors import UsageError
from corrections_sim.cli.options import label
from corrections_sim.defaults import DEFAULTS


def _interact_settings(args: argparse.Namespace):
    """The study an interactive session runs: the file given, else fig. 4's paper settings
    (the 48 environments, laptop and table), with the command line's overrides."""
    from corrections_sim.figures.presets import EXPERIMENTS_DIR
    from corrections_sim.study import schema

    overrides = {n: getattr(args, n) for n in ("set", "seed", "theta0", "cov0", "user")}
    overrides = {n: v for n, v in overrides.items() if v is not None}
    # The session's learner is one of the study's, so --set learners.NAME.… reaches it.
    overrides["session_learner"] = args.learner or DEFAULT_LEARNER
    if args.headless and args.theta_star is not None:
        overrides["theta_star"] = args.theta_star
    source = Path(args.study_file) if args.study_file else EXPERIMENTS_DIR / "fig4.toml"
    name = source.stem if args.study_file else "fig4"
    try:
        return schema.load_study(source, name=name, quick=False, overrides=overrides)
    except ValueError as exc:
        unknown = f"learners.{overrides['session_learner']}: unknown learner"
        if str(exc).startswith(unknown):  # (a study's plug-ins may register it: asked there)
            raise UsageError(f"--learner {str(exc)[len('learners.') :]}") from None
        raise UsageError(f"{source}: {exc}") from None


def _physical_learner(settings, learner: str, args: argparse.Namespace) -> dict | None:
    """A physical session's learner: the study's, with the ``physical`` model of a push where
    it takes a model and none was set (``--set learners.NAME.model=...``)."""
    from corrections_sim.session.session import physical_learner

    given = any(item.startswith(f"learners.{learner}.model") for item in args.set or ())
    return physical_learner(settings, learner, model_set=given)


def db_of(args: argparse.Namespace) -> Path:
    return (
        Path(args.db) if args.db else output_folder.default_out(False) / "interact" / "study.sqlite"
    )


#: Who learns in a session without --learner.
DEFAULT_LEARNER = DEFAULTS["session"][0]
#: What ``interact --resume`` takes besides; the session's own settings are the rest.
RESUME_OPTIONS = ("resume", "db", "host", "port", "speed")
#: After "Done", the server keeps the page (the deployment) up until its tab closes, at most
#: this many seconds (Ctrl-C stops it at once).
AFTER_DONE = 600.0


def _check_interact_options(args: argparse.Namespace) -> None:
    """What can be refused before anything is opened or written (no database file, no
    session row, no server)."""
    from corrections_sim.session.log import check_participant

    if args.participant is not None:
        try:
            check_participant(args.participant)
        except ValueError as exc:
            raise UsageError(f"--participant: {exc}") from None
    if args.resume is not None:
        given = [
            label(name)
            for name in COMMAND.options
            if name not in RESUME_OPTIONS and getattr(args, name) not in (None, False)
        ]
        if given:
            raise UsageError(
                f"--resume: the session's own settings apply; drop {', '.join(given)} "
                "(give --db, and --host, --port or --speed if they change)"
            )
        db = db_of(args)
        if not db.is_file():
            raise UsageError(f"--db {db}: no such file; --resume reads the session's log")
        from corrections_sim.pages.server import serving
        from corrections_sim.session.log import LogError, StudyLog

        try:
            with StudyLog(db) as log:
                row = log.session(args.resume)
                pid = serving(log, args.resume)
        except LogError as exc:
            raise UsageError(f"--db {db}: {exc}") from None
        if row.ended is not None:
            raise UsageError(f"--resume {args.resume}: the session ended at {row.ended}")
        if pid is not None:
            raise UsageError(
                f"--resume {args.resume}: its page is still served by process {pid} on this "
                "machine; stop that one first (Ctrl-C), or open its page"
            )
        return
    physical = args.mode == "physical"
    if physical and args.drag_model:
        raise UsageError("--drag-model: a physical session deforms by the push; drop it")
    if args.speed is not None and not physical:
        raise UsageError("--speed: plays a physical session's motions; add --mode physical")
    if args.labelled is not None and args.headless:
        raise UsageError("--labelled: asks a person at the page; drop --headless")


def _host(args: argparse.Namespace) -> str:
    """Where the page is served: --host as given (an empty one is refused, not defaulted)."""
    return "127.0.0.1" if args.host is None else args.host


def _session_speed(log, session, given: float | None) -> float:
    """A physical page's speed: the one given, else the one its page last played at (a
    resumed session keeps its speed), else real time."""
    if given is not None:
        if not session.physical:
            raise UsageError(f"--speed: session {session.id} is dragged, not pushed; drop it")
        return given
    pages = log.events(session.id, "page")
    return float(pages[-1]["detail"]["speed"]) if pages else 1.0


def run_interact(args: argparse.Namespace) -> list[Path]:
    """A session of corrections: in a browser page (prints its URL; ends with "Done" or
    Ctrl-C, every confirmed correction already logged), or headless by a simulated user."""
    from corrections_sim.session.log import LogError, StudyLog

    _check_interact_options(args)
    plan = None if args.resume is not None else _session_plan(args)
    server = None
    if not args.headless:
        from corrections_sim.pages.server import AddressError, open_server

        # Before the log is touched: a busy port or an unusable host writes nothing.
        try:
            server = open_server(_host(args), args.port or 8080)
        except AddressError as exc:
            raise UsageError(str(exc)) from None
    try:
        db = db_of(args)
        try:
            log = StudyLog(db)
        except (LogError, OSError) as exc:
            raise UsageError(f"--db {db}: {exc}") from None
        try:
            session = _open_session(args, log, plan)
            args.interact_session = session.id  # for an interrupt's message
            if args.headless:
                return _run_headless(args, session, db)
            speed = _session_speed(log, session, args.speed)
        except (LogError, ValueError) as exc:
            log.close()
            raise UsageError(str(exc).splitlines()[0]) from None
        return _serve_session(args, server, session, log, db, speed)
    except BaseException:
        if server is not None:
            from corrections_sim.pages.server import stop

            stop(server)
        raise


def _session_plan(args: argparse.Namespace) -> dict:
    """What a new session is started with (Session.start's arguments), checked before the
    server or the log is opened: a bad study file, learner, model or option writes nothing."""
    from corrections_sim.session.session import Session

    settings = _interact_settings(args)
    corrector = "person"
    if args.headless:
        corrector = settings.study.user_params()
        if settings.user_features:
            raise UsageError(
                "user_features: a headless session plans the simulated person over the "
                "robot's features; simulate a person with their own in a study "
                "(run study FILE)"
            )
    learner = args.learner or DEFAULT_LEARNER
    physical = args.mode == "physical"
    plan = {
        "settings": settings,
        "learner": learner,
        "params": _physical_learner(settings, learner, args) if physical else None,
        "correction": "physical" if physical else (args.drag_model or "waypoint"),
    }
    try:
        Session.prepare(**plan)
    except ValueError as exc:
        raise UsageError(str(exc).splitlines()[0]) from None
    participant = args.participant or ("simulated" if args.headless else "anonymous")
    plan |= {"participant": participant, "corrector": corrector}
    if args.labelled:
        from corrections_sim.session.session import make_asks

        preference = args.theta_star
        if preference is not None and len(preference) != settings.study.k:
            raise UsageError(
                f"--theta-star: {len(preference)} weights, the study has {settings.study.k} "
                f"features ({', '.join(settings.features)})"
            )
        plan |= {"asks": make_asks(args.labelled, settings.study.seed), "preference": preference}
    return plan


def _open_session(args: argparse.Namespace, log, plan: dict | None):
    from corrections_sim.session.session import Session

    if args.resume is not None:
        return Session.resume(log, args.resume)
    return Session.start(log=log, **plan)


def _run_headless(args: argparse.Namespace, session, db: Path) -> list[Path]:
    """The study's simulated user corrects the session, --iterations times, and ends it."""
    from corrections_sim.session.simulate import simulate

    s = session.settings.study
    count = args.iterations or s.iterations
    rows = simulate(session, s.user, s.theta_star, count)
    session.finish()
    session.log.close()
    print(
        f"session {session.id}: {len(rows)} corrections by the simulated {s.user_name} "
        f"user; θ̂ = {np.round(session.belief.theta, 4).tolist()}",
        file=sys.stderr,
    )
    return [db]


def _serve_session(args, server, session, log, db: Path, speed: float) -> list[Path]:
    """The page of ``session`` on ``server`` until "Done" and its tab closing (at most
    :data:`AFTER_DONE` s later), or an interrupt."""
    from corrections_sim.pages.server import show, stop

    page = None
    try:
        page = show(server, session, speed=speed)
        url = f"http://{_host(args)}:{server.get_port()}"
        resume = f"--resume {session.id} --db {db}"
        how = f"physical at speed {speed:g}" if session.physical else "drag"
        print(
            f"session {session.id} ({session.learner}, {how}, "
            f"participant {log.session(session.id).participant}): open {url} ; "
            f"resume later with {resume}",
            file=sys.stderr,
            flush=True,
        )
        while not page.finished.wait(0.5):
            pass
        print(
            f"session {session.id}: done; the page shows the deployment until its tab closes "
            f"(the server stops then, or in {AFTER_DONE / 60:.0f} min; Ctrl-C stops it now)",
            file=sys.stderr,
            flush=True,
        )
        waited = 0.0
        while waited < AFTER_DONE and not page.left.wait(0.5):
            waited += 0.5
    finally:
        if page is not None:
            page.settle()  # a push still learning is logged before the log closes
        stop(server)
        log.close()
    return [db]


def nothing_kept(args: argparse.Namespace) -> str:
    """What an interrupted session leaves: every confirmed correction, and how to resume."""
    session = getattr(args, "interact_session", None)
    if session is None:
        return "interact stopped before a session was started"
    return (
        f"interact stopped session {session}; every confirmed correction is in its log; "
        "continue it with "
        f"--resume {session} --db {db_of(args)}"
    )


COMMAND = Command(
    name="interact",
    run=run_interact,
    help="a person corrects the robot in a browser page (or --headless)",
    options=(
        "study_file",
        "learner",
        "db",
        "participant",
        "host",
        "port",
        "resume",
        "drag_model",
        "headless",
        "mode",
        "speed",
        "labelled",
        "user",
        "iterations",
        "seed",
        "set",
        "theta_star",
        "theta0",
        "cov0",
    ),
    option_help={
        "study_file": "a study file (TOML) whose settings the session runs (default: fig. 4's)",
        "learner": f"who learns (default {DEFAULT_LEARNER})",
    },
    nothing_kept=nothing_kept,
)
