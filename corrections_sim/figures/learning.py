"""Figs. 4 and 5: the learners of :data:`corrections_sim.study.LEARNERS` (the paper's PP, KF and
AL, and EKF, KF-C, AL-C, PP-C) learning from a simulated user's corrections.

Settings live as data in ``experiments/fig4.toml`` and ``fig5.toml`` (a paper-scale and a quick
preset each). :func:`run` executes every (learner, run) on any ``concurrent.futures``
executor (a process pool, a Dask client's executor) and returns tidy records. The curves do
not depend on the executor, the number of workers or the order in which runs finish: each
run draws from its own generator, made from (seed, learner stream, run), and everything is
put back in (learner, run) order before anything is averaged.

Order: first the plans every run shares (the user's ξ*(θ*, E) and the robot's ξ*(θ̂⁰, E) in
all environments, one task); then the runs of every learner with a covariance; a PP-type
learner's rate αᵗ is the mean of diag(Kᵗ) over the runs of the filter it follows (PP: KF, as
in the paper §6; PP-C: KF-C), unless the settings fix α; then the PP-type runs. A
:class:`RunCache` (see :mod:`corrections_sim.store`) makes a run resumable: finished runs
are loaded instead of recomputed, and each new one is handed to it the moment it finishes.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from concurrent.futures import Executor, Future, as_completed
from dataclasses import dataclass, fields
from typing import Protocol

import numpy as np

from corrections_sim import calibration
from corrections_sim.environments import paper_environments
from corrections_sim.figures.presets import read_preset
from corrections_sim.learners import learning_rate_schedule
from corrections_sim.metrics import mean_sem
from corrections_sim.planner import PlannerConfig, shared_planner
from corrections_sim.study import (
    LEARNERS,
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
#: Figures and tables list learners in the registry's order.
_ORDER = {name: i for i, name in enumerate(LEARNERS)}
#: Curves averaged over runs, and the metrics compared between learners.
METRICS = ("estimate_error", "regret", "regret_paper")


@dataclass(frozen=True)
class FigureSettings:
    """A figure's study settings plus the planner's multi-start count and solver."""

    study: StudySettings
    n_starts: int = 1
    solver: str = "fatrop"

    def planner_config(self) -> PlannerConfig:
        return PlannerConfig(features=FEATURES, n_starts=self.n_starts, solver=self.solver)

    def as_dict(self) -> dict:
        d = {f.name: getattr(self.study, f.name) for f in fields(self.study)}
        d["n_starts"] = self.n_starts
        d["solver"] = self.solver
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
    return settings_from_values(values)


def settings_from_values(values: dict) -> FigureSettings:
    """A figure's settings from a flat mapping of :class:`StudySettings` keys, ``n_starts``
    and ``solver``.

    Raises:
        ValueError: an unknown key or a bad value (the message names the field).
    """
    values = dict(values)
    n_starts = int(values.pop("n_starts", 1))
    solver = str(values.pop("solver", "fatrop"))
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
    settings = FigureSettings(study=StudySettings(**values), n_starts=n_starts, solver=solver)
    settings.planner_config()  # validates n_starts and solver
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
    seq = np.random.SeedSequence([s.seed, LEARNERS[learner].stream, run])
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
    names = sorted(s.learners, key=lambda n: (not LEARNERS[n].has_covariance, _ORDER[n]))
    return [(name, r) for name in names for r in range(s.runs_of(name))]


def learning_rates(settings: FigureSettings, results: Mapping) -> dict[str, np.ndarray]:
    """αᵗ of every PP-type learner: ``fixed_alpha``, or the mean diag(Kᵗ) over the runs of
    the filter it follows (a step that failed counts as a zero gain)."""
    s = settings.study
    rates = {}
    for name in s.learners:
        source = LEARNERS[name].rate_from
        if LEARNERS[name].has_covariance:
            continue
        if s.fixed_alpha is not None:
            rates[name] = np.full(s.iterations, s.fixed_alpha)
            continue
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
            rates = (alphas or {}).get(learner)
            futures[executor.submit(run_one, settings, shared, learner, r, rates)] = (learner, r)
        for fut in as_completed(futures):
            key = futures[fut]
            results[key] = fut.result()
            if cache is not None:
                cache.save(*key, results[key])
            done += 1
            if progress:
                progress(done, total)

    execute([k for k in keys if LEARNERS[k[0]].has_covariance])
    alphas = learning_rates(settings, results)
    execute([k for k in keys if not LEARNERS[k[0]].has_covariance], alphas)

    records = [
        rec
        for key in sorted(results, key=lambda k: (_ORDER[k[0]], k[1]))
        for rec in results[key].records
    ]
    points = _mean_thetas(settings, records) if mean_estimate else []
    values = list(
        executor.map(
            mean_estimate_point,
            [settings] * len(points),
            [shared] * len(points),
            [theta for *_, theta in points],
        )
    )
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


def curves(settings: FigureSettings, records: list[dict]) -> dict[str, dict[str, np.ndarray]]:
    """learner -> metric -> values (runs, T + 1), for the metrics and "nees", "nis"."""
    out = {}
    for learner in sorted(settings.study.learners, key=_ORDER.get):
        rows = [r for r in records if r["learner"] == learner]
        runs = sorted({r["run"] for r in rows})
        out[learner] = {
            key: np.array(
                [[_number(r[key]) for r in rows if r["run"] == run] for run in runs], dtype=float
            )
            for key in (*METRICS, "nees", "nis")
        }
    return out


def _number(value) -> float:
    """A record's value as a float; None and "" (no value) are NaN."""
    return float("nan") if value is None or value == "" else float(value)


