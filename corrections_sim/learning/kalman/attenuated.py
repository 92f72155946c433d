"""KF-A: a UKF for corrections that deliver an unknown fraction a ~ log-uniform[
``attenuation_min``, ``attenuation_max``] of the intended feature change
(:mod:`corrections_sim.learning.kalman.attenuation`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import Learner, LearnerContext, Step
from corrections_sim.learning.kalman.attenuation import Attenuation
from corrections_sim.learning.kalman.attenuation import update as attenuated_update
from corrections_sim.learning.observation import Observation, PlanFeatures
from corrections_sim.learning.params import renamed_keys
from corrections_sim.planning.planner import Plan
from corrections_sim.scene.environments import Environment

_ATTENUATION_NAMES = {
    "Attenuation.a_min": "attenuation_min",
    "Attenuation.a_max": "attenuation_max",
    "Attenuation.n_a": "attenuation_points",
}


@dataclass(frozen=True)
class AttenuatedKalman(Learner):
    """UKF for corrections that deliver an unknown fraction a of the intended change.

    Attributes:
        attenuation_min, attenuation_max: the range of a, 0 < min ≤ max (log-uniform prior).
        attenuation_points: how many log-spaced values of a (1 … 10,000).
    """

    label = "Attenuated-correction KF (KF-A)"
    question = (
        "Can a filter learn what fraction of the way to their plan the person moves the robot?"
    )
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
        return renamed_keys(
            lambda: Attenuation(
                a_min=self.attenuation_min,
                a_max=self.attenuation_max,
                n_a=self.attenuation_points,
            ),
            _ATTENUATION_NAMES,
        )

    def observation(self) -> Observation:
        return PlanFeatures()

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        return attenuated_update(
            belief,
            self.observer(ctx, belief, env),
            plan.features,
            phi_h,
            ctx.noise,
            self.attenuation(),
            ctx.sigma,
        )
