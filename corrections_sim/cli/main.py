"""Command line: reproduce a figure of the paper headless.

    python -m corrections_sim.run fig4             # results/fig4/ (CSV, summary, PNG, PDF)
    python -m corrections_sim.run fig5 --quick     # results/quick/fig5/ (what CI runs)
    python -m corrections_sim.run study my.toml    # results/my/ (docs/study-files.md)
    python -m corrections_sim.run scene            # results/scene.png

Bad input ends with a one-line message on stderr and exit status 2; nothing already in the
output folder is overwritten by a run that failed, and a figure folder made with other
settings only with --force (:mod:`corrections_sim.cli.output_folder`). SIGINT and SIGTERM end
the command within seconds at any moment with one line and exit status 130, keeping the
finished runs (:mod:`corrections_sim.cli.executors`).
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import json
import os
import re
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor
from pathlib import Path

import numpy as np

from corrections_sim import provenance
from corrections_sim.cli import output_folder, study_commands
from corrections_sim.cli.errors import UsageError
from corrections_sim.cli.executors import (
    Interrupted,
    check_scheduler_address,
    dask_executor,
    interruption,
    interrupts,
    process_pool,
    uninterrupted,
)

#: Seconds to wait for a Dask scheduler before giving up (--scheduler).
SCHEDULER_TIMEOUT_S = 5
#: New process pools to try when a worker process dies mid-run (finished runs are kept).
WORKER_DEATH_RETRIES = 2


def _out(args: argparse.Namespace) -> Path:
    """The output folder: --out, or the preset's default (see :mod:`output_folder`)."""
    if args.out is None:
        return output_folder.default_out(args.quick)
    if not args.out.strip():
        raise UsageError("--out '': give a folder name (default: results, or results/quick)")
    return Path(args.out)


def _check_replace(
    args: argparse.Namespace, final: Path, figure: str, settings: dict, upgrade=None
) -> str:
    """Refuse (exit 2) to replace a figure folder made by other settings without --force;
    otherwise the line to print, once the command is sure to start, saying what it replaces."""
    preset = "quick" if args.quick else "paper"
    try:
        return output_folder.check_replace(final, figure, preset, settings, args.force, upgrade)
    except output_folder.FolderTaken as exc:
        raise UsageError(f"--out {final.parent}: {exc}") from None


def _say(notice: str) -> None:
    if notice:
        print(notice, file=sys.stderr)


def _writable_dir(path: Path) -> Path:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--out {path}: cannot create the folder ({exc.strerror})") from None
    if not os.access(path, os.W_OK):
        raise UsageError(f"--out {path}: the folder is not writable")
    return path


def run_scene(args: argparse.Namespace) -> list[Path]:
    """The scene with the optimal cup paths for θ = (0, 0) and θ = (+1, −1)."""
    from corrections_sim.planning.planner import Planner, PlannerConfig
    from corrections_sim.scene.environments import paper_environments

    envs = {e.name: e for e in paper_environments()}
    args.env = args.env or "s0-t0-l1"
    if args.env not in envs:
        raise UsageError(f"--env {args.env!r}: unknown; choose one of {', '.join(envs)}")
    env = envs[args.env]
    out = _writable_dir(_out(args))
    planner = Planner(PlannerConfig(features=("laptop", "table")))
    cases = (
        ((0.0, 0.0), (0.15, 0.45, 0.95, 1.0), "θ = (0, 0): smoothness only"),
        ((1.0, -1.0), (0.85, 0.25, 0.55, 1.0), "θ = (+1, −1): seek the laptop, avoid the table"),
    )
    plans = [(planner.solve(np.array(theta), env), rgba, label) for theta, rgba, label in cases]
    from corrections_sim.figures.plotting import save_scene_figure
    from corrections_sim.scene import render

    image = render.render_scene(
        env, [(render.cup_path(p.trajectory), rgba) for p, rgba, _ in plans], q=env.q_start
    )
    legend = [
        (rgba, f"{label}   Φ = (laptop {p.features[0]:.2f}, table {p.features[1]:.2f})")
        for p, rgba, label in plans
    ]
    title = f"Panda carrying coffee, environment {env.name}: optimal cup paths ξ*(θ, E)"
    return [save_scene_figure(out / "scene.png", image, title, legend)]


def run_video(args: argparse.Namespace) -> list[Path]:
    """An MP4/GIF of a recorded fig. 4/5 run: plan, correction, learned plan (see video.py)."""
    from corrections_sim.figures import video
    from corrections_sim.scene.models import ModelFileError

    try:
        result = video.make_video(
            _out(args),
            args.source or "fig4",
            learner=args.learner or "KF",
            run=0 if args.run is None else args.run,
            corrections=args.corrections,
            model_path=None if args.model is None else Path(args.model),
            video_file=None if args.video_file is None else Path(args.video_file),
        )
    except ModelFileError as exc:
        raise UsageError(f"--model {exc}") from None
    except video.VideoInputError as exc:
        raise UsageError(str(exc)) from None
    print(f"{result.frames} frames, {result.seconds:.1f} s", file=sys.stderr)
    return [result.path]


