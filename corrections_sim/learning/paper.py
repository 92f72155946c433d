"""The paper's learners and their calibrated variants, as registered :class:`Learner` plug-ins.

* "PP" (eq. B5, αᵗ from the KF runs' gains as in the paper), "PP-C" (αᵗ from KF-C's gains,
  so that no learner wins by a larger step alone);
* "KF" (the UKF the paper simulates, h(θ) = Φ(ξ*(θ, E))), "EKF" (eqs. K4–K7 with
  H = ∂Φ(ξ*(θ, E))/∂θ by central differences of the planner, step ``ekf_step``);
* "KF-C", the correction-aware UKF: hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E)), E), the features of the
  correction a person with preference θ would make to the robot's current trajectory ξᵗ,
  under the robot's correction model C (its parameter ``model``, any registered in
  :mod:`corrections_sim.people.corrections`). It reuses the sigma points' plans; no extra solves;
* "AL" and "AL-C": KF and KF-C with Eᵗ chosen by eq. (A1) from their predicted covariance;
* "KF-A", a UKF for corrections that deliver an unknown fraction a ~ log-uniform[
  ``attenuation_min``, ``attenuation_max``] of the intended feature change
  (:mod:`corrections_sim.learning.attenuated`), and "BP", a Gaussian posterior under a
  Boltzmann model, P(ξ_h ≻ ξᵗ | θ) = σ(β θ·(Φ_h − Φ(ξᵗ))), β integrated out over
  [``beta_min``, ``beta_max``] (:mod:`corrections_sim.learning.preference_posterior`).

Each is a frozen dataclass whose fields are its own parameters (``[learners.KF-A]
attenuation_min = 0.1`` in a study file); the filters' shared M, N and sigma points come from
the study through :class:`~corrections_sim.learning.base.LearnerContext`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass

import numpy as np

from corrections_sim import components
from corrections_sim.belief import Belief, KalmanNoise, NoisePosterior, PersonBelief, symmetrize
from corrections_sim.components import ParameterError
from corrections_sim.learning.active import select_environment
from corrections_sim.learning.attenuated import Attenuation
from corrections_sim.learning.attenuated import update as attenuated_update
from corrections_sim.learning.base import Learner, LearnerContext, Step, register_learner
from corrections_sim.learning.exact_posterior import gaussian_log_likelihood as particle_likelihood
from corrections_sim.learning.kalman import (
    Observe,
    batch_update,
    ekf_update,
    finite_difference_jacobian,
    iterated_update,
    ukf_predicted_covariance,
    ukf_update,
    vb_ukf_update,
)
from corrections_sim.learning.particles import belief_of as particles_belief
from corrections_sim.learning.particles import correct as particles_correct
from corrections_sim.learning.particles import draw as particles_draw
from corrections_sim.learning.perceptron import perceptron_update
from corrections_sim.learning.preference_posterior import BoltzmannCorrection
from corrections_sim.learning.preference_posterior import update as posterior_update
from corrections_sim.learning.relevance import SPACES, Relevance, explain, judge, load_fit
from corrections_sim.people.corrections import (
    CORRECTIONS,
    CorrectionModel,
    WaypointCorrection,
)
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.learnt import Network, learn
from corrections_sim.planning.learnt import register as register_learnt
from corrections_sim.planning.planner import Plan, PlanningError, shared_planner
from corrections_sim.planning.plans import PlanBook
from corrections_sim.scene.environments import Environment


def _positive(name: str, value) -> None:
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if not (ok and value > 0):
        raise ParameterError(name, f"must be a finite number > 0, got {value!r}")


def _count(name: str, value, low: int) -> None:
    """Refuse a parameter that is not an integer >= ``low``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ParameterError(name, f"must be an integer >= {low}, got {value!r}")


def _renamed(build, names: dict[str, str]):
    """``build()``, with a ValueError that names a field of the maths' own class (``a_min``)
    re-raised under the learner's parameter name (``attenuation_min``)."""
    try:
        return build()
    except ValueError as exc:
        message = str(exc)
        for old, new in names.items():
            if message.startswith(old + ":"):
                raise ParameterError(new, message[len(old) + 1 :].strip()) from None
        raise


@register_learner("PP")
@dataclass(frozen=True)
class Perceptron(Learner):
    """The Preference Perceptron, eq. (B5): θ̂ += αᵗ (Φ_h − Φ(ξᵗ)); P stays P⁰.

    Attributes:
        fixed_alpha: a fixed learning rate α > 0; None (default): αᵗ is the mean diag(Kᵗ)
            over the runs of :attr:`rate_from` (the paper's choice).
    """

    label = "Preference Perceptron (PP)"
    style = ("#7f7f7f", "-")
    has_covariance = False
    rate_from = "KF"

    fixed_alpha: float | None = None

    def __post_init__(self) -> None:
        if self.fixed_alpha is not None:
            _positive("fixed_alpha", self.fixed_alpha)

    def rate_source(self) -> str | None:
        return None if self.fixed_alpha is not None else self.rate_from

    def fixed_rate(self) -> float | None:
        return self.fixed_alpha

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        new = perceptron_update(belief, plan.features, phi_h, float(ctx.alphas[ctx.iteration]))
        return Step(new, None, phi_h - plan.features, None)


