"""The MuJoCo scene: the Panda on its pedestal, a table with a laptop, a cup in the hand.

The scene is composed with :class:`mujoco.MjSpec` from example-robot-data's
``panda_collision.urdf`` (all collision geoms are primitives) and the props whose dimensions
live in :mod:`corrections_sim.scene.geometry`. Two models come from one composition:

* the collision model (no meshes) for fast checks of configurations and trajectories;
* the visual model (adds the STL meshes of ``meshes/collision`` as visuals) for renders.

The model is built once; an :class:`~corrections_sim.scene.environments.Environment` only moves
the static ``table`` and ``laptop`` bodies (``model.body_pos`` / ``model.body_quat``), and
``mj_kinematics`` recomputes their world poses on every check, so no state is stale.

The fingers are not joints here: they are welded at ``robot.FINGER_OPENING`` (holding the
cup), so ``qpos`` is exactly the 7 arm joints.
"""

from __future__ import annotations

import copy
import functools
import re
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from dataclasses import dataclass

import mujoco
import numpy as np

from corrections_sim.scene import geometry as g
from corrections_sim.scene import robot
from corrections_sim.scene.environments import Environment

#: Geom groups: props and robot collision primitives are in 0, robot meshes in 2. Renders
#: show groups 0 and 2 and hide the robot's primitives (group 3 in the visual model).
GROUP_PROPS = 0
GROUP_ROBOT_MESH = 2
GROUP_ROBOT_COLLISION = 3

CUP_BODY = "cup"
TABLE_BODY = "table"
LAPTOP_BODY = "laptop"
PEDESTAL_BODY = "pedestal"
FLOOR_BODY = "floor"

#: Extra pairs that never collide in a meaningful way, beyond the SRDF's: the base and the
#: first link rest on the pedestal; the cup is held by the hand and fingers, next to link 7.
EXTRA_EXCLUDES = (
    ("panda_link0", PEDESTAL_BODY),
    ("panda_link1", PEDESTAL_BODY),
    (CUP_BODY, "panda_hand"),
    (CUP_BODY, "panda_leftfinger"),
    (CUP_BODY, "panda_rightfinger"),
    (CUP_BODY, "panda_link7"),
)

_TABLE_LEG_RADIUS = 0.025
_TABLE_LEG_INSET = 0.05  # leg axis distance from the top's edges
_OFFSCREEN_SIZE = (1920, 1440)  # largest render (width, height) the visual model allows

_LINK_RGBA = (0.93, 0.93, 0.95, 1.0)
_DARK_RGBA = (0.18, 0.18, 0.2, 1.0)
_TABLE_RGBA = (0.55, 0.38, 0.22, 1.0)
_LAPTOP_RGBA = (0.35, 0.36, 0.4, 1.0)
_SCREEN_RGBA = (0.1, 0.12, 0.18, 1.0)
_CUP_RGBA = (0.85, 0.2, 0.15, 1.0)
_PEDESTAL_RGBA = (0.3, 0.3, 0.33, 1.0)


# --- composition ---------------------------------------------------------------------------


def _urdf_text(*, visual: bool) -> str:
    """The collision URDF with MuJoCo compiler flags, meshes resolved or visuals removed."""
    files = robot.panda_files()
    text = files.collision_urdf.read_text()
    if visual:
        # The DAE visuals need trimesh + pycollada; the STL collision meshes look the same.
        mesh_dir = files.root / "meshes" / "collision"
        text = re.sub(
            r"package://[^\"]*/meshes/visual/(\w+)\.dae",
            lambda match: str(mesh_dir / f"{match.group(1)}.stl"),
            text,
        )
    else:
        text = re.sub(r"<visual>.*?</visual>", "", text, flags=re.DOTALL)
    # The fingers become fixed offsets (see _weld_fingers), so their mimic coupling goes.
    text = re.sub(r"<mimic[^>]*/>", "", text)
    compiler = (
        '<mujoco><compiler fusestatic="false" discardvisual="false" strippath="false"/></mujoco>'
    )
    return re.sub(r"(<robot[^>]*>)", lambda match: match.group(1) + compiler, text, count=1)


@functools.cache
def srdf_disabled_pairs() -> tuple[tuple[str, str], ...]:
    """The SRDF's ``disable_collisions`` link pairs (35 for the Panda)."""
    root = ET.parse(robot.panda_files().srdf).getroot()
    return tuple((e.get("link1"), e.get("link2")) for e in root.iter("disable_collisions"))


