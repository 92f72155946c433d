"""Learnt features (``bench learnt``): what training one costs, what planning with one costs
against the hand-written feature it imitates, and what a newly learnt one costs the planner.

- Training: CPU seconds of :func:`~corrections_sim.learnt.training.learn` from 10 traces of
  the default teacher (per seed), and the learnt feature's Spearman ρ.
- Planning: the same problems (θ over laptop, table and the person's feature, a random paper
  environment) planned over (laptop, table, human) and over (laptop, table, the learnt
  feature): cold (the planner's multi-start) and warm (from the plan of a θ 0.05 away, as a
  run's book does) wall milliseconds, median and 90th percentile.
- A new feature: seconds to get the planner of a second learnt feature of the same shape
  (a view of the first: no compile), and whether any library was built for it.
- ``--build``: the first build of a shape's NLP (fatrop's library and the Newton re-solve's)
  in an empty cache, seconds.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from corrections_sim.learnt import training as L
from corrections_sim.people.teacher import Teacher
from corrections_sim.planning.planner import (
    Planner,
    PlannerConfig,
    PlanningError,
    cache_dir,
    shared_planner,
)
from corrections_sim.scene.environments import paper_environments


def _learn(seed: int, env) -> tuple[L.Learnt, float]:
    rng = np.random.default_rng(seed)
    traces = Teacher().traces("human", 10, env, rng)
    start = time.process_time()
    learnt = L.learn(traces, env, rng)
    return learnt, time.process_time() - start


def run_bench(problems: int, seed: int, build: bool) -> list[str]:
    envs = paper_environments()
    env = envs[0]
    lines = ["training from 10 traces of the default teacher (CPU s, Spearman rho vs human):"]
    learnt = []
    for s in range(5):
        feature, seconds = _learn(s, env)
        L.register(feature)
        rho = L.quality(feature.name, "human", env).spearman
        learnt.append(feature)
        lines.append(f"  seed {s}: {seconds:6.2f} s   rho {rho:.3f}")
    lines.append("  target: <= 5 s CPU")

    human = PlannerConfig(features=("laptop", "table", "human"), n_starts=4)
    mine = PlannerConfig(features=("laptop", "table", learnt[0].name), n_starts=4)
    before = set(os.listdir(cache_dir())) if cache_dir().is_dir() else set()
    planners = {"human": shared_planner(human), "learnt": shared_planner(mine)}
    rng = np.random.default_rng(seed)
    thetas = np.column_stack(
        [rng.uniform(-1.5, 1.5, (problems, 2)), rng.uniform(-5.0, 0.0, (problems, 1))]
    )
    where = rng.integers(0, len(envs), problems)
    for planner in planners.values():  # the first solves load or build the libraries
        planner.solve(thetas[0], envs[int(where[0])])
        planner.solve(
            thetas[0] + 0.05,
            envs[int(where[0])],
            inits=[planner.solve(thetas[0], envs[int(where[0])]).trajectory],
        )
    times: dict[str, dict[str, list[float]]] = {n: {"cold": [], "warm": []} for n in planners}
    failed = {n: 0 for n in planners}
    for theta, i in zip(thetas, where, strict=True):
        e = envs[int(i)]
        for name, planner in planners.items():
            try:
                start = time.perf_counter()
                plan = planner.solve(theta, e)
                times[name]["cold"].append(time.perf_counter() - start)
                start = time.perf_counter()
                planner.solve(theta + 0.05, e, inits=[plan.trajectory])
                times[name]["warm"].append(time.perf_counter() - start)
            except PlanningError:
                failed[name] += 1
    lines.append(f"planning, {problems} problems (theta_human in [-5, 0]), wall ms:")
    lines.append(
        f"  {'features':10} {'cold med':>9} {'cold p90':>9} {'warm med':>9} {'warm p90':>9} failed"
    )
    for name in planners:
        c, w = (np.array(times[name][m]) * 1e3 for m in ("cold", "warm"))
        lines.append(
            f"  {name:10} {np.median(c):9.1f} {np.percentile(c, 90):9.1f} "
            f"{np.median(w):9.2f} {np.percentile(w, 90):9.2f} {failed[name]}"
        )
    ratio = np.median(times["learnt"]["warm"]) / np.median(times["human"]["warm"])
    cold = np.median(times["learnt"]["cold"]) / np.median(times["human"]["cold"])
    lines.append(f"  learnt / human: warm {ratio:.2f}x, cold {cold:.2f}x   (target: warm <= 2x)")

    start = time.perf_counter()
    other = shared_planner(PlannerConfig(features=("laptop", "table", learnt[1].name), n_starts=4))
    other.solve(thetas[0], envs[int(where[0])])
    seconds = time.perf_counter() - start
    built = sorted(set(os.listdir(cache_dir())) - before - _libraries_of(planners))
    lines.append(
        f"a second learnt feature of the shape: its planner and first solve {seconds:.2f} s; "
        f"libraries built for it: {built or 'none'}"
    )
    if build:
        lines.append(_first_build(learnt[2]))
    return lines


def _libraries_of(planners) -> set[str]:
    """The library files the benchmark's two first planners built or loaded (whatever the
    cache held before)."""
    return {p.name for p in Path(cache_dir()).glob("*.so")} if cache_dir().is_dir() else set()


def _first_build(feature: L.Learnt) -> str:
    """The first build of the learnt shape's NLP in an empty cache (no clearance library)."""
    config = PlannerConfig(
        features=("laptop", "table", feature.name), n_starts=1, certificate=False
    )
    old = os.environ.get("CORRECTIONS_SIM_CACHE")
    with tempfile.TemporaryDirectory() as scratch:
        os.environ["CORRECTIONS_SIM_CACHE"] = scratch
        try:
            start = time.perf_counter()
            planner = Planner(config)
            fatrop = time.perf_counter() - start
            env = paper_environments()[0]
            plan = planner.solve(np.array([1.0, -1.0, -2.0]), env)
            start = time.perf_counter()
            planner.solve(np.array([1.0, -1.0, -2.05]), env, inits=[plan.trajectory])
            newton = time.perf_counter() - start
        finally:
            if old is None:
                os.environ.pop("CORRECTIONS_SIM_CACHE", None)
            else:
                os.environ["CORRECTIONS_SIM_CACHE"] = old
    return (
        f"first build of the shape {feature.network.slot}: fatrop's library {fatrop:.1f} s, "
        f"the Newton re-solve's {newton:.1f} s (once per machine and shape)"
    )
