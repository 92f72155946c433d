"""Random restarts of the trajectory optimizer and how far a plan is from the best of them:
shared by ``bench planner`` (:mod:`benchmarks.bench`) and ``bench confidence``
(:mod:`benchmarks.bench_confidence`), so that neither imports the other."""

from __future__ import annotations

import numpy as np

from corrections_sim.scene.environments import Environment
from corrections_sim.scene.robot import N_ARM_JOINTS, joint_limits

RESTART_BUMP_STD = 0.4  # rad, std of each sine coefficient of a random restart
RESTART_MODES = 3  # sine modes per joint in a random restart's perturbation


def random_restarts(
    env: Environment, n_waypoints: int, count: int, rng: np.random.Generator
) -> list[np.ndarray]:
    """The straight joint-space line, then ``count - 1`` smooth random bends of it.

    A bend adds Σ_m a_m sin(mπs) per joint (s ∈ [0, 1] along the path, m = 1..RESTART_MODES,
    a_m ~ N(0, (RESTART_BUMP_STD/m)²)), so start and goal stay fixed; clipped to the limits.
    """
    s = np.linspace(0.0, 1.0, n_waypoints)[:, None]  # (T, 1)
    line = (1 - s) * env.q_start + s * env.q_goal  # (T, 7)
    lo, hi = joint_limits()
    modes = np.arange(1, RESTART_MODES + 1)
    out = [line]
    for _ in range(count - 1):
        coeffs = rng.normal(0.0, RESTART_BUMP_STD / modes[:, None], (RESTART_MODES, N_ARM_JOINTS))
        bend = np.sin(np.pi * s * modes) @ coeffs  # (T, 7)
        out.append(np.clip(line + bend, lo, hi))
    return out


def relative_gap(best: float, value: float) -> float:
    """(best − value)/|best|: how much worse ``value`` is than ``best`` (< 0 if better)."""
    return (best - value) / abs(best)
