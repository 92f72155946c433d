"""Every registered figure as a command (``fig1`` … ``fig6``, ``study``, …), and ``all``: the
settings, the executor, the output folder, the runs (resumed from their caches, on a new pool
if a worker dies), the figure's files and ``summary.json``, written only if everything
succeeded."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import time
from collections.abc import Iterator
from concurrent.futures import Executor
from pathlib import Path

from corrections_sim import provenance
from corrections_sim.cli.command import Command
from corrections_sim.cli.common import Progress, check_replace, out_dir, say, staged, writable_dir
from corrections_sim.cli.errors import UsageError
from corrections_sim.cli.executors import (
    Interrupted,
    check_interrupted,
    check_scheduler_address,
    dask_executor,
    process_pool,
)

#: Seconds to wait for a Dask scheduler before giving up (--scheduler).
SCHEDULER_TIMEOUT_S = 5
#: New process pools to try when a worker process dies mid-run (finished runs are kept).
WORKER_DEATH_RETRIES = 2


def figures() -> dict:
    """The registered figures, by name (:mod:`corrections_sim.figures.registry`)."""
    from corrections_sim.figures.registry import figures

    return figures()


def figure_commands() -> dict[str, Command]:
    """A command per registered figure: the common options and the figure's own."""
    from corrections_sim.figures.registry import COMMON_OPTIONS

    def command(name: str, figure) -> Command:
        return Command(
            name=name,
            run=lambda args: run_figure(args, figure),
            help=figure.help,
            options=(*COMMON_OPTIONS, *figure.options),
            file=getattr(figure, "file", "FILE"),
            option_help=getattr(figure, "option_help", {}),
        )

    return {name: command(name, figure) for name, figure in figures().items()}


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
def open_executor(args: argparse.Namespace) -> Iterator[tuple[Executor, str]]:
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
    beside = getattr(figure, "default_out", None)  # a figure that goes inside another's folder
    out = beside(settings) if beside is not None and args.out is None else out_dir(args)
    name = figure.folder(settings)
    final = out / name
    recorded = figure.recorded(settings, quick=args.quick)
    preset = getattr(settings, "preset", None) or ("quick" if args.quick else "paper")
    upgrade = getattr(figure, "upgrade_recorded", None)
    notice = check_replace(args, final, name, recorded, upgrade, preset=preset)
    t0 = time.perf_counter()
    check_interrupted()  # one that a library's import swallowed: before any worker starts
    with contextlib.ExitStack() as stack:
        # The cluster is reached (or the pool started) before anything is written.
        first = stack.enter_context(open_executor(args))
        writable_dir(out)
        caches = _open_caches(out, name, figure.cache_keys(settings), stack)
        say(notice)
        try:
            for attempt in range(1, WORKER_DEATH_RETRIES + 2):
                try:
                    context = contextlib.nullcontext(first) if attempt == 1 else open_executor(args)
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
    with staged(final) as staging:
        fields = figure.write(settings, result, staging)
        summary = {
            "figure": name,
            "preset": preset,
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
    for line in getattr(figure, "lines", lambda *_: [])(settings, result):
        print(line)  # what the figure reports on the standard output (the reference's table)
    return [final / name for name in names]
