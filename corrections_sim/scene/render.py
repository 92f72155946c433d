"""Offscreen images of the scene: the arm at a configuration, the props, the cup's paths.

Headless by default: ``MUJOCO_GL`` defaults to ``egl`` (Mesa's llvmpipe works without a GPU;
Debian needs ``libegl1 libegl-mesa0 libopengl0 libgl1-mesa-dri``). ``MUJOCO_GL=osmesa``
(``libosmesa6``) works too. The GL context is chosen here from ``MUJOCO_GL`` at render time,
not when :mod:`mujoco` was first imported, so importing :mod:`corrections_sim.scene.world` first
does not pin a windowed backend.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import atexit  # noqa: E402
import functools  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from corrections_sim.scene import world as scene  # noqa: E402
from corrections_sim.scene.environments import Environment  # noqa: E402
from corrections_sim.scene.robot import cup_pose  # noqa: E402

_FIX_HINT = (
    "install libegl1 libegl-mesa0 libopengl0 libgl1-mesa-dri (MUJOCO_GL=egl) "
    "or libosmesa6 (MUJOCO_GL=osmesa)"
)


@dataclass(frozen=True)
class Camera:
    """A free camera: it looks at ``lookat`` from ``distance`` metres away.

    Attributes:
        lookat: world point (x, y, z) at the image centre.
        distance: metres from the camera to ``lookat``.
        azimuth: degrees about world z of the viewing direction (0 looks along +x).
        elevation: degrees of the viewing direction above the horizon (negative looks down).
    """

    lookat: tuple[float, float, float] = (0.42, 0.0, 0.1)
    distance: float = 1.75
    azimuth: float = 160.0
    elevation: float = -42.0


#: Looks from the table's far corner back at the robot: pedestal, arm, table, laptop, and
#: cup positions anywhere over the table are in view.
DEFAULT_CAMERA = Camera()
#: Looks from beyond the table's far left corner and lower: heights of cup paths over the
#: table and the laptop show (the figures' renders).
SIDE_CAMERA = Camera(lookat=(0.5, 0.0, 0.15), distance=1.6, azimuth=200.0, elevation=-35.0)
#: Looks down from beyond the table (world y to the right of the image): where the cup
#: passes over the table and the laptop.
TOP_CAMERA = Camera(lookat=(0.45, 0.0, 0.1), distance=1.55, azimuth=180.0, elevation=-62.0)
#: SIDE_CAMERA from further back: the whole arm stays in view while it moves (the video).
VIDEO_CAMERA = Camera(lookat=(0.4, 0.0, 0.3), distance=2.1, azimuth=205.0, elevation=-28.0)
#: The views by name; ``models/scene.xml`` has a fixed camera of each name.
CAMERAS = {
    "overview": DEFAULT_CAMERA,
    "side": SIDE_CAMERA,
    "top": TOP_CAMERA,
    "video": VIDEO_CAMERA,
}

#: A path of the cup: world points (N, 3) and an rgba colour (4,), optionally followed by
#: the radius (m) of the spheres at its points (default: ``render_scene``'s waypoint_radius).
Path3 = tuple[np.ndarray, Sequence[float]] | tuple[np.ndarray, Sequence[float], float]


def cup_path(trajectory: np.ndarray, substeps: int = 6) -> np.ndarray:
    """Cup centre (N, 3) along the joint-space interpolation of a trajectory (T, 7).

    N = (T − 1) · substeps + 1: the path the cup really follows between waypoints.
    """
    return np.array([cup_pose(q)[1] for q in scene.interpolate(trajectory, substeps)])


@functools.cache
def _visual_model() -> mujoco.MjModel:
    return scene.build_model(visual=True)


class _Offscreen:
    """A GL context and MuJoCo render context, made once per process and backend.

    Making them costs ~0.3 s with llvmpipe, as much as a frame; they are freed at exit
    (before ``mujoco.egl`` terminates its display).
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        self.backend = os.environ.get("MUJOCO_GL", "egl").lower()
        width, height = model.vis.global_.offwidth, model.vis.global_.offheight
        try:
            if self.backend == "egl":
                from mujoco.egl import GLContext
            elif self.backend == "osmesa":
                from mujoco.osmesa import GLContext
            elif self.backend == "glfw":
                from mujoco.glfw import GLContext
            else:
                raise ValueError("not one of egl, osmesa, glfw")
            self.gl = GLContext(width, height)
            self.gl.make_current()
            self.mjr = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        except Exception as exc:
            raise RuntimeError(
                f"MUJOCO_GL={self.backend}: no OpenGL context ({type(exc).__name__}: {exc}); "
                f"{_FIX_HINT}"
            ) from exc
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self.mjr)
        atexit.register(self.free)

    def free(self) -> None:
        self.mjr.free()
        self.gl.free()


#: One context per (backend, model): a render context holds its model's meshes and textures.
_OFFSCREEN: dict[tuple[str, int], _Offscreen] = {}


def _offscreen(model: mujoco.MjModel) -> _Offscreen:
    key = (os.environ.get("MUJOCO_GL", "egl").lower(), id(model))
    if key not in _OFFSCREEN:
        _OFFSCREEN[key] = _Offscreen(model)
    offscreen = _OFFSCREEN[key]
    offscreen.gl.make_current()
    return offscreen