#: How a filter treats the person's observation noise N (the ``noise`` parameter).
NOISE_MODES = ("fixed", "learnt")

#: How a filter linearises its observation (the ``iterate`` parameter): "none" (the UKF),
#: "each" (the correction again around its posterior, IPLF), "all" (every correction so far
#: again around the current posterior).
ITERATE_MODES = ("none", "each", "all")


@register_learner("KF")
@dataclass(frozen=True)
class UnscentedKalman(Learner):
    """The UKF the paper simulates, observation h(θ) = Φ(ξ*(θ, E), E), with the study's
    M, N and sigma points.

    Attributes:
        noise: "fixed" (N is the study's, the paper's filter) or "learnt": N is estimated
            jointly with θ by variational Bayes (:func:`~.kalman.vb_ukf_update`), from a prior
            IW whose estimate is the study's N, held with ``noise_dof`` degrees of freedom.
        noise_dof: the prior's degrees of freedom ν₀ > k − 1 (how many corrections' worth
            the study's N counts for); None: k + 2.
        iterate: "none" (the UKF step), "each" (the iterated posterior linearisation
            filter: each correction's h linearised again w.r.t. the posterior it gives,
            :func:`~.kalman.iterated_update`) or "all" (after that, every correction so far
            linearised again w.r.t. the current posterior and the prior updated by all of
            them at once, :func:`~.kalman.batch_update`: θ is static, so past corrections are
            evidence to be read again once P has shrunk). Needs ``noise = "fixed"``.
        iterations: at most this many linearisations per correction ("each"), and passes
            over all corrections ("all"); >= 1.
        tolerance: stop iterating once the posterior moves by less than this KL (nats, > 0).
    """

    label = "Kalman filter (KF)"
    style = ("#1f77b4", "-")

    noise: str = "fixed"
    noise_dof: float | None = None
    iterate: str = "none"
    iterations: int = 3
    tolerance: float = 0.01

    def __post_init__(self) -> None:
        if self.noise not in NOISE_MODES:
            raise ParameterError(
                "noise", f"must be one of {', '.join(NOISE_MODES)}, got {self.noise!r}"
            )
        if self.noise_dof is not None:
            _positive("noise_dof", self.noise_dof)
        if self.iterate not in ITERATE_MODES:
            raise ParameterError(
                "iterate", f"must be one of {', '.join(ITERATE_MODES)}, got {self.iterate!r}"
            )
        _count("iterations", self.iterations, 1)
        _positive("tolerance", self.tolerance)
        if self.iterate != "none" and self.noise != "fixed":
            raise ParameterError(
                "iterate", f'{self.iterate!r} needs noise = "fixed" (N is learnt here)'
            )

    def initial(self, belief: Belief, noise: KalmanNoise) -> Belief:
        if self.iterate == "all":  # the prior first, then each correction (see update)
            return Belief(theta=belief.theta, cov=belief.cov, history=((belief.theta, belief.cov),))
        if self.noise == "fixed":
            return belief
        dof = self.noise_dof if self.noise_dof is not None else belief.dim + 2.0
        if not dof > belief.dim - 1:
            raise ParameterError("noise_dof", f"must be > k - 1 = {belief.dim - 1}, got {dof}")
        prior = NoisePosterior.around(noise.observation, dof)
        return Belief(theta=belief.theta, cov=belief.cov, noise=prior)

    def filter_noise(self, ctx: LearnerContext, belief: Belief) -> KalmanNoise:
        """M and N as this filter believes them now (N̂ when it learns N)."""
        if belief.noise is None:
            return ctx.noise
        return KalmanNoise(process=ctx.noise.process, observation=belief.noise.estimate())

    def observer(self, ctx: LearnerContext, belief: Belief, env: Environment) -> Observe:
        """What this learner believes a correction in ``env`` shows, as a function of θ."""
        return ctx.book.observe(env)

    def observer_of(self, ctx: LearnerContext, env: Environment, robot: np.ndarray) -> Observe:
        """What a correction in ``env`` to the robot's trajectory ``robot`` shows."""
        return ctx.book.observe(env)

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        # Innovation against Φ(ξᵗ) (eq. K5); for KF-C that is hₜ(θ̂), since C(ξᵗ, ξᵗ) = ξᵗ.
        observe = self.observer(ctx, belief, env)
        if belief.noise is not None:
            return vb_ukf_update(
                belief, observe, phi_h, ctx.noise, ctx.sigma, reference=plan.features
            )
        if self.iterate == "none":
            return ukf_update(belief, observe, phi_h, ctx.noise, ctx.sigma, reference=plan.features)
        start = Belief(theta=belief.theta, cov=belief.cov)
        step = iterated_update(
            start, observe, phi_h, ctx.noise, ctx.sigma, reference=plan.features,
            iterations=self.iterations, tolerance=self.tolerance,
        )  # fmt: skip
        if self.iterate == "each":
            return step
        entry = (env, plan.trajectory, np.asarray(phi_h, float), ctx.noise.observation)
        (theta0, cov0), *past = (*belief.history, entry)
        # θ is static here; the random walk's M over t corrections widens the prior instead.
        prior = Belief(theta=theta0, cov=cov0 + len(past) * ctx.noise.process)
        after, passes, change = batch_update(
            prior,
            [self.observer_of(ctx, e, robot) for e, robot, _, _ in past],
            [z for _, _, z, _ in past],
            [n for _, _, _, n in past],
            step.belief,
            ctx.sigma,
            iterations=self.iterations,
            tolerance=self.tolerance,
        )
        kept = Belief(theta=after.theta, cov=after.cov, history=(*belief.history, entry))
        return dataclasses.replace(step, belief=kept, passes=step.passes + passes, change=change)


