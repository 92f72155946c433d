"""Draws from an exact learner's posterior, within its cells (not at its nodes), and its
density anywhere: what simulation-based calibration ranks the truth among
(:mod:`corrections_sim.figures.sbc`). Plain values in and out; no planning.

An exact learner's posterior is known at its cells' nodes; its integrals are the trapezoid
rule's on every leaf cell (:class:`~corrections_sim.learning.exact.cells.Cells`), which is
the integral of the density interpolated multilinearly from the leaf's 2^k corners. That
interpolant is the density these draws come from. Its mean is the learner's θ̂ where every
node's neighbours sit alike; its spread is the learner's P with ``spread = "cells"``, and
wider than the nodes' P (``spread = "nodes"``) by what the cells cannot resolve
(:func:`~corrections_sim.learning.exact.cells.cell_moments`). The draws:

* a leaf is drawn with probability its mass, its volume times the mean of its corners;
* within it, the multilinear density is a mixture over its corners b, weighed by their
  densities, of product densities Πᵢ gᵢ(uᵢ), g(u) = 2u where bᵢ = 1 and 2(1 − u) where
  bᵢ = 0 (each integrates to 2^−k on the unit cell): a corner is drawn, then each uᵢ
  (√U or 1 − √U), exactly.
"""

from __future__ import annotations

import numpy as np

from corrections_sim.learning.exact.cells import (
    Cells,
    corner_bits,
    corner_densities,
    leaf_boxes,
)


def _masses(widths: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Each leaf's unnormalized mass (m,): its volume times the mean of its corners."""
    return np.prod(widths, axis=1) * corners.mean(axis=1)


def leaf_masses(cells: Cells, log_density: np.ndarray) -> np.ndarray:
    """Each leaf's share of the posterior's mass (m,), summing to 1."""
    _, widths = leaf_boxes(cells)
    mass = _masses(widths, corner_densities(cells, log_density))
    return mass / mass.sum()


def cell_draws(
    cells: Cells, log_density: np.ndarray, n: int, rng: np.random.Generator
) -> np.ndarray:
    """``n`` independent draws (n, k) from the multilinear interpolant of the posterior
    whose log density (up to a constant) is ``log_density`` at the nodes of ``cells``
    (module docstring)."""
    k = cells.k
    corners = corner_densities(cells, log_density)
    lower, widths = leaf_boxes(cells)
    mass = _masses(widths, corners)
    leaf = rng.choice(len(mass), size=n, p=mass / mass.sum())
    within = corners[leaf] / corners[leaf].sum(axis=1, keepdims=True)
    pick = (rng.random(n)[:, None] > np.cumsum(within, axis=1)).sum(axis=1)
    pick = np.minimum(pick, 2**k - 1)  # a cumulative sum a rounding short of 1
    bits = corner_bits(k)[pick]
    root = np.sqrt(rng.random((n, k)))
    u = np.where(bits == 1.0, root, 1.0 - root)
    return lower[leaf] + u * widths[leaf]


def density_at(cells: Cells, log_density: np.ndarray, thetas: np.ndarray) -> np.ndarray:
    """The posterior's normalized density (the multilinear interpolant's, divided by its
    integral) at ``thetas`` (n, k); 0 outside the cells' box. On a face shared by two
    leaves, the first leaf's value."""
    thetas = np.atleast_2d(np.asarray(thetas, float))
    k = cells.k
    corners = corner_densities(cells, log_density)
    lower, widths = leaf_boxes(cells)
    total = float(np.sum(_masses(widths, corners)))
    bits = corner_bits(k)
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
