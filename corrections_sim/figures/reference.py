"""The exact posterior beside a learner's Gaussian, for the runs of a finished learning figure.

    python -m corrections_sim.figures.reference results/quick/fig4 --learner KF-C --runs 2

For each chosen run of a Gaussian learner, the posterior p(θ | corrections) is computed on a
grid (:mod:`corrections_sim.learning.reference`) under exactly the model the learner assumes:
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

import argparse
import csv
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

from corrections_sim.belief import Belief, PersonBelief
from corrections_sim.figures.output import write_records
from corrections_sim.learning import reference as ref
from corrections_sim.learning.paper import (
    BoltzmannPosterior,
    CorrectionAwareKalman,
    PersonRelevanceKalman,
    RelevanceAwareKalman,
    UnscentedKalman,
)
from corrections_sim.learning.relevance import (
    MOVED,
    NUDGE_DIMENSIONS,
    beta_rho_density,
    embed,
    random_direction_shape,
)
from corrections_sim.people.users import Situation
from corrections_sim.planning.features import waypoint_features
from corrections_sim.planning.planner import Planner, PlanningError, build_key, cache_dir
from corrections_sim.planning.plans import PlanBook
from corrections_sim.scene.environments import Environment
from corrections_sim.study import schema
from corrections_sim.study.settings import FigureSettings


def grid_plans(planner: Planner, env: Environment, grid: ref.Grid) -> np.ndarray:
    """ξ*(θ, E) at every grid point, (n, T, 7); NaN where the planner found none. Solved in
    a snake order, each from its neighbour's plan, and cached by planner, environment and grid."""
    key = hashlib.sha256(
        f"{build_key(planner.config)}|{env.key().hex()}|{grid}".encode()
    ).hexdigest()[:20]
    path = cache_dir() / "reference" / f"{key}.npy"
    if path.is_file():
        return np.load(path)
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
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{hashlib.sha256(str(id(plans)).encode()).hexdigest()[:6]}.tmp.npy")
    np.save(tmp, plans)
    tmp.replace(path)
    return plans


def _filter_step(model, study, book: PlanBook, env, robot, z, start, row) -> Belief:
    """The learner's update of the correction ``z`` to the robot's plan ``robot``, from the
    Gaussian N(``start``) (the reference's moments before it): the UKF with the learner's
    observation model and noise (N / β̂ for a relevance-aware learner, its β̂ from the
    record)."""
    from corrections_sim.belief import KalmanNoise
    from corrections_sim.learning.kalman import ukf_update
    from corrections_sim.learning.paper import correction_observer

    names = book.planner.config.features
    if isinstance(model, CorrectionAwareKalman):
        observe = correction_observer(book, env, robot.trajectory, model.model, names)
    else:
        observe = book.observe(env)
    noise = study.noise()
    if isinstance(model, RelevanceAwareKalman) and row.get("relevance"):
        beta = float(row["relevance"])
        noise = KalmanNoise(process=noise.process, observation=noise.observation / beta)
    prior = Belief(theta=start[0], cov=start[1])
    step = ukf_update(prior, observe, z, noise, study.sigma(), reference=robot.features)
    return step.belief


def grid_observations(plans: np.ndarray, robot: np.ndarray, correct, env, names) -> np.ndarray:
    """h(θ) at every grid point (n, k): Φ of ``correct(robot, ξ*(θ))``, NaN where the grid
    has no plan; the features of every corrected trajectory in one call."""
    n, T = plans.shape[:2]
    finite = np.all(np.isfinite(plans), axis=(1, 2))
    out = np.full((n, len(names)), np.nan)
    if finite.any():
        corrected = np.stack([correct(robot, p) for p in plans[finite]])
        per_waypoint = waypoint_features(corrected.reshape(-1, 7), env.params(), names)
        out[finite] = per_waypoint.reshape(-1, T, len(names)).sum(axis=1)
    return out


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


