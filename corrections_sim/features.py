r"""Features φ(x, E) of one waypoint and their sums Φ(ξ, E) over a trajectory.

Every feature is defined once, as a CasADi expression of the arm configuration q (7,) and the
environment parameters e = (laptop x, y, yaw, table x, y). The planner uses the expressions
symbolically; :func:`feature_counts` evaluates the same compiled function numerically. Each
per-waypoint feature lies in [0, 1] and is smooth (C^∞), so Φ(ξ, E) ∈ [0, T]^k.

With c the cup centre (world, metres) and z_h the hand's approach axis:

* ``laptop``  — how much the coffee is carried *over the laptop*:
  :math:`\exp\!\big(-\|c_{xy} - l_{xy}\|^2 / (2\,σ_l^2)\big)`, σ_l = ``LAPTOP_SCALE``.
* ``table``   — how close the coffee is to the table top while above it:
  :math:`s(c_{xy})\,\exp\!\big(-h^2 / (2\,σ_t^2)\big)`, h = c_z − table top, σ_t =
  ``TABLE_SCALE``, and s a smooth indicator of the table's footprint (product of logistic
  edges of width ``TABLE_EDGE``).
* ``coffee``  — how far the cup is tilted: :math:`(1 + z_h \cdot \hat z)/2`, 0 upright,
  1 upside down.

Positive weights θ_i make the robot seek a feature, negative ones avoid it.
"""

from __future__ import annotations

import functools

import casadi as ca
import numpy as np

from corrections_sim import geometry as g
from corrections_sim.robot import N_ARM_JOINTS, symbolic_fk

FEATURE_NAMES = ("laptop", "table", "coffee")
#: Number of environment parameters: laptop (x, y, yaw), table (x, y).
N_ENV_PARAMS = 5

LAPTOP_SCALE = 0.15  # m, σ_l
TABLE_SCALE = 0.20  # m, σ_t
TABLE_EDGE = 0.02  # m, width of the logistic footprint edges


def check_feature_names(names: tuple[str, ...]) -> tuple[str, ...]:
    """Validate a feature selection; returns it as a tuple."""
    names = tuple(names)
    unknown = [n for n in names if n not in FEATURE_NAMES]
    if unknown or not names or len(set(names)) != len(names):
        raise ValueError(
            f"features: {list(names)} must be distinct names from {list(FEATURE_NAMES)}"
        )
    return names


def _logistic(x: ca.SX) -> ca.SX:
    return 0.5 * (1 + ca.tanh(0.5 * x))


def symbolic_features(
    rot_hand: ca.SX, pos_hand: ca.SX, env: ca.SX, names: tuple[str, ...]
) -> ca.SX:
    """Per-waypoint features (k,) from the hand pose and environment parameters (5,)."""
    cup = pos_hand + rot_hand @ ca.DM(g.CUP_CENTER_IN_HAND)
    out = []
    for name in names:
        if name == "laptop":
            d2 = (cup[0] - env[0]) ** 2 + (cup[1] - env[1]) ** 2
            out.append(ca.exp(-d2 / (2 * LAPTOP_SCALE**2)))
        elif name == "table":
            hx, hy = g.TABLE_HALF_SIZE
            dx, dy = cup[0] - env[3], cup[1] - env[4]
            inside = (
                _logistic((hx + dx) / TABLE_EDGE)
                * _logistic((hx - dx) / TABLE_EDGE)
                * _logistic((hy + dy) / TABLE_EDGE)
                * _logistic((hy - dy) / TABLE_EDGE)
            )
            h = cup[2] - g.TABLE_TOP_Z
            out.append(inside * ca.exp(-(h**2) / (2 * TABLE_SCALE**2)))
        elif name == "coffee":
            out.append(0.5 * (1 + rot_hand[2, 2]))
        else:
            raise ValueError(f"unknown feature {name!r}")
    return ca.vertcat(*out)


@functools.cache
def waypoint_feature_function(names: tuple[str, ...]) -> ca.Function:
    """CasADi Function (q (7,), e (5,)) -> φ (k,) for one waypoint."""
    names = check_feature_names(names)
    q = ca.SX.sym("q", N_ARM_JOINTS)
    e = ca.SX.sym("e", N_ENV_PARAMS)
    rot, pos = symbolic_fk(q, ("panda_hand",))["panda_hand"]
    return ca.Function("phi", [q, e], [symbolic_features(rot, pos, e, names)], ["q", "e"], ["phi"])


@functools.cache
def _mapped(names: tuple[str, ...], n_waypoints: int) -> ca.Function:
    return waypoint_feature_function(names).map(n_waypoints)


def waypoint_features(
    trajectory: np.ndarray, env_params: np.ndarray, names: tuple[str, ...]
) -> np.ndarray:
    """Features of each waypoint, shape (T, k), for a trajectory (T, 7)."""
    traj = np.asarray(trajectory, dtype=float)
    if traj.ndim != 2 or traj.shape[1] != N_ARM_JOINTS:
        raise ValueError(f"trajectory: expected shape (T, {N_ARM_JOINTS}), got {traj.shape}")
    f = _mapped(check_feature_names(names), traj.shape[0])
    return np.asarray(f(traj.T, np.asarray(env_params, float))).T


def feature_counts(
    trajectory: np.ndarray, env_params: np.ndarray, names: tuple[str, ...]
) -> np.ndarray:
    """Φ(ξ, E) = Σ_i φ(x^i, E), shape (k,), for a trajectory (T, 7)."""
    return waypoint_features(trajectory, env_params, names).sum(axis=0)
