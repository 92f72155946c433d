"""Command line: reproduce a figure of the paper headless.

    python -m corrections_sim.run fig4             # results/fig4/ (CSV, summary, PNG, PDF)
    python -m corrections_sim.run fig5 --quick     # results/quick/fig5/ (what CI runs)
    python -m corrections_sim.run scene            # results/scene.png

Bad input ends with a one-line message on stderr and exit status 2; nothing already in the
output folder is overwritten by a run that failed, and a figure folder made with other
settings only with --force (:mod:`corrections_sim.output_folder`). SIGINT and SIGTERM end
the command within seconds at any moment with one line and exit status 130, keeping the
finished runs (:mod:`corrections_sim.executors`).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
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

from corrections_sim import output_folder, provenance
from corrections_sim.executors import (
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


class UsageError(Exception):
    """Bad input from the command line: printed as one line, exit status 2."""


def _out(args: argparse.Namespace) -> Path:
    """The output folder: --out, or the preset's default (see :mod:`output_folder`)."""
    if args.out is None:
        return output_folder.default_out(args.quick)
    if not args.out.strip():
        raise UsageError("--out '': give a folder name (default: results, or results/quick)")
    return Path(args.out)


def _check_replace(args: argparse.Namespace, final: Path, figure: str, settings: dict) -> str:
    """Refuse (exit 2) to replace a figure folder made by other settings without --force;
    otherwise the line to print, once the command is sure to start, saying what it replaces."""
    preset = "quick" if args.quick else "paper"
    try:
        return output_folder.check_replace(final, figure, preset, settings, args.force)
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
    from corrections_sim.environments import paper_environments
    from corrections_sim.planner import Planner, PlannerConfig

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
    from corrections_sim import render
    from corrections_sim.plotting import save_scene_figure

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
    from corrections_sim import video
    from corrections_sim.models import ModelFileError

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


def _write_csv(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in row.items()})


_versions = provenance.versions

#: Modules that cannot change a learning run's numbers (files, plots, CLI, other figures).
_EDGE_MODULES = (
    "run.py",
    "store.py",
    "plotting.py",
    "render.py",
    "bench.py",
    "bench_ik.py",
    "models.py",
    "video.py",
    "executors.py",
    "output_folder.py",
    "provenance.py",
    "report.py",
)


def _code_fingerprint() -> str:
    """Hash of the sources a learning run executes and of the solver versions: part of the run
    cache's key, so runs made by other code never mix with these."""
    import hashlib

    digest = hashlib.sha256()
    root = Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        name = path.relative_to(root).as_posix()
        if name in _EDGE_MODULES or (name.startswith("figures/") and name != "figures/learning.py"):
            continue
        if name.startswith("experiments/"):  # the presets, in a wheel; settings are in the key
            continue
        digest.update(name.encode())
        digest.update(path.read_bytes())
    for name, value in sorted(_versions().items()):
        digest.update(f"{name}={value}".encode())
    return digest.hexdigest()[:16]


