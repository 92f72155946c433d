"""Figs. 4 and 5: the learners of :data:`corrections_sim.learning.base.LEARNERS` (the paper's PP,
KF and
AL, and EKF, KF-C, AL-C, PP-C) learning from a simulated user's corrections.

Settings live as data: a study file each (``experiments/fig4.toml``, ``fig5.toml``; any other
with ``run study FILE``, see :mod:`corrections_sim.study.schema`). :func:`run` executes
every (learner, run) on any ``concurrent.futures`` executor (a process pool, a Dask client's
executor) and returns tidy records. The curves do not depend on the executor, the number of
workers or the order in which runs finish: each run draws from its own generator, made from
(seed, learner stream, run), and everything is put back in (learner, run) order before
anything is averaged.

Order: first the plans every run shares (the user's ξ*(θ*, E) and the robot's ξ*(θ̂⁰, E) in
all environments, one task); then the runs of every learner with a covariance; a PP-type
learner's rate αᵗ is the mean of diag(Kᵗ) over the runs of the filter it follows (PP: KF, as
in the paper §6; PP-C: KF-C), unless the settings fix α; then the PP-type runs. A
:class:`RunCache` (see :mod:`corrections_sim.study.store`) makes a run resumable: finished runs
are loaded instead of recomputed, and each new one is handed to it the moment it finishes.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from concurrent.futures import Executor, Future, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim import calibration, components, provenance
from corrections_sim.figures.output import write_records
from corrections_sim.figures.presets import EXPERIMENTS_DIR
from corrections_sim.figures.registry import Caches, RunCache, register
from corrections_sim.learning import learning_rate_schedule
from corrections_sim.learning.base import LEARNERS, make_learner
from corrections_sim.metrics import mean_sem
from corrections_sim.planning.planner import shared_planner
from corrections_sim.planning.plans import PlanBook, PlanEntries, Target, evaluate
from corrections_sim.scene.environments import (
    LAPTOP_OFFSETS,
    START_POSITIONS,
    TABLE_POSITIONS,
)
from corrections_sim.study import schema
from corrections_sim.study.loop import RunResult, run_learner
from corrections_sim.study.settings import FigureSettings

FIGURES = ("fig4", "fig5")
#: Features of figs. 4–5 and the default of a study file.
FEATURES = ("laptop", "table")
#: Figures and tables list learners in the registry's order.


def _order(name: str) -> int:
    """A learner's place in tables and plots: its registration order (plug-ins registered
    after this module was imported included)."""
    return list(LEARNERS).index(name)


N_PAPER_ENVIRONMENTS = len(START_POSITIONS) * len(TABLE_POSITIONS) * len(LAPTOP_OFFSETS)
#: Curves averaged over runs, and the metrics compared between learners.
METRICS = ("estimate_error", "regret", "regret_paper")


def load_settings(figure: str, *, quick: bool, overrides: dict | None = None) -> FigureSettings:
    """Settings of ``figure`` from its study file ``experiments/<figure>.toml`` with
    command-line overrides.

    Raises:
        ValueError: unknown figure or a bad value (the message names the key path).
    """
    if figure not in FIGURES:
        raise ValueError(f"figure {figure!r}: choose one of {', '.join(FIGURES)}")
    return schema.load_study(
        EXPERIMENTS_DIR / f"{figure}.toml", name=figure, quick=quick, overrides=overrides
    )


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
    schema.load_plugins(settings.plugins)
    s = settings.study
    planner = shared_planner(settings.planner_config())
    envs = settings.envs()
    target = Target.solve(planner, np.array(s.theta_star), envs)
    book = PlanBook(planner)
    evaluate(book, target, envs, np.array(s.theta0, float))
    return Shared(target=target, prior=book.entries(), solves=len(envs) + book.solves)


def run_one(
    settings: FigureSettings, shared: Shared, learner: str, run: int, alphas=None
) -> RunResult:
    """One (learner, run); safe to call in a worker process."""
    schema.load_plugins(settings.plugins)
    s = settings.study
    seq = np.random.SeedSequence([s.seed, LEARNERS[learner].stream, run])
    return run_learner(
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
    )


def mean_estimate_point(
    settings: FigureSettings, shared: Shared, theta: tuple[float, ...]
) -> tuple[float, float, int, int]:
    """(regret, paper regret, failed environments, solves) of one θ; a worker task."""
    schema.load_plugins(settings.plugins)
    book = PlanBook(shared_planner(settings.planner_config()), shared.prior)
    regret, paper, failed = evaluate(book, shared.target, settings.envs(), np.array(theta))
    return regret, paper, failed, book.solves


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

    execute([k for k in keys if not LEARNERS[k[0]].needs_rates()])
    alphas = learning_rates(settings, results)
    execute([k for k in keys if LEARNERS[k[0]].needs_rates()], alphas)

    records = [
        rec
        for key in sorted(results, key=lambda k: (_order(k[0]), k[1]))
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
    for learner in sorted(settings.study.learners, key=_order):
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
    params = components.params(s.user)
    shown = ", ".join(
        f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}"
        for k, v in params.items()
        if not isinstance(v, dict)
    )
    user = s.user_name + (f", {shown}" if shown else "")
    return f"θ* = {_vector(s.theta_star)}, θ̂⁰ = {_vector(s.theta0)}, P⁰ = {prior}; {user} user"


# --- files, and the figures registered by name -------------------------------------------------

#: Command-line options of a learning study (their argparse destinations), beyond the common ones:
#: each sets a key of the study (``schema.OPTION_PATHS``); ``set`` is ``--set PATH=VALUE``.
OPTIONS = (
    "set",
    "runs",
    "iterations",
    "seed",
    "theta_star",
    "theta0",
    "cov0",
    "learners",
    "user",
    "user_step",
    "user_waypoints",
    "correction_model",
    "correction_step",
    "correction_waypoints",
    "fixed_alpha",
    "warm_start",
    "solver",
)


def run_key(settings: FigureSettings) -> dict:
    """The settings a run's numbers depend on: all but which learners run (a run of one
    learner is the same whichever others run beside it), so adding a learner to a study
    reuses the runs already made; a learner's parameters count where they differ from its
    defaults (changing one gives new runs)."""
    key = {k: v for k, v in settings.as_dict().items() if k != "learners"}
    key["learner_params"] = {
        name: params
        for name, params in settings.study.learner_params().items()
        if params != components.params(make_learner(name))
    }
    return key


def shown_curves(settings: FigureSettings, result: FigureResult) -> dict:
    """What the plot draws: mean and SEM over runs at every iteration, per learner and metric
    (NEES/NIS are summarized under "calibration")."""
    from corrections_sim.figures.plotting import mean_sem

    shown = {}
    for learner, data in curves(settings, result.records).items():
        shown[learner] = {}
        for key in METRICS:
            mean, sem = mean_sem(data[key])
            shown[learner][key] = {"mean": mean, "sem": sem}
    return shown


def write(settings: FigureSettings, result: FigureResult, folder: Path, name: str) -> dict:
    """curves.csv, mean_estimate.csv and the plot (PNG, PDF) in ``folder``; returns the
    summary's fields (statistics, provenance of the numbers, the curves drawn)."""
    from corrections_sim.figures.plotting import plot_learning_curves

    write_records(folder / "curves.csv", result.records)
    write_records(folder / "mean_estimate.csv", result.mean_estimate)
    stats = summarize(settings, result)
    data = curves(settings, result.records)
    title = f"{name}: {describe(settings)}"
    if settings.description:
        title = f"{name}: {settings.description}\n{describe(settings)}"
    plot_learning_curves(
        data,
        title,
        [folder / f"{name}.png", folder / f"{name}.pdf"],
        bands={n: c["band"] for n, c in stats["calibration"].items()},
        n_environments=len(settings.envs()),
    )
    return {
        "seed": settings.study.seed,
        "planner_solves": result.solves,
        "resumed_runs": result.resumed,
        "learning_rates": result.alphas,
        **stats,
        "regret_failures": int(sum(r["regret_failures"] for r in result.records)),
        "skipped_updates": int(sum(bool(r["update_skipped"]) for r in result.records)),
        "planner": provenance.plain(settings.planner_config()),
        "runs_per_learner": {learner: len(d["regret"]) for learner, d in data.items()},
        "curves": provenance.plain(shown_curves(settings, result)),
    }


