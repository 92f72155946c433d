"""KF-CRX: KF-CRP that, when corrections keep going unexplained, asks its person for feature
traces and learns the feature it lacks (FERL, :mod:`corrections_sim.learnt.training`); and what
a study measures of it: which feature its person lacks (:func:`missing_feature`), the learnt
feature against that one (:func:`quality_of`) and its record's columns (:func:`columns`).
"""

from __future__ import annotations

from dataclasses import dataclass

from corrections_sim.learning.relevance.learners import PersonRelevanceKalman
from corrections_sim.learning.relevance.state import RelevanceState
from corrections_sim.learning.step import Step
from corrections_sim.learnt.training import quality
from corrections_sim.scene.environments import Environment


@dataclass(frozen=True)
class ExpandingRelevanceKalman(PersonRelevanceKalman):
    """KF-CRP that learns the feature it lacks (FERL): when the person's corrections are
    believed mostly unexplained, it asks for 10 feature traces, learns a feature from them
    and learns its weight from the corrections that follow (see
    :meth:`PersonRelevanceKalman.expand`)."""

    label = "KF-CRP with feature expansion (KF-CRX)"
    style = ("#17becf", "-")

    expand_traces: int = 10


def missing_feature(target, current: tuple[str, ...]) -> str | None:
    """The feature the person minds most (largest |θ*|) that ``current`` lacks, or None."""
    theirs = target.features or current
    weights = {n: abs(float(w)) for n, w in zip(theirs, target.theta_star, strict=True)}
    lacking = [n for n in theirs if n not in current and weights[n] > 0]
    return max(lacking, key=lambda n: weights[n]) if lacking else None


def quality_of(name: str, target, current: tuple[str, ...], env: Environment) -> dict:
    """A learnt feature against the person's feature it was taught for: Spearman ρ and the
    affine fit true ≈ a·learnt + b over random reachable configurations of the environment
    it was taught in; the person's weight maps to a·θ* on the learnt feature."""
    true = missing_feature(target, current)
    if true is None:
        return {}
    q = quality(name, true, env)
    weight = float(target.theta_star[list(target.features or current).index(true)])
    return {"spearman": q.spearman, "r2": q.r2, "target": weight * q.scale}


def columns(belief, step: Step | None, learnt: dict, k: int) -> dict:
    """Columns of a learner that can learn features: whether it asked, whether it has
    expanded (and at which correction), the learnt feature's quality against the person's
    (Spearman ρ, R² of the best affine fit), its weight θ̂ and the weight the person's maps
    to through that fit (θ*·a), for every record after it expanded."""
    asked = isinstance(belief.state, RelevanceState) and belief.state.asked
    if not (asked or (step is not None and step.expansion is not None)):
        return {}
    out: dict = {"asked": float(asked), "expanded": float(bool(belief.extra))}
    if belief.extra and learnt:
        out |= {
            "expanded_at": learnt["expanded_at"],
            "learnt_spearman": learnt.get("spearman"),
            "learnt_r2": learnt.get("r2"),
            "learnt_weight": float(belief.theta[k]),
            "learnt_weight_target": learnt.get("target"),
        }
    return out
