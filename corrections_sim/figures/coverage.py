"""Do the credible regions cover people the robot's model does not hold? A command.

    python -m corrections_sim.run coverage            # results/coverage/ (fig. 6's and the
                                                       # relevance study's people)
    python -m corrections_sim.run coverage --quick    # fig. 6's first two people, CI's size

Simulation-based calibration (:mod:`corrections_sim.figures.sbc`) draws its people from the
recommended robot's own prior, where exact Bayes must be calibrated. This is the other half
of issue 67's question: the people of fig. 6 (four ways of correcting besides the paper's)
and of the relevance study (irrelevant nudges, a feature the robot lacks), whom no learner's
model holds. Each (person, learner, run) is the matrix's own run, replayed with the same
draws (its error equals the committed ``curves.csv``'s), and its posterior after the last
correction judged against θ* (:func:`corrections_sim.study.sbc.judged_run`): the share of
runs whose θ* lies in the 50% and 90% highest-density regions, with Wilson intervals.

The settings are ``experiments/coverage.toml``: which matrices, which learners, how many runs
of each (the first runs of the matrix's).

* ``runs.csv``: one row per person, learner and run (level, ranks, NEES, error, regret);
* ``summary.json``: per person and learner, ``coverage_50`` and ``coverage_90`` (share and
  ``ci95``), and the mean level, NEES and error;
* ``coverage.png``: each learner's coverage per person with its interval, against 50% and 90%.
"""

from __future__ import annotations

import csv
import tomllib
from collections.abc import Callable, Mapping
from concurrent.futures import Executor, Future, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from corrections_sim.figures import robustness
from corrections_sim.figures.presets import EXPERIMENTS_DIR
from corrections_sim.figures.registry import Caches, register
from corrections_sim.plans import spread
from corrections_sim.study import loop, runner
from corrections_sim.study import sbc as core
from corrections_sim.study.settings import FigureSettings

FIGURE = "coverage"
#: The keys of ``experiments/coverage.toml`` (and of its ``[quick]`` table).
KEYS = ("description", "matrices", "learners", "runs", "columns", "set")


@dataclass(frozen=True)
class Person:
    """One column of a matrix: its matrix's name, its label and its study's settings (the
    learners judged, the runs asked for)."""

    matrix: str
    label: str
    settings: FigureSettings

    @property
    def name(self) -> str:
        return f"{self.matrix}: {self.label}"

    @property
    def key(self) -> str:
        """Its key in ``summary.json``: ``fig6:biased,_half_way`` (no space, no dot, so that
        a page's quote can name it)."""
        return f"{self.matrix}:{self.label.replace(' ', '_').replace('.', '_')}"


@dataclass(frozen=True)
class CoverageSettings:
    people: tuple[Person, ...]
    learners: tuple[str, ...]
    runs: int
    preset: str

    def as_dict(self) -> dict:
        return {
            "learners": list(self.learners),
            "runs": self.runs,
            "people": {p.name: p.settings.as_dict() for p in self.people},
            "coverage": list(core.COVERAGE),
            "level_samples": core.LEVEL_SAMPLES,
        }


@dataclass(frozen=True)
class CoverageResult:
    rows: list[dict]
    resumed: int


def _table(values: dict, where: str) -> dict:
    unknown = [k for k in values if k not in KEYS]
    if unknown:
        raise ValueError(f"{where}{unknown[0]}: unknown key (expected {', '.join(KEYS)})")
    return values


