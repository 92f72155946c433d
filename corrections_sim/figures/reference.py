"""The exact posterior beside a learner's Gaussian, for the runs of a finished learning figure.

    python -m corrections_sim.run reference results/quick/fig4 --learner KF-C --runs 2

For each chosen run of a Gaussian learner, the posterior p(θ | corrections) is computed on a
grid (:mod:`corrections_sim.learning.exact.bayes`) under exactly the model the learner assumes:
KF/AL's h(θ) = Φ(ξ*(θ, E)), KF-C/AL-C's hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E))) with its correction model,
N fixed or (``noise = "learnt"``) integrated out under the learner's prior, and BP's Boltzmann
likelihood. Each correction is replayed from the figure's records: Eᵗ and θ̂ᵗ⁻¹ give the
robot's plan ξᵗ, the (deterministic) user gives Φ_h. ξ*(θ, E) at the grid's points is solved
once per environment, grid and planner, and kept in a content-addressed file beside the
compiled planner. The process noise M (1e-4 I in the figures) is left out: over 12
corrections it widens the posterior by less than 0.04 in θ, below the grid's spacing.

Writes ``reference-<learner>.csv`` in the figure's folder (per run and iteration: the
reference's mean and covariance, its NEES against θ*, the learner's NEES, and
``ref_kl`` = KL(reference ‖ learner's N(θ̂, P)), and ``ref_kl_gaussian``, its part that a
Gaussian with the reference's moments already has), prints the means over runs, and writes the
last iteration's summary with 95% intervals over runs to ``reference-<learner>.json`` (NEES /
reference NEES, ``ref_kl``; with ``--one-step`` and ``--restart``, where the gap enters).
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import os
from pathlib import Path

import numpy as np

from corrections_sim.belief import Belief, PersonBelief
from corrections_sim.learning import correction
from corrections_sim.learning.exact import bayes as ref
from corrections_sim.learning.exact.cells import Cells
from corrections_sim.learning.observation import features_at_plans
from corrections_sim.learning.particles.cloud import smoothed_kl
from corrections_sim.learning.particles.learners import particle_reference
from corrections_sim.learning.relevance.judge import (
    MOVED,
    NUDGE_DIMENSIONS,
    beta_rho_density,
    embed,
    random_direction_shape,
)
from corrections_sim.people.users import Situation
from corrections_sim.planning.compiled import build_once
from corrections_sim.planning.planner import Planner, PlanningError, build_key, cache_dir
from corrections_sim.plans.atlas import AtlasGrid
from corrections_sim.plans.book import PlanBook
from corrections_sim.scene.environments import Environment
from corrections_sim.study.settings import FigureSettings


def grid_plans(planner: Planner, env: Environment, grid: ref.Grid) -> np.ndarray:
    """ξ*(θ, E) at every grid point, (n, T, 7); NaN where the planner found none. Solved in
    a snake order, each from its neighbour's plan, and cached by planner, environment and grid."""
    key = hashlib.sha256(
        f"{build_key(planner.config)}|{env.key().hex()}|{grid}".encode()
    ).hexdigest()[:20]
    path = cache_dir() / "reference" / f"{key}.npy"
    build_once(path, lambda target: _save(target, _solve_grid(planner, env, grid)))
    return np.load(path)


def _save(path: Path, array: np.ndarray) -> None:
    """``array`` to ``path`` atomically (written beside it under this process's name)."""
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npy")
    np.save(tmp, array)
    tmp.replace(path)


def _solve_grid(planner: Planner, env: Environment, grid: ref.Grid) -> np.ndarray:
    thetas, n = grid.thetas(), grid.points
    plans = np.full((len(thetas), planner.config.n_waypoints, 7), np.nan)
    previous = None
    for row in range(n):
        columns = range(n) if row % 2 == 0 else range(n - 1, -1, -1)
        for col in columns:
            i = row * n + col
            try:
                inits = None if previous is None else [previous]
                try:
                    plan = planner.solve(thetas[i], env, inits=inits)
                except PlanningError:
                    plan = planner.solve(thetas[i], env)
                plans[i] = previous = plan.trajectory
            except PlanningError:
                previous = None
    return plans


