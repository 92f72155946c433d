"""The MuJoCo scene: FK against pinocchio, collision checks, moving props, renders."""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.scene import geometry as g
from corrections_sim.scene import robot
from corrections_sim.scene import world as scene
from corrections_sim.scene.environments import Environment

HOME = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785])
ROBOT_BODIES = frozenset(
    [f"panda_link{i}" for i in range(9)]
    + ["panda_hand", "panda_hand_tcp", "panda_leftfinger", "panda_rightfinger", scene.CUP_BODY]
)
FK_BODIES = tuple(f"panda_link{i}" for i in range(1, 8)) + ("panda_hand", "panda_hand_tcp")


def _ik(cup_position: tuple[float, float, float]) -> np.ndarray:
    q = robot.inverse_kinematics(np.array(cup_position), 0.0, HOME)
    assert q is not None, f"IK failed for {cup_position}"
    return q


def _env(laptop=(0.55, -0.1, 0.0), table=(0.55, 0.0)) -> Environment:
    return Environment(q_start=HOME, q_goal=HOME, laptop=laptop, table=table)


@pytest.fixture(scope="module")
def checker() -> scene.CollisionChecker:
    return scene.CollisionChecker()


def test_mujoco_fk_equals_pinocchio(checker, rng):
    lo, hi = robot.joint_limits()
    for q in rng.uniform(lo, hi, size=(120, robot.N_ARM_JOINTS)):
        expected = robot.frame_poses(q, FK_BODIES)
        for body in FK_BODIES:
            rot, pos = checker.body_pose(q, body)
            np.testing.assert_allclose(pos, expected[body].translation, rtol=0, atol=1e-9)
            np.testing.assert_allclose(rot, expected[body].rotation, rtol=0, atol=1e-9)


def test_fingers_are_welded_open_and_cup_hangs_in_the_hand(checker, rng):
    q = rng.uniform(*robot.joint_limits())
    fingers = robot.frame_poses(q, ("panda_leftfinger", "panda_rightfinger"))
    for body, pose in fingers.items():
        np.testing.assert_allclose(checker.body_pose(q, body)[1], pose.translation, atol=1e-9)
    rot, cup = checker.body_pose(q, scene.CUP_BODY)
    np.testing.assert_allclose(cup, robot.cup_pose(q)[1], atol=1e-9)
    np.testing.assert_allclose(rot, robot.cup_pose(q)[0], atol=1e-9)
    assert checker.model.nq == robot.N_ARM_JOINTS


def test_excludes_are_the_srdf_pairs_plus_extras(checker):
    assert len(scene.srdf_disabled_pairs()) == 35
    assert checker.model.nexclude == 35 + len(scene.EXTRA_EXCLUDES)


def test_hand_down_above_table_is_collision_free(checker):
    q = _ik((0.5, 0.2, 0.15))
    rot, _ = checker.body_pose(q, "panda_hand")
    assert rot[2, 2] < -0.999  # approach axis points at the floor
    report = checker.check_configuration(q, _env())
    assert report.collision_free
    assert report.contacts == () and report.n_samples == 1 and report.max_depth == 0.0


def test_hand_pushed_through_table_names_table_and_arm(checker):
    report = checker.check_configuration(_ik((0.55, 0.2, -0.12)), _env())
    assert not report.collision_free
    pairs = report.body_pairs()
    assert ("panda_hand", "table") in pairs
    assert all("table" in pair and set(pair) & ROBOT_BODIES for pair in pairs)
    assert 0.03 < report.max_depth < 0.1


def test_trajectory_through_laptop_reports_sample_index(checker):
    waypoints = np.array([_ik((0.55, 0.25, 0.2)), _ik((0.55, -0.1, 0.06)), _ik((0.45, -0.3, 0.2))])
    report = checker.check_trajectory(waypoints, _env(), substeps=8)
    assert report.n_samples == 17 and not report.collision_free
    hit = report.colliding_samples()
    assert 8 in hit and 0 not in hit and 16 not in hit  # waypoint 1 is sample 8
    assert all(c.involves(scene.LAPTOP_BODY) for c in report.contacts)
    assert ("cup", "laptop") in report.body_pairs()
    for contact in report.contacts:
        assert contact.time == contact.sample / 8
        assert contact.depth > 0
    # The dense samples are exactly those checked one at a time.
    samples = scene.interpolate(waypoints, 8)
    for k in (hit[0], hit[0] - 1):
        single = checker.check_configuration(samples[k], _env())
        assert single.collision_free == (k not in hit)