def _add_geom(
    scn: mujoco.MjvScene, kind: int, size: np.ndarray, pos: np.ndarray, rgba: np.ndarray
) -> mujoco.MjvGeom:
    if scn.ngeom >= scn.maxgeom:
        raise ValueError(f"paths: more than {scn.maxgeom} geoms to draw; pass fewer points")
    geom = scn.geoms[scn.ngeom]
    mujoco.mjv_initGeom(geom, kind, size, pos, np.eye(3).ravel(), rgba)
    geom.category = mujoco.mjtCatBit.mjCAT_DECOR
    scn.ngeom += 1
    return geom


def _draw_paths(
    scn: mujoco.MjvScene, paths: Sequence[Path3], radius: float, waypoint_radius: float
) -> None:
    """Append each path as capsules between consecutive points and spheres at the points."""
    for i, (points, rgba, *size) in enumerate(paths):
        points = np.asarray(points, dtype=float)
        sphere = float(size[0]) if size else waypoint_radius
        if len(size) > 1 or not (np.isfinite(sphere) and sphere > 0):
            raise ValueError(f"paths[{i}]: expected (points, rgba) or (points, rgba, radius > 0)")
        if points.ndim != 2 or points.shape[1] != 3 or not np.all(np.isfinite(points)):
            raise ValueError(f"paths[{i}]: points must be finite with shape (N, 3)")
        color = np.asarray(rgba, dtype=np.float32)
        if color.shape != (4,) or np.any((color < 0) | (color > 1)):
            raise ValueError(f"paths[{i}]: rgba must be 4 values in [0, 1]")
        for a, b in zip(points[:-1], points[1:], strict=True):
            if np.allclose(a, b):
                continue
            geom = _add_geom(scn, mujoco.mjtGeom.mjGEOM_CAPSULE, np.zeros(3), np.zeros(3), color)
            mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_CAPSULE, radius, a, b)
        for p in points:
            _add_geom(scn, mujoco.mjtGeom.mjGEOM_SPHERE, np.full(3, sphere), p, color)


def render_scene(
    env: Environment,
    paths: Sequence[Path3] = (),
    *,
    q: np.ndarray | None = None,
    width: int = 960,
    height: int = 720,
    camera: Camera = DEFAULT_CAMERA,
    path_radius: float = 0.004,
    waypoint_radius: float = 0.012,
    show_goal: bool = True,
    model: mujoco.MjModel | None = None,
) -> np.ndarray:
    """Render the arm at ``q`` in ``env`` with the cup paths drawn over the scene.

    Args:
        env: table and laptop poses; ``env.q_start`` is the default configuration.
        paths: sequence of (points (N, 3) world positions of the cup centre, rgba (4,)),
            each optionally with a third element, its own sphere radius in metres.
        q: arm configuration (7,) to show; defaults to ``env.q_start``.
        width: image width in pixels (at most 1920).
        height: image height in pixels (at most 1440).
        camera: the free camera.
        path_radius: radius of the capsules joining consecutive points, metres.
        waypoint_radius: radius of the sphere at each point, metres (unless the path gives
            its own).
        show_goal: mark the cup centre at ``env.q_goal`` with a translucent green sphere.
        model: the scene to draw, kept alive by the caller (e.g. ``models/scene.xml`` loaded
            by :func:`corrections_sim.scene.models.load_model`); default the scene built in code.

    Returns:
        RGB image, shape (height, width, 3), uint8.

    Raises:
        RuntimeError: when no OpenGL context can be made with ``MUJOCO_GL``'s backend.
    """
    model = _visual_model() if model is None else model
    max_w, max_h = model.vis.global_.offwidth, model.vis.global_.offheight
    if not (0 < width <= max_w and 0 < height <= max_h):
        raise ValueError(f"width, height: expected within (0, {max_w}] x (0, {max_h}]")
    q = env.q_start if q is None else np.asarray(q, dtype=float)
    if q.shape != (7,) or not np.all(np.isfinite(q)):
        raise ValueError(f"q: expected 7 finite joint angles, got shape {q.shape}")

    scene.place_environment(model, env)
    data = mujoco.MjData(model)
    cup = model.body(scene.CUP_BODY).id
    scene.set_configuration(model, data, env.q_goal)
    goal_cup = np.array(data.xpos[cup])
    scene.set_configuration(model, data, q)
    mujoco.mj_forward(model, data)

    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = camera.lookat
    cam.distance = camera.distance
    cam.azimuth = camera.azimuth
    cam.elevation = camera.elevation
    option = mujoco.MjvOption()
    option.geomgroup[:] = 0
    option.geomgroup[scene.GROUP_PROPS] = 1
    option.geomgroup[scene.GROUP_ROBOT_MESH] = 1

    scn = mujoco.MjvScene(model, maxgeom=model.ngeom + 4000)
    mujoco.mjv_updateScene(model, data, option, None, cam, mujoco.mjtCatBit.mjCAT_ALL.value, scn)
    _draw_paths(scn, paths, path_radius, waypoint_radius)
    if show_goal:
        rgba = np.array([0.1, 0.75, 0.25, 0.45], dtype=np.float32)
        _add_geom(scn, mujoco.mjtGeom.mjGEOM_SPHERE, np.full(3, 0.05), goal_cup, rgba)

    offscreen = _offscreen(model)
    viewport = mujoco.MjrRect(0, 0, width, height)
    mujoco.mjr_render(viewport, scn, offscreen.mjr)
    image = np.empty((height, width, 3), dtype=np.uint8)
    mujoco.mjr_readPixels(image, None, viewport, offscreen.mjr)
    return np.flipud(image).copy()
