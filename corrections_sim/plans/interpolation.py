"""A function of the plan, v(ξ*(θ, E)) — the features a correction would show, say — read
off a plan atlas at any θ: multilinear within a cell of the atlas's grid where that is
accurate, solved where it is not.

A cell is *trusted* when the multilinear interpolant of the values at its 2^k corners is,
at each of its probes — the midpoints of its edges (faces, …) and its centre, the nodes its
children would add — within ``tolerance`` of the value of the plan solved there
(:meth:`Atlas.plans <corrections_sim.plans.atlas.Atlas.plans>`), as the caller's
``measure`` of the difference says. For a value smooth over the cell the multilinear
interpolant's error is −Σᵢ hᵢ² ∂²v/∂θᵢ² / 8 at the centre, each term its own at an edge's
midpoint (the centre alone misses a saddle, where they cancel), and the cross terms it
represents exactly; so the probes' error stands for the cell's (measured on fig. 4's
environments: docs/atlas.md). A cell that fails is cut
into 2^k children half as wide (level ℓ + 1; their new corners solved), down to
``max_level``; a cell that still fails there — a basin boundary runs through it, the plan
jumps — is not interpolated: every θ in it gets its own solve, counted (:attr:`solved`).
Outside the atlas's box, the atlas's own answer (the planner's cold starts).

Which cells are trusted is a property of the cells (their corners and centre are plans at
fixed θ, each a function of (θ, E) alone), never of the order they were asked about, so the
value at θ depends on (θ, E, v) alone, and keeping cells between calls changes no number.
So they are kept on disk too (:class:`CellStore`): each cell checked, with its status, and a
trusted cell's corner values, as shards ``<name>.cells-<checksum>.npz`` beside the atlas, the
name a hash of everything a status depends on (:func:`cell_name`); a process reads them when
it first makes the interpolant, and checks only cells no process of the machine checked.
"""

from __future__ import annotations

import collections
import hashlib
import inspect
import itertools
import sys
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from corrections_sim.planning.features import waypoint_features
from corrections_sim.plans.atlas import Atlas
from corrections_sim.plans.between import read_shards, write_shard
from corrections_sim.scene.environments import Environment

Values = Callable[[np.ndarray], np.ndarray]
"""plans (n, T, 7), NaN where there is none -> their values (n, m), NaN there."""

Measure = Callable[[np.ndarray], np.ndarray]
"""differences of values (..., m) -> their size (...), in the tolerance's units."""

_TRUSTED, _CUT, _SOLVE = 0, 1, 2


def check_tolerance(tolerance) -> float:
    """``tolerance`` as a float, or a one-line ValueError unless it is a finite number > 0."""
    ok = isinstance(tolerance, int | float) and not isinstance(tolerance, bool)
    if not (ok and np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"interpolation tolerance {tolerance!r}: must be a number > 0")
    return float(tolerance)


@dataclass(frozen=True)
class CellStore:
    """Where an interpolant's checked cells live on disk: the folder (the atlas store's), the
    name (:func:`cell_name`), and the list a file found and not trusted is said in, as
    (file name, why)."""

    root: Path
    name: str
    rejected: list[tuple[str, str]] = field(default_factory=list)


def cell_name(atlas: Atlas, env: Environment, *what: object) -> str:
    """The name of E's checked cells of a function v that ``what`` identifies (its code, its
    scale, the tolerance and finest level): a hash of those, E's atlas key, the code of the
    answers between nodes (:func:`~corrections_sim.plans.atlas.answer_version`) and this
    module's, so changed code leaves the old cells unread."""
    h = hashlib.sha256(atlas.between_key(env).encode())
    h.update(inspect.getsource(sys.modules[__name__]).encode())
    h.update(repr(what).encode())
    return f"{atlas.key(env)}-{h.hexdigest()[:16]}"


