"""The Kalman learners: KF (the UKF the paper simulates, h(θ) = Φ(ξ*(θ, E))), KF-C (the
correction-aware UKF, hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E)), E) under the robot's correction model C),
KF-CL (N learnt) and KF-CI (iterated posterior linearisation, each step).

Two left the registry once their question was answered (``roster.py`` says why, and
looking them up says so): KF-CB (the whole batch iterated) and the EKF of the paper's
exposition, eqs. (K4)–(K7), whose update stays in :mod:`.filter` (``ekf_update``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim import components
from corrections_sim.belief import Belief, KalmanNoise
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import Learner, LearnerContext, Likelihood, Step
from corrections_sim.learning.kalman.filter import (
    ukf_predicted_covariance,
    ukf_update,
)
from corrections_sim.learning.kalman.iterated import iterated_update
from corrections_sim.learning.kalman.learnt_noise import vb_ukf_update
from corrections_sim.learning.kalman.state import NoisePosterior, NoiseState
from corrections_sim.learning.observation import (
    CorrectedPlanFeatures,
    Observation,
    PlanFeatures,
)
from corrections_sim.learning.params import require_count, require_positive
from corrections_sim.people.corrections import (
    CORRECTIONS,
    CorrectionModel,
    WaypointCorrection,
)
from corrections_sim.planning.planner import Plan
from corrections_sim.scene.environments import Environment

#: How a filter treats the person's observation noise N (the ``noise`` parameter).
NOISE_MODES = ("fixed", "learnt")


#: How a filter linearises its observation (the ``iterate`` parameter): "none" (the UKF) or
#: "each" (the correction again around its posterior, IPLF). A batch form, every correction so
#: far again around the current posterior (KF-CB), measured no better than KF-C and was removed
#: (docs/exact-confidence.md).
ITERATE_MODES = ("none", "each")


@dataclass(frozen=True)
class UnscentedKalman(Learner):
    """The UKF the paper simulates, observation h(θ) = Φ(ξ*(θ, E), E), with the study's
    M, N and sigma points.

    Attributes:
        noise: "fixed" (N is the study's, the paper's filter) or "learnt": N is estimated
            jointly with θ by variational Bayes (``learning.learnt_noise.vb_ukf_update``),
            from a prior IW whose estimate is the study's N, held with ``noise_dof`` degrees
            of freedom.
        noise_dof: the prior's degrees of freedom ν₀ > k − 1 (how many corrections' worth
            the study's N counts for); None: k + 2.
        iterate: "none" (the UKF step) or "each" (the iterated posterior linearisation
            filter: each correction's h linearised again w.r.t. the posterior it gives,
            ``learning.kalman.iterated.iterated_update``). Needs ``noise = "fixed"``.
        iterations: at most this many linearisations per correction ("each"); >= 1.
        tolerance: stop iterating once the posterior moves by less than this KL (nats, > 0).
    """

    label = "Kalman filter (KF)"
    question = (
        "The paper's question: does a learner that tracks its uncertainty (a UKF reading a "
        "correction's features as Φ(ξ*) plus noise) learn faster than PP?"
    )
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
            require_positive("noise_dof", self.noise_dof)
        if self.iterate not in ITERATE_MODES:
            raise ParameterError(
                "iterate", f"must be one of {', '.join(ITERATE_MODES)}, got {self.iterate!r}"
            )
        require_count("iterations", self.iterations, 1)
        require_positive("tolerance", self.tolerance)
        if self.iterate != "none" and self.noise != "fixed":
            raise ParameterError(
                "iterate", f'{self.iterate!r} needs noise = "fixed" (N is learnt here)'
            )

    def initial(self, belief: Belief, noise: KalmanNoise) -> Belief:
        prior = self.noise_prior(belief, noise)
        if prior is None:
            return belief
        return Belief(theta=belief.theta, cov=belief.cov, state=NoiseState(prior))

    def noise_prior(self, belief: Belief, noise: KalmanNoise) -> NoisePosterior | None:
        """The inverse-Wishart prior over N around the study's ``noise`` (None with N fixed)."""
        if self.noise == "fixed":
            return None
        dof = self.noise_dof if self.noise_dof is not None else belief.dim + 2.0
        if not dof > belief.dim - 1:
            raise ParameterError("noise_dof", f"must be > k - 1 = {belief.dim - 1}, got {dof}")
        return NoisePosterior.around(noise.observation, dof)

    def likelihood(self) -> Likelihood:
        kind = "gaussian" if self.noise == "fixed" else "gaussian-learnt-noise"
        return Likelihood(kind, self.assumed_correction())

    def filter_noise(self, ctx: LearnerContext, belief: Belief) -> KalmanNoise:
        """M and N as this filter believes them now (N̂ when it learns N)."""
        estimate = belief.state.noise_estimate()
        if estimate is None:
            return ctx.noise
        return KalmanNoise(process=ctx.noise.process, observation=estimate)

    def observation(self) -> Observation:
        """h(θ) = Φ(ξ*(θ, E), E), the paper's; a correction model's for KF-C and its kin."""
        correction = self.assumed_correction()
        return PlanFeatures() if correction is None else CorrectedPlanFeatures(correction)

    def predicted_covariance(
        self, ctx: LearnerContext, belief: Belief, env: Environment
    ) -> np.ndarray:
        """P after a correction in ``env`` as the UKF predicts it before the correction is
        made (k, k): what active learning (eq. A1) compares environments by."""
        observe = self.observer(ctx, belief, env)
        return ukf_predicted_covariance(belief, observe, self.filter_noise(ctx, belief), ctx.sigma)

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        # Innovation against Φ(ξᵗ) (eq. K5); for KF-C that is hₜ(θ̂), since C(ξᵗ, ξᵗ) = ξᵗ.
        observe = self.observer(ctx, belief, env)
        if isinstance(belief.state, NoiseState):
            return vb_ukf_update(
                belief, observe, phi_h, ctx.noise, ctx.sigma, reference=plan.features
            )
        if self.iterate == "none":
            return ukf_update(belief, observe, phi_h, ctx.noise, ctx.sigma, reference=plan.features)
        return iterated_update(
            belief, observe, phi_h, ctx.noise, ctx.sigma, reference=plan.features,
            iterations=self.iterations, tolerance=self.tolerance,
        )  # fmt: skip


