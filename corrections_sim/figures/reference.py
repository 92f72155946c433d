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

Its records, per run and iteration: the reference's mean and covariance, its NEES against θ*,
the learner's NEES, ``ref_kl`` = KL(reference ‖ learner's N(θ̂, P)) and ``ref_kl_gaussian``,
its part that a Gaussian with the reference's moments already has; and the summary at every
iteration with 95% intervals over runs (NEES / reference NEES, ``ref_kl``; with
``--one-step`` and ``--restart``, where the gap enters). The command
(:mod:`corrections_sim.figures.reference_figure`) runs a ``ReferenceJob`` run by run on
its executor and writes them to ``<figure>/reference-<learner>/``.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from corrections_sim.belief import Belief
from corrections_sim.learning import correction
from corrections_sim.learning.exact import bayes as ref
from corrections_sim.learning.exact.cells import Cells
from corrections_sim.learning.exact.grid import GRID_MODELS, Seen
from corrections_sim.learning.observation import features_at_plans
from corrections_sim.learning.particles.cloud import against_grid
from corrections_sim.learning.particles.learners import particle_reference
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


def _filter_step(model, grid_model, study, book: PlanBook, env, robot, z, start, row) -> Belief:
    """The learner's update of the correction ``z`` to the robot's plan ``robot``, from the
    Gaussian N(``start``) (the reference's moments before it): the UKF with the learner's
    observation model and noise (N / β̂ for a relevance-aware learner, its β̂ from the
    record: :meth:`~corrections_sim.learning.exact.grid.GridModel.filter_noise`)."""
    from corrections_sim.learning.kalman.filter import ukf_update

    names = book.planner.config.features
    observe = model.observation().observe(book, env, robot.trajectory, names)
    noise = grid_model.filter_noise(study.noise(), row)
    prior = Belief(theta=start[0], cov=start[1])
    step = ukf_update(prior, observe, z, noise, study.sigma(), reference=robot.features)
    return step.belief


def grid_observations(plans: np.ndarray, robot: np.ndarray, correct, env, names) -> np.ndarray:
    """h(θ) at every grid point (n, k): Φ of ``correct(robot, plans)`` (every plan at once),
    NaN where the grid has no plan
    (:func:`~corrections_sim.learning.observation.features_at_plans`)."""
    return features_at_plans(plans, robot, correct, env, names)


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


