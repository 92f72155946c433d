"""Learners of the human's preferences θ from corrections.

* :mod:`.base`: the :class:`~.base.Learner` protocol, its context and the ``LEARNERS`` registry;
  :mod:`.learners`: the built-in learners, one module per family, registered by name;
  :mod:`.step`: :class:`~.step.Step`, the one result every update returns.
* The maths, pure numpy (no planner): :mod:`.perceptron` (eq. B5), :mod:`.kalman` (UKF and
  EKF, eqs. K1–K7, and their predicted covariances), :mod:`.active` (eq. A1),
  :mod:`.attenuated` (a UKF for corrections that deliver an unknown fraction of the intended
  feature change), :mod:`.preference_posterior` (a Gaussian posterior under a Boltzmann model
  of corrections).
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

# The built-in learners are registered on import; first, so they lead the registry's order.
from corrections_sim.learning import learners  # noqa: E402,F401