def load_settings(*, quick: bool, overrides: Mapping[str, Any]) -> CoverageSettings:
    """``experiments/coverage.toml`` (its ``[quick]`` table with ``--quick``); ``--runs``
    and ``--learners`` override it. Each matrix's columns at its own preset, with the judged
    learners, the runs and the file's ``set`` (key paths) applied to every column."""
    path = EXPERIMENTS_DIR / "coverage.toml"
    values = tomllib.loads(path.read_text())
    quick_values = _table(values.pop("quick", {}), "quick.")
    values = _table(values, "")
    if quick:
        values = {**values, **quick_values}
    learners = overrides.get("learners") or values["learners"]
    learners = list(learners.split(",") if isinstance(learners, str) else learners)
    runs = overrides.get("runs") or values["runs"]
    if not isinstance(runs, int) or runs < 1:
        raise ValueError(f"runs = {runs!r}: expected an integer >= 1")
    columns = values.get("columns")
    people = []
    for matrix in values["matrices"]:
        given = {**values.get("set", {}), "learners": learners, "runs": runs}
        found = robustness.load_settings(quick=quick, overrides=given, figure=matrix)
        for column in found.columns[:columns]:
            study = column.settings.study
            for name in learners:
                if not study.learners[name].has_covariance:
                    raise ValueError(f"learners: {name} has no posterior to judge")
            people.append(Person(matrix, column.label, column.settings))
    return CoverageSettings(tuple(people), tuple(learners), runs, "quick" if quick else "paper")


def _key(person: Person, learner: str, run: int) -> str:
    return f"{person.name} | {learner} | {run}"


def run(
    settings: CoverageSettings,
    executor: Executor,
    progress: Callable[[int, int], None] | None = None,
    caches: Caches | None = None,
) -> CoverageResult:
    """Every person's runs of every learner on ``executor`` (each person's shared plans
    first), resumed from ``caches`` (a person's, keyed by its study; a run's row kept as
    that run's records)."""
    caches = caches or {}
    rows: dict[str, dict] = {}
    for person in settings.people:
        cache = caches.get(person.name)
        if cache is not None:
            for (learner, r), kept in cache.load_all().items():
                rows[_key(person, learner, r)] = dict(kept.records[0])
    wanted = [
        (person, learner, r)
        for person in settings.people
        for learner in settings.learners
        for r in range(settings.runs)
    ]
    done = resumed = sum(_key(*w) in rows for w in wanted)
    if progress:
        progress(done, len(wanted))
    # Each person's shared plans first, all at once (the atlas is built before, once per
    # machine: the people of a matrix share its planner); then every run.
    todo = [w for w in wanted if _key(*w) not in rows]
    people = [p for p in settings.people if any(w[0] is p for w in todo)]
    extras: dict[str, dict] = {}
    for person in people:
        base = person.settings
        handed = spread.ready(base.atlas_spec(), base.envs(), executor)
        extras[person.name] = {} if handed is None else {"handed": handed}
    prepared = {
        p.name: executor.submit(runner.prepare, p.settings, **extras[p.name]) for p in people
    }
    futures: dict[Future, tuple[Person, str, int]] = {}
    for person, learner, r in todo:
        shared, extra = prepared[person.name].result(), extras[person.name]
        fut = executor.submit(core.judged_run, person.settings, shared, learner, r, **extra)
        futures[fut] = (person, learner, r)
    for fut in as_completed(futures):
        person, learner, r = futures[fut]
        row = {"matrix": person.matrix, "person": person.label, **fut.result()}
        rows[_key(person, learner, r)] = row
        cache = caches.get(person.name)
        if cache is not None:
            kept = loop.RunResult(records=(row,), gains=np.zeros(0), solves=0)
            cache.save(learner, r, kept)
        done += 1
        if progress:
            progress(done, len(wanted))
    return CoverageResult([rows[_key(*w)] for w in wanted], resumed)


def summarize(settings: CoverageSettings, rows: list[dict]) -> dict:
    """Per person (:attr:`Person.key`) and learner:
    :func:`~corrections_sim.study.sbc.coverage_of`."""
    out: dict = {}
    for person in settings.people:
        mine = [r for r in rows if (r["matrix"], r["person"]) == (person.matrix, person.label)]
        out[person.key] = {
            learner: core.coverage_of([r for r in mine if r["learner"] == learner])
            for learner in settings.learners
        }
    return out