def _weld_fingers(spec: mujoco.MjSpec) -> None:
    """Replace the finger joints by fixed offsets of ``robot.FINGER_OPENING`` along their axes."""
    for name in ("panda_leftfinger", "panda_rightfinger"):
        body = spec.body(name)
        (joint,) = body.joints
        body.pos = np.asarray(body.pos) + robot.FINGER_OPENING * np.asarray(joint.axis)
        spec.delete(joint)


def _add_props(spec: mujoco.MjSpec, *, visual: bool) -> None:
    """Floor, pedestal, table (top + 4 legs), laptop (keyboard + screen) and the cup."""
    world = spec.worldbody
    floor_material = ""
    if visual:
        spec.add_texture(
            name="grid",
            type=mujoco.mjtTexture.mjTEXTURE_2D,
            builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
            rgb1=[0.82, 0.84, 0.86],
            rgb2=[0.74, 0.76, 0.78],
            width=256,
            height=256,
        )
        spec.add_material(name="floor", texrepeat=[8, 8], textures=["", "grid"])
        floor_material = "floor"
        spec.add_texture(
            name="sky",
            type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
            builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
            rgb1=[0.95, 0.96, 0.98],
            rgb2=[0.7, 0.75, 0.82],
            width=64,
            height=64,
        )
        spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
        spec.visual.headlight.diffuse = [0.45, 0.45, 0.45]
        key_light = world.add_light(pos=[0.8, -1.0, 2.5], dir=[-0.3, 0.4, -1.0])
        key_light.type = mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
        key_light.diffuse = [0.5, 0.5, 0.5]
        key_light.castshadow = True

    floor = world.add_body(name=FLOOR_BODY, pos=[0.0, 0.0, g.FLOOR_Z])
    floor.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[3.0, 3.0, 0.05],
        material=floor_material,
        rgba=[0.8, 0.8, 0.8, 1.0],
    )

    pedestal_height = 0.0 - g.FLOOR_Z
    pedestal = world.add_body(name=PEDESTAL_BODY, pos=[0.0, 0.0, g.FLOOR_Z + pedestal_height / 2])
    pedestal.add_geom(
        name="pedestal",
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[g.PEDESTAL_RADIUS, pedestal_height / 2, 0.0],
        rgba=_PEDESTAL_RGBA,
    )

    # Table body frame: the centre of the top surface, moved per environment.
    table = world.add_body(name=TABLE_BODY, pos=[0.0, 0.0, g.TABLE_TOP_Z])
    hx, hy = g.TABLE_HALF_SIZE
    half_t = g.TABLE_THICKNESS / 2
    table.add_geom(
        name="table_top",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[hx, hy, half_t],
        pos=[0.0, 0.0, -half_t],
        rgba=_TABLE_RGBA,
    )
    leg_half = (g.TABLE_TOP_Z - g.TABLE_THICKNESS - g.FLOOR_Z) / 2
    for i, (sx, sy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
        table.add_geom(
            name=f"table_leg{i}",
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            size=[_TABLE_LEG_RADIUS, leg_half, 0.0],
            pos=[
                sx * (hx - _TABLE_LEG_INSET),
                sy * (hy - _TABLE_LEG_INSET),
                -g.TABLE_THICKNESS - leg_half,
            ],
            rgba=_TABLE_RGBA,
        )

    # Laptop body frame: keyboard centre (x, y) on the table top, yawed per environment.
    laptop = world.add_body(name=LAPTOP_BODY, pos=[0.0, 0.0, g.TABLE_TOP_Z])
    bx, by, bz = g.LAPTOP_BASE_HALF_SIZE
    laptop.add_geom(
        name="laptop_keyboard",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[bx, by, bz],
        pos=[0.0, 0.0, bz],
        rgba=_LAPTOP_RGBA,
    )
    sx_, sy_, sz_ = g.LAPTOP_SCREEN_HALF_SIZE
    tilt = g.LAPTOP_SCREEN_TILT
    # Hinge on the keyboard's top back (+y) edge; the screen leans back (its top toward +y):
    # a rotation by -tilt about x, with the slab's back face flush with the keyboard's edge.
    rot = np.array(
        [[1.0, 0.0, 0.0], [0.0, np.cos(tilt), np.sin(tilt)], [0.0, -np.sin(tilt), np.cos(tilt)]]
    )
    hinge = np.array([0.0, by, 2 * bz])
    screen_center = hinge + rot @ np.array([0.0, -sy_, sz_])
    laptop.add_geom(
        name="laptop_screen",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[sx_, sy_, sz_],
        pos=screen_center,
        quat=[np.cos(-tilt / 2), np.sin(-tilt / 2), 0.0, 0.0],
        rgba=_SCREEN_RGBA,
    )

    # The cup: its axis is the hand's z axis; its open top faces the hand.
    cup = spec.body("panda_hand").add_body(name=CUP_BODY, pos=list(g.CUP_CENTER_IN_HAND))
    cup.add_geom(
        name="cup",
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[g.CUP_RADIUS, g.CUP_HALF_HEIGHT, 0.0],
        rgba=_CUP_RGBA,
    )


def _style_robot(spec: mujoco.MjSpec) -> None:
    """Robot meshes in ``GROUP_ROBOT_MESH`` (no contacts), primitives in the hidden group."""
    for body in spec.bodies:
        if not body.name.startswith("panda_"):
            continue
        for geom in body.geoms:
            if geom.type == mujoco.mjtGeom.mjGEOM_MESH:
                geom.group = GROUP_ROBOT_MESH
                geom.contype = 0
                geom.conaffinity = 0
                dark = "finger" in body.name or body.name in ("panda_link0",)
                geom.rgba = _DARK_RGBA if dark else _LINK_RGBA
            else:
                geom.group = GROUP_ROBOT_COLLISION


def build_spec(*, visual: bool = False) -> mujoco.MjSpec:
    """Compose the scene.

    Args:
        visual: add the robot's meshes, lights, textures and offscreen buffer for renders.

    Returns:
        An uncompiled spec; ``qpos`` of its model is the 7 arm joints.
    """
    spec = mujoco.MjSpec.from_string(_urdf_text(visual=visual))
    spec.modelname = "corrections_scene"
    _weld_fingers(spec)
    _add_props(spec, visual=visual)
    if visual:
        _style_robot(spec)
        spec.visual.global_.offwidth, spec.visual.global_.offheight = _OFFSCREEN_SIZE
        spec.visual.quality.shadowsize = 4096
    for link1, link2 in (*srdf_disabled_pairs(), *EXTRA_EXCLUDES):
        spec.add_exclude(bodyname1=link1, bodyname2=link2)
    return spec


@functools.cache
def _compiled(visual: bool) -> mujoco.MjModel:
    return build_spec(visual=visual).compile()


def build_model(*, visual: bool = False) -> mujoco.MjModel:
    """A private copy of the compiled scene (compiled once per process and kind).

    The copy is the caller's own: moving its table and laptop affects no other model.
    """
    return copy.copy(_compiled(visual))


def _yaw_quat(yaw: float) -> np.ndarray:
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def place_environment(model: mujoco.MjModel, env: Environment) -> None:
    """Move the table and the laptop of ``model`` (in place) to ``env``'s poses.

    The table top's centre goes to ``(env.table, TABLE_TOP_Z)``; the keyboard's bottom
    centre to ``(env.laptop[:2], TABLE_TOP_Z)``, turned by ``env.laptop[2]`` about z.
    """
    tx, ty = env.table
    lx, ly, yaw = env.laptop
    table = model.body(TABLE_BODY).id
    laptop = model.body(LAPTOP_BODY).id
    model.body_pos[table] = (tx, ty, g.TABLE_TOP_Z)
    model.body_pos[laptop] = (lx, ly, g.TABLE_TOP_Z)
    model.body_quat[laptop] = _yaw_quat(float(yaw))


def set_configuration(model: mujoco.MjModel, data: mujoco.MjData, q: np.ndarray) -> None:
    """Write the arm configuration (7,) into ``data`` and run ``mj_kinematics``."""
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)


