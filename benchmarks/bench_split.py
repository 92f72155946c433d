"""Where a study's time goes, learner by learner (``python -m benchmarks.bench split``).

A figure's study (fig. 4 by default, or a study file) at paper settings, ``runs`` runs of every
learner (seed as the study's), in this process on one thread, the study's atlas read or built
before the clock starts. For each learner: CPU seconds a run, of which the regret metric (the
plans of θ̂ᵗ in every environment, after each correction) and the learner's own update, the
planner solves a run, and what the study's own runs of it would cost at that rate (its
``runs`` runs, one for a learner whose run is deterministic). Apart, the command's fixed part:
the plans every run shares (the person's, which every run is measured against, and the
prior's). What a run costs does not depend on how many workers share the runs, so the table
says where a study's CPU goes, not its wall time.
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Sequence
from concurrent.futures import Executor, Future

from benchmarks.bench_exact import _settings


class _Here(Executor):
    """Runs each task at once, in this thread (so that what it does can be timed here)."""

    def submit(self, fn, /, *args, **kwargs) -> Future:
        future: Future = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # handed to the caller as a pool would
            future.set_exception(exc)
        return future


def measure(figure: str, overrides: dict) -> tuple[dict, float, dict]:
    """(per learner: runs, CPU s, regret metric s, update s, solves; the CPU s of the plans
    every run shares (the person's and the prior's); the study's run counts per learner) for
    ``figure`` with ``overrides``."""
    from corrections_sim.learning import correction
    from corrections_sim.planning import planner as planner_module
    from corrections_sim.plans.spread import prepare
    from corrections_sim.study import loop, runner

    settings = _settings(figure, overrides)
    spec = settings.atlas_spec()
    if spec is not None:  # read or built before any timing
        prepare(spec, settings.envs())
    full = _settings(figure, {k: v for k, v in overrides.items() if k != "runs"})
    study_runs: dict[str, int] = defaultdict(int)
    for name, _ in runner.tasks(full):
        study_runs[name] += 1
    current: list[str] = []
    tally: dict[str, dict[str, float]] = defaultdict(lambda: defaultdict(float))

    def add(key: str, seconds: float, count: float = 0.0) -> None:
        if current:
            tally[current[-1]][key] += seconds
            tally[current[-1]][key + "_n"] += count

    def timed(function, key: str):
        def wrapper(*args, **kwargs):
            t0 = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                add(key, time.process_time() - t0, 1)

        return wrapper

    fixed = [0.0]

    def prepare_timed(*args, **kwargs):
        t0 = time.process_time()
        try:
            return original["prepare"](*args, **kwargs)
        finally:
            fixed[0] += time.process_time() - t0

    original = {
        "prepare": runner.prepare,
        "run_one": runner.run_one,
        "evaluate": loop.evaluate,
        "step": correction.step,
        "solve": planner_module.Planner.solve,
    }
    timed_run = timed(original["run_one"], "run")

    def run_one(settings_, shared, learner, run, *args, **kwargs):
        current.append(learner)
        try:
            return timed_run(settings_, shared, learner, run, *args, **kwargs)
        finally:
            current.pop()

    try:
        runner.prepare = prepare_timed
        runner.run_one = run_one
        loop.evaluate = timed(original["evaluate"], "regret")
        correction.step = timed(original["step"], "update")
        planner_module.Planner.solve = timed(original["solve"], "solve")
        runner.run(settings, _Here(), mean_estimate=False)
    finally:
        runner.prepare = original["prepare"]
        runner.run_one = original["run_one"]
        loop.evaluate = original["evaluate"]
        correction.step = original["step"]
        planner_module.Planner.solve = original["solve"]
    return {name: dict(values) for name, values in tally.items()}, fixed[0], dict(study_runs)


def run_bench(figure: str, runs: int, overrides: dict, learners: Sequence[str] | None) -> list[str]:
    """The table of ``bench split`` (module docstring)."""
    chosen = {**overrides, "runs": runs}
    if learners:
        chosen["learners"] = list(learners)
    tally, shared, study_runs = measure(figure, chosen)
    lines = [
        f"{figure}, up to {runs} run(s) of each learner, one thread, CPU seconds; the plans "
        f"every run shares (the person's, the prior's; once a command): {shared:.1f} s",
        "",
        "| learner | runs | a run | regret metric | update | other | solves a run "
        "| the study's runs | at this rate |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    total = 0.0
    for name, t in tally.items():
        n = int(t["run_n"])
        each = t["run"] / n
        regret, update = t.get("regret", 0.0) / n, t.get("update", 0.0) / n
        other = each - regret - update
        solves = t.get("solve_n", 0.0) / n
        study = study_runs.get(name, n)
        total += each * study
        lines.append(
            f"| {name} | {n} | {each:.2f} | {regret:.2f} | {update:.2f} | {other:.2f} "
            f"| {solves:.0f} | {study} | {each * study:.0f} s |"
        )
    lines.append(f"| all | | | | | | | | {total:.0f} s (+ {shared:.0f} s the shared plans) |")
    return lines
