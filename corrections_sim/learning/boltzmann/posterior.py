"""A Gaussian posterior over θ under a Boltzmann (Bradley–Terry) model of corrections.

The Kalman filters of :mod:`.kalman` model a correction as *showing* Φ(ξ*(θ, E)), the features
of the human's optimal trajectory; a person who fixes only part of the trajectory shows a
fraction of that change, and the filter grows over-confident (issue 9). This learner assumes
only that a correction is a noisy *improvement* of the robot's trajectory ξᵗ under the
human's reward θ·Φ (the planner maximizes θ·Φ − λS):

    P(ξ_h ≻ ξᵗ | θ) = ℓ(θ·Δ),   Δ = Φ(ξ_h) − Φ(ξᵗ)                                  (k,)
    ℓ(s) = ε/2 + (1 − ε) · (1/n) Σ_j σ(β_j s),   σ(x) = 1 / (1 + e⁻ˣ)

The rationality β is not known: it is integrated out per correction under a log-uniform prior
on [β_min, β_max] (n log-spaced points), so a correction that is barely better, or a little
worse (ε, the lapse rate), is not read as decisive. Nothing here says *how* the person edits
the trajectory, and the update needs no planner solve.

The update is assumed-density filtering (moment matching): with the prior N(θ̂, P⁻), P⁻ = P + M,
the posterior p(θ) ∝ N(θ; θ̂, P⁻) ℓ(θ·Δ) depends on θ through s = θ·Δ only, and θ | s is
Gaussian, so its mean and covariance follow exactly from the 1-D tilted moments of s:

    m = θ̂·Δ,   v = Δᵀ P⁻ Δ,   Z = ∫ ℓ(s) N(s; m, v) ds
    μ = E[s],  τ² = Var[s]  under  ℓ(s) N(s; m, v) / Z
    θ̂⁺ = θ̂ + P⁻Δ (μ − m) / v                 (= θ̂ + K Δ with K = (μ − m)/v · P⁻)
    P⁺ = P⁻ − P⁻ΔΔᵀP⁻ (v − τ²) / v²

Only the Gaussian projection after each correction is approximate: at fig. 4's settings
(24 runs × 10 corrections) a 201 × 201 grid posterior under the same model ends at
‖θ̂ − θ*‖₁ = 0.20 / 0.34 (one-waypoint user, step 1 / 0.5) where this learner ends at
0.18 / 0.32. The 1-D integrals are computed on an adaptive grid (:func:`tilted_moments`).

What it cannot learn: ℓ depends on θ·Δ, and with β unknown only on the *direction* of θ;
how large θ is relative to the planner's smoothness weight comes from the prior alone.
Measured with P⁰ = I, θ̂⁰ = 0: for θ* = (1, −1) (a typical draw of that prior) the final
error is 0.18, for θ* = (2, −2) it stays at 2.1 (the paper's KF: 1.10 and 2.76). Learning
the scale needs a model of how much a person changes, which is what this learner avoids.

Units: β multiplies θ·Δ, so it is in inverse units of reward; the default range [0.3, 30]
spans two decades around the rewards of fig. 4's corrections (θ*·Δ ≈ 0.5–0.9 for the
one-waypoint user at θ̂ = 0).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief, _as_vector, symmetrize
from corrections_sim.learning.kalman.filter import COV_FLOOR_RTOL
from corrections_sim.learning.observation import Observe
from corrections_sim.learning.step import Step

LogLikelihood = Callable[[np.ndarray], np.ndarray]
"""log ℓ(s) of the projected preference s = θ·Δ, vectorized: shape (n,) -> (n,)."""

# Grid of the tilted integrals: a coarse pass over the whole range finds where the integrand
# is within e^-TAIL of its maximum, a fine pass integrates there (trapezoid, which converges
# exponentially for a smooth integrand that has decayed at both ends).
_GRID_POINTS = 4001
_TAIL = 60.0
# Half-width of the coarse range in prior standard deviations beyond [min(m, c), max(m, c)].
_RANGE_SD = 14.0


@dataclass(frozen=True)
class BoltzmannCorrection:
    """The correction model ℓ(s) = ε/2 + (1 − ε) mean_j σ(β_j s), and the process noise.

    Attributes:
        beta_min: smallest rationality β, > 0.
        beta_max: largest rationality β, ≥ beta_min.
        n_beta: number of log-spaced β between beta_min and beta_max (both included), ≥ 1;
            must be 1 when beta_min == beta_max.
        lapse: ε in [0, 1): probability that a correction carries no information
            (it is then better or worse with probability 1/2 each).
        process_noise: q ≥ 0, the process noise M = q · I of θᵗ = θᵗ⁻¹ + m (eq. K1).

    Raises:
        ValueError: on a field outside its range; the message names the field.
    """

    beta_min: float = 0.3
    beta_max: float = 30.0
    n_beta: int = 15
    lapse: float = 0.0
    process_noise: float = 0.0

    def __post_init__(self) -> None:
        for name in ("beta_min", "beta_max", "lapse", "process_noise"):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float | np.number)
                or not math.isfinite(value)
            ):
                raise ValueError(
                    f"BoltzmannCorrection.{name}: expected a finite number, got {value!r}"
                )
        if self.beta_min <= 0.0:
            raise ValueError(f"BoltzmannCorrection.beta_min: must be > 0, got {self.beta_min}")
        if self.beta_max < self.beta_min:
            raise ValueError(
                f"BoltzmannCorrection.beta_max: must be >= beta_min = {self.beta_min}, "
                f"got {self.beta_max}"
            )
        n = self.n_beta
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
            raise ValueError(f"BoltzmannCorrection.n_beta: must be an integer >= 1, got {n!r}")
        if self.beta_max == self.beta_min and n != 1:
            raise ValueError(
                f"BoltzmannCorrection.n_beta: must be 1 when beta_min == beta_max, got {n}"
            )
        if not 0.0 <= self.lapse < 1.0:
            raise ValueError(f"BoltzmannCorrection.lapse: must lie in [0, 1), got {self.lapse}")
        if self.process_noise < 0.0:
            raise ValueError(
                f"BoltzmannCorrection.process_noise: must be >= 0, got {self.process_noise}"
            )

    @classmethod
    def fixed(cls, beta: float, lapse: float = 0.0, process_noise: float = 0.0):
        """The model with one known rationality β (plain Bradley–Terry when lapse = 0)."""
        return cls(beta_min=beta, beta_max=beta, n_beta=1, lapse=lapse, process_noise=process_noise)

    @property
    def betas(self) -> np.ndarray:
        """β_j, shape (n_beta,), log-spaced from beta_min to beta_max."""
        return np.geomspace(self.beta_min, self.beta_max, self.n_beta)

    def log_likelihood(self, s: np.ndarray) -> np.ndarray:
        """log ℓ(s), shape (n,) -> (n,); stable for any |β s|."""
        s = np.asarray(s, dtype=float)
        # log σ(x) = −log(1 + e⁻ˣ); the mean over β in log space.
        log_sig = -np.logaddexp(0.0, -np.multiply.outer(self.betas, s))
        log_mix = np.logaddexp.reduce(log_sig, axis=0) - math.log(self.n_beta)
        if self.lapse == 0.0:
            return log_mix
        return np.logaddexp(math.log(0.5 * self.lapse), math.log1p(-self.lapse) + log_mix)


@dataclass(frozen=True, eq=False, kw_only=True)
class PosteriorStep(Step):
    """Result of one correction.

    Attributes:
        belief: the moment-matched posterior N(θ̂⁺, P⁺).
        gain: K = (μ − m)/v · P⁻, shape (k, k), so that θ̂⁺ = θ̂ + K Δ (the counterpart of the
            Kalman gain and of the Preference Perceptron's α I); zeros if Δ = 0.
        innovation: Δ = Φ_h − Φ(ξᵗ), shape (k,).
        innovation_cov: None: the model predicts whether a correction improves the reward,
            not its features, so there is no innovation covariance (and no NIS). Use
            ``log_evidence`` as the calibration check a deployment can run.
        log_evidence: log Z = log P(this correction is an improvement | prior), ≤ 0.
        repaired: True if the tilted variance τ² had to be floored to keep P⁺ definite.
    """

    log_evidence: float


def update(
    belief: Belief,
    observe: Observe | None,
    phi_robot: np.ndarray,
    phi_human: np.ndarray,
    model: BoltzmannCorrection | None = None,
) -> PosteriorStep:
    """One correction: add the process noise, then moment-match ℓ(θ·Δ) (see module doc).

    Args:
        belief: prior N(θ̂ᵗ, Pᵗ), k features.
        observe: the environment's batch h(θ) = Φ(ξ*(θ, E), E); unused (the update needs
            no plans) and accepted so that the study loop calls every learner alike.
        phi_robot: Φ(ξᵗ, Eᵗ), features of the robot's trajectory, shape (k,).
        phi_human: Φ(ξ_hᵗ, Eᵗ), features of the human's correction, shape (k,).
        model: the correction model; ``BoltzmannCorrection()`` if None.

    Returns:
        The posterior and its diagnostics, see :class:`PosteriorStep`.

    Raises:
        ValueError: on mismatched shapes or non-finite features; the field is named.
    """
    del observe
    model = model or BoltzmannCorrection()
    k = belief.dim
    phi_robot = _as_vector("phi_robot", phi_robot, k)
    phi_human = _as_vector("phi_human", phi_human, k)
    prior = Belief(theta=belief.theta, cov=belief.cov + model.process_noise * np.eye(k))
    return moment_match(prior, phi_human - phi_robot, model.log_likelihood)


def moment_match(
    belief: Belief, direction: np.ndarray, log_likelihood: LogLikelihood, center: float = 0.0
) -> PosteriorStep:
    """Gaussian N(θ̂, P) times a likelihood ℓ(θ·d), projected back onto a Gaussian.

    Exact in its first two moments: the result has the mean and covariance of
    p(θ) ∝ N(θ; θ̂, P) ℓ(θ·d). No process noise is added here.

    Args:
        belief: the prior N(θ̂, P), k features.
        direction: d, shape (k,); the likelihood sees θ only through s = θ·d.
        log_likelihood: log ℓ, vectorized (n,) -> (n,).
        center: a value of s near which ℓ changes (0 for a preference between two
            trajectories); the integration range covers it as well as the prior's mass.

    Returns:
        The posterior; ``innovation`` is d and ``gain`` K with θ̂⁺ = θ̂ + K d.

    Raises:
        ValueError: on a bad direction or a likelihood that is zero or not finite wherever
            the prior has mass.
    """
    k = belief.dim
    d = _as_vector("direction", direction, k)
    cov = belief.cov
    if not np.any(d):
        return PosteriorStep(
            belief=belief,
            gain=np.zeros((k, k)),
            innovation=d,
            log_evidence=float(log_likelihood(np.zeros(1))[0]),
        )
    mean_s = float(belief.theta @ d)
    cov_d = cov @ d
    var_s = float(d @ cov_d)
    log_z, mu, tau2 = tilted_moments(mean_s, var_s, log_likelihood, center)
    floor = COV_FLOOR_RTOL * var_s
    repaired = tau2 < floor
    tau2 = max(tau2, floor)
    weight = (mu - mean_s) / var_s
    post = Belief(
        theta=belief.theta + weight * cov_d,
        cov=symmetrize(cov - np.outer(cov_d, cov_d) * (var_s - tau2) / var_s**2),
    )
    return PosteriorStep(
        belief=post,
        gain=weight * cov,
        innovation=d,
        log_evidence=log_z,
        repaired=repaired,
    )


def tilted_moments(
    mean: float, var: float, log_likelihood: LogLikelihood, center: float = 0.0
) -> tuple[float, float, float]:
    """(log Z, μ, τ²) of the tilted density ℓ(s) N(s; mean, var) / Z on the real line.

    Z = ∫ ℓ(s) N(s; mean, var) ds; μ and τ² are the tilted mean and variance. A coarse grid of
    the range [min(mean, center), max(mean, center)] ± 14 √var locates the integrand's mass
    (where it lies within e^-60 of its maximum); a fine grid there integrates it with the
    trapezoid rule. Accurate when ℓ is smooth on the scale of the fine grid and the mass lies
    in the coarse range, which holds for any nondecreasing ℓ with center at its transition.

    Args:
        mean: prior mean of s.
        var: prior variance of s, > 0.
        log_likelihood: log ℓ, vectorized (n,) -> (n,).
        center: where ℓ changes; widens the range to include it.

    Raises:
        ValueError: if var is not > 0, or ℓ is zero or not finite on the whole range.
    """
    if not (math.isfinite(mean) and math.isfinite(var) and var > 0.0):
        raise ValueError(f"tilted_moments: need a finite mean and var > 0, got {mean}, {var}")
    sd = math.sqrt(var)
    lo = min(mean, center) - _RANGE_SD * sd
    hi = max(mean, center) + _RANGE_SD * sd

    def log_integrand(s: np.ndarray) -> np.ndarray:
        out = np.asarray(log_likelihood(s), dtype=float)
        if out.shape != s.shape or np.any(np.isnan(out)) or np.any(out == np.inf):
            raise ValueError("log_likelihood: must return finite or -inf values of shape (n,)")
        return out - 0.5 * (s - mean) ** 2 / var

    coarse = np.linspace(lo, hi, _GRID_POINTS)
    values = log_integrand(coarse)
    top = float(np.max(values))
    if not math.isfinite(top):
        raise ValueError("log_likelihood: the likelihood is zero wherever the prior has mass")
    inside = np.flatnonzero(values >= top - _TAIL)
    step = coarse[1] - coarse[0]
    fine = np.linspace(coarse[inside[0]] - step, coarse[inside[-1]] + step, _GRID_POINTS)
    values = log_integrand(fine)
    top = float(np.max(values))
    weights = np.exp(values - top)
    weights[[0, -1]] *= 0.5
    total = float(np.sum(weights))
    mu = float(weights @ fine) / total
    tau2 = float(weights @ (fine - mu) ** 2) / total
    h = fine[1] - fine[0]
    log_z = top + math.log(total * h) - 0.5 * math.log(2.0 * math.pi * var)
    return log_z, mu, tau2
