"""A plan atlas beyond one process: :class:`AtlasSpec`, the atlas as plain picklable data a
worker rebuilds it from; :func:`prepare`, the atlases a study lacks built ahead on an executor
(each handed back, so the process that asked keeps it in its own store too); and
:func:`carried` / :func:`receive`, the atlases handed to workers that may share no files with
it (a Dask cluster's), so that each is built once in all (docs/atlas.md, "On a Dask cluster").

The executor is the caller's; nothing here decides where work runs.
"""

from __future__ import annotations

import functools
import uuid
import warnings
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from corrections_sim.planning.planner import PlannerConfig
from corrections_sim.plans.atlas import Atlas, AtlasGrid, AtlasStore, EnvironmentAtlas, atlas_key
from corrections_sim.scene.environments import Environment


@dataclass(frozen=True)
class AtlasSpec:
    """What makes an atlas, as plain picklable data (a worker process rebuilds the atlas from
    it, :meth:`atlas`): the planner's configuration, the grid, the build's cold-start stride
    and the store's folder (None: the compile cache's)."""

    config: PlannerConfig
    grid: AtlasGrid
    cold_stride: int = 10
    root: str | None = None

    def store(self) -> AtlasStore:
        return AtlasStore(None if self.root is None else Path(self.root))

    def key(self, env: Environment | None) -> str:
        return atlas_key(self.config, env, self.grid, cold_stride=self.cold_stride)

    def missing(
        self, envs: Iterable[Environment], store: AtlasStore | None = None
    ) -> list[Environment]:
        """The distinct environments of ``envs`` whose atlas the store lacks (or holds a file
        of it cannot trust: ``store.rejected`` says which and why)."""
        store = store if store is not None else self.store()
        out, seen = [], set()
        for env in envs:
            if env.key() not in seen:
                seen.add(env.key())
                if store.load(self.key(env), self.grid, self.config.n_waypoints) is None:
                    out.append(env)
        return out

    def atlas(self) -> Atlas:
        """This process's atlas of the spec (one per process and store, so its memory maps
        are shared by every run the process executes; a process pointed at another cache
        meanwhile gets that cache's atlas, not one that writes to the first)."""
        root = self.root if self.root is not None else str(AtlasStore(None).root)
        return _shared_atlas(replace(self, root=root))


@functools.cache
def _shared_atlas(spec: AtlasSpec) -> Atlas:
    from corrections_sim.planning.planner import shared_planner

    planner = shared_planner(spec.config)
    return Atlas(planner, spec.grid, store=spec.store(), cold_stride=spec.cold_stride)