@register_learner("EKF")
@dataclass(frozen=True)
class ExtendedKalman(Learner):
    """Eqs. (K4)–(K7) with H by central differences of the planner.

    Attributes:
        step: the central-difference step δ of H, in θ units (> 0).
    """

    label = "Extended Kalman filter (EKF)"
    style = ("#2ca02c", "-")

    step: float = 0.05

    def __post_init__(self) -> None:
        _positive("step", self.step)

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        jac = finite_difference_jacobian(ctx.book.observe(env), belief.theta, self.step)
        return ekf_update(belief, jac, plan.features, phi_h, ctx.noise)


class _Active:
    """Mix-in: Eᵗ = argmin_E ‖P_{t+1}(E)‖_F, eq. (A1), over the environments whose plans
    exist and that were not declined since the last correction (one that fails, or that the
    person skipped, is no candidate; if none is left, the run's draw)."""

    active = True
    stream = 1

    def choose(self, ctx: LearnerContext, belief: Belief, draw: int) -> int:
        candidates, covs = [], []
        for i, env in enumerate(ctx.envs):
            if i in ctx.declined:
                continue
            try:
                observe = self.observer(ctx, belief, env)
                noise = self.filter_noise(ctx, belief)
                covs.append(ukf_predicted_covariance(belief, observe, noise, ctx.sigma))
                candidates.append(i)
            except PlanningError:
                continue
        return candidates[select_environment(covs)] if candidates else draw


@register_learner("AL")
@dataclass(frozen=True)
class ActiveLearning(_Active, UnscentedKalman):
    """KF with environments chosen by eq. (A1)."""

    label = "Active learning (AL)"
    style = ("#d62728", "-")


@register_learner("PP-C")
@dataclass(frozen=True)
class PerceptronFromCorrectionAware(Perceptron):
    """PP with αᵗ from KF-C's gains."""

    label = "PP, α from KF-C's gains (PP-C)"
    style = ("#7f7f7f", "--")
    rate_from = "KF-C"


def _require_model(model) -> None:
    """Refuse a ``model`` parameter that is not a correction model."""
    if not isinstance(model, CorrectionModel):
        raise ParameterError("model", f"expected a correction model, got {model!r}")


def _model_fits(model: CorrectionModel, n_waypoints: int) -> None:
    """The correction model's own check for T = ``n_waypoints``, under the key ``model.…``."""
    try:
        model.check(n_waypoints)
    except ParameterError as exc:
        raise ParameterError(f"model.{exc.name}", exc.message) from None


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


@register_learner("KF-C")
@dataclass(frozen=True)
class CorrectionAwareKalman(UnscentedKalman):
    """UKF with hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E)), E) under the correction model C.

    Attributes:
        model: C, any registered correction model with its parameters (a name, or a table
            ``{ name = "waypoint", step = 0.5 }``); the paper's one-waypoint correction by
            default.
    """

    label = "Correction-aware KF (KF-C)"
    style = ("#1f77b4", "--")

    model: CorrectionModel = components.nested(CORRECTIONS, WaypointCorrection())

    def __post_init__(self) -> None:
        super().__post_init__()
        _require_model(self.model)

    def check(self, n_waypoints: int) -> None:
        _model_fits(self.model, n_waypoints)

    def observer(self, ctx: LearnerContext, belief: Belief, env: Environment) -> Observe:
        robot = ctx.book.plan(belief.theta, env).trajectory
        return self.observer_of(ctx, env, robot)

    def observer_of(self, ctx: LearnerContext, env: Environment, robot: np.ndarray) -> Observe:
        return correction_observer(ctx.book, env, robot, self.model, ctx.features)


@register_learner("AL-C")
@dataclass(frozen=True)
class CorrectionAwareActive(_Active, CorrectionAwareKalman):
    """KF-C with environments chosen by eq. (A1)."""

    label = "Correction-aware AL (AL-C)"
    style = ("#d62728", "--")


_ATTENUATION_NAMES = {
    "Attenuation.a_min": "attenuation_min",
    "Attenuation.a_max": "attenuation_max",
    "Attenuation.n_a": "attenuation_points",
}
_BOLTZMANN_NAMES = {
    "BoltzmannCorrection.beta_min": "beta_min",
    "BoltzmannCorrection.beta_max": "beta_max",
    "BoltzmannCorrection.n_beta": "beta_points",
    "BoltzmannCorrection.lapse": "lapse",
}