def write(settings: CoverageSettings, result: CoverageResult, folder: Path) -> dict:
    """``runs.csv``, ``coverage.png``; the summary's fields."""
    folder.mkdir(parents=True, exist_ok=True)
    columns: list[str] = []
    for row in result.rows:
        columns += [c for c in row if c not in columns]
    with open(folder / "runs.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns)
        writer.writeheader()
        writer.writerows(result.rows)
    summary = summarize(settings, result.rows)
    plot(settings, summary, folder / "coverage.png")
    return {"runs": settings.runs, "resumed_runs": result.resumed, "coverage": summary}


def plot(settings: CoverageSettings, summary: dict, path: Path) -> Path:
    """Two panels (the 50% and the 90% region): each learner's coverage per person, with its
    95% interval; the dashed line is what a calibrated posterior covers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from corrections_sim.figures import style

    people = [p.key for p in settings.people]
    learners = list(settings.learners)
    fig, axes = plt.subplots(1, 2, figsize=(12, 0.42 * len(people) + 2.0), sharey=True)
    offsets = np.linspace(-0.25, 0.25, len(learners)) if len(learners) > 1 else [0.0]
    for ax, alpha in zip(axes, core.COVERAGE, strict=True):
        key = f"coverage_{round(100 * alpha)}"
        for j, learner in enumerate(learners):
            colour, line = style.learner_style(learner)[:2]
            ys, xs, lo, hi = [], [], [], []
            for i, person in enumerate(people):
                entry = summary[person][learner][key]
                if entry["share"] is None:
                    continue
                ys.append(i + offsets[j])
                xs.append(entry["share"])
                lo.append(entry["share"] - entry["ci95"][0])
                hi.append(entry["ci95"][1] - entry["share"])
            ax.errorbar(xs, ys, xerr=[lo, hi], fmt="o", color=colour, ms=5, capsize=2,
                        label=learner, lw=1.2)  # fmt: skip
        ax.axvline(alpha, color="0.3", ls="--", lw=1)
        ax.set_xlim(-0.02, 1.02)
        ax.set_xlabel(f"share of runs whose θ* lies in the {round(100 * alpha)}% region")
        ax.set_title(f"{round(100 * alpha)}% region: calibrated on the dashed line", fontsize=10)
        ax.grid(axis="x", color="0.9")
    axes[0].set_yticks(range(len(people)), [p.name for p in settings.people])
    axes[0].invert_yaxis()
    axes[1].legend(loc="upper left", fontsize=8, frameon=True)
    fig.suptitle(
        f"Coverage for people the model does not hold ({settings.runs} runs each, after the last "
        "correction; left of the line: over-confident, right: under-confident)",
        fontsize=10,
    )
    style.save_and_close(fig, [path], dpi=110, rect=(0, 0, 1, 0.94))
    return path


class CoverageFigure:
    """Coverage for the matrices' people as a registered figure; resumable per run."""

    name = FIGURE
    help = (
        "coverage of the credible regions for people no learner's model holds (fig. 6, relevance)"
    )
    options = ("runs", "learners")
    unit = "run"
    in_all = False
    option_help: ClassVar[dict[str, str]] = {"runs": "runs of each learner a person (default 20)"}

    def load(self, *, quick: bool, overrides: Mapping[str, Any]) -> CoverageSettings:
        return load_settings(quick=quick, overrides=overrides)

    def folder(self, settings: CoverageSettings) -> str:
        return FIGURE

    def cache_keys(self, settings: CoverageSettings) -> dict[str, dict]:
        keys = {}
        for person in settings.people:
            key = runner.run_key(person.settings)
            key["coverage"] = {"level_samples": core.LEVEL_SAMPLES, "judged": "last"}
            keys[person.name] = key
        return keys

    def recorded(self, settings: CoverageSettings, *, quick: bool) -> dict:
        return settings.as_dict()

    def run(
        self, settings: CoverageSettings, executor: Executor, progress, cache: Caches | None
    ) -> CoverageResult:
        return run(settings, executor, progress, cache)

    def write(self, settings: CoverageSettings, result: CoverageResult, folder: Path) -> dict:
        return write(settings, result, folder)

    def lines(self, settings: CoverageSettings, result: CoverageResult) -> list[str]:
        out = []
        summary = summarize(settings, result.rows)
        for person in settings.people:
            for learner, entry in summary[person.key].items():
                c50, c90 = entry["coverage_50"]["share"], entry["coverage_90"]["share"]
                out.append(f"{person.name}, {learner}: coverage 50%: {c50:.2f}, 90%: {c90:.2f}")
        return out


register(CoverageFigure())