def _filter_step(model, study, book: PlanBook, env, robot, z, start, row) -> Belief:
    """The learner's update of the correction ``z`` to the robot's plan ``robot``, from the
    Gaussian N(``start``) (the reference's moments before it): the UKF with the learner's
    observation model and noise (N / β̂ for a relevance-aware learner, its β̂ from the
    record)."""
    from corrections_sim.belief import KalmanNoise
    from corrections_sim.learning.kalman.filter import ukf_update

    names = book.planner.config.features
    likelihood = model.likelihood()
    observe = model.observation().observe(book, env, robot.trajectory, names)
    noise = study.noise()
    if likelihood.relevance == "per-correction" and row.get("relevance"):
        beta = float(row["relevance"])
        noise = KalmanNoise(process=noise.process, observation=noise.observation / beta)
    prior = Belief(theta=start[0], cov=start[1])
    step = ukf_update(prior, observe, z, noise, study.sigma(), reference=robot.features)
    return step.belief


def grid_observations(plans: np.ndarray, robot: np.ndarray, correct, env, names) -> np.ndarray:
    """h(θ) at every grid point (n, k): Φ of ``correct(robot, ξ*(θ))``, NaN where the grid
    has no plan (:func:`~corrections_sim.learning.observation.features_at_plans`)."""
    return features_at_plans(plans, robot, correct, env, names)


#: Equal-probability nodes of KF-CRP's prior on τ in its exact reference.
PERSON_TAU_NODES = 48


def grid_residuals(
    plans: np.ndarray, robot: np.ndarray, corrected: np.ndarray, model, space: str = "joint"
) -> np.ndarray:
    """ρ(θ) = ‖ξ_h − ĉ(θ)‖ / ‖ξ_h − ξ‖ on the moved waypoints, in ``space``, at every grid
    point (n,), ĉ the correction ``model`` toward the grid's plan; NaN where the grid has no
    plan."""
    corrected = np.asarray(corrected, float)
    rows = np.linalg.norm(corrected - robot, axis=1) > MOVED
    target = embed(space, corrected[rows])
    size = float(np.linalg.norm(target - embed(space, robot[rows])))
    out = np.full(plans.shape[0], np.nan)
    if size == 0.0:
        return np.zeros(plans.shape[0])
    for i, plan in enumerate(plans):
        if np.all(np.isfinite(plan)):
            out[i] = np.linalg.norm(target - embed(space, model.at(robot, plan, rows))) / size
    return out


