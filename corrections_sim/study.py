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

Learners live in one table, :data:`LEARNERS` (a :class:`LearnerSpec` each): how they update,
what they believe a correction shows, whether they choose environments, where PP-type
learners take their step size from. The loop knows no learner by name:

* "PP" (eq. B5, αᵗ from the KF runs' gains as in the paper), "PP-C" (the same with αᵗ from
  KF-C's gains, so that no learner wins by a larger step alone);
* "KF" (the UKF the paper simulates, h(θ) = Φ(ξ*(θ, E))), "EKF" (eqs. K4–K7 with
  H = ∂Φ(ξ*(θ, E))/∂θ by central differences of the planner, step ``ekf_step``);
* "KF-C", the correction-aware UKF: hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E)), E), the features of the
  correction a person with preference θ would make to the robot's current trajectory ξᵗ,
  under the robot's correction model C (``correction_model``, see
  :mod:`corrections_sim.corrections`). It reuses the sigma points' plans; no extra solves;
* "AL" and "AL-C": KF and KF-C with Eᵗ chosen by eq. (A1) from their predicted covariance;
* remedies that assume nothing about *how* people correct: "KF-A", a UKF for corrections that
  deliver an unknown fraction a ~ log-uniform[``attenuation_min``, ``attenuation_max``] of the
  intended feature change (:mod:`corrections_sim.learners.attenuated`), and "BP", a Gaussian
  posterior under a Boltzmann model, P(ξ_h ≻ ξᵗ | θ) = σ(β θ·(Φ_h − Φ(ξᵗ))), β integrated out
  over [``beta_min``, ``beta_max``] (:mod:`corrections_sim.learners.preference_posterior`).

Everything random flows from ``np.random.Generator`` objects made from the study's seed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from corrections_sim import calibration
from corrections_sim.corrections import CORRECTION_KINDS, CorrectionModel
from corrections_sim.environments import Environment
from corrections_sim.features import feature_counts
from corrections_sim.human import BiasedUser, DeformingUser, NoisyOptimalUser
from corrections_sim.learners import (
    Attenuation,
    Belief,
    BoltzmannCorrection,
    KalmanNoise,
    Observe,
    SigmaPoints,
    attenuated_update,
    ekf_update,
    finite_difference_jacobian,
    perceptron_update,
    posterior_update,
    select_environment,
    ukf_predicted_covariance,
    ukf_update,
)
from corrections_sim.metrics import estimate_error, regret_terms
from corrections_sim.planner import Plan, Planner, PlanningError, smoothness_cost


@dataclass(frozen=True)
class LearnerSpec:
    """What distinguishes one learner from another; the study loop reads nothing else.

    Attributes:
        update: "perceptron" (eq. B5), "ukf", "ekf", "attenuated" (KF-A) or "posterior" (BP).
        observation: what the learner believes a correction shows: "optimal" (the features
            of ξ*(θ, E), the paper's model) or "correction" (of C(ξᵗ, ξ*(θ, E))).
        active: chooses Eᵗ by eq. (A1) instead of at random.
        rate_from: PP-type learners: the learner whose Kalman gains give αᵗ.
        stream: random stream of its runs; learners on one stream share their environment
            draws run by run (common random numbers), so they are compared paired.
        label: name in figures.
    """

    update: str
    observation: str = "optimal"
    active: bool = False
    rate_from: str | None = None
    stream: int = 0
    label: str = ""

    @property
    def has_covariance(self) -> bool:
        """Whether its P means something (the perceptron carries P⁰ unchanged)."""
        return self.update != "perceptron"


