"""Figs. 4 and 5: PP, KF and AL learning from the biased user's corrections.

Settings live as data in ``experiments/fig4.toml`` and ``fig5.toml`` (a paper-scale and a quick
preset each). :func:`run` executes every (learner, run) on any ``concurrent.futures``
executor and returns tidy records; the curves are independent of the executor and of the
number of workers because each run draws from its own generator, made from (seed, learner,
run).

Order: KF runs and the AL run first; PP's learning rate αᵗ is then the mean of diag(Kᵗ) over
the KF runs (paper §6), unless the settings fix α.
"""

from __future__ import annotations

import functools
import tomllib
from collections.abc import Callable
from concurrent.futures import Executor, Future
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from corrections_sim.environments import paper_environments
from corrections_sim.human import BiasedUser
from corrections_sim.learners import learning_rate_schedule
from corrections_sim.planner import Planner, PlannerConfig
from corrections_sim.study import PlanBook, RunResult, StudySettings, Target, evaluate, run_learner

EXPERIMENTS_DIR = Path(__file__).resolve().parents[2] / "experiments"
FIGURES = ("fig4", "fig5")
FEATURES = ("laptop", "table")
_LEARNER_STREAM = {"PP": 0, "KF": 0, "AL": 1}  # PP and KF run r share draws on purpose


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
    with open(EXPERIMENTS_DIR / f"{figure}.toml", "rb") as fh:
        presets = tomllib.load(fh)
    values = dict(presets["quick" if quick else "paper"])
    values.update({k: v for k, v in (overrides or {}).items() if v is not None})
    n_starts = int(values.pop("n_starts", 1))
    known = {f.name for f in fields(StudySettings)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"settings: unknown keys {unknown}")
    values["theta_star"] = tuple(values["theta_star"])
    values["theta0"] = tuple(values["theta0"])
    values["cov0"] = tuple(tuple(row) for row in values["cov0"])
    if "learners" in values:
        values["learners"] = tuple(values["learners"])
    settings = FigureSettings(study=StudySettings(**values), n_starts=n_starts)
    settings.planner_config()  # validates n_starts
    return settings


@functools.cache
def _context(config: PlannerConfig, theta_star: tuple[float, ...]):
    """Per-process planner, environments and the user's optimal plans (built once)."""
    planner = Planner(config)
    envs = paper_environments()
    return planner, envs, Target.solve(planner, np.array(theta_star), envs)


def run_one(settings: FigureSettings, learner: str, run: int, alphas=None) -> RunResult:
    """One (learner, run); safe to call in a worker process."""
    s = settings.study
    planner, envs, target = _context(settings.planner_config(), s.theta_star)
    seq = np.random.SeedSequence([s.seed, _LEARNER_STREAM[learner], run])
    return run_learner(
        learner,
        run,
        s,
        planner,
        envs,
        target,
        BiasedUser(step=s.user_step),
        np.random.default_rng(seq),
        alphas=alphas,
    )


def mean_estimate_regret(settings: FigureSettings, records: list[dict]) -> list[dict]:
    """The paper's fig. 4 caption: regret of the *mean* θ̂ᵗ over runs, per learner and t."""
    s = settings.study
    planner, envs, target = _context(settings.planner_config(), s.theta_star)
    book = PlanBook(planner)
    out = []
    for learner in s.learners:
        rows = [r for r in records if r["learner"] == learner]
        for t in range(s.iterations + 1):
            at_t = [r for r in rows if r["iteration"] == t]
            theta = np.mean([[r[f"theta_{i}"] for i in range(s.k)] for r in at_t], axis=0)
            regret, paper, failed = evaluate(book, target, envs, theta)
            out.append(
                {
                    "learner": learner,
                    "iteration": t,
                    "runs": len(at_t),
                    **{f"theta_{i}": float(theta[i]) for i in range(s.k)},
                    "regret": regret,
                    "regret_paper": paper,
                    "regret_failures": failed,
                }
            )
    return out


@dataclass(frozen=True)
class FigureResult:
    records: list[dict]
    mean_estimate: list[dict]
    alphas: list[float]
    solves: int


def run(
    settings: FigureSettings,
    executor: Executor,
    progress: Callable[[int, int], None] | None = None,
) -> FigureResult:
    """All runs of the figure on ``executor``; records sorted by (learner, run, iteration)."""
    s = settings.study
    total = s.runs * (("KF" in s.learners) + ("PP" in s.learners)) + ("AL" in s.learners)
    done = 0
    results: dict[tuple[str, int], RunResult] = {}

    def collect(futures: dict[Future, tuple[str, int]]) -> None:
        nonlocal done
        for fut, key in futures.items():
            results[key] = fut.result()
            done += 1
            if progress:
                progress(done, total)

    first = {}
    if "KF" in s.learners:
        for r in range(s.runs):
            first[executor.submit(run_one, settings, "KF", r)] = ("KF", r)
    if "AL" in s.learners:
        first[executor.submit(run_one, settings, "AL", 0)] = ("AL", 0)
    collect(first)
    if s.fixed_alpha is not None:
        alphas = np.full(s.iterations, s.fixed_alpha)
    else:
        gains = [results[k].gains for k in results if k[0] == "KF"]
        if not gains:
            raise ValueError("fixed_alpha: PP without KF runs needs a fixed learning rate")
        alphas = learning_rate_schedule(np.nan_to_num(np.array(gains), nan=0.0))
    if "PP" in s.learners:
        second = {
            executor.submit(run_one, settings, "PP", r, alphas): ("PP", r) for r in range(s.runs)
        }
        collect(second)
    order = {name: i for i, name in enumerate(("PP", "KF", "AL"))}
    records = [
        rec
        for key in sorted(results, key=lambda k: (order[k[0]], k[1]))
        for rec in results[key].records
    ]
    return FigureResult(
        records=records,
        mean_estimate=mean_estimate_regret(settings, records),
        alphas=[float(a) for a in alphas],
        solves=sum(r.solves for r in results.values()),
    )