class Progress:
    """Progress of a batch: a tqdm bar with rate and ETA on a terminal, otherwise a plain
    line at most every ``every`` seconds (and at the end), for CI logs."""

    def __init__(self, label: str, *, unit: str = "run", every: float = 15.0, stream=None) -> None:
        self.label = label
        self.unit = unit
        self.every = every
        self.stream = stream or sys.stderr
        self._bar = None
        self._start = time.perf_counter()
        self._last = -np.inf

    def __call__(self, done: int, total: int) -> None:
        if self.stream.isatty():
            if self._bar is None:
                from tqdm import tqdm

                self._bar = tqdm(
                    total=total, initial=done, desc=self.label, unit=self.unit, file=self.stream
                )
            self._bar.update(done - self._bar.n)
            if done == total:
                self._bar.close()
            return
        now = time.perf_counter()
        if done < total and now - self._last < self.every:
            return
        self._last = now
        elapsed = now - self._start
        rate = done / elapsed if elapsed > 0 else 0.0
        eta = f"{(total - done) / rate:.0f} s" if 0 < rate and done < total else "-"
        print(
            f"{self.label}: {done}/{total} {self.unit}s, {elapsed:.0f} s elapsed, ETA {eta}",
            file=self.stream,
            flush=True,
        )


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value}: must be a positive integer")
    return value


def _port(text: str) -> int:
    """A TCP port to listen on, 1 … 65535 (viser's server thread would die on a larger one and
    leave the command waiting for ever)."""
    value = _positive_int(text)
    if value > 65535:
        raise argparse.ArgumentTypeError(f"{value}: a port lies in [1, 65535]")
    return value


