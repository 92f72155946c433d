"""The runner: every (learner, run) of a study on any ``concurrent.futures`` executor.

:func:`run` executes a study's runs on an executor (a process pool, a Dask client's executor,
threads) and returns tidy records. The numbers do not depend on the executor, the number of
workers or the order in which runs finish: each run draws from its own generator, made from
(seed, learner stream, run), and everything is put back in (learner, run) order.

Order: first the plans every run shares (the user's ξ*(θ*, E) and the robot's ξ*(θ̂⁰, E) in
all environments, one task); then the runs of every learner with a covariance; a PP-type
learner's rate αᵗ is the mean of diag(Kᵗ) over the runs of the filter it follows (PP: KF, as
in the paper §6; PP-C: KF-C), unless its ``fixed_alpha`` fixes it; then the PP-type runs. A
:class:`RunCache` (e.g. :class:`~corrections_sim.study.store.RunStore`) makes a study
resumable: finished runs are loaded instead of recomputed, and each new one is handed to it
the moment it finishes.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from concurrent.futures import Executor, Future, as_completed
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from corrections_sim import components
from corrections_sim.learning import learning_rate_schedule
from corrections_sim.learning.base import LEARNERS, make_learner
from corrections_sim.planning.planner import shared_planner
from corrections_sim.plans import interpolation, spread
from corrections_sim.plans.book import PlanBook, PlanEntries, Target, evaluate
from corrections_sim.study.loop import RunResult, run_learner
from corrections_sim.study.plugins import load_plugins
from corrections_sim.study.settings import FigureSettings


class RunCache(Protocol):
    """Where finished runs live between invocations (e.g. ``store.RunStore``)."""

    def load_all(self) -> Mapping[tuple[str, int], Any]: ...

    def save(self, learner: str, run: int, result: Any) -> object: ...


def _order(name: str) -> int:
    """A learner's place in tables and plots: its registration order (plug-ins registered
    after this module was imported included)."""
    return list(LEARNERS).index(name)


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


def prepare(settings: FigureSettings, handed: spread.Carried | None = None) -> Shared:
    """Solve the shared plans; a task for a worker (the caller needs no planner). ``handed``:
    the study's atlases, to a worker that may not share the caller's files."""
    load_plugins(settings.plugins)
    _receive(settings, handed)
    s = settings.study
    planner = shared_planner(settings.planner_config())
    envs = settings.envs()
    target = settings.person_target(envs)
    book = PlanBook(planner, atlas=settings.atlas())
    evaluate(book, target, envs, np.array(s.theta0, float))
    return Shared(target=target, prior=book.entries(), solves=len(envs) + book.solves)


def _receive(settings: FigureSettings, handed: spread.Carried | None) -> None:
    """Hold the atlases handed to this worker (a cluster's; None on a process pool)."""
    if handed is not None:
        spread.receive(settings.atlas_spec(), handed)


def run_one(
    settings: FigureSettings,
    shared: Shared,
    learner: str,
    run: int,
    alphas=None,
    plan_book: type[PlanBook] = PlanBook,
    handed: spread.Carried | None = None,
    exchange=None,
    watch=None,
) -> RunResult:
    """One (learner, run); safe to call in a worker process. ``watch``: called with (t, the
    belief after t corrections), as :func:`~corrections_sim.study.loop.run_learner`'s (a
    judge of the posterior itself, which the records hold only as its moments). ``plan_book``: see
    :func:`~corrections_sim.study.loop.run_learner`; ``handed``: as :func:`prepare`'s;
    ``exchange``: a cluster's :class:`~corrections_sim.plans.spread.PlanExchange`, through
    which the run takes the plans between the atlas's nodes other workers solved whenever it
    has many to solve, and gives its own (workers that share no files then rarely solve one
    twice; no number depends on it)."""
    load_plugins(settings.plugins)
    _receive(settings, handed)
    s = settings.study
    seq = np.random.SeedSequence([s.seed, LEARNERS[learner].stream, run])
    atlas = settings.atlas()
    spec = settings.atlas_spec()
    spread.attach(spec, exchange)
    result = run_learner(
        learner,
        run,
        s,
        shared_planner(settings.planner_config()),
        settings.envs(),
        shared.target,
        s.user,
        np.random.default_rng(seq),
        alphas=alphas,
        known=shared.prior,
        plan_book=plan_book,
        atlas=atlas,
        watch=watch,
    )
    if atlas is not None:  # the plans it solved between the nodes, for the next process
        if exchange is not None and spec is not None:
            spread.flush(spec)
        atlas.save(at_least=SAVE_AT_LEAST)
        interpolation.save_kept(at_least=SAVE_AT_LEAST)  # and the cells it checked
    return result


#: Off-node plans of an environment a run leaves unsaved before they go to the store (a
#: shard a file; fewer wait for the next run of the process).
SAVE_AT_LEAST = 200


def mean_estimate_chain(
    settings: FigureSettings,
    shared: Shared,
    thetas: tuple[tuple[float, ...], ...],
    handed: spread.Carried | None = None,
) -> list[tuple[float, float, int, int]]:
    """(regret, paper regret, failed environments, solves) of each θ, in order; a worker task.

    One book for the whole chain (one learner's mean θ̂ᵗ, t = 0, 1, ...), seeded with the
    prior's plans: with the study's ``warm_start`` each θ's plans start from the nearest θ
    solved before in the chain, as a run evaluates its own θ̂ᵗ; without, every plan is cold.
    ``handed``: as :func:`prepare`'s.
    """
    load_plugins(settings.plugins)
    _receive(settings, handed)
    planner = shared_planner(settings.planner_config())
    book = PlanBook(
        planner, shared.prior, warm_start=settings.study.warm_start, atlas=settings.atlas()
    )
    envs = settings.envs()
    out = []
    for theta in thetas:
        before = book.solves
        regret, paper, failed = evaluate(book, shared.target, envs, np.array(theta))
        out.append((regret, paper, failed, book.solves - before))
    return out


def _mean_thetas(
    settings: FigureSettings, records: list[dict]
) -> list[tuple[str, int, int, tuple]]:
    """(learner, t, runs, mean θ̂ᵗ over runs) for every learner and iteration."""
    s = settings.study
    out = []
    for learner in sorted(s.learners, key=_order):
        rows = [r for r in records if r["learner"] == learner]
        for t in range(s.iterations + 1):
            at_t = [r for r in rows if r["iteration"] == t]
            theta = np.mean([[r[f"theta_{i}"] for i in range(s.k)] for r in at_t], axis=0)
            out.append((learner, t, len(at_t), tuple(float(v) for v in theta)))
    return out


@dataclass(frozen=True)
class FigureResult:
    """Everything a figure's files are made of.

    Attributes:
        records: one dict per (learner, run, iteration), in that order.
        mean_estimate: the regret of the mean θ̂ᵗ over runs, per learner and t.
        alphas: each PP-type learner's learning rate per iteration.
        solves: planner solves behind these results (including runs loaded from a cache).
        resumed: runs loaded from the cache rather than computed now.
    """

    records: list[dict]
    mean_estimate: list[dict]
    alphas: dict[str, list[float]]
    solves: int
    resumed: int


def tasks(settings: FigureSettings) -> list[tuple[str, int]]:
    """Every (learner, run) of the figure, PP-type learners last (their learning rate needs
    the filter runs); an active learner runs once unless the user is random."""
    s = settings.study
    names = sorted(s.learners, key=lambda n: (LEARNERS[n].needs_rates(), _order(n)))
    return [(name, r) for name in names for r in range(s.runs_of(name))]


def learning_rates(settings: FigureSettings, results: Mapping) -> dict[str, np.ndarray]:
    """αᵗ of every PP-type learner: ``fixed_alpha``, or the mean diag(Kᵗ) over the runs of
    the filter it follows (a step that failed counts as a zero gain)."""
    s = settings.study
    rates = {}
    for name, learner in s.learners.items():
        if not LEARNERS[name].needs_rates():
            continue
        if learner.fixed_rate() is not None:
            rates[name] = np.full(s.iterations, learner.fixed_rate())
            continue
        source = learner.rate_source()
        gains = [results[(source, r)].gains for r in range(s.runs_of(source))]
        rates[name] = learning_rate_schedule(np.nan_to_num(np.array(gains), nan=0.0))
    return rates


def run(
    settings: FigureSettings,
    executor: Executor,
    progress: Callable[[int, int], None] | None = None,
    cache: RunCache | None = None,
    *,
    mean_estimate: bool = True,
) -> FigureResult:
    """All runs of the figure on ``executor``; records sorted by (learner, run, iteration).

    Args:
        settings: the figure's resolved settings.
        executor: where the runs execute; any ``concurrent.futures.Executor``.
        progress: called as progress(done, total) after each finished run (loaded runs
            count as done from the start).
        cache: finished runs to reuse, and where to put each new one at once.
        mean_estimate: also evaluate the regret of the mean θ̂ᵗ over runs (the paper's
            fig. 4 caption; 48 solves per learner and iteration).
    """
    s = settings.study
    keys = tasks(settings)
    results: dict[tuple[str, int], RunResult] = {}
    if cache is not None:
        wanted = set(keys)
        results.update((k, v) for k, v in cache.load_all().items() if k in wanted)
    resumed = len(results)
    spec = settings.atlas_spec()
    # Even when every run is cached: the mean estimate plans from the atlas.
    phase = getattr(progress, "phase", None)
    atlas_progress = phase("atlas", "environment") if phase and spec is not None else None
    handed = spread.ready(spec, settings.envs(), executor, atlas_progress)
    # Only a cluster's tasks are handed the atlases: a process pool's are called as ever.
    extra = {} if handed is None else {"handed": handed}
    shared = executor.submit(prepare, settings, **extra).result()
    # A cluster's runs also hand each other the plans they solve between the atlas's nodes.
    exchange = spread.exchange_for(spec, executor)
    each_run = extra if exchange is None else {**extra, "exchange": exchange}
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
            rates = (alphas or {}).get(learner)
            future = executor.submit(run_one, settings, shared, learner, r, rates, **each_run)
            futures[future] = (learner, r)
        for fut in as_completed(futures):
            key = futures[fut]
            results[key] = fut.result()
            if cache is not None:
                cache.save(*key, results[key])
            done += 1
            if progress:
                progress(done, total)

    execute([k for k in keys if not LEARNERS[k[0]].needs_rates()])
    alphas = learning_rates(settings, results)
    execute([k for k in keys if LEARNERS[k[0]].needs_rates()], alphas)
    if exchange is not None:  # this machine keeps what a cluster solved between nodes too
        spread.keep_all(spec, exchange)

    records = [
        rec
        for key in sorted(results, key=lambda k: (_order(k[0]), k[1]))
        for rec in results[key].records
    ]
    points = _mean_thetas(settings, records) if mean_estimate else []
    # One chain a learner (its mean θ̂ᵗ in order of t), the learners side by side.
    chains: dict[str, list[tuple[float, ...]]] = {}
    for learner, _, _, theta in points:
        chains.setdefault(learner, []).append(theta)
    values = [
        value
        for chain in executor.map(
            mean_estimate_chain,
            [settings] * len(chains),
            [shared] * len(chains),
            [tuple(thetas) for thetas in chains.values()],
            *([[handed] * len(chains)] if handed is not None else []),
        )
        for value in chain
    ]
    mean_rows = [
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
        mean_estimate=mean_rows,
        alphas={name: [float(a) for a in rate] for name, rate in alphas.items()},
        solves=shared.solves + sum(r.solves for r in results.values()) + sum(v[3] for v in values),
        resumed=resumed,
    )


def run_key(settings: FigureSettings) -> dict:
    """The settings a run's numbers depend on: all but which learners run (a run of one
    learner is the same whichever others run beside it), so adding a learner to a study
    reuses the runs already made; a learner's parameters count where they differ from its
    defaults (changing one gives new runs)."""
    key = {k: v for k, v in settings.as_dict().items() if k != "learners"}
    # The clearance certificate only skips checks whose answer it proves: no number moves.
    key["planner"] = {k: v for k, v in key["planner"].items() if k != "certificate"}
    spec = settings.atlas_spec()
    if spec is not None:  # the planner's build and options, the grid and the algorithm
        key["atlas_identity"] = spec.key(None)
    key["learner_params"] = {
        name: params
        for name, params in settings.study.learner_params().items()
        if params != components.params(make_learner(name))
    }
    return key
