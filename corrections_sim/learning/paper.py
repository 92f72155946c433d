"""The paper's learners and their calibrated variants, as registered :class:`Learner` plug-ins.

* "PP" (eq. B5, αᵗ from the KF runs' gains as in the paper), "PP-C" (αᵗ from KF-C's gains,
  so that no learner wins by a larger step alone);
* "KF" (the UKF the paper simulates, h(θ) = Φ(ξ*(θ, E))), "EKF" (eqs. K4–K7 with
  H = ∂Φ(ξ*(θ, E))/∂θ by central differences of the planner, step ``ekf_step``);
* "KF-C", the correction-aware UKF: hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E)), E), the features of the
  correction a person with preference θ would make to the robot's current trajectory ξᵗ,
  under the robot's correction model C (``correction_model``, see
  :mod:`corrections_sim.people.corrections`). It reuses the sigma points' plans; no extra solves;
* "AL" and "AL-C": KF and KF-C with Eᵗ chosen by eq. (A1) from their predicted covariance;
* "KF-A", a UKF for corrections that deliver an unknown fraction a ~ log-uniform[
  ``attenuation_min``, ``attenuation_max``] of the intended feature change
  (:mod:`corrections_sim.learning.attenuated`), and "BP", a Gaussian posterior under a
  Boltzmann model, P(ξ_h ≻ ξᵗ | θ) = σ(β θ·(Φ_h − Φ(ξᵗ))), β integrated out over
  [``beta_min``, ``beta_max``] (:mod:`corrections_sim.learning.preference_posterior`).

Their parameters are the study's settings keys named above (``from_settings`` reads them).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from corrections_sim.learning import (
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
from corrections_sim.learning.base import Learner, LearnerContext, Step, register_learner
from corrections_sim.planning.planner import Plan, PlanningError
from corrections_sim.planning.plans import correction_observer
from corrections_sim.scene.environments import Environment

if TYPE_CHECKING:
    from corrections_sim.people.corrections import CorrectionModel
    from corrections_sim.study.loop import StudySettings


@register_learner("PP")
class Perceptron(Learner):
    """The Preference Perceptron, eq. (B5): θ̂ += αᵗ (Φ_h − Φ(ξᵗ)); P stays P⁰."""

    label = "Preference Perceptron (PP)"
    style = ("#7f7f7f", "-")
    has_covariance = False
    rate_from = "KF"

    @classmethod
    def from_settings(cls, settings: StudySettings) -> Learner:
        return cls()

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        new = perceptron_update(belief, plan.features, phi_h, float(ctx.alphas[ctx.iteration]))
        return Step(new, None, phi_h - plan.features, None)


class _Filter(Learner):
    """A Gaussian filter with the study's noise M, N and sigma points."""

    def __init__(self, noise: KalmanNoise, sigma: SigmaPoints) -> None:
        self.noise = noise
        self.sigma = sigma

    @classmethod
    def from_settings(cls, settings: StudySettings) -> Learner:
        return cls(settings.noise(), settings.sigma())


@register_learner("KF")
class UnscentedKalman(_Filter):
    """The UKF the paper simulates, observation h(θ) = Φ(ξ*(θ, E), E)."""

    label = "Kalman filter (KF)"
    style = ("#1f77b4", "-")

    def observer(self, ctx: LearnerContext, belief: Belief, env: Environment) -> Observe:
        """What this learner believes a correction in ``env`` shows, as a function of θ."""
        return ctx.book.observe(env)

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        # Innovation against Φ(ξᵗ) (eq. K5); for KF-C that is hₜ(θ̂), since C(ξᵗ, ξᵗ) = ξᵗ.
        step = ukf_update(
            belief,
            self.observer(ctx, belief, env),
            phi_h,
            self.noise,
            self.sigma,
            reference=plan.features,
        )
        return Step(step.belief, step.gain, step.innovation, step.innovation_cov)


