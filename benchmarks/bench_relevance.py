"""The relevance study's learners, their cost per correction (``bench relevance``).

For each person of ``experiments/relevance.toml`` and each learner asked for, ``runs`` runs of
12 corrections as the study makes them (the same seeds, the same shared plans), one at a time
in this process: wall seconds per correction and planner solves per correction (every
ξ*(θ, E) the run's book solved: the UKF's sigma points, the explanations' searches and the
regret's evaluation in the 48 environments at each θ̂; memoized ones not counted), and what each
relevance learner solves beyond KF-C's (its judging).
"""

from __future__ import annotations

import time

from corrections_sim.figures import robustness
from corrections_sim.study import runner


def run_bench(learners: tuple[str, ...], runs: int, smaller: dict | None = None) -> list[str]:
    """The table for ``learners``, ``runs`` runs each; ``smaller``: overrides that shrink the
    study (:mod:`benchmarks.sizes`: its plan atlas, which the study plans from, and its
    environments; a fresh machine builds the atlas first)."""
    overrides = {"runs": runs, **(smaller or {})}
    settings = robustness.load_settings(quick=False, overrides=overrides, figure="relevance")
    lines = [
        f"relevance study, {runs} runs x {settings.columns[0].settings.study.iterations} "
        "corrections per person and learner, one process",
        f"{'person':24} {'learner':8} {'s/correction':>13} {'solves/correction':>18}",
    ]
    totals: dict[str, list[float]] = {name: [0.0, 0.0, 0.0] for name in learners}
    for column in settings.columns:
        shared = runner.prepare(column.settings)
        study = column.settings.study
        for name in learners:
            if name not in study.learners:
                raise ValueError(f"learner {name}: not in the relevance study")
            seconds, solves = 0.0, 0
            for run in range(runs):
                start = time.perf_counter()
                result = runner.run_one(column.settings, shared, name, run)
                seconds += time.perf_counter() - start
                solves += result.solves
            n = runs * study.iterations
            totals[name][0] += seconds
            totals[name][1] += solves
            totals[name][2] += n
            lines.append(f"{column.label:24} {name:8} {seconds / n:13.3f} {solves / n:18.1f}")
    lines.append("all people:")
    for name, (seconds, solves, n) in totals.items():
        lines.append(f"{'':24} {name:8} {seconds / n:13.3f} {solves / n:18.1f}")
    per = {name: solves / n for name, (_, solves, n) in totals.items()}
    if "KF-C" in per:
        # Every learner's runs also evaluate the regret (the 48 environments at each θ̂), and
        # KF-C's filter solves its sigma points: what a relevance learner adds is its judging.
        lines.append("solves per correction beyond KF-C's (the judging of relevance):")
        for name in per:
            if name != "KF-C":
                lines.append(f"{'':24} {name:8} {per[name] - per['KF-C']:18.1f}")
    return lines
