"""The person's plans on disk: ξ*(θ*, E) as :meth:`Target.solve <.book.Target.solve>` finds
it (the best of the planner's cold starts, the atlas's answer and the environment's own random
restarts), kept once per machine, as the plan atlas keeps its nodes.

A study's person gets 30 random restarts an environment where it has an atlas (the plans regret
is measured against must be global), about 12 s of CPU for fig. 4's 48 environments; every
command of a study paid them again (13 times in one run of the suite, 156 s). The answer is a
function of what :func:`answer_keys` hashes alone — the planner's build key and every option
that can change an answer, the code that picks the plan and draws the restarts, θ*, the
restarts, the environment and, when the atlas answers too, its key and the version of the code
that answers from it — so reading it back changes no number (tested: the same bits as a fresh
solve).

One ``<key>.npz`` an environment and person under ``cache_dir()/person``
(``$CORRECTIONS_SIM_CACHE/person``), written to a temporary name and renamed; read back only if
the key and the shapes agree, anything else is said (:attr:`TargetStore.rejected`) and solved
again. A read-only store is read as it is.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import os
import tempfile
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from corrections_sim.planning.cache import cache_dir, mark_used
from corrections_sim.planning.planner import Plan, PlannerConfig
from corrections_sim.plans import book
from corrections_sim.plans.atlas import solver_key
from corrections_sim.scene.environments import Environment

if TYPE_CHECKING:
    from corrections_sim.plans.atlas import Atlas

#: Bumped when what a stored plan means changes: older files are never read.
VERSION = 1


def store_root() -> Path:
    """Where the person's plans live: ``cache_dir()/person``."""
    return cache_dir() / "person"


def answer_keys(
    config: PlannerConfig, envs: Sequence[Environment], theta, restarts: int, atlas: Atlas | None
) -> list[str]:
    """What the person's plan in each of ``envs`` depends on (module docstring), hashed; what
    the environments share is hashed once."""
    h = hashlib.sha256()
    h.update(f"person|{VERSION}".encode())
    for part in solver_key(config):
        h.update(b"" if part is None else part.encode())
    for code in (book.Target.solve, book._best_plan, book.own_starts, book.random_starts):
        h.update(inspect.getsource(code).encode())
    h.update(repr((book.RESTART_MODES, book.RESTART_BUMP_STD)).encode())
    h.update(np.asarray(theta, float).tobytes())
    h.update(str(int(restarts)).encode())
    keys = []
    for env in envs:
        each = h.copy()
        each.update(env.key())
        each.update(b"" if atlas is None else atlas.between_key(env).encode())
        keys.append(each.hexdigest()[:24])
    return keys


class TargetStore:
    """The person's plans on disk (module docstring), one file a key."""

    def __init__(self, root: Path | None = None) -> None:
        self.root = Path(root) if root is not None else store_root()
        #: (key, why) of every file found and not trusted.
        self.rejected: list[tuple[str, str]] = []

    def keys(
        self,
        config: PlannerConfig,
        envs: Sequence[Environment],
        theta,
        restarts: int,
        atlas: Atlas | None,
    ) -> list[str]:
        """:func:`answer_keys`'s."""
        return answer_keys(config, envs, theta, restarts, atlas)

    def load(self, key: str, n_waypoints: int, k: int) -> Plan | None:
        """The plan kept under ``key``, or None (none kept, or a file not trusted)."""
        path = self.root / f"{key}.npz"
        if not path.exists():
            return None
        try:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(str(data["meta"]))
                trajectory = np.array(data["trajectory"], float)
                features = np.array(data["features"], float)
            if meta.get("key") != key:
                raise ValueError("another plan's file")
            if trajectory.shape != (n_waypoints, 7) or features.shape != (k,):
                raise ValueError(f"shapes {trajectory.shape}, {features.shape}")
            mark_used(path)
            return Plan(
                trajectory=trajectory,
                features=features,
                reward=float.fromhex(meta["reward"]),
                status=meta["status"],
                iterations=int(meta["iterations"]),
                solve_time=float(meta["solve_time"]),
                starts=int(meta["starts"]),
                solver=meta["solver"],
            )
        except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as exc:
            self.rejected.append((key, str(exc).splitlines()[0] if str(exc) else repr(exc)))
            return None

    def save(self, key: str, plan: Plan) -> None:
        """Keep ``plan`` under ``key`` (atomically); a store that cannot be written is left
        as it is."""
        meta = {
            "key": key,
            "reward": float(plan.reward).hex(),  # to the bit
            "status": plan.status,
            "iterations": int(plan.iterations),
            "solve_time": float(plan.solve_time),
            "starts": int(plan.starts),
            "solver": plan.solver,
        }
        tmp = None
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=self.root, suffix=".npz.tmp")
            with os.fdopen(fd, "wb") as fh:
                np.savez(
                    fh,
                    trajectory=np.ascontiguousarray(plan.trajectory, float),
                    features=np.ascontiguousarray(plan.features, float),
                    meta=np.array(json.dumps(meta)),
                )
            os.replace(tmp, self.root / f"{key}.npz")
        except OSError:
            if tmp is not None:
                Path(tmp).unlink(missing_ok=True)
