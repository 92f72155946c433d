"""The densities of ρ*, fitted to labelled corrections (issue 38): what a relevant and an
irrelevant correction leave unexplained, in the space where the person acts.

    python -m corrections_sim.run relevance-fit            # results/relevance_fit/
    python -m corrections_sim.run relevance-fit --quick    # 12 per kind, results/quick/

Labelled corrections are made by simulated people in three ways, each relevant (toward the
plan of a preference θ_p over the robot's own features) or irrelevant (the same size, in a
uniformly random direction), at several step sizes and noise levels drawn per correction:

* ``joint``: the worst waypoint moved ``step`` of the way onto the person's plan in joint
  space, plus joint noise (the simulated users of the figures); a nudge is the distracted
  user's;
* ``drag``: the cup at the worst cup waypoint moved ``step`` of the way toward the person's
  plan's cup, plus noise in metres, the joints by inverse kinematics with the hand's rotation
  kept (what the page does with a drag); a nudge moves the cup as far in a random direction;
* ``push``: the physical push model (:class:`~corrections_sim.people.physical.
  PhysicalCorrection`) toward the person's plan, or toward a cup target as far away in a
  random direction.

For each, ρ* (the least unexplained fraction over θ, :func:`~corrections_sim.learning.
relevance.explain`) is measured in joint and in task space under the correction model the
learner would use (the one-waypoint correction for joint and drag, the push model for
pushes), from the sigma points of N(θ̂, I) around the robot's θ̂. The fit per space
(joint: the joint corrections; task: drags and pushes): the Gamma over people's precision τ
of a relevant ρ* (each person half-normal with their τ: a half Student-t, by maximum
likelihood; KF-CRP's prior on τ, which it then learns per person), Beta(a, b) of irrelevant
ρ*² by maximum likelihood, and where the irrelevant corrections' best explanations lie around
θ̂ (θ_e − θ̂: a core about as wide as the people's preferences and a far tail, two isotropic
Gaussians by EM: where KF-CRP expects an irrelevant correction to be explained).

Writes ``data.csv`` (one row per correction), ``fit.json`` (what
``learners.KF-CRP.fit`` reads; the shipped default is ``experiments/relevance_fit.json``, a
copy of the committed fit) and ``densities.png``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from corrections_sim.learning.kalman.filter import SigmaPoints
from corrections_sim.learning.relevance.judge import SPACES, beta_rho_density, explain
from corrections_sim.people.corrections import WaypointCorrection, worst_waypoints
from corrections_sim.people.physical import PhysicalCorrection, worst_cup_waypoint
from corrections_sim.planning.planner import PlannerConfig, PlanningError, shared_planner
from corrections_sim.plans.book import PlanBook
from corrections_sim.scene.environments import paper_environments
from corrections_sim.scene.robot import cup_inverse_kinematics, cup_pose

MODES = ("joint", "drag", "push")
#: The space each mode's corrections are fitted in.
FIT_SPACE = {"joint": "joint", "drag": "task", "push": "task"}
STEPS = (0.5, 1.0)
JOINT_NOISE = (0.0, 0.02, 0.05)  # rad per joint
CUP_NOISE = (0.0, 0.01, 0.02)  # m per axis
FEATURES = ("laptop", "table")
SEED = 38


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


def _drag(robot, intended, step, noise, relevant, rng):
    """The page's drag: the cup at the worst cup waypoint moved toward ``intended``'s cup."""
    i, theirs = worst_cup_waypoint(robot, intended)
    rotation, cup = cup_pose(robot[i])
    goal = cup + step * (theirs[i] - cup) + noise * rng.normal(size=3)
    direction = _unit(rng, 3)  # drawn every time: the stream does not depend on the label
    if not relevant:
        goal = cup + np.linalg.norm(goal - cup) * direction
    q = cup_inverse_kinematics(goal, rotation, robot[i])
    if q is None:
        return None
    out = robot.copy()
    out[i] = q
    return out


def _push(robot, intended, relevant, rng):
    """The push model toward ``intended``, or toward a cup target as far in a random
    direction (the intended path then differs from the robot's at that waypoint only)."""
    model = PhysicalCorrection()
    direction = _unit(rng, 3)
    if relevant:
        return model.apply(robot, intended)
    i, theirs = worst_cup_waypoint(robot, intended)
    rotation, cup = cup_pose(robot[i])
    goal = cup + np.linalg.norm(theirs[i] - cup) * direction
    q = cup_inverse_kinematics(goal, rotation, robot[i])
    if q is None:
        return None
    fake = robot.copy()
    fake[i] = q
    return model.apply(robot, fake)


def _joint(robot, intended, step, noise, relevant, rng):
    """The simulated user's one-waypoint correction, or the distracted user's nudge."""
    i = int(worst_waypoints(robot, intended, 1)[0])
    moved = step * (intended[i] - robot[i]) + noise * rng.normal(size=7)
    direction = _unit(rng, 7)
    out = robot.copy()
    out[i] += moved if relevant else np.linalg.norm(moved) * direction
    return out


def labelled_corrections(per_kind: int, seed: int = SEED) -> list[dict]:
    """``per_kind`` relevant and as many irrelevant corrections per mode, each with ρ* in
    both spaces (rows of ``data.csv``)."""
    planner = shared_planner(PlannerConfig(features=FEATURES, n_starts=4))
    envs = paper_environments()
    rng = np.random.default_rng(seed)
    sigma = SigmaPoints()
    rows = []
    for mode in MODES:
        model = PhysicalCorrection() if mode == "push" else WaypointCorrection()
        made = 0
        while made < 2 * per_kind:
            relevant = made % 2 == 0
            env = envs[int(rng.integers(len(envs)))]
            theta_hat = rng.normal(size=2)
            theta_p = rng.uniform(-2.0, 2.0, size=2)
            step = float(rng.choice(STEPS))
            noise = float(rng.choice(CUP_NOISE if mode == "drag" else JOINT_NOISE))
            book = PlanBook(planner, warm_start=True)
            try:
                robot = book.plan(theta_hat, env).trajectory
                intended = book.plan(theta_p, env).trajectory
            except PlanningError:
                continue
            if mode == "joint":
                corrected = _joint(robot, intended, step, noise, relevant, rng)
            elif mode == "drag":
                corrected = _drag(robot, intended, step, noise, relevant, rng)
            else:
                corrected = _push(robot, intended, relevant, rng)
                step = noise = 0.0
            if corrected is None or np.allclose(corrected, robot):
                continue
            starts = sigma.points(theta_hat, np.eye(2))
            row = {
                "mode": mode,
                "relevant": int(relevant),
                "environment": env.name,
                "step": step,
                "noise": noise,
                "theta_hat_0": float(theta_hat[0]),
                "theta_hat_1": float(theta_hat[1]),
                "theta_p_0": float(theta_p[0]),
                "theta_p_1": float(theta_p[1]),
            }
            for space in SPACES:
                found = explain(book, env, robot, corrected, model, starts, space=space)
                row[f"rho_{space}"] = float(found.rho)
                for j in range(2):  # where the best explanation is, from the robot's θ̂
                    row[f"explained_{space}_{j}"] = float(found.theta[j] - theta_hat[j])
            rows.append(row)
            made += 1
            print(f"{mode}: {made}/{2 * per_kind}", file=sys.stderr, end="\r", flush=True)
        print(file=sys.stderr)
    return rows


def fit(rows: list[dict]) -> dict:
    """Per space, from the rows of the modes fitted in it: the Gamma over the precision of
    relevant ρ*, the Beta (a, b) of irrelevant ρ*² (both by maximum likelihood) and the
    scatter of irrelevant explanations."""
    from scipy import stats

    spaces = {}
    for space in SPACES:
        mine = [r for r in rows if FIT_SPACE[r["mode"]] == space]
        if not mine:
            continue
        relevant = np.array([r[f"rho_{space}"] for r in mine if int(r["relevant"]) == 1], float)
        other = np.array([r[f"rho_{space}"] for r in mine if int(r["relevant"]) == 0], float)
        x = np.clip(other**2, 1e-6, 1.0 - 1e-6)
        a, b, _, _ = stats.beta.fit(x, floc=0.0, fscale=1.0)
        offsets = np.array(
            [
                [float(r[f"explained_{space}_{j}"]) for j in range(2)]
                for r in mine
                if int(r["relevant"]) == 0
            ]
        )
        shape, rate = precision_prior(relevant)
        spaces[space] = {
            "irrelevant": [float(a), float(b)],
            "precision": [shape, rate],
            "scatter": scatter_mixture(offsets),
            "relevant_count": int(relevant.size),
            "irrelevant_count": int(other.size),
            "modes": sorted({r["mode"] for r in mine}),
        }
    return {"spaces": spaces}


#: The largest Gamma shape fitted (a shape this large is a single precision for everyone).
MAX_SHAPE = 1000.0


def precision_prior(rho: np.ndarray) -> list[float]:
    """[shape, rate] of the Gamma over people's precision τ that makes the relevant ρ* most
    likely: each person's ρ* half-normal with their τ, τ ~ Gamma(shape, rate), so ρ* is a
    half Student-t with 2·shape degrees of freedom and scale √(rate / shape) (maximum
    likelihood; the shape at most :data:`MAX_SHAPE`)."""
    from scipy import optimize, stats

    x = np.maximum(np.asarray(rho, float), 1e-9)

    def nll(p):
        a, b = np.exp(p)
        return -np.sum(stats.t.logpdf(x, df=2 * a, scale=np.sqrt(b / a)))

    start = [0.0, np.log(np.mean(x**2))]
    found = optimize.minimize(nll, start, method="Nelder-Mead", options={"maxiter": 4000})
    shape, rate = np.exp(found.x)
    if shape > MAX_SHAPE:  # no tail: one precision, the half-normal's maximum likelihood
        shape = MAX_SHAPE
        rate = shape * float(np.mean(x**2))
    return [float(shape), float(rate)]


def scatter_mixture(offsets: np.ndarray, iterations: int = 500) -> list[list[float]]:
    """[[w, sd], [w, sd]]: two zero-mean isotropic Gaussians over the explanations' offsets
    (n, k) by expectation–maximization (started at a core of sd 1 and a tail of sd 5); the
    core first."""
    r2 = np.sum(offsets**2, axis=1)
    k = offsets.shape[1]
    w, var = np.array([0.8, 0.2]), np.array([1.0, 25.0])
    for _ in range(iterations):
        log = np.log(w) - 0.5 * k * np.log(2 * np.pi * var) - r2[:, None] / (2 * var)
        g = np.exp(log - log.max(axis=1, keepdims=True))
        g /= g.sum(axis=1, keepdims=True)
        w = g.mean(axis=0)
        var = np.maximum((g * r2[:, None]).sum(axis=0) / (k * g.sum(axis=0)), 1e-6)
    order = np.argsort(var)
    return [[float(w[i]), float(np.sqrt(var[i]))] for i in order]


def plot(rows: list[dict], fitted: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy import stats

    spaces = list(fitted["spaces"])
    fig, axes = plt.subplots(1, len(spaces), figsize=(5.5 * len(spaces), 3.8), squeeze=False)
    grid = np.linspace(1e-3, 1.0, 400)
    for ax, space in zip(axes[0], spaces, strict=True):
        entry = fitted["spaces"][space]
        mine = [r for r in rows if FIT_SPACE[r["mode"]] == space]
        for label, colour, name in ((1, "#2ca02c", "relevant"), (0, "#d62728", "irrelevant")):
            values = [r[f"rho_{space}"] for r in mine if int(r["relevant"]) == label]
            ax.hist(
                values,
                bins=25,
                range=(0, 1),
                density=True,
                alpha=0.45,
                color=colour,
                label=f"{name} ({len(values)})",
            )
        shape, rate = entry["precision"]
        half_t = 2.0 * stats.t.pdf(grid, df=2 * shape, scale=np.sqrt(rate / shape))
        ax.plot(
            grid,
            half_t,
            color="#2ca02c",
            label=f"half-t: τ ~ Gamma({shape:.3g}, {rate:.3g}), σ̂ = {np.sqrt(rate / shape):.3f}",
        )
        a, b = entry["irrelevant"]
        ax.plot(
            grid,
            [beta_rho_density(g, a, b) for g in grid],
            color="#d62728",
            label=f"ρ² ~ Beta({a:.2f}, {b:.2f})",
        )
        ax.set_ylim(0, 12)
        ax.set_xlabel(f"ρ*, {space} space ({', '.join(entry['modes'])})")
        ax.set_ylabel("density")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
