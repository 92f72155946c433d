"""A plan atlas: ξ*(θ, E) solved on a grid of θ per environment, once, and global at its
nodes — so that a plan can start from the atlas instead of from whatever a run solved before.

The grid (:class:`AtlasGrid`) spans a box of θ with n_i points per weight, nodes in C order.
For one environment, :func:`build` solves every node by continuation from cold starts:

1. **seeds**: the planner's cold starts at every ``cold_stride``-th node per axis;
2. **continuation**: every plan that improves a node (a higher reward θ·Φ − λS) is offered,
   warm, to each of the node's grid neighbours, first in first out, until no node improves.
   So each node is offered the plan of every basin that reaches it from any seed, and keeps
   the best; the order depends on the grid alone, never on what a run solved before.

A node no start converges at keeps NaN (and reward −inf). :func:`cell_starts` gives the
warm starts of an off-grid θ: the plans at the corners of its cell, best first by their
reward *at θ* (linear in θ, so no solve is needed to rank them).

Pure: plain values in and out. The cache on disk (:class:`AtlasStore`) keeps one file per
(planner build, solver options, environment, grid) under the compile cache, written atomically
and checked on reading: a truncated, corrupt or foreign file is rebuilt, never trusted.
"""

from __future__ import annotations

import collections
import functools
import hashlib
import inspect
import itertools
import json
import math
import os
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from corrections_sim.planning import newton
from corrections_sim.planning.cache import mark_used
from corrections_sim.planning.planner import (
    Plan,
    Planner,
    PlannerConfig,
    PlanningError,
    build_key,
    cache_dir,
    smoothness_cost,
)
from corrections_sim.plans.between import BetweenNodes, PlanShards, row_keys
from corrections_sim.scene.environments import Environment

#: Bumped when the build's algorithm changes: older atlases are rebuilt, never read.
ALGORITHM = 1


@functools.cache
def answer_version() -> str:
    """What an answer between the nodes depends on beyond the atlas's key, hashed: the source
    of the code that makes it (:meth:`Atlas.solve`, the corners' ranking
    :func:`iter_cell_starts`, the cell's arithmetic) and Newton's warm re-solve (``newton.py``
    and ``newton.c``); plans kept between nodes are named by it, so changed code leaves them
    unread, and other edits to this module (how plans are looked up, kept or documented) do
    not. Computed once a process."""
    h = hashlib.sha256()
    for code in (Atlas.solve, iter_cell_starts, AtlasGrid.contains, AtlasGrid.cell):
        h.update(inspect.getsource(code).encode())
    for path in (Path(newton.__file__), Path(newton.__file__).with_suffix(".c")):
        h.update(path.read_bytes())
    return h.hexdigest()[:12]


