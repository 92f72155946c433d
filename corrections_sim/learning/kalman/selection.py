"""Active learning by greedy environment selection, eq. (A1).

    Eᵗ = argmin_{E ∈ 𝓔} ‖Pᵗ⁺¹(E)‖_F

Pᵗ⁺¹(E) is the covariance the filter would reach after a correction in E; it does not
depend on the correction itself (``ukf_predicted_covariance`` / ``ekf_predicted_covariance``),
so the robot can choose before the human acts.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def frobenius(cov: np.ndarray) -> float:
    """‖P‖_F = sqrt(Σ_ij P_ij²).

    Args:
        cov: square matrix, shape (k, k).

    Raises:
        ValueError: if cov is not a finite square matrix.
    """
    cov = np.asarray(cov, dtype=float)
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1]:
        raise ValueError(f"cov: expected a square matrix of shape (k, k), got {cov.shape}")
    if not np.all(np.isfinite(cov)):
        raise ValueError("cov: all values must be finite")
    return float(np.linalg.norm(cov, ord="fro"))


def select_environment(predicted_covs: Sequence[np.ndarray]) -> int:
    """Index of the environment whose predicted covariance has the smallest Frobenius norm.

    Ties (equal norms) go to the lowest index, so the choice is deterministic.

    Args:
        predicted_covs: Pᵗ⁺¹(E) for each candidate E, each shape (k, k), same k.

    Returns:
        The index into predicted_covs of Eᵗ.

    Raises:
        ValueError: if predicted_covs is empty, or holds non-square, mismatched or
            non-finite matrices.
    """
    if len(predicted_covs) == 0:
        raise ValueError("predicted_covs: expected at least one candidate covariance, got none")
    shapes = {np.shape(cov) for cov in predicted_covs}
    if len(shapes) != 1:
        raise ValueError(f"predicted_covs: all matrices must have one shape, got {sorted(shapes)}")
    norms = np.array([frobenius(cov) for cov in predicted_covs])
    # np.argmin returns the first minimum: the lowest index on ties.
    return int(np.argmin(norms))
