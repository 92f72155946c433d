"""Learners of the human's preferences θ from corrections.

* :mod:`.base`: the :class:`~.base.Learner` protocol, its context and the ``LEARNERS`` registry;
  :mod:`.step`: :class:`~.step.Step`, the one result every update returns;
  :mod:`.correction`: the one correction step every caller takes (context, update);
  :mod:`.observation`: hₜ(θ), what a correction shows of θ; :mod:`.params`: parameter checks.
* One folder a family, each with its maths and its learners: :mod:`.perceptron`,
  :mod:`.kalman`, :mod:`.boltzmann`, :mod:`.particles`, :mod:`.exact`, :mod:`.relevance`;
  :mod:`.roster` registers the built-in learners in the order tables list them.
"""

from corrections_sim.belief import Belief, KalmanNoise, symmetrize
from corrections_sim.learning.boltzmann.posterior import (
    BoltzmannCorrection,
    PosteriorStep,
    tilted_moments,
)
from corrections_sim.learning.boltzmann.posterior import moment_match as posterior_moment_match
from corrections_sim.learning.boltzmann.posterior import update as posterior_update
from corrections_sim.learning.kalman.attenuation import AttenuatedStep, Attenuation
from corrections_sim.learning.kalman.attenuation import update as attenuated_update
from corrections_sim.learning.kalman.filter import (
    COV_FLOOR_RTOL,
    EkfStep,
    SigmaPoints,
    UkfStep,
    ekf_predicted_covariance,
    ekf_update,
    finite_difference_jacobian,
    ukf_predicted_covariance,
    ukf_update,
)
from corrections_sim.learning.kalman.selection import frobenius, select_environment
from corrections_sim.learning.observation import Observe
from corrections_sim.learning.perceptron.update import learning_rate_schedule, perceptron_update

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
from corrections_sim.learning import roster  # noqa: E402,F401
