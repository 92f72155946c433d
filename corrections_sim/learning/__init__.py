"""Learners of the human's preferences θ from corrections: pure numpy, no planner.

* :mod:`.belief`: the Gaussian belief N(θ̂, P) and the filter's noise (M, N).
* :mod:`.perceptron`: the Preference Perceptron, eq. (B5).
* :mod:`.kalman`: UKF and EKF updates, eqs. (K1)–(K7), and their predicted covariances.
* :mod:`.active`: greedy environment selection, eq. (A1).
* :mod:`.attenuated`: a UKF for corrections that deliver an unknown fraction of the intended
  feature change (a Gaussian sum over the fraction, collapsed after each step).
* :mod:`.preference_posterior`: a Gaussian posterior under a Boltzmann model of corrections
  (a correction is a noisy improvement); no planner solves, no model of how people edit.
"""

from corrections_sim.belief import Belief, KalmanNoise, symmetrize
from corrections_sim.learning.active import frobenius, select_environment
from corrections_sim.learning.attenuated import AttenuatedStep, Attenuation
from corrections_sim.learning.attenuated import update as attenuated_update
from corrections_sim.learning.kalman import (
    COV_FLOOR_RTOL,
    EkfStep,
    Observe,
    SigmaPoints,
    UkfStep,
    ekf_predicted_covariance,
    ekf_update,
    finite_difference_jacobian,
    ukf_predicted_covariance,
    ukf_update,
)
from corrections_sim.learning.perceptron import learning_rate_schedule, perceptron_update
from corrections_sim.learning.preference_posterior import (
    BoltzmannCorrection,
    PosteriorStep,
    tilted_moments,
)
from corrections_sim.learning.preference_posterior import moment_match as posterior_moment_match
from corrections_sim.learning.preference_posterior import update as posterior_update

__all__ = [
    "Attenuation",
    "AttenuatedStep",
    "COV_FLOOR_RTOL",
    "attenuated_update",
    "Belief",
    "BoltzmannCorrection",
    "EkfStep",
    "KalmanNoise",
    "Observe",
    "SigmaPoints",
    "UkfStep",
    "ekf_predicted_covariance",
    "ekf_update",
    "finite_difference_jacobian",
    "frobenius",
    "learning_rate_schedule",
    "perceptron_update",
    "posterior_moment_match",
    "posterior_update",
    "PosteriorStep",
    "select_environment",
    "symmetrize",
    "tilted_moments",
    "ukf_predicted_covariance",
    "ukf_update",
]

# The paper's learners register themselves on import; first, so they lead the registry's order.
from corrections_sim.learning import paper  # noqa: E402,F401
