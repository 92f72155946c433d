"""Simulation-based calibration as a command: is a learner's posterior what it says?

    python -m corrections_sim.run sbc            # results/sbc/ (200 people, fig. 4's settings)
    python -m corrections_sim.run sbc --quick    # 4 people on a 7-point atlas (CI's size)

The study file ``experiments/sbc.toml`` gives fig. 4's settings and the learners judged
(KF-C, KF-CL and the recommended robot, EX-M); ``runs`` is how many people are drawn from
EX-M's prior. The computation is :mod:`corrections_sim.study.sbc`'s; here are the command
(resumable per person drawn), its files and its figure:

* ``draws.csv``: one row per person, learner and t (the person drawn, each weight's rank, the
  highest-density level of θ*, NEES, error, and for EX-M p(the person's own model));
* ``summary.json``: per learner and t, each weight's χ² p-value (``chi2_p``), the coverage of
  the 50% and 90% highest-density regions, and the same test per correction model;
* ``sbc.png``: the ranks' histograms, with the band a uniform histogram stays in.

An exact learner's draws come from the density its integrals use, multilinear in every leaf
cell (:mod:`corrections_sim.learning.exact.draws`): their variance exceeds the learner's
trapezoid moments (``spread = "nodes"``) by the cells' own spread, h²/6 along an axis of cells
of width h on a uniform grid (5–7% of the variance at one node an sd, measured in
``tests/test_sbc.py``), a little toward too many middle ranks; with ``spread = "cells"`` the
learner's P is theirs (:func:`~corrections_sim.learning.exact.cells.cell_moments`).
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Mapping
from concurrent.futures import Executor, Future, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from corrections_sim.figures.presets import EXPERIMENTS_DIR
from corrections_sim.figures.registry import Caches, register
from corrections_sim.plans import spread
from corrections_sim.study import loop, runner, schema
from corrections_sim.study import sbc as core
from corrections_sim.study.settings import FigureSettings

FIGURE = "sbc"


@dataclass(frozen=True)
class SBCResult:
    """Every person's rows (person by person) and how many people were resumed from the
    cache rather than run."""

    rows: list[dict]
    resumed: int


@dataclass(frozen=True)
class SBCSettings:
    """The study's settings (``experiments/sbc.toml``: fig. 4's, ``runs`` people drawn) and
    the preset they were read with."""

    base: FigureSettings
    preset: str

    @property
    def draws(self) -> int:
        return self.base.study.runs

    def as_dict(self) -> dict:
        return {
            "study": self.base.as_dict(),
            "robot": core.ROBOT,
            "at": list(core.AT),
            "samples": core.SAMPLES,
            "bins": core.BINS,
            "level_samples": core.LEVEL_SAMPLES,
        }


def load_settings(*, quick: bool, overrides: Mapping[str, Any]) -> SBCSettings:
    """``experiments/sbc.toml`` with command-line overrides; a study SBC cannot judge is
    refused in one line (:func:`~corrections_sim.study.sbc.check`)."""
    path = EXPERIMENTS_DIR / "sbc.toml"
    base = schema.load_study(path, name=FIGURE, quick=quick, overrides=dict(overrides))
    core.check(base)
    return SBCSettings(base, "quick" if quick else "paper")


def run(
    settings: SBCSettings,
    executor: Executor,
    progress: Callable[[int, int], None] | None = None,
    cache=None,
) -> SBCResult:
    """Every person on ``executor`` (the study's atlas built first), resumed from ``cache``
    (a person's rows kept as a run's records, under the name ``sbc``)."""
    base = settings.base
    results: dict[int, list[dict]] = {}
    if cache is not None:
        found = cache.load_all().items()
        results.update((d, list(kept.records)) for (name, d), kept in found if name == FIGURE)
    phase = getattr(progress, "phase", None)
    atlas_progress = phase("atlas", "environment") if phase else None
    handed = spread.ready(base.atlas_spec(), base.envs(), executor, atlas_progress)
    extra = {} if handed is None else {"handed": handed}
    wanted = range(settings.draws)
    done = resumed = sum(d in results for d in wanted)
    if progress:
        progress(done, settings.draws)
    futures: dict[Future, int] = {
        executor.submit(core.sbc_draw, base, d, **extra): d for d in wanted if d not in results
    }
    for fut in as_completed(futures):
        d = futures[fut]
        results[d] = fut.result()
        if cache is not None:
            kept = loop.RunResult(records=tuple(results[d]), gains=np.zeros(0), solves=0)
            cache.save(FIGURE, d, kept)
        done += 1
        if progress:
            progress(done, settings.draws)
    return SBCResult([row for d in wanted for row in results[d]], resumed)


def summary_of(settings: SBCSettings, rows: list[dict]) -> dict:
    study = settings.base.study
    return core.summarize(list(study.learners), study.k, rows)


def write(settings: SBCSettings, result: SBCResult, folder: Path) -> dict:
    """``draws.csv``, ``sbc.png``; the summary's fields."""
    rows = result.rows
    folder.mkdir(parents=True, exist_ok=True)
    columns: list[str] = []
    for row in rows:
        columns += [c for c in row if c not in columns]
    with open(folder / "draws.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    summary = summary_of(settings, rows)
    plot(settings, summary, folder / "sbc.png")
    return {"draws": settings.draws, "resumed_runs": result.resumed, "sbc": summary}


def plot(settings: SBCSettings, summary: dict, path: Path) -> Path:
    """The ranks' histograms: a row a learner, a column a weight and t; grey, the band a
    uniform histogram of as many people stays in (99% a bin), and its mean."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy import stats

    from corrections_sim.figures import style

    learners = list(summary)
    k = settings.base.study.k
    names = settings.base.features
    panels = [(t, i) for t in core.AT for i in range(k)]
    fig, axes = plt.subplots(
        len(learners), len(panels), figsize=(3.1 * len(panels), 2.3 * len(learners) + 0.8),
        squeeze=False, sharex=True, sharey=True,
    )  # fmt: skip
    edges = np.arange(core.BINS + 1) * (core.SAMPLES + 1) // core.BINS
    for row, learner in enumerate(learners):
        colour = style.learner_style(learner)[0]
        for col, (t, i) in enumerate(panels):
            ax = axes[row][col]
            entry = summary[learner][str(t)]
            counts = np.array(entry[f"weight_{i}"]["counts"])
            n = int(counts.sum())
            if n:
                lo, hi = stats.binom.ppf([0.005, 0.995], n, 1.0 / core.BINS)
                ax.axhspan(lo, hi, color="0.88", zorder=0)
                ax.axhline(n / core.BINS, color="0.55", lw=0.8, zorder=1)
            ax.bar(edges[:-1], counts, width=np.diff(edges), align="edge", color=colour,
                   alpha=0.85, edgecolor="white", zorder=2)  # fmt: skip
            p = entry[f"weight_{i}"]["chi2_p"]
            ax.set_title(f"{learner}: θ {names[i]}, t = {t}; χ² p = {p:.2g}", fontsize=9)
            if col == 0:
                ax.set_ylabel("people")
            if row == len(learners) - 1:
                ax.set_xlabel(f"rank of θ* among {core.SAMPLES} draws")
    fig.suptitle(
        f"Simulation-based calibration: {settings.draws} people drawn from {core.ROBOT}'s prior. "
        "Calibrated: flat, within the grey band (99% a bin);\n"
        "a ∪ shape: over-confident; a ∩ shape: under-confident; a slope: biased",
        fontsize=10,
    )
    style.save_and_close(fig, [path], dpi=110, rect=(0, 0, 1, 0.95))
    return path


class SBCFigure:
    """Simulation-based calibration as a registered figure; resumable per person drawn."""

    name = FIGURE
    help = "simulation-based calibration: people drawn from the recommended robot's prior"
    options = ("set", "runs", "seed", "learners")
    unit = "draw"
    in_all = False
    option_help: ClassVar[dict[str, str]] = {"runs": "how many people to draw (default 200)"}

    def load(self, *, quick: bool, overrides: Mapping[str, Any]) -> SBCSettings:
        return load_settings(quick=quick, overrides=overrides)

    def folder(self, settings: SBCSettings) -> str:
        return FIGURE

    def cache_keys(self, settings: SBCSettings) -> dict[str, dict]:
        key = runner.run_key(settings.base)
        key["sbc"] = {k: v for k, v in settings.as_dict().items() if k != "study"}
        key["learners"] = list(settings.base.study.learners)
        return {"": key}

    def recorded(self, settings: SBCSettings, *, quick: bool) -> dict:
        return settings.as_dict()

    def run(
        self, settings: SBCSettings, executor: Executor, progress, cache: Caches | None
    ) -> SBCResult:
        return run(settings, executor, progress, (cache or {}).get(""))

    def write(self, settings: SBCSettings, result: SBCResult, folder: Path) -> dict:
        return write(settings, result, folder)

    def lines(self, settings: SBCSettings, result: SBCResult) -> list[str]:
        out = []
        for learner, by_t in summary_of(settings, result.rows).items():
            for t, entry in by_t.items():
                k = settings.base.study.k
                ps = ", ".join(f"{entry[f'weight_{i}']['chi2_p']:.3g}" for i in range(k))
                cover = ", ".join(
                    f"{round(100 * a)}%: {entry[f'coverage_{round(100 * a)}']['share']:.2f}"
                    for a in core.COVERAGE
                )
                out.append(f"{learner} t = {t}: chi2 p {ps}; coverage {cover}")
        return out


register(SBCFigure())