@dataclass(frozen=True)
class AtlasGrid:
    """A box of θ with ``counts[i]`` evenly spaced values of weight i from ``lows[i]`` to
    ``highs[i]`` (both included); nodes in C order (the last weight fastest).

    Raises:
        ValueError: in one line, for fewer than 3 points on an axis, an empty or non-finite
            box, or lengths that differ.
    """

    lows: tuple[float, ...]
    highs: tuple[float, ...]
    counts: tuple[int, ...]

    def __post_init__(self) -> None:
        lows = tuple(float(v) for v in self.lows)
        highs = tuple(float(v) for v in self.highs)
        counts = tuple(self.counts)
        if not len(lows) == len(highs) == len(counts) >= 1:
            raise ValueError("atlas grid: lows, highs and counts need one entry per weight")
        for i, (lo, hi, n) in enumerate(zip(lows, highs, counts, strict=True)):
            if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 3:
                raise ValueError(f"atlas grid: axis {i} needs an integer >= 3 points, got {n!r}")
            if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                raise ValueError(f"atlas grid: axis {i} needs finite low < high, got {lo}, {hi}")
        object.__setattr__(self, "lows", lows)
        object.__setattr__(self, "highs", highs)
        object.__setattr__(self, "counts", tuple(int(n) for n in counts))

    @classmethod
    def around(
        cls, mean: Sequence[float], sd: Sequence[float], *, width: float = 5.0, count: int = 31
    ) -> AtlasGrid:
        """mean ± ``width`` sd on every axis, ``count`` points each (a study's prior box)."""
        mean, sd = np.asarray(mean, float), np.asarray(sd, float)
        if not np.all(sd > 0):
            raise ValueError(f"atlas grid: every prior sd must be > 0, got {sd.tolist()}")
        return cls(tuple(mean - width * sd), tuple(mean + width * sd), (count,) * len(mean))

    @property
    def k(self) -> int:
        return len(self.counts)

    @property
    def size(self) -> int:
        return int(np.prod(self.counts))

    def axes(self) -> list[np.ndarray]:
        return [
            np.linspace(lo, hi, n)
            for lo, hi, n in zip(self.lows, self.highs, self.counts, strict=True)
        ]

    def thetas(self) -> np.ndarray:
        """Every node's θ (size, k), C order."""
        mesh = np.meshgrid(*self.axes(), indexing="ij")
        return np.stack([m.ravel() for m in mesh], axis=1)

    def contains(self, theta: Sequence[float]) -> bool:
        t = np.asarray(theta, float).tolist()
        return len(t) == self.k and all(
            lo <= x <= hi for x, lo, hi in zip(t, self.lows, self.highs, strict=True)
        )

    def require(self, theta: Sequence[float], what: str = "the prior mean") -> None:
        """Refuse, in one line, a box that does not contain ``theta``."""
        if not self.contains(theta):
            box = ", ".join(
                f"[{lo:g}, {hi:g}]" for lo, hi in zip(self.lows, self.highs, strict=True)
            )
            raise ValueError(f"atlas grid {box} does not contain {what} {list(theta)}")

    def cell(self, theta: Sequence[float]) -> list[int]:
        """The node indices of the corners of θ's cell (2^k, deduplicated; θ inside the box).
        Plain Python arithmetic: an off-grid plan asks for it once a solve."""
        lower, strides, stride = [], [], 1
        for x, lo, hi, n in zip(
            np.asarray(theta, float).tolist(), self.lows, self.highs, self.counts, strict=True
        ):
            pos = (x - lo) / (hi - lo) * (n - 1)
            lower.append(min(max(math.floor(pos), 0), n - 2))
        for n in reversed(self.counts):  # C order: the last weight fastest
            strides.insert(0, stride)
            stride *= n
        corners = {
            sum((i + d) * s for i, d, s in zip(lower, bits, strides, strict=True))
            for bits in itertools.product((0, 1), repeat=self.k)
        }
        return sorted(corners)

    def neighbours(self) -> list[list[int]]:
        """Per node, its 2k axis neighbours (fewer at the box's faces)."""
        out = []
        for node in range(self.size):
            at = np.unravel_index(node, self.counts)
            mine = []
            for axis in range(self.k):
                for step in (-1, 1):
                    j = list(at)
                    j[axis] += step
                    if 0 <= j[axis] < self.counts[axis]:
                        mine.append(int(np.ravel_multi_index(tuple(j), self.counts)))
            out.append(mine)
        return out


@dataclass(frozen=True)
class EnvironmentAtlas:
    """The atlas of one environment: the best plan found at every node.

    Attributes:
        grid: the nodes.
        trajectories: (size, T, 7), NaN where no start converged.
        features: Φ (size, k), NaN there.
        smoothness: S(ξ) (size,), NaN there.
        rewards: θ·Φ − λS at the node (size,), −inf there.
        solves: planner calls the build took (warm and cold).
    """

    grid: AtlasGrid
    trajectories: np.ndarray
    features: np.ndarray
    smoothness: np.ndarray
    rewards: np.ndarray
    solves: int

    @property
    def found(self) -> np.ndarray:
        return np.isfinite(self.rewards)