def _rows(folder: Path, learner: str) -> dict[int, list[dict]]:
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
) -> list[dict]:
    """The reference after every correction of one run (``rows``: its records, t = 0 … T).

    With ``one_step`` (a Kalman learner with N fixed), also the learner's own update started
    from the reference before the correction (its moments), as ``one_step_nees`` and
    ``one_step_kl`` against the reference after it: the error of one step of the filter, apart
    from what earlier steps left (which the learner's own NEES and ``ref_kl`` include). With
    ``restarts`` (iterations s), also the learner's filter run on from the reference at each s
    (s = 0: the prior, i.e. the learner replayed), as ``restart_<s>_nees``: how much of the
    final gap the steps before s leave."""
    study = settings.study
    model = study.learners[learner]
    if study.user.stochastic:
        raise ValueError(
            f"user {study.user_name}: draws random numbers; its corrections cannot be replayed"
        )
    if not isinstance(model, UnscentedKalman | BoltzmannPosterior):
        raise ValueError(f"learner {learner}: no reference for it (KF-type learners and BP)")
    if isinstance(model, RelevanceAwareKalman) and model.noise == "learnt":
        raise ValueError(f"learner {learner}: no reference for relevance with N learnt")
    k, names = study.k, planner.config.features
    envs = {e.name: e for e in settings.envs()}
    theta_star = np.array(study.theta_star)  # the learners' part, what NEES is against
    target = settings.person_target(list(envs.values()))
    intended = dict(zip(envs, (p.trajectory for p in target.plans), strict=True))
    thetas = grid.thetas()
    log_p = ref.gaussian_log_prior(thetas, study.prior())
    noise = study.noise().observation
    learnt = isinstance(model, UnscentedKalman) and model.noise == "learnt"
    prior_noise = model.initial(study.prior(), study.noise()).noise if learnt else None
    zs, hs, out = [], [], []
    person = None
    if isinstance(model, PersonRelevanceKalman):
        _, (shape, rate), _ = model.densities()
        a = model.relevance_prior * model.relevance_count
        b = (1.0 - model.relevance_prior) * model.relevance_count
        fine = PersonBelief.prior(shape, rate, a, b, tau_points=PERSON_TAU_NODES, rate_points=41)
        person = ref.PersonPosterior.prior(thetas, log_p, fine)
    if (one_step or restarts) and (
        person is not None or not (isinstance(model, UnscentedKalman) and not learnt)
    ):
        raise ValueError(
            f"learner {learner}: --one-step and --restart need a Kalman learner with N fixed"
        )
    book = PlanBook(planner)
    restarted: dict[int, Belief] = {}
    for row in rows[1:]:
        start = ref.moments(thetas, ref.posterior(log_p)) if one_step or restarts else None
        t = int(row["iteration"])
        for s in restarts:
            if s == t - 1:
                restarted[s] = study.prior() if s == 0 else Belief(theta=start[0], cov=start[1])
        t, env = int(row["iteration"]), envs[row["environment"]]
        before = _belief(rows[t - 1], k)
        robot = planner.solve(before.theta, env)
        seen = Situation(robot.trajectory, intended[env.name], env, names, target.theta_star)
        outcome = study.user.perform(seen, np.random.default_rng(0))
        z = np.asarray(outcome.phi_h, float)
        judged = {}
        if isinstance(model, BoltzmannPosterior):
            betas = model.correction_model(0.0).betas
            log_l = ref.boltzmann_log_likelihood(thetas, z - robot.features, betas, model.lapse)
            log_p = log_p + log_l
            log_post = log_p
        else:
            plans = grid_plans(planner, env, grid)
            correct = (
                model.model.apply if isinstance(model, CorrectionAwareKalman) else (lambda r, x: x)
            )
            h = grid_observations(plans, robot.trajectory, correct, env, names)
            if person is not None:
                plans_rho = grid_residuals(
                    plans, robot.trajectory, outcome.corrected, model.model, model.space
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
            elif isinstance(model, RelevanceAwareKalman):
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
        weights = ref.posterior(log_post)
        mean, cov = ref.moments(thetas, weights)
        belief = _belief(row, k)
        rec = {"learner": learner, "run": int(row["run"]), "iteration": t, "environment": env.name}
        for i in range(k):
            rec[f"ref_theta_{i}"] = float(mean[i])
        for i in range(k):
            for j in range(i, k):
                rec[f"ref_cov_{i}{j}"] = float(cov[i, j])
        rec["ref_nees"] = ref.nees(mean, cov, theta_star)
        rec["nees"] = float(row["nees"]) if row["nees"] else None
        rec["ref_kl"] = ref.kl_to_gaussian(grid, thetas, weights, belief)
        rec["ref_kl_gaussian"] = ref.gaussian_kl(mean, cov, belief)
        if judged:
            rec["relevance"] = float(row["relevance"]) if row.get("relevance") else None
            rec |= judged
        if one_step:
            step = _filter_step(model, study, book, env, robot, z, start, row)
            rec["one_step_nees"] = ref.nees(step.theta, step.cov, theta_star)
            rec["one_step_kl"] = ref.kl_to_gaussian(grid, thetas, weights, step)
        for s, state in restarted.items():
            state = _filter_step(model, study, book, env, robot, z, (state.theta, state.cov), row)
            restarted[s] = state
            rec[f"restart_{s}_nees"] = ref.nees(state.theta, state.cov, theta_star)
        out.append(rec)
    return out


def final_summary(records: list[dict], *, resamples: int = 2000) -> dict:
    """At the last iteration, over runs: NEES / reference NEES as the ratio of the means with
    a 95% bootstrap interval over runs (seeded, so the same records give the same interval),
    and ``ref_kl``'s mean with its 95% t-interval."""
    from scipy import stats

    last = max(r["iteration"] for r in records)
    at = [r for r in records if r["iteration"] == last and r["nees"] is not None]
    nees = np.array([r["nees"] for r in at], float)
    ref_nees = np.array([r["ref_nees"] for r in at], float)
    kl = np.array([r["ref_kl"] for r in at], float)
    n = len(at)
    picks = np.random.default_rng(0).integers(n, size=(resamples, n))

    def ratio_ci(values: np.ndarray) -> list[float]:
        """95% bootstrap interval over runs of mean(values) / mean(reference NEES)."""
        boot = values[picks].mean(axis=1) / ref_nees[picks].mean(axis=1)
        return [float(np.quantile(boot, 0.025)), float(np.quantile(boot, 0.975))]

    half = float(stats.t.ppf(0.975, n - 1) * kl.std(ddof=1) / np.sqrt(n)) if n > 1 else np.nan
    out = {
        "iteration": last,
        "runs": n,
        "nees": float(nees.mean()),
        "ref_nees": float(ref_nees.mean()),
        "ratio": float(nees.mean() / ref_nees.mean()),
        "ratio_ci95": ratio_ci(nees),
        "ref_kl": float(kl.mean()),
        "ref_kl_ci95": [float(kl.mean() - half), float(kl.mean() + half)],
        "ref_kl_gaussian": float(np.mean([r["ref_kl_gaussian"] for r in at])),
    }
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


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m corrections_sim.figures.reference", description=__doc__.split("\n\n")[0]
    )
    p.add_argument(
        "folder", type=Path, help="a finished learning figure's folder (curves.csv, summary.json)"
    )
    p.add_argument("--learner", default="KF-C")
    p.add_argument("--runs", type=int, default=2, help="how many runs (the first N)")
    p.add_argument("--points", type=int, default=61, help="grid points per axis over [-3, 3]^2")
    p.add_argument(
        "--one-step",
        action="store_true",
        help="also the learner's update from the reference before each correction (a Kalman "
        "learner with N fixed): the error of one filter step, apart from accumulation",
    )
    p.add_argument(
        "--restart",
        default="",
        metavar="S,S",
        help="also the learner's filter run on from the reference at these iterations (0: the "
        "prior): NEES / reference NEES at the end for each",
    )
    p.add_argument(
        "--check-grid",
        action="store_true",
        help="also on the halved grid (first run): how much mean and covariance move",
    )
    args = p.parse_args(argv)
    try:
        summary = json.loads((args.folder / "summary.json").read_text())
        settings = schema.parse_study(summary["settings"], name=summary.get("figure", ""))
        if args.learner not in settings.study.learners:
            known = ", ".join(settings.study.learners)
            raise ValueError(f"--learner {args.learner}: not in this figure ({known})")
        runs = _rows(args.folder, args.learner)
        try:
            restarts = tuple(sorted({int(v) for v in args.restart.split(",") if v.strip()}))
        except ValueError:
            raise ValueError(f"--restart {args.restart}: expected iterations like 0,1,4") from None
        if any(s < 0 for s in restarts):
            raise ValueError(f"--restart {args.restart}: iterations are >= 0")
        grid = ref.Grid((-3.0,) * settings.study.k, (3.0,) * settings.study.k, args.points)
        planner = Planner(settings.planner_config())
        records = []
        for run in sorted(runs)[: args.runs]:
            records += reference_run(
                settings,
                args.learner,
                runs[run],
                grid,
                planner,
                one_step=args.one_step,
                restarts=restarts,
            )
            print(f"run {run}: done", file=sys.stderr, flush=True)
    except (OSError, KeyError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    path = write_records(args.folder / f"reference-{args.learner}.csv", records)
    n_runs = len({r["run"] for r in records})
    print(
        f"{'t':>3} {'ref NEES':>9} {'learner NEES':>13} {'ref_kl':>8}  (means over {n_runs} runs)"
    )
    for t in sorted({r["iteration"] for r in records}):
        at = [r for r in records if r["iteration"] == t]
        means = [np.mean([r[key] for r in at]) for key in ("ref_nees", "nees", "ref_kl")]
        print(f"{t:>3} {means[0]:9.2f} {means[1]:13.2f} {means[2]:8.3f}")
    final = final_summary(records)
    (args.folder / f"reference-{args.learner}.json").write_text(
        json.dumps({"learner": args.learner, **final}, indent=1) + "\n"
    )
    print(
        f"t = {final['iteration']}: NEES / reference NEES = {final['ratio']:.2f} "
        f"[{final['ratio_ci95'][0]:.2f}, {final['ratio_ci95'][1]:.2f}], ref_kl = "
        f"{final['ref_kl']:.3f} [{final['ref_kl_ci95'][0]:.3f}, {final['ref_kl_ci95'][1]:.3f}] "
        f"(95% intervals over {final['runs']} runs), of which Gaussian "
        f"{final['ref_kl_gaussian']:.3f}"
    )
    if "one_step_ratio" in final:
        low, high = final["one_step_ratio_ci95"]
        print(
            f"one filter step from the reference: NEES / reference NEES = "
            f"{final['one_step_ratio']:.2f} [{low:.2f}, {high:.2f}], KL "
            f"{final['one_step_kl']:.3f}"
        )
    if "relevance_gap" in final:
        print(
            f"β̂ against the exact one: mean |gap| {final['relevance_gap']:.3f} (largest "
            f"{final['relevance_gap_max']:.3f}); the same side of 1/2 for "
            f"{final['relevance_agree']:.0%} of the corrections"
        )
    for key, value in final.items():
        if key.startswith("restart_"):
            at = key.split("_")[1]
            print(f"the filter from the reference at t = {at} on: NEES / ref NEES {value:.2f}")
    if args.check_grid:
        fine = grid.halved()
        first = sorted(runs)[0]
        coarse = [r for r in records if r["run"] == first]
        finer = reference_run(settings, args.learner, runs[first], fine, planner)
        pairs = list(zip(coarse, finer, strict=True))
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
        print(
            f"grid {grid.points} -> {fine.points} points per axis: the mean moves by at most "
            f"{worst_mean:.2%} of its sd, the variances by {worst_cov:.2%}"
        )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
