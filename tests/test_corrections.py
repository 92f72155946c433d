"""Correction models against hand-computed corrections, and the users built on them."""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.components import build
from corrections_sim.people.corrections import (
    CORRECTIONS,
    OptimalCorrection,
    WaypointCorrection,
    deformation_correction,
    deformation_shapes,
    waypoint_correction,
    worst_waypoints,
)
from corrections_sim.people.users import BiasedUser, DeformingUser


def _pair() -> tuple[np.ndarray, np.ndarray]:
    """Robot (6, 2) all zeros; intended differs at rows 1 (norm 1), 2 (norm 5) and 4 (norm 2)."""
    robot = np.zeros((6, 2))
    intended = robot.copy()
    intended[1] = (1.0, 0.0)
    intended[2] = (3.0, 4.0)
    intended[4] = (0.0, -2.0)
    return robot, intended


def test_worst_waypoints_in_order_and_never_the_fixed_ends():
    robot, intended = _pair()
    intended[0] = intended[-1] = (100.0, 100.0)  # would be worst, but start and goal are fixed
    assert worst_waypoints(robot, intended, 3).tolist() == [2, 4, 1]


def test_one_waypoint_correction_by_hand():
    robot, intended = _pair()
    out = waypoint_correction(robot, intended, step=0.5)
    expected = robot.copy()
    expected[2] = (1.5, 2.0)
    np.testing.assert_array_equal(out, expected)


def test_two_waypoint_correction_by_hand():
    robot, intended = _pair()
    out = waypoint_correction(robot, intended, step=1.0, count=2)
    expected = robot.copy()
    expected[2] = (3.0, 4.0)
    expected[4] = (0.0, -2.0)
    np.testing.assert_array_equal(out, expected)


def test_deformation_shape_is_the_minimum_jerk_solution():
    t = 8
    shapes = deformation_shapes(t)
    # K: full convolution of [-1, 3, -3, 1] over the 6 free waypoints; A = KᵀK.
    free = t - 2
    k = np.zeros((free + 3, free))
    for j in range(free):
        k[j : j + 4, j] = (-1, 3, -3, 1)
    column = np.linalg.solve(k.T @ k, np.eye(free)[:, 2])
    np.testing.assert_allclose(shapes[1:-1, 3], column / column[2], atol=1e-12)
    assert np.all(shapes[[0, -1], :] == 0.0)  # start and goal never move
    np.testing.assert_allclose(np.diag(shapes)[1:-1], 1.0)
    # Smooth and local: the neighbours move less the farther they are.
    assert shapes[3, 3] > shapes[2, 3] > shapes[1, 3] > 0.0


def test_deformation_moves_the_worst_waypoint_exactly_and_its_neighbours_along():
    robot, intended = _pair()
    out = deformation_correction(robot, intended, step=0.5)
    np.testing.assert_allclose(out[2], 0.5 * intended[2])
    shape = deformation_shapes(6)[:, 2]
    np.testing.assert_allclose(out, robot + 0.5 * np.outer(shape, intended[2]))
    assert np.all(out[0] == robot[0]) and np.all(out[-1] == robot[-1])


def test_model_values_and_the_optimal_model():
    robot, intended = _pair()
    assert np.array_equal(OptimalCorrection().apply(robot, intended), intended)
    model = WaypointCorrection(step=0.5, waypoints=2)
    model.check(6)
    np.testing.assert_array_equal(
        model.apply(robot, intended), waypoint_correction(robot, intended, 0.5, 2)
    )
    assert list(CORRECTIONS)[:3] == ["waypoint", "deform", "optimal"]


@pytest.mark.parametrize(
    ("name", "params", "match"),
    [
        ("magic", {}, "model: unknown correction model 'magic'"),
        ("waypoint", {"step": 0.0}, r"model.step: must lie in \(0, 1\], got 0.0"),
        ("deform", {"step": 1.5}, r"model.step: must lie in \(0, 1\], got 1.5"),
        ("waypoint", {"waypoints": 0}, "model.waypoints: must be >= 1"),
        ("deform", {"waypoints": 2}, "model.waypoints: the deform correction model has no such"),
        ("optimal", {"step": 0.5}, "model.step: the optimal correction model has no such"),
    ],
)
def test_bad_model_parameters_are_refused_by_name(name, params, match):
    with pytest.raises(ValueError, match=match):
        build(CORRECTIONS, name, params, where="model")


