"""``python -m benchmarks.bench particles``: what PF-C costs with its likelihood read off the
plan atlas (``interpolation``, :mod:`corrections_sim.plans.interpolation`) against solved
plans, per correction, in fig. 4.

Two parts, each in this process:

* **accuracy**: in the first ``envs`` paper environments, ``count`` θ ~ N(θ̂⁰, P⁰) (fig. 4's
  prior), KF-C's hₜ(θ) from the interpolated waypoints against hₜ from the atlas's solved
  plans (the robot's trajectory: the atlas's plan at a random θ), in noise sds: median, 99th
  percentile, largest, the share within the bound; and what the cells cost (cells checked,
  plans they needed, θ solved one by one, CPU);
* **runs**: PF-C with ``count`` particles, ``moves`` Metropolis moves and the bound, ``runs``
  runs of fig. 4 one after another: CPU seconds a correction (the run's robot plans and
  regret included, which every learner pays), the cells checked and the particles solved one
  by one so far.

The plans the cells need and the cells checked are kept on disk (``Atlas.save``,
``interpolation.save_kept``), so a second invocation on the same machine measures the warm
cost; the first line says how many plans were already there, the column "read" how many
cells. It never asserts.
"""

from __future__ import annotations

import time

import numpy as np

from corrections_sim.figures.learning_study import load_settings
from corrections_sim.learning.observation import CorrectedPlanFeatures
from corrections_sim.people.corrections import WaypointCorrection
from corrections_sim.plans import interpolation
from corrections_sim.plans.interpolation import waypoint_table
from corrections_sim.study import runner


def run_bench(
    count: int = 2000,
    runs: int = 4,
    bound: float = 0.02,
    envs: int = 4,
    seed: int = 0,
    moves: int = 2,
    smaller: dict | None = None,
) -> list[str]:
    """The report (module docstring); ``smaller``: overrides that shrink fig. 4's study
    (:mod:`benchmarks.sizes`)."""
    overrides = {
        "runs": runs,
        "learners": ["PF-C"],
        "learners.PF-C.particles": count,
        "learners.PF-C.interpolation": bound,
        "learners.PF-C.moves": moves,
    }
    overrides.update(smaller or {})
    settings = load_settings("fig4", quick=False, overrides=overrides)
    shared = runner.prepare(settings)
    atlas = settings.atlas()
    study = settings.study
    names = tuple(settings.planner_config().features)
    sd = np.sqrt(np.diag(study.noise().observation))
    T = atlas.planner.config.n_waypoints
    observation = CorrectedPlanFeatures(WaypointCorrection())
    rng = np.random.default_rng(seed)
    shards = atlas.store.shards
    stored = sum(len(shards.load(atlas.between_key(e), T, study.k)[0]) for e in settings.envs())
    lines = [
        f"fig. 4's atlas {atlas.grid.counts} over {atlas.grid.lows}..{atlas.grid.highs}; "
        f"{stored} plans between nodes already on disk; bound {bound} noise sd, "
        f"{count} particles, {moves} moves",
        f"{'environment':12} {'median':>7} {'p99':>7} {'max':>7} {'within':>7} {'read':>6} "
        f"{'cells':>6} {'plans':>6} {'solved':>6} {'CPU s':>6}",
    ]
    for env in settings.envs()[:envs]:
        table = waypoint_table(atlas, env, names, sd, bound, 4)
        read = len(table._status)  # cells checked by earlier processes, read from disk
        thetas = rng.multivariate_normal(study.theta0, study.cov0, size=count)
        robot = atlas.solve(rng.multivariate_normal(study.theta0, study.cov0), env).trajectory
        start = time.process_time()
        values = table(thetas)
        cpu = time.process_time() - start
        plans = values[:, : T * 7].reshape(-1, T, 7)
        features = values[:, T * 7 :].reshape(-1, T, len(names))
        got = observation.at_waypoints(plans, features, robot, env, names)
        picks = rng.choice(count, size=min(count, 300), replace=False)
        exact = observation.at_plans(atlas.plans(thetas[picks], env), robot, env, names)
        error = np.max(np.abs(got[picks] - exact) / sd, axis=1)
        lines.append(
            f"{env.name:12} {np.median(error):7.4f} {np.quantile(error, 0.99):7.4f} "
            f"{error.max():7.3f} {np.mean(error <= bound):7.1%} {read:6d} {table.checked:6d} "
            f"{len(table._nodes):6d} {table.solved:6d} {cpu:6.1f}"
        )
    atlas.save()
    interpolation.save_kept()
    lines.append(f"PF-C, {runs} runs of fig. 4 ({study.iterations} corrections each):")
    for run in range(runs):
        start = time.process_time()
        runner.run_one(settings, shared, "PF-C", run, None)
        cpu = time.process_time() - start
        kept = list(interpolation._KEPT.values())
        lines.append(
            f"  run {run}: {cpu / study.iterations:.3f} s CPU a correction; so far "
            f"{sum(t.checked for t in kept)} cells checked, "
            f"{sum(t.solved for t in kept)} particles solved one by one"
        )
    return lines
