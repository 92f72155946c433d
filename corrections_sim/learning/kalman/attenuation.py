"""A UKF that does not know how much of the intended change a person delivers.

The paper's filter (:func:`.kalman.ukf_update` with ``reference = Φ(ξᵗ)``) reads a correction
as showing the whole change Φ(ξ*(θ, E)) − Φ(ξᵗ); a person who delivers a fraction of it is
read as "θ̂ is nearly right", and P shrinks regardless (issue 9). Here the person delivers an
unknown fraction a of the intended feature change:

    Φ_h − Φ(ξᵗ) = a · (h(θ) − Φ(ξᵗ)) + n,   h(θ) = Φ(ξ*(θ, E), E),   n ~ N(0, N)
    a ~ log-uniform on [a_min, a_max], drawn afresh for each correction (n_a log-spaced values)

Nothing is assumed about *how* the person edits the trajectory (one waypoint, a deformation),
only that what they show points from the robot's features toward their intended ones.

Update (a Gaussian-sum filter collapsed after each step, "GPB1"): the sigma points χ of
N(θ̂, P⁻), P⁻ = P + M, and z_i = h(χ_i) are shared by every a_j, so a step costs the paper
UKF's 2k + 1 plans. Per a_j, with d_i = z_i − Φ(ξᵗ):

    ẑ_j = a_j Σ W_mi d_i,   S_j = a_j² Σ W_ci (d_i − d̄)(d_i − d̄)ᵀ + N
    C_j = a_j Σ W_ci (χ_i − θ̂)(d_i − d̄)ᵀ,   K_j = C_j S_j⁻¹
    ν_j = (Φ_h − Φ(ξᵗ)) − a_j d_0                (d_0 = h(θ̂) − Φ(ξᵗ) = 0 when ξᵗ = ξ*(θ̂))
    θ̂_j = θ̂ + K_j ν_j,   P_j = P⁻ − K_j S_j K_jᵀ,   w_j ∝ N(ν_j; 0, S_j)
    θ̂⁺ = Σ w_j θ̂_j,   P⁺ = Σ w_j (P_j + (θ̂_j − θ̂⁺)(θ̂_j − θ̂⁺)ᵀ)

As in the paper's update (K5), the innovation is taken from the prediction at θ̂ (d_0), not
from the sigma-point mean. With a single a = 1 this is exactly the paper's UKF
(``ukf_update(..., reference=phi_robot)``).

Measured at fig. 4's settings (θ* = (1, −1), θ̂⁰ = 0, P⁰ = I, 24 runs × 10 corrections, the
defaults below; in brackets the paper's UKF on the same draws): mean NEES after 10
corrections 1.36 [77] with the one-waypoint user, 3.23 [147] when it moves the waypoint half
way, 0.55 [1.85] with the noisy-optimal user (χ² 95% band for 24 runs: [1.28, 2.88]);
‖θ̂ − θ*‖₁ 0.74 [1.10], 1.05 [1.48], 0.22 [0.19]. It learns slowly from small corrections:
an honest P costs step size. What it cannot do: learn the fraction a across corrections
(a is drawn afresh each time), or give the posterior covariance before the correction (the
weights w_j depend on Φ_h), so it has no eq. (A1) predicted covariance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief, KalmanNoise, _as_vector, symmetrize
from corrections_sim.learning.kalman.filter import (
    SigmaPoints,
    _check_noise,
    _repair_innovation_covariance,
    observe_batch,
    repair_covariance,
)
from corrections_sim.learning.observation import Observe
from corrections_sim.learning.step import Step


@dataclass(frozen=True)
class Attenuation:
    """The prior on the delivered fraction a: log-uniform on [a_min, a_max], n_a points.

    Attributes:
        a_min: smallest fraction, in (0, a_max].
        a_max: largest fraction, ≥ a_min (1: never more than the intended change).
        n_a: number of log-spaced values, both ends included; 1 when a_min == a_max.

    Raises:
        ValueError: on a field outside its range; the message names the field.
    """

    a_min: float = 0.05
    a_max: float = 1.0
    n_a: int = 12

    def __post_init__(self) -> None:
        for name in ("a_min", "a_max"):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float | np.number)
                or not math.isfinite(value)
            ):
                raise ValueError(f"Attenuation.{name}: expected a finite number, got {value!r}")
        if self.a_min <= 0.0:
            raise ValueError(f"Attenuation.a_min: must be > 0, got {self.a_min}")
        if self.a_max < self.a_min:
            raise ValueError(
                f"Attenuation.a_max: must be >= a_min = {self.a_min}, got {self.a_max}"
            )
        n = self.n_a
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
            raise ValueError(f"Attenuation.n_a: must be an integer >= 1, got {n!r}")
        if self.a_max == self.a_min and n != 1:
            raise ValueError(f"Attenuation.n_a: must be 1 when a_min == a_max, got {n}")

    @property
    def values(self) -> np.ndarray:
        """a_j, shape (n_a,), log-spaced from a_min to a_max."""
        return np.geomspace(self.a_min, self.a_max, self.n_a)


@dataclass(frozen=True, eq=False, kw_only=True)
class AttenuatedStep(Step):
    """Result of one correction.

    Attributes:
        belief: the collapsed posterior N(θ̂⁺, P⁺).
        gain: Σ_j w_j K_j, shape (k, k); θ̂⁺ = θ̂ + gain · innovation when ξᵗ = ξ*(θ̂, E).
        innovation: Φ_h − Φ(ξᵗ), shape (k,).
        innovation_cov: covariance of Φ_h − Φ(ξᵗ) predicted before the correction, shape
            (k, k): the a-mixture Σ_j (S_j + (ẑ_j − z̄)(ẑ_j − z̄)ᵀ) / n_a, z̄ = mean of ẑ_j.
        weights: posterior weights w_j of the a_j, shape (n_a,).
        repaired: True if some S_j or P_j had to be repaired to stay positive definite.
    """

    weights: np.ndarray


def update(
    belief: Belief,
    observe: Observe,
    phi_robot: np.ndarray,
    phi_human: np.ndarray,
    noise: KalmanNoise,
    attenuation: Attenuation | None = None,
    sigma: SigmaPoints | None = None,
) -> AttenuatedStep:
    """One correction under the attenuated observation model (see module doc).

    Args:
        belief: prior N(θ̂ᵗ, Pᵗ), k features.
        observe: batch h, (n, k) -> (n, k); called once with the 2k + 1 sigma points.
        phi_robot: Φ(ξᵗ, Eᵗ), features of the robot's trajectory, shape (k,).
        phi_human: Φ(ξ_hᵗ, Eᵗ), features of the human's correction, shape (k,).
        noise: process M and observation N covariances, (k, k) each.
        attenuation: the prior on a; ``Attenuation()`` if None.
        sigma: sigma-point parameters; the defaults of :class:`SigmaPoints` if None.

    Returns:
        The posterior and its diagnostics, see :class:`AttenuatedStep`.

    Raises:
        ValueError: on mismatched shapes, non-finite features, or a bad observe output.
    """
    attenuation = attenuation or Attenuation()
    sigma = sigma or SigmaPoints()
    k = belief.dim
    _check_noise(noise, k)
    phi_robot = _as_vector("phi_robot", phi_robot, k)
    phi_human = _as_vector("phi_human", phi_human, k)
    prior_cov = symmetrize(belief.cov + noise.process)
    points = sigma.points(belief.theta, prior_cov)
    change = observe_batch(observe, points, k) - phi_robot  # d_i, (2k+1, k)
    wm, wc = sigma.weights(k)
    d_mean = wm @ change
    dd = change - d_mean
    dtheta = points - belief.theta
    cov_dd = (wc[:, None] * dd).T @ dd  # (k, k)
    cross = (wc[:, None] * dtheta).T @ dd  # (k, k)
    delta = phi_human - phi_robot

    log_w, means, covs, gains, s_all = [], [], [], [], []
    repaired = False
    for a in attenuation.values:
        s, s_rep = _repair_innovation_covariance(
            a * a * cov_dd + noise.observation, noise.observation
        )
        gain = np.linalg.solve(s, a * cross.T).T
        cov, p_rep = repair_covariance(prior_cov - gain @ s @ gain.T, prior_cov)
        nu = delta - a * change[0]
        log_w.append(-0.5 * nu @ np.linalg.solve(s, nu) - 0.5 * np.linalg.slogdet(s)[1])
        means.append(belief.theta + gain @ nu)
        covs.append(cov)
        gains.append(gain)
        s_all.append(s)
        repaired = repaired or s_rep or p_rep
    log_w = np.array(log_w)
    weights = np.exp(log_w - log_w.max())
    weights /= weights.sum()
    means_arr = np.array(means)
    mean = weights @ means_arr
    spread = means_arr - mean
    post_cov = (
        np.einsum("j,jab->ab", weights, np.array(covs)) + (weights[:, None] * spread).T @ spread
    )
    post_cov, p_rep = repair_covariance(post_cov, prior_cov)

    predicted = np.outer(attenuation.values, d_mean)  # ẑ_j, (n_a, k)
    pred_spread = predicted - predicted.mean(axis=0)
    innovation_cov = np.mean(np.array(s_all), axis=0) + pred_spread.T @ pred_spread / len(predicted)
    return AttenuatedStep(
        belief=Belief(theta=mean, cov=post_cov),
        gain=np.einsum("j,jab->ab", weights, np.array(gains)),
        innovation=delta,
        innovation_cov=symmetrize(innovation_cov),
        weights=weights,
        repaired=repaired or p_rep,
    )
