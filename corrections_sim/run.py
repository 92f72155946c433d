"""Command line: reproduce a figure of the paper headless.

    python -m corrections_sim.run fig4             # results/fig4/ (CSV, summary, PNG, PDF)
    python -m corrections_sim.run fig5 --quick     # the quick preset (what CI runs)
    python -m corrections_sim.run scene            # results/scene.png

Bad input ends with a one-line message on stderr and exit status 2; nothing already in the
output folder is overwritten by a run that failed.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np


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


def _cup_path(trajectory: np.ndarray, substeps: int = 6) -> np.ndarray:
    """Cup centre (N, 3) along the joint-space interpolation of a trajectory."""
    from corrections_sim.robot import cup_pose
    from corrections_sim.scene import interpolate

    return np.array([cup_pose(q)[1] for q in interpolate(trajectory, substeps)])


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
        env, [(_cup_path(p.trajectory), rgba) for p, rgba, _ in plans], q=env.q_start
    )
    legend = [
        (rgba, f"{label}   Φ = (laptop {p.features[0]:.2f}, table {p.features[1]:.2f})")
        for p, rgba, label in plans
    ]
    title = f"Panda carrying coffee, environment {env.name}: optimal cup paths ξ*(θ, E)"
    return [save_scene_figure(out / "scene.png", image, title, legend)]


def _progress_printer(label: str) -> Callable[[int, int], None]:
    start = time.perf_counter()
    tty = sys.stderr.isatty()

    def show(done: int, total: int) -> None:
        elapsed = time.perf_counter() - start
        eta = elapsed / done * (total - done)
        line = f"{label}: {done}/{total} runs, {elapsed:.0f} s elapsed, ETA {eta:.0f} s"
        if tty:
            print("\r" + line, end="\n" if done == total else "", file=sys.stderr, flush=True)
        else:
            print(line, file=sys.stderr, flush=True)

    return show


def _write_csv(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in row.items()})


def _versions() -> dict[str, str]:
    from importlib.metadata import version

    names = ("corrections_sim", "mujoco", "casadi", "pin", "numpy", "dm-control")
    return {n: version(n) for n in names}


def run_learning_figure(args: argparse.Namespace) -> list[Path]:
    """Figs. 4/5: PP, KF, AL learning curves, CSV, summary and plots."""
    from concurrent.futures import ProcessPoolExecutor

    from corrections_sim.figures import learning
    from corrections_sim.plotting import mean_sem, plot_learning_curves

    for name in ("runs", "iterations", "workers"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise UsageError(f"--{name} {value}: must be a positive integer")
    try:
        settings = learning.load_settings(
            args.figure,
            quick=args.quick,
            overrides={"runs": args.runs, "iterations": args.iterations, "seed": args.seed},
        )
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = _writable_dir(Path(args.out))
    final = out / args.figure
    staging = Path(tempfile.mkdtemp(prefix=f".{args.figure}-", dir=out))
    try:
        t0 = time.perf_counter()
        with ProcessPoolExecutor(max_workers=args.workers or os.cpu_count()) as pool:
            result = learning.run(settings, pool, _progress_printer(args.figure))
        wall = time.perf_counter() - t0
        s = settings.study
        _write_csv(staging / "curves.csv", result.records)
        _write_csv(staging / "mean_estimate.csv", result.mean_estimate)
        curves = {}
        for learner in s.learners:
            rows = [r for r in result.records if r["learner"] == learner]
            runs = sorted({r["run"] for r in rows})
            curves[learner] = {
                key: np.array([[r[key] for r in rows if r["run"] == run] for run in runs])
                for key in ("estimate_error", "regret", "regret_paper")
            }
        final_stats = {}
        for learner, data in curves.items():
            stats = {}
            for key, values in data.items():
                mean, sem = mean_sem(values[:, -1:])
                stats[key] = {
                    "mean": float(mean[0]),
                    "sem": float(sem[0]),
                    "auc_mean": float(np.mean(values.sum(axis=1))),
                }
            final_stats[learner] = stats
        summary = {
            "figure": args.figure,
            "preset": "quick" if args.quick else "paper",
            "settings": settings.as_dict(),
            "seed": s.seed,
            "workers": args.workers or os.cpu_count(),
            "versions": _versions(),
            "wall_time_s": round(wall, 1),
            "planner_solves": result.solves,
            "pp_learning_rate": result.alphas,
            "final": final_stats,
            "regret_failures": int(sum(r["regret_failures"] for r in result.records)),
            "skipped_updates": int(sum(bool(r["update_skipped"]) for r in result.records)),
        }
        (staging / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")

        def fmt(values) -> str:
            return "(" + ", ".join(f"{v:g}" for v in values) + ")"

        title = (
            f"{args.figure}: θ* = {fmt(s.theta_star)}, θ̂⁰ = {fmt(s.theta0)}, "
            f"P⁰ = diag{fmt(np.diag(np.array(s.cov0)))}; mean ± SEM; biased user"
        )
        plot_learning_curves(
            curves, title, [staging / f"{args.figure}.png", staging / f"{args.figure}.pdf"]
        )
        final.mkdir(parents=True, exist_ok=True)
        written = []
        for item in sorted(staging.iterdir()):
            os.replace(item, final / item.name)
            written.append(final / item.name)
        return written
    finally:
        shutil.rmtree(staging, ignore_errors=True)


COMMANDS: dict[str, tuple[Callable[[argparse.Namespace], list[Path]], str]] = {
    "fig4": (run_learning_figure, "PP vs KF vs AL, equal initial uncertainty"),
    "fig5": (run_learning_figure, "PP vs KF vs AL, laptop known, table uncertain"),
    "scene": (run_scene, "render the scene with optimal paths for two preferences"),
}


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m corrections_sim.run",
        description="Reproduce a figure of Losey & O'Malley (CoRL 2018) headless.",
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
    p.add_argument("--runs", type=int, help="runs of PP and KF (default: the preset's)")
    p.add_argument("--iterations", type=int, help="corrections per run (default: the preset's)")
    p.add_argument("--seed", type=int, help="root seed of every random draw (default: preset's)")
    p.add_argument("--workers", type=int, help="worker processes (default: the number of cores)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        written = COMMANDS[args.figure][0](args)
    except UsageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # a missing GL backend, a planner failure: one line, no trace
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for path in written:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
