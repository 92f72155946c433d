"""Simulated users (paper §6): the biased user moves exactly its worst waypoint toward its
intended trajectory, and that is an improvement under θ*; the noisy-optimal user is
Φ(ξ*) + N(0, σ²I), reproducibly from its generator."""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.people.users import BiasedUser, NoisyOptimalUser, Situation
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import Planner
from corrections_sim.scene.environments import Environment, paper_environments

THETA_STAR = np.array([1.0, -1.0])  # seek the laptop, avoid the table
ROBOT_THETA = np.array([0.0, 0.0])  # the robot's prior: smoothness only
# One environment of each start, spread over the table and laptop poses.
ENV_NAMES = ("s0-t0-l0", "s0-t2-l1", "s1-t1-l2", "s2-t0-l3", "s3-t0-l0", "s3-t2-l1")
NAMES = ("laptop", "table")


def _situation(robot, intended, env, names) -> Situation:
    theta = np.zeros(len(names))
    return Situation(robot=robot, intended=intended, env=env, features=names, theta_star=theta)


@pytest.fixture(scope="module")
def planner() -> Planner:
    return Planner()


@pytest.fixture(scope="module")
def envs() -> tuple[Environment, ...]:
    by_name = {e.name: e for e in paper_environments()}
    return tuple(by_name[n] for n in ENV_NAMES)


def _pair() -> tuple[np.ndarray, np.ndarray]:
    """A robot trajectory (6, 7) and an intended one whose worst waypoint is row 4.

    Row 1 has the single largest joint difference (0.9 rad), row 4 the largest joint-space
    norm (0.6·√7 ≈ 1.59 rad): the user must pick row 4.
    """
    robot = np.linspace(0.0, 1.0, 6)[:, None] * np.arange(1.0, 8.0)[None, :] * 0.1
    intended = robot.copy()
    intended[1, 2] += 0.9
    intended[3] -= 0.3
    intended[4] += 0.6
    return robot, intended


# --------------------------------------------------------------------------- BiasedUser


@pytest.mark.parametrize("step", [0.25, 0.5, 1.0])
def test_biased_user_moves_only_the_worst_waypoint_by_step(step):
    robot, intended = _pair()
    robot_before, intended_before = robot.copy(), intended.copy()
    out = BiasedUser(step=step).corrected_trajectory(robot, intended)

    assert out.shape == robot.shape
    np.testing.assert_allclose(out[4], robot[4] + step * 0.6, rtol=0, atol=1e-15)
    others = [i for i in range(6) if i != 4]
    np.testing.assert_array_equal(out[others], robot[others])
    # The correction is a new array; neither input is touched.
    np.testing.assert_array_equal(robot, robot_before)
    np.testing.assert_array_equal(intended, intended_before)


def test_biased_user_full_step_puts_the_waypoint_on_the_intended_one():
    robot, intended = _pair()
    out = BiasedUser(step=1.0).corrected_trajectory(robot, intended)
    np.testing.assert_allclose(out[4], intended[4], rtol=0, atol=1e-15)
    # Only that waypoint: the other errors (rows 1 and 3) remain.
    np.testing.assert_allclose(np.linalg.norm(intended - out, axis=1)[[1, 3]], [0.9, 0.3 * 7**0.5])
    assert BiasedUser().step == 1.0


def test_biased_user_identical_trajectories_are_left_alone():
    robot, _ = _pair()
    np.testing.assert_array_equal(BiasedUser(0.5).corrected_trajectory(robot, robot), robot)


@pytest.mark.parametrize("step", [0.0, -0.2, 1.0001, 2.0, float("nan")])
def test_biased_user_refuses_step_outside_zero_one(step):
    with pytest.raises(ValueError, match="step"):
        BiasedUser(step=step)


def test_biased_user_features_are_those_of_the_corrected_trajectory(envs):
    env = envs[0]
    robot = np.linspace(env.q_start, env.q_goal, 12)
    intended = robot.copy()
    intended[5:8, 1] += np.array([0.2, 0.4, 0.2])
    user = BiasedUser(step=0.5)
    phi_h = user.correction_features(_situation(robot, intended, env, NAMES), None)
    expected = feature_counts(user.corrected_trajectory(robot, intended), env.params(), NAMES)
    np.testing.assert_array_equal(phi_h, expected)
    assert phi_h.shape == (2,)


