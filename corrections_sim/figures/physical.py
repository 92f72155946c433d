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
    from corrections_sim.learning import correction
    from corrections_sim.learning.base import LEARNERS
    from corrections_sim.people.physical import PhysicalCorrection
    from corrections_sim.people.users import Situation
    from corrections_sim.plans.book import PlanBook
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
            not isinstance(study.learners[n].assumed_correction(), PhysicalCorrection),
            not LEARNERS[n].has_covariance,
        ),
    )
    agent = study.learners[names[0]]
    # Planned as the study's runs plan: from its atlas when it has one (an exact learner needs it).
    book = PlanBook(planner, warm_start=study.warm_start, atlas=figure.atlas())
    belief = agent.initial(study.prior(), study.noise())
    mine = book.plan(belief.theta, env)
    person = figure.person_target([env])
    star = person.plans[0]
    rng = np.random.default_rng(study.seed)
    ctx = correction.context(
        belief,
        study.noise(),
        book=book,
        envs=figure.envs(),
        features=figure.features,
        n_waypoints=planner.config.n_waypoints,
        alphas=None,
        rng=rng,
        sigma=study.sigma(),
    )
    learnt = []

    def replan(deformed, q_now, t_now):
        phi = feature_counts(deformed, env, figure.features)
        learnt.append(correction.step(agent, ctx, belief, env, mine, phi).belief)
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


def plot_physical(curves: dict, tasks: dict, k: int, title: str, paths) -> None:
    """The physical-corrections figure: estimate error and regret against corrections per
    learner (solid: the physical person, dashed: the other columns' users), the regret of
    the motion the person got with online replanning minus with the plan kept after the same
    push, per correction, and the mean NEES (log, calibrated band shaded).

    Args:
        curves: user label -> ``analysis.curves`` (learner -> metric -> (runs, T + 1)).
        tasks: user label -> learner -> per-task column -> (runs, T).
        k: θ's dimension (NEES's calibrated mean).
    """
    from matplotlib.lines import Line2D

    from corrections_sim.calibration import mean_band
    from corrections_sim.figures.style import learner_label, learner_style, plt, save_and_close
    from corrections_sim.metrics import mean_sem

    users = list(curves)
    physical = [
        u
        for u in users
        if any(
            np.isfinite(v["executed_regret"]).any()
            for v in tasks[u].values()
            if v["executed_regret"].size
        )
    ]
    learners = list(dict.fromkeys(n for u in users for n in curves[u]))
    # One colour per learner (learner_style gives KF-C KF's colour, dashed; here dashes mark
    # the user); a learner drawn in black by its own style (the recommended robot) keeps it.
    free = iter(plt.cm.tab10(i) for i in range(10))
    palette = {
        n: "#000000" if learner_style(n)[0] == "#000000" else next(free, "0.5") for n in learners
    }
    fig, axes = plt.subplots(2, 2, figsize=(13, 9.4))
    panels = (
        (axes[0, 0], "estimate_error", "estimate error ‖θ̂ − θ*‖₁"),
        (axes[0, 1], "regret", "regret of the next plans, Σ over environments"),
    )
    for ax, key, label in panels:
        for user in users:
            dashes = "-" if user in physical else "--"
            for learner, values in curves[user].items():
                colour = palette[learner]
                mean, sem = mean_sem(values[key])
                x = np.arange(mean.size)
                ax.plot(x, mean, dashes, color=colour, lw=1.8)
                ax.fill_between(x, mean - sem, mean + sem, color=colour, alpha=0.15, lw=0)
        ax.set_xlabel("corrections")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
    ax = axes[1, 0]
    for user in physical:
        for learner, columns in tasks[user].items():
            online, kept = columns["executed_regret"], columns["executed_regret_kept"]
            if kept.size == 0 or not np.isfinite(kept).any():
                continue
            mean, sem = mean_sem(online - kept)
            x = np.arange(1, mean.size + 1)
            colour = palette[learner]
            ax.plot(x, mean, "-o", color=colour, lw=1.8, ms=3)
            ax.fill_between(x, mean - sem, mean + sem, color=colour, alpha=0.15, lw=0)
    ax.axhline(0.0, color="0.3", lw=1)
    ax.set_xlabel("correction (task)")
    ax.set_title(
        "regret of the motion the person got, a task: online replanning − plan kept\n"
        "(the same push; below 0: replanning helps)",
        fontsize=10,
    )
    ax.grid(alpha=0.3)
    ax = axes[1, 1]
    for user in users:
        dashes = "-" if user in physical else "--"
        for learner, values in curves[user].items():
            nees = values["nees"]
            if not np.isfinite(nees).any():
                continue
            colour = palette[learner]
            mean = np.nanmean(nees, axis=0)
            ax.plot(np.arange(mean.size), mean, dashes, color=colour, lw=1.8)
        runs = next(iter(curves[user].values()))["nees"].shape[0]
    low, high = mean_band(k, runs)
    band = ax.axhspan(low, high, color="0.6", alpha=0.25, lw=0)
    ax.set_yscale("log")
    ax.set_xlabel("corrections")
    ax.set_title(
        "mean NEES (log): calibrated inside the grey band,\nover-confident above it, "
        "under-confident below",
        fontsize=10,
    )
    ax.grid(alpha=0.3)
    # One legend for the figure, below the panels: colours are learners, dashes are people.
    handles = [Line2D([], [], color=palette[n], lw=2.2) for n in learners]
    labels = [learner_label(n) for n in learners]
    for user in users:
        handles.append(Line2D([], [], color="0.3", lw=1.8, ls="-" if user in physical else "--"))
        labels.append(f"{'solid' if user in physical else 'dashed'}: {user}")
    handles.append(band)
    labels.append(f"calibrated band of the mean NEES (95%, {runs} runs)")
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(title, fontsize=11)
    save_and_close(fig, paths, dpi=110, rect=(0, 0.07, 1, 1))


