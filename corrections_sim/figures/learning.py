"""Figs. 4 and 5: the learners of :data:`corrections_sim.study.loop.LEARNERS` (the paper's PP, KF and
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
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim import calibration, provenance
from corrections_sim.figures.output import write_records
from corrections_sim.figures.presets import EXPERIMENTS_DIR
from corrections_sim.figures.registry import Caches, RunCache, register
from corrections_sim.learning import learning_rate_schedule
from corrections_sim.metrics import mean_sem
from corrections_sim.planning.planner import PlannerConfig, shared_planner
from corrections_sim.scene.environments import (
    LAPTOP_OFFSETS,
    START_POSITIONS,
    TABLE_POSITIONS,
    Environment,
)
from corrections_sim.study import schema as study_file
from corrections_sim.study.loop import (
    DEFAULT_LEARNERS,
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


@dataclass(frozen=True)
class FigureSettings:
    """A learning study: its study settings, features, environments and planner settings.

    Attributes:
        study: learners, user, prior, counts (see :class:`~corrections_sim.study.loop.StudySettings`).
        planner: planner settings as (name, value) pairs, passed to ``PlannerConfig``
            (``study_file.PLANNER_SETTINGS``: ``n_starts``, the multi-start count).
        features: the features θ weighs, in order (k of them).
        environments: "paper" (the 48), or paper environment names and specs of the user's own
            (see :mod:`corrections_sim.study.schema`).
        name: the figure or study file's name (output folder, titles); not a setting.
        description: a line for the plot's title; not a setting.
    """

    study: StudySettings
    planner: tuple[tuple[str, Any], ...] = tuple(study_file.PLANNER_SETTINGS.items())
    features: tuple[str, ...] = FEATURES
    environments: study_file.Environments = study_file.PAPER
    plugins: tuple[study_file.PluginFile, ...] = ()
    name: str = field(default="", compare=False)
    description: str = field(default="", compare=False)

    def planner_config(self) -> PlannerConfig:
        return PlannerConfig(features=self.features, **dict(self.planner))

    def envs(self) -> tuple[Environment, ...]:
        """The study's environments (memoized per process)."""
        return study_file.resolve(self.environments)

    def as_dict(self) -> dict:
        d = {f.name: getattr(self.study, f.name) for f in fields(self.study)}
        d.update(self.planner)
        d["features"] = list(self.features)
        d["environments"] = study_file.as_data(self.environments)
        if self.plugins:
            d["plugins"] = [p.as_dict() for p in self.plugins]
        return d


def load_settings(figure: str, *, quick: bool, overrides: dict | None = None) -> FigureSettings:
    """Settings of ``figure`` from its study file ``experiments/<figure>.toml`` with
    command-line overrides.

    Raises:
        ValueError: unknown figure or a bad value (the message names the field).
    """
    if figure not in FIGURES:
        raise ValueError(f"figure {figure!r}: choose one of {', '.join(FIGURES)}")
    return load_file(
        EXPERIMENTS_DIR / f"{figure}.toml", name=figure, quick=quick, overrides=overrides
    )


def load_file(source, *, name: str, quick: bool, overrides: dict | None = None) -> FigureSettings:
    """Settings from a study file (a path, or a resource of the installed package), with
    command-line overrides.

    Raises:
        ValueError: a bad file or value (the message names the key; see ``study_file``).
    """
    values = study_file.read(source, quick=quick)
    values.update({k: v for k, v in (overrides or {}).items() if v is not None})
    base = Path(source).resolve().parent if isinstance(source, str | Path) else None
    return settings_from_values(values, name=name, base=base)