def build(
    planner: Planner,
    env: Environment,
    grid: AtlasGrid,
    *,
    cold_stride: int = 10,
) -> EnvironmentAtlas:
    """Solve every node of ``grid`` in ``env`` (module docstring): the planner's cold starts
    on a lattice of every ``cold_stride``-th node per axis, then continuation: each plan
    that improves a node is offered, warm, to each of its grid neighbours, until no node
    improves (first in, first out, so the answer depends on nothing but the grid); each
    node keeps its best."""
    if grid.k != planner.config.k:
        raise ValueError(f"atlas grid has {grid.k} weights, the planner {planner.config.k}")
    if isinstance(cold_stride, bool) or not isinstance(cold_stride, int) or cold_stride < 1:
        raise ValueError(f"cold_stride = {cold_stride!r} must be an integer >= 1")
    thetas = grid.thetas()
    n, T = grid.size, planner.config.n_waypoints
    trajectories = np.full((n, T, 7), np.nan)
    features = np.full((n, grid.k), np.nan)
    smooth = np.full(n, np.nan)
    rewards = np.full(n, -np.inf)
    solves = 0

    def offer(node: int, inits) -> bool:
        """Solve ``node`` from ``inits`` (None: the cold starts); keep it if better."""
        nonlocal solves
        solves += 1
        try:
            plan = planner.solve(thetas[node], env, inits=inits)
        except PlanningError:
            return False
        if plan.reward > rewards[node] + 1e-9 * max(1.0, abs(plan.reward)):
            rewards[node] = plan.reward
            trajectories[node] = plan.trajectory
            features[node] = plan.features
            smooth[node] = smoothness_cost(plan.trajectory)
            return True
        return False

    lattice = np.ones(grid.counts, bool)
    for axis, count in enumerate(grid.counts):
        keep = np.zeros(count, bool)
        keep[::cold_stride] = True
        keep[-1] = True
        shape = [1] * grid.k
        shape[axis] = count
        lattice &= keep.reshape(shape)
    neighbours = grid.neighbours()
    queue: collections.deque[int] = collections.deque()
    queued = np.zeros(n, bool)

    def improve(node: int, inits) -> None:
        """Offer ``node`` a start; if its plan improves, its neighbours get offered it."""
        if offer(node, inits) and not queued[node]:
            queue.append(node)
            queued[node] = True

    def propagate() -> None:
        while queue:
            node = queue.popleft()
            queued[node] = False
            plan = trajectories[node].copy()
            # Every neighbour, the one this plan came from included: re-solved there from
            # another start, it can land in a better basin (not offering it back saved 26% of
            # the solves and left a node 0.06% below the planner's own cold starts).
            for other in neighbours[node]:
                improve(other, [plan])

    for node in np.flatnonzero(lattice.ravel()).tolist():
        improve(node, None)
    propagate()
    for node in np.flatnonzero(~np.isfinite(rewards)).tolist():  # never reached: cold, once
        if not np.isfinite(rewards[node]):
            improve(node, None)
            propagate()
    return EnvironmentAtlas(grid, trajectories, features, smooth, rewards, solves)


def cell_starts(atlas: EnvironmentAtlas, theta: Sequence[float], smoothness: float) -> list:
    """The warm starts of θ from its cell: the corner plans (T, 7) that exist, distinct, best
    first by their reward at θ (θ·Φ − λS: linear in θ, no solve). Empty outside the box."""
    return list(iter_cell_starts(atlas, theta, smoothness))


def iter_cell_starts(
    atlas: EnvironmentAtlas, theta: Sequence[float], smoothness: float
) -> Iterator[np.ndarray]:
    """:func:`cell_starts` one at a time (a caller that needs only the first pays for no
    comparison of the others)."""
    t = np.asarray(theta, float)
    if not atlas.grid.contains(t):
        return
    corners = [c for c in atlas.grid.cell(t) if atlas.found[c]]
    value = {c: float(t @ atlas.features[c] - smoothness * atlas.smoothness[c]) for c in corners}
    out: list[np.ndarray] = []
    for c in sorted(corners, key=lambda c: (-value[c], c)):
        plan = atlas.trajectories[c]
        if not any(np.allclose(plan, o, atol=1e-4) for o in out):
            out.append(plan)
            yield plan


# --- the cache on disk ------------------------------------------------------------------


def solver_key(config: PlannerConfig) -> tuple[str, str, str | None]:
    """What ``config``'s answers depend on beyond the problem, for every key of stored answers:
    (the build key, the options as JSON but the clearance certificate — it skips only checks
    whose answer it proves —, the Newton code's key when warm starts take its steps, or None)."""
    config = replace(config, certificate=True)
    shaping = {**asdict(config), "features": list(config.features)}
    ipopt = replace(config, solver="ipopt")
    warm = newton.library_key(build_key(ipopt)) if config.warm == "newton" else None
    return build_key(config), json.dumps(shaping, sort_keys=True, default=str), warm


