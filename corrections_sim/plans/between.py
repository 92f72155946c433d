"""The plans of a plan atlas between its nodes — the exact learners' finer cells, the reference
tool's, a particle learner's interpolation cells — kept so that a machine solves each once.

Every such plan is :meth:`Atlas.solve <corrections_sim.plans.atlas.Atlas.solve>`'s answer,
a function of (θ, E) alone, so keeping it changes no number. :class:`BetweenNodes` keeps them
per process (θ's bytes -> the trajectory, None where no start converged), and
:class:`PlanShards` on disk, beside the atlas's own files: one shard
``<atlas key>-<answer version>.extra-<checksum>.npz`` per save (the version hashes the code
the answer comes from, :func:`~corrections_sim.plans.atlas.answer_version`), written
atomically; shards only add up (two
workers that solved the same θ wrote the same plan), and one whose bytes do not match its
checksum is skipped and said, its plans solved again. A large shard's trajectories are mapped
from its file, not copied into the process (:data:`MAP_AT`, :func:`read_shards`' ``mapped``):
a machine's store can hold far more plans than a process could keep in memory (millions,
gigabytes), and a process reads the pages of the ones it looks up.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import os
import struct
import tempfile
import zipfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

from corrections_sim.planning.cache import mark_used

#: Plans between nodes kept in a process's own memory (0.67 kB each at T = 12: 670 MB at
#: most; past it, the unsaved ones are saved, all are dropped, and they are read again from
#: disk when asked). The shards' plans, mapped from their files, do not count: the page cache
#: holds them.
MAX_KEPT = 1_000_000
#: A shard of at least this many bytes has its mapped arrays mapped (:func:`read_shards`); a
#: smaller one is copied. A map holds a file descriptor open, so an environment's many small
#: shards (a run's new plans each, until :data:`COMPACT_AT` merges them) are copied, and a
#: process holds a few maps an environment (at most 4 on a store of 4.7 million plans).
MAP_AT = 1 << 20
#: A process that reads at least this many shards of one atlas merges them into one shard
#: (its plans once each) and removes the ones merged: a store that many runs added to stays a
#: few files an atlas (fig. 4's had up to 174, read at 0.3 s an environment).
COMPACT_AT = 16


def write_shard(root: Path, prefix: str, arrays: dict[str, np.ndarray]) -> Path:
    """``arrays`` as ``<prefix>-<sha256[:16]>.npz`` in ``root``, named by its checksum,
    written to a temporary name and renamed."""
    root.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=root, suffix=".npz.tmp")
    with os.fdopen(fd, "wb") as fh:
        np.savez(fh, **arrays)
    digest = hashlib.sha256(Path(tmp).read_bytes()).hexdigest()[:16]
    path = root / f"{prefix}-{digest}.npz"
    os.replace(tmp, path)
    return path


def read_shards(
    root: Path,
    prefix: str,
    rejected: list[tuple[str, str]],
    check: Callable[[dict[str, np.ndarray]], None],
    read: list[Path] | None = None,
    mapped: tuple[str, ...] = (),
) -> Iterator[dict[str, np.ndarray]]:
    """The arrays of every shard ``<prefix>-*.npz`` in ``root`` (:func:`write_shard`), each
    marked as used (and its path appended to ``read``); one whose bytes do not match its
    name's checksum, that lacks an array or that ``check`` refuses (ValueError) is appended
    to ``rejected`` as (name, why) and skipped. One gone since the folder was listed was
    merged into another by a process that read it (:meth:`PlanShards.blocks`), which wrote the
    merged shard first: the folder is listed again and the shards not yet read are read.

    The arrays named in ``mapped`` of a shard of :data:`MAP_AT` bytes or more are read-only
    maps of the file's bytes (:func:`_mapped`), the others copies: the checksum was checked
    over the whole file first, so a mapped array holds the bytes it was written with (a shard
    is never written in place: a new one is renamed over nothing, and one merged away stays
    readable while mapped)."""
    seen: set[str] = set()
    gone = True
    while gone:
        gone = False
        for path in sorted(root.glob(f"{prefix}-*.npz")):
            if path.name in seen:
                continue
            seen.add(path.name)
            try:
                digest = path.name[len(prefix) + 1 : -len(".npz")]
                with path.open("rb") as fh:
                    found = hashlib.file_digest(fh, "sha256").hexdigest()[:16]
                if found != digest:
                    raise ValueError("its data does not match its checksum (truncated or changed)")
                large = path.stat().st_size >= MAP_AT
                with np.load(path) as data:
                    arrays = {
                        name: _mapped(path, name) if large and name in mapped else data[name]
                        for name in data.files
                    }
                check(arrays)
            except FileNotFoundError:
                gone = True
                continue
            except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
                rejected.append((path.name, str(exc).splitlines()[0]))
                continue
            mark_used(path)
            if read is not None:
                read.append(path)
            yield arrays


def _mapped(path: Path, name: str) -> np.ndarray:
    """The array ``name`` of the ``.npz`` at ``path`` as a read-only map of the file's bytes
    (``np.savez`` stores its members uncompressed, each an ``.npy`` file's bytes); a copy
    where the member is compressed."""
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo(f"{name}.npy")
    if info.compress_type != zipfile.ZIP_STORED:
        with np.load(path) as data:
            return data[name]
    with path.open("rb") as fh:
        fh.seek(info.header_offset)
        header = fh.read(30)  # the member's local header: its name and extra field follow
        if header[:4] != b"PK\x03\x04":
            raise ValueError(f"{name}: no local header where the archive says")
        name_length, extra_length = struct.unpack("<HH", header[26:30])
        fh.seek(info.header_offset + 30 + name_length + extra_length)
        version = np.lib.format.read_magic(fh)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(fh)
        else:
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(fh)
        offset = fh.tell()
    if dtype.hasobject:
        raise ValueError(f"{name}: an array of objects")
    if offset + dtype.itemsize * int(np.prod(shape)) > path.stat().st_size:
        raise ValueError(f"{name}: the file ends inside the array")
    if int(np.prod(shape)) == 0:
        return np.zeros(shape, dtype)
    order = "F" if fortran else "C"
    return np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=shape, order=order)


class PlanShards:
    """The plans between an atlas's nodes on disk, in ``root``; files found and not trusted
    are appended to ``rejected`` as (name, why)."""

    def __init__(self, root: Path, rejected: list[tuple[str, str]] | None = None) -> None:
        self.root = Path(root)
        self.rejected = rejected if rejected is not None else []

    def load(self, key: str, T: int, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Every plan kept for the atlas ``key``: θ (n, k) and trajectories (n, T, 7), NaN
        where no start converged, in this process's memory (:meth:`blocks`, joined)."""
        found = self.blocks(key, T, k)
        thetas = [np.zeros((0, k))] + [t for t, _ in found]
        plans = [np.zeros((0, T, 7))] + [np.asarray(p, float) for _, p in found]
        return np.concatenate(thetas), np.concatenate(plans)

    def blocks(self, key: str, T: int, k: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """Every plan kept for the atlas ``key``, a block a shard: θ (n, k) and trajectories
        (n, T, 7) (NaN where no start converged), a ``np.memmap`` of the shard's file where it
        is mapped (:func:`read_shards`), else in memory; a shard whose content does not
        match its checksum, or of another shape, is reported (:attr:`rejected`) and skipped.
        Having read :data:`COMPACT_AT` shards or more, it writes their plans (once each) as
        one shard, removes them (not on a read-only store) and gives that one block, in
        memory; a plan is a function of (θ, E) alone, so nothing is lost however processes
        interleave."""

        def check(arrays: dict[str, np.ndarray]) -> None:
            t, p = arrays["thetas"], arrays["plans"]
            if t.shape[1:] != (k,) or p.shape != (len(t), T, 7):
                raise ValueError(f"shapes {t.shape}, {p.shape}")

        found, read = [], []
        prefix = f"{key}.extra"
        for arrays in read_shards(self.root, prefix, self.rejected, check, read, ("plans",)):
            found.append((arrays["thetas"], arrays["plans"]))
        if len(read) < COMPACT_AT:
            return found
        every = np.concatenate([t for t, _ in found])
        every, trajectories = distinct(every, np.concatenate([p for _, p in found]))
        with contextlib.suppress(OSError):  # a read-only store is read as it is
            merged = self.save(key, every, trajectories)
            for path in read:
                if path != merged:
                    path.unlink(missing_ok=True)
        return [(every, trajectories)]

    def save(self, key: str, thetas: np.ndarray, plans: np.ndarray) -> Path:
        """Plans of the atlas ``key`` (θ (n, k), trajectories (n, T, 7)) as a shard of their
        own (:func:`write_shard`)."""
        arrays = {"thetas": np.asarray(thetas, float), "plans": np.asarray(plans, float)}
        return write_shard(self.root, f"{key}.extra", arrays)


def distinct(thetas: np.ndarray, plans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Plans as stored (θ (n, k), trajectories (n, T, 7)) with each θ once (by its bytes,
    so 0.0 and −0.0 stay apart as a lookup tells them apart), first found first."""
    rows = np.ascontiguousarray(thetas, float)
    _, first = np.unique(_row_items(rows), return_index=True)
    first.sort()
    return rows[first], plans[first]


#: A :class:`PlanTable` of more blocks (a plan exchange's takes add one each) copies all but
#: its first (the shards as read, the largest) into one, so a lookup visits a few.
MAX_BLOCKS = 8


class PlanTable(Mapping):
    """One environment's plans between nodes, as a read-only mapping θ's bytes -> trajectory
    (T, 7), None where no start converged (a NaN row), kept as rows of a few arrays (the
    shards as read, then a growing block for what is added) so that many are looked up and
    taken in one array step (:meth:`rows`, :meth:`take`). A θ kept twice keeps its first
    plan (a plan depends on (θ, E) alone: the two are the same)."""

    def __init__(self, T: int):
        self.T = T
        self._index: dict[bytes, int] = {}
        self._blocks: list[tuple[int, np.ndarray]] = []  # (first row, rows), in row order
        self._rows = 0  # rows stored (a θ repeated in a block keeps its row, unpointed)
        self._tail: np.ndarray | None = None  # the last block's room, when it grows row by row
        self._mapped = False  # whether a block is mapped from a shard's file (unchecked rows)
        self._frozen = 0  # the blocks up to the last mapped one, never merged (nor copied)

    def __len__(self) -> int:
        return len(self._index)

    def __iter__(self) -> Iterator[bytes]:
        return iter(self._index)

    def __contains__(self, memo: object) -> bool:
        return memo in self._index

    def __getitem__(self, memo: bytes) -> np.ndarray | None:
        plan = self.take([self._index[memo]])[0]
        return plan if np.isfinite(plan).all() else None

    def rows(self, memos: Sequence[bytes]) -> np.ndarray:
        """The row of each θ (its bytes), −1 where none is kept."""
        n = len(memos)
        return np.fromiter(map(self._index.get, memos, itertools.repeat(-1, n)), np.int64, n)

    def take(self, rows: Sequence[int] | np.ndarray) -> np.ndarray:
        """The trajectories at ``rows`` (:meth:`rows`'s), (n, T, 7), NaN where no start
        converged (a row with a NaN is no plan, as :meth:`add_many` keeps it)."""
        rows = np.asarray(rows, np.int64)
        out = np.empty((len(rows), self.T, 7))
        for start, block in self._blocks:
            inside = (rows >= start) & (rows < start + len(block))
            if inside.all():
                out = np.asarray(block[rows - start], float)
                break
            if inside.any():
                out[inside] = block[rows[inside] - start]
        if self._mapped:  # a shard's rows were not looked at when mapped: whole or absent
            out[~np.isfinite(out).all(axis=(1, 2))] = np.nan
        return out

    def add(self, memo: bytes, plan: np.ndarray | None) -> bool:
        """Keep ``plan`` (None: no start converged) at θ (its bytes); whether it was new."""
        if memo in self._index:
            return False
        if self._tail is None:  # a block of its own after every kept row
            self._tail = np.empty((64, self.T, 7))
            self._blocks.append((self._rows, self._tail[:0]))
        start = self._blocks[-1][0]
        used = self._rows - start
        if used == len(self._tail):  # full: twice the room, the rows kept
            grown = np.empty((2 * used, self.T, 7))
            grown[:used] = self._tail
            self._tail = grown
        self._tail[used] = np.nan if plan is None else plan
        self._blocks[-1] = (start, self._tail[: used + 1])  # only the rows in use
        self._index[memo] = self._rows
        self._rows += 1
        return True

    def add_many(
        self, memos: Sequence[bytes], plans: np.ndarray, *, mapped: bool = False
    ) -> list[bytes]:
        """Keep each of ``plans`` (n, T, 7; NaN where no start converged) at its θ (its
        bytes) where none is kept yet, as one block; those that were new, in order.
        ``mapped``: ``plans`` are a shard's, mapped from its file (:meth:`PlanShards.blocks`),
        kept as they are (not read now, not copied, never merged with another block)."""
        if not mapped:
            plans = np.asarray(plans, float)
        if len(plans) != len(memos):
            raise ValueError(f"{len(memos)} thetas for {len(plans)} plans")
        if plans.shape[1:] != (self.T, 7):
            raise ValueError(f"plans of shape {plans.shape}, expected (n, {self.T}, 7)")
        if not mapped:
            finite = np.isfinite(plans)
            partial = ~finite.all(axis=(1, 2)) & finite.any(axis=(1, 2))
            if partial.any():  # a plan is whole or absent: a row with a NaN is no plan
                plans = np.array(plans)
                plans[partial] = np.nan
        index, new = self._index, []
        for row, memo in enumerate(memos, start=self._rows):
            if memo not in index:
                index[memo] = row
                new.append(memo)
        if new:
            self._blocks.append((self._rows, plans))
            self._rows += len(plans)
            self._tail = None
            if mapped:
                self._mapped, self._frozen = True, len(self._blocks)
            elif len(self._blocks) - self._frozen > MAX_BLOCKS:  # the later, smaller ones as one
                second = self._frozen + 1
                first, later = self._blocks[second][0], [b for _, b in self._blocks[second:]]
                self._blocks[second:] = [(first, np.concatenate(later))]
        return new


def row_keys(thetas: np.ndarray) -> list[bytes]:
    """``θ.tobytes()`` of each row of ``thetas`` (n, k), the key a plan between nodes is kept
    under, in one array step."""
    return _row_items(thetas).tolist()


def _row_items(thetas: np.ndarray) -> np.ndarray:
    """Each row of ``thetas`` (n, k) as one opaque item of its bytes (n,), as floats."""
    rows = np.ascontiguousarray(thetas, dtype=float)
    return rows.view(np.dtype((np.void, rows.shape[1] * rows.itemsize))).ravel()


class BetweenNodes:
    """One process's plans between an atlas's nodes, environment by environment, read from
    ``shards`` (None: memory only) when an environment is first asked about."""

    def __init__(self, shards: PlanShards | None, T: int, k: int) -> None:
        self.shards, self.T, self.k = shards, T, k
        self._known: dict[bytes, PlanTable] = {}
        self._unsaved: dict[bytes, list[bytes]] = {}
        self._keys: dict[bytes, str] = {}
        self._kept = 0
        #: Plans solved here not yet handed on (:meth:`outgoing`), per environment.
        self._outgoing: dict[bytes, list[bytes]] = {}
        #: Plans solved in this process (not read from disk, not received).
        self.solved = 0

    def known(self, env_key: bytes, atlas_key: str) -> PlanTable:
        """E's plans known here (θ's bytes -> trajectory or None), to read and add to (then
        :meth:`added`); ``atlas_key`` names E's atlas on disk."""
        if self._kept >= MAX_KEPT:
            self.save()
            self._known.clear()
            self._kept = 0
        found = self._known.get(env_key)
        if found is None:
            found = self._known[env_key] = PlanTable(self.T)
            self._keys[env_key] = atlas_key
            if self.shards is not None:
                for thetas, plans in self.shards.blocks(atlas_key, self.T, self.k):
                    mapped = isinstance(plans, np.memmap)
                    found.add_many(row_keys(thetas), plans, mapped=mapped)
                    self._kept += 0 if mapped else len(thetas)
        return found

    def added(self, env_key: bytes, theta: bytes) -> None:
        """A plan solved here for E at θ (its bytes), to be saved and handed on."""
        self._unsaved.setdefault(env_key, []).append(theta)
        self._outgoing.setdefault(env_key, []).append(theta)
        self._kept += 1
        self.solved += 1

    def pending(self) -> int:
        """Plans solved here not yet handed on (:meth:`outgoing`)."""
        return sum(len(thetas) for thetas in self._outgoing.values())

    def outgoing(self) -> list[tuple[bytes, str, np.ndarray, np.ndarray]]:
        """The plans solved here since the last call, to hand to other processes: per
        environment (E's key, its atlas's name on disk, θ (n, k), trajectories (n, T, 7), NaN
        where no start converged)."""
        out = []
        for env_key, thetas in self._outgoing.items():
            known = self._known.get(env_key)
            kept = [t for t in thetas if known is not None and t in known]
            if kept:
                out.append((env_key, self._keys[env_key], *self._stack(known, kept)))
        self._outgoing.clear()
        return out

    def merge(
        self,
        env_key: bytes,
        atlas_key: str,
        thetas: np.ndarray,
        plans: np.ndarray,
        save: bool = True,
    ) -> int:
        """Plans another process solved for E (its key; its atlas's name on disk ``atlas_key``),
        kept here as if solved here — (``save``) saved with this process's own, not handed on
        again; how many were new here. A plan depends on (θ, E) alone, so a plan received is the
        plan this process would have solved."""
        known = self.known(env_key, atlas_key)
        new = known.add_many(row_keys(np.asarray(thetas, float)), plans)
        if save and new:
            self._unsaved.setdefault(env_key, []).extend(new)
        self._kept += len(new)
        return len(new)

    def _stack(self, known: PlanTable, thetas: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
        """θ (n, k) and trajectories (n, T, 7; NaN where no start converged) of ``thetas``
        (their bytes), as stored."""
        plans = known.take(known.rows(thetas))
        return np.frombuffer(b"".join(thetas)).reshape(len(thetas), self.k).copy(), plans

    def save(self, at_least: int = 1) -> int:
        """The unsaved plans of every environment with at least ``at_least`` of them, a shard
        each (nothing without shards); how many were written."""
        if self.shards is None:
            return 0
        written = 0
        for env_key, thetas in self._unsaved.items():
            if len(thetas) < max(1, at_least):
                continue
            known = self._known.get(env_key)
            kept = [t for t in thetas if known is not None and t in known]
            if kept:
                self.shards.save(self._keys[env_key], *self._stack(known, kept))
                written += len(kept)
            thetas.clear()
        return written
