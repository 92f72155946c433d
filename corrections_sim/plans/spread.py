"""A plan atlas beyond one process: :class:`AtlasSpec`, the atlas as plain picklable data a
worker rebuilds it from; :func:`prepare`, the atlases a study lacks built ahead on an executor
(each handed back, so the process that asked keeps it in its own store too); and
:func:`carried` / :func:`receive`, the atlases handed to workers that may share no files with
it (a Dask cluster's), so that each is built once in all (docs/atlas.md, "On a Dask cluster").

The executor is the caller's; nothing here decides where work runs.
"""

from __future__ import annotations

import functools
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
        """This process's atlas of the spec (one per process, so its memory maps are shared
        by every run the process executes)."""
        return _shared_atlas(self)


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
