"""What exact-Bayes confidence costs (``bench confidence``): the iterated and particle learners
against KF-C, per correction.

For figs. 4 and 5 (paper-scale settings, the same seeds and shared plans as the figures), each
learner asked for runs ``runs`` runs of 12 corrections one at a time in this process: CPU
seconds per correction and planner solves per correction (every ξ*(θ, E) the run's book solved,
memoized ones not counted). Every run also evaluates the regret (the 48 environments at each
θ̂) and plans the robot's trajectory; PP, which plans nothing else, gives that baseline, so
"update solves" = a learner's solves − PP's, and the last column is that over KF-C's (the
issue's ≤ 3× for the iterated update). An active learner's extra CPU over its passive
twin is its choice of environment.
"""

from __future__ import annotations

import time

import numpy as np

from corrections_sim.figures.learning_study import load_settings
from corrections_sim.study import runner


def run_bench(
    learners: tuple[str, ...],
    runs: int,
    figures=("fig4", "fig5"),
    iterations: int | None = None,
    smaller: dict | None = None,
) -> list[str]:
    """The table (module docstring); ``iterations``: corrections a run (None: the figure's),
    ``smaller``: overrides that shrink the figure's study (:mod:`benchmarks.sizes`)."""
    names = tuple(dict.fromkeys(("PP", "KF-C", *learners)))
    lines = [
        f"{runs} runs x {iterations or 12} corrections per learner, one process; CPU s and "
        "planner solves "
        "per correction",
        f"{'figure':6} {'learner':7} {'CPU s':>7} {'solves':>8} {'update solves':>14} "
        f"{'/ KF-C':>7}",
    ]
    for figure in figures:
        overrides = {"runs": runs, "learners": list(names), "learners.PP.fixed_alpha": 0.2}
        if iterations is not None:
            overrides["iterations"] = iterations
        overrides.update(smaller or {})
        settings = load_settings(figure, quick=False, overrides=overrides)
        shared = runner.prepare(settings)
        study = settings.study
        cost: dict[str, tuple[float, float]] = {}
        for name in names:
            cpu, solves = 0.0, 0
            for run in range(runs):
                start = time.process_time()
                alphas = None
                if study.learners[name].needs_rates():
                    alphas = np.full(study.iterations, 0.2)
                result = runner.run_one(settings, shared, name, run, alphas)
                cpu += time.process_time() - start
                solves += result.solves
            n = runs * study.iterations
            cost[name] = (cpu / n, solves / n)
        base = cost["PP"][1]
        kfc = cost["KF-C"][1] - base
        for name, (cpu, solves) in cost.items():
            own = solves - base
            ratio = f"{own / kfc:7.2f}" if name != "PP" and kfc > 0 else f"{'-':>7}"
            lines.append(f"{figure:6} {name:7} {cpu:7.3f} {solves:8.1f} {own:14.1f} {ratio}")
    return lines


def local_optima(problems: int = 150, restarts: int = 10, seed: int = 0) -> list[str]:
    """How often PF-C's plans are local optima: every plan a fig. 4 PF-C run (run 0, the
    figure's settings) solved is recorded; ``problems`` of them, drawn at random, are solved
    again from ``restarts`` random starts (the straight line and smooth random bends, as
    ``bench planner``), and the particle's reward compared with the best. A plan more than 1%
    below the best puts the particle's likelihood on a trajectory the person would not
    think optimal."""
    from benchmarks.restarts import random_restarts, relative_gap
    from corrections_sim.planning.planner import PlanningError, shared_planner
    from corrections_sim.plans.book import PlanBook

    solved: list[tuple[np.ndarray, object, float]] = []

    class Recording(PlanBook):
        def plan(self, theta, env):
            fresh = self._key(np.asarray(theta, float), env) not in self._plans
            plan = super().plan(theta, env)
            if fresh:
                solved.append((np.array(theta, float), env, plan.reward))
            return plan

    settings = load_settings("fig4", quick=False, overrides={"runs": 1, "learners": ["PF-C"]})
    shared = runner.prepare(settings)
    runner.run_one(settings, shared, "PF-C", 0, plan_book=Recording)
    rng = np.random.default_rng(seed)
    picks = rng.choice(len(solved), size=min(problems, len(solved)), replace=False)
    planner = shared_planner(settings.planner_config())
    gaps, absolute = [], []
    for i in picks:
        theta, env, reward = solved[i]
        starts = random_restarts(env, planner.config.n_waypoints, restarts, rng)
        best = reward
        for start in starts:
            try:
                best = max(best, planner.solve(theta, env, inits=[start]).reward)
            except PlanningError:
                continue
        gaps.append(relative_gap(best, reward))
        absolute.append(best - reward)
    gaps, absolute = np.array(gaps), np.array(absolute)
    worse = gaps > 0.01
    return [
        f"PF-C's plans (fig. 4, run 0: {len(solved)} solved), {len(gaps)} drawn, each against "
        f"the best of {restarts} random starts:",
        f"  within 1% of the best: {np.mean(gaps <= 0.01):.1%}; within 0.1%: "
        f"{np.mean(gaps <= 0.001):.1%}; median gap {np.median(gaps):.2e}",
        f"  the {int(worse.sum())} more than 1% below: reward short by "
        + ", ".join(f"{a:.3g} ({g:.0%})" for a, g in zip(absolute[worse], gaps[worse], strict=True))
        + " (a relative gap is large where the best reward is near 0)",
    ]
