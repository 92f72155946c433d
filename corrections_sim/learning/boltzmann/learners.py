"""BP: a Gaussian posterior under a Boltzmann model of corrections, P(ξ_h ≻ ξᵗ | θ) =
σ(β θ·(Φ_h − Φ(ξᵗ))), β integrated out over [``beta_min``, ``beta_max``]
(:mod:`corrections_sim.learning.boltzmann.posterior`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import Learner, LearnerContext, Likelihood, Step
from corrections_sim.learning.boltzmann.posterior import BoltzmannCorrection
from corrections_sim.learning.boltzmann.posterior import update as posterior_update
from corrections_sim.learning.params import renamed_keys
from corrections_sim.planning.planner import Plan
from corrections_sim.scene.environments import Environment

_BOLTZMANN_NAMES = {
    "BoltzmannCorrection.beta_min": "beta_min",
    "BoltzmannCorrection.beta_max": "beta_max",
    "BoltzmannCorrection.n_beta": "beta_points",
    "BoltzmannCorrection.lapse": "lapse",
}


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
    question = (
        "How well does a learner do that needs no plans at all: the correction preferred to "
        "the robot's plan, Boltzmann-rational with its rationality integrated out?"
    )
    style = ("#8c564b", ":")

    beta_min: float = 0.3
    beta_max: float = 30.0
    beta_points: int = 15
    lapse: float = 0.0

    def __post_init__(self) -> None:
        if isinstance(self.beta_points, int) and self.beta_points > 10_000:
            raise ParameterError("beta_points", "at most 10,000")
        self.correction_model(0.0)

    def likelihood(self) -> Likelihood:
        return Likelihood("boltzmann")

    def correction_model(self, process_noise: float) -> BoltzmannCorrection:
        """Its model of a correction, with the study's process noise M = q I."""
        return renamed_keys(
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
