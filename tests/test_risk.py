"""Risk-sensitive deployment, eqs. (A2)–(A4): the set Γ, the (A4) choice, and the exact
max-min (A3) planner against (A4) in the study's scene."""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.learning import Belief
from corrections_sim.planning import risk
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import Planner, PlannerConfig, smoothness_cost
from corrections_sim.scene import world as scene
from corrections_sim.scene.environments import paper_environments


def _random_spd(rng: np.random.Generator, k: int) -> np.ndarray:
    a = rng.normal(size=(k, k))
    return a @ a.T + 0.1 * np.eye(k)


# --- Γ, eq. (A2) ---------------------------------------------------------------------------------


@pytest.mark.parametrize("k", [1, 2, 3, 5])
def test_matrix_sqrt_is_the_symmetric_root(rng, k):
    p = _random_spd(rng, k)
    s = risk.matrix_sqrt(p)
    np.testing.assert_allclose(s, s.T, atol=1e-14)
    np.testing.assert_allclose(s @ s, p, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(s @ s.T, p, rtol=1e-10, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(s) > 0)  # the principal root


@pytest.mark.parametrize("k", [1, 2, 3])
def test_every_offset_of_gamma_is_one_standard_deviation_along_p(rng, k):
    """Γ_i − θ̂ = ±s_i lies on the 1-σ ellipsoid dᵀ P⁻¹ d = 1, and the 2k offsets
    reproduce P: ½ Σ_i d_i d_iᵀ = P (they are the k = 1, α = 1 sigma points of N(θ̂, P))."""
    theta = rng.normal(size=k)
    p = _random_spd(rng, k)
    gammas = risk.preference_set(Belief(theta, p))
    assert gammas.shape == (2 * k + 1, k)
    np.testing.assert_array_equal(gammas[0], theta)
    offsets = gammas[1:] - theta
    mahalanobis = np.einsum("ij,jk,ik->i", offsets, np.linalg.inv(p), offsets)
    np.testing.assert_allclose(mahalanobis, 1.0, rtol=1e-10)
    np.testing.assert_allclose(0.5 * offsets.T @ offsets, p, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(offsets[:k], -offsets[k:], atol=1e-14)


def test_with_a_diagonal_p_gamma_moves_one_weight_by_its_standard_deviation():
    theta = np.array([-1.0, 0.0])
    gammas = risk.preference_set(Belief(theta, np.diag([0.01, 4.0])))
    expected = np.array([[-1.0, 0.0], [-0.9, 0.0], [-1.0, 2.0], [-1.1, 0.0], [-1.0, -2.0]])
    np.testing.assert_allclose(gammas, expected, atol=1e-15)


@pytest.mark.parametrize(
    ("cov", "message"),
    [
        ([[1.0, 0.5], [0.0, 1.0]], "cov: must be symmetric"),
        ([[1.0, 0.0], [0.0, -1.0]], "cov: must be positive definite"),
        ([[1.0, 2.0], [2.0, 1.0]], "cov: must be positive definite"),
        ([[1.0, np.nan], [np.nan, 1.0]], "cov: all values must be finite"),
        ([1.0, 2.0], "cov: expected a square matrix"),
    ],
)
def test_matrix_sqrt_refuses_a_p_that_is_not_symmetric_positive_definite(cov, message):
    with pytest.raises(ValueError, match=message):
        risk.matrix_sqrt(cov)


# --- (A4) choice and the worst case ------------------------------------------------------------


def test_a4_index_picks_min_max_and_the_mean():
    values = np.array([-3.0, -1.0, -2.0, -4.0, -4.0])
    assert risk.a4_index(values, "averse") == 3  # ties: the lowest index
    assert risk.a4_index(values, "seeking") == 1
    assert risk.a4_index(values, "neutral") == 0
    with pytest.raises(ValueError, match="attitude 'bold'"):
        risk.a4_index(values, "bold")
    with pytest.raises(ValueError, match="values"):
        risk.a4_index([0.0, np.nan, 1.0], "averse")


def test_worst_case_reward_is_the_min_over_gamma_minus_smoothness():
    gammas = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 1.0]])
    assert risk.worst_case_reward(gammas, [2.0, 3.0], 0.5, 4.0) == pytest.approx(1.0 - 2.0)


# --- planners in the study's scene --------------------------------------------------------------

THETA = np.array([-1.0, 0.0])  # avoid the laptop, no opinion about the table (fig. 3)


@pytest.fixture(scope="module")
def planners():
    config = PlannerConfig()  # the default: the planner the other tests compile too
    return Planner(config), risk.WorstCasePlanner(config)


@pytest.fixture(scope="module")
def envs():
    return {e.name: e for e in paper_environments()}


#: (environment, P) of the cases below, measured: in s0-t0-l2 with P = I the worst case of
#: (A3)'s trajectory is shared by two preferences (a kink no single ξ*(γ) reaches) and (A3)
#: gains 0.30 over (A4); in s0-t0-l1 with P = diag(0.01, 1) one γ binds and (A3) is (A4).
CASES = {"kink": ("s0-t0-l2", np.eye(2)), "exact": ("s0-t0-l1", np.diag([0.01, 1.0]))}


