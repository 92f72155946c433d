"""Command line: reproduce a figure of the paper headless.

    python -m corrections_sim.run fig4             # results/fig4/ (CSV, summary, PNG, PDF)
    python -m corrections_sim.run fig5 --quick     # the quick preset (what CI runs)
    python -m corrections_sim.run scene            # results/scene.png

Bad input ends with a one-line message on stderr and exit status 2; nothing already in the
output folder is overwritten by a run that failed.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor
from pathlib import Path

import numpy as np

from corrections_sim.corrections import CORRECTION_KINDS
from corrections_sim.study import LEARNERS, USERS

#: Seconds to wait for a Dask scheduler before giving up (--scheduler).
SCHEDULER_TIMEOUT_S = 5
#: New process pools to try when a worker process dies mid-run (finished runs are kept).
WORKER_DEATH_RETRIES = 2


class UsageError(Exception):
    """Bad input from the command line: printed as one line, exit status 2."""


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
    if args.env not in envs:
        raise UsageError(f"--env {args.env!r}: unknown; choose one of {', '.join(envs)}")
    env = envs[args.env]
    out = _writable_dir(Path(args.out))
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
            Path(args.out),
            args.source,
            learner=args.learner,
            run=args.run,
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


def _versions() -> dict[str, str]:
    from importlib.metadata import version

    names = ("corrections_sim", "mujoco", "casadi", "pin", "numpy")
    return {n: version(n) for n in names}


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
    for name in _PASSED_AS_IS:
        if getattr(args, name) is not None:
            overrides[name] = getattr(args, name)
    if args.warm_start:
        overrides["warm_start"] = True
    return overrides


@contextlib.contextmanager
def _executor(args: argparse.Namespace) -> Iterator[tuple[Executor, str]]:
    """The executor the runs go to: a Dask cluster's (--scheduler) or a local process pool."""
    if args.scheduler is None:
        from concurrent.futures import ProcessPoolExecutor

        workers = args.workers or os.cpu_count() or 1
        with ProcessPoolExecutor(max_workers=workers) as pool:
            yield pool, f"process pool, {workers} worker{'s' if workers != 1 else ''}"
        return
    if args.workers is not None:
        raise UsageError("--workers: not with --scheduler (the cluster has its own workers)")
    from distributed import Client

    try:
        client = Client(args.scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s", set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise UsageError(f"--scheduler {args.scheduler}: cannot connect ({message})") from None
    try:
        n = len(client.scheduler_info(n_workers=-1).get("workers", {}))
        yield client.get_executor(pure=False), f"dask {args.scheduler}, {n} workers"
    finally:
        client.close()


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
    out = _writable_dir(Path(args.out))
    final = out / args.figure
    store = RunStore(
        out / ".runs" / args.figure,
        {"figure": args.figure, "settings": _run_key(settings), "code": _code_fingerprint()},
    )
    try:
        with store.lock():
            return _learning_figure(args, settings, store, final)
    except StoreLocked as exc:
        raise UsageError(f"--out {out}: {exc}") from None
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
        for item in sorted(staging.iterdir()):
            os.replace(item, final / item.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _learning_figure(args, settings, store, final: Path) -> list[Path]:
    from concurrent.futures.process import BrokenProcessPool

    from corrections_sim.figures import learning
    from corrections_sim.plotting import plot_learning_curves

    s = settings.study
    t0 = time.perf_counter()
    progress = Progress(args.figure)
    for attempt in range(1, WORKER_DEATH_RETRIES + 2):
        try:
            with _executor(args) as (executor, where):
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
    out = _writable_dir(Path(args.out))
    final = out / robustness.FIGURE
    code = _code_fingerprint()
    stores = [
        RunStore(
            out / ".runs" / robustness.FIGURE / f"column-{i}",
            {"figure": robustness.FIGURE, "settings": _run_key(c.settings), "code": code},
        )
        for i, c in enumerate(settings.columns)
    ]
    t0 = time.perf_counter()
    try:
        with contextlib.ExitStack() as held:
            for store in stores:
                held.enter_context(store.lock())
            with _executor(args) as (executor, where):
                results = robustness.run(
                    settings, executor, Progress(robustness.FIGURE), caches=stores
                )
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
        }
        (staging / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        first = settings.columns[0].settings
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


#: Options of the learning figures that figs. 1–3 do not take.
_LEARNING_ONLY = (
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


def run_uncertainty_figure(args: argparse.Namespace) -> list[Path]:
    """Figs. 1–3: where to learn (heat maps of eq. A1) and how to deploy (A2–A4)."""
    from corrections_sim.figures import deployment, selection

    given = [n for n in _LEARNING_ONLY if getattr(args, n) is not None]
    if given and args.figure != "all":
        option = "--" + given[0].replace("_", "-")
        raise UsageError(f"{option}: only for fig4, fig5 and fig6, not {args.figure}")
    for name in ("workers",):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise UsageError(f"--{name} {value}: must be a positive integer")
    figure = args.figure if args.figure != "all" else args.current
    module = deployment if figure in deployment.FIGURES else selection
    try:
        settings = module.load_settings(figure, quick=args.quick)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    final = _writable_dir(Path(args.out)) / figure
    t0 = time.perf_counter()
    with _executor(args) as (executor, where):
        result = module.run(settings, executor, Progress(figure, unit="task"))
    wall = time.perf_counter() - t0
    with _staging(final) as staging:
        module.write(settings, result, staging)
        summary = {
            "figure": figure,
            "preset": "quick" if args.quick else "paper",
            "executor": where,
            "versions": _versions(),
            "wall_time_s": round(wall, 1),
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


class _Parser(argparse.ArgumentParser):
    """argparse, but a bad option is one line on stderr (no usage block), exit status 2."""

    def error(self, message: str):
        self.exit(2, f"error: {message} (see --help)\n")


def parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="python -m corrections_sim.run",
        description="Reproduce a figure of Losey & O'Malley (CoRL 2018) headless. "
        "Figures 4 and 5 are resumable: finished runs are kept in OUT/.runs/<figure>/ "
        "(keyed by a hash of the settings and the code) and an interrupted command, run "
        "again, only computes what is missing.",
    )
    p.add_argument(
        "figure",
        choices=sorted(COMMANDS),
        help="what to produce: " + "; ".join(f"{k}: {v[1]}" for k, v in COMMANDS.items()),
    )
    p.add_argument("--out", default="results", help="output folder (default: results)")
    p.add_argument(
        "--env", default="s0-t0-l1", help="environment name for 'scene' (default: s0-t0-l1)"
    )
    p.add_argument("--quick", action="store_true", help="the figure's quick preset (CI size)")
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
        "--warm-start",
        action="store_true",
        default=None,
        help="start each solve from the run's nearest solved θ (faster; results move at the "
        "solver's tolerance, see README)",
    )
    v = p.add_argument_group("video (reads OUT/<figure>/curves.csv of a finished fig4/fig5)")
    v.add_argument(
        "--from", dest="source", metavar="FIG", default="fig4", help="fig4 or fig5 (default fig4)"
    )
    v.add_argument("--learner", default="KF", help="whose run to show (default KF)")
    v.add_argument("--run", type=int, default=0, help="the run's index (default 0)")
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


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        written = COMMANDS[args.figure][0](args)
    except UsageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # a missing GL backend, a planner failure: one line, no trace
        print(f"error: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(
            "interrupted: finished runs are kept; run the command again to resume", file=sys.stderr
        )
        return 130
    for path in written:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