def prepare(
    spec: AtlasSpec,
    envs: Sequence[Environment],
    executor: Executor | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> int:
    """Build into the store the atlases of ``envs`` it lacks (or holds only rejected files
    of), one task an environment on ``executor`` (None: here); ``progress(done, total)``
    after each. Each task hands its atlas back, and this process keeps it in its own store
    too (a worker of a cluster may not share this machine's files). Returns how many were
    built."""
    store = spec.store()
    todo = spec.missing(envs, store)
    for key, why in store.rejected:  # rebuilt below, never read
        warnings.warn(f"plan atlas {key}: not trusted, built again: {why}", stacklevel=2)
    if progress is not None and todo:
        progress(0, len(todo))
    if executor is None:
        done = (_build_into_store(spec, env) for env in todo)
    else:
        done = (f.result() for f in [executor.submit(_build_into_store, spec, e) for e in todo])
    for i, (env, built) in enumerate(zip(todo, done, strict=True)):
        _keep(spec, store, env, built)
        if progress is not None:
            progress(i + 1, len(todo))
    return len(todo)


def _build_into_store(spec: AtlasSpec, env: Environment) -> EnvironmentAtlas:
    """E's atlas into the store (this process's copy if it holds one, else built), and
    back to the caller as plain arrays."""
    built = spec.atlas().environment(env)
    _keep(spec, spec.store(), env, built)
    return _plain(built)


def _keep(spec: AtlasSpec, store: AtlasStore, env: Environment, built: EnvironmentAtlas) -> None:
    """``built`` into ``store`` unless it holds E's atlas already."""
    if store.load(spec.key(env), spec.grid, spec.config.n_waypoints) is None:
        store.save(spec.key(env), built)


def _plain(built: EnvironmentAtlas) -> EnvironmentAtlas:
    """An atlas with its trajectories in memory (not a map of this machine's file)."""
    return replace(built, trajectories=np.array(built.trajectories))


@dataclass(frozen=True)
class Carried:
    """Atlases handed to a worker that may not share this machine's files (a Dask cluster's):
    (environment, atlas) pairs, the atlases in memory."""

    atlases: tuple[tuple[Environment, EnvironmentAtlas], ...]


def ready(
    spec: AtlasSpec | None,
    envs: Sequence[Environment],
    executor: Executor,
    progress: Callable[[int, int], None] | None = None,
) -> Carried | None:
    """Before a command's runs: the atlases of ``envs`` its store lacks built, one task an
    environment on ``executor`` (:func:`prepare`), so that no two runs build one at once; on an
    executor whose workers may not share this machine's files (one with ``share``: a
    cluster), the handle of the atlases handed to each worker (:func:`receive` them there),
    else None. Nothing without an atlas."""
    if spec is None:
        return None
    prepare(spec, envs, executor, progress)
    share = getattr(executor, "share", None)
    return None if share is None else share(carried(spec, envs))


def carried(spec: AtlasSpec, envs: Sequence[Environment]) -> Carried:
    """The atlases of ``envs`` from this process's store (after :func:`prepare`), to hand to
    workers (:func:`receive`)."""
    mine = spec.atlas()
    distinct = {env.key(): env for env in envs}
    return Carried(tuple((env, _plain(mine.environment(env))) for env in distinct.values()))


def receive(spec: AtlasSpec, handed: Carried) -> None:
    """In a worker: hold each atlas of ``handed`` for this process (so it builds none of them)
    and keep it in this machine's store if the store lacks it."""
    mine, store = spec.atlas(), spec.store()
    for env, built in handed.atlases:
        if not mine.holds(env):
            mine.hold(env, built)
            _keep(spec, store, env, built)


class PlanExchange:
    """The plans between an atlas's nodes that a cluster's workers solved, for the others:
    plain state, held on the cluster as one object that every worker calls (a Dask actor:
    the executor makes it, ``executor.exchange()``, and the runner hands it to each run). A
    worker hands on what it solved (:meth:`add`) and takes what others added since it last
    asked (:meth:`since`); a plan depends on (θ, E) alone, so taking one changes no number,
    only who solves it."""

    def __init__(self, shared_files: bool = False) -> None:
        self._items: list[tuple[Environment, str, np.ndarray, np.ndarray]] = []
        self._identity = uuid.uuid4().hex
        self._shared_files = shared_files

    def identity(self) -> str:
        """A name of this exchange, the same through every handle on it."""
        return self._identity

    def shared_files(self) -> bool:
        """Whether its processes share one store (a process pool's): then what one takes is
        on disk already, saved by the one that solved it, and is not saved again."""
        return self._shared_files

    def add(self, items: list[tuple[Environment, str, np.ndarray, np.ndarray]]) -> int:
        """Keep ``items`` (:meth:`Atlas.outgoing`'s); how many the exchange holds."""
        self._items.extend(items)
        return len(self._items)

    def since(self, cursor: int) -> tuple[list, int]:
        """The items added after the first ``cursor``, and the cursor after them."""
        return self._items[cursor:], len(self._items)


class Peer:
    """This process's side of a :class:`PlanExchange` (a handle on it), as an atlas's
    :attr:`~corrections_sim.plans.atlas.Atlas.peer`: it takes what other processes added
    since it last asked and gives what this one solved. An exchange that cannot be reached
    is left alone (the plans are then solved here, the same bits), said once a process."""

    def __init__(self, exchange) -> None:
        self.exchange = exchange
        self.identity = _call(exchange.identity())
        self.keep = not _call(exchange.shared_files())
        self.cursor = 0
        #: Plans taken from others that were new here, and plans given.
        self.taken = 0
        self.given = 0

    def take(self, atlas: Atlas) -> int:
        """Others' plans since the last call, kept by ``atlas``; how many were new."""
        try:
            items, self.cursor = _call(self.exchange.since(self.cursor))
        except Exception as exc:  # noqa: BLE001 -- any failure to reach it: solve here
            _unreachable(exc)
            return 0
        new = 0
        for env, name, thetas, plans in items:
            try:
                new += atlas.merge(env, name, thetas, plans, save=self.keep)
            except ValueError:  # another atlas's or other code's plans: not ours to use
                continue
        self.taken += new
        return new

    def give(self, atlas: Atlas) -> int:
        """The plans ``atlas`` solved since the last call, to the exchange; how many."""
        items = atlas.outgoing()
        if not items:
            return 0
        try:
            _call(self.exchange.add(items))
        except Exception as exc:  # noqa: BLE001 -- the others then solve these themselves
            _unreachable(exc)
            return 0
        n = sum(len(thetas) for _, _, thetas, _ in items)
        self.given += n
        return n


def connect(spec: AtlasSpec, exchange) -> Peer | None:
    """In a worker: this process's atlas of ``spec`` takes and gives plans between nodes
    through ``exchange`` (kept across the runs of one exchange, replaced by another's); None
    when the exchange cannot be reached (said once a process)."""
    atlas = spec.atlas()
    try:
        identity = _call(exchange.identity())
    except Exception as exc:  # noqa: BLE001 -- any failure to reach it: solve here
        _unreachable(exc)
        return None
    if atlas.peer is None or atlas.peer.identity != identity:
        atlas.peer = Peer(exchange)
    atlas.peer.take(atlas)
    return atlas.peer


def keep_all(spec: AtlasSpec, exchange) -> int:
    """In the command's process, after the runs: every plan of ``exchange`` this process's
    store lacks, saved there; how many. Nothing when its workers shared this store (a pool's:
    each saved its own) or the exchange cannot be reached."""
    try:
        if _call(exchange.shared_files()):
            return 0
    except Exception as exc:  # noqa: BLE001 -- nothing to keep then
        _unreachable(exc)
        return 0
    if connect(spec, exchange) is None:
        return 0
    kept = spec.atlas().save()
    disconnect(spec)  # the command is done with it; its handle must not outlive it here
    return kept


def exchange_for(spec: AtlasSpec | None, executor):
    """The executor's plan exchange for a command's runs (``executor.exchange()``: a pool's
    or a cluster's), None without an atlas or an executor that offers none."""
    make = getattr(executor, "exchange", None)
    return make() if spec is not None and make is not None else None


def attach(spec: AtlasSpec | None, exchange) -> None:
    """At a run's start in a worker: its atlas asks ``exchange`` (:func:`connect`), or none
    (:func:`disconnect`: not an earlier command's); nothing without an atlas."""
    if spec is None:
        return
    if exchange is not None:
        connect(spec, exchange)
    else:
        disconnect(spec)


def disconnect(spec: AtlasSpec) -> None:
    """This process's atlas of ``spec`` asks no exchange any more (one of a finished command
    may be gone: asking it would only be said and skipped)."""
    spec.atlas().peer = None


def flush(spec: AtlasSpec) -> int:
    """Give the exchange whatever this process's atlas solved and has not given yet."""
    atlas = spec.atlas()
    return 0 if atlas.peer is None else atlas.peer.give(atlas)


def _call(value):
    """A remote call's answer (an actor's method returns a future), or a local one's."""
    return value.result() if hasattr(value, "result") else value


_said: list[str] = []


def _unreachable(exc: Exception) -> None:
    if not _said:
        _said.append(str(exc))
        warnings.warn(
            f"plan exchange unreachable, plans between nodes solved here: {exc}", stacklevel=3
        )
