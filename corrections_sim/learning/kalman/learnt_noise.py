"""The UKF that learns the observation noise N with θ (KF-CL, AL-CL): variational Bayes over an
inverse-Wishart posterior on N carried in the belief (:func:`vb_ukf_update`). Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief, KalmanNoise, _as_vector, frozen, symmetrize
from corrections_sim.learning.kalman.filter import (
    SigmaPoints,
    UkfStep,
    check_iterations,
    correct_moments,
    sigma_moments,
    ukf_step,
)
from corrections_sim.learning.kalman.state import NoisePosterior, NoiseState
from corrections_sim.learning.observation import Observe


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
    the sigma-point filter (Särkkä & Hartikainen 2013), N ~ IW(ν, V) (``belief.state``).

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
        belief: prior belief N(θ̂ᵗ, Pᵗ) with ``belief.state`` the posterior over N so far.
        observe: as in :func:`ukf_update`.
        phi_human: as in :func:`ukf_update`.
        sigma: as in :func:`ukf_update`.
        reference: as in :func:`ukf_update`.
        noise: the process noise M (``noise.process``).
        iterations: fixed-point iterations (≥ 1).

    Returns:
        The posterior (its ``belief.state`` updated) and the intermediate quantities.

    Raises:
        ValueError: a belief without a noise posterior, or as :func:`ukf_update`.
    """
    if not isinstance(belief.state, NoiseState):
        raise ValueError("belief.state: a noise-learning update needs a posterior over N")
    prior = belief.state.noise
    check_iterations(iterations)
    phi_human = _as_vector("phi_human", phi_human, belief.dim)
    moments = sigma_moments(belief, observe, noise, sigma or SigmaPoints())
    base = moments.obs_mean if reference is None else _as_vector("reference", reference, belief.dim)
    innovation = phi_human - base
    dof = prior.dof + 1.0
    scale = prior.scale
    estimate = scale / dof
    change = np.inf
    for _ in range(iterations):
        stats = correct_moments(moments, estimate)
        share = np.linalg.solve(stats.innovation_cov, estimate).T  # N̂ S⁻¹
        noise_mean = share @ innovation  # E[n | Φ_h]
        noise_cov = estimate - share @ estimate  # Cov[n | Φ_h]
        scale = symmetrize(prior.scale + noise_cov + np.outer(noise_mean, noise_mean))
        new_estimate = scale / dof
        change = float(np.max(np.abs(new_estimate - estimate)))
        estimate = new_estimate
    stats = correct_moments(moments, estimate)
    posterior = NoisePosterior(dof=dof, scale=scale)
    return ukf_step(
        VbUkfStep,
        belief,
        stats,
        innovation,
        state=NoiseState(posterior),
        noise_estimate=frozen(posterior.estimate()),
        fixed_point_change=change,
    )