#: Every learner, in the order figures and tables list them.
LEARNERS: dict[str, LearnerSpec] = {
    "PP": LearnerSpec("perceptron", rate_from="KF", label="Preference Perceptron (PP)"),
    "KF": LearnerSpec("ukf", label="Kalman filter (KF)"),
    "EKF": LearnerSpec("ekf", label="Extended Kalman filter (EKF)"),
    "AL": LearnerSpec("ukf", active=True, stream=1, label="Active learning (AL)"),
    "PP-C": LearnerSpec("perceptron", rate_from="KF-C", label="PP, α from KF-C's gains (PP-C)"),
    "KF-C": LearnerSpec("ukf", observation="correction", label="Correction-aware KF (KF-C)"),
    "AL-C": LearnerSpec(
        "ukf", observation="correction", active=True, stream=1, label="Correction-aware AL (AL-C)"
    ),
    "KF-A": LearnerSpec("attenuated", label="Attenuated-correction KF (KF-A)"),
    "BP": LearnerSpec("posterior", label="Boltzmann preference posterior (BP)"),
}
#: The paper's three; the others are opt-in (``learners`` in the settings, ``--learners``).
DEFAULT_LEARNERS = ("PP", "KF", "AL")
#: Largest counts accepted: a run is ~50 planner solves per iteration (≈ 0.1 s), so these are
#: far beyond a week on one machine, and refusing them up front beats running out of memory.
MAX_COUNT = {"runs": 100_000, "iterations": 10_000}
#: Records (learner × run × iteration) a study may hold in memory (≈ 2 kB each).
MAX_RECORDS = 2_000_000
#: Simulated users by name (see :meth:`StudySettings.make_user`).
USERS = ("biased", "deform", "noisy")


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
        user: "biased" (the paper's one-waypoint user, :class:`~corrections_sim.human.BiasedUser`),
            "deform" (a smooth deformation around the worst waypoint,
            :class:`~corrections_sim.human.DeformingUser`) or "noisy" (Φ(ξ*) plus Gaussian
            noise of covariance N, the filter's own model).
        user_step: fraction of the way the biased or deforming user moves its worst waypoint.
        user_waypoints: how many of its worst waypoints the biased user moves.
        correction_model: KF-C's and AL-C's model C of a correction: "waypoint" (the paper's
            §6 correction), "deform" (a minimum-jerk deformation) or "optimal" (the person
            shows ξ* itself: KF-C is then the paper's KF).
        correction_step: how far C moves the corrected waypoint, in (0, 1].
        correction_waypoints: how many waypoints a "waypoint" C moves.
        attenuation_min, attenuation_max, attenuation_points: KF-A's prior on the fraction a
            of the intended feature change a correction delivers (log-uniform, that many
            points).
        beta_min, beta_max, beta_points, lapse: BP's rationality β (log-uniform, that many
            points, integrated out) and lapse rate ε.
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
    user_waypoints: int = 1
    correction_model: str = "waypoint"
    correction_step: float = 1.0
    correction_waypoints: int = 1
    attenuation_min: float = 0.05
    attenuation_max: float = 1.0
    attenuation_points: int = 12
    beta_min: float = 0.3
    beta_max: float = 30.0
    beta_points: int = 15
    lapse: float = 0.0
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
            if v > MAX_COUNT[name]:
                raise ValueError(f"{name} = {v}: at most {MAX_COUNT[name]:,}")
        records = self.runs * (self.iterations + 1) * len(self.learners)
        if records > MAX_RECORDS:
            raise ValueError(
                f"runs = {self.runs}, iterations = {self.iterations}: {records:,} records for "
                f"{len(self.learners)} learners, at most {MAX_RECORDS:,} (they are held in memory)"
            )
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
                f"learners: {list(self.learners)} must be distinct names from {', '.join(LEARNERS)}"
            )
        for name in self.learners:
            source = LEARNERS[name].rate_from
            if source and self.fixed_alpha is None and source not in self.learners:
                raise ValueError(
                    f"learners: {name} takes its learning rate from {source}'s gains; add "
                    f"{source} or set fixed_alpha (--fixed-alpha)"
                )
        if self.user not in USERS:
            raise ValueError(f"user = {self.user!r} must be one of {', '.join(USERS)}")
        if not (np.isfinite(self.ekf_step) and self.ekf_step > 0):
            raise ValueError(f"ekf_step = {self.ekf_step} must be finite and > 0")
        # The user and the sigma points validate their own parameters; build them here so
        # a bad value is refused where it enters, not in the middle of a run.
        self.make_user()
        try:
            CorrectionModel(waypoints=self.user_waypoints)
        except ValueError as exc:
            raise ValueError(f"user_{exc}") from None
        if self.user != "biased" and self.user_waypoints != 1:
            raise ValueError(f"user_waypoints = {self.user_waypoints}: only the biased user has it")
        if self.correction_model not in CORRECTION_KINDS:
            raise ValueError(
                f"correction_model = {self.correction_model!r} must be one of {CORRECTION_KINDS}"
            )
        try:
            self.correction()
        except ValueError as exc:
            raise ValueError(f"correction_{exc}") from None
        self.sigma()
        for build in (self.attenuation, self.boltzmann):
            try:
                build()
            except ValueError as exc:
                raise ValueError(_rename_fields(str(exc))) from None
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

    def make_user(self) -> BiasedUser | DeformingUser | NoisyOptimalUser:
        """The simulated user these settings name; the noisy one's std is √N per feature."""
        if self.user == "noisy":
            return NoisyOptimalUser(noise=float(np.sqrt(self.observation_noise)))
        if self.user == "deform":
            return DeformingUser(step=self.user_step)
        return BiasedUser(step=self.user_step, waypoints=self.user_waypoints)

    def attenuation(self) -> Attenuation:
        """KF-A's prior on the delivered fraction a."""
        return Attenuation(
            a_min=self.attenuation_min, a_max=self.attenuation_max, n_a=self.attenuation_points
        )

    def boltzmann(self) -> BoltzmannCorrection:
        """BP's correction model, with the filters' process noise M."""
        return BoltzmannCorrection(
            beta_min=self.beta_min,
            beta_max=self.beta_max,
            n_beta=self.beta_points,
            lapse=self.lapse,
            process_noise=self.process_noise,
        )

    def correction(self, n_waypoints: int = 12) -> CorrectionModel:
        """KF-C's model of a correction, for trajectories of ``n_waypoints`` waypoints."""
        return CorrectionModel(
            kind=self.correction_model,
            step=self.correction_step,
            waypoints=self.correction_waypoints,
            n_waypoints=n_waypoints,
        )

    def runs_of(self, learner: str) -> int:
        """How many runs ``learner`` makes: an active learner's run is deterministic unless
        the user draws random numbers, so it runs once then, ``runs`` times otherwise."""
        if LEARNERS[learner].active and not self.make_user().stochastic:
            return 1
        return self.runs


#: Parameter names of the learners' own classes -> the settings keys that set them.
_FIELD_NAMES = {
    "Attenuation.a_min": "attenuation_min",
    "Attenuation.a_max": "attenuation_max",
    "Attenuation.n_a": "attenuation_points",
    "BoltzmannCorrection.beta_min": "beta_min",
    "BoltzmannCorrection.beta_max": "beta_max",
    "BoltzmannCorrection.n_beta": "beta_points",
    "BoltzmannCorrection.lapse": "lapse",
    "BoltzmannCorrection.process_noise": "process_noise",
}


def _rename_fields(message: str) -> str:
    for old, new in _FIELD_NAMES.items():
        message = message.replace(old, new)
    return message


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


@dataclass(frozen=True, eq=False)
class _Step:
    """One learner update: the new belief, and what calibration needs of it."""

    belief: Belief
    gain: np.ndarray | None  # (k, k); None for the perceptron
    innovation: np.ndarray  # (k,)
    innovation_cov: np.ndarray | None  # (k, k) predicted S; None if the learner has none


def correction_observer(
    book: PlanBook, env: Environment, robot: np.ndarray, model: CorrectionModel, names
) -> Observe:
    """hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E)), E) as a batch callable (n, k) -> (n, k).

    The correction a person with preference θ would make to the robot's trajectory ``robot``
    (T, 7) under the correction model ``model``; ξ*(θ, E) comes from ``book`` (memoized, so
    the plans the paper's filter would solve are the only ones solved).
    """
    params = env.params()

    def h(thetas: np.ndarray) -> np.ndarray:
        return np.array(
            [
                feature_counts(model.apply(robot, book.plan(t, env).trajectory), params, names)
                for t in np.atleast_2d(thetas)
            ]
        )

    return h


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
    """One run of ``learner`` (a name in :data:`LEARNERS`) for ``settings.iterations``
    corrections.

    Args:
        alphas: a PP-type learner's learning rate per iteration (iterations,); required.
        rng: this run's generator: draws the environments (up front, whether the learner
            uses them or not, so learners on one stream see the same ones) and the user's noise.
        known: plans solved before the run (see :class:`PlanBook`); the results are the same
            with or without them, only the solve count differs.
    """
    if learner not in LEARNERS:
        raise ValueError(f"learner {learner!r} must be one of {', '.join(LEARNERS)}")
    spec = LEARNERS[learner]
    if spec.update == "perceptron" and alphas is None:
        raise ValueError(f"alphas: {learner} needs a learning rate per iteration")
    book = PlanBook(planner, known, warm_start=settings.warm_start)
    names = planner.config.features
    noise, sigma = settings.noise(), settings.sigma()
    model = settings.correction(planner.config.n_waypoints)
    attenuation, boltzmann = settings.attenuation(), settings.boltzmann()
    belief = settings.prior()
    k, n_iter = settings.k, settings.iterations
    # Drawn up front so PP and KF run r see the same environments (common random numbers).
    draws = rng.integers(len(envs), size=n_iter)
    gains = np.full((n_iter, k, k), np.nan)
    records = []

    def observer(env: Environment) -> Observe:
        """What this learner believes a correction in ``env`` shows, as a function of θ."""
        if spec.observation == "correction":
            robot = book.plan(belief.theta, env).trajectory
            return correction_observer(book, env, robot, model, names)
        return book.observe(env)

    def update(env: Environment, mine: Plan, phi_h: np.ndarray, t: int) -> _Step:
        if spec.update == "perceptron":
            new = perceptron_update(belief, mine.features, phi_h, float(alphas[t]))
            return _Step(new, None, phi_h - mine.features, None)
        if spec.update == "posterior":
            post = posterior_update(belief, None, mine.features, phi_h, boltzmann)
            return _Step(post.belief, post.gain, post.innovation, None)
        if spec.update == "attenuated":
            step = attenuated_update(
                belief, book.observe(env), mine.features, phi_h, noise, attenuation, sigma
            )
        elif spec.update == "ekf":
            jac = finite_difference_jacobian(book.observe(env), belief.theta, settings.ekf_step)
            step = ekf_update(belief, jac, mine.features, phi_h, noise)
        else:
            # Innovation against Φ(ξᵗ) (eq. K5); for KF-C that is hₜ(θ̂), since C(ξᵗ, ξᵗ) = ξᵗ.
            step = ukf_update(belief, observer(env), phi_h, noise, sigma, reference=mine.features)
        return _Step(step.belief, step.gain, step.innovation, step.innovation_cov)

    def record(t: int, env_name: str, skipped: str, step: _Step | None) -> None:
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
            for j in range(i, k):
                rec[f"cov_{i}{j}"] = float(belief.cov[i, j])
        # None (an empty CSV cell) where there is nothing to normalize by: the perceptron
        # has no covariance, and the prior no innovation.
        rec["nees"] = (
            calibration.nees(belief.theta, belief.cov, target.theta_star)
            if spec.has_covariance
            else None
        )
        rec["nis"] = (
            calibration.nis(step.innovation, step.innovation_cov)
            if step is not None and step.innovation_cov is not None
            else None
        )
        records.append(rec)

    record(0, "", "", None)
    for t in range(n_iter):
        if spec.active:
            # Eq. (A1) over the environments whose plans exist; one that fails is no candidate.
            candidates, covs = [], []
            for i, env in enumerate(envs):
                try:
                    covs.append(ukf_predicted_covariance(belief, observer(env), noise, sigma))
                    candidates.append(i)
                except PlanningError:
                    continue
            idx = candidates[select_environment(covs)] if candidates else int(draws[t])
        else:
            idx = int(draws[t])
        env = envs[idx]
        skipped = ""
        step = None
        try:
            mine = book.plan(belief.theta, env)
            phi_h = user.correction_features(
                mine.trajectory, target.plans[idx].trajectory, env.params(), names, rng
            )
            step = update(env, mine, phi_h, t)
            belief = step.belief
            if step.gain is not None:
                gains[t] = step.gain
        except PlanningError as exc:
            skipped = str(exc).splitlines()[0]
        record(t + 1, env.name, skipped, step)
    return RunResult(records=tuple(records), gains=gains, solves=book.solves)