def atlas_key(config: PlannerConfig, env: Environment | None, grid: AtlasGrid, **options) -> str:
    """What an atlas depends on: :func:`solver_key`, the environment (None: an atlas's identity,
    the key of all but the environment), the grid, the build's options, :data:`ALGORITHM`."""
    build, shaping, warm = solver_key(config)
    h = hashlib.sha256()
    h.update(build.encode())
    h.update(shaping.encode())
    h.update(b"" if env is None else env.key())
    h.update(json.dumps(asdict(grid), sort_keys=True).encode())
    h.update(json.dumps(options, sort_keys=True).encode())
    h.update(str(ALGORITHM).encode())
    h.update(b"" if warm is None else warm.encode())  # the build's warm solves: Newton's steps
    return h.hexdigest()[:24]


class AtlasStore:
    """Atlases on disk, one ``<key>.npy`` (trajectories, memory-mapped when read) and one
    ``<key>.json`` (the grid, the rewards, and the .npy's SHA-256) per atlas, under
    ``cache_dir()/atlas`` by default. Written atomically (the JSON last, so a reader that
    finds it finds the whole .npy); read back only if the key, the shape and the checksum
    agree — anything else is reported (:attr:`rejected`) and rebuilt."""

    def __init__(self, root: Path | None = None) -> None:
        self.root = Path(root) if root is not None else cache_dir() / "atlas"
        #: (key, why) of every file found and not trusted.
        self.rejected: list[tuple[str, str]] = []
        #: The plans between the atlases' nodes, beside them (their rejections said above).
        self.shards = PlanShards(self.root, self.rejected)

    def load(self, key: str, grid: AtlasGrid, T: int) -> EnvironmentAtlas | None:
        meta_path, data_path = self.root / f"{key}.json", self.root / f"{key}.npy"
        if not meta_path.exists():
            return None
        try:
            meta = json.loads(meta_path.read_text())
            if meta.get("key") != key or AtlasGrid(**meta["grid"]) != grid:
                raise ValueError("another atlas's file")
            digest = hashlib.sha256(data_path.read_bytes()).hexdigest()
            if digest != meta["sha256"]:
                raise ValueError("its data does not match its checksum (truncated or changed)")
            trajectories = np.load(data_path, mmap_mode="r")
            if trajectories.shape != (grid.size, T, 7):
                raise ValueError(f"shape {trajectories.shape}, expected {(grid.size, T, 7)}")
            mark_used(meta_path, data_path)
            return EnvironmentAtlas(
                grid,
                trajectories,
                np.asarray(meta["features"], float).reshape(grid.size, grid.k),
                np.asarray(meta["smoothness"], float),
                np.asarray(meta["rewards"], float),
                int(meta["solves"]),
            )
        except (OSError, ValueError, KeyError, TypeError) as exc:
            self.rejected.append((key, str(exc).splitlines()[0]))
            return None

    def save(self, key: str, atlas: EnvironmentAtlas) -> Path:
        self.root.mkdir(parents=True, exist_ok=True)
        data_path = self.root / f"{key}.npy"
        fd, tmp = tempfile.mkstemp(dir=self.root, suffix=".npy.tmp")
        with os.fdopen(fd, "wb") as fh:
            np.save(fh, np.ascontiguousarray(atlas.trajectories, float))
        digest = hashlib.sha256(Path(tmp).read_bytes()).hexdigest()
        os.replace(tmp, data_path)
        meta = {
            "key": key,
            "grid": asdict(atlas.grid),
            "sha256": digest,
            # NaN and −inf as JSON null / strings would lose the type: keep them as text.
            "features": [_num(v) for v in atlas.features.ravel()],
            "smoothness": [_num(v) for v in atlas.smoothness],
            "rewards": [_num(v) for v in atlas.rewards],
            "solves": atlas.solves,
        }
        fd, tmp = tempfile.mkstemp(dir=self.root, suffix=".json.tmp")
        with os.fdopen(fd, "w") as fh:
            json.dump(meta, fh)
        os.replace(tmp, self.root / f"{key}.json")
        return data_path


def _num(v: float) -> float | str:
    return float(v) if np.isfinite(v) else str(float(v))


# --- plans as a function of (θ, E) ---------------------------------------------------------


#: Plans between nodes :meth:`Atlas.plans` must solve (or has solved and not handed on)
#: before it asks its peer (a round trip costs a few solves).
PEER_BATCH = 8


