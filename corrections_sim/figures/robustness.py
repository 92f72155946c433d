"""Fig. 6 (beyond the paper): a robustness matrix of learners × simulated users.

Rows are learners (the paper's PP, KF and AL; the correction-aware KF-C and AL-C; whatever
else ``learners`` names), columns are simulated users, including ones no filter models: the
paper's biased user, one who moves its worst waypoint only half way, one who corrects its
three worst waypoints, one who pushes the arm into a smooth deformation, and the noisy-optimal
user (the paper KF's own model). A cell holds the final estimate error and regret (mean ±
SEM) and the calibration (mean NEES, coverage of θ* by the 95% credible ellipse).

Settings are data in ``experiments/fig6.toml`` (the one dialect of
:mod:`corrections_sim.study.schema`): the study settings every column shares (fig. 4's by
default) and a list of ``[[columns]]`` tables, each a column with its ``label`` and its
``user``, a name or a table with the user's parameters (``{ name = "biased", step = 0.5 }``;
plug-in users included). Each column is a learning study run by
:func:`corrections_sim.study.runner.run`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim import provenance
from corrections_sim.figures import learning_study
from corrections_sim.figures.output import write_records
from corrections_sim.figures.presets import EXPERIMENTS_DIR
from corrections_sim.figures.registry import Caches, register
from corrections_sim.study import analysis, files, legacy, runner, schema
from corrections_sim.study.runner import FigureResult, RunCache
from corrections_sim.study.settings import FigureSettings

FIGURE = "fig6"
#: Keys a column may set; everything else is shared by all columns. A column is a person:
#: their way of correcting (``user``), what they weigh (``user_features``, ``theta_star``).
COLUMN_KEYS = ("label", "user", "online", "user_features", "theta_star")
#: Options that set the user: refused, the columns are the users.
USER_OPTIONS = ("user", "user_step", "user_waypoints")


@dataclass(frozen=True)
class Column:
    """One simulated user: a label and its settings."""

    label: str
    settings: FigureSettings


@dataclass(frozen=True)
class RobustnessSettings:
    """The columns of the matrix (each a complete figure's settings)."""

    columns: tuple[Column, ...]

    @property
    def learners(self) -> tuple[str, ...]:
        return self.columns[0].settings.study.learners

    def as_dict(self) -> dict:
        return {c.label: c.settings.as_dict() for c in self.columns}


def load_settings(
    *,
    quick: bool,
    overrides: dict | None = None,
    figure: str = FIGURE,
    column_keys: tuple[str, ...] = COLUMN_KEYS,
) -> RobustnessSettings:
    """Settings of fig. 6 from ``experiments/fig6.toml`` (or of another matrix of users,
    ``experiments/<figure>.toml``, whose columns may take more ``column_keys``); ``overrides``
    apply to every column (the user cannot be overridden: the columns are the users).

    Raises:
        ValueError: a bad value, named as ``columns[i].key`` or by its key path.
    """
    keys = (*schema.STUDY_KEYS, *legacy.LEGACY_KEYS, "columns")
    values = files.read(EXPERIMENTS_DIR / f"{figure}.toml", quick=quick, keys=keys)
    columns = values.pop("columns", None)
    if not isinstance(columns, list) or not columns:
        raise ValueError("columns: expected a non-empty list of [[columns]] tables")
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    for key in USER_OPTIONS:
        if key in given:
            raise ValueError(f"{key}: {figure}'s columns are its users; set them in {figure}.toml")
    if any(item.partition("=")[0].strip().startswith("user") for item in given.get("set", ())):
        raise ValueError(
            f"--set user…: {figure}'s columns are its users; set them in {figure}.toml"
        )
    if "user" in values:
        raise ValueError(f"user: {figure}'s columns are its users; give each [[columns]] its user")
    columns, shared = _column_overrides(
        columns, given.get("set") or (), figure, study_theta="theta_star" in given
    )
    given = {**given, "set": shared} if "set" in given else given
    values = schema.apply_overrides(values, given)
    out, labels = [], set()
    for i, column in enumerate(columns):
        if not isinstance(column, dict):
            raise ValueError(f"columns[{i}]: expected a table with label and user")
        unknown = sorted(set(column) - set(column_keys))
        if unknown:
            raise ValueError(
                f"columns[{i}].{unknown[0]}: unknown key (a column takes {', '.join(column_keys)})"
            )
        label = column.get("label")
        if not isinstance(label, str) or not label or label in labels:
            raise ValueError(f"columns[{i}].label: expected a distinct non-empty name")
        if "user" not in column:
            raise ValueError(f"columns[{i}].user: missing (a name or a table with its parameters)")
        labels.add(label)
        try:
            extra = {k: column[k] for k in column_keys[2:] if k in column}
            settings = schema.parse_study({**values, "user": column["user"], **extra})
        except ValueError as exc:
            raise ValueError(f"columns[{i}] ({label}): {exc}") from None
        out.append(Column(label=label, settings=settings))
    return RobustnessSettings(columns=tuple(out))


def _column_overrides(
    columns: list, items: Sequence[str], figure: str, *, study_theta: bool
) -> tuple[list, list[str]]:
    """The file's columns with ``--set columns.C.KEY=VALUE`` applied (C a column's index from
    0 or its label) and the ``--set`` items left for every column. A study-wide θ*
    (``--theta-star``, ``--set theta_star=…``) does not reach a column that sets its own (a
    person who also weighs what the robot lacks): such a column's θ* must then be given too,
    or the command refuses, rather than run that person at the file's θ* unannounced.

    Raises:
        ValueError: an unknown column, a malformed item, or a column whose own θ* a
            study-wide θ* would silently leave as it is.
    """
    columns = [dict(c) if isinstance(c, dict) else c for c in columns]
    shared, touched = [], set()
    for item in items:
        path, sep, text = item.partition("=")
        head, _, rest = path.strip().partition(".")
        if head != "columns":
            shared.append(item)
            continue
        which, _, key = rest.partition(".")
        index = next(
            (
                i
                for i, c in enumerate(columns)
                if isinstance(c, dict) and (which == str(i) or which == c.get("label"))
            ),
            None,
        )
        if index is None or not sep or not key:
            raise ValueError(
                f"--set {item}: expected columns.C.KEY=VALUE with C one of {figure}'s columns "
                f"(0 to {len(columns) - 1}, or a label), e.g. columns.1.theta_star=[2, -2, -2]"
            )
        files.set_path(columns[index], key, files.parse_value(text.strip()))
        touched.add((index, key))
    study_theta = study_theta or any(
        item.partition("=")[0].strip().partition(".")[0] == "theta_star" for item in shared
    )
    for i, column in enumerate(columns):
        if (
            study_theta
            and isinstance(column, dict)
            and "theta_star" in column
            and (i, "theta_star") not in touched
        ):
            raise ValueError(
                f"theta_star: column {i} ({column.get('label')}) sets its own θ* "
                f"{column['theta_star']}, which a study-wide θ* does not change; give it too, "
                f"e.g. --set columns.{i}.theta_star=[...]"
            )
    return columns, shared


def run(
    settings: RobustnessSettings,
    executor: Executor,
    progress: Callable[[int, int], None] | None = None,
    caches: Sequence[RunCache | None] | None = None,
) -> list[FigureResult]:
    """Every column's study on ``executor``, one after the other; one result per column."""
    caches = caches or [None] * len(settings.columns)
    results = []
    total = sum(len(runner.tasks(c.settings)) for c in settings.columns)
    offset = 0
    for column, cache in zip(settings.columns, caches, strict=True):
        n = len(runner.tasks(column.settings))

        def report(done: int, _total: int, base: int = offset) -> None:
            if progress:
                progress(base + done, total)

        # The atlas's build is a phase of its own (the first column builds it; minutes).
        phase = getattr(progress, "phase", None)
        if phase is not None:
            report.phase = phase  # type: ignore[attr-defined]
        results.append(
            runner.run(column.settings, executor, report, cache=cache, mean_estimate=False)
        )
        offset += n
    return results


def matrix(settings: RobustnessSettings, results: Sequence[FigureResult]) -> list[dict]:
    """One row per (learner, user): final error and regret (mean, SEM), calibration and, for
    EX-M, its final posterior over the person's correction models (``model_<tag>``)."""
    rows = []
    for column, result in zip(settings.columns, results, strict=True):
        stats = analysis.summarize(column.settings, result)
        for learner in settings.learners:
            final = stats["final"][learner]
            calib = stats["calibration"].get(learner)
            row = {"learner": learner, "user": column.label, "runs": final["runs"]}
            for key in ("estimate_error", "regret"):
                row[f"{key}_mean"] = final[key]["mean"]
                row[f"{key}_sem"] = final[key]["sem"]
                row[f"{key}_auc"] = final[key]["auc_mean"]
            # None (an empty CSV cell, JSON null) where the learner has no covariance.
            row["nees_final"] = calib["mean_nees"][-1] if calib else None
            row["nees_mean"] = float(np.mean(calib["mean_nees"][1:])) if calib else None
            row["nees_band_low"], row["nees_band_high"] = calib["band"] if calib else (None, None)
            row["inside_band"] = calib["inside_band"] if calib else None
            row["coverage_2sigma"] = calib["coverage_2sigma_mean"] if calib else None
            row |= _final_model_posterior(result.records, learner)
            rows.append(row)
    return rows


def _final_model_posterior(records: Sequence[dict], learner: str) -> dict[str, float]:
    """A learner's posterior over how the person corrects (EX-M's ``model_<tag>`` columns)
    after the last correction, the mean over runs; empty for a learner without one."""
    last = max(r["iteration"] for r in records)
    finals = [r for r in records if r["learner"] == learner and r["iteration"] == last]
    keys = [k for k in (finals[0] if finals else {}) if k.startswith("model_")]
    return {k: float(np.mean([float(r[k]) for r in finals])) for k in keys}


#: The learner a matrix compares every other one with, paired by run (``paired.csv``), when
#: it is one of the matrix's learners: the exact posterior over how the person corrects.
PAIRED_AGAINST = "EX-M"


def final_pairs(user: str, data: dict, a: str, b: str) -> list[dict]:
    """Paired 95% t-intervals of ``a`` minus ``b`` for one ``user`` (``data``: their curves,
    :func:`~corrections_sim.study.analysis.curves`), final estimate error and final regret
    (the learners share their runs' draws); none where they ran different numbers of runs (an
    active learner runs once)."""
    if data[a]["regret"].shape[0] != data[b]["regret"].shape[0]:
        return []
    return [
        {"user": user, "a": a, "b": b, "metric": f"final {metric}"}
        | analysis._mean_ci(data[a][metric][:, -1] - data[b][metric][:, -1])
        for metric in ("estimate_error", "regret")
    ]


def paired_against(
    settings: RobustnessSettings, results: Sequence[FigureResult], learner: str = PAIRED_AGAINST
) -> list[dict] | None:
    """:func:`final_pairs` of ``learner`` minus every other learner, per user; None where
    ``learner`` is not in the matrix."""
    rows = []
    for column, result in zip(settings.columns, results, strict=True):
        learners = column.settings.study.learners
        if learner not in learners:
            continue
        data = analysis.curves(column.settings, result.records)
        for other in learners:
            if other != learner:
                rows += final_pairs(column.label, data, learner, other)
    return rows or None


def title(settings: RobustnessSettings, what: str) -> str:
    """A matrix figure's plot title: ``what``, the runs and corrections, the shared settings."""
    first = settings.columns[0].settings
    return (
        f"{what}: {first.study.runs} runs × {first.study.iterations} corrections; "
        + learning_study.describe(first).rsplit(";", 1)[0]
    )


def write_matrix(
    settings: RobustnessSettings,
    results: Sequence[FigureResult],
    rows: list[dict],
    folder: Path,
    paired: list[dict] | None = None,
) -> dict:
    """matrix.csv (``rows``), curves.csv (every column's records, labelled by user) and, when
    given, paired.csv in ``folder``; returns the summary's fields every matrix of users
    shares (with ``paired``)."""
    write_records(folder / "matrix.csv", rows)
    if paired is not None:
        write_records(folder / "paired.csv", paired)
    write_records(
        folder / "curves.csv",
        [
            {"user": c.label, **rec}
            for c, result in zip(settings.columns, results, strict=True)
            for rec in result.records
        ],
    )
    first = settings.columns[0].settings
    return {
        "planner_solves": sum(r.solves for r in results),
        "resumed_runs": sum(r.resumed for r in results),
        "matrix": rows,
        "planner": provenance.plain(first.planner_config()),
        "runs_per_learner": runs_per_learner(settings),
        **({"paired": paired} if paired is not None else {}),
    }


def runs_per_learner(settings: RobustnessSettings) -> dict[str, int | dict[str, int]]:
    """Each learner's runs: one number when every column gives it as many, else the runs per
    column label (an active learner runs once under a deterministic person and ``runs`` times
    under a random one: fig. 6's noisy-optimal column)."""
    out: dict[str, int | dict[str, int]] = {}
    for name in settings.learners:
        by_column = {c.label: c.settings.study.runs_of(name) for c in settings.columns}
        counts = set(by_column.values())
        out[name] = counts.pop() if len(counts) == 1 else by_column
    return out


def write(settings: RobustnessSettings, results: Sequence[FigureResult], folder: Path) -> dict:
    """matrix.csv, curves.csv (every column's records, labelled by user), with EX-M among
    the learners paired.csv (:func:`paired_against`), and the plot in ``folder``; returns the
    summary's fields."""

    rows = matrix(settings, results)
    summary = write_matrix(settings, results, rows, folder, paired_against(settings, results))
    first = settings.columns[0].settings
    title = (
        f"fig6: learners × simulated users; {first.study.runs} runs × "
        f"{first.study.iterations} corrections; " + learning_study.describe(first).rsplit(";", 1)[0]
    )
    paths = [folder / "fig6.png", folder / "fig6.pdf"]
    plot_robustness_matrix(rows, title, paths, environments=len(first.envs()))
    return summary


@dataclass(frozen=True)
class RobustnessFigure:
    """Fig. 6 as a registered figure; resumable per column (``column-<i>`` caches)."""

    name: str = FIGURE
    help: str = "beyond the paper: learners x simulated users, calibration"
    options: tuple[str, ...] = learning_study.OPTIONS
    unit: str = "run"
    in_all: bool = True

    def load(self, *, quick: bool, overrides: Mapping[str, Any]) -> RobustnessSettings:
        return load_settings(quick=quick, overrides=dict(overrides))

    def folder(self, settings: RobustnessSettings) -> str:
        return self.name

    def cache_keys(self, settings: RobustnessSettings) -> dict[str, dict]:
        return {f"column-{i}": runner.run_key(c.settings) for i, c in enumerate(settings.columns)}

    def recorded(self, settings: RobustnessSettings, *, quick: bool) -> dict:
        return settings.as_dict()

    def upgrade_recorded(self, old: dict) -> dict:
        """Settings an older ``summary.json`` recorded (flat keys per column), in today's form."""
        return {
            label: legacy.normalize_recorded(v) if isinstance(v, dict) else v
            for label, v in old.items()
        }

    def run(
        self,
        settings: RobustnessSettings,
        executor: Executor,
        progress: Callable[[int, int], None] | None,
        cache: Caches | None,
    ) -> list[FigureResult]:
        caches = [(cache or {}).get(f"column-{i}") for i in range(len(settings.columns))]
        return run(settings, executor, progress, caches=caches)

    def write(self, settings: RobustnessSettings, result: list[FigureResult], folder: Path) -> dict:
        return write(settings, result, folder)


register(RobustnessFigure())


def plot_robustness_matrix(rows: Sequence[dict], title: str, paths, *, environments: int) -> None:
    """Fig. 6: learners (rows) × users (columns); final estimate error, final regret and
    final mean NEES as coloured tables with mean ± SEM in each cell.

    Args:
        rows: ``robustness.matrix`` rows (learner, user, *_mean, *_sem, nees_final, band).
        paths: files to write.
        environments: how many the regret is summed over.
    """
    from corrections_sim.figures.style import plt, save_and_close

    learners = list(dict.fromkeys(r["learner"] for r in rows))
    users = list(dict.fromkeys(r["user"] for r in rows))
    cell = {(r["learner"], r["user"]): r for r in rows}
    panels = (
        ("estimate_error", "Final estimate error ‖θ̂ − θ*‖₁ (lower is better)", "viridis_r"),
        ("regret", f"Final regret, Σ over {environments} envs (lower is better)", "viridis_r"),
        ("nees", "Final mean NEES (calibrated: k = 2; log colour)", "coolwarm"),
    )
    fig, axes = plt.subplots(1, 3, figsize=(6.2 * 3, 0.55 * len(learners) + 2.6))
    for ax, (key, label, cmap) in zip(axes, panels, strict=True):
        values = np.full((len(learners), len(users)), np.nan)
        for i, learner in enumerate(learners):
            for j, user in enumerate(users):
                r = cell[(learner, user)]
                value = r["nees_final"] if key == "nees" else r[f"{key}_mean"]
                values[i, j] = np.nan if value is None else value
        if key == "nees":
            # Diverging around k = 2 on a log scale: blue under-, red over-confident.
            shown = np.log10(values / 2.0)
            limit = max(1.0, float(np.nanmax(np.abs(shown))))
            image = ax.imshow(shown, cmap=cmap, vmin=-limit, vmax=limit, aspect="auto")
        else:
            image = ax.imshow(values, cmap=cmap, aspect="auto")
        colours = image.cmap(image.norm(shown if key == "nees" else values))
        for i, learner in enumerate(learners):
            for j, user in enumerate(users):
                r = cell[(learner, user)]
                if key == "nees":
                    v = r["nees_final"]
                    if v is None:
                        text = "—"
                    else:
                        inside = r["nees_band_low"] <= v <= r["nees_band_high"]
                        text = f"{v:.3g}" + (" ✓" if inside else "")
                else:
                    sem = r[f"{key}_sem"]
                    text = f"{r[f'{key}_mean']:.3g}" + (f"\n± {sem:.2g}" if sem else "\n(N = 1)")
                luminance = np.dot(colours[i, j, :3], (0.299, 0.587, 0.114))
                ax.text(
                    j,
                    i,
                    text,
                    ha="center",
                    va="center",
                    fontsize=8,
                    color="black" if luminance > 0.5 or not np.isfinite(values[i, j]) else "white",
                )
        ax.set_xticks(range(len(users)), users, rotation=20, ha="right", fontsize=9)
        ax.set_yticks(range(len(learners)), learners, fontsize=9)
        ax.set_title(label, fontsize=10)
    fig.text(
        0.99,
        0.01,
        "NEES: ✓ inside the 95% χ² band of a calibrated mean for its N; — no covariance (PP)",
        ha="right",
        fontsize=8,
    )
    fig.suptitle(title, fontsize=11)
    save_and_close(fig, paths, dpi=150)
