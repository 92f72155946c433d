"""Active learning (eq. A1): a Kalman learner that chooses Eᵗ from its predicted covariance —
AL over KF, AL-C over KF-C, AL-CL over KF-CL (AL-PF, over the particles, is in
:mod:`.particles`).
"""

from __future__ import annotations

from dataclasses import dataclass

from corrections_sim.belief import Belief
from corrections_sim.learning.base import LearnerContext
from corrections_sim.learning.kalman.learners import (
    CorrectionAwareKalman,
    CorrectionAwareKalmanLearntNoise,
    UnscentedKalman,
)
from corrections_sim.learning.kalman.selection import select_environment
from corrections_sim.planning.planner import PlanningError


class ActiveMixin:
    """Mix-in over a learner that predicts its covariance: Eᵗ = argmin_E ‖P_{t+1}(E)‖_F,
    eq. (A1), over the environments whose plans exist and that were not declined since the
    last correction (one that fails, or that the person skipped, is no candidate; if none is
    left, the run's draw). What it needs of the learner it is mixed into is one method,
    ``predicted_covariance(ctx, belief, env)`` (every Kalman learner has it; a class that
    mixes it into a learner without it is refused when it is defined)."""

    active = True
    stream = 1

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if not callable(getattr(cls, "predicted_covariance", None)):
            raise TypeError(
                f"{cls.__name__}: active learning mixes into a learner that predicts its "
                "covariance (predicted_covariance(ctx, belief, env) -> (k, k))"
            )

    def choose(self, ctx: LearnerContext, belief: Belief, draw: int) -> int:
        candidates, covs = [], []
        for i, env in enumerate(ctx.envs):
            if i in ctx.declined:
                continue
            try:
                covs.append(self.predicted_covariance(ctx, belief, env))
                candidates.append(i)
            except PlanningError:
                continue
        return candidates[select_environment(covs)] if candidates else draw


@dataclass(frozen=True)
class ActiveLearning(ActiveMixin, UnscentedKalman):
    """KF with environments chosen by eq. (A1)."""

    label = "Active learning (AL)"
    question = (
        "The paper's active learning: does choosing the environment that minimizes the "
        "predicted covariance (eq. (A1)) learn faster than random environments?"
    )
    style = ("#d62728", "-")


@dataclass(frozen=True)
class CorrectionAwareActive(ActiveMixin, CorrectionAwareKalman):
    """KF-C with environments chosen by eq. (A1)."""

    label = "Correction-aware AL (AL-C)"
    question = (
        "Does the paper's active learning still help once the filter models how the person "
        "corrects?"
    )
    style = ("#d62728", "--")


@dataclass(frozen=True)
class CorrectionAwareActiveLearntNoise(ActiveMixin, CorrectionAwareKalmanLearntNoise):
    """AL-C that learns the person's observation noise N: environments by eq. (A1) with N̂."""

    label = "AL-C, N learnt (AL-CL)"
    question = "Does active learning help a filter that also learns how noisy the person is?"
    style = ("#ff7f0e", "--")
