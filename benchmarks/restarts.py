"""Random restarts of the trajectory optimizer and how far a plan is from the best of them:
shared by ``bench planner`` (:mod:`benchmarks.bench`) and ``bench confidence``
(:mod:`benchmarks.bench_confidence`), so that neither imports the other."""

from __future__ import annotations

from corrections_sim.plans.book import (  # noqa: F401  (the benchmarks' names)
    RESTART_BUMP_STD,
    RESTART_MODES,
)
from corrections_sim.plans.book import random_starts as random_restarts  # noqa: F401


def relative_gap(best: float, value: float) -> float:
    """(best − value)/|best|: how much worse ``value`` is than ``best`` (< 0 if better)."""
    return (best - value) / abs(best)
