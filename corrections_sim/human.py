"""Simulated users who know the true preference θ* and correct the robot.

* :class:`BiasedUser` — the paper's user (§6): looks at the robot's trajectory ξᵗ and its
  own intended trajectory ξ* = ξ*(θ*, E), picks the one waypoint with the largest joint-space
  error, and moves it a fraction ``step`` of the way toward the matching waypoint of ξ*.
  Its feature counts are a biased, partial improvement, which violates the Kalman filter's
  Gaussian observation model (K2) on purpose.
  With ``waypoints`` > 1 it moves that many of its worst waypoints.
* :class:`DeformingUser` — pushes its worst waypoint toward ξ* and the trajectory follows in
  a smooth minimum-jerk deformation (:func:`corrections_sim.corrections.deformation_correction`),
  as a person physically pushing the arm would.
* :class:`NoisyOptimalUser` — the Kalman filter's own assumption: Φ(ξ*) + n, n ~ N(0, σ²I).

All return Φ(ξ_h, E), the features of the correction, which is all the learners see. A user's
``stochastic`` says whether it draws from its generator (then every learner, active learning
included, runs as many times as the others).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.corrections import deformation_correction, waypoint_correction
from corrections_sim.features import feature_counts


class _EditingUser:
    """A user who edits the robot's trajectory deterministically (``corrected_trajectory``)."""

    stochastic = False

    def corrected_trajectory(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def correction_features(
        self,
        robot: np.ndarray,
        intended: np.ndarray,
        env_params: np.ndarray,
        names: tuple[str, ...],
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Φ(ξ_h, E), shape (k,). Deterministic; ``rng`` is unused."""
        return feature_counts(self.corrected_trajectory(robot, intended), env_params, names)


@dataclass(frozen=True)
class BiasedUser(_EditingUser):
    """Corrects its worst waypoint(s) toward its intended trajectory.

    Attributes:
        step: fraction in (0, 1] of the way the worst waypoint moves toward ξ*'s
            (default 1: the user puts that waypoint where they want it).
        waypoints: how many of the worst waypoints it moves (default 1, the paper's user).
    """

    step: float = 1.0
    waypoints: int = 1

    def __post_init__(self) -> None:
        if not (isinstance(self.step, int | float) and 0.0 < self.step <= 1.0):
            raise ValueError(f"user_step = {self.step} must lie in (0, 1]")
        if isinstance(self.waypoints, bool) or not isinstance(self.waypoints, int):
            raise ValueError(f"user_waypoints = {self.waypoints!r} must be an integer")
        if self.waypoints < 1:
            raise ValueError(f"user_waypoints = {self.waypoints} must be >= 1")

    def corrected_trajectory(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        """ξ_h (T, 7): ``robot`` (T, 7) with its worst waypoint(s) moved toward ``intended``."""
        robot = np.asarray(robot, float)
        if self.waypoints > robot.shape[0] - 2:
            raise ValueError(
                f"user_waypoints = {self.waypoints}: more than the {robot.shape[0] - 2} free "
                "waypoints"
            )
        return waypoint_correction(robot, intended, self.step, self.waypoints)


@dataclass(frozen=True)
class DeformingUser(_EditingUser):
    """Pushes its worst waypoint ``step`` of the way toward ξ*'s; the rest deforms smoothly.

    Attributes:
        step: fraction in (0, 1] of the way the worst waypoint moves.
    """

    step: float = 1.0

    def __post_init__(self) -> None:
        if not (isinstance(self.step, int | float) and 0.0 < self.step <= 1.0):
            raise ValueError(f"user_step = {self.step} must lie in (0, 1]")

    def corrected_trajectory(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        """ξ_h (T, 7), see :func:`corrections_sim.corrections.deformation_correction`."""
        return deformation_correction(robot, intended, self.step)


@dataclass(frozen=True)
class NoisyOptimalUser:
    """Shows its optimal trajectory's features with Gaussian noise of std ``noise`` per feature."""

    noise: float = 0.1
    stochastic = True

    def __post_init__(self) -> None:
        if not (np.isfinite(self.noise) and self.noise >= 0):
            raise ValueError(f"user noise = {self.noise} must be finite and >= 0")

    def correction_features(
        self,
        robot: np.ndarray,
        intended: np.ndarray,
        env_params: np.ndarray,
        names: tuple[str, ...],
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Φ(ξ*, E) + n, shape (k,)."""
        phi = feature_counts(intended, env_params, names)
        return phi + rng.normal(0.0, self.noise, size=phi.shape)