# --- collision checks --------------------------------------------------------------------------


@dataclass(frozen=True)
class Contact:
    """The deepest contact between two bodies at one sample.

    Attributes:
        sample: index of the checked configuration (row of the dense samples).
        time: position along the trajectory in waypoint units: ``sample / substeps``, so an
            integer is a waypoint and 2.5 is half-way between waypoints 2 and 3.
        body_a: name of one body (the lower body id).
        body_b: name of the other body.
        depth: penetration depth, metres (> 0).
    """

    sample: int
    time: float
    body_a: str
    body_b: str
    depth: float

    def involves(self, body: str) -> bool:
        """Whether ``body`` is one of the two bodies."""
        return body in (self.body_a, self.body_b)


@dataclass(frozen=True)
class CollisionReport:
    """Result of a collision check of one configuration or a whole trajectory.

    Attributes:
        contacts: the colliding body pairs per sample, in sample order.
        n_samples: number of configurations checked.
        substeps: samples per waypoint segment (1 for single configurations).
    """

    contacts: tuple[Contact, ...]
    n_samples: int
    substeps: int = 1

    @property
    def collision_free(self) -> bool:
        """True when no sample penetrates anything."""
        return not self.contacts

    @property
    def max_depth(self) -> float:
        """Deepest penetration over all contacts, metres (0 when collision free)."""
        return max((c.depth for c in self.contacts), default=0.0)

    def colliding_samples(self) -> tuple[int, ...]:
        """Sorted indices of samples with at least one contact."""
        return tuple(sorted({c.sample for c in self.contacts}))

    def body_pairs(self) -> frozenset[tuple[str, str]]:
        """The distinct colliding (body_a, body_b) pairs."""
        return frozenset((c.body_a, c.body_b) for c in self.contacts)