def _speed(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a number") from None
    if not (np.isfinite(value) and 0 < value <= 1):
        raise argparse.ArgumentTypeError(f"{value}: must lie in (0, 1]")
    return value


def _positive_float(option: str) -> Callable[[str], float]:
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: expected a number") from None
        if not (np.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"{option} must be a finite number > 0, got {text}")
        return value

    return parse


def _floats(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected comma-separated numbers") from None
    if not all(np.isfinite(values)):
        raise argparse.ArgumentTypeError(f"{text!r}: every value must be finite")
    return values


def _matrix(text: str) -> tuple[tuple[float, ...], ...]:
    """'a,b' is diag(a, b); 'a,b;c,d' is a full matrix, rows separated by ';'."""
    rows = [_floats(row) for row in text.split(";")]
    if len(rows) == 1:
        return tuple(
            tuple(v if i == j else 0.0 for j in range(len(rows[0]))) for i, v in enumerate(rows[0])
        )
    if any(len(r) != len(rows) for r in rows):
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected a square matrix, rows separated by ';'"
        )
    return tuple(rows)


def _counts(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected whole numbers like 4,8,12, got {text!r}"
        ) from None
    if not values or any(v < 1 for v in values):
        raise argparse.ArgumentTypeError(f"expected whole numbers >= 1, got {text!r}")
    return values


def _names(text: str) -> tuple[str, ...]:
    return tuple(n.strip() for n in text.split(","))


def _check_executor_options(args: argparse.Namespace) -> None:
    """--workers and --scheduler, checked before anything is created."""
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers {args.workers}: must be a positive integer")
    if args.scheduler is not None:
        if args.workers is not None:
            raise UsageError("--workers: not with --scheduler (the cluster has its own workers)")
        try:
            check_scheduler_address(args.scheduler)
        except ValueError as exc:
            raise UsageError(f"--scheduler {args.scheduler}: {exc}") from None


@contextlib.contextmanager
def _executor(args: argparse.Namespace) -> Iterator[tuple[Executor, str]]:
    """The executor the runs go to: a Dask cluster's (--scheduler) or a local process pool
    whose workers die with the command (see :mod:`corrections_sim.cli.executors`)."""
    if args.scheduler is None:
        workers = args.workers or len(os.sched_getaffinity(0)) or 1
        with process_pool(workers) as pool:
            yield pool, f"process pool, {workers} worker{'s' if workers != 1 else ''}"
        return
    with contextlib.ExitStack() as stack:
        try:
            executor, n = stack.enter_context(dask_executor(args.scheduler, SCHEDULER_TIMEOUT_S))
        except (ConnectionError, ValueError) as exc:
            raise UsageError(f"--scheduler {args.scheduler}: cannot connect ({exc})") from None
        yield executor, f"dask {args.scheduler}, {n} workers"


@contextlib.contextmanager
def _staging(final: Path) -> Iterator[Path]:
    """A scratch folder beside ``final``; its files replace ``final``'s only if the body
    succeeds, so a failed command leaves earlier results as they were."""
    staging = Path(tempfile.mkdtemp(prefix=f".{final.name}-", dir=final.parent))
    try:
        yield staging
        final.mkdir(parents=True, exist_ok=True)
        with uninterrupted():
            for item in sorted(staging.iterdir()):
                os.replace(item, final / item.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _open_caches(out: Path, name: str, keys: dict, stack: contextlib.ExitStack) -> dict:
    """A :class:`~corrections_sim.study.store.RunStore` per part under ``OUT/.runs/<name>/``, keyed
    by the settings and the code's fingerprint, each locked for the whole command."""
    from corrections_sim.study.store import RunStore, StoreLocked

    root = out / ".runs" / name
    code = provenance.code_fingerprint()
    stores = {}
    for part, key in keys.items():
        store = RunStore(
            root / part if part else root, {"figure": name, "settings": key, "code": code}
        )
        try:
            stack.enter_context(store.lock())
        except StoreLocked as exc:
            raise UsageError(f"--out {out}: {exc}") from None
        stores[part] = store
    return stores


def _cache_folder(stores: dict, out: Path, name: str) -> Path:
    return next(iter(stores.values())).folder if len(stores) == 1 else out / ".runs" / name


def _kept(stores: dict, out: Path, name: str) -> str:
    kept = sum(len(store.load_all()) for store in stores.values())
    return (
        f"{kept} finished run{'s' if kept != 1 else ''} kept in {_cache_folder(stores, out, name)}"
    )


def _overrides(args: argparse.Namespace, figure) -> dict:
    """The options given that ``figure`` takes, as parsed values, by destination."""
    return {n: getattr(args, n) for n in figure.options if getattr(args, n) is not None}


def run_figure(args: argparse.Namespace, figure) -> list[Path]:
    """Any registered figure: its settings, the executor, the output folder, the run (resumed
    from its caches, on a new pool if a worker dies), its files and summary.json, written
    only if everything succeeded."""
    from concurrent.futures.process import BrokenProcessPool

    from corrections_sim.study.store import CorruptRun

    try:
        settings = figure.load(quick=args.quick, overrides=_overrides(args, figure))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    _check_executor_options(args)
    out = _out(args)
    name = figure.folder(settings)
    final = out / name
    recorded = figure.recorded(settings, quick=args.quick)
    notice = _check_replace(args, final, name, recorded, getattr(figure, "upgrade_recorded", None))
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        # The cluster is reached (or the pool started) before anything is written.
        first = stack.enter_context(_executor(args))
        _writable_dir(out)
        caches = _open_caches(out, name, figure.cache_keys(settings), stack)
        _say(notice)
        try:
            for attempt in range(1, WORKER_DEATH_RETRIES + 2):
                try:
                    context = contextlib.nullcontext(first) if attempt == 1 else _executor(args)
                    with context as (executor, where):
                        progress = Progress(name, unit=figure.unit)
                        result = figure.run(settings, executor, progress, caches or None)
                    break
                except BrokenProcessPool:
                    # A worker process died (killed, out of memory): its run was lost, the
                    # finished ones are in the caches; a fresh pool resumes from them.
                    if not caches:
                        raise RuntimeError(f"{name}: a worker process died") from None
                    if attempt > WORKER_DEATH_RETRIES:
                        raise RuntimeError(
                            f"{name}: worker processes died {attempt} times; "
                            f"{_kept(caches, out, name)}, run the command again to resume"
                        ) from None
                    print(f"{name}: a worker died; resuming on a new pool", file=sys.stderr)
        except Interrupted as exc:
            if caches:
                exc.kept = _kept(caches, out, name)
            raise
        except CorruptRun as exc:
            raise RuntimeError(str(exc)) from None
        except (ValueError, TypeError) as exc:
            # A value the checks could not see until it ran (a user's or learner's code that
            # raises): one line naming it; the runs that finished stay in the caches.
            kept = f"; {_kept(caches, out, name)}" if caches else ""
            first_line = str(exc).splitlines()[0] if str(exc) else ""
            raise UsageError(
                f"{name}: a run failed: {type(exc).__name__}: {first_line}{kept}"
            ) from None
    wall = time.perf_counter() - t0
    with _staging(final) as staging:
        fields = figure.write(settings, result, staging)
        summary = {
            "figure": name,
            "preset": "quick" if args.quick else "paper",
            "settings": recorded,
            "executor": where,
            "versions": provenance.versions(),
            "wall_time_s": round(wall, 1),
        }
        if caches:
            summary["run_cache"] = str(_cache_folder(caches, out, name))
        summary.update(fields)
        summary.update(provenance.record(args.argv))
        (staging / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        names = sorted(p.name for p in staging.iterdir())
    return [final / name for name in names]


def run_all(args: argparse.Namespace) -> list[Path]:
    """Every figure of the paper, fig1 to fig6, one after the other (the scene render is
    ``run scene``); each takes the options that apply to it."""
    written = []
    for figure in _figures().values():
        if figure.in_all:
            written += run_figure(args, figure)
    return written


def _figures() -> dict:
    from corrections_sim.figures.registry import figures

    return figures()


def _interact_settings(args: argparse.Namespace):
    """The study an interactive session runs: the file given, else fig. 4's paper settings
    (the 48 environments, laptop and table), with the command line's overrides."""
    from corrections_sim.figures.presets import EXPERIMENTS_DIR
    from corrections_sim.study import schema

    overrides = {n: getattr(args, n) for n in ("set", "seed", "theta0", "cov0", "user")}
    overrides = {n: v for n, v in overrides.items() if v is not None}
    if args.headless and args.theta_star is not None:
        overrides["theta_star"] = args.theta_star
    source = Path(args.study_file) if args.study_file else EXPERIMENTS_DIR / "fig4.toml"
    name = source.stem if args.study_file else "fig4"
    try:
        return schema.load_study(source, name=name, quick=False, overrides=overrides)
    except ValueError as exc:
        raise UsageError(f"{source}: {exc}") from None


def _physical_learner(settings, learner: str, args: argparse.Namespace) -> dict | None:
    """A physical session's learner: the study's, with the ``physical`` model of a push where
    it takes a model and none was set (``--set learners.NAME.model=...``)."""
    from corrections_sim.session.session import physical_learner

    given = any(item.startswith(f"learners.{learner}.model") for item in args.set or ())
    return physical_learner(settings, learner, model_set=given)


def _db(args: argparse.Namespace) -> Path:
    return (
        Path(args.db) if args.db else output_folder.default_out(False) / "interact" / "study.sqlite"
    )


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
            _label(name)
            for name in TOOL_OPTIONS["interact"]
            if name not in RESUME_OPTIONS and getattr(args, name) not in (None, False)
        ]
        if given:
            raise UsageError(
                f"--resume: the session's own settings apply; drop {', '.join(given)} "
                "(give --db, and --host, --port or --speed if they change)"
            )
        db = _db(args)
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
        db = _db(args)
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
    learner = args.learner or "KF-CL"
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
        stop(server)
        log.close()
    return [db]


def _learner_sets(items) -> dict[str, dict]:
    """``--set learners.NAME.KEY=VALUE`` items as {NAME: {KEY: value}} (a replay changes its
    learners only: the environments, features and prior are the session's)."""
    from corrections_sim.study.schema import parse_value

    out: dict[str, dict] = {}
    for item in items:
        path, sep, text = item.partition("=")
        parts = path.strip().split(".")
        if not sep or len(parts) < 3 or parts[0] != "learners" or not all(parts):
            raise UsageError(
                f"--set {item}: a replay sets learners' parameters only, "
                "e.g. learners.KF-CR.model=physical"
            )
        node = out.setdefault(parts[1], {})
        for key in parts[2:-1]:
            node = node.setdefault(key, {})
        node[parts[-1]] = parse_value(text.strip())
    return out


def run_replay(args: argparse.Namespace) -> list[Path]:
    """A logged session replayed through learners, written as a study (curves.csv, the
    plot, summary.json) in OUT/replay-<session>/."""
    from corrections_sim.session.log import LogError, StudyLog
    from corrections_sim.session.replay import replay, write

    if not args.study_file:
        raise UsageError("replay: give the database, e.g. replay results/interact/study.sqlite")
    db = Path(args.study_file)
    if not db.is_file():
        raise UsageError(f"{db}: no such database")
    try:
        log = StudyLog(db)
        ids = log.session_ids()
        session = args.session if args.session is not None else (ids[-1] if ids else None)
        if session is None:
            raise UsageError(f"{db}: no sessions")
        settings, result, facts = replay(
            log, session, args.learners, params=_learner_sets(args.set or ())
        )
    except (LogError, ValueError) as exc:
        raise UsageError(str(exc).splitlines()[0]) from None
    out = _writable_dir(_out(args))
    final = out / f"replay-{session}"
    with _staging(final) as staging:
        fields = write(settings, result, facts, staging)
        summary = {"figure": final.name, "settings": settings.as_dict(), **fields}
        summary.update(provenance.record(args.argv))
        (staging / "summary.json").write_text(
            json.dumps(provenance.plain(summary), indent=2) + "\n"
        )
        names = sorted(p.name for p in staging.iterdir())
    for name, entry in facts["final"].items():
        error = entry["estimate_error"]
        tail = "" if error is None else f", error {error:.3f} against the stated θ"
        print(f"{name}: θ̂ = {np.round(entry['theta'], 3).tolist()}{tail}", file=sys.stderr)
    for entry in facts.get("learnt_features", []):
        weight = entry["weight"]
        said = "" if weight is None else f", final weight {weight:+.3f}"
        said += "" if entry["sd"] is None else f" ± {entry['sd']:.3f}"
        if entry.get("logged_weight") is not None:
            said += f" (the session logged {entry['logged_weight']:+.3f})"
        for true, q in entry["quality"].items():
            said += f"; against {true}: Spearman {q['spearman']:.3f}, R² {q['r2']:.3f}"
        print(
            f"learnt feature {entry['feature']} (after correction {entry['after']}, from "
            f"{entry['traces']} traces){said}",
            file=sys.stderr,
        )
    for name, score in facts.get("labelled", {}).items():
        if score["auc"] is None:  # one kind only: nothing to rank
            continue
        low, high = score["auc_ci95"]
        print(
            f"{name} on the {score['toward']} + {score['nudges']} labelled corrections: ROC AUC "
            f"{score['auc']:.3f} [{low:.3f}, {high:.3f}], median β̂ {score['median_toward']:.3f}"
            f" toward, {score['median_nudge']:.3g} nudges",
            file=sys.stderr,
        )
    return [final / n for n in names]


#: Commands that are not figures: (function, help).
TOOLS: dict[str, tuple[Callable[[argparse.Namespace], list[Path]], str]] = {
    "scene": (run_scene, "render the scene with optimal paths for two preferences"),
    "all": (run_all, "fig1 to fig6, one after the other"),
    "video": (run_video, "animate corrections of a recorded fig4/fig5 run (MP4 or GIF)"),
    "interact": (run_interact, "a person corrects the robot in a browser page (or --headless)"),
    "replay": (run_replay, "replay a logged session (FILE: the database) through learners"),
    "serve-study": (
        study_commands.run_serve_study,
        "serve a protocol's study to several participants at once, with the experimenter's page",
    ),
    "study-status": (study_commands.run_study_status, "who is where in a study log"),
    "analyze": (
        study_commands.run_analyze,
        "a study log's tidy CSVs, mixed model, paired comparisons, plots and report",
    ),
    "pilot": (
        study_commands.run_pilot,
        "simulated participants through a protocol, then its analysis",
    ),
    "power": (
        study_commands.run_power,
        "the power to detect a protocol's condition effect, from simulated studies",
    ),
}
#: The options each tool takes; a figure takes the common ones and its own ``options``.
TOOL_OPTIONS: dict[str, tuple[str, ...]] = {
    "scene": ("out", "env"),
    "video": ("out", "source", "learner", "run", "corrections", "model", "video_file"),
    "interact": (
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
    "replay": ("study_file", "out", "session", "learners", "set"),
    "serve-study": ("study_file", "db", "host", "port", "speed", "enroll"),
    "study-status": ("db",),
    "analyze": ("study_file", "out"),
    "pilot": ("study_file", "out", "db", "participants"),
    "power": ("study_file", "out", "pool", "sizes", "outcome", "workers"),
}


def applies(command: str) -> tuple[str, ...]:
    """The options ``command`` takes; any other option given is refused, not ignored."""
    from corrections_sim.figures.registry import COMMON_OPTIONS

    figures = _figures()
    if command in figures:
        return (*COMMON_OPTIONS, *figures[command].options)
    if command == "all":  # each figure takes what applies to it
        options = [o for f in figures.values() if f.in_all for o in f.options]
        return tuple(dict.fromkeys((*COMMON_OPTIONS, *options)))
    return TOOL_OPTIONS[command]


def command_help(command: str) -> str:
    """``COMMAND --help``: the command's own options only."""
    p = parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[command].format_help()


#: An option's help where one command reads it otherwise than the others do.
_COMMAND_HELP = {
    ("replay", "study_file"): "the study log to replay (the SQLite database interact wrote)",
    ("replay", "set"): "change a replayed learner's parameter, learners.NAME.KEY=VALUE, e.g. "
    "learners.KF-C.model=physical (repeatable; any other key is refused)",
    ("interact", "study_file"): "a study file (TOML) whose settings the session runs "
    "(default: fig. 4's)",
    ("replay", "learners"): "which learners to replay, any registered ones (default "
    "PP,KF,KF-C,BP and the session's own); their parameters are the session's",
    ("interact", "learner"): "who learns (default KF-CL)",
    ("serve-study", "study_file"): "the protocol (TOML; experiments/protocol.toml)",
    ("pilot", "study_file"): "the protocol (TOML) with its [simulation] population",
    ("power", "study_file"): "the protocol (TOML) with its [simulation] population",
    ("analyze", "study_file"): "the study log (SQLite) a protocol's study wrote",
    ("serve-study", "db"): "the study log (default results/study/study.sqlite; a log "
    "belongs to one protocol)",
    ("study-status", "db"): "the study log (default results/study/study.sqlite)",
    ("pilot", "db"): "the pilot's log (default OUT/study.sqlite)",
    ("analyze", "out"): "where the tables, plots and report go (default: LOG's folder/analysis)",
    ("pilot", "out"): "the pilot's folder (default results/pilot)",
    ("power", "out"): "the power analysis' folder (default results/power; the pool's logs "
    "in OUT/.pool, resumable)",
    ("power", "workers"): "worker processes simulating the pool (default 2)",
    ("video", "learner"): "whose run to show (default KF)",
}


def _asks_command_help(given: Sequence[str]) -> str | None:
    """The command of ``COMMAND ... --help`` (None for a bare ``--help``)."""
    if not any(a in ("-h", "--help") for a in given):
        return None
    known = {*_figures(), *TOOLS}
    for token in given:
        if token in known:
            return token
        if not token.startswith("-"):
            return None
    return None


def _label(dest: str) -> str:
    """How the command line spells an option (the positional FILE has no dashes)."""
    return "FILE" if dest == "study_file" else "--" + dest.replace("_", "-")


#: A value that starts with a minus sign but is a number or a list of numbers ("-1,1",
#: "-.5,1;0,2", "-1e-3"): a value, never an option.
_NUMBERS = re.compile(r"-\.?\d[\d.eE+\-]*([,;]\s*[-+]?\.?\d[\d.eE+\-]*)*")


class _Parser(argparse.ArgumentParser):
    """argparse, but a bad option is one line on stderr (no usage block), exit status 2."""

    def error(self, message: str):
        self.exit(2, f"error: {message} (see --help)\n")

    def _parse_optional(self, arg_string: str):
        # argparse reads any token that starts with a minus sign and is not a plain number
        # as an option, so "--theta-star -1,1" would lack its value; a list of numbers is a
        # value wherever it stands.
        if _NUMBERS.fullmatch(arg_string):
            return None
        return super()._parse_optional(arg_string)


def catalogue() -> argparse.ArgumentParser:
    """Every option of every command, once (each command's parser takes its own from here,
    :func:`parser`)."""
    # Imported here, not at the top: they load the planner's stack (CasADi, MuJoCo, pinocchio),
    # and main() has its interrupt handlers in place by the time this runs.
    from corrections_sim.learning.base import LEARNERS
    from corrections_sim.people.corrections import CORRECTIONS
    from corrections_sim.people.users import USERS

    p = _Parser(prog="python -m corrections_sim.run", allow_abbrev=False)
    p.add_argument(
        "study_file",
        nargs="?",
        metavar="FILE",
        help="the study file (TOML; see docs/study-files.md, and experiments/ for examples)",
    )
    p.add_argument(
        "--out",
        help="output folder (default: results; with --quick the scratch folder results/quick)",
    )
    p.add_argument("--env", help="environment name for 'scene' (default: s0-t0-l1)")
    p.add_argument("--quick", action="store_true", help="the figure's quick preset (CI size)")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace a figure folder made with other settings or another preset (without "
        "it, such a folder is left alone and the command refuses)",
    )
    g = p.add_argument_group(
        "learning studies (fig4, fig5, fig6, study); defaults come from the study file"
    )
    g.add_argument(
        "--runs",
        type=_positive_int,
        help="runs per learner (an active learner runs once: it chooses its environments)",
    )
    g.add_argument("--iterations", type=_positive_int, help="corrections per run")
    g.add_argument("--seed", type=int, help="root seed of every random draw")
    g.add_argument(
        "--theta-star", type=_floats, metavar="W,W", help="the user's true weights θ*, e.g. -1,1"
    )
    g.add_argument(
        "--theta0", type=_floats, metavar="W,W", help="the robot's initial estimate θ̂⁰, e.g. 0,0"
    )
    g.add_argument(
        "--cov0",
        type=_matrix,
        metavar="P",
        help="initial covariance P⁰: 'a,b' for diag(a, b) or 'a,b;c,d' row by row "
        "(symmetric positive definite)",
    )
    g.add_argument(
        "--learners",
        type=_names,
        metavar="L,L",
        help="which learners, from "
        + ", ".join(LEARNERS)
        + " or a plug-in's (e.g. PP,KF,AL,KF-C); "
        "their parameters stay as the study file gives them",
    )
    g.add_argument(
        "--user",
        help="the simulated user, from " + ", ".join(USERS) + " or a plug-in's (biased: "
        "moves its worst waypoint(s), the paper's; deform: the path deforms smoothly; noisy: "
        "Φ(ξ*) + Gaussian noise; model: any correction model); replaces the file's user",
    )
    g.add_argument(
        "--set",
        action="append",
        metavar="KEY.PATH=VALUE",
        help="set any key of the study, e.g. user.step=0.5, learners.KF-C.model=deform, "
        "filter.observation_noise=0.1 (repeatable; a value is read as TOML, else as text); "
        "replay sets its learners' keys only (learners.NAME.KEY)",
    )
    g.add_argument("--user-step", type=float, help="= --set user.step=S")
    g.add_argument("--user-waypoints", type=int, help="= --set user.waypoints=N")
    g.add_argument(
        "--correction-model",
        help="KF-C's and AL-C's model of a correction, from " + ", ".join(CORRECTIONS) + " or a "
        "plug-in's (= --set learners.KF-C.model=NAME)",
    )
    g.add_argument("--correction-step", type=float, help="how far KF-C's model moves, (0, 1]")
    g.add_argument("--correction-waypoints", type=int, help="how many waypoints KF-C's model moves")
    g.add_argument(
        "--fixed-alpha",
        type=_positive_float("fixed_alpha"),
        help="a fixed learning rate for PP and PP-C (default: from KF's / KF-C's gains)",
    )
    g.add_argument(
        "--solver",
        help="the planner's solver (default fatrop; ipopt is the original path)",
    )
    g.add_argument(
        "--warm-start",
        action="store_true",
        default=None,
        help="start each solve from the run's nearest solved θ (faster; results move at the "
        "solver's tolerance, see docs/choices.md)",
    )
    g.add_argument(
        "--online",
        action="store_true",
        default=None,
        help="learn during the motion: a physical user's push updates the learner and the robot "
        "replans the rest of the motion (= --set online=true)",
    )
    v = p.add_argument_group("video (reads OUT/<figure>/curves.csv of a finished fig4/fig5)")
    v.add_argument("--from", dest="source", metavar="FIG", help="fig4 or fig5 (default fig4)")
    v.add_argument(
        "--learner",
        help="video: whose run to show (default KF); interact: who learns (default KF-CL)",
    )
    v.add_argument("--run", type=int, help="the run's index (default 0)")
    v.add_argument(
        "--corrections",
        metavar="T,T",
        help="iterations to show, e.g. 1,6,12 (default: first, middle, last)",
    )
    v.add_argument("--model", help="the MJCF to render (default models/scene.xml)")
    v.add_argument(
        "--video-file", help="an .mp4 or .gif (default OUT/video/<figure>-<learner>-run<N>.mp4)"
    )
    i = p.add_argument_group(
        "interact (FILE: a study file, default fig. 4's) and replay (FILE: the database)"
    )
    i.add_argument("--db", help="the study's SQLite log (default results/interact/study.sqlite)")
    i.add_argument("--participant", help="the participant's pseudonym (never a name)")
    i.add_argument("--host", help="address to serve the page on (default 127.0.0.1)")
    i.add_argument("--port", type=_port, help="port of the page, 1-65535 (default 8080)")
    i.add_argument("--resume", type=int, metavar="SESSION", help="continue a logged session")
    i.add_argument(
        "--mode",
        choices=["drag", "physical"],
        help="drag (default): drag the cup at a waypoint of the plan; physical: push the cup "
        "while the arm moves under impedance, the robot learns and replans when you let go",
    )
    i.add_argument(
        "--speed",
        type=_speed,
        help="physical: simulated seconds per real second, in (0, 1] (default 1)",
    )
    i.add_argument(
        "--drag-model",
        help="how a dragged waypoint becomes the corrected path: waypoint (default: only "
        "that waypoint, as the learners' default model of a correction), deform (the "
        "minimum-jerk deformation of the path), or a plug-in's",
    )
    i.add_argument(
        "--headless",
        action="store_true",
        help="no page: the study's simulated user (--user) corrects, --iterations times",
    )
    i.add_argument(
        "--labelled",
        type=_positive_int,
        metavar="N",
        help="interact: ask the person for N labelled corrections, half toward a stated "
        "preference (--theta-star, default the study's θ*), half nudges for no reason, in a "
        "seeded order; the page says which, the log keeps the label",
    )
    i.add_argument("--session", type=int, help="for replay: which session (default the last)")
    u = p.add_argument_group("a user study from a protocol")
    u.add_argument(
        "--enroll",
        metavar="CODE,CODE",
        help="enroll these participant codes (pseudonyms) and print each one's link",
    )
    u.add_argument("--participants", type=_positive_int, help="simulated participants (default 12)")
    u.add_argument(
        "--pool",
        type=_positive_int,
        help="simulated participants to cut into studies (default 2400: 200 studies of 12)",
    )
    u.add_argument(
        "--sizes",
        type=_counts,
        metavar="N,N",
        help="study sizes to measure the power at (default 4,8,12,16,24,32,48)",
    )
    u.add_argument(
        "--outcome",
        help="the outcome to power for: final_error, mean_regret, seconds (default: the "
        "protocol's primary)",
    )
    x = p.add_argument_group("where the runs execute")
    x.add_argument(
        "--workers",
        type=_positive_int,
        help="local worker processes (default: the cores this process may use)",
    )
    x.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="run on an existing Dask cluster instead of local processes",
    )
    return p


def parser() -> argparse.ArgumentParser:
    """The command line: one subcommand per figure and tool, each with its own options
    (from :func:`catalogue`), help and errors."""
    flat = catalogue()
    figures = _figures()
    commands = {**{n: f.help for n, f in figures.items()}, **{n: t[1] for n, t in TOOLS.items()}}
    p = _Parser(
        prog="python -m corrections_sim.run",
        allow_abbrev=False,
        description="Reproduce a figure of Losey & O'Malley (CoRL 2018) headless, or run a "
        "user study. Figures 4-6 and study files are resumable: finished runs are kept in "
        "OUT/.runs/<figure>/ (keyed by a hash of the settings and the code) and an "
        "interrupted command, run again, only computes what is missing. Ctrl-C or SIGTERM "
        "stops the command within seconds (exit status 130). A figure folder made with other "
        "settings or another preset is replaced only with --force. "
        "COMMAND --help lists the command's own options.",
    )
    sub = p.add_subparsers(
        dest="figure", metavar="COMMAND", title="commands", parser_class=_Parser, required=True
    )
    every = [a for a in flat._actions if a.dest != "help"]
    for name, what in commands.items():
        allowed = set(applies(name))
        sp = sub.add_parser(
            name,
            help=what,
            description=f"{name}: {what}.",
            prog=f"python -m corrections_sim.run {name}",
            allow_abbrev=False,
        )
        groups: dict[str, argparse._ArgumentGroup] = {}
        for group in flat._action_groups:
            for action in group._group_actions:
                if action.dest not in allowed:
                    continue
                mine = copy.copy(action)
                mine.help = _COMMAND_HELP.get((name, action.dest), action.help)
                if action.dest == "study_file":
                    mine.metavar = _FILE.get(name, "FILE")
                    sp._add_action(mine)
                    continue
                title = group.title if group.title == "where the runs execute" else "options"
                if title not in groups:
                    groups[title] = (
                        sp._optionals if title == "options" else sp.add_argument_group(title)
                    )
                groups[title]._add_action(mine)
        # Options of other commands read as unset, as the code that reads them expects.
        sp.set_defaults(**{a.dest: a.default for a in every if a.dest not in allowed})
    return p


#: What FILE is, by command.
_FILE = {
    "analyze": "LOG",
    "replay": "LOG",
    "serve-study": "PROTOCOL",
    "pilot": "PROTOCOL",
    "power": "PROTOCOL",
}


def _parse(given: Sequence[str]) -> argparse.Namespace:
    """``given`` parsed by its command's parser; an option of another command is refused in
    one line that says which options the command takes."""
    p = parser()
    args, extra = p.parse_known_args(given)
    if extra:
        token = extra[0]
        allowed = applies(args.figure)
        takes = ", ".join(_label(n) for n in allowed)
        if token.startswith("-"):
            option = token.split("=")[0]
            known = {o for a in catalogue()._actions for o in a.option_strings}
            if option in known:
                raise UsageError(f"{option}: does not apply to {args.figure} (it takes {takes})")
            raise UsageError(f"{option}: no such option of {args.figure} (it takes {takes})")
        if "study_file" not in allowed:
            raise UsageError(f"FILE: does not apply to {args.figure} (it takes {takes})")
        raise UsageError(f"{token}: an argument {args.figure} does not take (it takes {takes})")
    return args


def _nothing_kept(args: argparse.Namespace | None) -> str:
    """What an interrupted command leaves, said for that command."""
    command = getattr(args, "figure", None)
    if command == "interact":
        session = getattr(args, "interact_session", None)
        if session is None:
            return "no session was started"
        db = _db(args)
        return (
            f"every confirmed correction is in the session's log; continue it with "
            f"--resume {session} --db {db}"
        )
    if command in ("scene", "video", "replay"):
        return f"{command} wrote nothing; run it again"
    return "no finished runs to keep (figs. 4-6 resume, figs. 1-3 start over)"


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; 0 on success, 1 on a failure, 2 on bad input, 130 on SIGINT/SIGTERM."""
    with interrupts():  # from the start: the heavy imports happen inside
        try:
            given = list(sys.argv[1:] if argv is None else argv)
            command = _asks_command_help(given)
            if command is not None:
                print(command_help(command), end="")
                return 0
            args = _parse(given)
            args.argv = given
            figures = _figures()
            if args.figure in figures:
                written = run_figure(args, figures[args.figure])
            else:
                written = TOOLS[args.figure][0](args)
        except UsageError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except (KeyboardInterrupt, Exception) as exc:
            cause = interruption(exc)
            if cause is None and isinstance(exc, RuntimeError):
                # A missing GL backend, a planner failure: one line, no trace.
                print(f"error: {str(exc).splitlines()[0]}", file=sys.stderr)
                return 1
            if cause is None:
                raise
            kept = getattr(cause, "kept", None)
            message = (
                f"{kept}; run the command again to resume"
                if kept
                else _nothing_kept(locals().get("args"))
            )
            by = f" ({cause})" if isinstance(cause, Interrupted) else ""
            print(f"interrupted: {message}{by}", file=sys.stderr)
            return 130
    for path in written:
        print(f"wrote {path}")
    return 0