def test_a_model_that_moves_more_waypoints_than_are_free_is_refused_once_t_is_known():
    WaypointCorrection(waypoints=10).check(12)
    with pytest.raises(ValueError, match="waypoints: 11 must lie in \\[1, 10\\]"):
        WaypointCorrection(waypoints=11).check(12)  # 12 waypoints: 10 free


def test_users_use_the_same_corrections():
    robot, intended = _pair()
    np.testing.assert_array_equal(
        BiasedUser(step=0.5, waypoints=2).corrected_trajectory(robot, intended),
        waypoint_correction(robot, intended, 0.5, 2),
    )
    np.testing.assert_array_equal(
        DeformingUser(step=1.0).corrected_trajectory(robot, intended),
        deformation_correction(robot, intended, 1.0),
    )
    assert not BiasedUser().stochastic and not DeformingUser().stochastic
    with pytest.raises(ValueError, match="waypoints: 5 must lie in"):
        BiasedUser(waypoints=5).corrected_trajectory(robot, intended)  # 4 free waypoints
    with pytest.raises(ValueError, match="step: must lie in"):
        DeformingUser(step=2.0)


@pytest.mark.parametrize(
    "name, params",
    [
        ("waypoint", {}),
        ("waypoint", {"step": 0.5, "waypoints": 3}),
        ("deform", {}),
        ("deform", {"step": 0.3}),
        ("optimal", {}),
    ],
)
def test_a_model_corrects_many_plans_at_once_with_the_same_bits(name, params):
    """An exact learner weighs a correction at thousands of nodes through ``apply_many``; its
    answer must be ``apply``'s on each, bit for bit (ties between waypoints included: plans
    equal to the robot's, or moved alike), or a committed curve would move."""
    rng = np.random.default_rng(7)
    model = build(CORRECTIONS, name, params, where="model")
    for _ in range(50):
        robot = rng.normal(size=(12, 7))
        scale = rng.choice([0.0, 1e-3, 1.0], size=(40, 1, 1))
        plans = robot[None] + scale * rng.normal(size=(40, 12, 7))
        plans[:, [0, -1]] = robot[[0, -1]]
        many = model.apply_many(robot, plans)
        assert many.shape == plans.shape
        assert np.array_equal(many, np.stack([model.apply(robot, p) for p in plans]))
    with pytest.raises(ValueError, match=r"\(m, T, n\)"):
        model.apply_many(robot, plans[0])


@pytest.mark.parametrize("name", ["waypoint", "deform", "optimal"])
def test_features_at_many_plans_are_the_plain_sums_bit_for_bit(name):
    """features_at_plans takes the robot's own waypoints' features where a correction leaves
    them; the answer must be the plain one (every waypoint of every shown trajectory counted,
    summed as waypoint_features lays them out), bit for bit, NaN plans kept NaN."""
    from corrections_sim.learning.observation import features_at_plans
    from corrections_sim.planning.features import waypoint_features
    from corrections_sim.scene.environments import paper_environments

    env = paper_environments()[3]
    names = ("laptop", "table")
    model = build(CORRECTIONS, name, {}, where="model")
    rng = np.random.default_rng(3)
    robot = 0.5 * rng.normal(size=(12, 7))
    plans = robot[None] + 0.3 * rng.normal(size=(300, 12, 7))
    plans[:, [0, -1]] = robot[[0, -1]]
    plans[5] = np.nan
    got = features_at_plans(plans, robot, model.apply_many, env, names)
    shown = model.apply_many(robot, np.delete(plans, 5, axis=0))
    plain = waypoint_features(shown.reshape(-1, 7), env.params(), names)
    plain = plain.reshape(-1, 12, 2).sum(axis=1)
    assert np.all(np.isnan(got[5]))
    assert np.array_equal(np.delete(got, 5, axis=0), plain)
