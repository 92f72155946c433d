"""Physical corrections (beyond the paper): learners under a person who pushes the moving arm.

The columns of ``experiments/physical.toml`` are users, as in fig. 6 (the same machinery,
:mod:`corrections_sim.figures.robustness`): the paper's kinematic biased user, and the
simulated physical person (:mod:`corrections_sim.people.physical`) who pushes the cup while the
arm runs under impedance control in MuJoCo, with online learning (the robot learns when the
push ends and replans the rest of the motion). Every physical task also plays the motion the
robot would have made had it kept its plan after the push, from the same state, so "online"
and "after the motion" are compared paired on the same pushes; θ̂, and so error and regret,
are the same either way (the push is the same and the learner gets it once).

Files: ``matrix.csv`` (fig. 6's columns, plus executed regret, effort and sensing error per
learner and user), ``curves.csv``, ``paired.csv`` (paired 95% intervals: final error of every
learner pair per user; executed regret online − kept per learner), the plot, and
``push.png``: one push drawn (the first correction of the physical column in its first
environment: the plans, the push's force, the executed motion, the deformation and the new
plan).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim.figures import robustness
from corrections_sim.figures.registry import register
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import shared_planner
from corrections_sim.study import analysis
from corrections_sim.study.runner import FigureResult

FIGURE = "physical"
#: Per-task columns of a physical user's records, averaged over a run's corrections.
TASK_COLUMNS = ("executed_regret", "executed_regret_kept", "effort", "push_time", "sense_error")


def _task_values(records: Sequence[dict], learner: str, key: str) -> np.ndarray:
    """(runs, iterations) of a per-task column of ``learner`` (NaN where absent)."""
    rows = [r for r in records if r["learner"] == learner and r["iteration"] > 0]
    runs = sorted({r["run"] for r in rows})
    return np.array(
        [[analysis._number(r.get(key)) for r in rows if r["run"] == run] for run in runs],
        dtype=float,
    )


def matrix(settings, results: Sequence[FigureResult]) -> list[dict]:
    """Fig. 6's rows (final error, regret, calibration) with the tasks' means: executed regret
    (online and kept) per correction, effort (N·s), push time (s), sensing error (relative RMS
    of τ_h against Jᵀ F), each the mean over runs of the mean over a run's corrections."""
    rows = robustness.matrix(settings, results)
    by_user = {c.label: r for c, r in zip(settings.columns, results, strict=True)}
    for row in rows:
        records = by_user[row["user"]].records
        for key in TASK_COLUMNS:
            values = _task_values(records, row["learner"], key)
            finite = values[np.isfinite(values)] if values.size else values
            row[f"{key}_mean"] = float(np.mean(np.nanmean(values, axis=1))) if finite.size else None
    return rows


def paired(settings, results: Sequence[FigureResult]) -> list[dict]:
    """Paired 95% t-intervals: for every user, final estimate error a − b of every learner pair
    that shares runs; for a physical online user, executed regret online − kept per learner
    (per task, all runs and corrections)."""
    out = []
    for column, result in zip(settings.columns, results, strict=True):
        data = analysis.curves(column.settings, result.records)
        for entry in analysis.paired_differences(column.settings, data):
            if entry["metric"] == "estimate_error":
                out.append(
                    {
                        "user": column.label,
                        "a": entry["a"],
                        "b": entry["b"],
                        "metric": "final estimate_error",
                        **entry["final"],
                    }
                )
        for learner in column.settings.study.learners:
            online = _task_values(result.records, learner, "executed_regret")
            kept = _task_values(result.records, learner, "executed_regret_kept")
            if kept.size == 0 or not np.isfinite(kept).any():
                continue
            diff = (online - kept)[np.isfinite(online - kept)]
            if diff.size > 1:
                out.append(
                    {
                        "user": column.label,
                        "a": f"{learner} online",
                        "b": f"{learner} kept",
                        "metric": "executed_regret per task",
                        **analysis._mean_ci(diff),
                    }
                )
    return out


@dataclass(frozen=True)
class PhysicalResult:
    """Every column's result, and one push drawn in ``push.png`` (see :func:`example`)."""

    columns: list[FigureResult]
    example: dict


