"""The Panda arm: pinocchio's model of example-robot-data's URDF, and a CasADi FK built from it.

pinocchio's PyPI wheels carry no ``pinocchio.casadi``, so the symbolic forward kinematics is
built here from the model's joint placements (every arm joint of the Panda is a revolute
joint about its local z axis). Numeric FK (pinocchio) and symbolic FK (CasADi) therefore
describe the same robot; ``tests/test_robot.py`` checks them against each other and against
MuJoCo.

Only the 7 arm joints move; the two finger joints stay at ``FINGER_OPENING`` (holding the cup).
"""

from __future__ import annotations

import functools
import importlib.metadata
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
import pinocchio as pin

from corrections_sim.scene import geometry as g

N_ARM_JOINTS = 7
FINGER_OPENING = 0.04  # each finger, metres: fully open around the cup
#: Frames whose world poses the symbolic FK returns, in this order.
FK_FRAMES = (
    "panda_link3",
    "panda_link4",
    "panda_link5",
    "panda_link6",
    "panda_link7",
    "panda_hand",
    "panda_hand_tcp",
)


@dataclass(frozen=True)
class PandaFiles:
    """Paths of example-robot-data's Panda description, as installed from PyPI."""

    root: Path  # .../robots/panda_description
    urdf: Path
    collision_urdf: Path
    srdf: Path
    package_dir: Path  # what ``package://`` resolves against


@functools.cache
def panda_files() -> PandaFiles:
    """Locate the Panda description shipped in the example-robot-data wheel (no download)."""
    dist = importlib.metadata.distribution("example-robot-data")
    share = Path(str(dist.locate_file("cmeel.prefix/share")))
    root = share / "example-robot-data" / "robots" / "panda_description"
    files = PandaFiles(
        root=root,
        urdf=root / "urdf" / "panda.urdf",
        collision_urdf=root / "urdf" / "panda_collision.urdf",
        srdf=root / "srdf" / "panda.srdf",
        package_dir=share,
    )
    for path in (files.urdf, files.collision_urdf, files.srdf):
        if not path.is_file():
            raise FileNotFoundError(f"example-robot-data is missing {path}; reinstall it")
    return files


@functools.cache
def model() -> pin.Model:
    """pinocchio model of the Panda (nq = 9: 7 arm joints, 2 fingers)."""
    return pin.buildModelFromUrdf(str(panda_files().urdf))


def joint_limits() -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper position limits of the arm joints, each shape (7,), rad."""
    m = model()
    return (
        np.array(m.lowerPositionLimit[:N_ARM_JOINTS]),
        np.array(m.upperPositionLimit[:N_ARM_JOINTS]),
    )


def full_configuration(q_arm: np.ndarray) -> np.ndarray:
    """pinocchio configuration (9,) from the arm's (7,), fingers open around the cup."""
    return np.concatenate([np.asarray(q_arm, dtype=float), [FINGER_OPENING, FINGER_OPENING]])


def frame_poses(q_arm: np.ndarray, frames: tuple[str, ...] = FK_FRAMES) -> dict[str, pin.SE3]:
    """Numeric FK with pinocchio: world pose of each named frame."""
    m = model()
    data = m.createData()
    pin.framesForwardKinematics(m, data, full_configuration(q_arm))
    return {name: data.oMf[m.getFrameId(name)].copy() for name in frames}


def _snap(values: np.ndarray, tol: float = 1e-12) -> np.ndarray:
    """Replace pinocchio's 1e-16 round-off by exact 0 and +-1, so the SX graph stays small."""
    out = np.array(values, dtype=float)
    for target in (0.0, 1.0, -1.0):
        out[np.abs(out - target) < tol] = target
    return out


def _rot_z(angle: ca.SX) -> ca.SX:
    c, s = ca.cos(angle), ca.sin(angle)
    return ca.vertcat(
        ca.horzcat(c, -s, 0),
        ca.horzcat(s, c, 0),
        ca.horzcat(0, 0, 1),
    )


def _se3_sx(placement: pin.SE3) -> tuple[ca.DM, ca.DM]:
    return ca.DM(_snap(placement.rotation)), ca.DM(_snap(placement.translation))


