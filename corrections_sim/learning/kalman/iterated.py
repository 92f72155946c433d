"""Iterated posterior linearisation (KF-CI): the UKF's statistical linearisation of h(θ)
redone around the posterior it gives (:func:`iterated_update`), one correction at a time; and
the Gaussian KL between two beliefs. Pure numpy, no planner: h comes in as a function
(:class:`~corrections_sim.learning.observation.Observe`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief, KalmanNoise, _as_vector, frozen, symmetrize
from corrections_sim.learning.kalman.filter import (
    SigmaPoints,
    UkfStep,
    check_iterations,
    observe_batch,
    repair_covariance,
    ukf_update,
)
from corrections_sim.learning.observation import Observe


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
    obs = observe_batch(observe, points, k)
    wm, wc = sigma.weights(k)
    mean = wm @ obs
    dz = obs - mean
    cross = (wc[:, None] * (points - belief.theta)).T @ dz
    spread = (wc[:, None] * dz).T @ dz
    matrix = np.linalg.solve(belief.cov, cross).T
    residual = symmetrize(spread - matrix @ belief.cov @ matrix.T)
    eigenvalues, vectors = np.linalg.eigh(residual)  # PSD in exact arithmetic (Schur)
    residual = symmetrize((vectors * np.maximum(eigenvalues, 0.0)) @ vectors.T)
    return Linearisation(frozen(matrix), frozen(mean - matrix @ belief.theta), frozen(residual))


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
    check_iterations(iterations)
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
    cov, _ = repair_covariance(np.array(current.cov), predicted.cov)
    return IteratedStep(
        belief=Belief(theta=current.theta, cov=cov),
        gain=frozen(np.array(gain)),
        innovation=first.innovation,
        predicted_obs=first.predicted_obs,
        sigma_points=first.sigma_points,
        sigma_obs=first.sigma_obs,
        innovation_cov=first.innovation_cov,
        repaired=first.repaired,
        passes=passes,
        change=change,
    )