def example(settings) -> dict:
    """One push, as the physical column's first correction goes in the study's first
    environment: the robot's plan at θ̂⁰, the person's at θ*, the push of the column's user, the
    update of its learner told how people push (model ``physical``; else one with a covariance)
    and, online, its new plan; cup paths (n, 3) and the force (n, 3) at the person's rate."""
    from corrections_sim.learning.base import LEARNERS, LearnerContext
    from corrections_sim.people.physical import PhysicalCorrection
    from corrections_sim.people.users import Situation
    from corrections_sim.planning.plans import PlanBook
    from corrections_sim.scene import dynamics

    column = next(c for c in settings.columns if c.settings.study.user.during_motion)
    figure = column.settings
    study = figure.study
    planner = shared_planner(figure.planner_config())
    env = figure.envs()[0]
    # The learner told how people push, if one is; else one with a covariance; else the first.
    names = sorted(
        study.learners,
        key=lambda n: (
            not isinstance(getattr(study.learners[n], "model", None), PhysicalCorrection),
            not LEARNERS[n].has_covariance,
        ),
    )
    agent = study.learners[names[0]]
    book = PlanBook(planner, warm_start=study.warm_start)
    belief = agent.initial(study.prior(), study.noise())
    mine = book.plan(belief.theta, env)
    person = figure.person_target([env])
    star = person.plans[0]
    rng = np.random.default_rng(study.seed)
    ctx = LearnerContext(
        book=book,
        envs=figure.envs(),
        features=figure.features,
        n_waypoints=planner.config.n_waypoints,
        alphas=None,
        rng=rng,
        noise=study.noise(),
        sigma=study.sigma(),
    )
    learnt = []

    def replan(deformed, q_now, t_now):
        phi = feature_counts(deformed, env, figure.features)
        learnt.append(agent.update(ctx, belief, env, mine, phi).belief)
        return book.plan(learnt[0].theta, env).trajectory if study.online else None

    situation = Situation(mine.trajectory, star.trajectory, env, figure.features, person.theta_star)
    outcome = study.user.perform(situation, rng, replan)
    cup = lambda q: dynamics.cup_kinematics(q)[0]  # noqa: E731
    dense = lambda traj: dynamics.TimedTrajectory(traj, outcome.trace.times[-1]).at(  # noqa: E731
        np.linspace(0.0, outcome.trace.times[-1], 120)
    )[0]
    return {
        "environment": env.name,
        "learner": names[0],
        "plan": cup(dense(mine.trajectory)),
        "person": cup(dense(star.trajectory)),
        "deformed": cup(dense(outcome.deformed)),
        "new_plan": cup(dense(book.plan(learnt[0].theta, env).trajectory)) if learnt else None,
        "executed": outcome.trace.cup,
        "force": outcome.trace.force,
        "theta": [study.theta0, None if not learnt else learnt[0].theta.tolist()],
        "effort": outcome.extras["effort"],
        "sense_error": outcome.extras["sense_error"],
    }


def write(settings, result: PhysicalResult, folder: Path) -> dict:
    """matrix.csv, curves.csv, paired.csv, the plot and push.png in ``folder``; the summary's
    fields."""
    from corrections_sim.figures.plotting import plot_physical, plot_push

    results = result.columns
    plot_push(result.example, [folder / "push.png"])

    rows = matrix(settings, results)
    pairs = paired(settings, results)
    summary = robustness.write_matrix(settings, results, rows, folder, pairs)
    first = settings.columns[0].settings
    title = robustness.title(settings, "physical corrections")
    curves = {
        c.label: analysis.curves(c.settings, r.records)
        for c, r in zip(settings.columns, results, strict=True)
    }
    tasks = {
        c.label: {
            learner: {key: _task_values(r.records, learner, key) for key in TASK_COLUMNS}
            for learner in c.settings.study.learners
        }
        for c, r in zip(settings.columns, results, strict=True)
    }
    plot_physical(
        curves, tasks, first.study.k, title, [folder / f"{FIGURE}.png", folder / f"{FIGURE}.pdf"]
    )
    return summary | {
        "example_push": {
            k: result.example[k]
            for k in ("environment", "learner", "theta", "effort", "sense_error")
        },
    }


@dataclass(frozen=True)
class PhysicalFigure(robustness.RobustnessFigure):
    """The physical-corrections study as a registered figure: fig. 6's columns and caches,
    its own file, files and plot."""

    name: str = FIGURE
    help: str = "beyond the paper: a person pushes the moving arm; learners, online replanning"
    in_all: bool = False

    def load(self, *, quick: bool, overrides: Mapping[str, Any]):
        return robustness.load_settings(quick=quick, overrides=dict(overrides), figure=FIGURE)

    def run(self, settings, executor, progress, cache) -> PhysicalResult:
        columns = super().run(settings, executor, progress, cache)
        return PhysicalResult(columns=columns, example=example(settings))

    def write(self, settings, result: PhysicalResult, folder: Path) -> dict:
        return write(settings, result, folder)


register(PhysicalFigure())
