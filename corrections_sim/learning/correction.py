"""One correction step, the same wherever a person corrects the robot: the study loop, a
browser session, a replayed log, the exact reference, the physical figure and the benchmarks.

:func:`context` is what a learner reads before and during a correction (to choose Eᵗ, to
update): the study's filter noise grown to the belief's dimension (a learner that learnt a
feature weighs more than the study's k). :func:`step` is the update itself: that context with
the person's corrected trajectory, and the learner's
:class:`~corrections_sim.learning.step.Step`; :func:`seen_features` the features it sees of
the correction (over its learnt features too).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from corrections_sim.belief import Belief, KalmanNoise
from corrections_sim.learning.base import Learner, LearnerContext
from corrections_sim.learning.step import Step
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import Plan
from corrections_sim.scene.environments import Environment


def context(belief: Belief, noise: KalmanNoise, **fields) -> LearnerContext:
    """The context of the next correction to ``belief``: the study's ``noise`` grown to the
    belief's dimension (its learnt features' observation noise the share its state holds),
    the other :class:`LearnerContext` fields as given."""
    return LearnerContext(noise=noise.grown(belief.dim, belief.state.learnt_share()), **fields)


def step(
    agent: Learner,
    ctx: LearnerContext,
    belief: Belief,
    env: Environment,
    plan: Plan,
    phi_h: np.ndarray,
    corrected: np.ndarray | None = None,
) -> Step:
    """The belief after one correction: ``agent``'s update of ``belief`` for the person's
    correction of ``plan`` in ``env`` with features ``phi_h`` (over ``ctx.features``) and,
    where they showed it, the corrected trajectory ``corrected`` (T, 7), which a
    relevance-aware learner judges; ``ctx`` is :func:`context`'s for ``belief``. May raise
    ``PlanningError`` (the update is then skipped)."""
    seen = ctx if corrected is None else replace(ctx, corrected=corrected)
    return agent.update(seen, belief, env, plan, phi_h)


def seen_features(
    belief: Belief, ctx: LearnerContext, env: Environment, corrected, phi_h: np.ndarray
) -> np.ndarray:
    """The features a learner sees of a correction: ``phi_h`` over the study's features, or
    Φ(ξ_h) over ``ctx.features`` once it learnt more (the person's ξ_h ``corrected``)."""
    if belief.extra:
        return feature_counts(corrected, env, ctx.features)
    return np.asarray(phi_h, dtype=float)
