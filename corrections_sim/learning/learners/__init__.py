"""The built-in learners, one module per family, registered here in the order figures and
tables list them (a plug-in's learner registers itself with
:func:`~corrections_sim.learning.base.register_learner`).

* :mod:`.perceptron`: PP, PP-C, PP-MAX; :mod:`.kalman`: KF, EKF, KF-C, KF-CL, KF-CI, KF-CB;
  :mod:`.active`: AL, AL-C, AL-CL; :mod:`.attenuated`: KF-A; :mod:`.boltzmann`: BP;
  :mod:`.relevance`: KF-CR, KF-CRP, PP-R; :mod:`.expansion`: KF-CRX; :mod:`.particles`: PF-C,
  AL-PF; :mod:`.exact`: EX-C, EX-CL (on the study's plan atlas).

Each is a frozen dataclass whose fields are its own parameters (``[learners.KF-A]
attenuation_min = 0.1`` in a study file); the filters' shared M, N and sigma points come from
the study through :class:`~corrections_sim.learning.base.LearnerContext`.
"""

from corrections_sim.learning.base import LEARNERS
from corrections_sim.learning.learners.active import (
    ActiveLearning,
    CorrectionAwareActive,
    CorrectionAwareActiveLearntNoise,
)
from corrections_sim.learning.learners.attenuated import AttenuatedKalman
from corrections_sim.learning.learners.boltzmann import BoltzmannPosterior
from corrections_sim.learning.learners.exact import (
    ExactCorrectionAware,
    ExactCorrectionAwareLearntNoise,
)
from corrections_sim.learning.learners.expansion import ExpandingRelevanceKalman
from corrections_sim.learning.learners.kalman import (
    BatchCorrectionAwareKalman,
    CorrectionAwareKalman,
    CorrectionAwareKalmanLearntNoise,
    ExtendedKalman,
    IteratedCorrectionAwareKalman,
    UnscentedKalman,
)
from corrections_sim.learning.learners.particles import ParticleActive, ParticleCorrectionAware
from corrections_sim.learning.learners.perceptron import (
    OneFeaturePerceptron,
    Perceptron,
    PerceptronFromCorrectionAware,
)
from corrections_sim.learning.learners.relevance import (
    PersonRelevanceKalman,
    RelevanceAwareKalman,
    RelevanceAwarePerceptron,
)

LEARNERS.register("PP", Perceptron)
LEARNERS.register("KF", UnscentedKalman)
LEARNERS.register("EKF", ExtendedKalman)
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
LEARNERS.register("KF-CB", BatchCorrectionAwareKalman)
LEARNERS.register("PF-C", ParticleCorrectionAware)
LEARNERS.register("AL-PF", ParticleActive)
LEARNERS.register("EX-C", ExactCorrectionAware)
LEARNERS.register("EX-CL", ExactCorrectionAwareLearntNoise)
