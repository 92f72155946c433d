"""What a correction shows about θ, as a component a learner holds: the observation function
hₜ(θ) its filter, its particles and its exact reference all read.

Two models, one question (:meth:`Observation.observe`): given the plans ξ*(θ, E) of a run
(its :class:`~corrections_sim.plans.book.PlanBook`), the environment E and the robot's
trajectory ξᵗ the person corrected, h as a batch callable (n, k) -> (n, k):

* :class:`PlanFeatures`, the paper's filter: h(θ) = Φ(ξ*(θ, E), E), the person shows their
  own optimum (ξᵗ plays no part);
* :class:`CorrectedPlanFeatures`, KF-C's: hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E)), E), the correction a
  person with preference θ would make to ξᵗ under the correction model C.

Where plans come from is the book's business (memoized per run today), so a learner does not
say how ξ* is computed, only what it believes a correction is.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from corrections_sim.planning.features import feature_counts, waypoint_features
from corrections_sim.scene.environments import Environment

if TYPE_CHECKING:
    from corrections_sim.people.corrections import CorrectionModel
    from corrections_sim.plans.book import PlanBook


Observe = Callable[[np.ndarray], np.ndarray]
"""Batch observation model: thetas (n, k) -> features Φ(ξ*(θ, E), E) for each row, (n, k)."""


class Observation(abc.ABC):
    """hₜ(θ): what a correction in E to the robot's ξᵗ shows, as a function of θ."""

    #: Whether h depends on the robot's trajectory ξᵗ (a learner then plans ξ*(θ̂, E) to ask
    #: about a correction not yet made; one that does not plans nothing for it).
    needs_robot: bool = True

    @abc.abstractmethod
    def observe(
        self,
        book: PlanBook,
        env: Environment,
        robot: np.ndarray | None,
        names: Sequence[str],
    ) -> Observe:
        """h as a batch callable (n, k) -> (n, k) for a correction in ``env`` to ``robot``
        (T, 7) over the features ``names``; ``robot`` may be None when :attr:`needs_robot` is
        false."""

    def at_plans(
        self, plans: np.ndarray, robot: np.ndarray | None, env: Environment, names: Sequence[str]
    ) -> np.ndarray:
        """h at given plans instead of a book's: ``plans`` (n, T, 7) stand for ξ*(θ, E) at n
        values of θ (a grid's, an atlas's), NaN where there is none; returns (n, k), NaN
        there. The features of every trajectory in one call."""
        return features_at_plans(plans, robot, self.shown_many, env, names)

    def shown(self, robot: np.ndarray | None, plan: np.ndarray) -> np.ndarray:
        """The trajectory whose features h is, given the plan ξ*(θ, E) (the plan itself)."""
        return plan

    def shown_many(self, robot: np.ndarray | None, plans: np.ndarray) -> np.ndarray:
        """:meth:`shown` for many plans (n, T, 7) at once, the same bits."""
        return np.asarray(plans, float)

    def at_waypoints(
        self,
        plans: np.ndarray,
        features: np.ndarray,
        robot: np.ndarray | None,
        env: Environment,
        names: Sequence[str],
    ) -> np.ndarray:
        """h given the plans ``plans`` (n, T, 7) and their waypoints' features ``features``
        (n, T, k) (e.g. both read off a plan atlas): the sum of the waypoints' features
        where the shown trajectory's waypoints are the plan's or the robot's own (no
        kinematics), else :meth:`at_plans`'s. (n, k), NaN where a plan is NaN."""
        return features.sum(axis=1)


@dataclass(frozen=True)
class PlanFeatures(Observation):
    """h(θ) = Φ(ξ*(θ, E), E): a correction shows the person's own optimal trajectory (the
    paper's filter, KF)."""

    needs_robot = False

    def observe(self, book, env, robot, names) -> Observe:
        return book.observe(env)


@dataclass(frozen=True)
class CorrectedPlanFeatures(Observation):
    """hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E)), E) under the correction model C (KF-C): ξ*(θ, E) from the
    book, so the plans the paper's filter would solve are the only ones solved.

    Attributes:
        model: C, the correction a person with preference θ makes to ξᵗ.
    """

    model: CorrectionModel

    def shown(self, robot, plan) -> np.ndarray:
        if robot is None:
            raise ValueError("a correction model's observation needs the robot's trajectory")
        return self.model.apply(robot, plan)

    def shown_many(self, robot, plans) -> np.ndarray:
        if robot is None:
            raise ValueError("a correction model's observation needs the robot's trajectory")
        return self.model.apply_many(robot, plans)

    def at_waypoints(self, plans, features, robot, env, names) -> np.ndarray:
        if robot is None:
            raise ValueError("a correction model's observation needs the robot's trajectory")
        taken = self.model.taken(robot, plans)
        if taken is None:
            return self.at_plans(plans, robot, env, names)
        own = waypoint_features(robot, env.params(), tuple(names))  # (T, k)
        return np.where(taken[:, :, None], features, own[None]).sum(axis=1)

    def observe(self, book, env, robot, names) -> Observe:
        if robot is None:
            raise ValueError("a correction model's observation needs the robot's trajectory")
        params = env.params()
        model = self.model

        def h(thetas: np.ndarray) -> np.ndarray:
            return np.array(
                [
                    feature_counts(model.apply(robot, book.plan(t, env).trajectory), params, names)
                    for t in np.atleast_2d(thetas)
                ]
            )

        return h


def features_at_plans(plans: np.ndarray, robot, shown_many, env: Environment, names) -> np.ndarray:
    """Φ(shown) for each of ``plans`` (n, T, 7), (n, k), the shown trajectories
    ``shown_many(robot, plans)`` of every finite plan at once; NaN rows where a plan is NaN.

    A waypoint's features depend on that waypoint alone (the same bits in any batch, tested),
    so the waypoints a correction leaves where the robot had them take the robot's own,
    counted once: a one-waypoint correction costs the kinematics of one waypoint a plan, not
    of T."""
    plans = np.asarray(plans, float)
    n, T = plans.shape[:2]
    finite = np.all(np.isfinite(plans), axis=(1, 2))
    out = np.full((n, len(names)), np.nan)
    if finite.any():
        stacked = shown_many(robot, plans[finite])  # (m, T, 7)
        params = env.params()
        if robot is None:
            per_waypoint = waypoint_features(stacked.reshape(-1, 7), params, names)
            per_waypoint = per_waypoint.reshape(-1, T, len(names))
        else:
            robot = np.asarray(robot, float)
            same = np.all(stacked == robot[None], axis=2)  # (m, T): the robot's own waypoint
            # Laid out as waypoint_features lays out its answer (weight-major): the sum over
            # waypoints below then adds in the same order, so to the same bits, as before.
            per_waypoint = np.empty((len(names), len(stacked) * T)).T.reshape(-1, T, len(names))
            per_waypoint[same] = waypoint_features(robot, params, names)[np.nonzero(same)[1]]
            if not same.all():
                per_waypoint[~same] = waypoint_features(stacked[~same], params, names)
        out[finite] = per_waypoint.sum(axis=1)
    return out
