"""The built-in learners, one folder a family, registered here in the order figures and
tables list them (a plug-in's learner registers itself with
:func:`~corrections_sim.learning.base.register_learner`): a new family is its folder and its
lines here.

* :mod:`~corrections_sim.learning.perceptron`: PP, PP-C, PP-MAX;
  :mod:`~corrections_sim.learning.kalman`: KF, KF-C, KF-CL, KF-CI, AL, AL-C, AL-CL,
  KF-A; :mod:`~corrections_sim.learning.boltzmann`: BP;
  :mod:`~corrections_sim.learning.relevance`: KF-CR, KF-CRP, PP-R, KF-CRX;
  :mod:`~corrections_sim.learning.particles`: PF-C, AL-PF;
  :mod:`~corrections_sim.learning.exact`: EX-C, EX-CL, EX-M (on the study's plan atlas;
  its asking for feature traces is :mod:`~corrections_sim.learning.relevance.asking`).

Each is a frozen dataclass whose fields are its own parameters (``[learners.KF-A]
attenuation_min = 0.1`` in a study file); the filters' shared M, N and sigma points come from
the study through :class:`~corrections_sim.learning.base.LearnerContext`.

A learner leaves the registry when its question is answered, it runs in no study but the
every-learner comparison (``run learners``), and no learner that stays needs it
(docs/decision.md, "Learners that left"); :data:`RETIRED` says why, and naming it anywhere
gives that reason in one line.
"""

from corrections_sim.learning.base import LEARNERS

# The families' models of a correction on the exact reference's grid, registered on import.
from corrections_sim.learning.boltzmann import grid as _boltzmann_grid  # noqa: F401
from corrections_sim.learning.boltzmann.learners import BoltzmannPosterior
from corrections_sim.learning.exact import grid as _exact_grid  # noqa: F401
from corrections_sim.learning.exact.learners import (
    ExactCorrectionAware,
    ExactCorrectionAwareLearntNoise,
)
from corrections_sim.learning.kalman.active import (
    ActiveLearning,
    CorrectionAwareActive,
    CorrectionAwareActiveLearntNoise,
)
from corrections_sim.learning.kalman.attenuated import AttenuatedKalman
from corrections_sim.learning.kalman.learners import (
    CorrectionAwareKalman,
    CorrectionAwareKalmanLearntNoise,
    IteratedCorrectionAwareKalman,
    UnscentedKalman,
)
from corrections_sim.learning.particles.learners import ParticleActive, ParticleCorrectionAware
from corrections_sim.learning.perceptron.learners import (
    OneFeaturePerceptron,
    Perceptron,
    PerceptronFromCorrectionAware,
)
from corrections_sim.learning.relevance import grid as _relevance_grid  # noqa: F401
from corrections_sim.learning.relevance.asking import AskingPersonModel
from corrections_sim.learning.relevance.expansion import ExpandingRelevanceKalman
from corrections_sim.learning.relevance.learners import (
    PersonRelevanceKalman,
    RelevanceAwareKalman,
    RelevanceAwarePerceptron,
)

LEARNERS.register("PP", Perceptron)
LEARNERS.register("KF", UnscentedKalman)
LEARNERS.register("AL", ActiveLearning)
LEARNERS.register("PP-C", PerceptronFromCorrectionAware)
LEARNERS.register("KF-C", CorrectionAwareKalman)
LEARNERS.register("AL-C", CorrectionAwareActive)
LEARNERS.register("KF-A", AttenuatedKalman)
LEARNERS.register("BP", BoltzmannPosterior)
LEARNERS.register("KF-CL", CorrectionAwareKalmanLearntNoise)
LEARNERS.register("AL-CL", CorrectionAwareActiveLearntNoise)
LEARNERS.register("KF-CR", RelevanceAwareKalman)
LEARNERS.register("KF-CRP", PersonRelevanceKalman)
LEARNERS.register("KF-CRX", ExpandingRelevanceKalman)
LEARNERS.register("PP-R", RelevanceAwarePerceptron)
LEARNERS.register("PP-MAX", OneFeaturePerceptron)
LEARNERS.register("KF-CI", IteratedCorrectionAwareKalman)
LEARNERS.register("PF-C", ParticleCorrectionAware)
LEARNERS.register("AL-PF", ParticleActive)
LEARNERS.register("EX-C", ExactCorrectionAware)
LEARNERS.register("EX-CL", ExactCorrectionAwareLearntNoise)
LEARNERS.register("EX-M", AskingPersonModel)

#: Learners that left the registry, and why (what naming one says; docs/decision.md).
RETIRED = {
    "KF-CB": (
        "KF-C iterating every past correction at once measured no better than KF-C "
        "(issue 64; docs/exact-confidence.md); use KF-CI or EX-C"
    ),
    "EKF": (
        "the paper's EKF answered its question, whether the unscented transform matters: "
        "neither filter led on both figures, both far behind KF-C (issue 66; "
        "docs/decision.md#learners-that-left); use KF, or ekf_update in a plug-in"
    ),
}
for _name, _why in RETIRED.items():
    LEARNERS.retire(_name, _why)