class CellInterpolant:
    """v(ξ*(θ, E)) at any θ (module docstring).

    Args:
        atlas: the plan atlas (its grid's cells are level 0).
        env: E.
        values: v, a batch of plans -> their values (m,) each.
        measure: the size of a difference of values, in the tolerance's units.
        tolerance: the largest error at a trusted cell's probes.
        max_level: the finest cells, the atlas's spacing / 2^max_level.
        store: where checked cells are kept on disk (None: in this process only); the
            store's name must identify everything above but the atlas and E.
    """

    def __init__(
        self,
        atlas: Atlas,
        env: Environment,
        values: Values,
        measure: Measure,
        *,
        tolerance: float = 0.02,
        max_level: int = 4,
        store: CellStore | None = None,
    ) -> None:
        self.tolerance = check_tolerance(tolerance)
        if isinstance(max_level, bool) or not isinstance(max_level, int) or max_level < 0:
            raise ValueError(f"interpolation max_level {max_level!r}: must be an integer >= 0")
        self.atlas, self.env, self.values, self.measure = atlas, env, values, measure
        self.max_level = max_level
        grid = atlas.grid
        self._lows, self._highs = np.array(grid.lows), np.array(grid.highs)
        self._cells0 = np.array(grid.counts) - 1
        self._step = (self._highs - self._lows) / self._cells0
        self._bits = np.array(list(itertools.product((0, 1), repeat=grid.k)), np.int64)
        # The probes of a cell: the midpoints of its edges, faces, …, and its centre (the
        # nodes its children add), in half widths from its lower corner; and the weights of
        # its corners in the multilinear interpolant there.
        half = np.array(list(itertools.product((0, 1, 2), repeat=grid.k)), np.int64)
        self._probes = half[np.any(half == 1, axis=1)]
        u = self._probes[:, None, :] / 2.0
        self._probe_weights = np.prod(np.where(self._bits[None], u, 1.0 - u), axis=2)
        # A node's coordinates in units of the finest cells' half width: integers.
        self._fine = 2 ** (max_level + 1)
        self._nodes: dict[tuple[int, ...], np.ndarray] = {}
        self._status: dict[tuple[int, ...], int] = {}
        self._corners: dict[tuple[int, ...], np.ndarray] = {}
        #: θ answered by a solve of their own (cells that stay untrusted at the finest level).
        self.solved = 0
        #: Cells checked (their probes against solved plans) in this process.
        self.checked = 0
        self.store = store
        self._unsaved: list[tuple[int, ...]] = []
        if store is not None:
            self._load(store)

    def _corner_coords(self, key: tuple[int, ...]) -> np.ndarray:
        """A cell's corners (2^k, k) in fine coordinates; ``key`` = (level, *lower corner)."""
        width = self._fine // 2 ** key[0]
        return (np.array(key[1:], np.int64) + self._bits) * width

    def _load(self, store: CellStore) -> None:
        """The cells checked and saved by any process (their trusted ones' corner values)."""
        k = len(self._lows)

        def check(a: dict[str, np.ndarray]) -> None:
            cells, status, nodes, values = a["cells"], a["status"], a["nodes"], a["values"]
            if cells.ndim != 2 or cells.shape[1] != k + 1 or status.shape != (len(cells),):
                raise ValueError(f"cells of shape {cells.shape}, statuses {status.shape}")
            if nodes.shape[1:] != (k,) or values.ndim != 2 or len(values) != len(nodes):
                raise ValueError(f"nodes of shape {nodes.shape}, values {values.shape}")
            if not np.isin(status, (_TRUSTED, _CUT, _SOLVE)).all():
                raise ValueError("a cell status that is none of trusted, cut, solve")

        for a in read_shards(store.root, f"{store.name}.cells", store.rejected, check):
            for key, value in zip(map(tuple, a["nodes"].tolist()), a["values"], strict=True):
                self._nodes.setdefault(key, value)
            for key, status in zip(
                map(tuple, a["cells"].tolist()), a["status"].tolist(), strict=True
            ):
                self._status.setdefault(key, int(status))
        for key, status in list(self._status.items()):
            if status == _TRUSTED:
                corners = [tuple(c) for c in self._corner_coords(key).tolist()]
                if all(c in self._nodes for c in corners):
                    self._corners[key] = np.array([self._nodes[c] for c in corners])
                else:  # a shard's cell without its corners: checked again
                    del self._status[key]

    def save(self, at_least: int = 1) -> int:
        """Write the cells checked since the last save as a shard, if at least ``at_least``
        (nothing without a store); how many were written."""
        if self.store is None or len(self._unsaved) < max(1, at_least):
            return 0
        keys, self._unsaved = self._unsaved, []
        trusted = [key for key in keys if self._status[key] == _TRUSTED]
        k, m = len(self._lows), (len(next(iter(self._corners.values()))[0]) if trusted else 0)
        nodes = np.zeros((0, k), np.int64)
        values = np.zeros((0, m))
        if trusted:
            coords = np.concatenate([self._corner_coords(key) for key in trusted])
            nodes, first = np.unique(coords, axis=0, return_index=True)
            values = np.concatenate([self._corners[key] for key in trusted])[first]
        arrays = {
            "cells": np.array(keys, np.int64).reshape(-1, k + 1),
            "status": np.array([self._status[key] for key in keys], np.int8),
            "nodes": nodes,
            "values": values,
        }
        write_shard(self.store.root, f"{self.store.name}.cells", arrays)
        return len(keys)

    def _node_values(self, coords: np.ndarray) -> np.ndarray:
        """The values at nodes given by fine coordinates (n, k) -> (n, m), solving (once)
        the plans of those not seen before."""
        keys = [tuple(c) for c in coords.tolist()]
        new = sorted({key for key in keys if key not in self._nodes})
        if new:
            thetas = self._lows + np.array(new, float) / self._fine * self._step
            found = self.values(self.atlas.plans(thetas, self.env))
            for key, value in zip(new, np.asarray(found, float), strict=True):
                self._nodes[key] = value
        return np.array([self._nodes[key] for key in keys])

    def _statuses(self, level: int, lower: np.ndarray) -> np.ndarray:
        """Each cell's status at ``level`` (lower corners (c, k) in that level's units),
        checking the cells not seen before."""
        keys = [(level, *c) for c in lower.tolist()]
        new = [i for i, key in enumerate(keys) if key not in self._status]
        if new:
            fresh = lower[new]
            width = self._fine // 2**level
            corners = (fresh[:, None, :] + self._bits[None, :, :]) * width  # (c, 2^k, k)
            probes = fresh[:, None, :] * width + self._probes[None, :, :] * (width // 2)
            n, m, k = len(fresh), len(self._bits), fresh.shape[1]
            at = self._node_values(np.concatenate([corners.reshape(-1, k), probes.reshape(-1, k)]))
            corner_values = at[: n * m].reshape(n, m, -1)
            probed = at[n * m :].reshape(n, len(self._probes), -1)
            guessed = np.einsum("qb,cbm->cqm", self._probe_weights, corner_values)
            with np.errstate(invalid="ignore"):
                error = np.max(self.measure(probed - guessed), axis=1)
            good = np.all(np.isfinite(corner_values), axis=(1, 2)) & np.isfinite(error)
            good &= error <= self.tolerance
            self.checked += n
            self._unsaved.extend(keys[i] for i in new)
            for i, ok, values in zip(new, good.tolist(), corner_values, strict=True):
                if ok:
                    self._status[keys[i]] = _TRUSTED
                    self._corners[keys[i]] = values
                else:
                    self._status[keys[i]] = _CUT if level < self.max_level else _SOLVE
        return np.array([self._status[key] for key in keys])

    def __call__(self, thetas: np.ndarray) -> np.ndarray:
        """v(ξ*(θ, E)) at each of ``thetas`` (n, k) -> (n, m), NaN where no plan exists."""
        thetas = np.atleast_2d(np.asarray(thetas, float))
        if not len(thetas):
            T = self.atlas.planner.config.n_waypoints
            return np.asarray(self.values(np.zeros((0, T, 7))), float)
        out: np.ndarray | None = None
        pos = (thetas - self._lows) / self._step
        inside = np.all((thetas >= self._lows) & (thetas <= self._highs), axis=1)
        todo = np.flatnonzero(inside)
        solve = [np.flatnonzero(~inside)]
        for level in range(self.max_level + 1):
            if not todo.size:
                break
            scaled = pos[todo] * 2**level
            lower = np.clip(np.floor(scaled), 0, self._cells0 * 2**level - 1).astype(np.int64)
            cells, inverse = np.unique(lower, axis=0, return_inverse=True)
            inverse = inverse.ravel()
            per_cell = self._statuses(level, cells)
            status = per_cell[inverse]
            trusted = status == _TRUSTED
            if trusted.any():
                m = next(iter(self._corners.values())).shape[1]
                nan = np.full((len(self._bits), m), np.nan)
                table = np.stack(
                    [
                        self._corners[(level, *c)] if s == _TRUSTED else nan
                        for c, s in zip(cells.tolist(), per_cell.tolist(), strict=True)
                    ]
                )
                u = scaled[trusted] - lower[trusted]  # (p, k), in [0, 1]
                bits = self._bits[None, :, :]
                weights = np.prod(np.where(bits, u[:, None, :], 1.0 - u[:, None, :]), axis=2)
                got = np.einsum("pb,pbm->pm", weights, table[inverse[trusted]])
                out = _into(out, len(thetas), todo[trusted], got)
            solve.append(todo[status == _SOLVE])
            todo = todo[status == _CUT]
        exact = np.concatenate(solve)
        if exact.size:
            self.solved += int(exact.size)
            plans = self.atlas.plans(thetas[exact], self.env)
            out = _into(out, len(thetas), exact, np.asarray(self.values(plans), float))
        return out


def _into(out: np.ndarray | None, n: int, where: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` at rows ``where`` of ``out`` ((n, m) of NaN, made on first use)."""
    if out is None:
        out = np.full((n, values.shape[1]), np.nan)
    out[where] = values
    return out


#: Interpolants kept per process: PF-C's hold one an environment, each its nodes' values (8 MB
#: for fig. 4's 2,000 particles from the prior: 9,000 nodes × (T·7 + T·k) floats), so 96 of
#: them, more environments than a study has, stay under 800 MB; past that the least recently
#: used goes, and its cells are checked again (from the plans on disk) when asked.
_MAX_INTERPOLANTS = 96
_KEPT: collections.OrderedDict[Hashable, CellInterpolant] = collections.OrderedDict()


def interpolant(key: Hashable, make: Callable[[], CellInterpolant]) -> CellInterpolant:
    """The interpolant of ``key`` kept in this process (``make()``'s if there is none): the
    same key must mean the same (atlas, E, v, scale, tolerance, max_level), so that keeping it
    changes no number, only what is solved again. The least recently used goes first."""
    found = _KEPT.get(key)
    if found is None:
        found = _KEPT[key] = make()
        while len(_KEPT) > _MAX_INTERPOLANTS:
            _KEPT.popitem(last=False)[1].save()
    else:
        _KEPT.move_to_end(key)
    return found


def save_kept(at_least: int = 1) -> int:
    """Save the cells of every interpolant kept in this process that checked at least
    ``at_least`` since its last save (:meth:`CellInterpolant.save`); how many were written."""
    return sum(found.save(at_least) for found in _KEPT.values())


def waypoint_table(
    atlas: Atlas,
    env: Environment,
    names: tuple[str, ...],
    sd: np.ndarray,
    tolerance: float,
    max_level: int,
) -> CellInterpolant:
    """ξ*(θ, E)'s waypoints and their features, (T·7 + T·k) a θ, read off the atlas
    (:class:`~corrections_sim.plans.interpolation.CellInterpolant`), a cell trusted where
    both the sum over waypoints of the features' error and the largest waypoint's are within
    ``tolerance`` × ``sd`` (the noise's) on every feature: a bound on the error of Φ(ξ*) and
    of Φ(ξ_h) when ξ_h takes one waypoint of ξ* and the others from the robot (n waypoints:
    n × the bound; :meth:`~corrections_sim.people.corrections.CorrectionModel.taken`). It
    depends on the environment alone, not on the correction, so every correction, run and
    learner of this process in E shares it (kept per process: keeping it changes no
    number)."""
    T, k = atlas.planner.config.n_waypoints, len(names)
    params = env.params()

    def values(plans: np.ndarray) -> np.ndarray:
        n = len(plans)
        features = np.full((n, T, k), np.nan)
        finite = np.all(np.isfinite(plans), axis=(1, 2))
        if finite.any():
            flat = waypoint_features(plans[finite].reshape(-1, 7), params, names)
            features[finite] = flat.reshape(-1, T, k)
        return np.concatenate([plans.reshape(n, -1), features.reshape(n, -1)], axis=1)

    def measure(differences: np.ndarray) -> np.ndarray:
        features = differences[..., T * 7 :].reshape(*differences.shape[:-1], T, k)
        worst = np.maximum(np.abs(features.sum(axis=-2)), np.abs(features).max(axis=-2))
        return np.max(worst / sd, axis=-1)

    key = ("waypoints", atlas.key(env), names, sd.tobytes(), tolerance, max_level)

    def make() -> CellInterpolant:
        store = None
        if atlas.store is not None:  # the cells any process of the machine checked
            what = (inspect.getsource(waypoint_table), *key[2:])
            name = cell_name(atlas, env, *what)
            store = CellStore(atlas.store.root, name, atlas.store.rejected)
        return CellInterpolant(
            atlas, env, values, measure, tolerance=tolerance, max_level=max_level, store=store
        )

    return interpolant(key, make)
