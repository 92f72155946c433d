"""The robot's belief over the human's preferences θ, and the Kalman filter's noise model.

Both are frozen values validated where they are made: a covariance that is not symmetric
positive definite, a NaN or a wrong shape is refused here, with the field named, instead of
surfacing as a failed Cholesky factorization several iterations later.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Relative tolerance on ‖C − Cᵀ‖_max / max(1, ‖C‖_max) accepted as "symmetric"; the
# asymmetry that is accepted is rounding, and it is removed on construction.
SYMMETRY_RTOL = 1e-8


def symmetrize(matrix: np.ndarray) -> np.ndarray:
    """Return (C + Cᵀ) / 2, the nearest symmetric matrix in the Frobenius norm.

    Args:
        matrix: square array, shape (k, k).

    Returns:
        A new symmetric array, shape (k, k).
    """
    matrix = np.asarray(matrix, dtype=float)
    return 0.5 * (matrix + matrix.T)


def _as_vector(name: str, value, k: int | None = None) -> np.ndarray:
    arr = np.array(value, dtype=float, copy=True)
    if arr.ndim != 1 or arr.shape[0] == 0:
        raise ValueError(f"{name}: expected a non-empty vector of shape (k,), got {arr.shape}")
    if k is not None and arr.shape[0] != k:
        raise ValueError(f"{name}: expected shape ({k},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: all values must be finite, got {arr.tolist()}")
    return arr


def _as_symmetric(name: str, value, k: int | None = None) -> np.ndarray:
    """Copy, check square / finite / symmetric within tolerance, and symmetrize exactly."""
    arr = np.array(value, dtype=float, copy=True)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or arr.shape[0] == 0:
        raise ValueError(f"{name}: expected a square matrix of shape (k, k), got {arr.shape}")
    if k is not None and arr.shape[0] != k:
        raise ValueError(f"{name}: expected shape ({k}, {k}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: all values must be finite, got {arr.tolist()}")
    scale = max(1.0, float(np.max(np.abs(arr))))
    asym = float(np.max(np.abs(arr - arr.T)))
    if asym > SYMMETRY_RTOL * scale:
        raise ValueError(
            f"{name}: must be symmetric (|C - C^T| <= {SYMMETRY_RTOL:g} * max(1, |C|)), "
            f"largest asymmetry is {asym:.3g}"
        )
    return symmetrize(arr)


def _check_positive_definite(name: str, matrix: np.ndarray) -> None:
    try:
        np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError:
        lowest = float(np.linalg.eigvalsh(matrix)[0])
        raise ValueError(
            f"{name}: must be positive definite (Cholesky failed; smallest eigenvalue "
            f"{lowest:.3g}, allowed > 0)"
        ) from None


def _check_positive_semidefinite(name: str, matrix: np.ndarray) -> None:
    eigenvalues = np.linalg.eigvalsh(matrix)
    # Eigenvalues of an exactly PSD matrix can come out at −(rounding) × its scale.
    tolerance = 1e-12 * max(1.0, float(np.max(np.abs(eigenvalues))))
    if eigenvalues[0] < -tolerance:
        raise ValueError(
            f"{name}: must be positive semidefinite (smallest eigenvalue "
            f"{eigenvalues[0]:.3g}, allowed >= 0)"
        )


def _freeze(arr: np.ndarray) -> np.ndarray:
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Belief:
    """Gaussian belief θ ~ N(θ̂, P) over the human's preference weights.

    The arrays are copied, symmetrized (cov) and made read-only, so a Belief can be shared
    between records without defensive copies.

    Attributes:
        theta: mean estimate θ̂, shape (k,).
        cov: covariance P, shape (k, k), symmetric positive definite. The Preference
            Perceptron has no covariance; it carries its initial one unchanged.
        noise: the belief over the person's observation noise N, for a learner that learns
            it (:class:`NoisePosterior`); None for one that assumes N.

    Raises:
        ValueError: on wrong shapes, non-finite values, or a cov that is not symmetric
            positive definite; the message names the field.
    """

    theta: np.ndarray
    cov: np.ndarray
    noise: NoisePosterior | None = None

    def __post_init__(self) -> None:
        theta = _as_vector("Belief.theta", self.theta)
        cov = _as_symmetric("Belief.cov", self.cov, theta.shape[0])
        _check_positive_definite("Belief.cov", cov)
        object.__setattr__(self, "theta", _freeze(theta))
        object.__setattr__(self, "cov", _freeze(cov))
        if self.noise is not None and self.noise.dim != theta.shape[0]:
            raise ValueError(
                f"Belief.noise: a posterior over {self.noise.dim} x {self.noise.dim} noise, "
                f"expected {theta.shape[0]} x {theta.shape[0]}"
            )

    @property
    def dim(self) -> int:
        """Number of features k."""
        return int(self.theta.shape[0])


@dataclass(frozen=True, eq=False)
class KalmanNoise:
    """Noise covariances of the filter's dynamical system, eqs. (K1)–(K2).

    θᵗ = θᵗ⁻¹ + m,  m ~ N(0, M)         (preferences are noisily constant)
    Φ_h = Φ(ξ*(θᵗ, E), E) + n,  n ~ N(0, N)

    Attributes:
        process: M, shape (k, k), symmetric positive semidefinite (zero is allowed: the
            preferences are then exactly constant).
        observation: N, shape (k, k), symmetric positive definite (it keeps the innovation
            covariance invertible).

    Raises:
        ValueError: on wrong or mismatched shapes, non-finite values, an M that is not PSD or
            an N that is not PD; the message names the field.
    """

    process: np.ndarray
    observation: np.ndarray

    def __post_init__(self) -> None:
        process = _as_symmetric("KalmanNoise.process", self.process)
        observation = _as_symmetric("KalmanNoise.observation", self.observation, process.shape[0])
        _check_positive_semidefinite("KalmanNoise.process", process)
        _check_positive_definite("KalmanNoise.observation", observation)
        object.__setattr__(self, "process", _freeze(process))
        object.__setattr__(self, "observation", _freeze(observation))

    @classmethod
    def isotropic(cls, k: int, process: float, observation: float) -> KalmanNoise:
        """M = process · I and N = observation · I, both (k, k)."""
        eye = np.eye(k)
        return cls(process=process * eye, observation=observation * eye)

    @property
    def dim(self) -> int:
        """Number of features k."""
        return int(self.process.shape[0])


@dataclass(frozen=True, eq=False)
class NoisePosterior:
    """A belief over the observation noise N: inverse-Wishart IW(ν, V), density
    ∝ |N|^(−(ν + k + 1)/2) exp(−tr(V N⁻¹)/2).

    Under it E[N⁻¹] = ν V⁻¹, so the noise a variational-Bayes filter plugs into its update
    is N̂ = E[N⁻¹]⁻¹ = V / ν (:meth:`estimate`).

    Attributes:
        dof: ν > k − 1, the degrees of freedom: how many corrections' worth of evidence.
        scale: V, shape (k, k), symmetric positive definite.
    """

    dof: float
    scale: np.ndarray

    def __post_init__(self) -> None:
        scale = _as_symmetric("NoisePosterior.scale", self.scale)
        _check_positive_definite("NoisePosterior.scale", scale)
        k = scale.shape[0]
        if not (np.isfinite(self.dof) and self.dof > k - 1):
            raise ValueError(f"NoisePosterior.dof: must be finite and > {k - 1}, got {self.dof}")
        object.__setattr__(self, "dof", float(self.dof))
        object.__setattr__(self, "scale", _freeze(scale))

    @classmethod
    def around(cls, noise: np.ndarray, dof: float) -> NoisePosterior:
        """A prior whose estimate is ``noise`` (k, k), held with ``dof`` degrees of freedom."""
        return cls(dof=dof, scale=dof * np.asarray(noise, dtype=float))

    @property
    def dim(self) -> int:
        return int(self.scale.shape[0])

    def estimate(self) -> np.ndarray:
        """N̂ = V / ν, shape (k, k)."""
        return self.scale / self.dof
