"""Kalman filters over the human's preferences θ, section 4 of the paper.

The dynamical system, eqs. (K1)–(K2):

    θᵗ = θᵗ⁻¹ + m,              m ~ N(0, M)
    Φ_hᵗ = h(θᵗ) + n,            n ~ N(0, N),    h(θ) = Φ(ξ*(θ, Eᵗ), Eᵗ)

h runs a trajectory optimization, so it is never called here directly: the caller passes a
batch callable ``observe(thetas) -> features``, shape (n, k) -> (n, k), that solves the n
problems together (and may cache them). Everything in this module is plain numpy.

Two filters:

* UKF (what the paper's simulations use; Wan & van der Merwe 2000): h is evaluated at
  2k + 1 sigma points of the prior N(θ̂, P + M). :func:`ukf_update`.
* EKF (what the paper writes down, eqs. (K4)–(K7)): the caller supplies the Jacobian
  H = ∂h/∂θ at θ̂ (e.g. :func:`finite_difference_jacobian`). :func:`ekf_update`.

Both also give the posterior covariance *before* the human corrects
(:func:`ukf_predicted_covariance`, :func:`ekf_predicted_covariance`): it does not depend on
Φ_h, which is what active learning, eq. (A1), needs. Prediction and update share one
function per filter, so the predicted covariance is exactly the one the update produces.

Keeping P symmetric positive definite: the EKF uses the Joseph form, PSD by construction
for any gain. The UKF has no Joseph form (there is no H), so it uses P⁺ = P⁻ − K S Kᵀ; that
difference can lose definiteness to cancellation when N ≪ H P Hᵀ, or when β < α² makes
the sigma-point covariance of h indefinite. Every posterior therefore passes
:func:`repair_covariance`: symmetrize, and if an eigenvalue lies below
``COV_FLOOR_RTOL`` × λ_max(P⁻), clip the eigenvalues to that floor. The floor caps the
condition number of P at 1/COV_FLOOR_RTOL, so the next step's Cholesky always succeeds.
The innovation covariance S is guarded the same way before it is inverted (see
:func:`_repair_innovation_covariance`). Steps report whether a repair happened.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import (
    NO_STATE,
    Belief,
    KalmanNoise,
    _as_vector,
    frozen,
    symmetrize,
)
from corrections_sim.learning.observation import Observe
from corrections_sim.learning.step import Step

COV_FLOOR_RTOL = 1e-9
"""Smallest eigenvalue allowed in a posterior covariance, relative to λ_max of its prior."""

S_FLOOR_RTOL = 1e-12
"""Smallest eigenvalue allowed in an innovation covariance S, relative to its λ_max."""


@dataclass(frozen=True)
class SigmaPoints:
    """Scaled unscented transform parameters (Wan & van der Merwe 2000).

    With λ = α² (k + κ) − k, the 2k + 1 points are θ̂ and θ̂ ± (√((k+λ) P⁻))_i, where the
    square root is the lower Cholesky factor and P⁻ = P + M. Weights:

        W_m0 = λ / (k + λ),   W_c0 = W_m0 + 1 − α² + β,   W_mi = W_ci = 1 / (2 (k + λ)).

    Defaults α = 1, β = 2, κ = 0 (so λ = 0): the points sit at ±√k standard deviations,
    i.e. h is sampled across the range of θ the robot actually believes plausible. That is
    the point of a UKF here: the features of an optimal trajectory are flat in some regions
    (laptop far from the path) and saturate in others, and a spread-out sample sees that
    where a local derivative does not. It also keeps every mean weight ≥ 0 (W_m0 = 0), so
    the solver's own tolerance noise in h is averaged, not amplified: the textbook α = 1e-3
    gives W_m0 ≈ −10⁶ and points 10⁻³ σ apart, i.e. a finite difference at the scale of
    IPOPT's tolerance. β = 2 is optimal for a Gaussian prior. Small α remains available
    and is handled exactly (negative W_m0, W_c0).

    Attributes:
        alpha: spread α > 0.
        beta: prior-knowledge term β ≥ 0 (2 for Gaussians).
        kappa: secondary scaling κ; k + κ must be > 0.
    """

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0

    def __post_init__(self) -> None:
        for name in ("alpha", "beta", "kappa"):
            value = getattr(self, name)
            if not isinstance(value, int | float | np.number) or not math.isfinite(value):
                raise ValueError(f"SigmaPoints.{name}: expected a finite number, got {value!r}")
        if self.alpha <= 0.0:
            raise ValueError(f"SigmaPoints.alpha: must be > 0, got {self.alpha}")
        if self.beta < 0.0:
            raise ValueError(f"SigmaPoints.beta: must be >= 0, got {self.beta}")

    def spread(self, k: int) -> float:
        """k + λ = α² (k + κ), the factor that scales P⁻ before its square root.

        Raises:
            ValueError: if k + κ ≤ 0 (the points would be imaginary).
        """
        if k + self.kappa <= 0.0:
            raise ValueError(
                f"SigmaPoints.kappa: k + kappa must be > 0, got k={k}, kappa={self.kappa}"
            )
        return self.alpha**2 * (k + self.kappa)

    def weights(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Mean and covariance weights (W_m, W_c), each shape (2k + 1,); Σ W_m = 1."""
        c = self.spread(k)
        lam = c - k
        wm = np.full(2 * k + 1, 0.5 / c)
        wc = wm.copy()
        wm[0] = lam / c
        wc[0] = lam / c + 1.0 - self.alpha**2 + self.beta
        return wm, wc

    def points(self, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """Sigma points of N(mean, cov), shape (2k + 1, k).

        Row 0 is the mean; rows 1..k add and rows k+1..2k subtract the columns of the lower
        Cholesky factor of (k + λ) cov.

        Args:
            mean: shape (k,).
            cov: symmetric positive definite, shape (k, k).
        """
        k = mean.shape[0]
        root = np.linalg.cholesky(self.spread(k) * cov)
        return np.vstack([mean, mean + root.T, mean - root.T])


@dataclass(frozen=True, eq=False, kw_only=True)
class UkfStep(Step):
    """Result of one UKF correction.

    Attributes:
        belief: posterior N(θ̂ᵗ⁺¹, Pᵗ⁺¹).
        gain: Kalman gain K = P_θz S⁻¹, shape (k, k).
        innovation: Φ_h − ẑ, shape (k,).
        predicted_obs: ẑ = Σ W_mi h(χ_i), shape (k,).
        sigma_points: χ, the θ at which h was evaluated, shape (2k + 1, k).
        sigma_obs: h(χ), shape (2k + 1, k). Row 0 is h(θ̂) = Φ(ξᵗ), the features of the
            robot's own trajectory, so that solve can be reused.
        innovation_cov: S = P_zz + N, the covariance the filter predicted for the innovation
            (after any repair), shape (k, k); νᵀS⁻¹ν is the normalized innovation squared.
        repaired: True if S or P⁺ had to be repaired to stay positive definite.
    """

    predicted_obs: np.ndarray
    sigma_points: np.ndarray
    sigma_obs: np.ndarray


@dataclass(frozen=True, eq=False)
class EkfStep(Step):
    """Result of one EKF correction, eqs. (K5)–(K7).

    Attributes:
        belief: posterior N(θ̂ᵗ⁺¹, Pᵗ⁺¹).
        gain: Kalman gain K, eq. (K6), shape (k, k).
        innovation: Φ_h − Φ(ξᵗ), shape (k,).
        innovation_cov: S = H P⁻ Hᵀ + N (after any repair), shape (k, k).
        repaired: True if S or P⁺ had to be repaired to stay positive definite.
    """


@dataclass(frozen=True, eq=False)
class UkfStatistics:
    """Everything of a UKF correction that does not depend on Φ_h."""

    points: np.ndarray  # (2k+1, k)
    obs: np.ndarray  # (2k+1, k)
    obs_mean: np.ndarray  # (k,)
    gain: np.ndarray  # (k, k)
    cov: np.ndarray  # (k, k)
    innovation_cov: np.ndarray  # (k, k)
    repaired: bool


@dataclass(frozen=True, eq=False)
class _EkfStatistics:
    """Everything of an EKF correction that does not depend on Φ_h."""

    gain: np.ndarray  # (k, k)
    cov: np.ndarray  # (k, k)
    innovation_cov: np.ndarray  # (k, k)
    repaired: bool


def ukf_update(
    belief: Belief,
    observe: Observe,
    phi_human: np.ndarray,
    noise: KalmanNoise,
    sigma: SigmaPoints | None = None,
    *,
    reference: np.ndarray | None = None,
) -> UkfStep:
    """One unscented Kalman filter step: predict with (K1), correct with Φ_h.

    P⁻ = P + M;  χ = sigma points of N(θ̂, P⁻);  z_i = h(χ_i);  ẑ = Σ W_mi z_i
    S = Σ W_ci (z_i − ẑ)(z_i − ẑ)ᵀ + N;   P_θz = Σ W_ci (χ_i − θ̂)(z_i − ẑ)ᵀ
    K = P_θz S⁻¹;   θ̂⁺ = θ̂ + K (Φ_h − ẑ);   P⁺ = P⁻ − K S Kᵀ  (repaired to stay SPD)

    Args:
        belief: prior belief N(θ̂ᵗ, Pᵗ), k features.
        observe: batch h, (n, k) -> (n, k); called once with the 2k + 1 sigma points.
        phi_human: Φ(ξ_hᵗ, Eᵗ), features of the human's correction, shape (k,).
        noise: process M and observation N covariances, (k, k) each.
        sigma: sigma-point parameters; the defaults of :class:`SigmaPoints` if None.
        reference: if given, the innovation is Φ_h − reference instead of Φ_h − ẑ. With
            reference = Φ(ξᵗ) = h(θ̂) this is the paper's update (K5): a correction is an
            *improvement* of the robot's trajectory, so it says how Φ should move from
            Φ(ξᵗ); the sigma-point mean ẑ differs from h(θ̂) wherever h is nonlinear, and
            that difference is not information from the human.

    Returns:
        The posterior and the intermediate quantities, see :class:`UkfStep`.

    Raises:
        ValueError: on mismatched dimensions, non-finite phi_human, or an observe that
            returns the wrong shape or non-finite values.
    """
    phi_human = _as_vector("phi_human", phi_human, belief.dim)
    stats = _ukf_statistics(belief, observe, noise, sigma or SigmaPoints())
    base = stats.obs_mean if reference is None else _as_vector("reference", reference, belief.dim)
    innovation = phi_human - base
    return ukf_step(UkfStep, belief, stats, innovation)


def ukf_step(cls, prior: Belief, stats: UkfStatistics, innovation: np.ndarray, **more):
    """The step ``cls`` (a :class:`UkfStep`) of a correction; ``more``: the posterior belief's
    ``state`` and the subclass's own fields."""
    state = more.pop("state", NO_STATE)
    return cls(
        belief=Belief(theta=prior.theta + stats.gain @ innovation, cov=stats.cov, state=state),
        gain=stats.gain,
        innovation=innovation,
        predicted_obs=stats.obs_mean,
        sigma_points=stats.points,
        sigma_obs=stats.obs,
        innovation_cov=stats.innovation_cov,
        repaired=stats.repaired,
        **more,
    )


def ukf_predicted_covariance(
    belief: Belief,
    observe: Observe,
    noise: KalmanNoise,
    sigma: SigmaPoints | None = None,
) -> np.ndarray:
    """Pᵗ⁺¹ the UKF would reach in this environment, before the human corrects.

    The UKF counterpart of eq. (A1)'s (I − K H)(P + M): it does not depend on Φ_h and is
    exactly ``ukf_update(...).belief.cov`` for any Φ_h.

    Args:
        belief: prior belief, k features.
        observe: batch h of the candidate environment, (n, k) -> (n, k).
        noise: process M and observation N covariances.
        sigma: sigma-point parameters; the defaults if None.

    Returns:
        Posterior covariance, shape (k, k), symmetric positive definite.
    """
    return _ukf_statistics(belief, observe, noise, sigma or SigmaPoints()).cov.copy()


def ekf_update(
    belief: Belief,
    jacobian: np.ndarray,
    phi_robot: np.ndarray,
    phi_human: np.ndarray,
    noise: KalmanNoise,
) -> EkfStep:
    """One extended Kalman filter step, eqs. (K5)–(K7).

    P⁻ = P + M;   S = H P⁻ Hᵀ + N;   K = P⁻ Hᵀ S⁻¹                          (K6)
    θ̂⁺ = θ̂ + K [Φ_h − Φ(ξᵗ)]                                              (K5)
    P⁺ = (I − K H) P⁻ (I − K H)ᵀ + K N Kᵀ                                   (K7, Joseph)

    The Joseph form equals (K7)'s (I − K H) P⁻ for this K and stays PSD for any K.

    Args:
        belief: prior belief N(θ̂ᵗ, Pᵗ), k features.
        jacobian: H = ∂Φ(ξ*(θ, E), E)/∂θ at θ̂ᵗ, eq. (K4), shape (k, k) (row: feature,
            column: preference weight).
        phi_robot: Φ(ξᵗ, Eᵗ) = h(θ̂ᵗ), features of the robot's trajectory, shape (k,).
        phi_human: Φ(ξ_hᵗ, Eᵗ), features of the human's correction, shape (k,).
        noise: process M and observation N covariances.

    Returns:
        The posterior, the gain and the innovation, see :class:`EkfStep`.

    Raises:
        ValueError: on mismatched dimensions or non-finite inputs; the field is named.
    """
    k = belief.dim
    phi_robot = _as_vector("phi_robot", phi_robot, k)
    phi_human = _as_vector("phi_human", phi_human, k)
    stats = _ekf_statistics(belief, jacobian, noise)
    innovation = phi_human - phi_robot
    return EkfStep(
        belief=Belief(theta=belief.theta + stats.gain @ innovation, cov=stats.cov),
        gain=stats.gain,
        innovation=innovation,
        innovation_cov=stats.innovation_cov,
        repaired=stats.repaired,
    )


def ekf_predicted_covariance(
    belief: Belief, jacobian: np.ndarray, noise: KalmanNoise
) -> np.ndarray:
    """Pᵗ⁺¹ = (I − K H)(P + M) of eq. (A1), before the human corrects.

    Exactly ``ekf_update(...).belief.cov`` for any Φ, Φ_h.

    Args:
        belief: prior belief, k features.
        jacobian: H of the candidate environment at θ̂, shape (k, k).
        noise: process M and observation N covariances.

    Returns:
        Posterior covariance, shape (k, k), symmetric positive definite.
    """
    return _ekf_statistics(belief, jacobian, noise).cov.copy()


def finite_difference_jacobian(
    observe: Observe, theta: np.ndarray, step: float | np.ndarray
) -> np.ndarray:
    """Central-difference Jacobian of h at θ, in one batched call of 2k evaluations.

    H[:, i] = (h(θ + δ_i e_i) − h(θ − δ_i e_i)) / (2 δ_i)

    Args:
        observe: batch h, (n, k) -> (n, k); called once with n = 2k.
        theta: point of linearization, shape (k,).
        step: δ > 0, a scalar or one per weight, shape (k,). With a trajectory optimizer
            in h, δ must be well above the solver's tolerance.

    Returns:
        H, shape (k, k): row j is feature j, column i is weight θ_i.

    Raises:
        ValueError: on a non-finite theta, a step that is not > 0, or a bad observe output.
    """
    theta = _as_vector("theta", theta)
    k = theta.shape[0]
    steps = np.array(step, dtype=float, copy=True)
    if steps.ndim == 0:
        steps = np.full(k, float(steps))
    if steps.shape != (k,):
        raise ValueError(f"step: expected a scalar or shape ({k},), got {steps.shape}")
    if not np.all(np.isfinite(steps)) or np.any(steps <= 0.0):
        raise ValueError(f"step: must be finite and > 0, got {np.asarray(step).tolist()}")
    offsets = np.diag(steps)
    obs = observe_batch(observe, np.vstack([theta + offsets, theta - offsets]), k)
    return (obs[:k] - obs[k:]).T / (2.0 * steps)


@dataclass(frozen=True, eq=False)
class SigmaMoments:
    """What the sigma points say before any noise N is added (one batch of h)."""

    prior_cov: np.ndarray  # P⁻ = P + M, (k, k)
    points: np.ndarray  # χ, (2k+1, k)
    obs: np.ndarray  # h(χ), (2k+1, k)
    obs_mean: np.ndarray  # ẑ, (k,)
    obs_cov: np.ndarray  # P_zz without N, (k, k)
    cross_cov: np.ndarray  # P_θz, (k, k)


def sigma_moments(
    belief: Belief, observe: Observe, noise: KalmanNoise, sigma: SigmaPoints
) -> SigmaMoments:
    k = belief.dim
    _check_noise(noise, k)
    prior_cov = symmetrize(belief.cov + noise.process)
    points = sigma.points(belief.theta, prior_cov)
    obs = observe_batch(observe, points, k)
    wm, wc = sigma.weights(k)
    obs_mean = wm @ obs
    dz = obs - obs_mean
    dtheta = points - belief.theta
    with np.errstate(over="ignore", invalid="ignore"):
        obs_cov = (wc[:, None] * dz).T @ dz
        cross_cov = (wc[:, None] * dtheta).T @ dz
    if not (np.all(np.isfinite(obs_cov)) and np.all(np.isfinite(cross_cov))):
        raise ValueError(
            "observe: features at the sigma points are too far apart to form a covariance "
            f"(overflow); largest |feature| {float(np.max(np.abs(obs))):.3g}"
        )
    return SigmaMoments(prior_cov, points, obs, obs_mean, obs_cov, cross_cov)


def correct_moments(moments: SigmaMoments, observation: np.ndarray) -> UkfStatistics:
    """The UKF correction of ``moments`` with observation noise N = ``observation``."""
    m = moments
    innovation_cov, s_repaired = _repair_innovation_covariance(m.obs_cov + observation, observation)
    gain = np.linalg.solve(innovation_cov, m.cross_cov.T).T
    cov, p_repaired = repair_covariance(m.prior_cov - gain @ innovation_cov @ gain.T, m.prior_cov)
    return UkfStatistics(
        points=frozen(m.points),
        obs=frozen(m.obs),
        obs_mean=frozen(m.obs_mean),
        gain=frozen(gain),
        cov=frozen(cov),
        innovation_cov=frozen(innovation_cov),
        repaired=s_repaired or p_repaired,
    )


def _ukf_statistics(
    belief: Belief, observe: Observe, noise: KalmanNoise, sigma: SigmaPoints
) -> UkfStatistics:
    return correct_moments(sigma_moments(belief, observe, noise, sigma), noise.observation)


def _ekf_statistics(belief: Belief, jacobian: np.ndarray, noise: KalmanNoise) -> _EkfStatistics:
    k = belief.dim
    _check_noise(noise, k)
    h = np.array(jacobian, dtype=float, copy=True)
    if h.shape != (k, k):
        raise ValueError(f"jacobian: expected shape ({k}, {k}), got {h.shape}")
    if not np.all(np.isfinite(h)):
        raise ValueError("jacobian: all values must be finite")
    prior_cov = symmetrize(belief.cov + noise.process)
    innovation_cov, s_repaired = _repair_innovation_covariance(
        h @ prior_cov @ h.T + noise.observation, noise.observation
    )
    gain = np.linalg.solve(innovation_cov, h @ prior_cov).T
    i_kh = np.eye(k) - gain @ h
    joseph = i_kh @ prior_cov @ i_kh.T + gain @ noise.observation @ gain.T
    cov, p_repaired = repair_covariance(joseph, prior_cov)
    return _EkfStatistics(
        gain=frozen(gain),
        cov=frozen(cov),
        innovation_cov=frozen(innovation_cov),
        repaired=s_repaired or p_repaired,
    )


def _repair_innovation_covariance(
    innovation_cov: np.ndarray, observation_cov: np.ndarray
) -> tuple[np.ndarray, bool]:
    """Keep S invertible: eigenvalues at least max(λ_min(N), S_FLOOR_RTOL · λ_max(S)).

    UKF: P_zz = Σ_{i≥1} W_i (z_i − z_0)(z_i − z_0)ᵀ + (β − α²)(z_0 − ẑ)(z_0 − ẑ)ᵀ is PSD
    whenever β ≥ α² (the defaults, and any α ≤ √2 with β = 2), negative W_m0 or not, so
    S = P_zz + N ≥ N. With β < α² it can be indefinite for a nonlinear h; S is then no more
    certain than N alone. Both filters: when H P Hᵀ dwarfs N, S is singular to working
    precision; its condition number is capped at 1 / S_FLOOR_RTOL, which only discards
    information finer than rounding. Raised eigenvalues replace a division by a near-zero or
    negative variance.
    """
    innovation_cov = symmetrize(innovation_cov)
    eigenvalues, vectors = np.linalg.eigh(innovation_cov)
    floor = max(
        float(np.linalg.eigvalsh(observation_cov)[0]), S_FLOOR_RTOL * float(eigenvalues[-1])
    )
    # The margin keeps rounding in a valid S (P_zz ≈ 0) from counting as a repair.
    if eigenvalues[0] >= floor * (1.0 - 1e-9):
        return innovation_cov, False
    return symmetrize((vectors * np.maximum(eigenvalues, floor)) @ vectors.T), True


def repair_covariance(cov: np.ndarray, prior_cov: np.ndarray) -> tuple[np.ndarray, bool]:
    """Symmetrize, and clip eigenvalues below COV_FLOOR_RTOL · λ_max(prior) up to it."""
    cov = symmetrize(cov)
    floor = COV_FLOOR_RTOL * float(np.linalg.eigvalsh(prior_cov)[-1])
    eigenvalues, vectors = np.linalg.eigh(cov)
    if eigenvalues[0] >= floor:
        return cov, False
    return symmetrize((vectors * np.maximum(eigenvalues, floor)) @ vectors.T), True


def observe_batch(observe: Observe, thetas: np.ndarray, k: int) -> np.ndarray:
    out = np.array(observe(thetas.copy()), dtype=float, copy=True)
    if out.shape != thetas.shape:
        raise ValueError(
            f"observe: must return features of shape {thetas.shape} for thetas of shape "
            f"{thetas.shape}, got {out.shape}"
        )
    if not np.all(np.isfinite(out)):
        bad = np.flatnonzero(~np.all(np.isfinite(out), axis=1)).tolist()
        raise ValueError(f"observe: returned non-finite features for rows {bad} (k={k})")
    return out


def check_iterations(iterations) -> None:
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
        raise ValueError(f"iterations = {iterations!r}: expected an integer >= 1")


def _check_noise(noise: KalmanNoise, k: int) -> None:
    if noise.dim != k:
        raise ValueError(f"noise: expected {k}x{k} covariances for k={k}, got {noise.dim}")