def check_reference(
    settings: FigureSettings,
    learner: str,
    grid: ref.Grid | None,
    *,
    particles: int = 0,
    one_step: bool = False,
    restarts: tuple[int, ...] = (),
    resolution: float | None = None,
    axes: str | None = None,
):
    """What :func:`reference_run` checks before anything is solved, in one line naming what
    does not fit (a random user, a learner without a covariance or a model, an option its
    model or k cannot take); returns the learner, its likelihood, its grid model's class and
    the particle engine (None without ``particles``)."""
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
    kind = GRID_MODELS[likelihood.kind]
    engine = particle_reference(model, learner, particles) if particles else None
    if grid is None and (engine is None or one_step or restarts):
        raise ValueError(
            f"k = {study.k}: no grid beyond k = 2 without a plan atlas (--particles N is the "
            "reference there; --one-step and --restart need the grid)"
        )
    if grid is not None:  # the learner's parameters, as its grid model reads them
        thetas = grid.thetas()
        kind(
            learner, likelihood, model, study, thetas, ref.gaussian_log_prior(thetas, study.prior())
        )
    if (one_step or restarts) and not kind.filtered:
        raise ValueError(
            f"learner {learner}: --one-step and --restart need a Kalman learner with N fixed"
        )
    if resolution is not None and not (np.isfinite(resolution) and resolution >= 0):
        raise ValueError(f"--resolution {resolution!r}: expected a number >= 0")
    refinable = settings.atlas_spec() is not None and grid is not None and kind.refinable
    if resolution is not None and resolution > 0 and not refinable:
        raise ValueError(
            f"--resolution {resolution:g}: refines only a KF/KF-C-type model's grid on a study "
            "with a plan atlas"
        )
    if axes is not None:
        if axes not in ref.REFINED_AXES:
            raise ValueError(f"--axes {axes}: expected one of {', '.join(ref.REFINED_AXES)}")
        if not refinable:
            raise ValueError(
                f"--axes {axes}: cuts only a refined grid's cells (a KF/KF-C-type model's, on "
                "a study with a plan atlas)"
            )
    return model, likelihood, kind, engine


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
    axes: str | None = None,
) -> list[dict]:
    """The reference after every correction of one run (``rows``: its records, t = 0 … T).

    With ``particles`` > 0 the particle machinery of PF-C (:mod:`~.learning.particles`) with
    that many particles also runs on the same corrections under the learner's model (KF/KF-C
    types with N fixed), seeded by ``seed``: where the grid exists (``grid`` not None) it is
    judged against the grid (``particle_kl``, KL from the grid to the smoothed particles,
    :func:`~.learning.particles.cloud.against_grid`; ``particle_mean_gap``,
    the largest |Δ mean| in the grid's sd; ``particle_var_gap``, the largest relative
    |Δ variance|); without a grid (k > 2 without a plan atlas) it *is* the reference (its
    moments; no ``ref_kl``, only its Gaussian part ``ref_kl_gaussian``).

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
    weighed again at the finer nodes, ξ*(θ, E) there from the atlas over ``grid``; its cells
    cut as ``axes`` says ("all" or "narrow"; None: as the learner cuts its own, "all" for a
    filter, whose cells are not its own: "narrow" makes a filter's reference at k = 3
    affordable, as it makes the exact learners there)."""
    model, likelihood, kind, engine = check_reference(
        settings, learner, grid, particles=particles, one_step=one_step, restarts=restarts,
        resolution=resolution, axes=axes,
    )  # fmt: skip
    study = settings.study
    k, names = study.k, planner.config.features
    envs = {e.name: e for e in settings.envs()}
    theta_star = np.array(study.theta_star)  # the learners' part, what NEES is against
    target = settings.person_target(list(envs.values()))
    intended = dict(zip(envs, (p.trajectory for p in target.plans), strict=True))
    thetas = grid.thetas() if grid is not None else np.zeros((1, k))
    log_p = ref.gaussian_log_prior(thetas, study.prior())
    out = []
    grid_model = None if grid is None else kind(learner, likelihood, model, study, thetas, log_p)
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
    refinable = at_nodes is not None and kind.refinable
    cells, past = None, []  # a refinable grid's cells; the corrections so far, to weigh again
    if refinable:
        # The core to e^−13.8 = 1e-6 of the peak, not an exact learner's 1e-4; its cells cut
        # as the learner cuts its own.
        resolution = 2.0 if resolution is None else resolution
        refine = ref.Refinement(resolution, cut=13.8, axes=axes or likelihood.axes)
        # One level finer than an exact learner may go: at twice its resolution, it is at
        # half its finest spacing.
        depth = likelihood.max_level + 1
        cells = Cells.base(box.lows, box.highs, box.counts, depth)
        thetas = cells.thetas()
        log_p = ref.gaussian_log_prior(thetas, study.prior())
        grid_model = kind(learner, likelihood, model, study, thetas, log_p)
    c = likelihood.correction
    correct = c.apply_many if c is not None else (lambda r, x: np.asarray(x, float))
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
            start = ref.moments(thetas, ref.posterior(grid_model.density(), at))
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
        if grid_model is None:
            log_post = None
        elif cells is not None:
            # Weighed where the posterior is within the margin of its peak; elsewhere the
            # correction waits until the peak may come near (GridModel.settle), as in an
            # exact learner.
            at = ref.near_peak(grid_model.posterior())
            plans = at_nodes.plans(thetas[at], env)
            h = grid_observations(plans, robot.trajectory, correct, env, names)
            seen_here = Seen(z, robot, plans, h, outcome.corrected, row, before)
            grid_model.correct(seen_here, at)
            past.append((env, robot.trajectory))

            def observe(j, points, past=past):
                e, r = past[j]
                plans_there = at_nodes.plans(grid_model.thetas[points], e)
                return grid_observations(plans_there, r, correct, e, names)

            log_post = grid_model.settle(observe)
            judged = grid_model.judged
            while (finer := refine.finer(cells, log_post)) is not None:
                new = finer.thetas()[len(thetas) :]
                new_hs = [
                    grid_observations(at_nodes.plans(new, e), r, correct, e, names) for e, r in past
                ]
                new_p = ref.gaussian_log_prior(new, study.prior())
                log_post = grid_model.refined(new, new_p, new_hs)
                cells, thetas = finer, finer.thetas()
        else:
            plans = h = None
            if kind.needs_plans:
                if at_nodes is None:
                    plans = grid_plans(planner, env, grid)
                else:
                    plans = at_nodes.plans(thetas, env)
                h = grid_observations(plans, robot.trajectory, correct, env, names)
            seen_here = Seen(z, robot, plans, h, outcome.corrected, row, before)
            log_post = grid_model.correct(seen_here)
            judged = grid_model.judged
        coefficients = None if cells is None else cells.coefficients
        belief = _belief(row, k)
        if log_post is None:  # the particles are the reference
            weights = None
            mean, cov = cloud.theta, cloud.cov  # the particles' moments
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
            rec |= against_grid(cloud, thetas, weights, mean, cov, coefficients)
        if judged:
            rec["relevance"] = float(row["relevance"]) if row.get("relevance") else None
            rec |= judged
        if one_step:
            step = _filter_step(model, grid_model, study, book, env, robot, z, start, row)
            rec["one_step_nees"] = ref.nees(step.theta, step.cov, theta_star)
            rec["one_step_kl"] = ref.kl_to_gaussian(grid, thetas, weights, step, coefficients)
        for s, state in restarted.items():
            state = (state.theta, state.cov)
            state = _filter_step(model, grid_model, study, book, env, robot, z, state, row)
            restarted[s] = state
            rec[f"restart_{s}_nees"] = ref.nees(state.theta, state.cov, theta_star)
        out.append(rec)
    return out


