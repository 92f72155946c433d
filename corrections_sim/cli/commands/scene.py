"""``scene``: the scene rendered with the optimal cup paths for two preferences."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from corrections_sim.cli.command import Command, wrote_nothing
from corrections_sim.cli.common import out_dir, writable_dir
from corrections_sim.cli.errors import UsageError


def run_scene(args: argparse.Namespace) -> list[Path]:
    """The scene with the optimal cup paths for θ = (0, 0) and θ = (+1, −1)."""
    from corrections_sim.planning.planner import Planner, PlannerConfig
    from corrections_sim.scene.environments import paper_environments

    envs = {e.name: e for e in paper_environments()}
    args.env = args.env or "s0-t0-l1"
    if args.env not in envs:
        raise UsageError(f"--env {args.env!r}: unknown; choose one of {', '.join(envs)}")
    env = envs[args.env]
    out = writable_dir(out_dir(args))
    planner = Planner(PlannerConfig(features=("laptop", "table")))
    cases = (
        ((0.0, 0.0), (0.15, 0.45, 0.95, 1.0), "θ = (0, 0): smoothness only"),
        ((1.0, -1.0), (0.85, 0.25, 0.55, 1.0), "θ = (+1, −1): seek the laptop, avoid the table"),
    )
    plans = [(planner.solve(np.array(theta), env), rgba, label) for theta, rgba, label in cases]
    from corrections_sim.figures.style import save_scene_figure
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


COMMAND = Command(
    name="scene",
    run=run_scene,
    help="render the scene with optimal paths for two preferences",
    options=("out", "env"),
    nothing_kept=wrote_nothing,
)
