r"""Fig. 3: risk-sensitive deployment, eqs. (A2)–(A4), and the exact max-min (A3) beside it.

The robot has learned N(θ̂, P) and deploys without supervision. For each panel's P it forms
Γ (eq. A2, :func:`corrections_sim.planning.risk.preference_set`), solves ξ*(γ, E) for every γ ∈ Γ
and deploys (eq. A4) the risk-averse ξ*(argmin_γ V(γ)), the risk-neutral ξ*(θ̂) and the
risk-seeking ξ*(argmax_γ V(γ)), V(γ) = max_ξ γ·Φ − λS. Beyond the paper it also solves the
exact risk-averse problem (A3), max_ξ min_γ γ·Φ − λS, in one NLP
(:class:`corrections_sim.planning.risk.WorstCasePlanner`), started from the 2k + 1 plans of (A4) and
the planner's own guesses, and compares the two rules' worst-case rewards in the figure's
scene and over the study's 48 environments.

Weak duality bounds the comparison: worst(A4's averse plan) ≤ worst(A3) ≤ min_γ V(γ).
(A4) is exact exactly when its averse plan's worst case is the γ it was planned for; (A3)
gains where the worst case switches between preferences along the way.

Settings are data (``experiments/fig3.toml``); :func:`run` spreads panels and comparison
environments over any ``concurrent.futures`` executor; the records do not depend on it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from corrections_sim.belief import Belief
from corrections_sim.figures import presets
from corrections_sim.figures.presets import PresetFigure, Scene
from corrections_sim.figures.registry import register
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import (
    Planner,
    PlannerConfig,
    PlanningError,
    initial_guesses,
    shared_planner,
    smoothness_cost,
)
from corrections_sim.planning.risk import (
    ATTITUDES,
    A4Plans,
    WorstCasePlan,
    WorstCasePlanner,
    plan_a4,
    refine_a4,
    worst_case_reward,
)
from corrections_sim.scene.environments import Environment, paper_environments
from corrections_sim.study import checks, files

FIGURES = ("fig3",)
#: The trajectories a panel draws, in order: (A4) per attitude, then (A3).
DRAWN = (*ATTITUDES, "A3")


@dataclass(frozen=True)
class Panel:
    """One panel: the covariance P the robot deploys with.

    Attributes:
        name: short label (CSV ``panel`` column).
        title: panel title.
        cov: P, k × k, symmetric positive definite.
    """

    name: str
    title: str
    cov: tuple[tuple[float, ...], ...]


@dataclass(frozen=True)
class DeploymentSettings:
    """Resolved settings of fig. 3.

    Attributes:
        features: the planner's features (k of them).
        theta: θ̂, the learned estimate (k,).
        scene: the environment the panels deploy in.
        panels: the covariances, in panel order.
        comparison_environments: how many of the study's 48 environments (in their order)
            the (A3)-vs-(A4) comparison covers, for every panel's P (0: none).
        n_starts: the planner's initial guesses per solve (also the extra starts of A3).
    """

    features: tuple[str, ...]
    theta: tuple[float, ...]
    scene: Scene
    panels: tuple[Panel, ...]
    comparison_environments: int = 48
    n_starts: int = 3
    figure: str = "fig3"

    @property
    def k(self) -> int:
        return len(self.features)

    def planner_config(self) -> PlannerConfig:
        return PlannerConfig(features=self.features, n_starts=self.n_starts)

    def belief(self, index: int) -> Belief:
        return Belief(theta=np.array(self.theta), cov=np.array(self.panels[index].cov))


def load_settings(
    figure: str = "fig3", *, quick: bool, overrides: dict | None = None
) -> DeploymentSettings:
    """Settings of fig. 3 from ``experiments/fig3.toml``, checked field by field.

    Args:
        figure: "fig3".
        quick: the CI-sized preset instead of the paper-scale one.
        overrides: top-level fields to replace (None values are ignored); there is no
            ``seed``, nothing is random.

    Raises:
        ValueError: a missing, unknown or bad field; the one-line message names it (e.g.
            ``panels[2].cov``, ``theta``).
    """
    values, features, theta = files.load_values(
        presets.EXPERIMENTS_DIR, figure, FIGURES, quick, overrides, "panels"
    )
    k = len(features)
    scene = Scene.parse(values)
    raw_panels = checks.take(values, "panels")
    if not isinstance(raw_panels, list) or not raw_panels:
        raise ValueError("panels: expected at least one [[panels]] table")
    panels = []
    for i, raw in enumerate(raw_panels):
        prefix = f"panels[{i}]."
        raw = dict(raw)
        name = str(checks.take(raw, "name", prefix))
        if not name.isidentifier():
            raise ValueError(f"{prefix}name = {name!r}: expected a short identifier")
        title = str(checks.take(raw, "title", prefix))
        cov = checks.covariance(f"{prefix}cov", checks.take(raw, "cov", prefix), k)
        checks.reject_unknown(raw, f"panels[{i}]")
        panels.append(Panel(name=name, title=title, cov=cov))
    if len({p.name for p in panels}) != len(panels):
        raise ValueError(f"panels: names must be distinct, got {[p.name for p in panels]}")
    optional = {}
    if "comparison_environments" in values:
        optional["comparison_environments"] = checks.integer(
            "comparison_environments",
            values.pop("comparison_environments"),
            low=0,
            high=len(paper_environments()),
        )
    if "n_starts" in values:
        optional["n_starts"] = checks.integer("n_starts", values.pop("n_starts"), low=1, high=3)
    checks.reject_unknown(values)
    return DeploymentSettings(
        features=features, theta=theta, scene=scene, panels=tuple(panels), **optional
    )


# --- computation -----------------------------------------------------------------------------


@functools.cache
def _planners(config: PlannerConfig) -> tuple[Planner, WorstCasePlanner]:
    """The (A4) planner (this process's shared one) and the (A3) planner, built once."""
    return shared_planner(config), WorstCasePlanner(config)


@dataclass(frozen=True, eq=False)
class Deployment:
    """The trajectories one belief deploys in one environment.

    Attributes:
        a4: the (A4) plans with the planner's usual starts (the paper's rule).
        refined: the (A4) plans re-solved from every plan of Γ and the (A3) trajectory
            (:func:`corrections_sim.planning.risk.refine_a4`): the rule without the planner's
            local-optimum noise.
        a3: the exact max-min plan, started from the (A4) plans and the planner's guesses.
    """

    a4: A4Plans
    refined: A4Plans
    a3: WorstCasePlan

    def trajectory(self, rule: str, attitude: str = "averse") -> np.ndarray:
        """Waypoints (T, 7) deployed by ``rule`` ("A4", "A4r" refined, or "A3", which is
        risk-averse only) with ``attitude``."""
        if rule == "A3":
            return self.a3.trajectory
        if rule not in ("A4", "A4r"):
            raise ValueError(f"rule {rule!r}: choose A4, A4r or A3")
        return (self.a4 if rule == "A4" else self.refined).plan(attitude).trajectory


def deploy(settings: DeploymentSettings, belief: Belief, env: Environment) -> Deployment:
    """(A4) for every attitude, (A3), and (A4) refined, for ``belief`` in ``env``.

    Raises:
        PlanningError: a plan of (A4) failed, or no start of (A3) converged.
    """
    planner, worst_case = _planners(settings.planner_config())
    cfg = planner.config
    a4 = plan_a4(planner, belief, env)
    inits = [p.trajectory for p in a4.plans]
    a3 = worst_case.solve(
        a4.gammas, env, inits=inits + initial_guesses(env, cfg.n_waypoints, cfg.n_starts)
    )
    refined = refine_a4(planner, a4, env, [*inits, a3.trajectory])
    return Deployment(a4=a4, refined=refined, a3=a3)


def trajectory_record(
    settings: DeploymentSettings, gammas: np.ndarray, trajectory: np.ndarray, env: Environment
) -> dict:
    """Features and rewards of one deployed trajectory: phi_<name>, smoothness S,
    reward under θ̂ (θ̂·Φ − λS), worst and best case over Γ, and the rows of Γ at the worst."""
    lam = settings.planner_config().smoothness
    phi = feature_counts(trajectory, env.params(), settings.features)
    s = smoothness_cost(trajectory)
    rewards = gammas @ phi
    rec = {f"phi_{n}": float(v) for n, v in zip(settings.features, phi, strict=True)}
    rec["smoothness"] = s
    rec["reward_theta_hat"] = float(np.array(settings.theta) @ phi - lam * s)
    rec["worst_case"] = worst_case_reward(gammas, phi, s, lam)
    rec["best_case"] = float(rewards.max() - lam * s)
    rec["worst_gammas"] = ";".join(str(j) for j in np.flatnonzero(rewards <= rewards.min() + 1e-6))
    return rec


def panel_task(settings: DeploymentSettings, index: int) -> Deployment:
    """One panel of the figure (a worker task)."""
    return deploy(settings, settings.belief(index), settings.scene.environment(name="scene"))


#: Columns of a comparison record after panel, environment and status.
COMPARISON_VALUES = (
    "a4_worst_case",
    "a4_refined_worst_case",
    "a3_worst_case",
    "gain",
    "gain_refined",
    "min_value_refined",
    "a4_averse_gamma",
    "a4_refined_averse_gamma",
    "a3_worst_gammas",
)


def comparison_task(settings: DeploymentSettings, index: int, env_index: int) -> dict:
    """(A3) against (A4)'s averse plan for panel ``index``'s P in study environment
    ``env_index`` (a worker task).

    Returns:
        panel, environment, status ("ok" or the planner's error), the worst cases over Γ
        of the (A4), refined (A4) and (A3) trajectories, gain = (A3) − (A4), gain_refined =
        (A3) − refined (A4), min_value_refined = min_j V(γ_j) after refinement (an upper
        bound of (A3) by weak duality), the rows of Γ (A4) and refined (A4) deploy with,
        and the rows at (A3)'s worst case (two or more: a kink (A4) cannot reach). NaN
        and -1 where planning failed.
    """
    env = paper_environments()[env_index]
    rec = {"panel": settings.panels[index].name, "environment": env.name, "status": "ok"}
    try:
        d = deploy(settings, settings.belief(index), env)
    except PlanningError as exc:
        rec["status"] = str(exc).splitlines()[0][:120]
        nan = float("nan")
        failed = {name: nan for name in COMPARISON_VALUES}
        failed.update(a4_averse_gamma=-1, a4_refined_averse_gamma=-1, a3_worst_gammas="")
        return {**rec, **failed}
    gammas = d.a4.gammas
    a4 = trajectory_record(settings, gammas, d.trajectory("A4", "averse"), env)
    a4r = trajectory_record(settings, gammas, d.trajectory("A4r", "averse"), env)
    a3 = trajectory_record(settings, gammas, d.a3.trajectory, env)
    rec.update(
        a4_worst_case=a4["worst_case"],
        a4_refined_worst_case=a4r["worst_case"],
        a3_worst_case=a3["worst_case"],
        gain=a3["worst_case"] - a4["worst_case"],
        gain_refined=a3["worst_case"] - a4r["worst_case"],
        min_value_refined=float(d.refined.values.min()),
        a4_averse_gamma=d.a4.index("averse"),
        a4_refined_averse_gamma=d.refined.index("averse"),
        a3_worst_gammas=a3["worst_gammas"],
    )
    return rec


@dataclass(frozen=True, eq=False)
class DeploymentResult:
    """Everything fig. 3 shows.

    Attributes:
        trajectories: one record per (panel, rule, trajectory): panel, rule ("A4": the
            paper's, "A4r": refined, "A3": exact), trajectory (averse, neutral, seeking;
            averse for A3), gamma_index (row of Γ deployed with; -1 for A3), that γ
            (gamma_<name>; NaN for A3), and :func:`trajectory_record`'s columns.
        gammas: one record per (panel, row j of Γ): gamma_<name>, value V(γ_j), the
            features of ξ*(γ_j), the attitudes that chose it, and the same after refinement.
        comparison: one record per (panel, study environment), see :func:`comparison_task`.
        deployments: the panels' :class:`Deployment` (trajectories for renders and paths).
        timings: (A3) wall time (s), starts and IPOPT iterations per panel and comparison
            environment (not written to the CSVs: they vary between runs).
    """

    trajectories: tuple[dict, ...]
    gammas: tuple[dict, ...]
    comparison: tuple[dict, ...]
    deployments: tuple[Deployment, ...]
    timings: tuple[dict, ...]


def _trajectory_records(settings: DeploymentSettings, panel: Panel, d: Deployment) -> list[dict]:
    env = settings.scene.environment(name="scene")
    out = []
    for rule, plans in (("A4", d.a4), ("A4r", d.refined), ("A3", None)):
        for label in ("averse",) if plans is None else ATTITUDES:
            j = -1 if plans is None else plans.index(label)
            rec = {"panel": panel.name, "rule": rule, "trajectory": label, "gamma_index": j}
            for n, name in enumerate(settings.features):
                rec[f"gamma_{name}"] = float(d.a4.gammas[j, n]) if j >= 0 else float("nan")
            rec.update(trajectory_record(settings, d.a4.gammas, d.trajectory(rule, label), env))
            out.append(rec)
    return out


def _gamma_records(settings: DeploymentSettings, panel: Panel, d: Deployment) -> list[dict]:
    out = []
    for j, gamma in enumerate(d.a4.gammas):
        rec = {"panel": panel.name, "gamma_index": j}
        rec.update({f"gamma_{n}": float(v) for n, v in zip(settings.features, gamma, strict=True)})
        for suffix, plans in (("", d.a4), ("_refined", d.refined)):
            rec[f"value{suffix}"] = float(plans.values[j])
            features = plans.plans[j].features
            rec.update(
                {
                    f"phi_{n}{suffix}": float(v)
                    for n, v in zip(settings.features, features, strict=True)
                }
            )
            rec[f"chosen_by{suffix}"] = ";".join(a for a in ATTITUDES if plans.index(a) == j)
        out.append(rec)
    return out


def run(
    settings: DeploymentSettings,
    executor: Executor,
    progress: Callable[[int, int], None] | None = None,
) -> DeploymentResult:
    """The panels and the (A3)-vs-(A4) comparison on ``executor``.

    Raises:
        PlanningError: a panel could not be planned (the comparison records failures
            instead).
    """
    n_panels = len(settings.panels)
    futures = [executor.submit(panel_task, settings, i) for i in range(n_panels)]
    pairs = [(i, e) for i in range(n_panels) for e in range(settings.comparison_environments)]
    futures += [executor.submit(comparison_task, settings, i, e) for i, e in pairs]
    results = []
    for n, fut in enumerate(futures, start=1):
        results.append(fut.result())
        if progress:
            progress(n, len(futures))
    deployments = tuple(results[:n_panels])
    trajectories, gammas, timings = [], [], []
    for panel, d in zip(settings.panels, deployments, strict=True):
        trajectories += _trajectory_records(settings, panel, d)
        gammas += _gamma_records(settings, panel, d)
        timings.append(
            {
                "panel": panel.name,
                "a3_solve_time": d.a3.solve_time,
                "a3_starts": d.a3.starts,
                "a3_iterations": d.a3.iterations,
            }
        )
    return DeploymentResult(
        trajectories=tuple(trajectories),
        gammas=tuple(gammas),
        comparison=tuple(results[n_panels:]),
        deployments=deployments,
        timings=tuple(timings),
    )


# --- output ----------------------------------------------------------------------------------

#: Colours of the trajectories in renders and tables; (A3) is drawn as a wide translucent
#: sleeve, so it stays visible where it coincides with the averse path.
STYLE = {
    "averse": ((0.15, 0.7, 0.3, 1.0), "risk-averse (paper's rule)"),
    "neutral": ((0.15, 0.4, 0.95, 1.0), "risk-neutral, ξ*(θ̂)"),
    "seeking": ((0.9, 0.25, 0.2, 1.0), "risk-seeking (paper's rule)"),
    "A3": ((1.0, 0.8, 0.0, 0.35), "risk-averse, exact max-min over Γ"),
}


def write(settings: DeploymentSettings, result: DeploymentResult, folder: Path) -> list[Path]:
    """Write the figure and its data into ``folder``.

    Files: ``trajectories.csv`` (features and rewards of each panel's trajectories under
    each rule), ``gammas.csv`` (Γ, V(γ) and the (A4) choices), ``comparison.csv`` ((A3)
    against (A4) over the study's environments, if any), ``paths.csv`` (waypoints),
    ``fig3.png`` and ``fig3.pdf`` (renders of the paper's (A4) and of (A3), tables, and the
    comparison).

    Returns:
        The paths written, in that order.
    """
    from corrections_sim.figures.deployment_plot import plot_deployment_figure
    from corrections_sim.figures.output import trajectory_rows, write_csv
    from corrections_sim.scene import render

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = [
        write_csv(folder / "trajectories.csv", list(result.trajectories)),
        write_csv(folder / "gammas.csv", list(result.gammas)),
    ]
    if result.comparison:
        written.append(write_csv(folder / "comparison.csv", list(result.comparison)))
    rows = []
    for panel, d in zip(settings.panels, result.deployments, strict=True):
        for rec in (r for r in result.trajectories if r["panel"] == panel.name):
            waypoints = d.trajectory(rec["rule"], rec["trajectory"])
            rows += trajectory_rows(
                waypoints, panel=panel.name, rule=rec["rule"], trajectory=rec["trajectory"]
            )
    written.append(write_csv(folder / "paths.csv", rows))
    env = settings.scene.environment(name="scene")
    images, tables, cup_paths = [], [], []
    for panel, d in zip(settings.panels, result.deployments, strict=True):
        paths, points_of = [], {}
        for label in DRAWN:
            rgba, _ = STYLE[label]
            points = render.cup_path(d.trajectory("A3" if label == "A3" else "A4", label))
            points_of[label] = points
            paths.append((points, rgba, 0.022) if label == "A3" else (points, rgba))
        cup_paths.append(points_of)
        images.append(
            render.render_scene(env, paths, width=720, height=540, camera=render.SIDE_CAMERA)
        )
        tables.append(
            [
                {**r, "style": "A3" if r["rule"] == "A3" else r["trajectory"]}
                for r in result.trajectories
                if r["panel"] == panel.name and r["rule"] in ("A4", "A3")
            ]
        )
    figures = [folder / "fig3.png", folder / "fig3.pdf"]
    plot_deployment_figure(
        images,
        [p.title for p in settings.panels],
        tables,
        settings.features,
        {label: STYLE[label] for label in DRAWN},
        list(result.comparison),
        _title(settings),
        figures,
        cup_paths=cup_paths,
        scene={"table": settings.scene.table, "laptop": settings.scene.laptop},
        panel_labels={p.name: p.title[p.title.find("P = ") :] for p in settings.panels},
    )
    return written + figures


def _title(settings: DeploymentSettings) -> str:
    theta = ", ".join(f"{v:g}" for v in settings.theta)
    names = ", ".join(settings.features)
    return (
        f"fig3: deploying under uncertainty. The robot's estimate θ̂ = ({theta}) over ({names}); "
        "Γ = θ̂ ± one standard deviation along each axis of P.\n"
        "Risk-averse / -seeking (the paper's rule): plan for the γ ∈ Γ with the lowest / highest "
        "best reward; exact max-min: the plan with the best worst case over Γ"
    )


register(
    PresetFigure(
        "fig3",
        "risk-sensitive deployment, eqs. (A2)-(A4) and exact (A3)",
        __name__,
        ("trajectories",),
    )
)