@register_learner("KF-A")
@dataclass(frozen=True)
class AttenuatedKalman(Learner):
    """UKF for corrections that deliver an unknown fraction a of the intended change.

    Attributes:
        attenuation_min, attenuation_max: the range of a, 0 < min ≤ max (log-uniform prior).
        attenuation_points: how many log-spaced values of a (1 … 10,000).
    """

    label = "Attenuated-correction KF (KF-A)"
    style = ("#9467bd", "-.")

    attenuation_min: float = 0.05
    attenuation_max: float = 1.0
    attenuation_points: int = 12

    def __post_init__(self) -> None:
        if isinstance(self.attenuation_points, int) and self.attenuation_points > 10_000:
            raise ParameterError("attenuation_points", "at most 10,000")
        self.attenuation()

    def attenuation(self) -> Attenuation:
        """The prior on the delivered fraction a."""
        return _renamed(
            lambda: Attenuation(
                a_min=self.attenuation_min,
                a_max=self.attenuation_max,
                n_a=self.attenuation_points,
            ),
            _ATTENUATION_NAMES,
        )

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        return attenuated_update(
            belief,
            ctx.book.observe(env),
            plan.features,
            phi_h,
            ctx.noise,
            self.attenuation(),
            ctx.sigma,
        )


@register_learner("BP")
@dataclass(frozen=True)
class BoltzmannPosterior(Learner):
    """Gaussian posterior under a Boltzmann model of corrections; no planner solves.

    Attributes:
        beta_min, beta_max: the range of the rationality β, 0 < min ≤ max (log-uniform,
            integrated out).
        beta_points: how many log-spaced values of β (1 … 10,000).
        lapse: ε in [0, 1), the chance that a correction carries no information.
    """

    label = "Boltzmann preference posterior (BP)"
    style = ("#8c564b", ":")

    beta_min: float = 0.3
    beta_max: float = 30.0
    beta_points: int = 15
    lapse: float = 0.0

    def __post_init__(self) -> None:
        if isinstance(self.beta_points, int) and self.beta_points > 10_000:
            raise ParameterError("beta_points", "at most 10,000")
        self.correction_model(0.0)

    def correction_model(self, process_noise: float) -> BoltzmannCorrection:
        """Its model of a correction, with the study's process noise M = q I."""
        return _renamed(
            lambda: BoltzmannCorrection(
                beta_min=self.beta_min,
                beta_max=self.beta_max,
                n_beta=self.beta_points,
                lapse=self.lapse,
                process_noise=process_noise,
            ),
            _BOLTZMANN_NAMES,
        )

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        model = self.correction_model(float(ctx.noise.process[0, 0]))
        return posterior_update(belief, None, plan.features, phi_h, model)


@register_learner("KF-CL")
@dataclass(frozen=True)
class CorrectionAwareKalmanLearntNoise(CorrectionAwareKalman):
    """KF-C that learns the person's observation noise N (``noise = "learnt"``)."""

    label = "KF-C, N learnt (KF-CL)"
    style = ("#17becf", "--")

    noise: str = "learnt"


@register_learner("AL-CL")
@dataclass(frozen=True)
class CorrectionAwareActiveLearntNoise(_Active, CorrectionAwareKalmanLearntNoise):
    """AL-C that learns the person's observation noise N: environments by eq. (A1) with N̂."""

    label = "AL-C, N learnt (AL-CL)"
    style = ("#ff7f0e", "--")


def _judge(
    ctx: LearnerContext,
    belief: Belief,
    env: Environment,
    plan: Plan,
    model: CorrectionModel,
    relevance: Relevance,
) -> tuple[float, float | None]:
    """(β̂, ρ) of the correction in ``ctx``: the relevance model's posterior from ρ, the
    unexplained fraction of the move under ``model`` (:func:`~.relevance.explain`, started
    from θ̂ and the sigma points of N(θ̂, P + M), the plans the UKF solves anyway). Without a
    trajectory to judge (a person who shows noisy features) it is the prior."""
    if ctx.corrected is None:
        return relevance.prior, None
    starts = ctx.sigma.points(belief.theta, belief.cov + ctx.noise.process)
    found = explain(ctx.book, env, plan.trajectory, ctx.corrected, model, starts)
    return relevance.probability(found.rho), found.rho


class _RelevanceAware:
    """Mix-in: the parameters of a learner that weighs each correction by its relevance β̂
    (:mod:`corrections_sim.learning.relevance`)."""

    relevance_prior: float
    relevance_spread: float

    def relevance(self, k: int) -> Relevance:
        """Its model of ρ under relevant and irrelevant corrections."""
        return Relevance(prior=self.relevance_prior, spread=self.relevance_spread, k=k)


@register_learner("KF-CR")
@dataclass(frozen=True)
class RelevanceAwareKalman(_RelevanceAware, CorrectionAwareKalman):
    """KF-C that weighs each correction by its relevance β̂ (Bobu et al., CoRL 2018): the
    observation noise of the update is N / β̂.

    Attributes:
        relevance_prior: p in (0, 1), the prior probability that a correction is relevant.
        relevance_spread: σ > 0 of the unexplained fraction ρ of a relevant correction.
    """

    label = "Relevance-aware KF-C (KF-CR)"
    style = ("#e377c2", "--")

    relevance_prior: float = 0.5
    relevance_spread: float = 0.05

    def __post_init__(self) -> None:
        super().__post_init__()
        self.relevance(2)

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        beta, rho = _judge(ctx, belief, env, plan, self.model, self.relevance(belief.dim))
        noise = KalmanNoise(process=ctx.noise.process, observation=ctx.noise.observation / beta)
        step = super().update(dataclasses.replace(ctx, noise=noise), belief, env, plan, phi_h)
        return dataclasses.replace(step, relevance=beta, residual=rho)