@dataclass(frozen=True)
class Judged:
    """What a reference of some runs found (``reference_figure.judged``): every record, the
    summary at each iteration (the last is the final one) and, with ``check_grid``, how much
    the first run's reference moves on the halved grid (points per axis before and after, the
    largest move of a mean in its sd and of a variance, relative)."""

    learner: str
    records: list[dict]
    by_iteration: list[dict]
    grid_check: tuple[int, int, float, float] | None = None


def reference_grid(settings: FigureSettings, points: int | None) -> ref.Grid | None:
    """The reference's grid: on a study with a plan atlas its box (at any k), at its spacing
    unless ``points`` is given; else, at k = 2 only, [-3, 3]² with ``points`` (61) a side;
    None beyond k = 2 without an atlas."""
    k, spec = settings.study.k, settings.atlas_spec()
    if spec is not None:
        box = spec.grid
        return ref.Grid(box.lows, box.highs, points or box.counts[0])
    return ref.Grid((-3.0,) * k, (3.0,) * k, points or 61) if k == 2 else None


def report_lines(judged: Judged, particles: int = 0) -> list[str]:
    """The table of the means over runs at each iteration and what the final one says, as
    the command prints them."""
    by_t, final = judged.by_iteration, judged.by_iteration[-1]
    lines = [
        f"(means over {len({r['run'] for r in judged.records})} runs; 95% intervals over runs)",
        f"{'t':>3} {'ref NEES':>9} {'NEES':>7} {'NEES / ref NEES':>22} {'ref_kl':>22} "
        f"{'Gaussian part':>22}",
    ]
    for row in by_t:
        ratio = f"{row['ratio']:.2f} [{row['ratio_ci95'][0]:.2f}, {row['ratio_ci95'][1]:.2f}]"
        kl = (
            f"{row['ref_kl']:.3f} [{row['ref_kl_ci95'][0]:.3f}, {row['ref_kl_ci95'][1]:.3f}]"
            if "ref_kl" in row
            else "-"
        )
        lo, hi = row["ref_kl_gaussian_ci95"]
        gauss = f"{row['ref_kl_gaussian']:.3f} [{lo:.3f}, {hi:.3f}]"
        lines.append(
            f"{row['iteration']:>3} {row['ref_nees']:9.2f} {row['nees']:7.2f} {ratio:>22} "
            f"{kl:>22} {gauss:>22}"
        )
    kl_text = (
        f"ref_kl = {final['ref_kl']:.3f} [{final['ref_kl_ci95'][0]:.3f}, "
        f"{final['ref_kl_ci95'][1]:.3f}], of which Gaussian "
        if "ref_kl" in final
        else "the reference is the particles': ref_kl's Gaussian part "
    )
    lines.append(
        f"t = {final['iteration']}: NEES / reference NEES = {final['ratio']:.2f} "
        f"[{final['ratio_ci95'][0]:.2f}, {final['ratio_ci95'][1]:.2f}], {kl_text}"
        f"{final['ref_kl_gaussian']:.3f} (95% intervals over {final['runs']} runs)"
    )
    if "particle_kl" in final:
        lines.append(
            f"{particles} particles against the grid: KL (smoothed on the grid) "
            f"{final['particle_kl']:.3f}, mean within {final['particle_mean_gap']:.1%} of an "
            f"sd, variances within {final['particle_var_gap']:.1%}, ESS "
            f"{final['particle_ess']:.0f}"
        )
    if "one_step_ratio" in final:
        low, high = final["one_step_ratio_ci95"]
        lines.append(
            f"one filter step from the reference: NEES / reference NEES = "
            f"{final['one_step_ratio']:.2f} [{low:.2f}, {high:.2f}], KL "
            f"{final['one_step_kl']:.3f}"
        )
    if "relevance_gap" in final:
        lines.append(
            f"β̂ against the exact one: mean |gap| {final['relevance_gap']:.3f} (largest "
            f"{final['relevance_gap_max']:.3f}); the same side of 1/2 for "
            f"{final['relevance_agree']:.0%} of the corrections"
        )
    for key, value in final.items():
        if key.startswith("restart_"):
            at = key.split("_")[1]
            lines.append(
                f"the filter from the reference at t = {at} on: NEES / ref NEES {value:.2f}"
            )
    if judged.grid_check is not None:
        points, finer, worst_mean, worst_cov = judged.grid_check
        lines.append(
            f"grid {points} -> {finer} points per axis: the mean moves by at most "
            f"{worst_mean:.2%} of its sd, the variances by {worst_cov:.2%}"
        )
    return lines


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
