"""KF-CRX: KF-CRP that, when corrections keep going unexplained, asks its person for feature
traces and learns the feature it lacks (FERL, :mod:`corrections_sim.learnt.training`).
"""

from __future__ import annotations

from dataclasses import dataclass

from corrections_sim.learning.relevance.learners import PersonRelevanceKalman


@dataclass(frozen=True)
class ExpandingRelevanceKalman(PersonRelevanceKalman):
    """KF-CRP that learns the feature it lacks (FERL): when the person's corrections are
    believed mostly unexplained, it asks for 10 feature traces, learns a feature from them
    and learns its weight from the corrections that follow (see
    :meth:`PersonRelevanceKalman.expand`)."""

    label = "KF-CRP with feature expansion (KF-CRX)"
    style = ("#17becf", "-")

    expand_traces: int = 10