def require_model(model) -> None:
    """Refuse a ``model`` parameter that is not a correction model."""
    if not isinstance(model, CorrectionModel):
        raise ParameterError("model", f"expected a correction model, got {model!r}")


def model_fits(model: CorrectionModel, n_waypoints: int) -> None:
    """The correction model's own check for T = ``n_waypoints``, under the key ``model.…``."""
    try:
        model.check(n_waypoints)
    except ParameterError as exc:
        raise ParameterError(f"model.{exc.name}", exc.message) from None


@dataclass(frozen=True)
class CorrectionAwareKalman(UnscentedKalman):
    """UKF with hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E)), E) under the correction model C.

    Attributes:
        model: C, any registered correction model with its parameters (a name, or a table
            ``{ name = "waypoint", step = 0.5 }``); the paper's one-waypoint correction by
            default.
    """

    label = "Correction-aware KF (KF-C)"
    question = (
        "Does modelling how the person corrects (the worst waypoint moved toward their plan) "
        "remove the bias of the paper's KF?"
    )
    style = ("#1f77b4", "--")

    model: CorrectionModel = components.nested(CORRECTIONS, WaypointCorrection())

    def assumed_correction(self) -> CorrectionModel:
        return self.model

    def __post_init__(self) -> None:
        super().__post_init__()
        require_model(self.model)

    def check(self, n_waypoints: int) -> None:
        model_fits(self.model, n_waypoints)


@dataclass(frozen=True)
class CorrectionAwareKalmanLearntNoise(CorrectionAwareKalman):
    """KF-C that learns the person's observation noise N (``noise = "learnt"``)."""

    label = "KF-C, N learnt (KF-CL)"
    question = (
        "Does learning how noisy the person is (N) make a correction-aware filter's "
        "confidence honest?"
    )
    style = ("#17becf", "--")

    noise: str = "learnt"


@dataclass(frozen=True)
class IteratedCorrectionAwareKalman(CorrectionAwareKalman):
    """KF-C whose every correction is linearised again around the posterior it gives, until
    it settles (IPLF, ``iterate = "each"``)."""

    label = "KF-C, iterated (KF-CI)"
    question = (
        "Does linearizing each correction again around the posterior it gives (an iterated "
        "filter) close KF-C's gap to its exact posterior?"
    )
    style = ("#9467bd", "--")

    iterate: str = "each"