def check_waypoints(waypoints: np.ndarray, substeps: int) -> tuple[np.ndarray, int]:
    """``waypoints`` as a C-contiguous float array (T, 7), T >= 1, all finite, and
    ``substeps`` as an int >= 1; a ValueError names what is wrong."""
    waypoints = np.ascontiguousarray(waypoints, dtype=float)
    if waypoints.ndim != 2 or waypoints.shape[0] < 1 or waypoints.shape[1] != robot.N_ARM_JOINTS:
        raise ValueError(f"waypoints: expected shape (T, 7) with T >= 1, got {waypoints.shape}")
    if not np.all(np.isfinite(waypoints)):
        raise ValueError("waypoints: all values must be finite")
    if int(substeps) != substeps or substeps < 1:
        raise ValueError(f"substeps: expected an integer >= 1, got {substeps}")
    return waypoints, int(substeps)


def interpolate(waypoints: np.ndarray, substeps: int) -> np.ndarray:
    """Linear joint-space interpolation of a trajectory.

    Args:
        waypoints: (T, 7) joint waypoints, T >= 1.
        substeps: samples per segment (>= 1); sample ``k * substeps`` is waypoint ``k``.

    Returns:
        (S, 7) samples with ``S = (T - 1) * substeps + 1``.
    """
    waypoints, substeps = check_waypoints(waypoints, substeps)
    if waypoints.shape[0] == 1:
        return waypoints.copy()
    s = np.arange(substeps) / substeps  # (substeps,)
    starts, ends = waypoints[:-1], waypoints[1:]
    dense = starts[:, None, :] + s[None, :, None] * (ends - starts)[:, None, :]
    return np.concatenate([dense.reshape(-1, robot.N_ARM_JOINTS), waypoints[-1:]])


