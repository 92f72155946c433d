"""BP's model on the exact reference's grid (:mod:`corrections_sim.learning.exact.grid`):
P(ξ_h ≻ ξᵗ | θ) under a Boltzmann model with β integrated out over BP's nodes."""

from __future__ import annotations

from corrections_sim.learning.exact import bayes
from corrections_sim.learning.exact.grid import GRID_MODELS, GridModel, Seen


@GRID_MODELS.decorator("boltzmann")
class BoltzmannGrid(GridModel):
    """A correction as a preference of ξ_h over ξᵗ (BP): reads Φ_h − Φ(ξᵗ), no plan at the
    grid's points."""

    needs_plans = False

    def correct(self, seen: Seen):
        betas = self.learner.correction_model(0.0).betas
        change = seen.z - seen.robot.features
        log_l = bayes.boltzmann_log_likelihood(self.thetas, change, betas, self.learner.lapse)
        self.log_p = self.log_p + log_l
        return self.log_p
