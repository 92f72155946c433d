"""The 48 paper environments and the Environment value's validation."""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.planning.planner import clearance
from corrections_sim.scene import robot
from corrections_sim.scene import world as scene
from corrections_sim.scene.environments import Environment, paper_environments

HOME = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, np.pi / 4])
VALID = {
    "q_start": HOME,
    "q_goal": HOME,
    "laptop": (0.55, -0.1, 0.2),
    "table": (0.55, 0.0),
}


def _env(**changes) -> Environment:
    return Environment(**{**VALID, **changes})


@pytest.fixture(scope="module")
def envs() -> tuple[Environment, ...]:
    return paper_environments()


def test_there_are_48_distinct_environments(envs):
    assert len(envs) == 48
    assert len(set(envs)) == 48
    assert len({e.name for e in envs}) == 48


def test_environments_vary_start_table_and_laptop(envs):
    assert len({e.q_start.tobytes() for e in envs}) >= 4
    assert len({e.table.tobytes() for e in envs}) >= 3
    assert len({e.laptop.tobytes() for e in envs}) >= 4
    # laptop poses relative to their table also vary (not just carried along with it)
    assert len({(e.laptop - np.r_[e.table, 0.0]).round(9).tobytes() for e in envs}) >= 4


def test_starts_and_goals_are_collision_free_and_clear(envs):
    checker = scene.CollisionChecker()
    for env in envs:
        for label, q in (("start", env.q_start), ("goal", env.q_goal)):
            report = checker.check_configuration(q, env)
            assert report.collision_free, (env.name, label, report.contacts)
            table_gap, laptop_gap = clearance(q, env)
            assert table_gap >= 0 and laptop_gap >= 0, (env.name, label, table_gap, laptop_gap)


def test_starts_and_goals_hold_the_cup_upright(envs):
    for q in [e.q_start for e in envs] + [e.q_goal for e in envs]:
        assert robot.cup_pose(q)[0][2, 2] < -1 + 1e-9


def test_valid_environment_is_frozen_and_has_params():
    env = _env()
    np.testing.assert_array_equal(env.params(), [0.55, -0.1, 0.2, 0.55, 0.0])
    with pytest.raises(ValueError):
        env.q_start[0] = 1.0  # read-only array
    with pytest.raises(AttributeError):
        env.name = "other"  # type: ignore[misc]


def test_equality_and_hash_are_by_content():
    a = _env(name="a")
    b = _env(name="b", laptop=np.array([0.55, -0.1, 0.2]), q_start=list(HOME))
    assert a == b and hash(a) == hash(b)
    assert len({a, b}) == 1
    c = _env(laptop=(0.55, -0.1, 0.21))
    assert a != c
    assert a != "not an environment"
    # the caller's array is copied: mutating it later does not change the environment
    q = HOME.copy()
    d = _env(q_start=q)
    q[0] = 0.5
    assert d == a


def test_laptop_near_the_edge_fits_only_unturned():
    assert _env(laptop=(0.55, 0.23, 0.0)).laptop[1] == 0.23
    with pytest.raises(ValueError, match="off the table"):
        _env(laptop=(0.55, 0.23, np.pi / 2))


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"laptop": (0.9, 0.0, 0.0)}, "laptop"),  # keyboard past the table's far edge
        ({"laptop": (0.55, 0.3, 0.0)}, "laptop"),  # over the side edge
        ({"laptop": (0.55, 0.23, np.pi / 2)}, "laptop"),  # fits unturned, not turned
        ({"table": (0.3, 0.0), "laptop": (0.3, 0.0, 0.0)}, "table.x"),
        ({"table": (0.55, 0.5), "laptop": (0.55, 0.5, 0.0)}, "table.y"),
        ({"q_start": HOME + np.r_[0, 0, 0, 3.0, 0, 0, 0]}, r"q_start\[3\]"),
        ({"q_goal": HOME + np.r_[0, 0, 0, 0, 0, -2.1, 0]}, r"q_goal\[5\]"),
        ({"q_start": np.r_[HOME[:6], np.nan]}, "q_start"),
        ({"q_goal": np.r_[HOME[:6], np.inf]}, "q_goal"),
        ({"laptop": (0.55, np.nan, 0.0)}, "laptop"),
        ({"table": (np.inf, 0.0)}, "table"),
        ({"q_start": HOME[:6]}, "q_start"),
        ({"q_goal": np.zeros((7, 1))}, "q_goal"),
        ({"laptop": (0.55, -0.1)}, "laptop"),
        ({"table": (0.55, 0.0, 0.0)}, "table"),
    ],
)
def test_environment_refuses_bad_fields(changes, field):
    with pytest.raises(ValueError, match=f"^{field}"):
        _env(**changes)