class CollisionChecker:
    """Collision checks on a private copy of the collision model (not thread-safe).

    Checks run ``mj_kinematics`` + ``mj_collision`` on one ``MjData``; a contact whose
    signed distance is below ``-tolerance`` is a collision. Self-collisions between the
    SRDF's disabled pairs (and :data:`EXTRA_EXCLUDES`) are never reported.
    """

    def __init__(self, *, tolerance: float = 0.0, model: mujoco.MjModel | None = None) -> None:
        """Build the checker.

        Args:
            tolerance: penetration depth (metres, >= 0) ignored as numerical contact.
            model: the scene to check in (a private copy is taken); default the collision
                model of :func:`build_model` (``models/scene.xml`` loads as another).
        """
        if not np.isfinite(tolerance) or tolerance < 0:
            raise ValueError(f"tolerance: expected a finite value >= 0, got {tolerance}")
        self.tolerance = float(tolerance)
        self.model = build_model(visual=False) if model is None else copy.copy(model)
        self.data = mujoco.MjData(self.model)
        self._body_names = tuple(self.model.body(i).name for i in range(self.model.nbody))
        self._geom_body = np.array(self.model.geom_bodyid)
        self._env_key: bytes | None = None

    def set_environment(self, env: Environment) -> None:
        """Move the table and laptop to ``env`` (skipped when already there)."""
        key = env.key()
        if key != self._env_key:
            place_environment(self.model, env)
            self._env_key = key

    def _contacts_now(self, sample: int, time: float) -> list[Contact]:
        d = self.data
        if d.ncon == 0:
            return []
        dist = np.array(d.contact.dist)
        hits = np.flatnonzero(dist < -self.tolerance)
        if hits.size == 0:
            return []
        geoms = np.array(d.contact.geom)[hits]  # (n, 2)
        bodies = np.sort(self._geom_body[geoms], axis=1)
        deepest: dict[tuple[int, int], float] = {}
        for (a, b), depth in zip(bodies.tolist(), (-dist[hits]).tolist(), strict=True):
            deepest[(a, b)] = max(depth, deepest.get((a, b), 0.0))
        return [
            Contact(sample, time, self._body_names[a], self._body_names[b], depth)
            for (a, b), depth in sorted(deepest.items())
        ]

    def _check_samples(self, samples: np.ndarray, substeps: int) -> CollisionReport:
        m, d = self.model, self.data
        contacts: list[Contact] = []
        for i, q in enumerate(samples):
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_collision(m, d)
            contacts += self._contacts_now(i, i / substeps)
        return CollisionReport(tuple(contacts), len(samples), substeps)

    def check_configuration(self, q: np.ndarray, env: Environment) -> CollisionReport:
        """Check one arm configuration (7,) in ``env``."""
        q = np.asarray(q, dtype=float)
        if q.shape != (robot.N_ARM_JOINTS,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q: expected 7 finite joint angles, got shape {q.shape}")
        self.set_environment(env)
        return self._check_samples(q[None, :], 1)

    def check_configurations(self, qs: Iterable[np.ndarray], env: Environment) -> CollisionReport:
        """Check a batch of configurations (N, 7); ``Contact.sample`` is the row index."""
        qs = np.asarray(qs, dtype=float)
        if qs.ndim != 2 or qs.shape[1] != robot.N_ARM_JOINTS or not np.all(np.isfinite(qs)):
            raise ValueError(f"qs: expected finite shape (N, 7), got {qs.shape}")
        self.set_environment(env)
        return self._check_samples(qs, 1)

    def check_trajectory(
        self, waypoints: np.ndarray, env: Environment, *, substeps: int = 8
    ) -> CollisionReport:
        """Check a trajectory, densely: waypoints (T, 7) joined by straight joint-space lines.

        Args:
            waypoints: (T, 7) joint waypoints.
            env: where the table and laptop are.
            substeps: samples per segment; ``(T - 1) * substeps + 1`` samples in all.

        Returns:
            The report; ``Contact.time`` locates each contact in waypoint units.
        """
        samples = interpolate(waypoints, substeps)
        self.set_environment(env)
        return self._check_samples(samples, int(substeps))

    def body_pose(self, q: np.ndarray, body: str) -> tuple[np.ndarray, np.ndarray]:
        """MuJoCo's world pose of ``body`` at arm configuration ``q`` (7,).

        Returns:
            Rotation (3, 3) and position (3,), copies.
        """
        try:
            body_id = self.model.body(body).id
        except KeyError:
            raise ValueError(f"body: no body named {body!r} in the scene") from None
        q = np.asarray(q, dtype=float)
        if q.shape != (robot.N_ARM_JOINTS,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q: expected 7 finite joint angles, got shape {q.shape}")
        set_configuration(self.model, self.data, q)
        return (
            np.array(self.data.xmat[body_id]).reshape(3, 3),
            np.array(self.data.xpos[body_id]),
        )


@functools.cache
def default_checker() -> CollisionChecker:
    """The process-wide checker used by the module-level functions (one per process)."""
    return CollisionChecker()


def check_configuration(q: np.ndarray, env: Environment) -> CollisionReport:
    """Collision check of one configuration (7,) in ``env``; see :class:`CollisionChecker`."""
    return default_checker().check_configuration(q, env)


def check_trajectory(
    waypoints: np.ndarray, env: Environment, *, substeps: int = 8
) -> CollisionReport:
    """Collision check of a trajectory (T, 7) in ``env``; see :class:`CollisionChecker`."""
    return default_checker().check_trajectory(waypoints, env, substeps=substeps)


def body_pose(q: np.ndarray, body: str) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's world rotation (3, 3) and position (3,) of ``body`` at ``q`` (7,)."""
    return default_checker().body_pose(q, body)
