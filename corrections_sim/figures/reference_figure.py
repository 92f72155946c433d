"""``reference`` as a registered figure: the exact reference of a finished figure's runs
(:mod:`corrections_sim.figures.reference`) on the command line's executor, resumable run by
run, written to a folder of its own inside the figure's, ``<figure>/reference-<learner>/``:

    python -m corrections_sim.run reference results/quick/fig4 --learner KF-C --runs 2

``records.csv`` (per run and iteration, see :func:`~.reference.reference_run`) and
``summary.json`` (the settings, the last iteration's summary with 95% intervals over runs and
every iteration's, under ``by_iteration``; the halved grid's check with ``--check-grid``). An
earlier reference of other settings there is replaced only with ``--force``.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping
from concurrent.futures import Executor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim.defaults import DEFAULTS
from corrections_sim.figures import reference as judge
from corrections_sim.figures.registry import Caches, register
from corrections_sim.learning.exact.bayes import Grid
from corrections_sim.study.loop import RunResult
from corrections_sim.study.settings import FigureSettings


@dataclass(frozen=True)
class ReferenceJob:
    """The exact reference of some runs of a learner in a finished figure, ready to run one
    run at a time (:func:`judge_run`, in any process) and to summarize (:func:`judged`).

    Attributes:
        figure: the finished figure's name (its ``summary.json``'s).
        settings: its settings.
        learner: whose runs.
        rows: the recorded rows of each run judged (``curves.csv``), by run.
        grid: the reference's grid (None beyond k = 2: the particles are the reference).
        options: :func:`~.reference.reference_run`'s keyword options (``seed`` is the first run's).
        check_grid: whether the first run is judged again on the halved grid.
    """

    figure: str
    settings: FigureSettings
    learner: str
    rows: dict[int, list[dict]]
    grid: Grid | None
    options: dict
    check_grid: bool = False


def reference_job(
    folder: Path,
    learner: str,
    *,
    runs: int = 2,
    points: int | None = None,
    restarts: tuple[int, ...] = (),
    particles: int = 0,
    seed: int = 0,
    one_step: bool = False,
    resolution: float | None = None,
    axes: str | None = None,
    check_grid: bool = False,
) -> ReferenceJob:
    """The reference of the first ``runs`` runs of ``learner`` in the finished figure in
    ``folder`` (its ``summary.json`` and ``curves.csv``), checked before anything is solved:
    see :func:`~.reference.reference_run` for the options.

    Raises:
        ValueError: one line, naming what does not fit (a learner not in the figure, an
            option the learner's model or k cannot take).
    """
    from corrections_sim.study import schema

    summary = json.loads((folder / "summary.json").read_text())
    figure = summary.get("figure", "")
    settings = schema.parse_study(summary["settings"], name=figure)
    if learner not in settings.study.learners:
        known = ", ".join(settings.study.learners)
        raise ValueError(f"--learner {learner}: not in this figure ({known})")
    recorded = judge.recorded_runs(folder, learner)
    if any(s < 0 for s in restarts):
        raise ValueError(f"--restart {','.join(map(str, restarts))}: iterations are >= 0")
    if check_grid and settings.study.k != 2:
        raise ValueError(
            f"--check-grid: only at k = 2, not {settings.study.k} (beyond it the halved grid's "
            "plan atlas would be built in full)"
        )
    grid = judge.reference_grid(settings, points)
    options = {
        "one_step": one_step,
        "restarts": tuple(restarts),
        "particles": particles,
        "seed": seed,
        "resolution": resolution,
    }
    if axes is not None:  # named only when given: earlier references' settings stay as they were
        options["axes"] = axes
    judge.check_reference(
        settings, learner, grid, particles=particles, one_step=one_step, restarts=restarts,
        resolution=resolution, axes=axes,
    )  # fmt: skip
    rows = {run: recorded[run] for run in sorted(recorded)[:runs]}
    return ReferenceJob(figure, settings, learner, rows, grid, options, check_grid)


def judge_run(job: ReferenceJob, run: int, exchange=None, handed=None) -> list[dict]:
    """The records of ``job``'s run ``run`` (safe in a worker process): the plans it solved
    between the atlas's nodes and the particles' checked cells are kept for the next, and
    with the command's ``exchange`` (:class:`~corrections_sim.plans.spread.PlanExchange`)
    plans between nodes pass between its workers as a study's runs pass them; ``handed``: the
    study's atlases, to a worker that may not share the command's files (a cluster's)."""
    from corrections_sim.planning.planner import shared_planner
    from corrections_sim.plans import interpolation, spread

    settings = job.settings
    spec = settings.atlas_spec()
    if handed is not None:
        spread.receive(spec, handed)
    spread.attach(spec, exchange)
    planner = shared_planner(settings.planner_config())
    options = {**job.options, "seed": job.options["seed"] + run}
    records = judge.reference_run(
        settings, job.learner, job.rows[run], job.grid, planner, **options
    )
    if settings.atlas() is not None:  # the plans solved between nodes, kept
        if exchange is not None and spec is not None:
            spread.flush(spec)
        settings.atlas().save()
        interpolation.save_kept()  # and the particles' checked cells
    return records


def grid_check(job: ReferenceJob, first: list[dict], handed=None) -> tuple[int, int, float, float]:
    """How much the first run's reference (its records ``first``) moves on the halved grid:
    points per axis before and after, the largest move of a mean in its sd and of a
    variance, relative; ``handed`` as :func:`judge_run`'s."""
    from corrections_sim.planning.planner import shared_planner
    from corrections_sim.plans import spread

    settings, fine = job.settings, job.grid.halved()
    if handed is not None:
        spread.receive(settings.atlas_spec(), handed)
    planner = shared_planner(settings.planner_config())
    rows = job.rows[min(job.rows)]
    finer = judge.reference_run(
        settings,
        job.learner,
        rows,
        fine,
        planner,
        resolution=job.options["resolution"],
        axes=job.options.get("axes"),
    )
    pairs = list(zip(first, finer, strict=True))
    k = settings.study.k
    worst_mean = max(
        abs(a[f"ref_theta_{i}"] - b[f"ref_theta_{i}"]) / np.sqrt(b[f"ref_cov_{i}{i}"])
        for a, b in pairs
        for i in range(k)
    )
    worst_cov = max(
        abs(a[f"ref_cov_{i}{i}"] - b[f"ref_cov_{i}{i}"]) / b[f"ref_cov_{i}{i}"]
        for a, b in pairs
        for i in range(k)
    )
    return job.grid.points, fine.points, worst_mean, worst_cov


def judged(job: ReferenceJob, by_run: dict[int, list[dict]], moved=None) -> judge.Judged:
    """What ``job`` found, from every run's records ``by_run`` (in run order)."""
    records = [r for run in sorted(by_run) for r in by_run[run]]
    by_t = [judge.summary_at(records, t) for t in sorted({r["iteration"] for r in records})]
    return judge.Judged(job.learner, records, by_t, moved)


@dataclass(frozen=True)
class ReferenceSettings:
    """A reference's settings: the finished figure's folder ``source`` and the job read from
    it (:class:`~.reference.ReferenceJob`), with ``preset`` the figure's."""

    source: Path
    preset: str
    job: ReferenceJob

    def as_dict(self) -> dict:
        job = self.job
        return {
            "figure": job.figure,
            "learner": job.learner,
            "runs": sorted(job.rows),
            "points": None if job.grid is None else job.grid.points,
            **{k: list(v) if isinstance(v, tuple) else v for k, v in job.options.items()},
            "check_grid": job.check_grid,
        }


class ReferenceFigure:
    """The registered figure ``reference`` (module docstring)."""

    name = "reference"
    help = "the exact posterior beside a learner's Gaussian, for a finished figure's runs"
    options = (
        "study_file",
        "learner",
        "runs",
        "points",
        "resolution",
        "axes",
        "one_step",
        "restart",
        "particles",
        "seed",
        "check_grid",
    )
    unit = "run"
    in_all = False
    file = "DIR"
    option_help = {
        "study_file": "a finished learning figure's folder (curves.csv, summary.json)",
        "learner": f"whose runs to judge (default {DEFAULTS['reference'][0]})",
        "runs": "how many runs (the first N; default 2)",
        "seed": "the particle reference's seed (default 0; run r uses seed + r)",
        "out": "where reference-<learner>/ goes (default: the figure's folder)",
    }

    def load(self, *, quick: bool, overrides: Mapping[str, Any]) -> ReferenceSettings:
        if quick:
            raise ValueError("--quick: a reference takes its preset from the figure's folder")
        given = overrides.get("study_file")
        if not given:
            raise ValueError("reference: give a finished figure's folder, e.g. results/quick/fig4")
        source = Path(given)
        if not (source / "summary.json").is_file() or not (source / "curves.csv").is_file():
            raise ValueError(f"{source}: not a finished learning figure's folder (no summary.json)")
        restart = overrides.get("restart") or ""
        try:
            restarts = tuple(sorted({int(v) for v in restart.split(",") if v.strip()}))
        except ValueError:
            raise ValueError(f"--restart {restart}: expected iterations like 0,1,4") from None
        try:
            job = reference_job(
                source,
                overrides.get("learner") or DEFAULTS["reference"][0],
                runs=overrides.get("runs", 2),
                points=overrides.get("points"),
                restarts=restarts,
                particles=overrides.get("particles") or 0,
                seed=overrides.get("seed") or 0,
                one_step=bool(overrides.get("one_step")),
                resolution=overrides.get("resolution"),
                axes=overrides.get("axes"),
                check_grid=bool(overrides.get("check_grid")),
            )
            preset = json.loads((source / "summary.json").read_text()).get("preset", "paper")
        except (OSError, KeyError) as exc:
            raise ValueError(f"{source}: {exc}") from None
        return ReferenceSettings(source, preset, job)

    def default_out(self, settings: ReferenceSettings) -> Path:
        """Where its folder goes without ``--out``: inside the figure's."""
        return settings.source

    def folder(self, settings: ReferenceSettings) -> str:
        return f"reference-{settings.job.learner}"

    def cache_keys(self, settings: ReferenceSettings) -> dict[str, dict]:
        # A run's reference depends on the figure's settings and the learner's recorded rows
        # (the code's fingerprint is added by the command line).
        job = settings.job
        rows = hashlib.sha256(json.dumps(job.rows, sort_keys=True).encode()).hexdigest()
        recorded = {k: v for k, v in settings.as_dict().items() if k not in ("runs", "check_grid")}
        return {"": {**recorded, "settings": job.settings.as_dict(), "rows": rows}}

    def recorded(self, settings: ReferenceSettings, *, quick: bool) -> dict:
        return settings.as_dict()

    def run(
        self,
        settings: ReferenceSettings,
        executor: Executor,
        progress: Callable[[int, int], None] | None,
        cache: Caches | None,
    ) -> judge.Judged:
        job = settings.job
        store = (cache or {}).get("")
        by_run: dict[int, list[dict]] = {}
        if store is not None:
            found = store.load_all()
            by_run = {
                r: list(found[(job.learner, r)].records)
                for r in job.rows
                if (job.learner, r) in found
            }
        total, done = len(job.rows), len(by_run)
        if progress:
            progress(done, total)
        from corrections_sim.plans import spread

        spec = job.settings.atlas_spec()
        todo = [run for run in job.rows if run not in by_run]
        # The atlases built first, one task an environment (else each run builds what it
        # meets, two workers the same at once); a cluster's workers are handed them.
        needs_atlas = todo or job.check_grid
        handed = spread.ready(spec, job.settings.envs(), executor) if needs_atlas else None
        exchange = spread.exchange_for(spec, executor)  # plans between nodes, shared
        futures = {executor.submit(judge_run, job, run, exchange, handed): run for run in todo}
        for future in as_completed(futures):
            run = futures[future]
            by_run[run] = future.result()
            if store is not None:
                store.save(job.learner, run, RunResult(tuple(by_run[run]), np.zeros((0,)), 0))
            done += 1
            if progress:
                progress(done, total)
        if exchange is not None:  # this machine keeps what a cluster solved between nodes
            spread.keep_all(spec, exchange)
        moved = None
        if job.check_grid:
            first = min(by_run)
            moved = executor.submit(grid_check, job, by_run[first], handed).result()
        return judged(job, by_run, moved)

    def write(self, settings: ReferenceSettings, result: judge.Judged, folder: Path) -> dict:
        """``records.csv``; the summary's fields: the learner, the final iteration's summary,
        every iteration's and the halved grid's check."""
        from corrections_sim.figures.output import write_records

        write_records(folder / "records.csv", result.records)
        fields = {"learner": result.learner, **result.by_iteration[-1]}
        fields["by_iteration"] = result.by_iteration
        if result.grid_check is not None:
            points, finer, mean, var = result.grid_check
            fields["grid_check"] = {
                "points": points,
                "finer": finer,
                "mean_moved_sd": mean,
                "variance_moved": var,
            }
        return fields

    def lines(self, settings: ReferenceSettings, result: judge.Judged) -> list[str]:
        """The table of its means over runs, printed after the files are written."""
        return judge.report_lines(result, settings.job.options["particles"])


register(ReferenceFigure())
