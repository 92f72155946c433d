"""The cells of a grid over θ, refined where needed: what an exact learner's posterior
(:class:`~corrections_sim.learning.exact.state.GridPosterior`) integrates over, and the
moments of the density that is multilinear in each of them (:func:`cell_moments`). Plain
values, no planning."""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Cells:
    """The cells of a grid over θ, refined where needed: a box cut into ``counts[i] − 1``
    cells a weight (level 0, corners at a plan atlas's nodes), each of which may be halved
    along every axis (2^k children) or along some (:meth:`cut`'s ``axes``); a cell's level
    along an axis is how often it was halved there, down to ``depth``. Integrals over θ are
    the trapezoid rule's on every leaf cell (its volume times the mean of its 2^k corners),
    so a node weighs :attr:`coefficients` (the volumes / 2^k of the leaves it is a corner
    of); a node shared by cells of several levels is one node.

    Attributes:
        lows, highs, counts: the box and its nodes a weight at level 0.
        depth: the finest level allowed.
        coords: every node's position in units of the finest spacing (n, k), level 0's nodes
            first in C order, every refinement's new nodes after them (sorted): a node keeps
            its index when cells are cut.
        leaves: the leaf cells (m, 2k): their level along each axis, then their lower
            corner's coords.
    """

    lows: tuple[float, ...]
    highs: tuple[float, ...]
    counts: tuple[int, ...]
    depth: int
    coords: np.ndarray
    leaves: np.ndarray

    @classmethod
    def base(cls, lows, highs, counts, depth: int) -> Cells:
        """Level 0: every node of the box's grid, every cell a leaf."""
        counts = tuple(int(n) for n in counts)
        k = len(counts)
        index = np.stack(
            np.meshgrid(*[np.arange(n) for n in counts], indexing="ij"), axis=-1
        ).reshape(-1, k)
        lower = index[np.all(index < np.array(counts) - 1, axis=1)]
        leaves = np.concatenate([np.zeros((len(lower), k), np.int64), lower * 2**depth], axis=1)
        return cls(
            tuple(float(v) for v in lows),
            tuple(float(v) for v in highs),
            counts,
            int(depth),
            index.astype(np.int64) * 2**depth,
            leaves.astype(np.int64),
        )

    @property
    def k(self) -> int:
        return len(self.counts)

    @property
    def levels(self) -> np.ndarray:
        """Each leaf's level along each axis (m, k)."""
        return self.leaves[:, : self.k]

    def unit(self) -> np.ndarray:
        """The finest spacing (k,): level 0's / 2^depth."""
        span = np.array(self.highs) - np.array(self.lows)
        return span / ((np.array(self.counts) - 1) * 2.0**self.depth)

    def spacing(self, level: int) -> np.ndarray:
        """A level's cell widths (k,)."""
        return self.unit() * 2 ** (self.depth - level)

    def thetas(self) -> np.ndarray:
        """Every node's θ (n, k)."""
        return np.array(self.lows) + self.coords * self.unit()

    def _keys(self, coords: np.ndarray) -> np.ndarray:
        shape = tuple((np.array(self.counts) - 1) * 2**self.depth + 1)
        return np.ravel_multi_index(tuple(np.asarray(coords).T), shape)

    @functools.cached_property
    def corners(self) -> np.ndarray:
        """Each leaf's corner nodes (m, 2^k), as indices into :attr:`coords` (computed once,
        read-only)."""
        keys = self._keys(self.coords)
        order = np.argsort(keys)
        width = 2 ** (self.depth - self.levels)
        out = []
        for bits in itertools.product((0, 1), repeat=self.k):
            at = self.leaves[:, self.k :] + width * np.array(bits)
            out.append(order[np.searchsorted(keys, self._keys(at), sorter=order)])
        corners = np.stack(out, axis=1)
        corners.setflags(write=False)
        return corners

    @functools.cached_property
    def coefficients(self) -> np.ndarray:
        """Each node's trapezoid weight (n,): the volumes / 2^k of the leaves it is a
        corner of (computed once, read-only)."""
        # Widths are powers of two, so the product is exact in any order.
        volume = np.prod(self.unit()) * np.prod(2.0 ** (self.depth - self.levels), axis=1)
        out = np.zeros(len(self.coords))
        for column in self.corners.T:
            np.add.at(out, column, volume / 2**self.k)
        out.setflags(write=False)
        return out

    def cut(self, which: np.ndarray, axes: np.ndarray | None = None) -> Cells:
        """The leaves ``which`` (m,) bool halved along ``axes`` (k,) bool (None: every axis,
        2^k children each); their new corner nodes appended to :attr:`coords` (sorted), the
        old keeping their indices."""
        which = np.asarray(which, bool)
        halve = np.ones(self.k, bool) if axes is None else np.asarray(axes, bool)
        if halve.shape != (self.k,) or not halve.any():
            raise ValueError(f"Cells.cut: axes must name at least one of {self.k} axes")
        chosen = self.leaves[which]
        levels, lower = chosen[:, : self.k], chosen[:, self.k :]
        if np.any(levels[:, halve] >= self.depth):
            raise ValueError(f"Cells.cut: a leaf is already at the finest level {self.depth}")
        half = 2 ** (self.depth - levels - halve)  # a halved axis's new width, else the width
        children, nodes = [], []
        for bits in itertools.product((0, 1), repeat=self.k):
            if all(h or not b for h, b in zip(halve, bits, strict=True)):
                children.append(np.concatenate([levels + halve, lower + half * bits], axis=1))
        for bits in itertools.product((0, 1, 2), repeat=self.k):
            if all(h or b != 1 for h, b in zip(halve, bits, strict=True)):
                step = np.where(halve, bits, np.array(bits) // 2)  # an unhalved axis: 0, 1
                nodes.append(lower + half * step)
        candidates = np.unique(np.concatenate(nodes), axis=0)
        known = np.isin(self._keys(candidates), self._keys(self.coords))
        coords = np.concatenate([self.coords, candidates[~known]])
        leaves = np.concatenate([self.leaves[~which], *children])
        return Cells(self.lows, self.highs, self.counts, self.depth, coords, leaves)


def corner_bits(k: int) -> np.ndarray:
    """The corners' offsets in the order of :attr:`Cells.corners` (2^k, k)."""
    return np.array(list(itertools.product((0, 1), repeat=k)), dtype=float)


def leaf_boxes(cells: Cells) -> tuple[np.ndarray, np.ndarray]:
    """Each leaf's lower corner θ (m, k) and widths (m, k)."""
    k = cells.k
    unit = cells.unit()
    lower = np.array(cells.lows) + cells.leaves[:, k:] * unit
    widths = unit * 2.0 ** (cells.depth - cells.levels)
    return lower, widths


def corner_densities(cells: Cells, log_density: np.ndarray) -> np.ndarray:
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


#: E[u] and Var[u] of a corner's factor g on the unit interval: 2u (its bit 1) has mean 2/3,
#: 2(1 − u) (bit 0) mean 1/3; both variance 1/18.
_FACTOR_VARIANCE = 1.0 / 18.0


def cell_moments(
    cells: Cells, log_density: np.ndarray, about: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The mean (k,) and the second moment about ``about`` (k, k) of the density multilinear
    in every leaf cell that interpolates ``log_density`` at the nodes of ``cells`` (what
    :func:`~corrections_sim.learning.exact.draws.cell_draws` draws from; its covariance where
    ``about`` is None, or is that mean), in closed form: a leaf's corner b weighs its mass
    share, and within it θ = lower + width ⊙ u, the uᵢ independent with mean 1/3 or 2/3 and
    variance 1/18 each, so E[(θ − a)(θ − a)ᵀ] = Σ p_{leaf, b} (e eᵀ + diag(width² / 18)),
    e = its mean − a.

    Where every node's neighbours sit alike, the mean is the trapezoid rule's (the learner's
    θ̂); the second moment is the trapezoid's point masses' plus what the density spreads
    within the cells, width² / 6 along an axis for a mass on one node: what the cells cannot
    resolve, which the nodes' moments leave out."""
    k = cells.k
    corners = corner_densities(cells, log_density)
    lower, widths = leaf_boxes(cells)
    share = np.prod(widths, axis=1)[:, None] * corners / 2**k  # (m, 2^k)
    share = share / share.sum()
    offsets = (1.0 + corner_bits(k)) / 3.0  # E[u] at each corner (2^k, k)
    means = lower[:, None, :] + widths[:, None, :] * offsets[None, :, :]  # (m, 2^k, k)
    mean = np.einsum("mb,mbi->i", share, means)
    centre = mean if about is None else np.asarray(about, float)
    e = means - centre
    second = np.einsum("mb,mbi,mbj->ij", share, e, e)
    within = _FACTOR_VARIANCE * np.einsum("mb,mi->i", share, widths**2)
    return mean, second + np.diag(within)