@register_learner("KF-CRP")
@dataclass(frozen=True)
class PersonRelevanceKalman(CorrectionAwareKalman):
    """KF-C that judges relevance across a person's corrections (in the spirit of Bobu et al.,
    T-RO 2020): one belief over the person's rate r of relevant corrections and the precision
    τ of those (:class:`~corrections_sim.belief.PersonBelief`, a grid updated exactly; prior
    Beta and Gamma), shared by all of their corrections, and each correction judged by where
    it is explained as well as by how much: a correction explained only by θ's the belief
    rules out is not believed (:func:`~.relevance.judge`). The observation noise of the
    update is N / β̂, as KF-CR's.

    Attributes:
        relevance_prior: E[r] before any correction, in (0, 1).
        relevance_count: how many corrections' worth the prior on r holds (> 0).
        relevance_spread: σ̂ before any correction (> 0) where no fit is used: τ's prior mean
            is 1 / σ̂² (with a fit, τ's prior is the fit's).
        spread_count: how many relevant corrections' worth that prior on τ holds (> 0).
        space: where ρ is measured: "joint" (the arm's joints, what a simulated person moves)
            or "task" (the cup's path, what a person at the page drags or pushes).
        fit: a fit file of the densities of ρ* and of the scatter of irrelevant
            explanations (``python -m corrections_sim.run relevance-fit``); "" is the
            shipped fit, except that in joint space f₀ is then the random direction's
            Beta((7 − k)/2, k/2) and σ̂ is ``relevance_spread``.
        expand_traces: feature expansion (FERL; :mod:`corrections_sim.planning.learnt`): how
            many feature traces to ask the person for when their corrections are not
            explained; 0 never asks.
        expand_below: ask once E[r], the person's believed rate of relevant corrections,
            falls below this, in (0, 1).
        expand_after: and no sooner than after this many corrections (>= 1).
        expand_variance: the learnt feature's weight starts at N(0, this) (P⁰'s diagonal in
            every study here), uncorrelated with the others.
        expand_inputs: what the learnt feature's network reads (``learnt.INPUTS``).
        expand_hidden: its hidden layers' widths.
    """

    label = "Person-level relevance KF-C (KF-CRP)"
    style = ("#d62728", "-.")

    relevance_prior: float = 0.5
    relevance_count: float = 2.0
    relevance_spread: float = 0.05
    spread_count: float = 2.0
    space: str = "joint"
    fit: str = ""
    expand_traces: int = 0
    expand_below: float = 0.35
    expand_after: int = 3
    expand_variance: float = 1.0
    expand_inputs: tuple[str, ...] = Network().inputs
    expand_hidden: tuple[int, ...] = Network().hidden

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.noise != "fixed":
            raise ParameterError("noise", "KF-CRP keeps N fixed (N / β̂ is its update)")
        if self.iterate != "none":
            raise ParameterError("iterate", "KF-CRP's update is not iterated (its own history)")
        _count("expand_traces", self.expand_traces, 0)
        _count("expand_after", self.expand_after, 1)
        if not (isinstance(self.expand_below, int | float) and 0 < self.expand_below < 1):
            raise ParameterError("expand_below", f"must lie in (0, 1), got {self.expand_below!r}")
        _positive("expand_variance", self.expand_variance)
        for name in ("expand_inputs", "expand_hidden"):
            value = getattr(self, name)
            if not isinstance(value, list | tuple):
                raise ParameterError(name, f"must be a list, got {value!r}")
            object.__setattr__(self, name, tuple(value))
        try:
            self.network()
        except ValueError as exc:
            raise ParameterError("expand_inputs", str(exc)) from None
        Relevance(prior=self.relevance_prior, spread=self.relevance_spread)
        _positive("relevance_count", self.relevance_count)
        _positive("spread_count", self.spread_count)
        if self.space not in SPACES:
            raise ParameterError("space", f"must be one of {', '.join(SPACES)}, got {self.space!r}")
        if not isinstance(self.fit, str):
            raise ParameterError("fit", f"must be a file name, got {self.fit!r}")
        try:
            self.densities()
        except ValueError as exc:
            raise ParameterError("fit", str(exc)) from None

    def network(self) -> Network:
        """The shape of the feature it learns when it expands."""
        return Network(inputs=self.expand_inputs, hidden=self.expand_hidden)

    def densities(self) -> tuple[tuple[float, float] | None, tuple[float, float], tuple]:
        """In this learner's space: the Beta (a, b) of an irrelevant ρ*² (None: the random
        direction's), the Gamma (shape, rate) of τ before any correction, and the scatter of
        irrelevant explanations ((weight, sd), … ; always from the fit)."""
        fitted = _fit(self.fit)
        if self.space not in fitted:
            where = self.fit or "the shipped fit"
            raise ValueError(f"{where}: has no densities for space {self.space!r}")
        mine = fitted[self.space]
        if self.space == "joint" and not self.fit:
            shape = 0.5 * self.spread_count
            return None, (shape, shape * self.relevance_spread**2), mine.scatter
        return mine.irrelevant, mine.precision, mine.scatter

    def person(self) -> PersonBelief:
        """The prior belief over the person."""
        _, (shape, rate), _ = self.densities()
        return PersonBelief.prior(
            shape,
            rate,
            self.relevance_prior * self.relevance_count,
            (1.0 - self.relevance_prior) * self.relevance_count,
        )

    def initial(self, belief: Belief, noise: KalmanNoise) -> Belief:
        # A learner that may learn a feature keeps the prior and its corrections, to read
        # them again over the new feature (see :meth:`grow`).
        kept = ((belief.theta, belief.cov),) if self.expand_traces else ()
        return Belief(theta=belief.theta, cov=belief.cov, person=self.person(), history=kept)

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        person = belief.person or self.person()
        prior = Belief(theta=belief.theta, cov=belief.cov)
        if belief.extra:
            # Expanded: the person taught what their corrections were about, so they are
            # taken as relevant (KF-C's update over k + 1 features). Judged one by one, a
            # learnt feature that ranks like the person's (Spearman 0.88-0.92) still leaves
            # most of a joint-space correction unexplained: β̂ stayed below 1e-4 (measured).
            step = super().update(ctx, prior, env, plan, phi_h)
            kept = dataclasses.replace(belief, theta=step.belief.theta, cov=step.belief.cov)
            return dataclasses.replace(step, belief=kept, relevance=1.0)
        if ctx.corrected is None:  # nothing to judge: the prior rate
            beta, found = person.rate_mean, None
        else:
            full = super().update(ctx, prior, env, plan, phi_h).belief  # p(θ | z), β̂ = 1
            irrelevant, _, scatter = self.densities()
            found = judge(
                ctx.book,
                env,
                plan.trajectory,
                ctx.corrected,
                self.model,
                full.theta,
                full.cov,
                ctx.sigma.points(belief.theta, belief.cov + ctx.noise.process),
                person=person,
                scatter=[(w, sd**2 * np.eye(belief.dim)) for w, sd in scatter],
                scatter_center=belief.theta,
                irrelevant=irrelevant,
                space=self.space,
            )
            beta = found.relevance
        noise = KalmanNoise(process=ctx.noise.process, observation=ctx.noise.observation / beta)
        step = super().update(dataclasses.replace(ctx, noise=noise), prior, env, plan, phi_h)
        if found is not None:
            person = found.person
        history = belief.history
        if history and not belief.asked and ctx.corrected is not None:
            history = (*history, (env, plan.trajectory, np.asarray(ctx.corrected, float)))
        after = Belief(
            theta=step.belief.theta,
            cov=step.belief.cov,
            person=person,
            extra=belief.extra,
            asked=belief.asked,
            history=history,
        )
        after, expansion = self.expand(ctx, after, env)
        return dataclasses.replace(
            step,
            belief=after,
            relevance=beta,
            residual=None if found is None else found.rho,
            expansion=expansion,
        )

    def expand(
        self, ctx: LearnerContext, belief: Belief, env: Environment
    ) -> tuple[Belief, dict | None]:
        """Feature expansion (FERL): once the person's corrections are believed mostly
        unexplained (E[r] < ``expand_below`` after ``expand_after`` corrections), ask them for
        ``expand_traces`` feature traces in ``env``, learn the feature, and go on over k + 1
        features: its weight N(0, ``expand_variance``) beside the belief so far; from then on
        the person's corrections are taken as relevant (see :meth:`update`)."""
        wanted = self.wants_traces(belief, ctx.iteration + 1)
        if not wanted or ctx.teach is None:  # no teacher here: a session asks its person
            return belief, None
        traces = ctx.teach(wanted, env)
        if traces is None:
            declined = dataclasses.replace(belief, asked=True, history=())
            return declined, {"asked": True, "taught": False}
        return self.grow(belief, env, traces, ctx.rng, ctx)

    def learns_features(self) -> bool:
        return self.expand_traces > 0

    def wants_traces(self, belief: Belief, corrections: int) -> int:
        """How many feature traces it asks for after ``corrections`` corrections with
        ``belief`` (0: none; it asks once)."""
        person = belief.person
        due = (
            self.expand_traces > 0
            and not belief.asked
            and corrections >= self.expand_after
            and person is not None
            and person.rate_mean < self.expand_below
        )
        return self.expand_traces if due else 0

    def grow(
        self,
        belief: Belief,
        env: Environment,
        traces,
        rng: np.random.Generator,
        ctx: LearnerContext,
    ) -> tuple[Belief, dict]:
        """The belief over k + 1 features after learning a feature from ``traces`` given in
        ``env`` (registered under its name; the expansion's facts beside it).

        The past is read again over the new features: from the prior (θ̂⁰, P⁰) extended by
        N(0, ``expand_variance``) for the new weight, each kept correction updates the belief
        as KF-C does (the person has shown what their corrections were about, so all are
        taken as relevant), planned over k + 1 features with ``ctx``'s planner settings."""
        start = time.process_time()
        learnt = learn(traces, env, rng, network=self.network())
        name = register_learnt(learnt)
        (theta0, cov0), *past = belief.history or ((belief.theta, belief.cov),)
        k = len(theta0)
        cov = np.zeros((k + 1, k + 1))
        cov[:k, :k] = cov0
        cov[k, k] = self.expand_variance
        grown = Belief(theta=np.append(theta0, 0.0), cov=cov)
        features = (*ctx.features, name)
        config = dataclasses.replace(ctx.book.planner.config, features=features)
        book = PlanBook(shared_planner(config), warm_start=ctx.book.warm_start)
        for env_i, robot, corrected in past:
            seen = dataclasses.replace(
                ctx, book=book, features=features, noise=ctx.noise.grown(k + 1),
                corrected=corrected,
            )  # fmt: skip
            plan = Plan(  # the plan the person corrected then, its Φ over k + 1 features
                trajectory=robot,
                features=feature_counts(robot, env_i, features),
                reward=float("nan"),
                status="kept",
                iterations=0,
                solve_time=0.0,
                starts=0,
            )
            try:
                phi_h = feature_counts(corrected, env_i, features)
                grown = CorrectionAwareKalman.update(self, seen, grown, env_i, plan, phi_h).belief
            except PlanningError:
                continue  # skipped, as the loop skips an update whose plans fail
        grown = Belief(theta=grown.theta, cov=grown.cov, extra=(*belief.extra, name), asked=True)
        return grown, {
            "asked": True,
            "taught": True,
            "feature": name,
            "traces": len(traces),
            "reread": len(past),
            "loss": learnt.loss,
            "seconds": time.process_time() - start,
        }


