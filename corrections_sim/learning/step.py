"""The one result every learner's update returns: :class:`Step`.

The maths of each family (:mod:`corrections_sim.learning.kalman.filter`,
:mod:`corrections_sim.learning.kalman.attenuation`,
:mod:`corrections_sim.learning.boltzmann.posterior`, ...) returns a ``Step``, or a subclass
that adds what only it computes (the UKF's sigma points, KF-A's weights over the fraction, BP's
evidence); a learner returns it to the study loop as it is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief


@dataclass(frozen=True, eq=False)
class Step:
    """One update: the new belief and what calibration needs of it.

    Attributes:
        belief: the belief after the correction.
        gain: the gain K (k, k) with θ̂⁺ = θ̂ + K · innovation, or None (a learner without
            one). The gains of ``rate_from`` learners' runs give PP-type learners their rate.
        innovation: Φ_h minus what the learner predicted (k,).
        innovation_cov: its predicted covariance S (k, k), or None (then no NIS).
        repaired: True if a covariance had to be repaired to stay positive definite.
        relevance: β̂, the learner's probability that the correction is explained by its
            features at all (a relevance-aware learner), else None.
        residual: ρ, the unexplained fraction of the correction β̂ was computed from, or None.
        expansion: what a learner that expands its features did after this correction:
            plain values (``asked``, ``taught``, ``feature``, ``traces``, ``loss``, ``seconds``),
            or None when it did not ask.
    """

    belief: Belief
    gain: np.ndarray | None
    innovation: np.ndarray
    innovation_cov: np.ndarray | None = None
    repaired: bool = False
    relevance: float | None = None
    residual: float | None = None
    expansion: dict | None = None