def recorded_runs(folder: Path, learner: str) -> dict[int, list[dict]]:
    with open(folder / "curves.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["learner"] == learner]
    runs: dict[int, list[dict]] = {}
    for r in rows:
        runs.setdefault(int(r["run"]), []).append(r)
    return {run: sorted(v, key=lambda r: int(r["iteration"])) for run, v in runs.items()}


def _belief(row: dict, k: int) -> Belief:
    theta = np.array([float(row[f"theta_{i}"]) for i in range(k)])
    cov = np.zeros((k, k))
    for i in range(k):
        for j in range(i, k):
            cov[i, j] = cov[j, i] = float(row[f"cov_{i}{j}"])
    return Belief(theta=theta, cov=cov)


def reference_run(
    settings: FigureSettings,
    learner: str,
    rows: list[dict],
    grid: ref.Grid,
    planner: Planner,
    *,
    one_step: bool = False,
    restarts: tuple[int, ...] = (),
    particles: int = 0,
    seed: int = 0,
    resolution: float | None = None,
) -> list[dict]:
    """The reference after every correction of one run (``rows``: its records, t = 0 … T).

    With ``particles`` > 0 the particle machinery of PF-C (:mod:`~.learning.particles`) with
    that many particles also runs on the same corrections under the learner's model (KF/KF-C
    types with N fixed), seeded by ``seed``: where the grid exists (``grid`` not None) it is
    judged against the grid (``particle_kl``, KL from the grid to the smoothed particles,
    :func:`~.learning.particles.smoothed_kl`; ``particle_mean_gap``,
    the largest |Δ mean| in the grid's sd; ``particle_var_gap``, the largest relative
    |Δ variance|); without a grid (k > 2) it *is* the reference (its moments; no ``ref_kl``,
    only its Gaussian part ``ref_kl_gaussian``).

    With ``one_step`` (a Kalman learner with N fixed), also the learner's own update started
    from the reference before the correction (its moments), as ``one_step_nees`` and
    ``one_step_kl`` against the reference after it: the error of one step of the filter, apart
    from what earlier steps left (which the learner's own NEES and ``ref_kl`` include). With
    ``restarts`` (iterations s), also the learner's filter run on from the reference at each s
    (s = 0: the prior, i.e. the learner replayed), as ``restart_<s>_nees``: how much of the
    final gap the steps before s leave.

    On a study with a plan atlas, a KF/KF-C-type model's grid is refined where the posterior
    has fewer than ``resolution`` nodes in its narrowest sd (None: 2, twice the exact
    learners' default; 0: never), as an exact learner's is
    (:class:`~corrections_sim.learning.exact.bayes.Refinement`): every correction so far
    weighed again at the finer nodes, ξ*(θ, E) there from the atlas over ``grid``."""
    study = settings.study
    model = study.learners[learner]
    if study.user.stochastic:
        raise ValueError(
            f"user {study.user_name}: draws random numbers; its corrections cannot be replayed"
        )
    if not model.has_covariance:
        raise ValueError(f"learner {learner}: has no covariance to judge against a reference")
    likelihood = model.likelihood()
    if likelihood is None:
        raise ValueError(f"learner {learner}: no reference for it (KF-type learners and BP)")
    if likelihood.relevance == "per-correction" and likelihood.noise == "learnt":
        raise ValueError(f"learner {learner}: no reference for relevance with N learnt")
    engine = particle_reference(model, learner, particles) if particles else None
    if grid is None and (engine is None or one_step or restarts):
        raise ValueError(
            f"k = {study.k}: no grid beyond k = 2 (--particles N is the reference there; "
            "--one-step and --restart need the grid)"
        )
    k, names = study.k, planner.config.features
    envs = {e.name: e for e in settings.envs()}
    theta_star = np.array(study.theta_star)  # the learners' part, what NEES is against
    target = settings.person_target(list(envs.values()))
    intended = dict(zip(envs, (p.trajectory for p in target.plans), strict=True))
    thetas = grid.thetas() if grid is not None else np.zeros((1, k))
    log_p = ref.gaussian_log_prior(thetas, study.prior())
    noise = study.noise().observation
    learnt = likelihood.kind == "gaussian" and likelihood.noise == "learnt"
    prior_noise = model.initial(study.prior(), study.noise()).noise if learnt else None
    zs, hs, out = [], [], []
    person = None
    if likelihood.relevance == "person":
        _, (shape, rate), _ = model.densities()
        a = model.relevance_prior * model.relevance_count
        b = (1.0 - model.relevance_prior) * model.relevance_count
        fine = PersonBelief.prior(shape, rate, a, b, tau_points=PERSON_TAU_NODES, rate_points=41)
        person = ref.PersonPosterior.prior(thetas, log_p, fine)
    if (one_step or restarts) and (
        person is not None or not (likelihood.kind == "gaussian" and not learnt)
    ):
        raise ValueError(
            f"learner {learner}: --one-step and --restart need a Kalman learner with N fixed"
        )
    # With the study's plan atlas, the robot's plans are replayed from it, as the run made
    # them, and ξ*(θ, E) at the grid's points is the atlas's over the grid (the study's own
    # where the grid is its atlas's, so an exact learner's posterior is this one).
    study_atlas = settings.atlas()
    book = PlanBook(planner, atlas=study_atlas)
    at_nodes = None
    if study_atlas is not None and grid is not None:
        spec = settings.atlas_spec()
        box = AtlasGrid(grid.low, grid.high, (grid.points,) * k)
        at_nodes = dataclasses.replace(spec, grid=box).atlas()
    refinable = (
        at_nodes is not None
        and likelihood.kind == "gaussian"
        and likelihood.relevance == "none"
        and person is None
    )
    if resolution is not None and not (np.isfinite(resolution) and resolution >= 0):
        raise ValueError(f"--resolution {resolution!r}: expected a number >= 0")
    if resolution is not None and resolution > 0 and not refinable:
        raise ValueError(
            f"--resolution {resolution:g}: refines only a KF/KF-C-type model's grid on a study "
            "with a plan atlas"
        )
    cells, past = None, []  # a refinable grid's cells; the corrections so far, to weigh again
    if refinable:
        # The core to e^−13.8 = 1e-6 of the peak, not an exact learner's 1e-4.
        refine = ref.Refinement(2.0 if resolution is None else resolution, cut=13.8)
        # One level finer than an exact learner may go: at twice its resolution, it is at
        # half its finest spacing.
        depth = getattr(model, "max_level", 4) + 1
        cells = Cells.base(box.lows, box.highs, box.counts, depth)
        thetas = cells.thetas()
        log_p = ref.gaussian_log_prior(thetas, study.prior())
    restarted: dict[int, Belief] = {}
    if engine is not None:
        cloud = engine.initial(study.prior(), study.noise())
        ctx = correction.context(
            cloud,
            study.noise(),
            book=PlanBook(planner, warm_start=study.warm_start, atlas=study_atlas),
            envs=tuple(envs.values()),
            features=names,
            n_waypoints=planner.config.n_waypoints,
            alphas=None,
            rng=np.random.default_rng(seed),
            sigma=study.sigma(),
        )
    for row in rows[1:]:
        start = None
        if one_step or restarts:
            at = None if cells is None else cells.coefficients
            start = ref.moments(thetas, ref.posterior(log_p, at))
        t = int(row["iteration"])
        for s in restarts:
            if s == t - 1:
                restarted[s] = study.prior() if s == 0 else Belief(theta=start[0], cov=start[1])
        t, env = int(row["iteration"]), envs[row["environment"]]
        before = _belief(rows[t - 1], k)
        robot = book.plan(before.theta, env)
        seen = Situation(robot.trajectory, intended[env.name], env, names, target.theta_star)
        outcome = study.user.perform(seen, np.random.default_rng(0))
        z = np.asarray(outcome.phi_h, float)
        judged = {}
        if engine is not None:
            at_t = dataclasses.replace(ctx, iteration=t - 1)
            cloud = correction.step(engine, at_t, cloud, env, robot, z, outcome.corrected).belief
        if grid is None:
            log_post = None
        elif likelihood.kind == "boltzmann":
            betas = model.correction_model(0.0).betas
            log_l = ref.boltzmann_log_likelihood(thetas, z - robot.features, betas, model.lapse)
            log_p = log_p + log_l
            log_post = log_p
        else:
            if at_nodes is None:
                plans = grid_plans(planner, env, grid)
            else:
                plans = at_nodes.plans(thetas, env)
            c = likelihood.correction
            correct = c.apply if c is not None else (lambda r, x: x)
            h = grid_observations(plans, robot.trajectory, correct, env, names)
            if person is not None:
                plans_rho = grid_residuals(
                    plans, robot.trajectory, outcome.corrected, likelihood.correction, model.space
                )
                recorded = float(row["relevance_residual"] or 1.0)
                rho_star = min(float(np.nanmin(plans_rho)), recorded)
                shape, _, scatter = model.densities()
                f0 = beta_rho_density(
                    rho_star, *(shape or random_direction_shape(NUDGE_DIMENSIONS, k))
                )
                mixture = [(w, sd**2 * np.eye(k)) for w, sd in scatter]
                tau0 = float(np.mean(person.taus))
                place = ref.irrelevant_place(
                    thetas, plans_rho, rho_star, before.theta, mixture, tau0
                )
                judged["ref_relevance"] = person.correct(
                    ref.gaussian_log_likelihood(z, h, noise),
                    plans_rho,
                    rho_star,
                    tau0,
                    np.log(max(f0, 1e-300)) + place,
                )
                judged["ref_relevance_rate"] = person.rate_mean()
                judged["ref_relevance_spread"] = person.spread()
                log_post = np.log(np.maximum(person.theta_weights(), 1e-300))
            elif likelihood.relevance == "per-correction":
                if row.get("relevance"):  # else the learner skipped this update
                    log_l = ref.relevance_log_likelihood(
                        ref.gaussian_log_likelihood(z, h, noise), log_p, float(row["relevance"])
                    )
                    log_p = log_p + log_l
                log_post = log_p
            elif learnt:
                zs.append(z)
                hs.append(h)
                log_l = ref.learnt_noise_log_likelihood(
                    np.array(zs), np.array(hs), prior_noise.dof, prior_noise.scale
                )
                log_post = log_p + log_l
            else:
                log_l = ref.gaussian_log_likelihood(z, h, noise)
                log_p = log_p + log_l
                log_post = log_p
            if cells is not None:
                past.append((env, robot.trajectory, z))
                while (finer := refine.finer(cells, log_post)) is not None:
                    new = finer.thetas()[len(thetas) :]
                    new_hs = [
                        grid_observations(at_nodes.plans(new, e), r, correct, e, names)
                        for e, r, _ in past
                    ]
                    new_p = ref.gaussian_log_prior(new, study.prior())
                    if learnt:
                        hs = [np.concatenate(pair) for pair in zip(hs, new_hs, strict=True)]
                        log_p = np.concatenate([log_p, new_p])
                        log_post = log_p + ref.learnt_noise_log_likelihood(
                            np.array(zs), np.array(hs), prior_noise.dof, prior_noise.scale
                        )
                    else:
                        for (*_, seen_z), seen_h in zip(past, new_hs, strict=True):
                            new_p = new_p + ref.gaussian_log_likelihood(seen_z, seen_h, noise)
                        log_p = log_post = np.concatenate([log_p, new_p])
                    cells, thetas = finer, finer.thetas()
        coefficients = None if cells is None else cells.coefficients
        belief = _belief(row, k)
        if log_post is None:  # the particles are the reference
            weights = None
            mean, cov = cloud.particles.moments()
        else:
            weights = ref.posterior(log_post, coefficients)
            mean, cov = ref.moments(thetas, weights)
        rec = {"learner": learner, "run": int(row["run"]), "iteration": t, "environment": env.name}
        for i in range(k):
            rec[f"ref_theta_{i}"] = float(mean[i])
        for i in range(k):
            for j in range(i, k):
                rec[f"ref_cov_{i}{j}"] = float(cov[i, j])
        rec["ref_nees"] = ref.nees(mean, cov, theta_star)
        rec["nees"] = float(row["nees"]) if row["nees"] else None
        rec["ref_kl"] = (
            None
            if weights is None
            else ref.kl_to_gaussian(grid, thetas, weights, belief, coefficients)
        )
        rec["ref_kl_gaussian"] = ref.gaussian_kl(mean, cov, belief)
        if engine is not None and weights is not None:
            rec |= _particles_against_grid(
                cloud.particles, thetas, weights, mean, cov, coefficients
            )
        if judged:
            rec["relevance"] = float(row["relevance"]) if row.get("relevance") else None
            rec |= judged
        if one_step:
            step = _filter_step(model, study, book, env, robot, z, start, row)
            rec["one_step_nees"] = ref.nees(step.theta, step.cov, theta_star)
            rec["one_step_kl"] = ref.kl_to_gaussian(grid, thetas, weights, step, coefficients)
        for s, state in restarted.items():
            state = _filter_step(model, study, book, env, robot, z, (state.theta, state.cov), row)
            restarted[s] = state
            rec[f"restart_{s}_nees"] = ref.nees(state.theta, state.cov, theta_star)
        out.append(rec)
    return out


def _particles_against_grid(cloud, thetas, weights, mean, cov, coefficients=None) -> dict:
    """How far the particles are from the grid reference: KL (the particles smoothed on the
    grid, its refined cells' volumes ``coefficients`` if any), moments."""
    p_mean, p_cov = cloud.moments()
    sd = np.sqrt(np.diag(cov))
    return {
        "particle_kl": smoothed_kl(thetas, weights, cloud, coefficients),
        "particle_mean_gap": float(np.max(np.abs(p_mean - mean) / sd)),
        "particle_var_gap": float(np.max(np.abs(np.diag(p_cov) - np.diag(cov)) / np.diag(cov))),
        "particle_ess": cloud.effective_size(),
    }


def summary_at(records: list[dict], iteration: int, *, resamples: int = 2000) -> dict:
    """At ``iteration``, over runs: NEES / reference NEES as the ratio of the means with
    a 95% bootstrap interval over runs (seeded, so the same records give the same interval),
    and ``ref_kl``'s and its Gaussian part's means with their 95% t-intervals (``ref_kl``
    only where the reference is a grid), and the particle reference's distance from the grid
    where both were computed."""
    from scipy import stats

    at = [r for r in records if r["iteration"] == iteration and r["nees"] is not None]
    nees = np.array([r["nees"] for r in at], float)
    ref_nees = np.array([r["ref_nees"] for r in at], float)
    n = len(at)
    picks = np.random.default_rng(0).integers(n, size=(resamples, n))

    def ratio_ci(values: np.ndarray) -> list[float]:
        """95% bootstrap interval over runs of mean(values) / mean(reference NEES)."""
        boot = values[picks].mean(axis=1) / ref_nees[picks].mean(axis=1)
        return [float(np.quantile(boot, 0.025)), float(np.quantile(boot, 0.975))]

    def mean_ci(key: str) -> tuple[float, list[float]]:
        values = np.array([r[key] for r in at], float)
        half = (
            float(stats.t.ppf(0.975, n - 1) * values.std(ddof=1) / np.sqrt(n)) if n > 1 else np.nan
        )
        mean = float(values.mean())
        return mean, [mean - half, mean + half]

    out = {
        "iteration": iteration,
        "runs": n,
        "nees": float(nees.mean()),
        "ref_nees": float(ref_nees.mean()),
        "ratio": float(nees.mean() / ref_nees.mean()),
        "ratio_ci95": ratio_ci(nees),
    }
    if at and at[0].get("ref_kl") is not None:
        out["ref_kl"], out["ref_kl_ci95"] = mean_ci("ref_kl")
    out["ref_kl_gaussian"], out["ref_kl_gaussian_ci95"] = mean_ci("ref_kl_gaussian")
    if at and "particle_kl" in at[0]:
        for key in ("particle_kl", "particle_mean_gap", "particle_var_gap", "particle_ess"):
            out[key], out[f"{key}_ci95"] = mean_ci(key)
    if at and "one_step_nees" in at[0]:
        one = np.array([r["one_step_nees"] for r in at], float)
        out["one_step_ratio"] = float(one.mean() / ref_nees.mean())
        out["one_step_ratio_ci95"] = ratio_ci(one)
        out["one_step_kl"] = float(np.mean([r["one_step_kl"] for r in at]))
    judged = [r for r in records if r.get("ref_relevance") is not None and r.get("relevance")]
    if judged:  # a learner with a belief over the person: its β̂ against the exact one
        gaps = np.array([abs(r["relevance"] - r["ref_relevance"]) for r in judged])
        out["relevance_gap"] = float(gaps.mean())
        out["relevance_gap_max"] = float(gaps.max())
        out["relevance_agree"] = float(
            np.mean([(r["relevance"] > 0.5) == (r["ref_relevance"] > 0.5) for r in judged])
        )
    for key in sorted(k for k in (at[0] if at else {}) if k.startswith("restart_")):
        out[key.removesuffix("_nees") + "_ratio"] = float(
            np.mean([r[key] for r in at]) / ref_nees.mean()
        )
    return out


def calibration_figure(folder: Path) -> Path:
    """The calibration figure from the reference summaries in ``folder`` (``<figure>-<learner>
    .json``, as in ``results/reference_posterior``, each with its ``by_iteration``): per
    figure, every learner's NEES / reference NEES and the Gaussian part of ``ref_kl``
    against t. Writes ``calibration.png`` there."""

    panels: dict[str, dict] = {}
    for path in sorted(folder.glob("*.json")):
        data = json.loads(path.read_text())
        if "by_iteration" not in data:
            continue
        figure = path.stem.removesuffix(f"-{data['learner']}")
        panels.setdefault(figure, {})[data["learner"]] = data["by_iteration"]
    if not panels:
        raise ValueError(f"{folder}: no reference summaries with by_iteration in it")
    runs = sorted({rows[-1]["runs"] for learners in panels.values() for rows in learners.values()})
    out = folder / "calibration.png"
    title = "Each learner against exact Bayes under its own model (95% intervals over "
    plot_reference_calibration(panels, f"{title}{'/'.join(map(str, runs))} runs)", [out])
    return out


def plot_reference_calibration(panels: dict, title: str, paths) -> None:
    """Each learner against its exact reference over t, one column per figure (``panels``:
    figure label -> {learner: by-iteration summaries of ``figures.reference``}): NEES /
    reference NEES with its 95% interval (1 is exact Bayes' confidence; the band
    [0.8, 1.25] shaded) and the Gaussian part of ``ref_kl`` (nats; 0 is the reference's own
    moments) with its interval."""
    from corrections_sim.figures.style import learner_style, plt, save_and_close

    columns = list(panels)
    fig, axes = plt.subplots(
        2, len(columns), figsize=(4.2 * len(columns), 6.4), squeeze=False, sharex="col"
    )
    for c, figure in enumerate(columns):
        top, bottom = axes[0, c], axes[1, c]
        top.axhspan(0.8, 1.25, color="0.9")
        top.axhline(1.0, color="0.5", lw=0.8)
        for learner, rows in panels[figure].items():
            colour, style = learner_style(learner)
            t = [r["iteration"] for r in rows]
            ratio = [r["ratio"] for r in rows]
            low, high = zip(*(r["ratio_ci95"] for r in rows), strict=True)
            top.plot(t, ratio, color=colour, ls=style, marker="o", ms=3, label=learner)
            top.fill_between(t, low, high, color=colour, alpha=0.15)
            gauss = [r["ref_kl_gaussian"] for r in rows]
            low, high = zip(*(r["ref_kl_gaussian_ci95"] for r in rows), strict=True)
            bottom.plot(t, gauss, color=colour, ls=style, marker="o", ms=3, label=learner)
            bottom.fill_between(t, low, high, color=colour, alpha=0.15)
        top.set_yscale("log")
        top.set_title(figure, fontsize=9)
        top.set_ylabel("NEES / reference NEES")
        bottom.axhline(0.02, color="0.6", lw=0.8, ls=":")
        bottom.set_ylabel("ref_kl, Gaussian part (nats)")
        bottom.set_xlabel("corrections t")
        for ax in (top, bottom):
            ax.grid(alpha=0.3)
        top.legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    save_and_close(fig, paths, dpi=130)