@register_learner("EKF")
class ExtendedKalman(_Filter):
    """Eqs. (K4)–(K7) with H by central differences of the planner (step ``ekf_step``)."""

    label = "Extended Kalman filter (EKF)"
    style = ("#2ca02c", "-")

    def __init__(self, noise: KalmanNoise, sigma: SigmaPoints, step: float) -> None:
        super().__init__(noise, sigma)
        self.step = step

    @classmethod
    def from_settings(cls, settings: StudySettings) -> Learner:
        return cls(settings.noise(), settings.sigma(), settings.ekf_step)

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        jac = finite_difference_jacobian(ctx.book.observe(env), belief.theta, self.step)
        step = ekf_update(belief, jac, plan.features, phi_h, self.noise)
        return Step(step.belief, step.gain, step.innovation, step.innovation_cov)


class _Active:
    """Mix-in: Eᵗ = argmin_E ‖P_{t+1}(E)‖_F, eq. (A1), over the environments whose plans
    exist (one that fails is no candidate; if none is left, the run's draw)."""

    active = True
    stream = 1

    def choose(self, ctx: LearnerContext, belief: Belief, draw: int) -> int:
        candidates, covs = [], []
        for i, env in enumerate(ctx.envs):
            try:
                observe = self.observer(ctx, belief, env)
                covs.append(ukf_predicted_covariance(belief, observe, self.noise, self.sigma))
                candidates.append(i)
            except PlanningError:
                continue
        return candidates[select_environment(covs)] if candidates else draw


@register_learner("AL")
class ActiveLearning(_Active, UnscentedKalman):
    """KF with environments chosen by eq. (A1)."""

    label = "Active learning (AL)"
    style = ("#d62728", "-")


@register_learner("PP-C")
class PerceptronFromCorrectionAware(Perceptron):
    """PP with αᵗ from KF-C's gains."""

    label = "PP, α from KF-C's gains (PP-C)"
    style = ("#7f7f7f", "--")
    rate_from = "KF-C"


@register_learner("KF-C")
class CorrectionAwareKalman(UnscentedKalman):
    """UKF with hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E)), E) under the correction model C."""

    label = "Correction-aware KF (KF-C)"
    style = ("#1f77b4", "--")

    def __init__(self, noise: KalmanNoise, sigma: SigmaPoints, model: CorrectionModel) -> None:
        super().__init__(noise, sigma)
        self.model = model

    @classmethod
    def from_settings(cls, settings: StudySettings) -> Learner:
        return cls(settings.noise(), settings.sigma(), settings.correction())

    def observer(self, ctx: LearnerContext, belief: Belief, env: Environment) -> Observe:
        robot = ctx.book.plan(belief.theta, env).trajectory
        model = self.model
        if model.n_waypoints != ctx.n_waypoints:
            model = type(model)(model.kind, model.step, model.waypoints, ctx.n_waypoints)
        return correction_observer(ctx.book, env, robot, model, ctx.features)


@register_learner("AL-C")
class CorrectionAwareActive(_Active, CorrectionAwareKalman):
    """KF-C with environments chosen by eq. (A1)."""

    label = "Correction-aware AL (AL-C)"
    style = ("#d62728", "--")


@register_learner("KF-A")
class AttenuatedKalman(_Filter):
    """UKF for corrections that deliver an unknown fraction a of the intended change."""

    label = "Attenuated-correction KF (KF-A)"
    style = ("#9467bd", "-.")

    def __init__(self, noise: KalmanNoise, sigma: SigmaPoints, attenuation: Attenuation) -> None:
        super().__init__(noise, sigma)
        self.attenuation = attenuation

    @classmethod
    def from_settings(cls, settings: StudySettings) -> Learner:
        return cls(settings.noise(), settings.sigma(), settings.attenuation())

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        step = attenuated_update(
            belief,
            ctx.book.observe(env),
            plan.features,
            phi_h,
            self.noise,
            self.attenuation,
            self.sigma,
        )
        return Step(step.belief, step.gain, step.innovation, step.innovation_cov)


@register_learner("BP")
class BoltzmannPosterior(Learner):
    """Gaussian posterior under a Boltzmann model of corrections; no planner solves."""

    label = "Boltzmann preference posterior (BP)"
    style = ("#8c564b", ":")

    def __init__(self, model: BoltzmannCorrection) -> None:
        self.model = model

    @classmethod
    def from_settings(cls, settings: StudySettings) -> Learner:
        return cls(settings.boltzmann())

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        post = posterior_update(belief, None, plan.features, phi_h, self.model)
        return Step(post.belief, post.gain, post.innovation, None)