def settings_from_values(
    values: dict, *, name: str = "", base: Path | None = None
) -> FigureSettings:
    """A study's settings from a flat mapping of study-file keys (``study_file.settings_keys``).

    Sizes are checked first (:func:`study_file.check_sizes`), so nothing is built for a
    study that cannot fit.

    Raises:
        ValueError: an unknown key or a bad value (the message names the field).
    """
    values = dict(values)
    study_file.check_keys(values)
    # Plug-ins first: they register the users, learners and features named below.
    plugins = study_file.parse_plugins(values.pop("plugins", ()), base)
    description = values.pop("description", "")
    if not isinstance(description, str):
        raise ValueError(f"description = {description!r}: expected a string")
    features = study_file.check_features(values.pop("features", FEATURES))
    k = len(features)
    learners = values.get("learners", DEFAULT_LEARNERS)
    if isinstance(learners, list | tuple):
        for i, learner in enumerate(learners):
            if learner not in study_file.learner_names():
                raise ValueError(
                    f"learners[{i}] = {learner!r}: unknown learner (choose from "
                    f"{', '.join(study_file.learner_names())})"
                )
    user = values.get("user", "biased")
    if user not in study_file.user_names():
        raise ValueError(
            f"user = {user!r}: unknown user (choose from {', '.join(study_file.user_names())})"
        )
    raw_envs = values.pop("environments", study_file.PAPER)
    n_envs = len(raw_envs) if isinstance(raw_envs, list | tuple) else N_PAPER_ENVIRONMENTS
    values.setdefault("runs", 10)
    values.setdefault("iterations", 12)
    study_file.check_sizes(
        values, n_envs, len(learners) if isinstance(learners, list | tuple) else 1
    )
    planner = tuple((k, values.pop(k, v)) for k, v in study_file.PLANNER_SETTINGS.items())
    if "theta_star" not in values:
        raise ValueError("theta_star: missing (the simulated user's true weights)")
    theta_star = values["theta_star"]
    if not isinstance(theta_star, list | tuple) or len(theta_star) != k:
        raise ValueError(
            f"theta_star: expected {k} weights for the features {features}, got "
            f"{len(theta_star) if isinstance(theta_star, list | tuple) else repr(theta_star)}"
        )
    values.setdefault("theta0", [0.0] * k)
    values.setdefault("cov0", [[float(i == j) for j in range(k)] for i in range(k)])
    for key in ("theta_star", "theta0"):
        if not isinstance(values[key], list | tuple) or not all(
            not isinstance(v, bool) and isinstance(v, int | float) for v in values[key]
        ):
            raise ValueError(f"{key} = {values[key]!r}: expected a list of numbers")
    cov0 = values["cov0"]
    if not isinstance(cov0, list | tuple) or not all(
        isinstance(row, list | tuple)
        and all(not isinstance(v, bool) and isinstance(v, int | float) for v in row)
        for row in cov0
    ):
        raise ValueError(f"cov0 = {cov0!r}: expected a {k} x {k} matrix (a list of rows)")
    if len(cov0) != k or any(len(row) != k for row in cov0):
        raise ValueError(f"cov0: expected a {k} x {k} matrix for the features {features}")
    values["theta_star"] = tuple(float(v) for v in values["theta_star"])
    values["theta0"] = tuple(float(v) for v in values["theta0"])
    values["cov0"] = tuple(tuple(float(v) for v in row) for row in cov0)
    if "learners" in values:
        values["learners"] = tuple(values["learners"])
    try:
        study = StudySettings(**values)
    except TypeError as exc:  # a value of the wrong type that the checks above let through
        raise ValueError(f"settings: {exc}") from None
    settings = FigureSettings(
        study=study,
        planner=planner,
        features=features,
        environments=study_file.parse_environments(raw_envs),
        plugins=plugins,
        name=name,
        description=description,
    )
    settings.planner_config()  # validates the planner settings
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
    study_file.load_plugins(settings.plugins)
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
    study_file.load_plugins(settings.plugins)
    s = settings.study
    seq = np.random.SeedSequence([s.seed, LEARNERS[learner].stream, run])
    return run_learner(
        learner,
        run,
        s,
        shared_planner(settings.planner_config()),
        settings.envs(),
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
    study_file.load_plugins(settings.plugins)
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
    for name in s.learners:
        source = LEARNERS[name].rate_from
        if not LEARNERS[name].needs_rates():
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
    user = s.user
    if s.user in ("biased", "deform"):
        user += f", step {s.user_step:g}"
    if s.user_waypoints != 1:
        user += f", {s.user_waypoints} waypoints"
    return f"θ* = {_vector(s.theta_star)}, θ̂⁰ = {_vector(s.theta0)}, P⁰ = {prior}; {user} user"


# --- files, and the figures registered by name -------------------------------------------------

#: Command-line options of a learning study (their argparse destinations), beyond the common ones.
OPTIONS = (
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
    reuses the runs already made."""
    return {k: v for k, v in settings.as_dict().items() if k != "learners"}


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
            return load_file(self.path, name=self.name, quick=quick, overrides=overrides)
        given = overrides.pop("study_file", None)
        if not given:
            raise ValueError(
                "study: give a study file, e.g. run study experiments/three_features.toml"
            )
        path = Path(given)
        try:
            return load_file(path, name=path.stem, quick=quick, overrides=overrides)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None

    def folder(self, settings: FigureSettings) -> str:
        return settings.name

    def cache_keys(self, settings: FigureSettings) -> dict[str, dict]:
        return {"": run_key(settings)}

    def recorded(self, settings: FigureSettings, *, quick: bool) -> dict:
        return settings.as_dict()

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
