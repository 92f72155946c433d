"""``cache``: what the machine's cache holds (compiled libraries, plan atlases, the plans kept
between their nodes, reference grids, the people's plans), by kind, and pruning of what no run
used for a while (:mod:`corrections_sim.planning.cache`).

    python -m corrections_sim.run cache               # what is there, its size, its last use
    python -m corrections_sim.run cache --prune 30    # remove what no run used for 30 days
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from corrections_sim.cli.command import Command

DAY = 86_400.0


def _size(n: int) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    raise AssertionError("unreachable")


def _table(found, now: float) -> list[str]:
    """A line a kind: how many entries, their size, the days since the newest and the oldest
    last use."""
    from corrections_sim.planning.cache import KINDS

    lines = [f"{'kind':<11}{'entries':>8}{'size':>11}  last used (days ago)"]
    for kind in KINDS:
        of = [e for e in found if e.kind == kind]
        if of:
            ages = sorted((now - e.last_used) / DAY for e in of)
            when = f"{ages[0]:.1f}" if len(of) == 1 else f"{ages[0]:.1f} to {ages[-1]:.1f}"
            lines.append(f"{kind:<11}{len(of):>8}{_size(sum(e.size for e in of)):>11}  {when}")
    total = sum(e.size for e in found)
    lines.append(f"{'total':<11}{len(found):>8}{_size(total):>11}")
    return lines


def run_cache(args: argparse.Namespace) -> list[Path]:
    """List the cache by kind; with ``--prune DAYS``, first remove what no run used for that
    long, and say what went."""
    from corrections_sim.planning.cache import entries, prune
    from corrections_sim.planning.planner import cache_dir

    root, now = cache_dir(), time.time()
    print(f"cache: {root}")
    found = entries(root)
    if args.prune is not None:
        removed = prune(found, args.prune * DAY, now)
        freed = sum(e.size for e in removed)
        print(f"removed {len(removed)} entries not used for {args.prune:g} days ({_size(freed)})")
        found = entries(root)
    print("\n".join(_table(found, now)))
    return []


COMMAND = Command(
    name="cache",
    run=run_cache,
    help="what the machine's cache holds, by kind (--prune DAYS: remove what no run used)",
    options=("prune",),
    nothing_kept=lambda args: "cache: what was removed is gone, the rest is kept; run it again",
)
