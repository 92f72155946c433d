"""The Panda model: CasADi FK against pinocchio and MuJoCo, collision spheres against the
URDF, inverse kinematics."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from corrections_sim.scene import robot
from corrections_sim.scene import world as scene
from corrections_sim.scene.environments import configuration_at

HOME = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, np.pi / 4])
#: Spheres of ARM_SPHERES that are ours, not the URDF's: one per open finger and the cup's
#: two (the URDF's finger spheres sit on the finger bodies, which the planner does not use).
N_OWN_SPHERES = 4


@pytest.fixture(scope="module")
def checker() -> scene.CollisionChecker:
    return scene.CollisionChecker()


def test_casadi_fk_equals_pinocchio_and_mujoco(checker, rng):
    fk = robot.fk_function()
    lo, hi = robot.joint_limits()
    qs = rng.uniform(lo, hi, size=(120, robot.N_ARM_JOINTS))
    for q in qs:
        outputs = fk(q)
        expected = robot.frame_poses(q)
        for i, name in enumerate(robot.FK_FRAMES):
            rot = np.array(outputs[2 * i])
            pos = np.array(outputs[2 * i + 1]).ravel()
            np.testing.assert_allclose(pos, expected[name].translation, rtol=0, atol=1e-9)
            np.testing.assert_allclose(rot, expected[name].rotation, rtol=0, atol=1e-9)
            rot_mj, pos_mj = checker.body_pose(q, name)
            np.testing.assert_allclose(pos, pos_mj, rtol=0, atol=1e-9)
            np.testing.assert_allclose(rot, rot_mj, rtol=0, atol=1e-9)


def _urdf_spheres() -> dict[str, list[tuple[tuple[float, float, float], float]]]:
    """Every sphere collision of panda_collision.urdf: frame -> [(offset, radius)]."""
    root = ET.parse(robot.panda_files().collision_urdf).getroot()
    out: dict[str, list] = {}
    for link in root.iter("link"):
        for collision in link.iter("collision"):
            sphere = collision.find("geometry/sphere")
            if sphere is None:
                continue
            origin = collision.find("origin")
            xyz = "0 0 0" if origin is None else origin.get("xyz", "0 0 0")
            offset = tuple(float(v) for v in xyz.split())
            out.setdefault(link.get("name"), []).append((offset, float(sphere.get("radius"))))
    return out


def _own(sphere: robot.Sphere) -> bool:
    return sphere in robot.ARM_SPHERES[-N_OWN_SPHERES:]


def test_own_spheres_are_the_fingers_and_the_cup():
    own = robot.ARM_SPHERES[-N_OWN_SPHERES:]
    assert all(s.frame == "panda_hand" for s in own)
    # finger spheres straddle the approach axis; the cup's lie on it
    assert sorted(s.offset[1] for s in own) == pytest.approx(
        [-(robot.FINGER_OPENING + 0.015), 0.0, 0.0, robot.FINGER_OPENING + 0.015]
    )


SPHERE_FRAMES = tuple(dict.fromkeys(s.frame for s in robot.ARM_SPHERES))


@pytest.mark.parametrize("frame", SPHERE_FRAMES)
def test_arm_spheres_are_the_urdf_spheres(frame):
    urdf = _urdf_spheres()[frame]
    ours = [s for s in robot.ARM_SPHERES if s.frame == frame and not _own(s)]
    for offset, radius in urdf:
        matches = [
            s for s in ours if np.allclose(s.offset, offset, atol=1e-9) and s.radius == radius
        ]
        assert matches, f"{frame}: URDF sphere at {offset} r {radius} missing from ARM_SPHERES"
    for s in ours:
        assert any(
            np.allclose(s.offset, offset, atol=1e-9) and s.radius == radius
            for offset, radius in urdf
        ), f"{frame}: ARM_SPHERES sphere {s} is not in the URDF"


def test_arm_spheres_cover_links_3_to_hand():
    assert SPHERE_FRAMES == (
        "panda_link3",
        "panda_link4",
        "panda_link5",
        "panda_link6",
        "panda_link7",
        "panda_hand",
    )


@pytest.mark.parametrize(
    ("target", "yaw"),
    [((0.5, 0.1, 0.25), 0.0), ((0.45, -0.3, 0.15), 0.4), ((0.35, 0.5, 0.35), -0.3)],
)
def test_inverse_kinematics_reaches_target_with_hand_down(target, yaw):
    q = robot.inverse_kinematics(np.array(target), yaw, HOME)
    assert q is not None
    lo, hi = robot.joint_limits()
    assert np.all((lo <= q) & (q <= hi))
    rot, cup = robot.cup_pose(q)
    np.testing.assert_allclose(cup, target, rtol=0, atol=1e-6)
    assert rot[:, 2] @ np.array([0.0, 0.0, -1.0]) > 1 - 1e-9  # approach axis at the floor
    np.testing.assert_allclose(rot, robot.hand_down_rotation(yaw), atol=1e-6)


def test_configuration_at_matches_target():
    q = configuration_at((0.42, -0.52, 0.28))
    rot, cup = robot.cup_pose(q)
    np.testing.assert_allclose(cup, (0.42, -0.52, 0.28), atol=1e-6)
    assert rot[2, 2] < -1 + 1e-9


@pytest.mark.parametrize("target", [(2.0, 0.0, 0.3), (0.0, 0.0, 1.6), (0.3, -1.2, -0.2)])
def test_unreachable_target(target):
    assert robot.inverse_kinematics(np.array(target), 0.0, HOME) is None
    with pytest.raises(ValueError, match="unreachable"):
        configuration_at(target)