class Atlas:
    """One planner's atlas over one grid, environment by environment: read from the store,
    or built there on first use (:meth:`environment`), or ahead, in parallel
    (:func:`~corrections_sim.plans.spread.prepare`).

    :meth:`solve` answers ξ*(θ, E) from the atlas alone, so the answer depends on (θ, E) and
    never on what was asked before: inside the box, warm from the plan at the corner of θ's
    cell whose reward at θ is highest (:func:`cell_starts`; the next corner if that solve
    fails, the planner's cold starts if every corner's does); outside it, the cold starts
    (counted in :attr:`outside`). Measured
    (200 problems, θ ~ U[−2, 2]², fig. 4's 48 environments, 31 × 31 over [−5, 5]²): the best
    corner alone is within 1% of 30 random restarts on 100% (worst 0.49%, 0.64 ms a
    problem); every corner, best kept, 100% (worst 0.19%, 4 solves); the nearest node's
    plan, 100% (worst 0.81%); the planner's cold starts, 97.5% (worst 215%, 16.6 ms).

    Args:
        planner: the planner (its configuration is part of every key).
        grid: the nodes.
        store: where atlases live (None: memory only, built per process).
        cold_stride: the build's cold-start lattice (:func:`build`).
    """

    def __init__(
        self,
        planner: Planner,
        grid: AtlasGrid,
        *,
        store: AtlasStore | None = None,
        cold_stride: int = 10,
    ) -> None:
        if grid.k != planner.config.k:
            raise ValueError(f"atlas grid has {grid.k} weights, the planner {planner.config.k}")
        self.planner = planner
        self.grid = grid
        self.store = store
        self.cold_stride = cold_stride
        self._atlases: dict[bytes, EnvironmentAtlas] = {}
        self._between = BetweenNodes(
            None if store is None else store.shards, planner.config.n_waypoints, grid.k
        )
        self._env_keys: dict[bytes, str] = {}
        self._envs: dict[bytes, Environment] = {}
        #: Environments whose atlas this process built (not read, not handed to it).
        self.built = 0
        #: Problems answered outside the box (the planner's cold starts).
        self.outside = 0
        #: Other processes' plans between nodes (a cluster's exchange, ``take(atlas)`` and
        #: ``give(atlas)``), consulted when :meth:`plans` has many to solve; None: none.
        self.peer = None

    def key(self, env: Environment) -> str:
        found = self._env_keys.get(env.key())
        if found is None:
            found = atlas_key(self.planner.config, env, self.grid, cold_stride=self.cold_stride)
            self._env_keys[env.key()] = found
            self._envs[env.key()] = env
        return found

    def between_key(self, env: Environment) -> str:
        """The name of E's answers between nodes on disk: its key and :func:`answer_version`."""
        return f"{self.key(env)}-{answer_version()}"

    def hold(self, env: Environment, built: EnvironmentAtlas) -> None:
        """Keep E's atlas built elsewhere (e.g. by a benchmark's pool) for this process."""
        if built.grid != self.grid:
            raise ValueError("Atlas.hold: an atlas over another grid")
        self._atlases[env.key()] = built

    def holds(self, env: Environment) -> bool:
        """Whether this process holds E's atlas already (read, built or handed to it)."""
        return env.key() in self._atlases

    def environment(self, env: Environment) -> EnvironmentAtlas:
        """E's atlas: in memory, else from the store, else built (and stored)."""
        found = self._atlases.get(env.key())
        if found is None:
            key = self.key(env)
            found = None
            if self.store is not None:
                found = self.store.load(key, self.grid, self.planner.config.n_waypoints)
            if found is None:
                found = build(self.planner, env, self.grid, cold_stride=self.cold_stride)
                self.built += 1
                if self.store is not None:
                    self.store.save(key, found)
            self._atlases[env.key()] = found
        return found

    def read(self, env: Environment) -> int:
        """E's atlas and the plans between its nodes kept on disk, read into this process
        now rather than at the first ask (a page server's first submits otherwise wait for
        them); how many plans between nodes it holds."""
        self.environment(env)
        return len(self._between.known(env.key(), self.between_key(env)))

    def solve(self, theta: Sequence[float], env: Environment) -> Plan:
        """ξ*(θ, E) from the atlas (class docstring); PlanningError if no start converges."""
        t = np.asarray(theta, float)
        if not self.grid.contains(t):
            self.outside += 1
            return self.planner.solve(t, env)
        starts = iter_cell_starts(self.environment(env), t, self.planner.config.smoothness)
        for start in starts:  # the corner best at θ first; the next only if it fails
            try:
                return self.planner.solve(t, env, inits=[start])
            except PlanningError:
                continue
        return self.planner.solve(t, env)  # no corner's plan converged: the cold starts

    def plans(self, thetas: np.ndarray, env: Environment) -> np.ndarray:
        """ξ*(θ, E) at many θ (n, k) as trajectories (n, T, 7), NaN where no start converges:
        a node's stored plan where θ is one of the grid's nodes, else :meth:`solve`'s answer,
        kept for this process and, once :meth:`save`d, for every later process on the machine
        (the answer depends on (θ, E) alone, so keeping it changes no number: it spares a
        refined grid's nodes and a particle learner's cells a second solve)."""
        thetas = np.atleast_2d(np.asarray(thetas, float))
        grid, built = self.grid, self.environment(env)
        out = np.full((len(thetas), self.planner.config.n_waypoints, 7), np.nan)
        lows, highs = np.array(grid.lows), np.array(grid.highs)
        pos = (thetas - lows) / (highs - lows) * (np.array(grid.counts) - 1)
        index = np.rint(pos)
        on = np.all(np.abs(pos - index) < 1e-9, axis=1) & np.all(
            (index >= 0) & (index <= np.array(grid.counts) - 1), axis=1
        )
        if on.any():
            nodes = np.ravel_multi_index(tuple(index[on].astype(int).T), grid.counts)
            out[on] = built.trajectories[nodes]
        known = self._between.known(env.key(), self.between_key(env))
        off = np.flatnonzero(~on)
        memos = row_keys(thetas[off])  # θ.tobytes() of each, in one array step
        rows = known.rows(memos)
        absent = np.flatnonzero(rows < 0)
        missing = off[absent].tolist()
        # With a peer, in chunks: before each, what others solved meanwhile; after, ours.
        chunk = PEER_BATCH * 4 if self.peer is not None else max(len(missing), 1)
        for start in range(0, len(missing), chunk):
            todo = missing[start : start + chunk]
            if self.peer is not None and len(todo) >= PEER_BATCH:
                self.peer.take(self)
            for i, memo in zip(todo, row_keys(thetas[todo]), strict=True):
                if memo in known:  # asked twice, or taken from the peer
                    continue
                try:
                    plan = self.solve(thetas[i], env).trajectory
                except PlanningError:
                    plan = None
                known.add(memo, plan)
                self._between.added(env.key(), memo)
            if self.peer is not None and self._between.pending() >= PEER_BATCH:
                self.peer.give(self)
        if absent.size:  # now solved (or taken from the peer)
            rows[absent] = known.rows([memos[j] for j in absent.tolist()])
        if len(off):
            out[off] = known.take(rows)  # NaN where no start converged
        return out

    def save(self, at_least: int = 1) -> int:
        """Store the plans between nodes solved here (or received, :meth:`merge`) and not yet
        saved, of every environment with at least ``at_least``, for the next process of the
        machine; how many."""
        return self._between.save(at_least)

    @property
    def solved_between(self) -> int:
        """Plans between nodes this process solved (not read from disk, not received)."""
        return self._between.solved

    def outgoing(self) -> list[tuple[Environment, str, np.ndarray, np.ndarray]]:
        """The plans between nodes solved here since the last call, for processes that share
        no files with this one (:class:`~corrections_sim.plans.spread.PlanExchange`): per
        environment (E, the name of its plans on disk, θ (n, k), trajectories (n, T, 7))."""
        return [
            (self._envs[env_key], name, thetas, plans)
            for env_key, name, thetas, plans in self._between.outgoing()
        ]

    def merge(
        self, env: Environment, name: str, thetas: np.ndarray, plans: np.ndarray, save: bool = True
    ) -> int:
        """Plans between nodes another process solved (:meth:`outgoing`'s items), kept here
        and (``save``) saved with this process's own; how many were new. Plans named for
        another atlas or other code than this process's (``name`` is not its
        :meth:`between_key` of E) are refused: a plan is the answer of the atlas and the code
        it came from."""
        if name != self.between_key(env):
            raise ValueError(f"plans named {name}: not this process's atlas of {env.name}")
        return self._between.merge(env.key(), name, thetas, plans, save)
