"""The scene's visual pieces as triangle meshes, and their world poses at a configuration.

The browser page draws what :func:`corrections_sim.scene.world.build_model` (``visual=True``,
the model ``models/scene.xml`` is written from) shows: the Panda's visual meshes, the cup,
pedestal, table and laptop, and the floor. MuJoCo's primitives become meshes here (boxes,
cylinders along their local z, the floor as a thin box), so the page needs no convention of
its own about primitive axes. Pure functions of the model: plain arrays in, plain arrays out.
"""

from __future__ import annotations

import copy
import functools
from dataclasses import dataclass

import mujoco
import numpy as np

from corrections_sim.scene import world
from corrections_sim.scene.environments import Environment

#: MuJoCo's geom group of the Panda's visual meshes (group 3 holds its collision shapes).
VISUAL_GROUPS = (0, 1, 2)


@dataclass(frozen=True, eq=False)
class Piece:
    """One visual geom: its mesh in the geom's frame and its colour."""

    name: str
    geom: int
    vertices: np.ndarray  # (n, 3) float32
    faces: np.ndarray  # (m, 3) uint32
    rgb: tuple[int, int, int]
    moves: bool  # attached to the arm (its pose depends on q)


def _box(half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    faces = np.array(
        [
            [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
            [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
        ]
    )  # fmt: skip
    return signs * half, faces


def _cylinder(radius: float, half: float, segments: int = 32) -> tuple[np.ndarray, np.ndarray]:
    angles = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=1)
    bottom = np.column_stack([ring, np.full(segments, -half)])
    top = np.column_stack([ring, np.full(segments, half)])
    vertices = np.vstack([bottom, top, [[0, 0, -half], [0, 0, half]]])
    faces = []
    for i in range(segments):
        j = (i + 1) % segments
        faces += [[i, j, segments + j], [i, segments + j, segments + i]]
        faces += [[2 * segments, j, i], [2 * segments + 1, segments + i, segments + j]]
    return vertices, np.array(faces)


def _geom_mesh(model: mujoco.MjModel, i: int) -> tuple[np.ndarray, np.ndarray] | None:
    kind = model.geom_type[i]
    size = model.geom_size[i]
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        m = model.geom_dataid[i]
        v0, nv = model.mesh_vertadr[m], model.mesh_vertnum[m]
        f0, nf = model.mesh_faceadr[m], model.mesh_facenum[m]
        return model.mesh_vert[v0 : v0 + nv].copy(), model.mesh_face[f0 : f0 + nf].copy()
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return _box(size)
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return _cylinder(float(size[0]), float(size[1]))
    if kind == mujoco.mjtGeom.mjGEOM_PLANE:
        extent = size[:2] if np.all(size[:2] > 0) else np.array([2.0, 2.0])
        vertices, faces = _box(np.array([extent[0], extent[1], 0.002]))
        return vertices - np.array([0.0, 0.0, 0.002]), faces
    return None


@functools.cache
def visual_model() -> mujoco.MjModel:
    return world.build_model(visual=True)


@functools.cache
def pieces() -> tuple[Piece, ...]:
    """Every visual geom of the scene as a mesh (its collision shapes left out)."""
    model = visual_model()
    arm = {model.body(b).id for b in range(model.nbody) if model.body(b).name.startswith("panda")}
    out = []
    for i in range(model.ngeom):
        if model.geom_group[i] not in VISUAL_GROUPS:
            continue
        mesh = _geom_mesh(model, i)
        if mesh is None:
            continue
        body = model.geom_bodyid[i]
        name = model.geom(i).name or f"{model.body(body).name}_{i}"
        rgb = tuple(int(round(255 * c)) for c in model.geom_rgba[i][:3])
        moves = body in arm or model.body(body).name == world.CUP_BODY
        out.append(
            Piece(
                name=name,
                geom=i,
                vertices=np.asarray(mesh[0], np.float32),
                faces=np.asarray(mesh[1], np.uint32),
                rgb=rgb,
                moves=bool(moves),
            )
        )
    return tuple(out)


class Poser:
    """World poses (position (3,), quaternion wxyz (4,)) of every piece at a configuration."""

    def __init__(self) -> None:
        self.model = copy.copy(visual_model())  # place_environment moves its props
        self.data = mujoco.MjData(self.model)
        self._env_key: bytes | None = None

    def poses(self, q: np.ndarray, env: Environment) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        if env.key() != self._env_key:
            world.place_environment(self.model, env)
            self._env_key = env.key()
        self.data.qpos[:] = np.asarray(q, float)
        mujoco.mj_kinematics(self.model, self.data)
        out = {}
        quat = np.empty(4)
        for piece in pieces():
            mujoco.mju_mat2Quat(quat, self.data.geom_xmat[piece.geom])
            out[piece.geom] = (self.data.geom_xpos[piece.geom].copy(), quat.copy())
        return out