def test_moving_props_changes_the_result(checker):
    waypoints = np.array([_ik((0.55, 0.25, 0.2)), _ik((0.55, -0.1, 0.06)), _ik((0.45, -0.3, 0.2))])
    through_table = _ik((0.55, 0.2, -0.12))
    assert not checker.check_trajectory(waypoints, _env()).collision_free
    assert checker.check_trajectory(waypoints, _env(laptop=(0.55, 0.2, 0.0))).collision_free
    assert not checker.check_trajectory(waypoints, _env()).collision_free  # and back again
    assert not checker.check_configuration(through_table, _env()).collision_free
    aside = _env(laptop=(0.55, -0.35, 0.0), table=(0.55, -0.35))
    assert checker.check_configuration(through_table, aside).collision_free


def test_laptop_yaw_moves_the_screen(checker):
    env = _env(laptop=(0.55, 0.0, 0.0))
    screen = checker.model.geom("laptop_screen").id
    turned = _env(laptop=(0.55, 0.0, np.pi / 2))
    checker.check_configuration(HOME, env)
    before = checker.data.geom_xpos[screen].copy()
    checker.check_configuration(HOME, turned)
    after = checker.data.geom_xpos[screen].copy()
    # Unturned the screen sits behind the keyboard (+y); turned by 90 deg it is at -x.
    assert before[1] > 0.05 and abs(before[0] - 0.55) < 1e-9
    assert after[0] < 0.55 - 0.05 and abs(after[1]) < 1e-9
    assert before[2] == pytest.approx(after[2])
    assert before[2] > g.TABLE_TOP_Z + 2 * g.LAPTOP_BASE_HALF_SIZE[2]


def test_no_self_contacts_near_home(checker, rng):
    lo, hi = robot.joint_limits()
    configurations = np.clip(HOME + rng.normal(0.0, 0.2, size=(50, 7)), lo, hi)
    report = checker.check_configurations(configurations, _env())
    assert report.n_samples == 50
    assert not any(set(pair) <= ROBOT_BODIES for pair in report.body_pairs())


def test_interpolate_hits_waypoints():
    waypoints = np.stack([HOME, HOME + 0.1, HOME - 0.2])
    dense = scene.interpolate(waypoints, 4)
    assert dense.shape == (9, 7)
    np.testing.assert_array_equal(dense[::4], waypoints)
    np.testing.assert_allclose(dense[2], HOME + 0.05)
    assert scene.interpolate(waypoints[:1], 4).shape == (1, 7)


@pytest.mark.parametrize(
    ("waypoints", "substeps", "field"),
    [
        (np.zeros((3, 6)), 8, "waypoints"),
        (np.full((2, 7), np.nan), 8, "waypoints"),
        (np.zeros((2, 7)), 0, "substeps"),
        (np.zeros((2, 7)), 2.5, "substeps"),
    ],
)
def test_bad_trajectory_is_refused(checker, waypoints, substeps, field):
    with pytest.raises(ValueError, match=field):
        checker.check_trajectory(waypoints, _env(), substeps=substeps)


def test_render_shows_scene_and_path():
    from corrections_sim.scene import render

    env = Environment(
        q_start=_ik((0.45, 0.4, 0.25)), q_goal=HOME, laptop=(0.55, -0.1, 0.0), table=(0.55, 0.0)
    )
    start = robot.cup_pose(env.q_start)[1]
    points = start + np.linspace(0.0, 1.0, 6)[:, None] * (np.array([0.5, -0.3, 0.2]) - start)
    image = render.render_scene(
        env, [(points, (0.0, 1.0, 0.0, 1.0))], width=160, height=120, show_goal=False
    )
    assert image.shape == (120, 160, 3) and image.dtype == np.uint8
    green = (image[..., 1] > 150) & (image[..., 0] < 90) & (image[..., 2] < 90)
    assert green.sum() > 20  # the path is drawn
    plain = render.render_scene(env, [], width=160, height=120, show_goal=False)
    plain_green = (plain[..., 1] > 150) & (plain[..., 0] < 90) & (plain[..., 2] < 90)
    assert plain_green.sum() == 0
