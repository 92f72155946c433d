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
:func:`_repair_covariance`: symmetrize, and if an eigenvalue lies below
``COV_FLOOR_RTOL`` × λ_max(P⁻), clip the eigenvalues to that floor. The floor caps the
condition number of P at 1/COV_FLOOR_RTOL, so the next step's Cholesky always succeeds.
The innovation covariance S is guarded the same way before it is inverted (see
:func:`_repair_innovation_covariance`). Steps report whether a repair happened.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import (
    Belief,
    KalmanNoise,
    NoisePosterior,
    _as_vector,
    symmetrize,
)
from corrections_sim.learning.step import Step

Observe = Callable[[np.ndarray], np.ndarray]
"""Batch observation model: thetas (n, k) -> features Φ(ξ*(θ, E), E) for each row, (n, k)."""

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
class _UkfStatistics:
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
    return _ukf_step(UkfStep, belief, stats, innovation)


def _ukf_step(cls, prior: Belief, stats: _UkfStatistics, innovation: np.ndarray, **more):
    """The step ``cls`` (a :class:`UkfStep`) of a correction; ``more``: the posterior belief's
    ``noise`` and the subclass's own fields."""
    noise = more.pop("noise", None)
    return cls(
        belief=Belief(theta=prior.theta + stats.gain @ innovation, cov=stats.cov, noise=noise),
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


@dataclass(frozen=True, eq=False, kw_only=True)
class VbUkfStep(UkfStep):
    """Result of one UKF correction that learns the observation noise too.

    Attributes:
        noise_estimate: N̂ = V/ν of the posterior over N after this correction, (k, k).
        fixed_point_change: max |ΔN̂| of the last fixed-point iteration (convergence).
    """

    noise_estimate: np.ndarray
    fixed_point_change: float


def vb_ukf_update(
    belief: Belief,
    observe: Observe,
    phi_human: np.ndarray,
    noise: KalmanNoise,
    sigma: SigmaPoints | None = None,
    *,
    reference: np.ndarray | None = None,
    iterations: int = 10,
) -> VbUkfStep:
    """One UKF step that learns the observation noise N jointly with θ: variational Bayes in
    the sigma-point filter (Särkkä & Hartikainen 2013), N ~ IW(ν, V) (``belief.noise``).

    The 2k + 1 observations h(χ) are made once, as in :func:`ukf_update`; the fixed point
    iterates only on them (no extra h), with N̂ = V⁽ʲ⁾/ν⁺, ν⁺ = ν + 1:

        S = P_zz + N̂;  K = P_θz S⁻¹;  θ̂⁺ = θ̂ + K ν_z;  P⁺ = P⁻ − K S Kᵀ
        V⁽ʲ⁺¹⁾ = V + E[n nᵀ | Φ_h] = V + N̂ − N̂ S⁻¹ N̂ + (N̂ S⁻¹ ν_z)(N̂ S⁻¹ ν_z)ᵀ

    where ν_z is the innovation (against ``reference`` when given, as in the paper's update).
    The sigma points linearize h statistically, Φ_h = H θ + b + e + n with e ~ N(0, Ω) the part
    of h's spread that is not linear in θ (Ω = P_zz − H P⁻ Hᵀ, inside S): E[n nᵀ | Φ_h] is
    the person's noise n's share of the innovation, so a nonlinear h is not mistaken for a
    noisy person. On a linear h (Ω = 0) it is E[(Φ_h − Hθ)(Φ_h − Hθ)ᵀ] under the posterior of
    θ, the exact VB step. With ν → ∞ this is :func:`ukf_update` with N = V/ν. The process
    noise M comes from ``noise``; its observation noise is not used.

    Args:
        belief: prior belief N(θ̂ᵗ, Pᵗ) with ``belief.noise`` the posterior over N so far.
        observe: as in :func:`ukf_update`.
        phi_human: as in :func:`ukf_update`.
        sigma: as in :func:`ukf_update`.
        reference: as in :func:`ukf_update`.
        noise: the process noise M (``noise.process``).
        iterations: fixed-point iterations (≥ 1).

    Returns:
        The posterior (its ``belief.noise`` updated) and the intermediate quantities.

    Raises:
        ValueError: a belief without a noise posterior, or as :func:`ukf_update`.
    """
    if belief.noise is None:
        raise ValueError("belief.noise: a noise-learning update needs a posterior over N")
    _check_iterations(iterations)
    phi_human = _as_vector("phi_human", phi_human, belief.dim)
    moments = _sigma_moments(belief, observe, noise, sigma or SigmaPoints())
    base = moments.obs_mean if reference is None else _as_vector("reference", reference, belief.dim)
    innovation = phi_human - base
    dof = belief.noise.dof + 1.0
    scale = belief.noise.scale
    estimate = scale / dof
    change = np.inf
    for _ in range(iterations):
        stats = _correct(moments, estimate)
        share = np.linalg.solve(stats.innovation_cov, estimate).T  # N̂ S⁻¹
        noise_mean = share @ innovation  # E[n | Φ_h]
        noise_cov = estimate - share @ estimate  # Cov[n | Φ_h]
        scale = symmetrize(belief.noise.scale + noise_cov + np.outer(noise_mean, noise_mean))
        new_estimate = scale / dof
        change = float(np.max(np.abs(new_estimate - estimate)))
        estimate = new_estimate
    stats = _correct(moments, estimate)
    posterior = NoisePosterior(dof=dof, scale=scale)
    return _ukf_step(
        VbUkfStep,
        belief,
        stats,
        innovation,
        noise=posterior,
        noise_estimate=_frozen(posterior.estimate()),
        fixed_point_change=change,
    )


@dataclass(frozen=True, eq=False)
class Linearisation:
    """Statistical linear regression of h with respect to N(m, P) (from its sigma points):
    h(θ) ≈ A θ + b + e, e ~ N(0, Ω), the linear model closest to h where N(m, P) puts θ.

    Attributes:
        matrix: A = Ψᵀ P⁻¹, Ψ = Σ W_ci (χ_i − m)(h(χ_i) − ȳ)ᵀ, shape (k, k).
        offset: b = ȳ − A m, ȳ = Σ W_mi h(χ_i), shape (k,).
        residual: Ω = Σ W_ci (h(χ_i) − ȳ)(h(χ_i) − ȳ)ᵀ − A P Aᵀ, the part of h's spread that
            is not linear in θ (positive semidefinite), shape (k, k).
    """

    matrix: np.ndarray
    offset: np.ndarray
    residual: np.ndarray


def linearise(belief: Belief, observe: Observe, sigma: SigmaPoints | None = None) -> Linearisation:
    """The statistical linearisation of ``observe`` w.r.t. N(θ̂, P) (one batch of 2k + 1 h).

    The UKF is this linearisation w.r.t. the prior followed by a Kalman step; the iterated
    filters below linearise again w.r.t. the posterior (García-Fernández et al. 2015)."""
    sigma = sigma or SigmaPoints()
    k = belief.dim
    points = sigma.points(belief.theta, belief.cov)
    obs = _observe_batch(observe, points, k)
    wm, wc = sigma.weights(k)
    mean = wm @ obs
    dz = obs - mean
    cross = (wc[:, None] * (points - belief.theta)).T @ dz
    spread = (wc[:, None] * dz).T @ dz
    matrix = np.linalg.solve(belief.cov, cross).T
    residual = symmetrize(spread - matrix @ belief.cov @ matrix.T)
    eigenvalues, vectors = np.linalg.eigh(residual)  # PSD in exact arithmetic (Schur)
    residual = symmetrize((vectors * np.maximum(eigenvalues, 0.0)) @ vectors.T)
    return Linearisation(_frozen(matrix), _frozen(mean - matrix @ belief.theta), _frozen(residual))


def linear_posterior(
    prior: Belief,
    linearisations: list[Linearisation],
    observations: list[np.ndarray],
    noises: list[np.ndarray],
) -> Belief:
    """The exact posterior of θ ~ N(θ̂⁰, P⁰) given zᵢ = Aᵢ θ + bᵢ + eᵢ + nᵢ, eᵢ ~ N(0, Ωᵢ),
    nᵢ ~ N(0, Nᵢ), all independent (information form: P⁻¹ = P⁰⁻¹ + Σ Aᵢᵀ Rᵢ⁻¹ Aᵢ,
    Rᵢ = Nᵢ + Ωᵢ)."""
    info = np.linalg.inv(prior.cov)
    vector = info @ prior.theta
    for lin, z, noise in zip(linearisations, observations, noises, strict=True):
        weighted = np.linalg.solve(symmetrize(noise + lin.residual), lin.matrix)  # R⁻¹ A
        info = info + lin.matrix.T @ weighted
        vector = vector + weighted.T @ (np.asarray(z, float) - lin.offset)
    cov = symmetrize(np.linalg.inv(symmetrize(info)))
    return Belief(theta=cov @ vector, cov=cov)


def gaussian_kl(p: Belief, q: Belief) -> float:
    """KL(N(θ̂_p, P_p) ‖ N(θ̂_q, P_q)) in nats, closed form."""
    k = p.dim
    inv = np.linalg.inv(q.cov)
    d = q.theta - p.theta
    _, logdet_q = np.linalg.slogdet(q.cov)
    _, logdet_p = np.linalg.slogdet(p.cov)
    return float(0.5 * (np.trace(inv @ p.cov) + d @ inv @ d - k + logdet_q - logdet_p))


@dataclass(frozen=True, eq=False, kw_only=True)
class IteratedStep(UkfStep):
    """Result of an iterated (posterior-linearised) correction. The prediction fields
    (``predicted_obs``, ``sigma_points``, ``sigma_obs``, ``innovation``, ``innovation_cov``)
    are the first pass's, the UKF's own (what the filter expected before the correction);
    ``belief`` and ``gain`` are the last pass's.

    Attributes:
        passes: linearisations made (1: the UKF step alone).
        change: KL(last ‖ the one before) in nats, 0 after one pass.
    """

    passes: int
    change: float


def iterated_update(
    belief: Belief,
    observe: Observe,
    phi_human: np.ndarray,
    noise: KalmanNoise,
    sigma: SigmaPoints | None = None,
    *,
    reference: np.ndarray | None = None,
    iterations: int = 3,
    tolerance: float = 0.01,
) -> IteratedStep:
    """The iterated posterior linearisation filter's step (IPLF; García-Fernández, Svensson,
    Morelande & Särkkä, IEEE TSP 2015): the UKF step of :func:`ukf_update` first, then
    again and again h linearised statistically w.r.t. the posterior just found
    (:func:`linearise`) and the prior N(θ̂, P + M) updated exactly under that linear model
    (:func:`linear_posterior`), until the posterior moves by less than ``tolerance`` nats
    (KL) or after ``iterations`` linearisations. Each pass after the first solves 2k + 1
    plans; with ``iterations = 1`` this is :func:`ukf_update`.

    A broad prior's sigma points straddle planner outcomes the unscented transform averages
    badly; the posterior's are where θ is, so the linear model is accurate where it
    matters."""
    _check_iterations(iterations)
    sigma = sigma or SigmaPoints()
    z = _as_vector("phi_human", phi_human, belief.dim)
    first = ukf_update(belief, observe, z, noise, sigma, reference=reference)
    predicted = Belief(theta=belief.theta, cov=symmetrize(belief.cov + noise.process))
    current, change, passes = first.belief, 0.0, 1
    gain = first.gain
    while passes < iterations:
        lin = linearise(current, observe, sigma)
        after = linear_posterior(predicted, [lin], [z], [noise.observation])
        change, current, passes = gaussian_kl(after, current), after, passes + 1
        residual = symmetrize(lin.matrix @ predicted.cov @ lin.matrix.T + lin.residual)
        gain = np.linalg.solve(residual + noise.observation, lin.matrix @ predicted.cov).T
        if change < tolerance:
            break
    cov, _ = _repair_covariance(np.array(current.cov), predicted.cov)
    return IteratedStep(
        belief=Belief(theta=current.theta, cov=cov),
        gain=_frozen(np.array(gain)),
        innovation=first.innovation,
        predicted_obs=first.predicted_obs,
        sigma_points=first.sigma_points,
        sigma_obs=first.sigma_obs,
        innovation_cov=first.innovation_cov,
        repaired=first.repaired,
        passes=passes,
        change=change,
    )


def batch_update(
    prior: Belief,
    observers: list[Observe],
    observations: list[np.ndarray],
    noises: list[np.ndarray],
    start: Belief,
    sigma: SigmaPoints | None = None,
    *,
    iterations: int = 3,
    tolerance: float = 0.01,
) -> tuple[Belief, int, float]:
    """Iterated posterior linearisation over *all* corrections (θ is static: each past
    correction is evidence, and it is read again around what is now believed): every hᵢ
    linearised w.r.t. the current posterior (starting at ``start``), the prior updated
    exactly under all those linear models at once, until the posterior moves by less than
    ``tolerance`` nats or after ``iterations`` passes. Returns (posterior, passes, last
    change). A pass solves 2k + 1 plans per correction (fewer where they are memoized)."""
    _check_iterations(iterations)
    sigma = sigma or SigmaPoints()
    current, change, passes = start, 0.0, 0
    while passes < iterations:
        lins = [linearise(current, observe, sigma) for observe in observers]
        after = linear_posterior(prior, lins, observations, noises)
        change, current, passes = gaussian_kl(after, current), after, passes + 1
        if change < tolerance:
            break
    return current, passes, change


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
    obs = _observe_batch(observe, np.vstack([theta + offsets, theta - offsets]), k)
    return (obs[:k] - obs[k:]).T / (2.0 * steps)


@dataclass(frozen=True, eq=False)
class _SigmaMoments:
    """What the sigma points say before any noise N is added (one batch of h)."""

    prior_cov: np.ndarray  # P⁻ = P + M, (k, k)
    points: np.ndarray  # χ, (2k+1, k)
    obs: np.ndarray  # h(χ), (2k+1, k)
    obs_mean: np.ndarray  # ẑ, (k,)
    obs_cov: np.ndarray  # P_zz without N, (k, k)
    cross_cov: np.ndarray  # P_θz, (k, k)


def _sigma_moments(
    belief: Belief, observe: Observe, noise: KalmanNoise, sigma: SigmaPoints
) -> _SigmaMoments:
    k = belief.dim
    _check_noise(noise, k)
    prior_cov = symmetrize(belief.cov + noise.process)
    points = sigma.points(belief.theta, prior_cov)
    obs = _observe_batch(observe, points, k)
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
    return _SigmaMoments(prior_cov, points, obs, obs_mean, obs_cov, cross_cov)


def _correct(moments: _SigmaMoments, observation: np.ndarray) -> _UkfStatistics:
    """The UKF correction of ``moments`` with observation noise N = ``observation``."""
    m = moments
    innovation_cov, s_repaired = _repair_innovation_covariance(m.obs_cov + observation, observation)
    gain = np.linalg.solve(innovation_cov, m.cross_cov.T).T
    cov, p_repaired = _repair_covariance(m.prior_cov - gain @ innovation_cov @ gain.T, m.prior_cov)
    return _UkfStatistics(
        points=_frozen(m.points),
        obs=_frozen(m.obs),
        obs_mean=_frozen(m.obs_mean),
        gain=_frozen(gain),
        cov=_frozen(cov),
        innovation_cov=_frozen(innovation_cov),
        repaired=s_repaired or p_repaired,
    )


def _ukf_statistics(
    belief: Belief, observe: Observe, noise: KalmanNoise, sigma: SigmaPoints
) -> _UkfStatistics:
    return _correct(_sigma_moments(belief, observe, noise, sigma), noise.observation)


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
    cov, p_repaired = _repair_covariance(joseph, prior_cov)
    return _EkfStatistics(
        gain=_frozen(gain),
        cov=_frozen(cov),
        innovation_cov=_frozen(innovation_cov),
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


def _repair_covariance(cov: np.ndarray, prior_cov: np.ndarray) -> tuple[np.ndarray, bool]:
    """Symmetrize, and clip eigenvalues below COV_FLOOR_RTOL · λ_max(prior) up to it."""
    cov = symmetrize(cov)
    floor = COV_FLOOR_RTOL * float(np.linalg.eigvalsh(prior_cov)[-1])
    eigenvalues, vectors = np.linalg.eigh(cov)
    if eigenvalues[0] >= floor:
        return cov, False
    return symmetrize((vectors * np.maximum(eigenvalues, floor)) @ vectors.T), True


def _observe_batch(observe: Observe, thetas: np.ndarray, k: int) -> np.ndarray:
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


def _check_iterations(iterations) -> None:
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
        raise ValueError(f"iterations = {iterations!r}: expected an integer >= 1")


def _check_noise(noise: KalmanNoise, k: int) -> None:
    if noise.dim != k:
        raise ValueError(f"noise: expected {k}x{k} covariances for k={k}, got {noise.dim}")


def _frozen(arr: np.ndarray) -> np.ndarray:
    arr.setflags(write=False)
    return arr
