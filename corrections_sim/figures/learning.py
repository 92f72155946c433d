"""Figs. 4 and 5: PP, KF (and EKF) and AL learning from a simulated user's corrections.

Settings live as data in ``experiments/fig4.toml`` and ``fig5.toml`` (a paper-scale and a quick
preset each). :func:`run` executes every (learner, run) on any ``concurrent.futures``
executor (a process pool, a Dask client's executor) and returns tidy records. The curves do
not depend on the executor, the number of workers or the order in which runs finish: each
run draws from its own generator, made from (seed, learner stream, run), and everything is
put back in (learner, run) order before anything is averaged.

Order: first the plans every run shares (the user's ξ*(θ*, E) and the robot's ξ*(θ̂⁰, E) in
all environments, one task); then the KF, EKF and AL runs; PP's learning rate αᵗ is the mean
of diag(Kᵗ) over the KF runs (paper §6), unless the settings fix α; then the PP runs. A
:class:`RunCache` (see :mod:`corrections_sim.store`) makes a run resumable: finished runs
are loaded instead of recomputed, and each new one is handed to it the moment it finishes.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from concurrent.futures import Executor, Future, as_completed
from dataclasses import dataclass, fields
from typing import Protocol

import numpy as np

from corrections_sim.environments import paper_environments
from corrections_sim.figures.presets import read_preset
from corrections_sim.learners import learning_rate_schedule
from corrections_sim.planner import PlannerConfig, shared_planner
from corrections_sim.study import (
    PlanBook,
    PlanEntries,
    RunResult,
    StudySettings,
    Target,
    evaluate,
    run_learner,
)

FIGURES = ("fig4", "fig5")
FEATURES = ("laptop", "table")
# PP, KF and EKF run r share their draws on purpose (common random numbers).
_LEARNER_STREAM = {"PP": 0, "KF": 0, "EKF": 0, "AL": 1}
_ORDER = {"PP": 0, "KF": 1, "EKF": 2, "AL": 3}


@dataclass(frozen=True)
class FigureSettings:
    """A figure's study settings plus the planner's multi-start count."""

    study: StudySettings
    n_starts: int = 1

    def planner_config(self) -> PlannerConfig:
        return PlannerConfig(features=FEATURES, n_starts=self.n_starts)

    def as_dict(self) -> dict:
        d = {f.name: getattr(self.study, f.name) for f in fields(self.study)}
        d["n_starts"] = self.n_starts
        return d


def load_settings(figure: str, *, quick: bool, overrides: dict | None = None) -> FigureSettings:
    """Settings of ``figure`` from ``experiments/<figure>.toml`` with command-line overrides.

    Raises:
        ValueError: unknown figure or a bad value (the message names the field).
    """
    if figure not in FIGURES:
        raise ValueError(f"figure {figure!r}: choose one of {', '.join(FIGURES)}")
    values = read_preset(figure, quick)
    values.update({k: v for k, v in (overrides or {}).items() if v is not None})
    n_starts = int(values.pop("n_starts", 1))
    known = {f.name for f in fields(StudySettings)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"settings: unknown keys {unknown}")
    if len(values["theta_star"]) != len(FEATURES):
        raise ValueError(
            f"theta_star: expected {len(FEATURES)} weights for the features {FEATURES}, "
            f"got {len(values['theta_star'])}"
        )
    values["theta_star"] = tuple(values["theta_star"])
    values["theta0"] = tuple(values["theta0"])
    values["cov0"] = tuple(tuple(row) for row in values["cov0"])
    if "learners" in values:
        values["learners"] = tuple(values["learners"])
    settings = FigureSettings(study=StudySettings(**values), n_starts=n_starts)
    settings.planner_config()  # validates n_starts
    return settings


@dataclass(frozen=True)
class Shared:
    """What every run needs and nobody should solve twice.

    Attributes:
        target: the user's side, θ* and ξ*(θ*, E) for all environments.
        prior: the robot's plans ξ*(θ̂⁰, E) for all environments (every run starts there).
        solves: planner solves it took.
    """

    target: Target
    prior: PlanEntries
    solves: int


def prepare(settings: FigureSettings) -> Shared:
    """Solve the shared plans; a task for a worker (the caller needs no planner)."""
    s = settings.study
    planner = shared_planner(settings.planner_config())
    envs = paper_environments()
    target = Target.solve(planner, np.array(s.theta_star), envs)
    book = PlanBook(planner)
    evaluate(book, target, envs, np.array(s.theta0, float))
    return Shared(target=target, prior=book.entries(), solves=len(envs) + book.solves)


def run_one(
    settings: FigureSettings, shared: Shared, learner: str, run: int, alphas=None
) -> RunResult:
    """One (learner, run); safe to call in a worker process."""
    s = settings.study
    seq = np.random.SeedSequence([s.seed, _LEARNER_STREAM[learner], run])
    return run_learner(
        learner,
        run,
        s,
        shared_planner(settings.planner_config()),
        paper_environments(),
        shared.target,
        s.make_user(),
        np.random.default_rng(seq),
        alphas=alphas,
        known=shared.prior,
    )


def mean_estimate_point(
    settings: FigureSettings, shared: Shared, theta: tuple[float, ...]
) -> tuple[float, float, int, int]:
    """(regret, paper regret, failed environments, solves) of one θ; a worker task."""
    book = PlanBook(shared_planner(settings.planner_config()), shared.prior)
    regret, paper, failed = evaluate(book, shared.target, paper_environments(), np.array(theta))
    return regret, paper, failed, book.solves


def _mean_thetas(
    settings: FigureSettings, records: list[dict]
) -> list[tuple[str, int, int, tuple]]:
    """(learner, t, runs, mean θ̂ᵗ over runs) for every learner and iteration."""
    s = settings.study
    out = []
    for learner in sorted(s.learners, key=_ORDER.get):
        rows = [r for r in records if r["learner"] == learner]
        for t in range(s.iterations + 1):
            at_t = [r for r in rows if r["iteration"] == t]
            theta = np.mean([[r[f"theta_{i}"] for i in range(s.k)] for r in at_t], axis=0)
            out.append((learner, t, len(at_t), tuple(float(v) for v in theta)))
    return out


class RunCache(Protocol):
    """Where finished runs live between invocations (e.g. ``store.RunStore``)."""

    def load_all(self) -> Mapping[tuple[str, int], RunResult]: ...

    def save(self, learner: str, run: int, result: RunResult) -> object: ...


@dataclass(frozen=True)
class FigureResult:
    """Everything a figure's files are made of.

    Attributes:
        records: one dict per (learner, run, iteration), in that order.
        mean_estimate: the regret of the mean θ̂ᵗ over runs, per learner and t.
        alphas: PP's learning rate per iteration.
        solves: planner solves behind these results (including runs loaded from a cache).
        resumed: runs loaded from the cache rather than computed now.
    """

    records: list[dict]
    mean_estimate: list[dict]
    alphas: list[float]
    solves: int
    resumed: int


def tasks(settings: FigureSettings) -> list[tuple[str, int]]:
    """Every (learner, run) of the figure, PP last (its learning rate needs the KF runs)."""
    s = settings.study
    keys = [(name, r) for name in ("KF", "EKF") if name in s.learners for r in range(s.runs)]
    if "AL" in s.learners:
        keys.append(("AL", 0))
    if "PP" in s.learners:
        keys.extend(("PP", r) for r in range(s.runs))
    return keys


def run(
    settings: FigureSettings,
    executor: Executor,
    progress: Callable[[int, int], None] | None = None,
    cache: RunCache | None = None,
) -> FigureResult:
    """All runs of the figure on ``executor``; records sorted by (learner, run, iteration).

    Args:
        settings: the figure's resolved settings.
        executor: where the runs execute; any ``concurrent.futures.Executor``.
        progress: called as progress(done, total) after each finished run (loaded runs
            count as done from the start).
        cache: finished runs to reuse, and where to put each new one at once.
    """
    s = settings.study
    keys = tasks(settings)
    results: dict[tuple[str, int], RunResult] = {}
    if cache is not None:
        wanted = set(keys)
        results.update((k, v) for k, v in cache.load_all().items() if k in wanted)
    resumed = len(results)
    shared = executor.submit(prepare, settings).result()
    total = len(keys)
    done = resumed
    if progress:
        progress(done, total)

    def execute(batch: list[tuple[str, int]], alphas=None) -> None:
        nonlocal done
        futures: dict[Future, tuple[str, int]] = {}
        for learner, r in batch:
            if (learner, r) in results:
                continue
            rates = alphas if learner == "PP" else None
            futures[executor.submit(run_one, settings, shared, learner, r, rates)] = (learner, r)
        for fut in as_completed(futures):
            key = futures[fut]
            results[key] = fut.result()
            if cache is not None:
                cache.save(*key, results[key])
            done += 1
            if progress:
                progress(done, total)

    execute([k for k in keys if k[0] != "PP"])
    if s.fixed_alpha is not None:
        alphas = np.full(s.iterations, s.fixed_alpha)
    else:
        gains = [results[("KF", r)].gains for r in range(s.runs) if "KF" in s.learners]
        if not gains:
            raise ValueError("fixed_alpha: PP without KF runs needs a fixed learning rate")
        alphas = learning_rate_schedule(np.nan_to_num(np.array(gains), nan=0.0))
    execute([k for k in keys if k[0] == "PP"], alphas)

    records = [
        rec
        for key in sorted(results, key=lambda k: (_ORDER[k[0]], k[1]))
        for rec in results[key].records
    ]
    points = _mean_thetas(settings, records)
    values = list(
        executor.map(
            mean_estimate_point,
            [settings] * len(points),
            [shared] * len(points),
            [theta for *_, theta in points],
        )
    )
    mean_estimate = [
        {
            "learner": learner,
            "iteration": t,
            "runs": n,
            **{f"theta_{i}": theta[i] for i in range(s.k)},
            "regret": regret,
            "regret_paper": paper,
            "regret_failures": failed,
        }
        for (learner, t, n, theta), (regret, paper, failed, _) in zip(points, values, strict=True)
    ]
    return FigureResult(
        records=records,
        mean_estimate=mean_estimate,
        alphas=[float(a) for a in alphas],
        solves=shared.solves + sum(r.solves for r in results.values()) + sum(v[3] for v in values),
        resumed=resumed,
    )
