"""Draws from an exact learner's posterior, within its cells (not at its nodes), and its
density anywhere: what simulation-based calibration ranks the truth among
(:mod:`corrections_sim.figures.sbc`). Plain values in and out; no planning.

An exact learner's posterior is known at its cells' nodes; its integrals are the trapezoid
rule's on every leaf cell (:class:`~corrections_sim.learning.exact.cells.Cells`), which is
the integral of the density interpolated multilinearly from the leaf's 2^k corners. That
interpolant is the density these draws come from. Its mean is the learner's θ̂ where every
node's neighbours sit alike; its spread is the learner's P with ``spread = "cells"``, and
wider than the nodes' P (``spread = "nodes"``) by what the cells cannot resolve
(:func:`cell_moments`). The draws:

* a leaf is drawn with probability its mass, its volume times the mean of its corners;
* within it, the multilinear density is a mixture over its corners b, weighed by their
  densities, of product densities Πᵢ gᵢ(uᵢ), g(u) = 2u where bᵢ = 1 and 2(1 − u) where
  bᵢ = 0 (each integrates to 2^−k on the unit cell): a corner is drawn, then each uᵢ
  (√U or 1 − √U), exactly.
"""

from __future__ import annotations

import itertools

import numpy as np

from corrections_sim.learning.exact.cells import Cells


def _corner_bits(k: int) -> np.ndarray:
    """The corners' offsets in the order of :attr:`Cells.corners` (2^k, k)."""
    return np.array(list(itertools.product((0, 1), repeat=k)), dtype=float)


def _leaf_boxes(cells: Cells) -> tuple[np.ndarray, np.ndarray]:
    """Each leaf's lower corner θ (m, k) and widths (m, k)."""
    k = cells.k
    unit = cells.unit()
    lower = np.array(cells.lows) + cells.leaves[:, k:] * unit
    widths = unit * 2.0 ** (cells.depth - cells.levels)
    return lower, widths


def _corner_densities(cells: Cells, log_density: np.ndarray) -> np.ndarray:
    """The density at every leaf's corners (m, 2^k), scaled so that its largest node is 1
    (−inf, a node where corrections wait, is 0)."""
    log_d = np.asarray(log_density, float)
    if log_d.shape != (len(cells.coords),):
        raise ValueError(
            f"log density of {log_d.shape} for {len(cells.coords)} nodes: expected one a node"
        )
    top = np.max(log_d)
    if not np.isfinite(top):
        raise ValueError("the posterior has no node with a finite density")
    with np.errstate(under="ignore"):
        nodes = np.exp(log_d - top)
    return nodes[cells.corners]


