"""The Preference Perceptron (eq. B5) and its variants: PP (αᵗ from KF's gains, as in the
paper), PP-C (αᵗ from KF-C's gains) and PP-MAX (one feature at a time).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief
from corrections_sim.learning.base import Learner, LearnerContext, Step
from corrections_sim.learning.params import require_positive
from corrections_sim.learning.perceptron.update import perceptron_update
from corrections_sim.planning.planner import Plan
from corrections_sim.scene.environments import Environment


@dataclass(frozen=True)
class Perceptron(Learner):
    """The Preference Perceptron, eq. (B5): θ̂ += αᵗ (Φ_h − Φ(ξᵗ)); P stays P⁰.

    Attributes:
        fixed_alpha: a fixed learning rate α > 0; None (default): αᵗ is the mean diag(Kᵗ)
            over the runs of :attr:`rate_from` (the paper's choice).
    """

    label = "Preference Perceptron (PP)"
    question = (
        "The paper's baseline: how far does a learner get that keeps no uncertainty (a step "
        "toward the correction's features at the rate KF's gains give)?"
    )
    style = ("#7f7f7f", "-")
    has_covariance = False
    rate_from = "KF"

    fixed_alpha: float | None = None

    def __post_init__(self) -> None:
        if self.fixed_alpha is not None:
            require_positive("fixed_alpha", self.fixed_alpha)

    def rate_source(self) -> str | None:
        return None if self.fixed_alpha is not None else self.rate_from

    def fixed_rate(self) -> float | None:
        return self.fixed_alpha

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        new = perceptron_update(belief, plan.features, phi_h, float(ctx.alphas[ctx.iteration]))
        return Step(new, None, phi_h - plan.features, None)


@dataclass(frozen=True)
class PerceptronFromCorrectionAware(Perceptron):
    """PP with αᵗ from KF-C's gains."""

    label = "PP, α from KF-C's gains (PP-C)"
    question = (
        "Is it the covariance or the step size that helps: PP stepping at KF-C's Kalman gains?"
    )
    style = ("#7f7f7f", "--")
    rate_from = "KF-C"


@dataclass(frozen=True)
class OneFeaturePerceptron(Perceptron):
    """One feature at a time (Bajcsy, Losey, O'Malley & Dragan, HRI 2018; FERL's "MAX"): the
    perceptron's update on the one feature the correction changed most, |Φ_h,i − Φ_i|, and
    none on the others. Every feature here is a sum of per-waypoint values in [0, 1], so the
    changes are compared as they are."""

    label = "One feature at a time (PP-MAX)"
    question = (
        "FERL's MAX baseline: does a perceptron that steps on one feature a correction (the "
        "one it changed most) drift less?"
    )
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
