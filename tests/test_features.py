"""Features: range, gradients against finite differences, sums, and what each one means."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from corrections_sim.planning.features import (
    FEATURE_NAMES,
    check_feature_names,
    feature_counts,
    waypoint_feature_function,
    waypoint_features,
)
from corrections_sim.scene import geometry as g
from corrections_sim.scene import robot
from corrections_sim.scene.environments import configuration_at, n_env_params

ALL = FEATURE_NAMES
LAPTOP, TABLE, COFFEE = (FEATURE_NAMES.index(n) for n in ("laptop", "table", "coffee"))
#: Planar arm with q2 - q4 - q6 = π: the hand's approach axis points straight up.
Q_HAND_UP = np.array([0.0, 1.5, 0.0, -(np.pi - 1.5 - 0.0175), 0.0, -0.0175, 0.0])


def _random_env_params(rng: np.random.Generator) -> np.ndarray:
    """(laptop x, y, yaw, table x, y) with the laptop somewhere on the table."""
    tx, ty = rng.uniform(*zip(g.TABLE_X_RANGE, g.TABLE_Y_RANGE, strict=True))
    hx, hy = g.TABLE_HALF_SIZE
    lx, ly = rng.uniform([tx - hx / 2, ty - hy / 2], [tx + hx / 2, ty + hy / 2])
    return np.array([lx, ly, rng.uniform(-np.pi, np.pi), tx, ty])


def _phi(q, e, names=ALL) -> np.ndarray:
    return np.array(waypoint_feature_function(names)(q, e)).ravel()


def test_features_lie_in_unit_interval(rng):
    lo, hi = robot.joint_limits()
    values = np.array(
        [_phi(rng.uniform(lo, hi), _random_env_params(rng)) for _ in range(300)]
    )  # (300, 3)
    assert values.shape == (300, len(ALL))
    assert np.all((values >= 0) & (values <= 1))
    # not degenerate: every feature takes a spread of values over random configurations
    assert np.all(values.max(axis=0) - values.min(axis=0) > 0.3)


def test_gradients_match_central_differences(rng):
    f = waypoint_feature_function(ALL)
    q_sym = ca.MX.sym("q", robot.N_ARM_JOINTS)
    e_sym = ca.MX.sym("e", n_env_params())
    jac = ca.Function(
        "phi_jacobian", [q_sym, e_sym], [ca.jacobian(f(q_sym, e_sym), ca.vertcat(q_sym, e_sym))]
    )
    lo, hi = robot.joint_limits()
    h = 1e-6
    for _ in range(20):
        # near the table and the laptop, where all features have sizeable slopes
        q = configuration_at(rng.uniform([0.4, -0.3, 0.05], [0.6, 0.3, 0.3]))
        q = np.clip(q + rng.normal(0.0, 0.2, robot.N_ARM_JOINTS), lo, hi)
        e = _random_env_params(rng)
        x = np.concatenate([q, e])
        analytic = np.array(jac(q, e))  # (3, 12)
        numeric = np.empty_like(analytic)
        for j in range(x.size):
            dx = np.zeros_like(x)
            dx[j] = h
            plus, minus = x + dx, x - dx
            numeric[:, j] = (_phi(plus[:7], plus[7:]) - _phi(minus[:7], minus[7:])) / (2 * h)
        np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-6)
        assert np.abs(analytic).max() > 1e-3


def test_feature_counts_sum_the_waypoint_features(rng):
    lo, hi = robot.joint_limits()
    e = _random_env_params(rng)
    trajectory = rng.uniform(lo, hi, size=(9, robot.N_ARM_JOINTS))
    per_waypoint = np.array([_phi(q, e) for q in trajectory])
    np.testing.assert_allclose(waypoint_features(trajectory, e, ALL), per_waypoint, atol=1e-14)
    np.testing.assert_allclose(feature_counts(trajectory, e, ALL), per_waypoint.sum(axis=0))
    # a subset of the features, in another order, picks the matching columns
    np.testing.assert_allclose(
        feature_counts(trajectory, e, ("coffee", "laptop")),
        per_waypoint[:, [COFFEE, LAPTOP]].sum(axis=0),
        atol=1e-12,
    )


def test_laptop_feature_is_one_above_the_laptop_and_zero_far_away():
    e = np.array([0.65, -0.2, 0.3, 0.55, 0.0])
    above = configuration_at((0.65, -0.2, 0.3))
    assert _phi(above, e)[LAPTOP] == pytest.approx(1.0, abs=1e-9)
    far = configuration_at((0.3, 0.55, 0.3))
    assert _phi(far, e)[LAPTOP] < 1e-5


def test_coffee_feature_is_tilt_of_the_cup():
    e = np.array([0.6, -0.1, 0.0, 0.55, 0.0])
    down = configuration_at((0.5, 0.2, 0.3))
    assert _phi(down, e)[COFFEE] == pytest.approx(0.0, abs=1e-12)
    assert robot.cup_pose(Q_HAND_UP)[0][2, 2] == pytest.approx(1.0, abs=1e-9)
    assert _phi(Q_HAND_UP, e)[COFFEE] == pytest.approx(1.0, abs=1e-9)


def test_table_feature_is_large_low_over_the_table_and_small_outside():
    # table top spans x in [0.45, 0.95], y in [-0.35, 0.35]
    e = np.array([0.7, -0.1, 0.0, 0.7, 0.0])
    hx, hy = g.TABLE_HALF_SIZE
    low_over_table = configuration_at((0.6, 0.2, 0.08))
    assert _phi(low_over_table, e)[TABLE] > 0.9
    # 10 cm outside an edge, low enough that the height term alone would be large
    for cup in [(0.6, hy + 0.1, 0.1), (0.6, -(hy + 0.1), 0.1), (0.7 - hx - 0.1, 0.2, 0.08)]:
        q = configuration_at(cup)
        assert _phi(q, e)[TABLE] < 1e-2, cup
    high_over_table = configuration_at((0.55, 0.2, 0.6))
    assert _phi(high_over_table, e)[TABLE] < 0.02


@pytest.mark.parametrize("names", [("laptop", "bogus"), ("laptop", "laptop"), (), ("Laptop",)])
def test_bad_feature_names_raise(names):
    with pytest.raises(ValueError, match="features"):
        check_feature_names(names)
    with pytest.raises(ValueError, match="features"):
        waypoint_feature_function(names)
    with pytest.raises(ValueError, match="features"):
        feature_counts(np.zeros((3, robot.N_ARM_JOINTS)), np.zeros(n_env_params()), names)


def test_wrong_trajectory_shape_raises():
    with pytest.raises(ValueError, match="trajectory"):
        feature_counts(np.zeros((3, 6)), np.zeros(n_env_params()), ALL)


@pytest.mark.parametrize("names", [ALL, ("coffee", "laptop"), ("table",)])
def test_compiled_waypoint_features_are_casadis_own_to_the_bit(rng, names):
    """The compiled loop (what every learner's features of many plans go through) and
    CasADi's evaluation of the same function give the same doubles, laid out alike (so the
    sums over waypoints agree to the bit too)."""
    from corrections_sim.planning.features import _mapped

    names = check_feature_names(names)
    lo, hi = robot.joint_limits()
    for _ in range(3):
        e = _random_env_params(rng)
        q = np.concatenate(
            [
                rng.uniform(lo, hi, size=(200, robot.N_ARM_JOINTS)),
                [
                    configuration_at(p)
                    for p in rng.uniform([0.4, -0.3, 0.05], [0.6, 0.3, 0.3], (50, 3))
                ],
            ]
        )
        compiled = waypoint_features(q, e, names)
        casadi = np.asarray(_mapped(names, n_env_params(), len(q))(q.T, e)).T
        assert compiled.shape == casadi.shape == (len(q), len(names))
        assert np.array_equal(compiled, casadi)
        if len(names) > 1:  # weight-major, as CasADi's; one column is contiguous either way
            assert compiled.strides == casadi.strides
        assert np.array_equal(compiled.sum(axis=0), casadi.sum(axis=0))
        assert np.array_equal(waypoint_features(q[:1], e, names), casadi[:1])


def test_the_compiled_loop_refuses_rows_of_the_wrong_size():
    from corrections_sim.planning.features import _rows

    rows = _rows(ALL, n_env_params())
    assert rows is not None
    with pytest.raises(ValueError, match=r"expected rows \(n, 7\)"):
        rows(np.zeros((3, 6)), np.zeros(n_env_params()))
    with pytest.raises(ValueError, match="parameters"):
        rows(np.zeros((3, 7)), np.zeros(n_env_params() + 1))


def test_a_cache_that_cannot_hold_the_library_leaves_the_features_to_casadi(
    tmp_path, monkeypatch, rng
):
    """Where the compiled loop cannot be built (here the cache's path runs through a file),
    one warning says so and CasADi gives the same numbers."""
    from corrections_sim.planning.features import _rows

    blocked = tmp_path / "a-file"
    blocked.write_text("")
    monkeypatch.setenv("CORRECTIONS_SIM_CACHE", str(blocked / "cache"))
    with pytest.warns(RuntimeWarning, match="not compiled"):
        assert _rows.__wrapped__(ALL, n_env_params()) is None
    lo, hi = robot.joint_limits()
    q, e = rng.uniform(lo, hi, size=(5, robot.N_ARM_JOINTS)), _random_env_params(rng)
    per_waypoint = np.array([_phi(one, e) for one in q])
    assert np.array_equal(waypoint_features(q, e, ALL), per_waypoint)