def plot_push(example: dict, paths) -> None:
    """One push seen from above and from the side: the robot's plan (blue), the person's
    (grey, dashed), the executed cup path (orange) with the person's force (red arrows, every
    0.1 s), the deformation ξ_H the robot learnt from (orange, dashed) and its new plan
    (green, dotted)."""
    from corrections_sim.figures.style import plt, save_and_close

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    force = np.asarray(example["force"])
    executed = np.asarray(example["executed"])
    pushing = np.flatnonzero(np.linalg.norm(force, axis=1) > 0)[::10]
    for ax, (i, j), view in zip(
        axes, ((0, 1), (0, 2)), ("from above", "from the side"), strict=True
    ):
        ax.plot(
            *example["person"][:, [i, j]].T,
            "--",
            color="0.45",
            lw=1.6,
            label="the person's plan ξ*(θ*)",
        )
        ax.plot(*example["plan"][:, [i, j]].T, color="tab:blue", lw=2, label="the robot's plan ξ_R")
        ax.plot(
            *executed[:, [i, j]].T, color="tab:orange", lw=2.2, label="executed (with the push)"
        )
        ax.plot(
            *example["deformed"][:, [i, j]].T,
            "--",
            color="tab:orange",
            lw=1.4,
            label="deformation ξ_H (learnt)",
        )
        if example["new_plan"] is not None:
            ax.plot(
                *example["new_plan"][:, [i, j]].T,
                ":",
                color="tab:green",
                lw=2.2,
                label="new plan (online)",
            )
        if pushing.size:
            ax.quiver(
                executed[pushing, i],
                executed[pushing, j],
                force[pushing, i],
                force[pushing, j],
                color="tab:red",
                angles="xy",
                scale_units="xy",
                scale=150,
                width=0.004,
                label="the person's force",
            )
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)" if j == 1 else "z (m)")
        ax.set_title(view, fontsize=10)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="best")
    before, after = (None if t is None else np.round(t, 2).tolist() for t in example["theta"])
    learnt = f" → {after}" if after is not None else ""
    fig.suptitle(
        f"one push in {example['environment']}: {example['learner']} θ̂ {before}{learnt}; "
        f"effort {example['effort']:.1f} N·s, sensing error {100 * example['sense_error']:.1f}%",
        fontsize=10,
    )
    save_and_close(fig, paths, dpi=110)