@register_learner("KF-CRX")
@dataclass(frozen=True)
class ExpandingRelevanceKalman(PersonRelevanceKalman):
    """KF-CRP that learns the feature it lacks (FERL): when the person's corrections are
    believed mostly unexplained, it asks for 10 feature traces, learns a feature from them
    and learns its weight from the corrections that follow (see
    :meth:`PersonRelevanceKalman.expand`)."""

    label = "KF-CRP with feature expansion (KF-CRX)"
    style = ("#17becf", "-")

    expand_traces: int = 10


@functools.lru_cache(maxsize=16)
def _fit(path: str):
    return load_fit(path or None)


@register_learner("PP-R")
@dataclass(frozen=True)
class RelevanceAwarePerceptron(_RelevanceAware, Perceptron):
    """PP whose rate is scaled by the correction's relevance β̂: θ̂ += αᵗ β̂ (Φ_h − Φ(ξᵗ)).

    Attributes:
        model: C, the correction model β̂ explains corrections with (KF-C's default).
        relevance_prior: p in (0, 1), the prior probability that a correction is relevant.
        relevance_spread: σ > 0 of the unexplained fraction ρ of a relevant correction.
    """

    label = "Relevance-aware PP (PP-R)"
    style = ("#bcbd22", "-")

    model: CorrectionModel = components.nested(CORRECTIONS, WaypointCorrection())
    relevance_prior: float = 0.5
    relevance_spread: float = 0.05

    def __post_init__(self) -> None:
        super().__post_init__()
        _require_model(self.model)
        self.relevance(2)

    def check(self, n_waypoints: int) -> None:
        _model_fits(self.model, n_waypoints)

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        beta, rho = _judge(ctx, belief, env, plan, self.model, self.relevance(belief.dim))
        alpha = float(ctx.alphas[ctx.iteration]) * beta
        new = perceptron_update(belief, plan.features, phi_h, alpha)
        return Step(new, None, phi_h - plan.features, None, relevance=beta, residual=rho)