def test_biased_correction_improves_the_robot_under_the_users_reward(planner, envs):
    """θ*·Φ_h ≥ θ*·Φ(ξᵗ), and Φ_h lies closer to Φ(ξ*) than Φ(ξᵗ) does.

    The robot plans with θ̂ = (0, 0); the user with θ* = (+1, −1) moves its worst waypoint all
    the way. At the time of writing all 6 environments satisfy both; "most" (5 of 6) is
    asserted because the correction is a single-waypoint edit, not an optimum.
    """
    user = BiasedUser(step=1.0)
    improves = closer = 0
    gains = []
    for env in envs:
        mine = planner.solve(ROBOT_THETA, env)
        star = planner.solve(THETA_STAR, env)
        phi_h = user.correction_features(
            _situation(mine.trajectory, star.trajectory, env, planner.config.features), None
        )
        gain = float(THETA_STAR @ (phi_h - mine.features))
        gains.append(gain)
        improves += gain >= 0.0
        closer += np.linalg.norm(phi_h - star.features) < np.linalg.norm(
            mine.features - star.features
        )
    assert improves >= 5, gains
    assert closer >= 5
    assert np.mean(gains) > 0.0


# --------------------------------------------------------------------------- NoisyOptimalUser


def test_noisy_optimal_user_is_phi_star_plus_gaussian_noise(envs):
    env = envs[1]
    intended = np.linspace(env.q_start, env.q_goal, 12)
    phi_star = feature_counts(intended, env.params(), NAMES)
    user = NoisyOptimalUser(noise=0.3)
    rng = np.random.default_rng(3)
    n = 4000
    draws = np.array(
        [
            user.correction_features(_situation(intended, intended, env, NAMES), rng)
            for _ in range(n)
        ]
    )
    assert draws.shape == (n, 2)
    # Mean within 4 standard errors of Φ(ξ*); sample std within 5 % of σ (n = 4000: ≈ 1.1 %).
    np.testing.assert_allclose(draws.mean(axis=0), phi_star, rtol=0, atol=4 * 0.3 / n**0.5)
    np.testing.assert_allclose(draws.std(axis=0, ddof=1), [0.3, 0.3], rtol=0.05)
    # Independent across features.
    assert abs(np.corrcoef(draws.T)[0, 1]) < 0.1


def test_noisy_optimal_user_ignores_the_robot_and_is_deterministic_given_the_seed(envs):
    env = envs[2]
    intended = np.linspace(env.q_start, env.q_goal, 12)
    robot = intended + 0.1
    user = NoisyOptimalUser(noise=0.2)

    def draws(seed: int) -> np.ndarray:
        rng = np.random.default_rng(seed)
        return np.array(
            [
                user.correction_features(_situation(robot, intended, env, NAMES), rng)
                for _ in range(5)
            ]
        )

    np.testing.assert_array_equal(draws(11), draws(11))
    assert not np.allclose(draws(11), draws(12))
    # The robot's trajectory plays no part: same seed, different robot, same draw.
    a = user.correction_features(_situation(robot, intended, env, NAMES), np.random.default_rng(5))
    b = user.correction_features(
        _situation(intended, intended, env, NAMES), np.random.default_rng(5)
    )
    np.testing.assert_array_equal(a, b)


def test_noise_free_optimal_user_shows_phi_star_exactly(envs):
    env = envs[3]
    intended = np.linspace(env.q_start, env.q_goal, 12)
    phi = NoisyOptimalUser(noise=0.0).correction_features(
        _situation(intended, intended, env, NAMES), np.random.default_rng(0)
    )
    np.testing.assert_array_equal(phi, feature_counts(intended, env.params(), NAMES))


@pytest.mark.parametrize("noise", [-0.1, float("nan"), float("inf")])
def test_noisy_optimal_user_refuses_bad_noise(noise):
    with pytest.raises(ValueError, match="noise"):
        NoisyOptimalUser(noise=noise)