def _floats(option: str, text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise UsageError(f"{option} {text!r}: expected comma-separated numbers") from None
    if not all(np.isfinite(values)):
        raise UsageError(f"{option} {text!r}: every value must be finite")
    return values


def _matrix(option: str, text: str) -> tuple[tuple[float, ...], ...]:
    """'a,b' is diag(a, b); 'a,b;c,d' is a full matrix, rows separated by ';'."""
    rows = [_floats(option, row) for row in text.split(";")]
    if len(rows) == 1:
        return tuple(
            tuple(v if i == j else 0.0 for j in range(len(rows[0]))) for i, v in enumerate(rows[0])
        )
    if any(len(r) != len(rows) for r in rows):
        raise UsageError(f"{option} {text!r}: expected a square matrix, rows separated by ';'")
    return tuple(rows)


#: Learning options whose parsed value is the setting's value, under the same name.
_PASSED_AS_IS = (
    "user",
    "user_step",
    "user_waypoints",
    "correction_model",
    "correction_step",
    "correction_waypoints",
    "fixed_alpha",
    "solver",
)


def _learning_overrides(args: argparse.Namespace) -> dict:
    for name in ("runs", "iterations", "workers"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise UsageError(f"--{name} {value}: must be a positive integer")
    overrides = {"runs": args.runs, "iterations": args.iterations, "seed": args.seed}
    if args.theta_star is not None:
        overrides["theta_star"] = _floats("--theta-star", args.theta_star)
    if args.theta0 is not None:
        overrides["theta0"] = _floats("--theta0", args.theta0)
    if args.cov0 is not None:
        overrides["cov0"] = _matrix("--cov0", args.cov0)
    if args.learners is not None:
        overrides["learners"] = tuple(n.strip() for n in args.learners.split(","))
    alpha = args.fixed_alpha
    if alpha is not None and not (np.isfinite(alpha) and alpha > 0):
        raise UsageError(f"--fixed-alpha {alpha}: fixed_alpha must be a finite number > 0")
    for name in _PASSED_AS_IS:
        if getattr(args, name) is not None:
            overrides[name] = getattr(args, name)
    if args.warm_start:
        overrides["warm_start"] = True
    return overrides


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
    whose workers die with the command (see :mod:`corrections_sim.executors`)."""
    if args.scheduler is None:
        workers = args.workers or os.cpu_count() or 1
        with process_pool(workers) as pool:
            yield pool, f"process pool, {workers} worker{'s' if workers != 1 else ''}"
        return
    with contextlib.ExitStack() as stack:
        try:
            executor, n = stack.enter_context(dask_executor(args.scheduler, SCHEDULER_TIMEOUT_S))
        except (ConnectionError, ValueError) as exc:
            raise UsageError(f"--scheduler {args.scheduler}: cannot connect ({exc})") from None
        yield executor, f"dask {args.scheduler}, {n} workers"


def run_learning_figure(args: argparse.Namespace) -> list[Path]:
    """Figs. 4/5: learning curves, CSV, summary and plots; resumable (see README)."""
    from corrections_sim.figures import learning
    from corrections_sim.store import CorruptRun, RunStore, StoreLocked

    try:
        settings = learning.load_settings(
            args.figure, quick=args.quick, overrides=_learning_overrides(args)
        )
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    _check_executor_options(args)
    out = _out(args)
    final = out / args.figure
    resolved = settings.as_dict()
    notice = _check_replace(args, final, args.figure, resolved)
    with contextlib.ExitStack() as stack:
        # The cluster is reached (or the pool started) before anything is written.
        first = stack.enter_context(_executor(args))
        _writable_dir(out)
        store = RunStore(
            out / ".runs" / args.figure,
            {"figure": args.figure, "settings": _run_key(settings), "code": _code_fingerprint()},
        )
        try:
            stack.enter_context(store.lock())
        except StoreLocked as exc:
            raise UsageError(f"--out {out}: {exc}") from None
        _say(notice)
        try:
            return _learning_figure(args, settings, store, final, first)
        except Interrupted as exc:
            kept = len(store.load_all())
            exc.kept = f"{kept} finished run{'s' if kept != 1 else ''} kept in {store.folder}"
            raise
        except CorruptRun as exc:
            raise RuntimeError(str(exc)) from None


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


def _learning_figure(args, settings, store, final: Path, first) -> list[Path]:
    from concurrent.futures.process import BrokenProcessPool

    from corrections_sim.figures import learning
    from corrections_sim.plotting import plot_learning_curves

    s = settings.study
    t0 = time.perf_counter()
    progress = Progress(args.figure)
    for attempt in range(1, WORKER_DEATH_RETRIES + 2):
        try:
            context = contextlib.nullcontext(first) if attempt == 1 else _executor(args)
            with context as (executor, where):
                result = learning.run(settings, executor, progress, cache=store)
            break
        except BrokenProcessPool:
            # A worker process died (killed, out of memory): its run was lost, the finished
            # ones are in the store; a fresh pool resumes from them.
            if attempt > WORKER_DEATH_RETRIES:
                raise RuntimeError(
                    f"{args.figure}: worker processes died {attempt} times; the finished runs "
                    f"are kept in {store.folder}, run the command again to resume"
                ) from None
            print(f"{args.figure}: a worker died; resuming on a new pool", file=sys.stderr)
    wall = time.perf_counter() - t0

    with _staging(final) as staging:
        _write_csv(staging / "curves.csv", result.records)
        _write_csv(staging / "mean_estimate.csv", result.mean_estimate)
        stats = learning.summarize(settings, result)
        summary = {
            "figure": args.figure,
            "preset": "quick" if args.quick else "paper",
            "settings": settings.as_dict(),
            "seed": s.seed,
            "executor": where,
            "versions": _versions(),
            "wall_time_s": round(wall, 1),
            "planner_solves": result.solves,
            "resumed_runs": result.resumed,
            "run_cache": str(store.folder),
            "learning_rates": result.alphas,
            **stats,
            "regret_failures": int(sum(r["regret_failures"] for r in result.records)),
            "skipped_updates": int(sum(bool(r["update_skipped"]) for r in result.records)),
        }
        summary.update(_learning_provenance(args, settings, result))
        (staging / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        title = f"{args.figure}: {learning.describe(settings)}"
        plot_learning_curves(
            learning.curves(settings, result.records),
            title,
            [staging / f"{args.figure}.png", staging / f"{args.figure}.pdf"],
            bands={n: c["band"] for n, c in stats["calibration"].items()},
        )
        names = sorted(p.name for p in staging.iterdir())
    return [final / name for name in names]


def _learning_provenance(args, settings, result) -> dict:
    """Summary fields beyond the statistics: where they came from, the planner, N per
    learner, and the curves the figure draws (mean and SEM over runs at every iteration)."""
    from corrections_sim.figures import learning
    from corrections_sim.plotting import mean_sem

    curves = learning.curves(settings, result.records)
    shown = {}
    for learner, data in curves.items():
        shown[learner] = {}
        for key in learning.METRICS:  # NEES/NIS are summarized under "calibration"
            mean, sem = mean_sem(data[key])
            shown[learner][key] = {"mean": mean, "sem": sem}
    return {
        **provenance.record(args.argv),
        "planner": provenance.plain(settings.planner_config()),
        "runs_per_learner": {learner: len(data["regret"]) for learner, data in curves.items()},
        "curves": provenance.plain(shown),
    }


def _run_key(settings) -> dict:
    """The settings a run's numbers depend on: all but which learners run (a run of one
    learner is the same whichever others run beside it), so adding a learner to a figure
    reuses the runs already made."""
    return {k: v for k, v in settings.as_dict().items() if k != "learners"}


def run_robustness_figure(args: argparse.Namespace) -> list[Path]:
    """Fig. 6: learners × simulated users, resumable per column like figs. 4/5."""
    from corrections_sim.figures import robustness
    from corrections_sim.plotting import plot_robustness_matrix
    from corrections_sim.store import CorruptRun, RunStore, StoreLocked

    try:
        settings = robustness.load_settings(quick=args.quick, overrides=_learning_overrides(args))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    _check_executor_options(args)
    out = _out(args)
    final = out / robustness.FIGURE
    notice = _check_replace(args, final, robustness.FIGURE, settings.as_dict())
    code = _code_fingerprint()
    t0 = time.perf_counter()
    try:
        with contextlib.ExitStack() as held:
            # The cluster is reached (or the pool started) before anything is written.
            executor, where = held.enter_context(_executor(args))
            _writable_dir(out)
            stores = [
                RunStore(
                    out / ".runs" / robustness.FIGURE / f"column-{i}",
                    {"figure": robustness.FIGURE, "settings": _run_key(c.settings), "code": code},
                )
                for i, c in enumerate(settings.columns)
            ]
            for store in stores:
                held.enter_context(store.lock())
            _say(notice)
            try:
                results = robustness.run(
                    settings, executor, Progress(robustness.FIGURE), caches=stores
                )
            except Interrupted as exc:
                kept = sum(len(store.load_all()) for store in stores)
                exc.kept = (
                    f"{kept} finished run{'s' if kept != 1 else ''} kept in "
                    f"{out / '.runs' / robustness.FIGURE}"
                )
                raise
    except StoreLocked as exc:
        raise UsageError(f"--out {out}: {exc}") from None
    except CorruptRun as exc:
        raise RuntimeError(str(exc)) from None
    wall = time.perf_counter() - t0
    rows = robustness.matrix(settings, results)
    with _staging(final) as staging:
        _write_csv(staging / "matrix.csv", rows)
        _write_csv(
            staging / "curves.csv",
            [
                {"user": c.label, **rec}
                for c, result in zip(settings.columns, results, strict=True)
                for rec in result.records
            ],
        )
        first = settings.columns[0].settings
        summary = {
            "figure": robustness.FIGURE,
            "preset": "quick" if args.quick else "paper",
            "settings": settings.as_dict(),
            "executor": where,
            "versions": _versions(),
            "wall_time_s": round(wall, 1),
            "planner_solves": sum(r.solves for r in results),
            "resumed_runs": sum(r.resumed for r in results),
            "matrix": rows,
            **provenance.record(args.argv),
            "planner": provenance.plain(first.planner_config()),
            "runs_per_learner": {n: first.study.runs_of(n) for n in settings.learners},
        }
        (staging / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        title = (
            f"fig6: learners × simulated users; {first.study.runs} runs × "
            f"{first.study.iterations} corrections; " + learning_title_prior(first)
        )
        plot_robustness_matrix(rows, title, [staging / "fig6.png", staging / "fig6.pdf"])
        names = sorted(p.name for p in staging.iterdir())
    return [final / name for name in names]


def learning_title_prior(settings) -> str:
    """θ*, θ̂⁰ and P⁰ of a learning figure's settings, without the user."""
    from corrections_sim.figures import learning

    return learning.describe(settings).rsplit(";", 1)[0]


def run_uncertainty_figure(args: argparse.Namespace) -> list[Path]:
    """Figs. 1–3: where to learn (heat maps of eq. A1) and how to deploy (A2–A4)."""
    from corrections_sim.figures import deployment, selection
    from corrections_sim.figures.presets import read_preset

    _check_executor_options(args)
    figure = args.figure if args.figure != "all" else args.current
    module = deployment if figure in deployment.FIGURES else selection
    try:
        settings = module.load_settings(figure, quick=args.quick)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = _out(args)
    final = out / figure
    preset = provenance.plain(read_preset(figure, args.quick))
    notice = _check_replace(args, final, figure, preset)
    t0 = time.perf_counter()
    with _executor(args) as (executor, where):
        final = _writable_dir(out) / figure
        _say(notice)
        result = module.run(settings, executor, Progress(figure, unit="task"))
    wall = time.perf_counter() - t0
    with _staging(final) as staging:
        module.write(settings, result, staging)
        # What the figure shows: the best cell of each heat map (figs. 1-2), the deployed
        # trajectories' features and rewards per panel and rule (fig. 3).
        shown = (
            {"maps": result.maps} if module is selection else {"trajectories": result.trajectories}
        )
        summary = {
            "figure": figure,
            "preset": "quick" if args.quick else "paper",
            "settings": preset,
            "executor": where,
            "versions": _versions(),
            "wall_time_s": round(wall, 1),
            **provenance.record(args.argv),
            "planner": provenance.plain(settings.planner_config()),
            "results": provenance.plain(shown),
        }
        (staging / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        names = sorted(p.name for p in staging.iterdir())
    return [final / name for name in names]


def run_all(args: argparse.Namespace) -> list[Path]:
    """Figs. 1–6 one after the other (the scene render is ``run scene``)."""
    written = []
    for figure in ("fig1", "fig2", "fig3"):
        args.current = figure
        written += run_uncertainty_figure(args)
    for figure in ("fig4", "fig5"):
        written += run_learning_figure(argparse.Namespace(**{**vars(args), "figure": figure}))
    written += run_robustness_figure(argparse.Namespace(**{**vars(args), "figure": "fig6"}))
    return written


COMMANDS: dict[str, tuple[Callable[[argparse.Namespace], list[Path]], str]] = {
    "fig1": (run_uncertainty_figure, "where to learn, one feature: heat maps of eq. (A1)"),
    "fig2": (run_uncertainty_figure, "where to learn, two features: the best start moves"),
    "fig3": (run_uncertainty_figure, "risk-sensitive deployment, eqs. (A2)-(A4) and exact (A3)"),
    "fig4": (run_learning_figure, "PP vs KF vs AL, equal initial uncertainty"),
    "fig5": (run_learning_figure, "PP vs KF vs AL, laptop known, table uncertain"),
    "fig6": (run_robustness_figure, "beyond the paper: learners x simulated users, calibration"),
    "scene": (run_scene, "render the scene with optimal paths for two preferences"),
    "all": (run_all, "fig1 to fig6, one after the other"),
    "video": (run_video, "animate corrections of a recorded fig4/fig5 run (MP4 or GIF)"),
}


_FIGURE_OPTIONS = ("out", "quick", "force", "workers", "scheduler")
_LEARNING_OPTIONS = (
    *_FIGURE_OPTIONS,
    "runs",
    "iterations",
    "seed",
    "theta_star",
    "theta0",
    "cov0",
    "learners",
    *_PASSED_AS_IS,
    "warm_start",
)
#: The options each command takes; any other option given is refused, not ignored.
APPLIES: dict[str, tuple[str, ...]] = {
    "scene": ("out", "env"),
    "fig1": _FIGURE_OPTIONS,
    "fig2": _FIGURE_OPTIONS,
    "fig3": _FIGURE_OPTIONS,
    "fig4": _LEARNING_OPTIONS,
    "fig5": _LEARNING_OPTIONS,
    "fig6": _LEARNING_OPTIONS,
    "all": _LEARNING_OPTIONS,  # the learning options go to figs. 4-6
    "video": ("out", "source", "learner", "run", "corrections", "model", "video_file"),
}


def _check_applies(args: argparse.Namespace) -> None:
    """Refuse an option the command does not take (``scene --runs 5``, ``fig4 --env X``)."""
    allowed = APPLIES[args.figure]
    for name in (a.dest for a in parser()._actions):
        if name in ("help", "figure") or name in allowed:
            continue
        if getattr(args, name) not in (None, False):
            takes = ", ".join("--" + n.replace("_", "-") for n in allowed)
            raise UsageError(
                f"--{name.replace('_', '-')}: does not apply to {args.figure} (it takes {takes})"
            )


class _Parser(argparse.ArgumentParser):
    """argparse, but a bad option is one line on stderr (no usage block), exit status 2."""

    def error(self, message: str):
        self.exit(2, f"error: {message} (see --help)\n")


def parser() -> argparse.ArgumentParser:
    # Imported here, not at the top: they load the planner's stack (CasADi, MuJoCo, pinocchio),
    # and main() has its interrupt handlers in place by the time this runs.
    from corrections_sim.corrections import CORRECTION_KINDS
    from corrections_sim.study import LEARNERS, USERS

    p = _Parser(
        prog="python -m corrections_sim.run",
        description="Reproduce a figure of Losey & O'Malley (CoRL 2018) headless. "
        "Figures 4 and 5 are resumable: finished runs are kept in OUT/.runs/<figure>/ "
        "(keyed by a hash of the settings and the code) and an interrupted command, run "
        "again, only computes what is missing. Ctrl-C or SIGTERM stops the command within "
        "seconds (exit status 130). A figure folder made with other settings or another "
        "preset is replaced only with --force.",
    )
    p.add_argument(
        "figure",
        choices=sorted(COMMANDS),
        help="what to produce: " + "; ".join(f"{k}: {v[1]}" for k, v in COMMANDS.items()),
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
    g = p.add_argument_group("learning figures (fig4, fig5, fig6); defaults come from the preset")
    g.add_argument("--runs", type=int, help="runs of PP, KF and EKF (AL runs once)")
    g.add_argument("--iterations", type=int, help="corrections per run")
    g.add_argument("--seed", type=int, help="root seed of every random draw")
    g.add_argument("--theta-star", metavar="W,W", help="the user's true weights θ*, e.g. 1,-1")
    g.add_argument("--theta0", metavar="W,W", help="the robot's initial estimate θ̂⁰, e.g. 0,0")
    g.add_argument(
        "--cov0",
        metavar="P",
        help="initial covariance P⁰: 'a,b' for diag(a, b) or 'a,b;c,d' row by row "
        "(symmetric positive definite)",
    )
    g.add_argument(
        "--learners",
        metavar="L,L",
        help="which learners, from " + ", ".join(LEARNERS) + " (e.g. PP,KF,AL,KF-C,AL-C,PP-C)",
    )
    g.add_argument(
        "--user",
        choices=USERS,
        help="biased: moves its worst waypoint(s) (paper); deform: pushes its worst waypoint "
        "and the path deforms smoothly; noisy: Φ(ξ*) + Gaussian noise",
    )
    g.add_argument(
        "--user-step", type=float, help="how far the user moves its worst waypoint, (0, 1]"
    )
    g.add_argument(
        "--user-waypoints", type=int, help="how many worst waypoints the biased user moves"
    )
    g.add_argument(
        "--correction-model",
        choices=CORRECTION_KINDS,
        help="KF-C's model of a correction: waypoint (paper's §6), deform (minimum-jerk), "
        "optimal (shows ξ*: the paper's KF)",
    )
    g.add_argument("--correction-step", type=float, help="how far KF-C's model moves, (0, 1]")
    g.add_argument("--correction-waypoints", type=int, help="how many waypoints KF-C's model moves")
    g.add_argument(
        "--fixed-alpha",
        type=float,
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
        "solver's tolerance, see README)",
    )
    v = p.add_argument_group("video (reads OUT/<figure>/curves.csv of a finished fig4/fig5)")
    v.add_argument("--from", dest="source", metavar="FIG", help="fig4 or fig5 (default fig4)")
    v.add_argument("--learner", help="whose run to show (default KF)")
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
    x = p.add_argument_group("where the runs execute")
    x.add_argument(
        "--workers", type=int, help="local worker processes (default: the number of cores)"
    )
    x.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="run on an existing Dask cluster instead of local processes",
    )
    return p


#: Options whose value may start with a minus sign (a vector or matrix of weights).
_VECTOR_OPTIONS = ("--theta-star", "--theta0", "--cov0")
_NEGATIVE_VALUE = re.compile(r"-\.?\d")


def _attach_negative_values(argv: Sequence[str]) -> list[str]:
    """``--theta-star -1,1`` as ``--theta-star=-1,1``: argparse reads a value that starts with
    a minus sign and is not a plain number as an option of its own."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        token = argv[i]
        following = argv[i + 1] if i + 1 < len(argv) else ""
        if token in _VECTOR_OPTIONS and _NEGATIVE_VALUE.match(following):
            out.append(f"{token}={following}")
            i += 2
            continue
        out.append(token)
        i += 1
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; 0 on success, 1 on a failure, 2 on bad input, 130 on SIGINT/SIGTERM."""
    with interrupts():  # from the start: the heavy imports happen inside
        try:
            given = list(sys.argv[1:] if argv is None else argv)
            args = parser().parse_args(_attach_negative_values(given))
            args.argv = given
            _check_applies(args)
            written = COMMANDS[args.figure][0](args)
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
                else "no finished runs to keep (figs. 4-6 resume, figs. 1-3 start over)"
            )
            by = f" ({cause})" if isinstance(cause, Interrupted) else ""
            print(f"interrupted: {message}{by}", file=sys.stderr)
            return 130
    for path in written:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    status = main()
    if status == 130:
        # The workers are dead already; skip the interpreter's exit-time joins of pools and
        # threads, which an interrupt may have left in any state.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    sys.exit(status)
