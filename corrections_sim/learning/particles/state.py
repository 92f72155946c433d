"""The particle family's part of a belief: its weighted sample of θ and the corrections it
reads again (:class:`ParticleState`). Plain values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import FamilyState, floored, frozen
from corrections_sim.learning.history import HistoryEntry, checked


@dataclass(frozen=True, eq=False)
class Particles:
    """A weighted sample of θ: the particle learner's belief, whose mean and covariance are
    the belief's θ̂ and P.

    Attributes:
        thetas: the particles, shape (n, k).
        log_weights: their normalized log weights (n,) (Σ exp = 1).
        log_likelihood: each particle's log-likelihood of every correction so far (n,), up
            to one constant (what a Metropolis move compares against).
    """

    thetas: np.ndarray
    log_weights: np.ndarray
    log_likelihood: np.ndarray

    def __post_init__(self) -> None:
        thetas = np.array(self.thetas, dtype=float, copy=True)
        if thetas.ndim != 2 or thetas.shape[0] < 2 or not np.all(np.isfinite(thetas)):
            raise ValueError(f"Particles.thetas: expected finite (n >= 2, k), got {thetas.shape}")
        n = thetas.shape[0]
        log_w = np.array(self.log_weights, dtype=float, copy=True)
        log_l = np.array(self.log_likelihood, dtype=float, copy=True)
        for name, arr in (("log_weights", log_w), ("log_likelihood", log_l)):
            if arr.shape != (n,) or np.any(np.isnan(arr)):
                raise ValueError(f"Particles.{name}: expected ({n},) without NaN, got {arr.shape}")
        top = float(np.max(log_w))
        if not np.isfinite(top):
            raise ValueError("Particles.log_weights: every particle has weight zero")
        log_w = log_w - (top + np.log(np.exp(log_w - top).sum()))
        object.__setattr__(self, "thetas", frozen(thetas))
        object.__setattr__(self, "log_weights", frozen(log_w))
        object.__setattr__(self, "log_likelihood", frozen(log_l))

    @property
    def count(self) -> int:
        return int(self.thetas.shape[0])

    def weights(self) -> np.ndarray:
        return np.exp(self.log_weights)

    def effective_size(self) -> float:
        """Kish's effective sample size 1 / Σ w²."""
        return float(1.0 / np.sum(self.weights() ** 2))

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """The weighted mean (k,) and covariance (k, k), the covariance kept positive
        definite (eigenvalues at least 1e-9 of the largest, as a filter's posterior)."""
        w = self.weights()
        mean = w @ self.thetas
        d = self.thetas - mean
        return mean, floored((w[:, None] * d).T @ d)


@dataclass(frozen=True, eq=False)
class ParticleState(FamilyState):
    """PF-C's and AL-PF's own state: the cloud (None before the first correction: it is drawn
    from the prior then) and the prior with every correction, read again at each move."""

    particles: Particles | None = None
    history: tuple[HistoryEntry, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "history", checked(self.history, "ParticleState.history"))

    def check(self, k: int) -> None:
        if self.particles is not None and self.particles.thetas.shape[1] != k:
            raise ValueError(
                f"ParticleState.particles: particles over {self.particles.thetas.shape[1]} "
                f"weights, expected {k}"
            )