def symbolic_fk(q: ca.SX, frames: tuple[str, ...] = FK_FRAMES) -> dict[str, tuple[ca.SX, ca.SX]]:
    """World (rotation (3, 3), position (3,)) of each frame as CasADi SX expressions of q (7,).

    The chain ``oMi = oMparent * jointPlacement * Rz(q_i)`` is walked over the arm joints
    only; the requested frames must hang off arm joints (true for every link and the hand).
    """
    m = model()
    rotations: list[ca.SX] = [ca.SX.eye(3)]
    positions: list[ca.SX] = [ca.SX.zeros(3)]
    for j in range(1, N_ARM_JOINTS + 1):
        if m.joints[j].shortname() != "JointModelRZ":
            raise RuntimeError(f"joint {m.names[j]} is {m.joints[j].shortname()}, expected RZ")
        parent = m.parents[j]
        r_p, p_p = _se3_sx(m.jointPlacements[j])
        rot = rotations[parent] @ r_p
        pos = positions[parent] + rotations[parent] @ p_p
        rotations.append(rot @ _rot_z(q[j - 1]))
        positions.append(pos)
    out = {}
    for name in frames:
        frame = m.frames[m.getFrameId(name)]
        if frame.parentJoint > N_ARM_JOINTS:
            raise ValueError(f"frame {name} does not hang off an arm joint")
        r_f, p_f = _se3_sx(frame.placement)
        rot_j, pos_j = rotations[frame.parentJoint], positions[frame.parentJoint]
        out[name] = (rot_j @ r_f, pos_j + rot_j @ p_f)
    return out


@functools.cache
def fk_function(frames: tuple[str, ...] = FK_FRAMES) -> ca.Function:
    """CasADi Function q (7,) -> [R_0 (3,3), p_0 (3,), R_1, p_1, ...] for ``frames``."""
    q = ca.SX.sym("q", N_ARM_JOINTS)
    poses = symbolic_fk(q, frames)
    outputs, names = [], []
    for name in frames:
        rot, pos = poses[name]
        outputs += [rot, pos]
        names += [f"R_{name}", f"p_{name}"]
    return ca.Function("panda_fk", [q], outputs, ["q"], names)


# --- collision spheres for the planner --------------------------------------------------------


@dataclass(frozen=True)
class Sphere:
    """A sphere fixed to a frame: centre ``offset`` in that frame, ``radius`` metres."""

    frame: str
    offset: tuple[float, float, float]
    radius: float


def _cup_spheres() -> tuple[Sphere, ...]:
    x, y, z = g.CUP_CENTER_IN_HAND
    half = g.CUP_HALF_HEIGHT / 2
    # Two spheres on the cup's axis whose union covers the cylinder.
    radius = float(np.hypot(g.CUP_RADIUS, g.CUP_HALF_HEIGHT - half)) + 1e-3
    return (
        Sphere("panda_hand", (x, y, z - half), radius),
        Sphere("panda_hand", (x, y, z + half), radius),
    )


#: Spheres that stand for the moving arm in the planner's table and laptop constraints: the
#: spheres of example-robot-data's collision URDF (panda_collision.urdf) for links 3 to 7
#: and the hand, one sphere per open finger, and the cup. ``tests/test_robot.py`` checks
#: them against that file.
ARM_SPHERES: tuple[Sphere, ...] = (
    Sphere("panda_link3", (0.0, 0.0, -0.07), 0.09),
    Sphere("panda_link3", (0.0, 0.0, -0.22), 0.09),
    Sphere("panda_link4", (0.0, 0.0, 0.06), 0.09),
    Sphere("panda_link4", (0.0, 0.0, -0.06), 0.09),
    Sphere("panda_link5", (0.0, 0.0, -0.21), 0.09),
    Sphere("panda_link5", (0.0, 0.0, -0.31), 0.09),
    Sphere("panda_link5", (0.0, 0.08, -0.06), 0.055),
    Sphere("panda_link5", (0.0, 0.08, -0.2), 0.055),
    Sphere("panda_link6", (0.0, 0.0, 0.01), 0.08),
    Sphere("panda_link6", (0.0, 0.0, -0.07), 0.08),
    Sphere("panda_link7", (0.0, 0.0, 0.08), 0.07),
    Sphere("panda_link7", (0.0, 0.0, -0.06), 0.07),
    Sphere("panda_link7", (0.043535534, 0.043535534, 0.09), 0.045),
    Sphere("panda_link7", (0.036464466, 0.036464466, 0.09), 0.045),
    Sphere("panda_hand", (0.0, -0.075, 0.03), 0.05),
    Sphere("panda_hand", (0.0, 0.075, 0.03), 0.05),
    # The open fingers (prismatic joints at FINGER_OPENING), one sphere each in hand frame.
    Sphere("panda_hand", (0.0, FINGER_OPENING + 0.015, 0.0884), 0.03),
    Sphere("panda_hand", (0.0, -(FINGER_OPENING + 0.015), 0.0884), 0.03),
    *_cup_spheres(),
)


