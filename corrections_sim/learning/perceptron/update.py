"""The Preference Perceptron, eq. (B5): the state-of-the-art learner the paper compares against.

    θ̂ᵗ⁺¹ = θ̂ᵗ + αᵗ [Φ(ξ_hᵗ, Eᵗ) − Φ(ξᵗ, Eᵗ)]

The perceptron keeps no uncertainty. So that every learner speaks in :class:`Belief` values,
it carries the covariance it was given unchanged: that P says nothing about the estimate.
"""

from __future__ import annotations

import math

import numpy as np

from corrections_sim.belief import Belief, _as_vector


def perceptron_update(
    belief: Belief, phi_robot: np.ndarray, phi_human: np.ndarray, alpha: float
) -> Belief:
    """One Preference Perceptron step, eq. (B5).

    Args:
        belief: current estimate; only ``theta`` (k,) is used, ``cov`` is carried unchanged.
        phi_robot: Φ(ξᵗ, Eᵗ), features of the robot's trajectory, shape (k,).
        phi_human: Φ(ξ_hᵗ, Eᵗ), features of the human's correction, shape (k,).
        alpha: learning rate αᵗ > 0, a scalar (see :func:`learning_rate_schedule`).

    Returns:
        New Belief with theta = θ̂ + α (Φ_h − Φ) and the same cov.

    Raises:
        ValueError: if a feature vector has the wrong shape or non-finite values, or alpha is
            not a finite number > 0.
    """
    k = belief.dim
    phi_robot = _as_vector("phi_robot", phi_robot, k)
    phi_human = _as_vector("phi_human", phi_human, k)
    alpha_value = _check_alpha(alpha)
    return Belief(theta=belief.theta + alpha_value * (phi_human - phi_robot), cov=belief.cov)


def learning_rate_schedule(gains: np.ndarray) -> np.ndarray:
    """The perceptron's αᵗ matched to the Kalman filter, as the paper's section 6 does.

    αᵗ = mean over runs r and features i of K_r^t[i, i], the Kalman gain of iteration t.

    Args:
        gains: Kalman gains of several KF runs, shape (runs, iters, k, k).

    Returns:
        αᵗ for every iteration, shape (iters,).

    Raises:
        ValueError: if gains is not (runs, iters, k, k) with square, non-empty blocks, or
            holds non-finite values.
    """
    gains = np.asarray(gains, dtype=float)
    if gains.ndim != 4 or gains.shape[2] != gains.shape[3] or 0 in gains.shape:
        raise ValueError(
            f"gains: expected a non-empty array of shape (runs, iters, k, k), got {gains.shape}"
        )
    if not np.all(np.isfinite(gains)):
        raise ValueError("gains: all values must be finite")
    return np.diagonal(gains, axis1=2, axis2=3).mean(axis=(0, 2))


def _check_alpha(alpha: float) -> float:
    arr = np.asarray(alpha)
    if arr.ndim != 0 or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"alpha: expected a scalar learning rate > 0, got {alpha!r}")
    value = float(arr)
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"alpha: learning rate must be finite and > 0, got {value}")
    return value
