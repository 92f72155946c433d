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
(:data:`~corrections_sim.learning.base.LEARNERS`, :data:`~corrections_sim.people.users.USERS`); the loop
calls their protocols (:class:`~corrections_sim.learning.base.Learner`,
:class:`~corrections_sim.people.users.User`) and knows none by name. The paper's learners are in
:mod:`corrections_sim.learning.paper`.

Everything random flows from ``np.random.Generator`` objects made from the study's seed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from corrections_sim import calibration
from corrections_sim.learning import (
    Attenuation,
    Belief,
    BoltzmannCorrection,
    KalmanNoise,
    SigmaPoints,
)
from corrections_sim.learning.base import LEARNERS, LearnerContext, Step, make_learner
from corrections_sim.metrics import estimate_error
from corrections_sim.people.corrections import CORRECTION_KINDS, CorrectionModel
from corrections_sim.people.users import USERS, Situation, User, make_user, user_parameters
from corrections_sim.planning.planner import Planner, PlanningError
from corrections_sim.planning.plans import (  # noqa: F401  (re-exported: part of this module's API)
    PlanBook,
    PlanEntries,
    Target,
    correction_observer,
    evaluate,
)
from corrections_sim.scene.environments import Environment

#: The paper's three; the others are opt-in (``learners`` in the settings, ``--learners``).
DEFAULT_LEARNERS = ("PP", "KF", "AL")
#: Largest counts accepted: a run is ~50 planner solves per iteration (≈ 0.1 s), so these are
#: far beyond a week on one machine, and refusing them up front beats running out of memory.
MAX_COUNT = {"runs": 100_000, "iterations": 10_000}
#: Records (learner × run × iteration) a study may hold in memory (≈ 2 kB each).
MAX_RECORDS = 2_000_000
#: Study settings keys that set a user's parameter when the user has it (the paper's users'
#: parameters predate ``user_params``); ``user_params`` overrides them.
_USER_KEYS = {
    "step": lambda s: s.user_step,
    "waypoints": lambda s: s.user_waypoints,
    "noise": lambda s: float(np.sqrt(s.observation_noise)),
}


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
        user: "biased" (the paper's one-waypoint user, :class:`~corrections_sim.people.users.BiasedUser`),
            "deform" (a smooth deformation around the worst waypoint,
            :class:`~corrections_sim.people.users.DeformingUser`) or "noisy" (Φ(ξ*) plus Gaussian
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
        user_params: parameters of the user by name (see
            :func:`~corrections_sim.people.users.user_parameters`); they override ``user_step``,
            ``user_waypoints`` and the noisy user's √N.
        learner_params: per learner name, its parameters (see
            :func:`~corrections_sim.learning.base.make_learner`); the paper's take none.
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
    user_params: Mapping[str, Any] = field(default_factory=dict)
    learner_params: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)

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
        try:
            LEARNERS.check(self.learners)
        except ValueError as exc:
            raise ValueError(f"learners: {exc}") from None
        for name in self.learners:
            source = LEARNERS[name].rate_from
            if source and self.fixed_alpha is None and source not in self.learners:
                raise ValueError(
                    f"learners: {name} takes its learning rate from {source}'s gains; add "
                    f"{source} or set fixed_alpha (--fixed-alpha)"
                )
        try:
            USERS[self.user]
        except ValueError as exc:
            raise ValueError(f"user: {exc}") from None
        if not (np.isfinite(self.ekf_step) and self.ekf_step > 0):
            raise ValueError(f"ekf_step = {self.ekf_step} must be finite and > 0")
        # The user and the sigma points validate their own parameters; build them here so
        # a bad value is refused where it enters, not in the middle of a run.
        self.make_user()
        try:
            CorrectionModel(waypoints=self.user_waypoints)
        except ValueError as exc:
            raise ValueError(f"user_{exc}") from None
        if "waypoints" not in user_parameters(self.user) and self.user_waypoints != 1:
            raise ValueError(
                f"user_waypoints = {self.user_waypoints}: the {self.user} user has no waypoints"
            )
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
        for name in self.learner_params:
            if name not in self.learners:
                raise ValueError(f"learner_params: {name!r} is not one of the learners")
        for name in self.learners:
            self.make_learner(name)
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

    def user_arguments(self) -> dict[str, Any]:
        """The user's parameters: from ``user_step``, ``user_waypoints`` and √N (the noisy
        user's std per feature) where the user has them, overridden by ``user_params``."""
        known = user_parameters(self.user)
        params = {key: get(self) for key, get in _USER_KEYS.items() if key in known}
        params.update(self.user_params)
        return params

    def make_user(self) -> User:
        """The simulated user these settings name (see :func:`~corrections_sim.people.users.make_user`).

        Raises:
            ValueError: a bad parameter, named by the settings key it came from.
        """
        try:
            return make_user(self.user, self.user_arguments())
        except ValueError as exc:
            message = str(exc)
            for key in ("step", "waypoints"):
                if key not in self.user_params:
                    message = message.replace(f": {key} = ", f": user_{key} = ")
            raise ValueError(message) from None

    def make_learner(self, name: str):
        """Learner ``name`` built for these settings with its ``learner_params``."""
        return make_learner(name, self, self.learner_params.get(name))

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
    cls = LEARNERS[learner]
    if cls.needs_rates() and alphas is None:
        raise ValueError(f"alphas: {learner} needs a learning rate per iteration")
    agent = settings.make_learner(learner)
    book = PlanBook(planner, known, warm_start=settings.warm_start)
    names = planner.config.features
    belief = settings.prior()
    k, n_iter = settings.k, settings.iterations
    # Drawn up front so PP and KF run r see the same environments (common random numbers).
    draws = rng.integers(len(envs), size=n_iter)
    gains = np.full((n_iter, k, k), np.nan)
    records = []

    def record(t: int, env_name: str, skipped: str, step: Step | None) -> None:
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
        # None (an empty CSV cell) where there is nothing to normalize by: a learner without
        # a covariance (the perceptron), and the prior no innovation.
        rec["nees"] = (
            calibration.nees(belief.theta, belief.cov, target.theta_star)
            if cls.has_covariance
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
        ctx = LearnerContext(
            book=book,
            envs=envs,
            features=names,
            n_waypoints=planner.config.n_waypoints,
            alphas=alphas,
            rng=rng,
            iteration=t,
        )
        idx = _index(learner, agent.choose(ctx, belief, int(draws[t])), len(envs))
        env = envs[idx]
        skipped = ""
        step = None
        try:
            mine = book.plan(belief.theta, env)
            situation = Situation(
                robot=mine.trajectory,
                intended=target.plans[idx].trajectory,
                env=env,
                features=names,
                theta_star=target.theta_star,
            )
            phi_h = np.asarray(user.correction_features(situation, rng), dtype=float)
            step = agent.update(ctx, belief, env, mine, phi_h)
            belief = step.belief
            if step.gain is not None:
                gains[t] = step.gain
        except PlanningError as exc:
            skipped = str(exc).splitlines()[0]
        record(t + 1, env.name, skipped, step)
    return RunResult(records=tuple(records), gains=gains, solves=book.solves)


def _index(learner: str, idx, n: int) -> int:
    """A learner's choice of environment, refused unless it is an index into the n."""
    if isinstance(idx, bool) or not isinstance(idx, int | np.integer) or not 0 <= idx < n:
        raise ValueError(f"learner {learner}: chose environment {idx!r}, not an index in [0, {n})")
    return int(idx)
