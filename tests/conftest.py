"""Shared pytest fixtures."""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.learning import Belief


@pytest.fixture
def rng() -> np.random.Generator:
    """A generator seeded with the paper's conference date, fresh for each test."""
    return np.random.default_rng(20181029)


@pytest.fixture
def random_belief():
    """A function (rng, k) -> a random Belief with a well-conditioned covariance (k, k)."""

    def make(rng: np.random.Generator, k: int) -> Belief:
        a = rng.normal(size=(k, k))
        return Belief(theta=rng.normal(size=k), cov=a @ a.T + 0.3 * np.eye(k))

    return make


@pytest.fixture(scope="module")
def planner():
    """Fig. 4's planner (laptop and table, four cold starts), for the tests that plan."""
    from corrections_sim.planning.planner import PlannerConfig, shared_planner

    return shared_planner(PlannerConfig(n_starts=4))
