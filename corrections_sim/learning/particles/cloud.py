"""Sequential Monte Carlo over a static θ, one likelihood term per correction.

The posterior p(θ | z₁…z_t) ∝ p(θ) Πᵢ p(zᵢ | θ) is carried by weighted particles
(:class:`~corrections_sim.learning.particles.state.Particles`). A correction reweights every
particle by its likelihood; when the effective sample size falls below a fraction of the
count, the particles are resampled (systematic) and each is moved by random-walk Metropolis
steps that target the whole posterior, re-evaluating every past correction at the proposal
(resample-move; Chopin, "A sequential particle filter method for static models", Biometrika
2002, IBIS; Gilks & Berzuini 2001). Moves keep the posterior invariant, so the sample stays
exact in the limit of many particles; they undo the degeneracy that reweighting alone
leaves.

Plain numpy: the caller passes the log-likelihoods (which need the planner) as arrays or as
a batch callable; everything random comes from the ``rng`` given.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief
from corrections_sim.learning.particles.state import Particles, ParticleState

LogDensity = Callable[[np.ndarray], np.ndarray]
"""thetas (n, k) -> a log density at each (n,), up to one constant; −inf where impossible."""

#: Random-walk Metropolis scale (Roberts, Gelman & Gilks 1997): proposals N(0, (2.38²/k) Σ).
RW_SCALE = 2.38


def draw(prior: Belief, count: int, rng: np.random.Generator) -> Particles:
    """``count`` equally weighted particles from N(θ̂⁰, P⁰)."""
    if isinstance(count, bool) or not isinstance(count, int) or count < 2:
        raise ValueError(f"particles = {count!r}: expected an integer >= 2")
    thetas = rng.multivariate_normal(prior.theta, prior.cov, size=count, method="cholesky")
    return Particles(thetas=thetas, log_weights=np.zeros(count), log_likelihood=np.zeros(count))


def systematic(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices of a systematic resample of normalized ``weights`` (one uniform draw)."""
    n = len(weights)
    positions = (rng.random() + np.arange(n)) / n
    cumulative = np.cumsum(weights)
    cumulative[-1] = 1.0
    return np.searchsorted(cumulative, positions)


@dataclass(frozen=True)
class Moved:
    """What one correction did to the sample.

    Attributes:
        particles: the sample after it.
        ess_before: the effective sample size after reweighting, before any resample.
        resampled: whether it resampled and moved.
        acceptance: the Metropolis moves' mean acceptance rate (NaN if none).
        evaluations: how many particle × correction likelihoods the moves evaluated.
    """

    particles: Particles
    ess_before: float
    resampled: bool
    acceptance: float
    evaluations: int


def correct(
    particles: Particles,
    log_like: np.ndarray,
    log_prior: LogDensity,
    log_total: Callable[[np.ndarray], tuple[np.ndarray, int]],
    rng: np.random.Generator,
    *,
    moves: int = 2,
    threshold: float = 0.5,
) -> Moved:
    """Take one correction in: reweight by ``log_like`` (its log-likelihood at each particle,
    (n,)); if the effective sample size falls below ``threshold`` × n, resample and move
    every particle by ``moves`` random-walk Metropolis steps targeting the posterior
    (``log_prior`` + every correction's log-likelihood, ``log_total(thetas)`` -> (values (n,),
    evaluations made)), the proposal's covariance (2.38²/k) × the sample's.

    Raises:
        ValueError: every particle impossible under the correction (no weight is left).
    """
    if isinstance(moves, bool) or not isinstance(moves, int) or moves < 0:
        raise ValueError(f"moves = {moves!r}: expected an integer >= 0")
    log_like = np.asarray(log_like, float)
    log_w = particles.log_weights + log_like
    if not np.any(np.isfinite(log_w)):
        raise ValueError("no particle explains the correction (every likelihood is zero)")
    log_l = particles.log_likelihood + log_like
    log_l = np.where(np.isfinite(log_l), log_l, -np.inf)
    weighted = Particles(thetas=particles.thetas, log_weights=log_w, log_likelihood=log_l)
    ess = weighted.effective_size()
    n, k = particles.thetas.shape
    if ess >= threshold * n:
        return Moved(weighted, ess, False, float("nan"), 0)
    _, cov = weighted.moments()
    picks = systematic(weighted.weights(), rng)
    thetas, log_l = weighted.thetas[picks].copy(), weighted.log_likelihood[picks].copy()
    root = np.linalg.cholesky(cov) * (RW_SCALE / np.sqrt(k))
    here = log_prior(thetas) + log_l
    accepted, evaluations = 0, 0
    for _ in range(moves):
        proposal = thetas + rng.standard_normal((n, k)) @ root.T
        proposed_l, made = log_total(proposal)
        evaluations += made
        there = log_prior(proposal) + proposed_l
        with np.errstate(invalid="ignore"):
            take = np.log(rng.random(n)) < there - here
        take &= np.isfinite(there)
        thetas[take], log_l[take], here[take] = proposal[take], proposed_l[take], there[take]
        accepted += int(take.sum())
    moved = Particles(thetas=thetas, log_weights=np.zeros(n), log_likelihood=log_l)
    rate = accepted / (moves * n) if moves else float("nan")
    return Moved(moved, ess, True, rate, evaluations)


