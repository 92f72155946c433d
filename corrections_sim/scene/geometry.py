"""Dimensions of the scene, shared by the MuJoCo model, the features and the planner.

World frame: the Panda's base (``panda_link0``) at the origin, x forward, z up. The robot
stands on a pedestal beside a table whose top is the plane ``z = TABLE_TOP_Z``. All lengths
are metres, angles radians.

One definition serves everyone: the MuJoCo scene draws these boxes and the planner keeps the
arm out of them, so the two can never disagree about where the table is.
"""

from __future__ import annotations

import numpy as np

# --- table -------------------------------------------------------------------------------
TABLE_TOP_Z = 0.0
TABLE_HALF_SIZE = (0.25, 0.35)  # half extents of the top along world x and y
TABLE_THICKNESS = 0.03
FLOOR_Z = -0.75
#: Allowed range of the table centre (x, y): the near edge stays clear of the pedestal and
#: the far edge within the arm's reach.
TABLE_X_RANGE = (0.45, 0.70)
TABLE_Y_RANGE = (-0.35, 0.35)

# --- robot pedestal ------------------------------------------------------------------------
PEDESTAL_RADIUS = 0.12

# --- laptop (on the table top; pose = x, y, yaw of the keyboard centre) --------------------
LAPTOP_BASE_HALF_SIZE = (0.14, 0.10, 0.01)  # keyboard slab half extents in the laptop frame
LAPTOP_SCREEN_HALF_SIZE = (0.14, 0.005, 0.095)  # screen slab half extents before its tilt
LAPTOP_SCREEN_TILT = 0.26  # rad the screen leans back from vertical
#: Keep-out ellipsoid that encloses keyboard and screen, in the laptop frame: centre
#: height above the table top and semi-axes (x, y, z). The planner keeps every arm sphere
#: outside this ellipsoid inflated by the sphere's radius.
LAPTOP_KEEPOUT_CENTER_Z = 0.04
LAPTOP_KEEPOUT_SEMI_AXES = (0.27, 0.27, 0.27)

# --- cup of coffee held in the hand ---------------------------------------------------------
CUP_RADIUS = 0.04
CUP_HALF_HEIGHT = 0.05
#: Cup centre in the ``panda_hand`` frame: on the approach axis, below the fingertips. The
#: cup's axis is the hand's z axis, so the coffee is upright when the hand points down.
CUP_CENTER_IN_HAND = (0.0, 0.0, 0.135)

# --- clearances -----------------------------------------------------------------------------
#: Minimum gap kept by the planner between any arm sphere and the table top or laptop.
CLEARANCE = 0.02


def laptop_rotation(yaw: float) -> np.ndarray:
    """Rotation (3, 3) of the laptop frame about world z."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def laptop_base_corners_xy(x: float, y: float, yaw: float) -> np.ndarray:
    """World (x, y) of the keyboard's four corners, shape (4, 2)."""
    hx, hy, _ = LAPTOP_BASE_HALF_SIZE
    local = np.array([[hx, hy], [hx, -hy], [-hx, hy], [-hx, -hy]])
    rot = laptop_rotation(yaw)[:2, :2]
    return local @ rot.T + np.array([x, y])
