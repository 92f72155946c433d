"""One learner, one simulated user, N iterations of corrections -> tidy records (paper §6).

Each iteration t: the environment Eᵗ is drawn (PP, KF, EKF: uniformly at random; AL: eq. (A1)),
the robot plans ξᵗ = ξ*(θ̂ᵗ, Eᵗ), the user corrects it, the learner updates its belief. Every
record describes the belief *after* t corrections (t = 0 is the prior): estimate error and
regret summed over all environments (see :mod:`corrections_sim.metrics`).

Planner solves are memoized per run (:class:`PlanBook`): the robot's own trajectory, the
UKF's mean sigma point and the regret in Eᵗ are one solve, not three. Plans every run shares
(those of the common prior θ̂⁰) can be solved once and handed to each run's book.

Learners: "PP" (eq. B5), "KF" (the UKF the paper simulates), "EKF" (eqs. K4–K7 as written,
with H = ∂Φ(ξ*(θ, E))/∂θ by central differences of the planner, step ``ekf_step``; the
solution's parametric sensitivity from CasADi was not used because the kept start of a
multi-start solve and MuJoCo's verification sit outside the NLP), and "AL" (the UKF with
Eᵗ chosen by eq. A1).
Everything random flows from ``np.random.Generator`` objects made from the study's seed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from corrections_sim.environments import Environment
from corrections_sim.human import BiasedUser, NoisyOptimalUser
from corrections_sim.learners import (
    Belief,
    KalmanNoise,
    SigmaPoints,
    ekf_update,
    finite_difference_jacobian,
    perceptron_update,
    select_environment,
    ukf_predicted_covariance,
    ukf_update,
)
from corrections_sim.metrics import estimate_error, regret_terms
from corrections_sim.planner import Plan, Planner, PlanningError, smoothness_cost

LEARNERS = ("PP", "KF", "EKF", "AL")
#: The paper's three; the EKF is opt-in (``learners`` in the settings, ``--learners``).
DEFAULT_LEARNERS = ("PP", "KF", "AL")
USERS = ("biased", "noisy")


@dataclass(frozen=True)
class StudySettings:
    """Resolved settings of one study (a figure's learning curves).

    Attributes:
        theta_star: the user's true preferences θ* (k,).
        theta0: the robot's initial estimate θ̂⁰ (k,).
        cov0: initial covariance P⁰ (k, k), symmetric positive definite.
        iterations: corrections per run.
        runs: runs of PP and KF (AL is deterministic and runs once).
        seed: root of every random draw.
        process_noise: M = process_noise · I.
        observation_noise: N = observation_noise · I.
        sigma_alpha, sigma_beta, sigma_kappa: UKF sigma-point parameters.
        user: "biased" (the paper's one-waypoint user, :class:`~corrections_sim.human.BiasedUser`)
            or "noisy" (Φ(ξ*) plus Gaussian noise of covariance N, the filter's own model).
        user_step: fraction of the way the biased user moves its worst waypoint.
        ekf_step: central-difference step δ of the EKF's Jacobian H (in θ units).
        warm_start: start each new solve of a run from its nearest solved θ in the same
            environment (see :class:`PlanBook`); faster, and history-dependent at the
            level of the solver's tolerance.
        fixed_alpha: if set, PP's learning rate; otherwise αᵗ = mean diag(Kᵗ) over KF runs.
        learners: which learners the study runs, names from ``LEARNERS``.
    """

    theta_star: tuple[float, ...]
    theta0: tuple[float, ...]
    cov0: tuple[tuple[float, ...], ...]
    iterations: int
    runs: int
    seed: int = 0
    process_noise: float = 1e-4
    observation_noise: float = 0.25
    sigma_alpha: float = 1.0
    sigma_beta: float = 2.0
    sigma_kappa: float = 0.0
    user: str = "biased"
    user_step: float = 1.0
    ekf_step: float = 0.05
    warm_start: bool = False
    fixed_alpha: float | None = None
    learners: tuple[str, ...] = field(default=DEFAULT_LEARNERS)

    def __post_init__(self) -> None:
        k = len(self.theta_star)
        if len(self.theta0) != k:
            raise ValueError(
                f"theta0: expected {k} weights like theta_star, got {len(self.theta0)}"
            )
        if not np.all(np.isfinite(np.asarray(self.theta_star, float))):
            raise ValueError(f"theta_star: all weights must be finite, got {self.theta_star}")
        for name in ("iterations", "runs"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
                raise ValueError(f"{name} = {v!r} must be an integer >= 1")
        for name in ("process_noise", "observation_noise"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} = {v} must be finite and >= 0")
        if not self.observation_noise > 0:
            raise ValueError("observation_noise must be > 0")
        if self.fixed_alpha is not None and not self.fixed_alpha > 0:
            raise ValueError(f"fixed_alpha = {self.fixed_alpha} must be > 0")
        unknown = [n for n in self.learners if n not in LEARNERS]
        if unknown or not self.learners or len(set(self.learners)) != len(self.learners):
            raise ValueError(
                f"learners: {list(self.learners)} must be distinct names from {LEARNERS}"
            )
        if self.user not in USERS:
            raise ValueError(f"user = {self.user!r} must be one of {USERS}")
        if not (np.isfinite(self.ekf_step) and self.ekf_step > 0):
            raise ValueError(f"ekf_step = {self.ekf_step} must be finite and > 0")
        # The user and the sigma points validate their own parameters; build them here so
        # a bad value is refused where it enters, not in the middle of a run.
        BiasedUser(step=self.user_step)
        self.sigma()
        # Validates P⁰ (symmetric positive definite) and θ̂⁰ where they enter, under the
        # names the caller used rather than Belief's.
        try:
            self.prior()
        except ValueError as exc:
            message = str(exc).replace("Belief.theta", "theta0").replace("Belief.cov", "cov0")
            raise ValueError(message) from None

    @property
    def k(self) -> int:
        return len(self.theta_star)

    def prior(self) -> Belief:
        return Belief(theta=np.array(self.theta0, float), cov=np.array(self.cov0, float))

    def noise(self) -> KalmanNoise:
        return KalmanNoise.isotropic(self.k, self.process_noise, self.observation_noise)

    def sigma(self) -> SigmaPoints:
        return SigmaPoints(alpha=self.sigma_alpha, beta=self.sigma_beta, kappa=self.sigma_kappa)

    def make_user(self) -> BiasedUser | NoisyOptimalUser:
        """The simulated user these settings name; the noisy one's std is √N per feature."""
        if self.user == "noisy":
            return NoisyOptimalUser(noise=float(np.sqrt(self.observation_noise)))
        return BiasedUser(step=self.user_step)


PlanEntries = dict[tuple[bytes, bytes], "Plan | PlanningError"]
"""Memoized solves: (θ bytes, environment key) -> the plan or the failure."""


class PlanBook:
    """Memoized ξ*(θ, E) for one run: identical problems are solved once.

    Failures are memoized too (as the exception), so a failing problem costs one solve.
    ``known`` seeds the book with plans solved elsewhere (e.g. the shared prior's, see
    :meth:`entries`); they count as neither solves nor failures here.

    With ``warm_start``, a new problem starts from the book's plan in the same environment
    whose θ is nearest (Euclidean; the first solved wins a tie), and falls back to the
    planner's cold starts if that fails. Along a run θ̂ moves in small steps, so this saves
    IPOPT iterations; the answer can then depend on what was solved before (the same local
    optimum up to the solver's tolerance when the landscape has one basin nearby, see README).
    """

    def __init__(
        self, planner: Planner, known: PlanEntries | None = None, *, warm_start: bool = False
    ) -> None:
        self.planner = planner
        self.warm_start = warm_start
        self._plans: dict[tuple[bytes, bytes], Plan | PlanningError] = dict(known or {})
        # Per environment, the converged plans in the order they were solved: (θ (k,), plan).
        self._by_env: dict[bytes, list[tuple[np.ndarray, Plan]]] = {}
        for (theta, env_key), plan in self._plans.items():
            if isinstance(plan, Plan):
                self._by_env.setdefault(env_key, []).append((np.frombuffer(theta), plan))
        self.solves = 0
        self.failures = 0

    @staticmethod
    def _key(theta: np.ndarray, env: Environment) -> tuple[bytes, bytes]:
        return (np.asarray(theta, float).tobytes(), env.key())

    def entries(self) -> PlanEntries:
        """Everything solved so far (plans and failures), to seed other books with."""
        return dict(self._plans)

    def _solve(self, theta: np.ndarray, env: Environment) -> Plan:
        near = self._by_env.get(env.key()) if self.warm_start else None
        if near:
            distances = [float(np.sum((t - theta) ** 2)) for t, _ in near]
            start = near[int(np.argmin(distances))][1].trajectory
            try:
                return self.planner.solve(theta, env, inits=[start])
            except PlanningError:
                self.solves += 1  # the warm start failed; the cold starts get their chance
        return self.planner.solve(theta, env)

    def plan(self, theta: np.ndarray, env: Environment) -> Plan:
        theta = np.asarray(theta, float)
        key = self._key(theta, env)
        hit = self._plans.get(key)
        if hit is None:
            self.solves += 1
            try:
                hit = self._solve(theta, env)
                self._by_env.setdefault(key[1], []).append((theta.copy(), hit))
            except PlanningError as exc:
                self.failures += 1
                hit = exc
            self._plans[key] = hit
        if isinstance(hit, PlanningError):
            raise hit
        return hit

    def observe(self, env: Environment) -> Callable[[np.ndarray], np.ndarray]:
        """h(θ) = Φ(ξ*(θ, E), E) as the learners' batch callable (n, k) -> (n, k)."""

        def h(thetas: np.ndarray) -> np.ndarray:
            return np.array([self.plan(t, env).features for t in np.atleast_2d(thetas)])

        return h


@dataclass(frozen=True)
class Target:
    """The user's side of every environment: θ* and its optimal plans ξ*(θ*, E)."""

    theta_star: np.ndarray
    plans: tuple[Plan, ...]

    @classmethod
    def solve(cls, planner: Planner, theta_star, envs: Sequence[Environment]) -> Target:
        theta = np.asarray(theta_star, float)
        return cls(theta_star=theta, plans=tuple(planner.solve(theta, e) for e in envs))


def evaluate(
    book: PlanBook, target: Target, envs: Sequence[Environment], theta_hat: np.ndarray
) -> tuple[float, float, int]:
    """(regret, paper regret, failed environments) of θ̂ summed over ``envs``.

    An environment whose plan fails is left out of both sums and counted instead.
    """
    lam = book.planner.config.smoothness
    full = paper = 0.0
    failed = 0
    for env, star in zip(envs, target.plans, strict=True):
        try:
            plan = book.plan(theta_hat, env)
        except PlanningError:
            failed += 1
            continue
        f, p = regret_terms(
            target.theta_star,
            star.features,
            smoothness_cost(star.trajectory),
            plan.features,
            smoothness_cost(plan.trajectory),
            lam,
        )
        full += f
        paper += p
    return full, paper, failed


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
    user,
    rng: np.random.Generator,
    alphas: np.ndarray | None = None,
    known: PlanEntries | None = None,
) -> RunResult:
    """One run of ``learner`` (one of ``LEARNERS``) for ``settings.iterations`` corrections.

    Args:
        alphas: PP's learning rate per iteration (iterations,); required for "PP".
        rng: this run's generator: draws the environments (PP, KF, EKF) and the user's noise.
        known: plans solved before the run (see :class:`PlanBook`); the results are the same
            with or without them, only the solve count differs.
    """
    if learner not in LEARNERS:
        raise ValueError(f"learner {learner!r} must be one of {LEARNERS}")
    if learner == "PP" and alphas is None:
        raise ValueError("alphas: PP needs a learning rate per iteration")
    book = PlanBook(planner, known, warm_start=settings.warm_start)
    names = planner.config.features
    noise, sigma = settings.noise(), settings.sigma()
    belief = settings.prior()
    k, n_iter = settings.k, settings.iterations
    # Drawn up front so PP and KF run r see the same environments (common random numbers).
    draws = rng.integers(len(envs), size=n_iter)
    gains = np.full((n_iter, k, k), np.nan)
    records = []

    def record(t: int, env_name: str, skipped: str) -> None:
        regret, paper, failed = evaluate(book, target, envs, belief.theta)
        rec = {
            "learner": learner,
            "run": run,
            "iteration": t,
            "environment": env_name,
            "estimate_error": estimate_error(belief.theta, target.theta_star),
            "regret": regret,
            "regret_paper": paper,
            "regret_failures": failed,
            "update_skipped": skipped,
        }
        for i in range(k):
            rec[f"theta_{i}"] = float(belief.theta[i])
        for i in range(k):
            rec[f"cov_{i}{i}"] = float(belief.cov[i, i])
        records.append(rec)

    record(0, "", "")
    for t in range(n_iter):
        if learner == "AL":
            covs = []
            for env in envs:
                try:
                    covs.append(ukf_predicted_covariance(belief, book.observe(env), noise, sigma))
                except PlanningError:
                    covs.append(np.full((k, k), np.inf))
            idx = select_environment(covs)
        else:
            idx = int(draws[t])
        env = envs[idx]
        skipped = ""
        try:
            mine = book.plan(belief.theta, env)
            phi_h = user.correction_features(
                mine.trajectory, target.plans[idx].trajectory, env.params(), names, rng
            )
            if learner == "PP":
                belief = perceptron_update(belief, mine.features, phi_h, float(alphas[t]))
            elif learner == "EKF":
                jac = finite_difference_jacobian(book.observe(env), belief.theta, settings.ekf_step)
                step = ekf_update(belief, jac, mine.features, phi_h, noise)
                belief, gains[t] = step.belief, step.gain
            else:
                step = ukf_update(
                    belief, book.observe(env), phi_h, noise, sigma, reference=mine.features
                )
                belief, gains[t] = step.belief, step.gain
        except PlanningError as exc:
            skipped = str(exc).splitlines()[0]
        record(t + 1, env.name, skipped)
    return RunResult(records=tuple(records), gains=gains, solves=book.solves)