@register_learner("PP-MAX")
@dataclass(frozen=True)
class OneFeaturePerceptron(Perceptron):
    """One feature at a time (Bajcsy, Losey, O'Malley & Dragan, HRI 2018; FERL's "MAX"): the
    perceptron's update on the one feature the correction changed most, |Φ_h,i − Φ_i|, and
    none on the others. Every feature here is a sum of per-waypoint values in [0, 1], so the
    changes are compared as they are."""

    label = "One feature at a time (PP-MAX)"
    style = ("#7f7f7f", ":")

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        change = np.asarray(phi_h, float) - plan.features
        only = np.zeros_like(change)
        i = int(np.argmax(np.abs(change)))
        only[i] = change[i]
        new = perceptron_update(
            belief, plan.features, plan.features + only, float(ctx.alphas[ctx.iteration])
        )
        return Step(new, None, change, None)


@register_learner("KF-CI")
@dataclass(frozen=True)
class IteratedCorrectionAwareKalman(CorrectionAwareKalman):
    """KF-C whose every correction is linearised again around the posterior it gives, until
    it settles (IPLF, ``iterate = "each"``)."""

    label = "KF-C, iterated (KF-CI)"
    style = ("#9467bd", "--")

    iterate: str = "each"


@register_learner("KF-CB")
@dataclass(frozen=True)
class BatchCorrectionAwareKalman(CorrectionAwareKalman):
    """KF-C that reads every correction so far again around the current posterior after
    each new one (batch iterated posterior linearisation, ``iterate = "all"``)."""

    label = "KF-C, all corrections iterated (KF-CB)"
    style = ("#8c564b", "--")

    iterate: str = "all"


