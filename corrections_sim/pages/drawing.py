"""How the pages draw: the camera, the colours and material of the scene, the cup's path, a
point's place on the screen, and the few helpers every page's controls share (a slider cleared
until answered, a count in words)."""

from __future__ import annotations

import numpy as np

from corrections_sim.scene.robot import cup_pose
from corrections_sim.scene.world import interpolate

#: Where the page's camera starts: beyond the table's far corner, looking back at the robot.
CAMERA_POSITION = (1.55, -1.05, 1.05)
CAMERA_LOOK_AT = (0.45, 0.0, 0.2)
CAMERA_FOV = 0.9  # vertical, radians
PLAN_RGB = (40, 110, 220)
CORRECTION_RGB = (235, 120, 20)
AVERSE_RGB = (30, 160, 80)
HANDLE_SCALE = 0.16
#: The scene's material: five-tone shading under the default lights. The standard material
#: samples the environment map at every pixel, which chromium's software WebGL (a machine
#: without a GPU) pays at every frame: the physical page during a motion drew 9–12 frames/s
#: with it, 24–31 with this (measured, docs/physical.md).
MESH_MATERIAL = "toon5"


def clear(slider) -> None:
    """Show a (float) ``slider`` unanswered: an empty box beside it, and a value on the
    server (NaN) that no value the page sends equals. viser 1.1.1 drops a value equal to the
    one it holds, so a keyboard user could not give the value a resting box showed (Enter in
    it sent nothing)."""
    slider.value = float("nan")


def resample_path(points: np.ndarray, count: int) -> np.ndarray:
    """At most ``count`` points evenly along the polyline ``points`` (n, 3), its ends kept."""
    points = np.asarray(points, float)
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    if points.shape[0] <= count or arc[-1] == 0.0:
        return points
    at = np.linspace(0.0, arc[-1], count)
    return np.column_stack([np.interp(at, arc, points[:, i]) for i in range(3)])


def cup_path(trajectory: np.ndarray, substeps: int = 6) -> np.ndarray:
    """Cup centre (N, 3) along the joint-space interpolation of ``trajectory`` (T, 7)."""
    return np.array([cup_pose(q)[1] for q in interpolate(trajectory, substeps)])


def project(
    point,
    width: float,
    height: float,
    *,
    position=CAMERA_POSITION,
    look_at=CAMERA_LOOK_AT,
    up=(0.0, 0.0, 1.0),
    fov: float = CAMERA_FOV,
) -> tuple[float, float]:
    """Pixel (x, y) of world ``point`` in a view ``width`` × ``height`` pixels from a camera
    at ``position`` looking at ``look_at`` with vertical field of view ``fov`` (radians); by
    default the page's initial camera. For driving the page from a script."""
    position = np.asarray(position, float)
    look_at = np.asarray(look_at, float)
    up = np.asarray(up, float)
    forward = look_at - position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    d = np.asarray(point, float) - position
    depth = d @ forward
    focal = (height / 2) / np.tan(fov / 2)
    x = width / 2 + focal * (d @ right) / depth
    y = height / 2 - focal * (d @ true_up) / depth
    return float(x), float(y)


def draw_path(scene, name: str, trajectory: np.ndarray, rgb) -> None:
    """The cup's path along ``trajectory`` (T, 7) as a line ``name`` in colour ``rgb``."""
    scene.add_spline_catmull_rom(
        name, cup_path(trajectory), thickness=3.0, thickness_units="screen", color=rgb
    )


def plural(n: int, word: str) -> str:
    """``word`` for ``n`` of them (one correction, two corrections)."""
    return word if n == 1 else word + "s"
