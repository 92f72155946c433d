"""What the machine's cache (:func:`cache_dir`) holds, when
each thing in it was last used, and pruning of what no run has used for a while.

Every key the cache is read by covers the code and settings its content depends on, so a
change of code leaves the old files unread, never wrong; they stay until pruned. Each reader
marks what it reads as used (:func:`mark_used`: the file's modification time), so an entry's
last use is the newest modification time of its files. Kinds:

- ``compiled``: a gcc-built library (the planner's NLP, Newton's loop, the clearance check,
  the features of many waypoints at once), ``<name>-<key>.so`` with its build lock;
- ``atlas``: a plan atlas, ``atlas/<key>.npy`` and ``.json``;
- ``between``: a shard of plans solved between an atlas's nodes, ``atlas/*.extra-*.npz``;
- ``cells``: a shard of interpolation cells checked on an atlas, ``atlas/*.cells-*.npz``;
- ``reference``: a reference grid of plans, ``reference/<key>.npy`` with its build lock;
- ``person``: a person's plan in one environment, ``person/<key>.npz``
  (:mod:`corrections_sim.plans.targets`);
- ``unfinished``: what a writer that died left (temporary files and build folders);
- ``other``: anything else, listed and never removed.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

KINDS = ("compiled", "atlas", "between", "cells", "reference", "person", "unfinished", "other")
#: The kinds :func:`prune` may remove.
PRUNABLE = KINDS[:-1]

_TEMPORARY = re.compile(r"tmp[\w-]*(\..*)?|.*\.tmp(\..*)?")


def cache_dir() -> Path:
    """Where compiled solvers live: ``$CORRECTIONS_SIM_CACHE`` or ``~/.cache/corrections_sim``."""
    env = os.environ.get("CORRECTIONS_SIM_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "corrections_sim"


def mark_used(*paths: Path) -> None:
    """Mark cache files as just used (their modification time); a read-only cache is left
    as it is."""
    for path in paths:
        with contextlib.suppress(OSError):
            os.utime(path)


@dataclass(frozen=True)
class Entry:
    """One thing in the cache: its kind (:data:`KINDS`), its name, its files (or temporary
    folder), their size in bytes and their last use (seconds since the epoch)."""

    kind: str
    name: str
    paths: tuple[Path, ...]
    size: int
    last_used: float


def _kind_and_name(relative: Path) -> tuple[str, str]:
    top, name = relative.parts[0], relative.name
    if len(relative.parts) > 1 and _TEMPORARY.fullmatch(top):
        return "unfinished", f"{top}/"  # a build's scratch folder, as a whole
    if _TEMPORARY.fullmatch(name):
        return "unfinished", relative.as_posix()
    stem = name.removesuffix(".lock")
    if len(relative.parts) == 1 and stem.endswith(".so"):
        return "compiled", stem
    if top == "atlas" and len(relative.parts) == 2:
        if ".extra-" in name and name.endswith(".npz"):
            return "between", name
        if ".cells-" in name and name.endswith(".npz"):
            return "cells", name
        if name.endswith((".npy", ".json")):
            return "atlas", name.rsplit(".", 1)[0]
    if top == "reference" and len(relative.parts) == 2 and stem.endswith(".npy"):
        return "reference", stem
    if top == "person" and len(relative.parts) == 2 and name.endswith(".npz"):
        return "person", name.removesuffix(".npz")
    return "other", relative.as_posix()


def entries(root: Path) -> list[Entry]:
    """Everything under ``root`` as entries, by kind then name (none if it does not exist)."""
    root = Path(root)
    groups: dict[tuple[str, str], list[tuple[Path, os.stat_result]]] = {}
    if root.is_dir():
        for path in root.rglob("*"):
            try:
                stat = path.lstat()
            except FileNotFoundError:  # removed meanwhile (a writer's temporary file)
                continue
            if not path.is_dir() or path.is_symlink():
                groups.setdefault(_kind_and_name(path.relative_to(root)), []).append((path, stat))
    out = []
    for (kind, name), found in groups.items():
        files, stats = [f for f, _ in found], [s for _, s in found]
        paths = (root / name,) if name.endswith("/") else tuple(sorted(files))
        size, used = sum(s.st_size for s in stats), max(s.st_mtime for s in stats)
        out.append(Entry(kind, name, paths, size, used))
    return sorted(out, key=lambda e: (KINDS.index(e.kind), e.name))


def prune(found: Iterable[Entry], unused_for: float, now: float) -> list[Entry]:
    """Remove the entries of :data:`PRUNABLE` kinds not used for ``unused_for`` seconds
    before ``now``; returns them. A file already gone is no error."""
    if not unused_for > 0:
        raise ValueError(f"unused_for = {unused_for!r} must be > 0 (seconds)")
    removed = []
    for entry in found:
        if entry.kind not in PRUNABLE or entry.last_used > now - unused_for:
            continue
        for path in entry.paths:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()
        removed.append(entry)
    return removed