def sphere_centers_symbolic(poses: dict[str, tuple[ca.SX, ca.SX]]) -> list[ca.SX]:
    """World centres (3,) of ``ARM_SPHERES`` given symbolic frame poses."""
    return [poses[s.frame][1] + poses[s.frame][0] @ ca.DM(s.offset) for s in ARM_SPHERES]


# --- numeric helpers -----------------------------------------------------------------------------


def cup_pose(q_arm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rotation (3, 3) of the hand and position (3,) of the cup centre."""
    hand = frame_poses(q_arm, ("panda_hand",))["panda_hand"]
    return hand.rotation.copy(), hand.rotation @ np.array(g.CUP_CENTER_IN_HAND) + hand.translation


def hand_down_rotation(yaw: float) -> np.ndarray:
    """Hand orientation with its approach (z) axis pointing at the floor, turned by ``yaw``."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])


def inverse_kinematics(
    cup_position: np.ndarray,
    yaw: float,
    q_init: np.ndarray,
    *,
    iterations: int = 200,
    damping: float = 1e-3,
    tol: float = 1e-6,
) -> np.ndarray | None:
    """Arm configuration that puts the cup centre at ``cup_position`` with the hand down.

    :func:`cup_inverse_kinematics` with the hand's rotation :func:`hand_down_rotation` (yaw).
    Returns ``None`` when it does not converge to ``tol`` (metres / radians) from ``q_init``.
    """
    return cup_inverse_kinematics(
        cup_position,
        hand_down_rotation(yaw),
        q_init,
        iterations=iterations,
        damping=damping,
        tol=tol,
    )


def cup_inverse_kinematics(
    cup_position: np.ndarray,
    rotation: np.ndarray,
    q_init: np.ndarray,
    *,
    iterations: int = 200,
    damping: float = 1e-3,
    tol: float = 1e-6,
) -> np.ndarray | None:
    """Arm configuration that puts the cup centre at ``cup_position`` with the hand's world
    rotation ``rotation`` (3, 3) (e.g. the one it has, to move the cup without tilting it).

    Damped least squares on the 6-D error of the hand frame (pinocchio Jacobian in the
    LOCAL frame), clipped to the joint limits each step. Returns ``None`` when it does not
    converge to ``tol`` (metres / radians) from ``q_init``.
    """
    m = model()
    data = m.createData()
    fid = m.getFrameId("panda_hand")
    rot_target = np.asarray(rotation, dtype=float)
    pos_target = np.asarray(cup_position, float) - rot_target @ np.array(g.CUP_CENTER_IN_HAND)
    target = pin.SE3(rot_target, pos_target)
    lo, hi = joint_limits()
    q = np.array(q_init, dtype=float)
    for _ in range(iterations):
        qf = full_configuration(q)
        pin.framesForwardKinematics(m, data, qf)
        err = pin.log6(data.oMf[fid].actInv(target)).vector
        if np.linalg.norm(err) < tol:
            return q
        jac = pin.computeFrameJacobian(m, data, qf, fid, pin.LOCAL)[:, :N_ARM_JOINTS]
        dq = jac.T @ np.linalg.solve(jac @ jac.T + damping * np.eye(6), err)
        q = np.clip(q + dq, lo, hi)
    return None