def smoothed_kl(
    points: np.ndarray,
    weights: np.ndarray,
    particles: Particles,
    coefficients: np.ndarray | None = None,
) -> float:
    """KL(reference ‖ particles) on a grid: ``weights`` the reference's cell weights at the
    grid's ``points`` (n, k), the particles smoothed into a density there by a Gaussian kernel
    of Silverman's bandwidth (the sample's covariance × (4 / ((k + 2) n_eff))^(2/(k + 4)),
    n_eff the effective sample size), times each point's cell volume (``coefficients``, the
    refined cells' trapezoid weights; None: a uniform grid's) and normalized over the same
    cells. Unsmoothed, a finite sample leaves the reference's tails empty and the KL is the
    floor's, not the sample's (200 particles binned on cells of 0.5: 1.0 nats, almost all of
    it from cells no particle reached)."""
    k = particles.thetas.shape[1]
    _, cov = particles.moments()
    factor = (4.0 / ((k + 2) * particles.effective_size())) ** (2.0 / (k + 4))
    inverse = np.linalg.inv(cov * factor)
    log_q = np.full(len(points), -np.inf)
    log_w = particles.log_weights
    for start in range(0, len(points), 4096):
        d = points[start : start + 4096, None, :] - particles.thetas[None, :, :]
        m = np.einsum("npi,ij,npj->np", d, inverse, d)
        terms = log_w[None, :] - 0.5 * m
        top = np.max(terms, axis=1)
        log_q[start : start + 4096] = top + np.log(np.exp(terms - top[:, None]).sum(axis=1))
    q = np.exp(log_q - np.max(log_q))
    if coefficients is not None:
        q = q * np.asarray(coefficients, float)
    q /= q.sum()
    p = np.asarray(weights, float) / np.sum(weights)
    keep = p > 0
    return float(np.sum(p[keep] * (np.log(p[keep]) - np.log(np.maximum(q[keep], 1e-300)))))


def against_grid(
    belief: Belief,
    thetas: np.ndarray,
    weights: np.ndarray,
    mean: np.ndarray,
    cov: np.ndarray,
    coefficients: np.ndarray | None = None,
) -> dict:
    """How far the particles of ``belief`` (a particle learner's) are from a grid reference
    (``weights`` at ``thetas``, its moments ``mean`` and ``cov``): KL (the particles smoothed
    on the grid, its refined cells' volumes ``coefficients`` if any), the moments' gaps and
    the effective sample size."""
    if not isinstance(belief.state, ParticleState) or belief.state.particles is None:
        raise ValueError("against_grid: the belief holds no particles")
    cloud = belief.state.particles
    p_mean, p_cov = cloud.moments()
    sd = np.sqrt(np.diag(cov))
    return {
        "particle_kl": smoothed_kl(thetas, weights, cloud, coefficients),
        "particle_mean_gap": float(np.max(np.abs(p_mean - mean) / sd)),
        "particle_var_gap": float(np.max(np.abs(np.diag(p_cov) - np.diag(cov)) / np.diag(cov))),
        "particle_ess": cloud.effective_size(),
    }
