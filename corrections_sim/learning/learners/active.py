"""Active learning (eq. A1): a Kalman learner that chooses Eᵗ from its predicted covariance —
AL over KF, AL-C over KF-C, AL-CL over KF-CL (AL-PF, over the particles, is in
:mod:`.particles`).
"""

from __future__ import annotations

from dataclasses import dataclass

from corrections_sim.belief import Belief
from corrections_sim.learning.active import select_environment
from corrections_sim.learning.base import LearnerContext
from corrections_sim.learning.kalman import (
    ukf_predicted_covariance,
)
from corrections_sim.learning.learners.kalman import (
    CorrectionAwareKalman,
    CorrectionAwareKalmanLearntNoise,
    UnscentedKalman,
)
from corrections_sim.planning.planner import PlanningError


class ActiveMixin:
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


@dataclass(frozen=True)
class ActiveLearning(ActiveMixin, UnscentedKalman):
    """KF with environments chosen by eq. (A1)."""

    label = "Active learning (AL)"
    style = ("#d62728", "-")


@dataclass(frozen=True)
class CorrectionAwareActive(ActiveMixin, CorrectionAwareKalman):
    """KF-C with environments chosen by eq. (A1)."""

    label = "Correction-aware AL (AL-C)"
    style = ("#d62728", "--")


@dataclass(frozen=True)
class CorrectionAwareActiveLearntNoise(ActiveMixin, CorrectionAwareKalmanLearntNoise):
    """AL-C that learns the person's observation noise N: environments by eq. (A1) with N̂."""

    label = "AL-C, N learnt (AL-CL)"
    style = ("#ff7f0e", "--")