def _mean_ci(values: np.ndarray) -> dict:
    """Mean, SEM and the 95% t-interval of the mean of ``values`` (n,)."""
    from scipy import stats

    n = values.size
    mean = float(np.mean(values))
    if n < 2:
        return {"mean": mean, "sem": None, "ci95": None, "n": n}
    sem = float(np.std(values, ddof=1) / np.sqrt(n))
    half = float(stats.t.ppf(0.975, n - 1) * sem)
    return {"mean": mean, "sem": sem, "ci95": [mean - half, mean + half], "n": n}


def paired_differences(settings: FigureSettings, data: dict) -> list[dict]:
    """Paired a − b of final value and area under the curve (Σ over iterations 0 … T) for
    every pair of learners that share their random stream and runs (common random numbers:
    run r of both saw the same environments), with the 95% t-interval of the mean."""
    names = list(data)
    out = []
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            if LEARNERS[a].stream != LEARNERS[b].stream:
                continue
            if data[a]["regret"].shape[0] != data[b]["regret"].shape[0]:
                continue
            if data[a]["regret"].shape[0] < 2:
                continue
            for key in METRICS:
                va, vb = data[a][key], data[b][key]
                out.append(
                    {
                        "a": a,
                        "b": b,
                        "metric": key,
                        "final": _mean_ci(va[:, -1] - vb[:, -1]),
                        "auc": _mean_ci(va.sum(axis=1) - vb.sum(axis=1)),
                    }
                )
    return out


def summarize(settings: FigureSettings, result: FigureResult) -> dict:
    """The figure's statistics, read from its records only: final mean ± SEM and AUC per
    learner and metric, calibration (NEES band, coverage, NIS) of every learner with a
    covariance, and paired differences."""
    s = settings.study
    data = curves(settings, result.records)
    final, calib = {}, {}
    for learner, values in data.items():
        stats = {}
        for key in METRICS:
            mean, sem = mean_sem(values[key][:, -1:])
            stats[key] = {
                "mean": float(mean[0]),
                "sem": float(sem[0]) if values[key].shape[0] > 1 else None,
                "auc_mean": float(np.mean(values[key].sum(axis=1))),
            }
        stats["runs"] = int(values["regret"].shape[0])
        final[learner] = stats
        if LEARNERS[learner].has_covariance:
            entry = calibration.summarize(values["nees"], s.k)
            nis = values["nis"][:, 1:]
            # None where no run has an innovation covariance (BP): valid JSON, not NaN.
            entry["mean_nis"] = [
                float(np.mean(col[np.isfinite(col)])) if np.isfinite(col).any() else None
                for col in nis.T
            ]
            entry["nis_band"] = list(calibration.mean_band(s.k, nis.shape[0]))
            calib[learner] = entry
    return {
        "final": final,
        "calibration": calib,
        "paired": paired_differences(settings, data),
    }


def _vector(values) -> str:
    return "(" + ", ".join(f"{v:g}" for v in values) + ")"


def describe(settings: FigureSettings) -> str:
    """One line of the settings a reader needs: θ*, θ̂⁰, P⁰ as given, and the user."""
    s = settings.study
    cov = np.array(s.cov0)
    if np.count_nonzero(cov - np.diag(np.diag(cov))) == 0:
        prior = f"diag{_vector(np.diag(cov))}"
    else:
        prior = "[" + "; ".join(", ".join(f"{v:g}" for v in row) for row in cov) + "]"
    user = s.user
    if s.user in ("biased", "deform"):
        user += f", step {s.user_step:g}"
    if s.user_waypoints != 1:
        user += f", {s.user_waypoints} waypoints"
    return f"θ* = {_vector(s.theta_star)}, θ̂⁰ = {_vector(s.theta0)}, P⁰ = {prior}; {user} user"
