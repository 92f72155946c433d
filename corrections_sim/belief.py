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


def floored(cov: np.ndarray) -> np.ndarray:
    """A weighted sample's covariance kept positive definite, as a filter's posterior is:
    symmetrized, its eigenvalues at least 1e-9 of the largest (a sample whose mass sits on
    one point or one line has none there)."""
    cov = symmetrize(cov)
    eigenvalues, vectors = np.linalg.eigh(cov)
    floor = 1e-9 * max(float(eigenvalues[-1]), 1e-12)
    if eigenvalues[0] < floor:
        cov = symmetrize((vectors * np.maximum(eigenvalues, floor)) @ vectors.T)
    return cov


def frozen(arr: np.ndarray) -> np.ndarray:
    arr.setflags(write=False)
    return arr


class FamilyState:
    """A learner family's own part of a belief: what a family keeps beyond θ̂ and P (a
    particle cloud, a grid posterior, a belief over the person, a posterior over N, the past
    it reads again). Each family defines its state as a frozen dataclass subclass in its own
    folder (``learning/<family>/state.py``); nothing outside the family reads its fields.

    What every consumer may ask of any state is here, with the answers of a family that
    keeps nothing."""

    @classmethod
    def of(cls, belief: Belief):
        """This family's state in ``belief``, or a fresh one (its fields' defaults) for a
        belief the family did not make (the study's prior)."""
        return belief.state if isinstance(belief.state, cls) else cls()

    def check(self, k: int) -> None:
        """Raise ``ValueError``, naming the field, if it does not fit a belief over ``k``
        weights."""

    def columns(self) -> dict[str, float]:
        """The columns it adds to a study's record (after θ̂ and P): none here."""
        return {}

    def noise_estimate(self) -> np.ndarray | None:
        """The observation noise N̂ (k, k) it holds, for a learner that learns N; else None."""
        return None

    def learnt_share(self) -> float:
        """The share of the study's observation noise its learnt features' values are given
        (:meth:`KalmanNoise.grown`): 1 here, what a learner that fits it chose otherwise."""
        return 1.0

    def describe(self) -> str:
        """A sentence for a page about what it has learnt beyond θ̂ and P ("" for nothing)."""
        return ""


#: The state of a belief whose family keeps nothing beyond θ̂ and P.
NO_STATE = FamilyState()


@dataclass(frozen=True, eq=False)
class Belief:
    """Gaussian belief θ ~ N(θ̂, P) over the human's preference weights.

    The arrays are copied, symmetrized (cov) and made read-only, so a Belief can be shared
    between records without defensive copies.

    Attributes:
        theta: mean estimate θ̂, shape (k,).
        cov: covariance P, shape (k, k), symmetric positive definite. The Preference
            Perceptron has no covariance; it carries its initial one unchanged.
        extra: the names of features the learner learnt beyond the study's (feature
            expansion: θ̂ and P then have ``len(extra)`` more entries, after the study's).
        state: its family's own state (:class:`FamilyState`; :data:`NO_STATE` for a family
            that keeps nothing beyond θ̂ and P).

    Raises:
        ValueError: on wrong shapes, non-finite values, or a cov that is not symmetric
            positive definite; the message names the field.
    """

    theta: np.ndarray
    cov: np.ndarray
    extra: tuple[str, ...] = ()
    state: FamilyState = NO_STATE

    def __post_init__(self) -> None:
        object.__setattr__(self, "extra", tuple(self.extra))
        theta = _as_vector("Belief.theta", self.theta)
        if len(self.extra) >= theta.shape[0]:
            raise ValueError(
                f"Belief.extra: {len(self.extra)} learnt features of {theta.shape[0]} weights"
            )
        cov = _as_symmetric("Belief.cov", self.cov, theta.shape[0])
        _check_positive_definite("Belief.cov", cov)
        object.__setattr__(self, "theta", frozen(theta))
        object.__setattr__(self, "cov", frozen(cov))
        if not isinstance(self.state, FamilyState):
            raise ValueError(f"Belief.state: expected a FamilyState, got {type(self.state)}")
        self.state.check(theta.shape[0])

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
        object.__setattr__(self, "process", frozen(process))
        object.__setattr__(self, "observation", frozen(observation))

    @classmethod
    def isotropic(cls, k: int, process: float, observation: float) -> KalmanNoise:
        """M = process · I and N = observation · I, both (k, k)."""
        eye = np.eye(k)
        return cls(process=process * eye, observation=observation * eye)

    @property
    def dim(self) -> int:
        """Number of features k."""
        return int(self.process.shape[0])

    def grown(self, dim: int, share: float = 1.0) -> KalmanNoise:
        """The noise over ``dim`` >= k features: a learnt feature's share (past the k) its
        mean diagonal entry, uncorrelated (the studies' M and N are m·I and n·I); its
        observation noise that entry times ``share`` (> 0; a learnt feature's values are in
        units of their own, so how much a correction moves them may be fitted: KF-CRX)."""
        k = self.dim
        if dim == k:
            return self
        if not (np.isfinite(share) and share > 0):
            raise ValueError(f"KalmanNoise.grown: share = {share!r} must be finite and > 0")

        def grow(a: np.ndarray, scale: float) -> np.ndarray:
            out = np.eye(dim) * (float(np.mean(np.diag(a))) * scale)
            out[:k, :k] = a
            return out

        return KalmanNoise(
            process=grow(self.process, 1.0), observation=grow(self.observation, float(share))
        )
