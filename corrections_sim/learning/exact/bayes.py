"""Exact reference posteriors on a grid over θ (k = 2), under exactly a learner's model.

A Gaussian learner approximates p(θ | corrections); where its NEES is off, the question is
whether the approximation (the unscented transform, a Gaussian collapse, moment matching) or
the model of the person is to blame. This module computes the posterior itself, on a regular
grid, from the values of the learner's observation model at the grid's points (the caller
solves ξ*(θ, E) there once; this module never plans):

* :func:`gaussian_log_likelihood` — KF/KF-C's model, Φ_h ~ N(h(θ), N) with N known;
* :func:`learnt_noise_log_likelihood` — the same with N integrated out under an
  inverse-Wishart prior IW(ν₀, V₀) (what a ``noise = "learnt"`` filter assumes), exactly:
  p(z₁…z_t | θ) ∝ |V₀ + Σᵢ rᵢ rᵢᵀ|^(−(ν₀ + t)/2), rᵢ = zᵢ − hᵢ(θ);
* :func:`relevance_log_likelihood` — KF-CR's: KF-C's Gaussian where the correction is
  relevant (probability β̂, the learner's own), uninformative where it is not;
* :class:`PersonPosterior` — KF-CRP's: a joint posterior over θ, the person's rate r of
  relevant corrections and the precision τ of their relevant corrections, each correction
  relevant (N(z; h(θ), N) f₁(ρ(θ); τ)) or not (the marginal of z times f₀(ρ*));
* :func:`boltzmann_log_likelihood` — BP's model, P(ξ_h ≻ ξᵗ | θ) = ε/2 + (1 − ε) mean_β σ(β θ·Δ).

:func:`posterior` turns a log prior plus log likelihoods into normalized cell weights;
:func:`moments`, :func:`kl_to_gaussian` and :func:`nees` compare it with a learner's Gaussian.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import expit

from corrections_sim.belief import Belief
from corrections_sim.learning.exact.cells import Cells
from corrections_sim.learning.kalman import iterated


@dataclass(frozen=True)
class Grid:
    """A regular grid over θ: ``points`` per axis between ``low`` and ``high`` (inclusive).

    Attributes:
        low, high: the box's corners, shape (k,) each.
        points: grid points per axis (≥ 3).
    """

    low: tuple[float, ...]
    high: tuple[float, ...]
    points: int

    def __post_init__(self) -> None:
        if len(self.low) != len(self.high) or not self.low:
            raise ValueError(f"low {self.low} and high {self.high}: expected two k-vectors")
        if not all(h > lo for lo, h in zip(self.low, self.high, strict=True)):
            raise ValueError(f"high {self.high} must exceed low {self.low} on every axis")
        if isinstance(self.points, bool) or not isinstance(self.points, int) or self.points < 3:
            raise ValueError(f"points = {self.points!r}: expected an integer >= 3")

    @property
    def axes(self) -> list[np.ndarray]:
        return [np.linspace(lo, h, self.points) for lo, h in zip(self.low, self.high, strict=True)]

    @property
    def spacing(self) -> np.ndarray:
        """Cell widths per axis, shape (k,)."""
        return (np.array(self.high) - np.array(self.low)) / (self.points - 1)

    def thetas(self) -> np.ndarray:
        """Every grid point, shape (points^k, k), the last axis fastest."""
        mesh = np.meshgrid(*self.axes, indexing="ij")
        return np.stack([m.ravel() for m in mesh], axis=1)

    def halved(self) -> Grid:
        """The same box at half the spacing (for the grid's own convergence check)."""
        return Grid(self.low, self.high, 2 * self.points - 1)


@dataclass(frozen=True)
class Refinement:
    """Where to cut a grid posterior's cells (:class:`~.cells.Cells`) finer.

    The leaves with a corner where the density is within ``cut`` of its peak are the
    posterior's core; while the core's coarsest cells leave the posterior's narrowest sd
    (its covariance's, in those cells' widths in every direction) under ``resolution``
    nodes, the core's coarsest leaves are cut, up to the cells' ``depth``: with ``axes =
    "all"`` in 2^k (every axis halved), with ``axes = "narrow"`` along one axis at a time,
    the one whose halving widens that narrowest sd most (a posterior narrow in one direction
    gets fine cells across it only: at k = 3 several times fewer nodes). The rest stays on
    coarser cells: nothing is dropped, but there a density below e^−cut of the peak is
    integrated coarsely. (A density with a floor far out — bounded features make the
    likelihood level off — holds more mass there than its peak's neighbourhood suggests, yet
    varies slowly.)

    Attributes:
        resolution: grid nodes a posterior sd needs (0: never cut). The trapezoid rule's
            error on a Gaussian's moments is about 2 exp(−2π² r²) at r nodes an sd (5e-9 at
            r = 1): r = 1 resolves a smooth posterior; the reference tool takes r = 2.
        cut: the core's edge, in log density below the peak (9.2: 1e-4 of it).
        axes: "all" or "narrow" (above).
    """

    resolution: float = 1.0
    cut: float = 9.2
    axes: str = "all"

    def __post_init__(self) -> None:
        if not (np.isfinite(self.resolution) and self.resolution >= 0):
            raise ValueError(f"resolution = {self.resolution!r}: expected a number >= 0")
        if not (np.isfinite(self.cut) and self.cut > 0):
            raise ValueError(f"cut = {self.cut!r}: expected a number > 0")
        if self.axes not in REFINED_AXES:
            raise ValueError(f"axes = {self.axes!r}: expected one of {', '.join(REFINED_AXES)}")

    def finer(self, cells: Cells, log_density: np.ndarray) -> Cells | None:
        """``cells`` cut once more where the posterior (``log_density`` at their nodes) needs
        it, or None where it needs no finer cells (or may have none)."""
        if self.resolution == 0:
            return None
        with np.errstate(invalid="ignore"):
            density = np.exp(np.asarray(log_density, float) - np.max(log_density))
        density = np.where(np.isfinite(density), density, 0.0)
        core = np.flatnonzero(density[cells.corners].max(axis=1) >= np.exp(-self.cut))
        levels = cells.levels[core]
        coarsest = levels.min(axis=0)  # per axis (with "all", the same on every axis)
        if np.all(coarsest >= cells.depth):
            return None
        weights = cells.coefficients * density
        _, cov = moments(cells.thetas(), weights / weights.sum())
        widths = cells.unit() * 2.0 ** (cells.depth - coarsest)
        if _narrowest(cov, widths) >= self.resolution**2:
            return None
        if self.axes == "all":
            halve = np.ones(cells.k, bool)
        else:  # the axis whose halving widens the narrowest sd most; the lowest on a tie
            gains = [
                _narrowest(cov, np.where(np.arange(cells.k) == a, widths / 2, widths))
                if coarsest[a] < cells.depth
                else -np.inf
                for a in range(cells.k)
            ]
            halve = np.arange(cells.k) == int(np.argmax(gains))
        axis = int(np.argmax(halve))
        which = np.zeros(len(cells.leaves), bool)
        which[core[levels[:, axis] == coarsest[axis]]] = True
        return cells.cut(which, halve)


#: How :class:`Refinement` cuts a cell.
REFINED_AXES = ("all", "narrow")


def _narrowest(cov: np.ndarray, widths: np.ndarray) -> float:
    """The smallest variance of ``cov`` in units of the cells' ``widths`` (k,) per axis."""
    scale = 1.0 / widths
    return float(np.linalg.eigvalsh(scale[:, None] * cov * scale[None, :])[0])


def gaussian_log_prior(thetas: np.ndarray, prior: Belief) -> np.ndarray:
    """log N(θ; θ̂⁰, P⁰) at each grid point (n,), up to a constant."""
    d = thetas - prior.theta
    return -0.5 * np.einsum("ni,ij,nj->n", d, np.linalg.inv(prior.cov), d)


def gaussian_log_density(z: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> float:
    """log N(z; mean, cov), normalised (−inf where cov is not positive definite)."""
    d = np.asarray(z, float) - mean
    sign, logdet = np.linalg.slogdet(2.0 * np.pi * cov)
    return float(-0.5 * d @ np.linalg.solve(cov, d) - 0.5 * logdet) if sign > 0 else -np.inf


def gaussian_log_likelihood(z: np.ndarray, h: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """log N(z; h(θ), N) at each grid point, up to a constant.

    Args:
        z: the observation Φ_h (k,).
        h: the model's prediction at each grid point (n, k).
        noise: N (k, k), symmetric positive definite.
    """
    r = np.asarray(z, float)[None, :] - h
    with np.errstate(invalid="ignore"):
        out = -0.5 * np.einsum("ni,ij,nj->n", r, np.linalg.inv(noise), r)
    return np.where(np.isfinite(out), out, -np.inf)  # no plan at a grid point: impossible


def relevance_log_likelihood(
    log_gaussian: np.ndarray, log_current: np.ndarray, relevance: float
) -> np.ndarray:
    """log p(z | θ) of a relevance-aware learner's model, the relevance r integrated out:
    β̂ N(z; h(θ), N) + (1 − β̂) c. β̂ is the learner's P(relevant | ρ) for this correction
    (from the joint-space evidence ρ, which does not depend on θ); c, the density of z if the
    correction is irrelevant, is the marginal of z under the current posterior,
    Σ_θ' w(θ') N(z; h(θ'), N), so that z itself adds no evidence about r beyond β̂.

    Args:
        log_gaussian: log N(z; h(θ), N) per grid point (n,), up to one constant
            (:func:`gaussian_log_likelihood`).
        log_current: the posterior before this correction, an unnormalized log density (n,).
        relevance: β̂ in (0, 1].
    """
    if not 0.0 < relevance <= 1.0:
        raise ValueError(f"relevance = {relevance!r}: expected a probability in (0, 1]")
    if relevance == 1.0:
        return log_gaussian
    weights = posterior(log_current)
    top = np.max(log_gaussian)
    marginal = float(weights @ np.exp(log_gaussian - top))  # c · exp(−top)
    with np.errstate(divide="ignore"):
        relevant = np.log(relevance) + log_gaussian - top
        return top + np.logaddexp(relevant, np.log1p(-relevance) + np.log(marginal))


def learnt_noise_log_likelihood(
    zs: np.ndarray, hs: np.ndarray, dof: float, scale: np.ndarray
) -> np.ndarray:
    """log p(z₁…z_t | θ) with N ~ IW(ν₀ = ``dof``, V₀ = ``scale``) integrated out, up to a
    constant: −(ν₀ + t)/2 · log|V₀ + Σᵢ rᵢ rᵢᵀ|, rᵢ = zᵢ − hᵢ(θ).

    Args:
        zs: the observations, shape (t, k).
        hs: the model's predictions, shape (t, n, k) (observation, grid point, feature).
    """
    zs, hs = np.atleast_2d(zs), np.asarray(hs, float)
    r = zs[:, None, :] - hs  # (t, n, k)
    finite = np.all(np.isfinite(r), axis=(0, 2))  # a grid point without a plan: impossible
    spread = scale[None, :, :] + np.einsum("tni,tnj->nij", r[:, finite], r[:, finite])
    sign, logdet = np.linalg.slogdet(spread)
    if np.any(sign <= 0):
        raise ValueError("scale: V0 + sum r r^T must stay positive definite")
    out = np.full(r.shape[1], -np.inf)
    out[finite] = -0.5 * (dof + zs.shape[0]) * logdet
    return out


def boltzmann_log_likelihood(
    thetas: np.ndarray, delta: np.ndarray, betas: np.ndarray, lapse: float
) -> np.ndarray:
    """log P(correction improves | θ) = log(ε/2 + (1 − ε) mean_j σ(β_j θ·Δ)) per grid point,
    β integrated out over ``betas`` (BP's model), Δ = Φ_h − Φ(ξᵗ)."""
    s = thetas @ np.asarray(delta, float)
    sig = expit(np.outer(s, np.asarray(betas, float))).mean(axis=1)
    return np.log(0.5 * lapse + (1.0 - lapse) * sig)


#: How far below the posterior's peak (in log density) a node may stay with corrections not yet
#: weighed at it: its weight is then certainly below e^−100 (4e-44) of the peak's, below what a
#: double adds to any moment (:func:`pending_needed`).
LAZY_MARGIN = 100.0


def near_peak(log_posterior: np.ndarray, margin: float = LAZY_MARGIN) -> np.ndarray:
    """The nodes (indices) within ``margin`` of the peak of ``log_posterior``: where a new
    correction is weighed at once; elsewhere it waits (:func:`pending_needed`)."""
    at = np.flatnonzero(np.isfinite(log_posterior))
    return at[log_posterior[at] >= log_posterior[at].max() - margin]


def pending_needed(
    bound: np.ndarray, pending: np.ndarray, margin: float = LAZY_MARGIN
) -> np.ndarray:
    """The nodes (n,) whose pending corrections must be weighed before the posterior is read.

    A node with every correction weighed (not ``pending``) has its log posterior in ``bound``;
    a pending node an upper bound of it (each correction not yet weighed can only lower it:
    :func:`gaussian_log_likelihood` is at most 0, and −(ν₀ + t)/2 · log|V₀ + Σ r rᵀ| only falls
    as terms are added). Needed: the pending nodes within ``margin`` of the larger of the peak
    (over the others) and the highest bound. Weighing them and asking again until none is
    needed leaves every pending node certainly ``margin`` below the peak: its weight is then 0
    to a double's precision, as it would be after weighing. Nodes at −inf are impossible and
    never needed."""
    pending = np.asarray(pending, bool)
    bound = np.asarray(bound, float)
    open_ = pending & np.isfinite(bound)
    if not open_.any():
        return open_
    done = ~pending & np.isfinite(bound)
    peak = bound[done].max() if done.any() else -np.inf
    return open_ & (bound >= max(peak, bound[open_].max()) - margin)


def posterior(log_density: np.ndarray, coefficients: np.ndarray | None = None) -> np.ndarray:
    """Normalized cell weights (n,) from an unnormalized log density at the grid points
    (each weighing ``coefficients``, a refined grid's trapezoid weights; None: the same)."""
    w = np.exp(log_density - np.max(log_density))
    if coefficients is not None:
        w = w * coefficients
    return w / w.sum()


def moments(thetas: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (k,) and covariance (k, k) of the grid posterior."""
    mean = weights @ thetas
    d = thetas - mean
    return mean, (weights[:, None] * d).T @ d


def kl_to_gaussian(
    grid: Grid,
    thetas: np.ndarray,
    weights: np.ndarray,
    belief: Belief,
    coefficients: np.ndarray | None = None,
) -> float:
    """KL(reference ‖ N(θ̂, P)) in nats, the reference's density w / the volume a node
    weighs (``coefficients``, a refined grid's trapezoid weights; None: ``grid``'s cell)."""
    volume = np.prod(grid.spacing) if coefficients is None else np.asarray(coefficients)
    keep = weights > 0
    density = weights[keep] / (volume if volume.ndim == 0 else volume[keep])
    k = thetas.shape[1]
    d = thetas[keep] - belief.theta
    _, logdet = np.linalg.slogdet(belief.cov)
    log_q = -0.5 * (
        np.einsum("ni,ij,nj->n", d, np.linalg.inv(belief.cov), d) + logdet + k * np.log(2 * np.pi)
    )
    return float(np.sum(weights[keep] * (np.log(density) - log_q)))


def gaussian_kl(mean: np.ndarray, cov: np.ndarray, belief: Belief) -> float:
    """KL(N(mean, cov) ‖ N(θ̂, P)) in nats, closed form: the part of ``ref_kl`` a Gaussian
    with the reference's own moments already has (the rest is the reference's shape)."""
    return iterated.gaussian_kl(Belief(theta=mean, cov=cov), belief)


def nees(mean: np.ndarray, cov: np.ndarray, theta_star: np.ndarray) -> float:
    """(θ̄ − θ*)ᵀ Σ⁻¹ (θ̄ − θ*) of the reference's own mean and covariance."""
    d = np.asarray(mean) - np.asarray(theta_star)
    return float(d @ np.linalg.solve(cov, d))


@dataclass
class PersonPosterior:
    """The exact posterior of KF-CRP's model on a grid: θ on ``thetas`` (n, k), and (τ, r) on
    a grid as :class:`~corrections_sim.learning.relevance.state.PersonBelief` has it (finer
    than the learner's).
    Per correction (relevant with probability r, each independently):

    * relevant: p(z, ξ_h | θ, τ) = N(z; h(θ), N) · f₁(ρ*; τ) · exp(−τ₀ (ρ(θ)² − ρ*²)/2): the
      person's precision τ governs how much of the move is left unexplained (f₁, the
      half-normal of ρ*), and how well θ explains the move (ρ(θ), the unexplained fraction at
      θ) weighs θ at the prior's mean precision τ₀, as KF-CRP's model has it;
    * irrelevant: c · f₀(ρ*) · Λ_W, c the marginal of z under the current posterior of θ
      (so z adds nothing about r by itself, as in :func:`relevance_log_likelihood`), f₀ the
      density of the least unexplained fraction ρ*, and Λ_W = E_{θ ~ W}[exp(−τ₀ (ρ(θ)² −
      ρ*²)/2)] the chance of the explanation's place under the scatter W of irrelevant
      explanations around the robot's θ̂, at the prior's mean precision τ₀ (an irrelevant
      correction is not made with the person's precision; :func:`irrelevant_place`).

    ``log_w`` (n, τ nodes, r points) is the unnormalized log posterior.
    """

    thetas: np.ndarray
    taus: np.ndarray
    rates: np.ndarray
    log_w: np.ndarray

    @classmethod
    def prior(cls, thetas: np.ndarray, log_prior: np.ndarray, person) -> PersonPosterior:
        """The prior: ``log_prior`` over θ (n,) times ``person``'s prior over (τ, r) (a
        :class:`~corrections_sim.learning.relevance.state.PersonBelief`, on the grid it has)."""
        log_w = log_prior[:, None, None] + np.asarray(person.log_w)[None, :, :]
        return cls(np.asarray(thetas, float), np.array(person.taus), np.array(person.rates), log_w)

    def theta_weights(self) -> np.ndarray:
        """The posterior over θ alone, normalized cell weights (n,)."""
        top = np.max(self.log_w)
        return posterior(np.log(np.exp(self.log_w - top).sum(axis=(1, 2))) + top)

    def correct(
        self,
        log_gaussian: np.ndarray,
        rho: np.ndarray,
        rho_star: float,
        tau0: float,
        log_irrelevant: float,
    ) -> float:
        """Take one correction in; returns its posterior probability of being relevant given
        everything before it and itself (the exact β̂).

        Args:
            log_gaussian: log N(z; h(θ), N) per grid point (n,), up to one constant.
            rho: ρ(θ) per grid point (n,), NaN where the grid has no plan.
            rho_star: ρ*, the least unexplained fraction.
            tau0: τ₀, the precision that weighs θ by ρ(θ).
            log_irrelevant: log of the irrelevant model's density of the correction
                (log f₀(ρ*) + log Λ_W).
        """
        theta_w = self.theta_weights()
        top = np.max(np.where(np.isfinite(log_gaussian), log_gaussian, -np.inf))
        log_c = top + np.log(float(theta_w @ np.exp(log_gaussian - top)))
        rho = np.where(np.isfinite(rho), rho, np.inf)
        with np.errstate(invalid="ignore", over="ignore"):
            log_place = -0.5 * tau0 * (rho**2 - rho_star**2)  # (n,)
        log_f1 = 0.5 * np.log(2.0 * self.taus / np.pi) - 0.5 * self.taus * rho_star**2
        log_on = (
            (log_gaussian + log_place)[:, None, None]
            + log_f1[None, :, None]
            + np.log(self.rates)[None, None, :]
        )
        log_off = log_c + float(log_irrelevant) + np.log1p(-self.rates)[None, None, :]
        log_on = np.where(np.isfinite(log_on), log_on, -np.inf)
        joint_on, joint_off = self.log_w + log_on, self.log_w + log_off
        top = max(np.max(joint_on), np.max(joint_off))
        on, off = np.exp(joint_on - top).sum(), np.exp(joint_off - top).sum()
        self.log_w = np.logaddexp(joint_on, joint_off)
        return float(on / (on + off))

    def rate_mean(self) -> float:
        """E[r | corrections]."""
        w = np.exp(self.log_w - np.max(self.log_w)).sum(axis=(0, 1))
        return float(w @ self.rates / w.sum())

    def spread(self) -> float:
        """E[τ | corrections]^(−1/2), comparable with the learner's σ̂."""
        w = np.exp(self.log_w - np.max(self.log_w)).sum(axis=(0, 2))
        return float((w @ self.taus / w.sum()) ** -0.5)


def irrelevant_place(
    thetas: np.ndarray, rho: np.ndarray, least: float, center: np.ndarray, scatter, tau0: float
) -> float:
    """log Λ_W = log E_{θ ~ W}[exp(−τ₀ (ρ(θ)² − ρ*²)/2)] on the grid, ρ* = ``least``, W the
    mixture Σ w_c N(center, W_c) of ``scatter`` = [(w_c, W_c (k, k)), …], each component
    normalized over the grid."""
    rho = np.where(np.isfinite(rho), rho, np.inf)
    weights = sum(
        w * posterior(gaussian_log_prior(thetas, Belief(theta=center, cov=cov)))
        for w, cov in scatter
    )
    with np.errstate(invalid="ignore", over="ignore"):
        terms = np.exp(-0.5 * tau0 * (rho**2 - least**2))
    terms = np.where(np.isfinite(terms), terms, 0.0)
    return float(np.log(max(float(weights @ terms), 1e-300)))