def _masses(widths: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Each leaf's unnormalized mass (m,): its volume times the mean of its corners."""
    return np.prod(widths, axis=1) * corners.mean(axis=1)


#: E[u] and Var[u] of a corner's factor g on the unit interval: 2u (its bit 1) has mean 2/3,
#: 2(1 − u) (bit 0) mean 1/3; both variance 1/18.
_FACTOR_VARIANCE = 1.0 / 18.0


def cell_moments(
    cells: Cells, log_density: np.ndarray, about: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The mean (k,) and the second moment about ``about`` (k, k) of the multilinear
    interpolant whose draws :func:`cell_draws` makes (its covariance where ``about`` is None,
    or is that mean), in closed form: a leaf's corner b weighs its mass share, and within it
    θ = lower + width ⊙ u, the uᵢ independent with mean 1/3 or 2/3 and variance 1/18 each,
    so E[(θ − a)(θ − a)ᵀ] = Σ p_{leaf, b} (e eᵀ + diag(width² / 18)), e = its mean − a.

    Where every node's neighbours sit alike, the mean is the trapezoid rule's (the learner's
    θ̂); the second moment is the trapezoid's point masses' plus what the density spreads
    within the cells, width² / 6 along an axis for a mass on one node: what the cells cannot
    resolve, which the nodes' moments leave out."""
    k = cells.k
    corners = _corner_densities(cells, log_density)
    lower, widths = _leaf_boxes(cells)
    share = np.prod(widths, axis=1)[:, None] * corners / 2**k  # (m, 2^k)
    share = share / share.sum()
    offsets = (1.0 + _corner_bits(k)) / 3.0  # E[u] at each corner (2^k, k)
    means = lower[:, None, :] + widths[:, None, :] * offsets[None, :, :]  # (m, 2^k, k)
    mean = np.einsum("mb,mbi->i", share, means)
    centre = mean if about is None else np.asarray(about, float)
    e = means - centre
    second = np.einsum("mb,mbi,mbj->ij", share, e, e)
    within = _FACTOR_VARIANCE * np.einsum("mb,mi->i", share, widths**2)
    return mean, second + np.diag(within)


def leaf_masses(cells: Cells, log_density: np.ndarray) -> np.ndarray:
    """Each leaf's share of the posterior's mass (m,), summing to 1."""
    _, widths = _leaf_boxes(cells)
    mass = _masses(widths, _corner_densities(cells, log_density))
    return mass / mass.sum()


def cell_draws(
    cells: Cells, log_density: np.ndarray, n: int, rng: np.random.Generator
) -> np.ndarray:
    """``n`` independent draws (n, k) from the multilinear interpolant of the posterior
    whose log density (up to a constant) is ``log_density`` at the nodes of ``cells``
    (module docstring)."""
    k = cells.k
    corners = _corner_densities(cells, log_density)
    lower, widths = _leaf_boxes(cells)
    mass = _masses(widths, corners)
    leaf = rng.choice(len(mass), size=n, p=mass / mass.sum())
    within = corners[leaf] / corners[leaf].sum(axis=1, keepdims=True)
    pick = (rng.random(n)[:, None] > np.cumsum(within, axis=1)).sum(axis=1)
    pick = np.minimum(pick, 2**k - 1)  # a cumulative sum a rounding short of 1
    bits = _corner_bits(k)[pick]
    root = np.sqrt(rng.random((n, k)))
    u = np.where(bits == 1.0, root, 1.0 - root)
    return lower[leaf] + u * widths[leaf]


def density_at(cells: Cells, log_density: np.ndarray, thetas: np.ndarray) -> np.ndarray:
    """The posterior's normalized density (the multilinear interpolant's, divided by its
    integral) at ``thetas`` (n, k); 0 outside the cells' box. On a face shared by two
    leaves, the first leaf's value."""
    thetas = np.atleast_2d(np.asarray(thetas, float))
    k = cells.k
    corners = _corner_densities(cells, log_density)
    lower, widths = _leaf_boxes(cells)
    total = float(np.sum(_masses(widths, corners)))
    bits = _corner_bits(k)
    out = np.zeros(len(thetas))
    tol = 1e-12 * np.max(widths)
    for i, theta in enumerate(thetas):
        inside = np.all((theta >= lower - tol) & (theta <= lower + widths + tol), axis=1)
        found = np.flatnonzero(inside)
        if not found.size:
            continue
        j = int(found[0])
        u = np.clip((theta - lower[j]) / widths[j], 0.0, 1.0)
        basis = np.prod(np.where(bits == 1.0, u, 1.0 - u), axis=1)
        out[i] = float(basis @ corners[j]) / total
    return out


def posterior_parts(learner, belief) -> list[tuple[float, Cells, np.ndarray]]:
    """An exact learner's posterior as (weight, cells, log density at their nodes): one a
    correction model for EX-M (weighed by p(m | corrections)), one for EX-C and EX-CL; []
    for any other learner (its belief is its Gaussian)."""
    from corrections_sim.learning.exact.mixture import MixtureState
    from corrections_sim.learning.exact.state import ExactState

    state = belief.state
    if isinstance(state, MixtureState):
        out = []
        for part, weight, b in zip(learner.parts(), state.weights(), state.parts, strict=True):
            exact = ExactState.of(b)
            out.append((float(weight), exact.grid.cells, part.state_log_posterior(exact)))
        return out
    if isinstance(state, ExactState) and state.grid is not None:
        return [(1.0, state.grid.cells, learner.state_log_posterior(state))]
    return []


def mixture_draws(parts, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` draws (n, k) from a posterior given as :func:`posterior_parts`: a part drawn by
    its weight, then a point within its cells."""
    weights = np.array([w for w, _, _ in parts])
    counts = rng.multinomial(n, weights / weights.sum())
    found = [
        cell_draws(cells, log_d, int(c), rng)
        for (_, cells, log_d), c in zip(parts, counts, strict=True)
        if c > 0
    ]
    out = np.concatenate(found)
    return out[rng.permutation(len(out))]


def mixture_density(parts, thetas: np.ndarray) -> np.ndarray:
    """The normalized density at ``thetas`` (n, k) of a posterior given as
    :func:`posterior_parts`: its parts' densities, weighed."""
    total = sum(w for w, _, _ in parts)
    return sum(w / total * density_at(cells, log_d, thetas) for w, cells, log_d in parts)
