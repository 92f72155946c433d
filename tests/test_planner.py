"""The trajectory optimizer ξ*(θ, E): convergence and safety on all 48 environments, the
effect of θ, the reported reward, warm and multi-start solves, and refusal of bad input."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from corrections_sim import robot, scene
from corrections_sim.environments import Environment, paper_environments
from corrections_sim.features import feature_counts
from corrections_sim.planner import (
    Plan,
    Planner,
    PlannerConfig,
    PlanningError,
    build_key,
    check_theta,
    initial_guesses,
)

CONVERGED = {"Solve_Succeeded", "Solved_To_Acceptable_Level"}
NEUTRAL, LAPTOP_LOVER, TABLE_LOVER = (0.0, 0.0), (1.0, -1.0), (-1.0, 1.0)
THETAS = (NEUTRAL, LAPTOP_LOVER, TABLE_LOVER)
N_ENVS = len(paper_environments())


@pytest.fixture(scope="module")
def planner() -> Planner:
    # The first build on a machine compiles for ~30 s; later ones load the cached solver.
    return Planner()


@pytest.fixture(scope="module")
def envs() -> tuple[Environment, ...]:
    return paper_environments()


@pytest.fixture(scope="module")
def plans(planner, envs) -> dict[tuple[tuple[float, float], int], Plan]:
    """Default solves of every (θ, environment) pair, shared by the tests below."""
    return {(theta, i): planner.solve(theta, env) for theta in THETAS for i, env in enumerate(envs)}


def _cup_path(trajectory: np.ndarray) -> np.ndarray:
    return np.array([robot.cup_pose(q)[1] for q in trajectory])  # (T, 3)


@pytest.mark.parametrize("theta", THETAS)
def test_every_environment_converges_to_a_safe_trajectory(planner, envs, plans, theta):
    checker = scene.CollisionChecker()
    lo, hi = robot.joint_limits()
    T = planner.config.n_waypoints
    for i, env in enumerate(envs):
        plan = plans[theta, i]
        assert plan.status in CONVERGED, (env.name, plan.status)
        assert plan.trajectory.shape == (T, robot.N_ARM_JOINTS)
        np.testing.assert_array_equal(plan.trajectory[0], env.q_start)
        np.testing.assert_array_equal(plan.trajectory[-1], env.q_goal)
        assert np.all((plan.trajectory >= lo) & (plan.trajectory <= hi)), env.name
        # denser than the planner's own check (8 samples per segment)
        report = checker.check_trajectory(plan.trajectory, env, substeps=16)
        assert report.collision_free, (env.name, report.contacts[:3])
        assert plan.iterations >= 1 and plan.starts == planner.config.n_starts


def test_reward_is_theta_dot_features_minus_smoothness(planner, envs, plans):
    lam = planner.config.smoothness
    for (theta, i), plan in plans.items():
        env = envs[i]
        phi = feature_counts(plan.trajectory, env.params(), planner.config.features)
        smooth = np.sum((plan.trajectory[1:] - plan.trajectory[:-1]) ** 2)
        expected = float(np.dot(theta, phi) - lam * smooth)
        np.testing.assert_allclose(plan.features, phi, rtol=0, atol=1e-12)
        assert plan.reward == pytest.approx(expected, rel=1e-12, abs=1e-12)
        assert planner.reward(theta, plan.trajectory, env) == pytest.approx(expected, abs=1e-12)


def test_laptop_weight_changes_the_path(envs, plans):
    deviations = np.array(
        [
            np.linalg.norm(
                _cup_path(plans[LAPTOP_LOVER, i].trajectory)
                - _cup_path(plans[NEUTRAL, i].trajectory),
                axis=1,
            ).max()
            for i in range(len(envs))
        ]
    )
    assert np.mean(deviations > 0.05) >= 0.8, np.round(deviations, 3)
    for i, env in enumerate(envs):
        neutral, lover = plans[NEUTRAL, i].features, plans[LAPTOP_LOVER, i].features
        assert lover[0] > neutral[0], (env.name, neutral, lover)  # more over the laptop
        assert lover[1] < neutral[1], (env.name, neutral, lover)  # less near the table


def test_table_weight_pulls_the_path_down_to_the_table(envs, plans):
    for i, env in enumerate(envs):
        neutral, lover = plans[NEUTRAL, i].features, plans[TABLE_LOVER, i].features
        assert lover[1] > neutral[1], (env.name, neutral, lover)


def test_each_optimum_beats_the_others_plans_under_its_own_theta(planner, envs, plans):
    """ξ*(θ) scores at least as well under θ as ξ*(θ') does: a local check of optimality."""
    worse = 0
    for i, env in enumerate(envs):
        for theta in THETAS:
            own = plans[theta, i].reward
            others = [planner.reward(theta, plans[t, i].trajectory, env) for t in THETAS]
            worse += own < max(others) - 1e-6
    # Local optima may rarely lose to another θ's plan; most must not.
    assert worse <= 0.05 * len(envs) * len(THETAS)


def test_warm_start_from_the_solution_returns_the_same_optimum(planner, envs, plans):
    for i in range(0, N_ENVS, 4):
        plan = plans[LAPTOP_LOVER, i]
        warm = planner.solve(LAPTOP_LOVER, envs[i], inits=[plan.trajectory])
        assert warm.status in CONVERGED
        assert warm.starts == 1
        assert warm.reward == pytest.approx(plan.reward, abs=1e-6)
        np.testing.assert_allclose(warm.trajectory, plan.trajectory, atol=1e-3)


def test_default_multi_start_is_no_worse_than_a_single_start(planner, envs, plans):
    T = planner.config.n_waypoints
    for theta in (LAPTOP_LOVER, TABLE_LOVER):
        for i in range(0, N_ENVS, 3):
            single = planner.solve(theta, envs[i], inits=initial_guesses(envs[i], T, 1))
            assert single.starts == 1
            assert plans[theta, i].reward >= single.reward - 1e-9


def test_solves_are_deterministic(planner, envs, plans):
    again = planner.solve(LAPTOP_LOVER, envs[5])
    np.testing.assert_array_equal(again.trajectory, plans[LAPTOP_LOVER, 5].trajectory)


def test_initial_guesses_join_start_and_goal_within_limits(planner, envs):
    lo, hi = robot.joint_limits()
    T = planner.config.n_waypoints
    env = envs[7]
    guesses = initial_guesses(env, T, 3)
    assert len(guesses) == 3
    np.testing.assert_allclose(guesses[0][T // 2], (env.q_start + env.q_goal) / 2, atol=0.2)
    for guess in guesses:
        assert guess.shape == (T, robot.N_ARM_JOINTS)
        np.testing.assert_allclose(guess[0], env.q_start, atol=1e-12)
        np.testing.assert_allclose(guess[-1], env.q_goal, atol=1e-12)
        assert np.all((guess >= lo) & (guess <= hi))
    assert not np.allclose(guesses[1], guesses[0])


@pytest.mark.parametrize(
    "theta", [(1.0,), (1.0, 2.0, 3.0), np.ones((2, 1)), (np.nan, 0.0), (0.0, np.inf)]
)
def test_bad_theta_raises_naming_theta(planner, envs, theta):
    with pytest.raises(ValueError, match="theta"):
        planner.solve(theta, envs[0])
    with pytest.raises(ValueError, match="theta"):
        check_theta(theta, 2)


def test_wrong_init_shape_raises(planner, envs):
    with pytest.raises(ValueError, match="inits"):
        planner.solve(NEUTRAL, envs[0], inits=[np.zeros((5, robot.N_ARM_JOINTS))])


def test_unconverged_nlp_raises_with_the_status(envs):
    # jit=False: a one-off config builds in a fraction of a second without gcc
    planner = Planner(PlannerConfig(max_iter=1, jit=False))
    with pytest.raises(PlanningError, match="Maximum_Iterations_Exceeded") as info:
        planner.solve(LAPTOP_LOVER, envs[0])
    assert envs[0].name in str(info.value)


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"smoothness": 0.0}, "smoothness"),
        ({"smoothness": -1.0}, "smoothness"),
        ({"smoothness": float("nan")}, "smoothness"),
        ({"smoothness": float("inf")}, "smoothness"),
        ({"n_waypoints": 2}, "n_waypoints"),
        ({"n_waypoints": 0}, "n_waypoints"),
        ({"features": ("laptop", "sofa")}, "features"),
        ({"features": ()}, "features"),
        ({"features": ("table", "table")}, "features"),
        ({"n_starts": 0}, "n_starts"),
        ({"max_iter": 0}, "max_iter"),
        ({"solver": "snopt"}, "solver = 'snopt'"),
        ({"solver": "fatrop", "n_waypoints": 3}, "n_waypoints"),
        ({"tol": -1e-6}, "tol"),
    ],
)
def test_planner_config_refuses_bad_values(changes, field):
    with pytest.raises(ValueError, match=field):
        PlannerConfig(**changes)


def test_build_key_tracks_what_shapes_the_compiled_library():
    base = PlannerConfig()
    assert build_key(base) == build_key(PlannerConfig())
    keys = {
        build_key(dataclasses.replace(base, **change))
        for change in (
            {},
            {"smoothness": 10.0},
            {"n_waypoints": 10},
            {"features": ("laptop", "table", "coffee")},
            {"solver": "ipopt"},
        )
    }
    assert len(keys) == 5
    # solver options are given when the library is loaded: no rebuild for them
    for change in ({"max_iter": 100}, {"tol": 1e-5}, {"n_starts": 1}, {"jit": False}):
        assert build_key(dataclasses.replace(base, **change)) == build_key(base)
