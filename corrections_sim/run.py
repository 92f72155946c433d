"""Command line: reproduce a figure of the paper headless.

    python -m corrections_sim.run scene            # results/scene.png
    python -m corrections_sim.run scene --env s1-t0-l1 --out /tmp/out

Bad input ends with a one-line message on stderr and exit status 2; nothing already in the
output folder is overwritten by a run that failed.
"""

from __future__ import annotations

import argparse
import os
import sys
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


COMMANDS: dict[str, tuple[Callable[[argparse.Namespace], list[Path]], str]] = {
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