@dataclass(frozen=True)
class LearningStudy:
    """A learning study as a registered figure: fig4 and fig5 read ``experiments/<name>.toml``;
    ``study`` reads the file given on the command line (its name is the file's stem).

    Attributes:
        name: the command.
        help: one line for ``--help``.
        path: the study file; None for ``study``, whose file is the ``study_file`` option.
    """

    name: str
    help: str
    path: Any = None
    unit: str = "run"

    @property
    def options(self) -> tuple[str, ...]:
        return OPTIONS if self.path is not None else ("study_file", *OPTIONS)

    @property
    def in_all(self) -> bool:
        return self.path is not None

    def load(self, *, quick: bool, overrides: Mapping[str, Any]) -> FigureSettings:
        overrides = dict(overrides)
        if self.path is not None:
            return schema.load_study(self.path, name=self.name, quick=quick, overrides=overrides)
        given = overrides.pop("study_file", None)
        if not given:
            raise ValueError(
                "study: give a study file, e.g. run study experiments/three_features.toml"
            )
        path = Path(given)
        try:
            return schema.load_study(path, name=path.stem, quick=quick, overrides=overrides)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None

    def folder(self, settings: FigureSettings) -> str:
        return settings.name

    def cache_keys(self, settings: FigureSettings) -> dict[str, dict]:
        return {"": run_key(settings)}

    def recorded(self, settings: FigureSettings, *, quick: bool) -> dict:
        return settings.as_dict()

    def upgrade_recorded(self, old: dict) -> dict:
        """Settings an older ``summary.json`` recorded (flat keys), in today's form."""
        return schema.normalize_recorded(old)

    def run(
        self,
        settings: FigureSettings,
        executor: Executor,
        progress: Callable[[int, int], None] | None,
        cache: Caches | None,
    ) -> FigureResult:
        return run(settings, executor, progress, cache=(cache or {}).get(""))

    def write(self, settings: FigureSettings, result: FigureResult, folder: Path) -> dict:
        return write(settings, result, folder, settings.name)


register(
    LearningStudy(
        "fig4", "PP vs KF vs AL, equal initial uncertainty", EXPERIMENTS_DIR / "fig4.toml"
    )
)
register(
    LearningStudy(
        "fig5", "PP vs KF vs AL, laptop known, table uncertain", EXPERIMENTS_DIR / "fig5.toml"
    )
)
register(LearningStudy("study", "a learning study described in a TOML file (see README)"))