@register_learner("PF-C")
@dataclass(frozen=True)
class ParticleCorrectionAware(CorrectionAwareKalman):
    """A particle learner under KF-C's model: particles over θ from the prior, each weighed
    by every correction's likelihood N(Φ_h; hₜ(θ), N) (one plan per particle, warm from the
    run's nearest planned θ), resampled when the effective sample size falls below
    ``resample_below`` × the count, and then moved by ``moves`` random-walk Metropolis steps
    that re-evaluate every past correction (:mod:`~corrections_sim.learning.particles`). Its
    mean and covariance are the belief every consumer reads. θ is static (no process noise
    M, as in the exact reference); its random draws come from a child of the run's generator
    (``rng.spawn``), so the person's draws are the same as for every other learner.

    Attributes:
        particles: how many (>= 2).
        moves: Metropolis steps per particle after a resample (>= 0).
        resample_below: resample once ESS < this × the count, in (0, 1].
    """

    label = "Particle filter, KF-C's model (PF-C)"
    style = ("#bcbd22", "--")

    particles: int = 200
    moves: int = 2
    resample_below: float = 0.5

    def __post_init__(self) -> None:
        super().__post_init__()
        _count("particles", self.particles, 2)
        _count("moves", self.moves, 0)
        threshold = self.resample_below
        ok = isinstance(threshold, int | float) and not isinstance(threshold, bool)
        if not (ok and 0.0 < threshold <= 1.0):
            raise ParameterError("resample_below", f"must be in (0, 1], got {threshold!r}")
        if self.iterate != "none":
            raise ParameterError("iterate", "a particle learner is not linearised")
        if self.noise != "fixed":
            raise ParameterError("noise", "PF-C keeps N fixed (its likelihood is N(h(θ), N))")

    def initial(self, belief: Belief, noise: KalmanNoise) -> Belief:
        return Belief(theta=belief.theta, cov=belief.cov, history=((belief.theta, belief.cov),))

    @staticmethod
    def predict(observe: Observe, thetas: np.ndarray) -> np.ndarray:
        """h(θ) at each of ``thetas`` (n, k), a row of NaN where the planner finds no plan."""
        h = np.full(thetas.shape, np.nan)
        for i, theta in enumerate(thetas):
            try:
                h[i] = observe(theta[None, :])[0]
            except PlanningError:
                continue
        return h

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        rng = ctx.rng.spawn(1)[0]
        (theta0, cov0), *_ = belief.history or ((belief.theta, belief.cov),)
        prior = Belief(theta=theta0, cov=cov0)
        cloud = belief.particles or particles_draw(prior, self.particles, rng)
        z = np.asarray(phi_h, float)
        noise = ctx.noise.observation
        h = self.predict(self.observer_of(ctx, env, plan.trajectory), cloud.thetas)
        # What it expected before the correction: the particles' predictive mean and spread.
        seen = np.all(np.isfinite(h), axis=1)
        if not seen.any():
            raise PlanningError(f"{env.name}: no particle's plan exists; the update is skipped")
        w = cloud.weights()[seen] / cloud.weights()[seen].sum()
        expected = w @ h[seen]
        spread = (w[:, None] * (h[seen] - expected)).T @ (h[seen] - expected)
        entry = (env, plan.trajectory, z, noise)
        past = [*belief.history[1:], entry]
        observers = [(self.observer_of(ctx, e, robot), zi, ni) for e, robot, zi, ni in past]

        def log_total(thetas: np.ndarray) -> tuple[np.ndarray, int]:
            total = np.zeros(len(thetas))
            for observe_i, zi, ni in observers:
                total += particle_likelihood(zi, self.predict(observe_i, thetas), ni)
            return total, len(thetas) * len(observers)

        inverse = np.linalg.inv(prior.cov)

        def log_prior(thetas: np.ndarray) -> np.ndarray:
            d = thetas - prior.theta
            return -0.5 * np.einsum("ni,ij,nj->n", d, inverse, d)

        moved = particles_correct(
            cloud,
            particle_likelihood(z, h, noise),
            log_prior,
            log_total,
            rng,
            moves=self.moves,
            threshold=self.resample_below,
        )
        after = particles_belief(moved.particles, history=((theta0, cov0), *past))
        return Step(
            after,
            None,
            z - plan.features,
            symmetrize(spread + noise),
        )


@register_learner("AL-PF")
@dataclass(frozen=True)
class ParticleActive(_Active, ParticleCorrectionAware):
    """PF-C with environments chosen by eq. (A1): the UKF's predicted covariance from the
    particles' mean and covariance (2k + 1 plans per candidate environment; the particles'
    own predicted posterior would cost a plan per particle per environment)."""

    label = "AL on PF-C's belief (AL-PF)"
    style = ("#ff7f0e", ":")
