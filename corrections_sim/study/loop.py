"""One learner, one simulated user, N iterations of corrections -> tidy records (paper §6).

Each iteration t: the environment Eᵗ is drawn (uniformly at random, or by eq. (A1) for the
active learners), the robot plans ξᵗ = ξ*(θ̂ᵗ, Eᵗ), the user corrects it, the learner updates
its belief. Every record describes the belief *after* t corrections (t = 0 is the prior):
estimate error and regret summed over all environments (see :mod:`corrections_sim.metrics`),
θ̂ and every entry of P, and the belief's calibration (:mod:`corrections_sim.calibration`):
NEES against θ* and the NIS of the correction that led to it.

Planner solves are memoized per run (:class:`PlanBook`): the robot's own trajectory, the
UKF's mean sigma point and the regret in Eᵗ are one solve, not three. Plans every run shares
(those of the common prior θ̂⁰) can be solved once and handed to each run's book.

Learners and simulated users are plug-ins, registered by name
(:data:`~corrections_sim.learning.base.LEARNERS`, :data:`~corrections_sim.people.users.USERS`);
the loop
calls their protocols (:class:`~corrections_sim.learning.base.Learner`,
:class:`~corrections_sim.people.users.User`) and knows none by name. The paper's learners are in
:mod:`corrections_sim.learning.roster`.

Everything random flows from ``np.random.Generator`` objects made from the study's seed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from corrections_sim import calibration
from corrections_sim.learning import correction
from corrections_sim.learning.base import LEARNERS, Step
from corrections_sim.learning.relevance import expansion
from corrections_sim.metrics import estimate_error, regret_terms
from corrections_sim.people.users import Situation, TaskOutcome, User
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import (
    Planner,
    PlanningError,
    shared_planner,
    smoothness_cost,
)
from corrections_sim.plans.atlas import Atlas
from corrections_sim.plans.book import PlanBook, PlanEntries, Target, evaluate
from corrections_sim.scene.environments import Environment

if TYPE_CHECKING:
    from corrections_sim.belief import Belief
    from corrections_sim.study.settings import StudySettings


@dataclass(frozen=True)
class RunResult:
    """Records of one learner run and the Kalman gains it used (for PP's learning rate)."""

    records: tuple[dict, ...]
    gains: np.ndarray  # (iterations, k, k); NaN where no update happened
    solves: int


def run_learner(
    learner: str,
    run: int,
    settings: StudySettings,
    planner: Planner,
    envs: Sequence[Environment],
    target: Target,
    user: User,
    rng: np.random.Generator,
    alphas: np.ndarray | None = None,
    known: PlanEntries | None = None,
    plan_book: type[PlanBook] = PlanBook,
    atlas: Atlas | None = None,
    watch: Callable[[int, Belief], None] | None = None,
) -> RunResult:
    """One run of ``learner`` (a name in :data:`LEARNERS`) for ``settings.iterations``
    corrections.

    Args:
        alphas: a PP-type learner's learning rate per iteration (iterations,); required.
        rng: this run's generator: draws the environments (up front, whether the learner
            uses them or not, so learners on one stream see the same ones) and the user's noise.
        known: plans solved before the run (see :class:`PlanBook`); the results are the same
            with or without them, only the solve count differs.
        plan_book: the class that memoizes the run's plans (a benchmark passes a subclass
            that records what it solves).
        atlas: the study's plan atlas (every plan over the study's features from it), or
            None. A learner that learns a feature plans over features the atlas lacks: those
            plans come from a book of their own, warm-started as ``settings.warm_start`` says.
        watch: called as watch(t, belief) with the belief after every correction t (and the
            prior, t = 0): what simulation-based calibration draws its posterior samples from
            (:mod:`corrections_sim.figures.sbc`); nothing it does changes the run.
    """
    cls = LEARNERS[learner]
    if cls.needs_rates() and alphas is None:
        raise ValueError(f"alphas: {learner} needs a learning rate per iteration")
    agent = settings.learners[learner]
    book = plan_book(planner, known, warm_start=settings.warm_start, atlas=atlas)
    names = planner.config.features
    # A learner that learns features (belief.extra) plans over more: one book per feature list.
    books = {names: book}

    def book_for(b) -> PlanBook:
        mine = names + tuple(b.extra)
        if mine not in books:
            config = replace(planner.config, features=mine)
            books[mine] = plan_book(shared_planner(config), warm_start=settings.warm_start)
        return books[mine]

    def teach(n: int, env: Environment, current: tuple[str, ...]) -> list[np.ndarray] | None:
        """The person's traces of the feature they mind most that the robot lacks (None:
        there is none)."""
        missing = expansion.missing_feature(target, current)
        if missing is None:
            return None
        return settings.teacher.traces(missing, n, env, rng)

    noise, sigma = settings.noise(), settings.sigma()
    belief = agent.initial(settings.prior(), noise)
    k, n_iter = settings.k, settings.iterations
    # Drawn up front so PP and KF run r see the same environments (common random numbers).
    draws = rng.integers(len(envs), size=n_iter)
    # θ* on the learners' features: what error and NEES compare against (the person may weigh
    # more; their regret is over all of theirs, see `evaluate`).
    known = np.array(settings.theta_star, float)
    gains = np.full((n_iter, k, k), np.nan)
    records = []

    learnt: dict = {}  # what the loop measured of a learnt feature (against the person's)

    def record(t: int, env_name: str, skipped: str, step: Step | None, task: dict) -> None:
        regret, paper, failed = evaluate(book_for(belief), target, envs, belief.theta)
        rec = {
            "learner": learner,
            "run": run,
            "iteration": t,
            "environment": env_name,
            "estimate_error": estimate_error(belief.theta[:k], known),
            "regret": regret,
            "regret_paper": paper,
            "regret_failures": failed,
            "update_skipped": skipped,
        }
        rec |= belief_columns(belief, step, known, cls.has_covariance)
        rec |= expansion.columns(belief, step, learnt, k)
        rec |= task
        records.append(rec)
        if watch is not None:
            watch(t, belief)

    record(0, "", "", None, {})
    for t in range(n_iter):
        book = book_for(belief)
        current = names + tuple(belief.extra)
        ctx = correction.context(
            belief,
            noise,
            book=book,
            envs=envs,
            features=current,
            n_waypoints=planner.config.n_waypoints,
            alphas=alphas,
            rng=rng,
            sigma=sigma,
            iteration=t,
            teach=lambda n, env, current=current: teach(n, env, current),
        )
        idx = _index(learner, agent.choose(ctx, belief, int(draws[t])), len(envs))
        env = envs[idx]
        skipped = ""
        step = None
        task: dict = {}
        try:
            mine = book.plan(belief.theta, env)
            situation = Situation(
                robot=mine.trajectory,
                intended=target.plans[idx].trajectory,
                env=env,
                features=names,
                theta_star=target.theta_star,
            )
            online: list[Step] = []

            def replan(
                deformed,
                q_now,
                t_now,
                ctx=ctx,
                env=env,
                mine=mine,
                online=online,
                prior=belief,
                current=current,
                book=book,
            ):
                """Online: learn from the push now and plan anew (the arm joins the new plan
                where it is; None, the old plan goes on, when the planner finds none). The
                plan is the book's, so the regret that follows reuses it."""
                phi = feature_counts(deformed, env, current)
                online.append(correction.step(agent, ctx, prior, env, mine, phi, deformed))
                try:
                    return book.plan(online[0].belief.theta, env).trajectory
                except PlanningError:
                    return None

            outcome = user.perform(situation, rng, replan if settings.online else None)
            task = _task_columns(outcome, target, idx, env, planner)
            label = _relevant(outcome, settings, known)
            if label is not None:
                task["relevant"] = label
            if online:
                step = online[0]
            else:
                phi_h = correction.seen_features(belief, ctx, env, outcome.corrected, outcome.phi_h)
                step = correction.step(agent, ctx, belief, env, mine, phi_h, outcome.corrected)
            belief = step.belief
            if step.gain is not None:
                gains[t] = step.gain[:k, :k]
            if step.expansion is not None and step.expansion.get("taught"):
                learnt.update(expansion.quality_of(step.expansion["feature"], target, current, env))
                learnt["expanded_at"] = t + 1
                learnt["variance"] = step.expansion.get("variance")
                learnt["noise"] = step.expansion.get("noise")
        except PlanningError as exc:
            skipped = str(exc).splitlines()[0]
        record(t + 1, env.name, skipped, step, task)
    return RunResult(records=tuple(records), gains=gains, solves=book.solves)


def belief_columns(
    belief, step: Step | None, reference: np.ndarray | None, has_covariance: bool
) -> dict:
    """A record's belief and calibration columns: θ̂ (``theta_i``), P (``cov_ij``, i ≤ j), N̂
    (``noise_ij``) for a learner that learns N, NEES against ``reference`` and the NIS of
    ``step``. None (an empty CSV cell) where there is nothing to normalize by: no covariance
    (the perceptron), no reference, and for the prior no innovation. A learner that learnt
    features has more θ̂ and P entries; its NEES is over the study's features' block."""
    k = len(belief.theta)
    rec: dict = {f"theta_{i}": float(belief.theta[i]) for i in range(k)}
    upper = [(i, j) for i in range(k) for j in range(i, k)]
    rec |= {f"cov_{i}{j}": float(belief.cov[i, j]) for i, j in upper}
    rec |= belief.state.columns()  # its family's: N̂ (``noise_ij``), the person's rate, …
    known = slice(0, k - len(belief.extra))
    rec["nees"] = (
        calibration.nees(belief.theta[known], belief.cov[known, known], reference)
        if has_covariance and reference is not None
        else None
    )
    rec["nis"] = (
        calibration.nis(step.innovation, step.innovation_cov)
        if step is not None and step.innovation_cov is not None
        else None
    )
    if step is not None and step.relevance is not None:
        rec["relevance"] = float(step.relevance)
        rec["relevance_residual"] = None if step.residual is None else float(step.residual)
    return rec


def _task_columns(outcome: TaskOutcome, target: Target, idx: int, env, planner: Planner) -> dict:
    """A task's own columns, for a user who corrects during the motion: the regret of the
    motion the person got (``executed_regret``, the planner's full objective under θ*, as
    ``regret``), with online replanning also that of the motion kept on the old plan
    (``executed_regret_kept``), and the user's numbers (effort, push time, …)."""
    if outcome.executed is None:
        return {}
    star = target.plans[idx]
    lam = planner.config.smoothness
    names = planner.config.features

    def regret(motion: np.ndarray) -> float:
        full, _ = regret_terms(
            target.theta_star,
            star.features,
            smoothness_cost(star.trajectory),
            feature_counts(motion, env, target.features or names),
            smoothness_cost(motion),
            lam,
        )
        return full

    columns = {"executed_regret": regret(outcome.executed)}
    if outcome.executed_kept is not None:
        columns["executed_regret_kept"] = regret(outcome.executed_kept)
    return columns | {key: float(value) for key, value in outcome.extras.items()}


def _relevant(outcome: TaskOutcome, settings: StudySettings, known: np.ndarray) -> float | None:
    """The ground-truth label of a correction for scoring relevance (1 relevant, 0 not), or
    None where every correction is relevant by construction (no column then). A correction is
    relevant when the person made it toward their own plan (not a nudge) and that plan weighs
    at least one of the learners' features; a person whose θ* weighs only features the robot
    lacks makes none."""
    if outcome.relevant is None and not settings.user_theta:
        return None
    made = True if outcome.relevant is None else bool(outcome.relevant)
    return float(made and bool(np.any(known != 0.0)))


def _index(learner: str, idx, n: int) -> int:
    """A learner's choice of environment, refused unless it is an index into the n."""
    if isinstance(idx, bool) or not isinstance(idx, int | np.integer) or not 0 <= idx < n:
        raise ValueError(f"learner {learner}: chose environment {idx!r}, not an index in [0, {n})")
    return int(idx)
