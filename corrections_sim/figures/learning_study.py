"""Figs. 4 and 5 and ``run study FILE``: learning studies as registered figures.

The learners of :data:`corrections_sim.learning.base.LEARNERS` (the paper's PP, KF and AL, and
KF-C, AL-C, PP-C, KF-A, BP, the exact learners, plug-ins) learning from a simulated user's
corrections. Settings live as data: a study file each (``experiments/fig4.toml``,
``fig5.toml``; any other with ``run study FILE``, see :mod:`corrections_sim.study.schema`).
The study runs in :mod:`corrections_sim.study.runner` and is summarized by
:mod:`corrections_sim.study.analysis`; this module writes its files (CSV, ``summary.json``
fields, the plot).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim import components, provenance
from corrections_sim.figures.output import write_records
from corrections_sim.figures.presets import EXPERIMENTS_DIR
from corrections_sim.figures.registry import Caches, register
from corrections_sim.study import legacy, schema
from corrections_sim.study.analysis import METRICS, curves, summarize
from corrections_sim.study.runner import FigureResult, run, run_key
from corrections_sim.study.settings import FigureSettings

FIGURES = ("fig4", "fig5")
#: Features of figs. 4–5 and the default of a study file.
FEATURES = ("laptop", "table")


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


def _vector(values) -> str:
    return "(" + ", ".join(f"{v:g}" for v in values) + ")"


def describe(settings: FigureSettings, user: str | None = None) -> str:
    """One line of the settings a reader needs: θ*, θ̂⁰, P⁰ as given, and the user (or
    ``user``, who corrected instead of the study's simulated user)."""
    s = settings.study
    cov = np.array(s.cov0)
    if np.count_nonzero(cov - np.diag(np.diag(cov))) == 0:
        prior = f"diag{_vector(np.diag(cov))}"
    else:
        prior = "[" + "; ".join(", ".join(f"{v:g}" for v in row) for row in cov) + "]"
    corrector, user = user, f"{s.user_name} user"
    shown = ", ".join(
        f"{k} {v:g}" if isinstance(v, float) else f"{k} {v['name'] if isinstance(v, dict) else v}"
        for k, v in components.params(s.user).items()
    )
    if shown:
        user += f" ({shown})"
    user = user if corrector is None else corrector
    return f"θ* = {_vector(s.theta_star)}, θ̂⁰ = {_vector(s.theta0)}, P⁰ = {prior}; {user}"


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
    "online",
    "solver",
)


def shown_curves(settings: FigureSettings, result: FigureResult) -> dict:
    """What the plot draws: mean and SEM over runs at every iteration, per learner and metric
    (NEES/NIS are summarized under "calibration")."""
    from corrections_sim.metrics import mean_sem

    shown = {}
    for learner, data in curves(settings, result.records).items():
        shown[learner] = {}
        for key in METRICS:
            mean, sem = mean_sem(data[key])
            shown[learner][key] = {"mean": mean, "sem": sem}
    return shown


def write(
    settings: FigureSettings,
    result: FigureResult,
    folder: Path,
    name: str,
    *,
    user: str | None = None,
    plot: Callable | None = None,
    heading: str | None = None,
) -> dict:
    """curves.csv, mean_estimate.csv and the plot (PNG, PDF) in ``folder``; returns the
    summary's fields (statistics, provenance of the numbers, the curves drawn). ``plot``:
    how the curves are drawn (default
    :func:`~corrections_sim.figures.learning_plot.plot_learning_curves`; ``run learners``
    draws every learner by family); ``heading``: the title's first words
    (default ``name``, which also names the plot's files)."""
    from corrections_sim.figures.learning_plot import plot_learning_curves

    write_records(folder / "curves.csv", result.records)
    write_records(folder / "mean_estimate.csv", result.mean_estimate)
    stats = summarize(settings, result)
    data = curves(settings, result.records)
    heading = heading or name
    title = f"{heading}: {describe(settings, user)}"
    if settings.description:
        title = f"{heading}: {settings.description}\n{describe(settings, user)}"
    (plot or plot_learning_curves)(
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
        return legacy.normalize_recorded(old)

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
        "fig4",
        "the paper's fig. 4: every learner of experiments/fig4.toml, equal initial uncertainty",
        EXPERIMENTS_DIR / "fig4.toml",
    )
)
register(
    LearningStudy(
        "fig5",
        "the paper's fig. 5: every learner of experiments/fig5.toml, laptop known, table uncertain",
        EXPERIMENTS_DIR / "fig5.toml",
    )
)
register(LearningStudy("study", "a learning study in a TOML file (see docs/study-files.md)"))
