"""Metrics of §6: the estimate error is the L1 distance, and regret comes in two forms — the
paper's θ*·(Φ* − Φ) and the planner's full objective, which also charges smoothness."""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.metrics import estimate_error, regret_terms


def test_estimate_error_is_the_l1_distance():
    # L1 = 1 + 2 + 0.5; L2 would be √5.25 ≈ 2.29, L∞ 2.
    assert estimate_error(np.array([1.0, -2.0, 0.5]), np.zeros(3)) == pytest.approx(3.5)
    assert estimate_error([0.0, 0.0], [1.0, -1.0]) == 2.0
    assert estimate_error([0.3, -0.4], [0.3, -0.4]) == 0.0
    assert isinstance(estimate_error([1.0], [0.0]), float)


def test_estimate_error_is_a_symmetric_metric(rng):
    a, b, c = rng.normal(size=(3, 4))
    assert estimate_error(a, b) == pytest.approx(estimate_error(b, a))
    assert estimate_error(a, c) <= estimate_error(a, b) + estimate_error(b, c) + 1e-12
    assert estimate_error(a, b) == pytest.approx(np.abs(a - b).sum())


def test_identical_trajectories_have_no_regret():
    full, paper = regret_terms(
        np.array([1.0, -1.0]), np.array([4.2, 0.7]), 0.31, np.array([4.2, 0.7]), 0.31, 20.0
    )
    assert (full, paper) == (0.0, 0.0)


def test_regret_by_hand():
    """θ* = (1, −1), λ = 20. The robot is over the laptop more than the user's optimum
    (Φ = (3.5, 1) vs Φ* = (3, 1)) by bending harder (S = 0.2 vs S* = 0.05):

    paper = θ*·(Φ* − Φ) = 1·(−0.5) + (−1)·0 = −0.5   (negative: a paper-regret artefact)
    full  = paper − λ (S* − S) = −0.5 − 20·(−0.15) = 2.5
    """
    full, paper = regret_terms(
        np.array([1.0, -1.0]), np.array([3.0, 1.0]), 0.05, np.array([3.5, 1.0]), 0.2, 20.0
    )
    assert paper == pytest.approx(-0.5)
    assert full == pytest.approx(2.5)
    assert isinstance(full, float) and isinstance(paper, float)


def test_full_regret_is_paper_regret_minus_smoothness_difference(rng):
    for _ in range(20):
        theta = rng.normal(size=3)
        phi_star, phi = rng.uniform(0, 12, size=(2, 3))
        s_star, s = rng.uniform(0, 2, size=2)
        lam = rng.uniform(0.1, 50)
        full, paper = regret_terms(theta, phi_star, s_star, phi, s, lam)
        assert paper == pytest.approx(theta @ (phi_star - phi), rel=1e-12, abs=1e-12)
        assert full == pytest.approx(paper - lam * (s_star - s), rel=1e-12, abs=1e-12)


def test_regret_is_the_drop_of_the_planner_objective():
    """full = R*(ξ*) − R*(ξ) with R*(ξ) = θ*·Φ(ξ) − λ S(ξ)."""
    theta = np.array([0.7, -1.3])
    phi_star, s_star = np.array([5.0, 0.8]), 0.12
    phi, s = np.array([2.5, 1.9]), 0.04
    lam = 20.0

    def objective(f: np.ndarray, sm: float) -> float:
        return float(theta @ f - lam * sm)

    full, _ = regret_terms(theta, phi_star, s_star, phi, s, lam)
    assert full == pytest.approx(objective(phi_star, s_star) - objective(phi, s))
