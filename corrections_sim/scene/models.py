"""The scene as MJCF files in the repository's ``models/`` folder: written here, opened by anyone.

``models/scene.xml``
    The Panda of example-robot-data's ``panda_collision.urdf`` (collision primitives in geom
    group 3, its STL meshes as visuals in group 2, fingers welded open), the pedestal, the
    table and laptop of environment :data:`SCENE_ENV`, the cup in the hand, lights, the
    figures' cameras (:data:`corrections_sim.scene.render.CAMERAS`) and keyframes ``start`` and
    ``goal``. ``python -m mujoco.viewer --mjcf models/scene.xml`` opens it.
``models/meshes/*.stl``
    example-robot-data's Panda collision meshes (118 kB), copied byte for byte so that the
    MJCF opens on any machine, with or without this package (``meshdir="meshes"`` is
    relative to the file); ``models/meshes/LICENSE`` is theirs (Apache 2.0).

The source of truth stays the code (:func:`corrections_sim.scene.world.build_spec`, the
dimensions in :mod:`corrections_sim.scene.geometry`, the installed example-robot-data):
``python -m corrections_sim.run models`` rewrites ``models/``, ``--check`` lists what drifted, and
``tests/test_models.py`` fails when the committed files differ from what :func:`scene_files`
makes, or when the model loaded from them disagrees with the collision checker's in forward
kinematics or collision verdicts.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from corrections_sim.scene import render, robot
from corrections_sim.scene import world as scene
from corrections_sim.scene.environments import paper_environments

#: The repository's models folder (next to the package in a source checkout).
MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
SCENE_FILE = "scene.xml"
MESH_DIR = "meshes"
#: The environment whose table and laptop poses and start/goal keyframes the file shows.
SCENE_ENV = "s0-t0-l1"

#: An XML comment may not contain two hyphens in a row (lxml, dm_control.mjcf refuse it).
_HEADER = (
    "<!-- The corrections_sim scene (Losey & O'Malley, CoRL 2018): Panda, pedestal, table, "
    "laptop, cup.\n"
    "     Written by `python -m corrections_sim.run models` from "
    "corrections_sim/scene/world.py, corrections_sim/scene/geometry.py\n"
    "     and example-robot-data's panda_collision.urdf; do not edit by hand: "
    "tests/test_models.py fails on drift.\n"
    "     Geom groups: 0 props, 2 robot meshes (visual only), 3 robot collision primitives.\n"
    "     Open it in MuJoCo's viewer as docs/scene.md says. -->\n"
)


class ModelFileError(ValueError):
    """A models/ file is missing, malformed, or not this project's scene."""


def _camera_quat(camera: render.Camera) -> tuple[np.ndarray, np.ndarray]:
    """Position (3,) and orientation quaternion (4,) of a fixed camera that shows what the
    free camera ``camera`` shows (MuJoCo cameras look along their −z axis, y up)."""
    az, el = np.radians(camera.azimuth), np.radians(camera.elevation)
    forward = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rotation = np.column_stack([right, up, -forward])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, rotation.ravel())
    position = np.asarray(camera.lookat) - camera.distance * forward
    return np.round(position, 6), np.round(quat, 6)


def scene_spec() -> mujoco.MjSpec:
    """The visual scene with the file's environment, cameras and keyframes (meshes absolute)."""
    spec = scene.build_spec(visual=True)
    env = {e.name: e for e in paper_environments()}[SCENE_ENV]
    lx, ly, yaw = env.laptop
    spec.body(scene.TABLE_BODY).pos = [*env.table, spec.body(scene.TABLE_BODY).pos[2]]
    spec.body(scene.LAPTOP_BODY).pos = [lx, ly, spec.body(scene.LAPTOP_BODY).pos[2]]
    spec.body(scene.LAPTOP_BODY).quat = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
    for name, camera in render.CAMERAS.items():
        position, quat = _camera_quat(camera)
        spec.worldbody.add_camera(name=name, pos=position, quat=quat)
    spec.add_key(name="start", qpos=np.round(env.q_start, 9))
    spec.add_key(name="goal", qpos=np.round(env.q_goal, 9))
    return spec


def _mesh_source() -> Path:
    return robot.panda_files().root / "meshes" / "collision"


def scene_files() -> dict[str, bytes]:
    """What ``models/`` must hold: relative path -> bytes (the MJCF, the meshes, their licence)."""
    spec = scene_spec()
    source = _mesh_source()
    spec.meshdir = str(source)
    for mesh in spec.meshes:
        mesh.file = Path(mesh.file).name
    xml = spec.to_xml().replace(f'meshdir="{source}/"', f'meshdir="{MESH_DIR}/"')
    xml = xml.replace(f'meshdir="{source}"', f'meshdir="{MESH_DIR}"')
    if str(source) in xml:
        raise RuntimeError(f"the MJCF still names {source}; the meshdir rewrite missed it")
    first_newline = xml.index("\n") + 1
    files = {SCENE_FILE: (xml[:first_newline] + _HEADER + xml[first_newline:]).encode()}
    for mesh in spec.meshes:
        files[f"{MESH_DIR}/{mesh.file}"] = (source / mesh.file).read_bytes()
    files[f"{MESH_DIR}/LICENSE"] = (robot.panda_files().root / "LICENSE").read_bytes()
    return files


def write(folder: Path = MODELS_DIR) -> list[Path]:
    """Write :func:`scene_files` under ``folder``; returns the paths written."""
    written = []
    for name, content in scene_files().items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(content)
        written.append(path)
    return written


def drift(folder: Path = MODELS_DIR) -> list[str]:
    """Files under ``folder`` that are missing or differ from :func:`scene_files` (sorted)."""
    return sorted(
        name
        for name, content in scene_files().items()
        if not (folder / name).is_file() or (folder / name).read_bytes() != content
    )


def load_model(path: str | Path = MODELS_DIR / SCENE_FILE) -> mujoco.MjModel:
    """Load an MJCF of the scene as MuJoCo's viewer does, and check it is this scene.

    Returns:
        The compiled model; ``qpos`` is the 7 arm joints.

    Raises:
        ModelFileError: the file is missing, not valid MJCF (a mesh it names is missing), or
            lacks a body the study needs. The message is one line and names the file.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"{path}: no such file")
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        detail = " ".join(str(exc).split())
        raise ModelFileError(f"{path}: not a loadable MJCF ({detail})") from None
    for body in (scene.CUP_BODY, scene.TABLE_BODY, scene.LAPTOP_BODY, "panda_hand"):
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body) < 0:
            raise ModelFileError(f"{path}: no body {body!r}; not the corrections_sim scene")
    if model.nq != robot.N_ARM_JOINTS:
        raise ModelFileError(f"{path}: {model.nq} joint coordinates, expected the Panda's 7")
    return model
