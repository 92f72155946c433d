"""The relevance-aware learners' models on the exact reference's grid
(:mod:`corrections_sim.learning.exact.grid`): KF-CR's, a correction's likelihood tempered by
the β̂ it judged (``relevance-per-correction``), and KF-CRP's, θ with the person's rate and
precision of relevant corrections (``relevance-person``)."""

from __future__ import annotations

import numpy as np

from corrections_sim.belief import KalmanNoise
from corrections_sim.learning.exact import bayes
from corrections_sim.learning.exact.grid import GRID_MODELS, GridModel, Seen
from corrections_sim.learning.relevance.judge import (
    MOVED,
    NUDGE_DIMENSIONS,
    beta_rho_density,
    embed,
    random_direction_shape,
)
from corrections_sim.learning.relevance.state import PersonBelief

#: Equal-probability nodes of KF-CRP's prior on τ in its exact reference.
PERSON_TAU_NODES = 48


@GRID_MODELS.decorator("relevance-per-correction")
class PerCorrectionGrid(GridModel):
    """A correction's Gaussian likelihood mixed with an irrelevant one by the β̂ the learner
    judged (KF-CR); a correction it skipped is not taken in. Its filter step is the UKF's
    with N / β̂."""

    filtered = True

    def filter_noise(self, noise: KalmanNoise, row: dict) -> KalmanNoise:
        if not row.get("relevance"):
            return noise
        beta = float(row["relevance"])
        return KalmanNoise(process=noise.process, observation=noise.observation / beta)

    def __init__(self, name, likelihood, learner, study, thetas, log_prior):
        if learner.noise == "learnt":
            raise ValueError(f"learner {name}: no reference for relevance with N learnt")
        super().__init__(name, likelihood, learner, study, thetas, log_prior)

    def correct(self, seen: Seen):
        if seen.row.get("relevance"):  # else the learner skipped this update
            log_l = bayes.relevance_log_likelihood(
                bayes.gaussian_log_likelihood(seen.z, seen.h, self.noise),
                self.log_p,
                float(seen.row["relevance"]),
            )
            self.log_p = self.log_p + log_l
        return self.log_p


@GRID_MODELS.decorator("relevance-person")
class PersonGrid(GridModel):
    """θ jointly with how often this person's corrections are relevant and how precisely
    (KF-CRP), on a finer grid of the person than the learner's; its exact β̂ of each
    correction, and the person's rate and spread, are the record's ``ref_relevance*``."""

    def __init__(self, name, likelihood, learner, study, thetas, log_prior):
        super().__init__(name, likelihood, learner, study, thetas, log_prior)
        _, (shape, rate), _ = learner.densities()
        a = learner.relevance_prior * learner.relevance_count
        b = (1.0 - learner.relevance_prior) * learner.relevance_count
        fine = PersonBelief.prior(shape, rate, a, b, tau_points=PERSON_TAU_NODES, rate_points=41)
        self.person = bayes.PersonPosterior.prior(thetas, log_prior, fine)

    def correct(self, seen: Seen):
        learner, k = self.learner, len(seen.z)
        rho = grid_residuals(
            seen.plans, seen.robot.trajectory, seen.corrected, self.correction, learner.space
        )
        recorded = float(seen.row["relevance_residual"] or 1.0)
        rho_star = min(float(np.nanmin(rho)), recorded)
        shape, _, scatter = learner.densities()
        f0 = beta_rho_density(rho_star, *(shape or random_direction_shape(NUDGE_DIMENSIONS, k)))
        mixture = [(w, sd**2 * np.eye(k)) for w, sd in scatter]
        tau0 = float(np.mean(self.person.taus))
        place = bayes.irrelevant_place(self.thetas, rho, rho_star, seen.before.theta, mixture, tau0)
        self.judged = {
            "ref_relevance": self.person.correct(
                bayes.gaussian_log_likelihood(seen.z, seen.h, self.noise),
                rho,
                rho_star,
                tau0,
                np.log(max(f0, 1e-300)) + place,
            ),
            "ref_relevance_rate": self.person.rate_mean(),
            "ref_relevance_spread": self.person.spread(),
        }
        return np.log(np.maximum(self.person.theta_weights(), 1e-300))


def grid_residuals(
    plans: np.ndarray, robot: np.ndarray, corrected: np.ndarray, model, space: str = "joint"
) -> np.ndarray:
    """ρ(θ) = ‖ξ_h − ĉ(θ)‖ / ‖ξ_h − ξ‖ on the moved waypoints, in ``space``, at every grid
    point (n,), ĉ the correction ``model`` toward the grid's plan; NaN where the grid has no
    plan."""
    corrected = np.asarray(corrected, float)
    rows = np.linalg.norm(corrected - robot, axis=1) > MOVED
    target = embed(space, corrected[rows])
    size = float(np.linalg.norm(target - embed(space, robot[rows])))
    out = np.full(plans.shape[0], np.nan)
    if size == 0.0:
        return np.zeros(plans.shape[0])
    for i, plan in enumerate(plans):
        if np.all(np.isfinite(plan)):
            out[i] = np.linalg.norm(target - embed(space, model.at(robot, plan, rows))) / size
    return out
