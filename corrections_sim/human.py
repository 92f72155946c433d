"""Simulated users who know the true preference θ* and correct the robot.

* :class:`BiasedUser` — the paper's user (§6): looks at the robot's trajectory ξᵗ and its
  own intended trajectory ξ* = ξ*(θ*, E), picks the one waypoint with the largest joint-space
  error, and moves it a fraction ``step`` of the way toward the matching waypoint of ξ*.
  Its feature counts are a biased, partial improvement, which violates the Kalman filter's
  Gaussian observation model (K2) on purpose.
* :class:`NoisyOptimalUser` — the Kalman filter's own assumption: Φ(ξ*) + n, n ~ N(0, σ²I).

Both return Φ(ξ_h, E), the features of the correction, which is all the learners see.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.features import feature_counts


@dataclass(frozen=True)
class BiasedUser:
    """Corrects one waypoint, the worst one, toward its intended trajectory.

    Attributes:
        step: fraction in (0, 1] of the way the worst waypoint moves toward ξ*'s
            (default 1: the user puts that waypoint where they want it).
    """

    step: float = 1.0

    def __post_init__(self) -> None:
        if not 0.0 < self.step <= 1.0:
            raise ValueError(f"user_step = {self.step} must lie in (0, 1]")

    def corrected_trajectory(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        """ξ_h (T, 7): ``robot`` (T, 7) with its worst waypoint moved toward ``intended``."""
        robot = np.asarray(robot, float)
        errors = np.linalg.norm(np.asarray(intended, float) - robot, axis=1)
        worst = int(np.argmax(errors))
        out = robot.copy()
        out[worst] += self.step * (intended[worst] - robot[worst])
        return out

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
class NoisyOptimalUser:
    """Shows its optimal trajectory's features with Gaussian noise of std ``noise`` per feature."""

    noise: float = 0.1

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
