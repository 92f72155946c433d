"""The exact family's part of a belief: its posterior on the grid's nodes, the past it
weighs again at a new node and, for EX-CL, N's prior (:class:`ExactState`). Plain values.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import FamilyState, frozen
from corrections_sim.learning.exact.cells import Cells
from corrections_sim.learning.history import HistoryEntry, checked
from corrections_sim.learning.kalman.state import NoisePosterior, check_noise, noise_columns


@dataclass(frozen=True, eq=False)
class GridPosterior:
    """An exact learner's posterior over θ on the nodes of a grid (its plan atlas's): the
    belief's θ̂ and P are its moments.

    Attributes:
        thetas: the nodes (n, k).
        log_density: the unnormalized log posterior at each node (n,), −inf where it is
            impossible; with N learnt, the log prior only (the corrections are in
            ``scatter``).
        scatter: with N learnt, Σᵢ rᵢ rᵢᵀ at each node (n, k, k), rᵢ = zᵢ − hᵢ(θ); else None.
        count: corrections taken in.
        cells: the nodes as cells (:class:`~corrections_sim.learning.exact.cells.Cells`;
            their trapezoid weights integrate the density), or None: every node weighs the
            same.
        left: what each correction left at each node when the corrections are not summed
            into ``scatter`` (EX-M judging relevance, :mod:`.relevance`): (n, t, k + 1), its
            residual rᵢ and the cosine of its move against the predicted one; else None.
        known: how many of the ``count`` corrections each node's ``log_density`` and
            ``scatter`` hold (n,), or None: all. A node with fewer holds an upper bound of its
            log posterior, left so because that bound is more than
            :data:`~corrections_sim.learning.exact.bayes.LAZY_MARGIN` below the peak
            (:func:`~corrections_sim.learning.exact.bayes.pending_needed`).
    """

    thetas: np.ndarray
    log_density: np.ndarray
    scatter: np.ndarray | None = None
    count: int = 0
    cells: Cells | None = None
    known: np.ndarray | None = None
    left: np.ndarray | None = None

    def __post_init__(self) -> None:
        thetas = np.array(self.thetas, dtype=float, copy=True)
        log_d = np.array(self.log_density, dtype=float, copy=True)
        if thetas.ndim != 2 or log_d.shape != (thetas.shape[0],) or np.any(np.isnan(log_d)):
            raise ValueError(
                f"GridPosterior: expected nodes (n, k) and n log densities without NaN, got "
                f"{thetas.shape} and {log_d.shape}"
            )
        if not np.any(np.isfinite(log_d)):
            raise ValueError("GridPosterior.log_density: every node is impossible")
        object.__setattr__(self, "thetas", frozen(thetas))
        object.__setattr__(self, "log_density", frozen(log_d))
        if self.scatter is not None:
            scatter = np.array(self.scatter, dtype=float, copy=True)
            k = thetas.shape[1]
            if scatter.shape != (thetas.shape[0], k, k):
                raise ValueError(f"GridPosterior.scatter: expected (n, k, k), got {scatter.shape}")
            object.__setattr__(self, "scatter", frozen(scatter))
        if self.left is not None:
            left = np.array(self.left, dtype=float, copy=True)
            if left.ndim != 3 or left.shape[:2] != (thetas.shape[0], self.count):
                raise ValueError(
                    f"GridPosterior.left: expected (n, t, k + 1) for {thetas.shape[0]} nodes and "
                    f"{self.count} corrections, got {left.shape}"
                )
            object.__setattr__(self, "left", frozen(left))
        if self.known is not None:
            known = np.array(self.known, dtype=np.int64, copy=True)
            if known.shape != log_d.shape or np.any((known < 0) | (known > self.count)):
                raise ValueError(
                    f"GridPosterior.known: expected {log_d.shape[0]} counts in [0, "
                    f"{self.count}], got shape {known.shape}"
                )
            object.__setattr__(self, "known", frozen(known))
        if self.cells is not None and len(self.cells.coords) != thetas.shape[0]:
            raise ValueError(
                f"GridPosterior.cells: {len(self.cells.coords)} nodes for {thetas.shape[0]} θ"
            )

    def memo(self, key, make: Callable[[], np.ndarray]) -> np.ndarray:
        """``make()``, a read-only value that depends on this grid alone (and on ``key``, which
        names it with whatever else it depends on), computed once and kept with the grid: a
        grid is never changed, so its log-determinants and noise marginals, asked for several
        times by an update and again by the next, are the same bits each time. Not pickled."""
        cache = self.__dict__.setdefault("_memo", {})
        if key not in cache:
            cache[key] = frozen(make())
        return cache[key]

    def made_from(self, parent: GridPosterior) -> GridPosterior:
        """This grid, noted as made from ``parent`` (the same first nodes, some of them with
        a new scatter, new nodes after them): a memo may take ``parent``'s values at the nodes
        whose scatter is unchanged (:meth:`parent_memo`), whether it kept them before or after
        this call. Returns this grid."""
        self.__dict__["_parent"] = (parent.scatter, parent.__dict__.setdefault("_memo", {}))
        return self

    def parent_memo(self, key) -> tuple[np.ndarray, np.ndarray] | None:
        """(the scatter, the memo under ``key``) of the grid this one was made from
        (:meth:`made_from`), or None: not made from one, or that one never computed it."""
        scatter, memo = self.__dict__.get("_parent", (None, {}))
        return None if key not in memo else (scatter, memo[key])

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state.pop("_memo", None)
        state.pop("_parent", None)
        return state

    def counts(self) -> np.ndarray:
        """How many corrections each node holds (n,) (:attr:`known`, or ``count`` for all)."""
        if self.known is None:
            return np.full(len(self.log_density), self.count, np.int64)
        return np.array(self.known)

    def pending(self) -> np.ndarray:
        """The nodes (n,) some of whose corrections are not weighed yet."""
        return self.counts() < self.count


@dataclass(frozen=True, eq=False)
class ExactState(FamilyState):
    """EX-C's and EX-CL's own state: the grid posterior (None before the first correction),
    the prior and every correction (what a refined cell weighs again) and, for EX-CL, the
    inverse-Wishart prior over N it integrates N out under (None for EX-C: N is known).
    Its N̂ is that prior's, as the run started."""

    noise: NoisePosterior | None = None
    grid: GridPosterior | None = None
    history: tuple[HistoryEntry, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "history", checked(self.history, "ExactState.history"))

    def check(self, k: int) -> None:
        check_noise(self.noise, k, "ExactState.noise")
        if self.grid is not None and self.grid.thetas.shape[1] != k:
            raise ValueError(
                f"ExactState.grid: nodes over {self.grid.thetas.shape[1]} weights, expected {k}"
            )

    def columns(self) -> dict[str, float]:
        return noise_columns(self.noise)

    def noise_estimate(self) -> np.ndarray | None:
        return None if self.noise is None else self.noise.estimate()