@pytest.fixture(scope="module")
def solved(planners, envs):
    """(A4), (A3) from the (A4) plans, and (A4) refined from all of them, per case."""
    planner, worst = planners
    out = {}
    for name, (env_name, cov) in CASES.items():
        env = envs[env_name]
        a4 = risk.plan_a4(planner, Belief(THETA, cov), env)
        inits = [p.trajectory for p in a4.plans]
        a3 = worst.solve(a4.gammas, env, inits=inits)
        refined = risk.refine_a4(planner, a4, env, [*inits, a3.trajectory])
        out[name] = (env, a4, a3, refined)
    return out


def _worst(a4: risk.A4Plans, trajectory: np.ndarray, env, lam: float) -> float:
    phi = feature_counts(trajectory, env.params(), ("laptop", "table"))
    return risk.worst_case_reward(a4.gammas, phi, smoothness_cost(trajectory), lam)


def test_a4_values_are_the_plans_rewards_and_the_choices_follow_them(solved):
    _, a4, _, _ = solved["kink"]
    k = 2
    np.testing.assert_allclose(a4.values, [p.reward for p in a4.plans])
    # Φ ≥ 0 makes V non-decreasing in every weight: averse lowers one, seeking raises one.
    assert k + 1 <= a4.index("averse") <= 2 * k
    assert 1 <= a4.index("seeking") <= k
    assert a4.plan("neutral") is a4.plans[0]


def test_averse_collects_less_and_seeking_more_of_the_feature_whose_weight_moved(solved):
    for _, a4, _, _ in solved.values():
        neutral = a4.plan("neutral").features
        i = a4.index("averse") - 3  # the lowered weight
        assert a4.plan("averse").features[i] < neutral[i]
        j = a4.index("seeking") - 1  # the raised weight
        assert a4.plan("seeking").features[j] > neutral[j]


def test_a3_lies_between_a4_and_the_refined_values(solved, planners):
    """worst(ξ) ≤ worst(A3) for every (A4) plan ξ (A3 starts from them), and worst(A3) ≤
    min_j V(γ_j) once the values are refined from the (A3) trajectory (weak duality).

    A refined plan is not among A3's starts, so A3 (a local method) may miss its basin:
    measured once, in s0-t0-l1, a refined plan's worst case beats A3's by 0.005 (0.04%)."""
    lam = planners[0].config.smoothness
    for env, a4, a3, refined in solved.values():
        assert a3.worst_reward == pytest.approx(_worst(a4, a3.trajectory, env, lam), abs=1e-12)
        for plan in a4.plans:
            assert a3.worst_reward >= _worst(a4, plan.trajectory, env, lam) - 1e-6
        for plan in refined.plans:
            assert a3.worst_reward >= _worst(a4, plan.trajectory, env, lam) - 1e-3 * abs(
                a3.worst_reward
            )
        assert np.all(refined.values >= a4.values - 1e-9)
        assert a3.worst_reward <= refined.values.min() + 1e-6


def test_a3_differs_from_a4_where_the_worst_case_switches_between_preferences(solved, planners):
    lam = planners[0].config.smoothness
    env, a4, a3, refined = solved["kink"]
    assert len(a3.binding) >= 2
    gain = a3.worst_reward - _worst(a4, refined.plan("averse").trajectory, env, lam)
    assert gain > 0.1
    env, a4, a3, refined = solved["exact"]
    assert a3.binding == (a4.index("averse"),)
    np.testing.assert_allclose(a3.trajectory, a4.plan("averse").trajectory, atol=1e-4)


def test_a3_trajectory_is_collision_free_in_mujoco_with_fixed_ends(solved):
    for env, _, a3, _ in solved.values():
        assert scene.check_trajectory(a3.trajectory, env, substeps=16).collision_free
        np.testing.assert_array_equal(a3.trajectory[0], env.q_start)
        np.testing.assert_array_equal(a3.trajectory[-1], env.q_goal)
        assert a3.status in {"Solve_Succeeded", "Solved_To_Acceptable_Level"}


def test_a3_from_its_default_guesses_finds_the_same_worst_case(solved, planners):
    env, a4, a3, _ = solved["kink"]
    again = planners[1].solve(a4.gammas, env)
    assert again.worst_reward == pytest.approx(a3.worst_reward, abs=1e-3)


def test_a3_refuses_a_gamma_set_of_the_wrong_shape(planners, envs):
    env = envs["s0-t0-l1"]
    with pytest.raises(ValueError, match=r"gammas: expected shape \(5, 2\)"):
        planners[1].solve(np.zeros((3, 2)), env)
    with pytest.raises(ValueError, match="inits"):
        planners[1].solve(np.zeros((5, 2)), env, inits=[])
