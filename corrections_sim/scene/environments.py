"""Environments E: where the robot starts and ends, where the laptop and the table are.

An :class:`Environment` is a frozen value. It is validated where it is made, so a laptop off
the table or a start outside the joint limits never reaches the planner.

Its parameters, the numbers features and the planner's constraints read, have names
(:data:`ENV_PARAMETERS`): ``laptop_x``, ``laptop_y``, ``laptop_yaw``, ``table_x``,
``table_y``, and whatever a plug-in registers with :func:`register_env_parameter` (a new
field with a default, set per environment through ``Environment(extra={...})``).
:meth:`Environment.params` is the vector of all of them in registration order; symbolic code
reads an entry by name (:func:`env_index`), never by position. Register parameters when a
plug-in module is imported, before any planner is built: the vector's length is part of it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from corrections_sim.registry import Registry
from corrections_sim.scene import geometry as g
from corrections_sim.scene.robot import N_ARM_JOINTS, inverse_kinematics, joint_limits


def _frozen_array(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.array(value, dtype=float, copy=True)
    if arr.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: all values must be finite, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


def _check_in_limits(name: str, q: np.ndarray) -> None:
    lo, hi = joint_limits()
    for i, (qi, lo_i, hi_i) in enumerate(zip(q, lo, hi, strict=True)):
        if not lo_i <= qi <= hi_i:
            raise ValueError(
                f"{name}[{i}] = {qi:.4f} rad is outside joint {i + 1}'s range "
                f"[{lo_i:.4f}, {hi_i:.4f}]"
            )


@dataclass(frozen=True, eq=False)
class Environment:
    """One environment E of the study.

    Attributes:
        q_start: start configuration of the 7 arm joints, shape (7,), rad.
        q_goal: goal configuration, shape (7,), rad (the cup's delivery pose).
        laptop: laptop pose on the table top, (x, y, yaw) of the keyboard centre.
        table: table centre (x, y); the top is at ``geometry.TABLE_TOP_Z``.
        name: a short label for plots and logs.
        extra: values of registered extra parameters (:func:`register_env_parameter`) by
            name; one left out takes its default.
    """

    q_start: np.ndarray
    q_goal: np.ndarray
    laptop: np.ndarray
    table: np.ndarray
    name: str = field(default="")
    extra: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = N_ARM_JOINTS
        object.__setattr__(self, "q_start", _frozen_array("q_start", self.q_start, (n,)))
        object.__setattr__(self, "q_goal", _frozen_array("q_goal", self.q_goal, (n,)))
        object.__setattr__(self, "laptop", _frozen_array("laptop", self.laptop, (3,)))
        object.__setattr__(self, "table", _frozen_array("table", self.table, (2,)))
        extra = {}
        for key, value in dict(self.extra).items():
            spec = ENV_PARAMETERS[key]
            if spec.default is None:
                raise ValueError(f"extra: {key!r} is one of the environment's own fields")
            value = float(value)
            if not np.isfinite(value):
                raise ValueError(f"extra.{key} = {value} must be finite")
            extra[key] = value
        object.__setattr__(self, "extra", extra)
        _check_in_limits("q_start", self.q_start)
        _check_in_limits("q_goal", self.q_goal)
        tx, ty = self.table
        for axis, value, (lo, hi) in (
            ("x", tx, g.TABLE_X_RANGE),
            ("y", ty, g.TABLE_Y_RANGE),
        ):
            if not lo <= value <= hi:
                raise ValueError(f"table.{axis} = {value:.3f} m is outside [{lo}, {hi}] m")
        corners = g.laptop_base_corners_xy(*self.laptop)
        hx, hy = g.TABLE_HALF_SIZE
        inside = (np.abs(corners[:, 0] - tx) <= hx) & (np.abs(corners[:, 1] - ty) <= hy)
        if not np.all(inside):
            raise ValueError(
                f"laptop = {self.laptop.tolist()} is off the table: its keyboard must lie "
                f"within x in [{tx - hx:.3f}, {tx + hx:.3f}] m, y in [{ty - hy:.3f}, "
                f"{ty + hy:.3f}] m"
            )

    def key(self) -> bytes:
        """Bytes that identify this environment's contents (for caches)."""
        arrays = (self.q_start, self.q_goal, self.laptop, self.table)
        key = b"".join(a.tobytes() for a in arrays)
        if self.extra:
            key += repr(sorted(self.extra.items())).encode()
        return key

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Environment) and self.key() == other.key()

    def __hash__(self) -> int:
        return hash(self.key())

    def params(self) -> np.ndarray:
        """The named parameters as a vector, in :data:`ENV_PARAMETERS` order (n,)."""
        return np.array([spec.value(self) for spec in ENV_PARAMETERS.values()], dtype=float)

    def param(self, name: str) -> float:
        """One named parameter, e.g. ``env.param("laptop_yaw")``."""
        return float(ENV_PARAMETERS[name].value(self))


@dataclass(frozen=True)
class EnvParameter:
    """A named number of an environment.

    Attributes:
        value: how to read it from an :class:`Environment`.
        default: None for the environment's own fields; else the value of an extra
            parameter an environment does not set.
    """

    value: Callable[[Environment], float]
    default: float | None = None


ENV_PARAMETERS: Registry[EnvParameter] = Registry("environment parameter")
"""Every named environment parameter, in the order of :meth:`Environment.params`."""
for _i, _name in enumerate(("laptop_x", "laptop_y", "laptop_yaw")):
    ENV_PARAMETERS.register(_name, EnvParameter(lambda e, i=_i: e.laptop[i]))
for _i, _name in enumerate(("table_x", "table_y")):
    ENV_PARAMETERS.register(_name, EnvParameter(lambda e, i=_i: e.table[i]))


def register_env_parameter(name: str, default: float) -> EnvParameter:
    """Add an extra environment parameter ``name`` (an environment sets it through
    ``extra={name: value}``; the others have ``default``)."""
    default = float(default)
    if not np.isfinite(default):
        raise ValueError(f"{name}: default = {default} must be finite")
    spec = EnvParameter(lambda e: e.extra.get(name, default), default)
    return ENV_PARAMETERS.register(name, spec)


def env_index(name: str) -> int:
    """Position of parameter ``name`` in :meth:`Environment.params` (for symbolic code)."""
    ENV_PARAMETERS[name]
    return list(ENV_PARAMETERS).index(name)


def n_env_params() -> int:
    """Length of :meth:`Environment.params`."""
    return len(ENV_PARAMETERS)


# --- the study's 48 environments ---------------------------------------------------------------

#: Cup-centre start positions (x, y, z), m: beside the table on the robot's left.
START_POSITIONS = (
    (0.40, 0.45, 0.22),
    (0.58, 0.42, 0.30),
    (0.33, 0.55, 0.35),
    (0.48, 0.55, 0.26),
)
#: Cup-centre goal position, m: the far side of the table on the robot's right.
GOAL_POSITION = (0.42, -0.52, 0.28)
#: Table centres (x, y), m.
TABLE_POSITIONS = ((0.55, 0.0), (0.60, -0.12), (0.50, 0.10))
#: Laptop poses relative to the table centre (dx, dy, yaw), m and rad.
LAPTOP_OFFSETS = ((0.0, 0.0, 0.0), (0.06, -0.14, 0.35), (-0.08, 0.05, -0.3), (0.08, 0.06, 0.0))
#: IK seed: the Panda's ready pose with the hand down, turned toward the target.
_IK_SEED = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, np.pi / 4])


def configuration_at(cup_position, yaw: float = 0.0) -> np.ndarray:
    """Arm configuration (7,) that holds the cup upright at ``cup_position`` (x, y, z).

    Raises:
        ValueError: no IK solution within the joint limits (the position is unreachable).
    """
    target = np.asarray(cup_position, dtype=float)
    seed = _IK_SEED.copy()
    seed[0] = np.arctan2(target[1], target[0])
    q = inverse_kinematics(target, yaw, seed)
    if q is None:
        raise ValueError(
            f"cup_position = {target.tolist()} is unreachable with the hand down "
            "(no IK solution within the joint limits)"
        )
    return q


#: The wrist joint that tilts the hand (and the cup) away from hand-down: joint 6 (index 5).
TILT_JOINT = 5


def tilted(q, angle: float) -> np.ndarray:
    """``q`` (7,) with the wrist (joint 6) turned by ``angle`` rad: the cup tilts (0.9 rad from
    hand-down gives ≈ 52°, coffee feature ≈ 0.19 per waypoint) and its centre moves a few cm.

    Environments whose start and goal hold the cup tilted make the coffee weight learnable:
    from an upright start the robot keeps the cup upright whatever θ_coffee ≤ 0
    (docs/three-features.md).

    Raises:
        ValueError: the turned joint leaves its range.
    """
    out = np.array(q, dtype=float, copy=True)
    out[TILT_JOINT] += float(angle)
    _check_in_limits("tilted q", out)
    return out


@functools.cache
def paper_environments() -> tuple[Environment, ...]:
    """The 48 environments of the study: 4 starts x 3 table positions x 4 laptop poses."""
    goal = configuration_at(GOAL_POSITION)
    envs = []
    for i, start in enumerate(START_POSITIONS):
        q_start = configuration_at(start)
        for j, (tx, ty) in enumerate(TABLE_POSITIONS):
            for k, (dx, dy, yaw) in enumerate(LAPTOP_OFFSETS):
                envs.append(
                    Environment(
                        q_start=q_start,
                        q_goal=goal,
                        laptop=(tx + dx, ty + dy, yaw),
                        table=(tx, ty),
                        name=f"s{i}-t{j}-l{k}",
                    )
                )
    return tuple(envs)


# --- grids of environments (figs. 1-2) ---------------------------------------------------------

#: Bounding box ((x), (y), (z) ranges, m) of the cup positions the arm may reach with the hand
#: down. Every reachable position lies inside; a position inside may still be unreachable
#: (:func:`configuration_at` raises), which grids mark per point.
CUP_WORKSPACE = ((-0.85, 0.85), (-0.85, 0.85), (0.1, 0.6))

# The laptop's allowed range is shrunk by this much (m), so a point on its edge cannot put
# the keyboard off the table by a rounding error in the validation of :class:`Environment`.
_EDGE_MARGIN = 1e-6


def _laptop_extent(yaw: float) -> np.ndarray:
    """Half extents (x, y) of the keyboard's footprint at ``yaw``, m."""
    return np.max(np.abs(g.laptop_base_corners_xy(0.0, 0.0, yaw)), axis=0)


def laptop_range(yaw: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """Where the laptop's centre (x, y) can be at ``yaw``, on a table anywhere in its range.

    The range is exact up to 1 µm (it is shrunk by that much against rounding).

    Returns:
        ((x_min, x_max), (y_min, y_max)), m.
    """
    slack = np.array(g.TABLE_HALF_SIZE) - _laptop_extent(yaw) - _EDGE_MARGIN
    (x0, x1), (y0, y1) = g.TABLE_X_RANGE, g.TABLE_Y_RANGE
    return (
        (float(x0 - slack[0]), float(x1 + slack[0])),
        (float(y0 - slack[1]), float(y1 + slack[1])),
    )


def table_holding(laptop, table) -> tuple[float, float]:
    """The table centre nearest to ``table`` whose top holds the laptop's keyboard.

    The table moves only as far as it must (per axis) and stays within its allowed range,
    so the result is ``table`` itself whenever the laptop already fits.

    Args:
        laptop: (x, y, yaw) of the keyboard centre.
        table: preferred table centre (x, y).

    Raises:
        ValueError: if no allowed table position holds the laptop (see :func:`laptop_range`).
    """
    lx, ly, yaw = (float(v) for v in laptop)
    slack = np.array(g.TABLE_HALF_SIZE) - _laptop_extent(yaw) - _EDGE_MARGIN
    out = []
    for axis, value, centre, s, (lo, hi) in (
        ("x", lx, table[0], slack[0], g.TABLE_X_RANGE),
        ("y", ly, table[1], slack[1], g.TABLE_Y_RANGE),
    ):
        if not lo - s <= value <= hi + s:
            raise ValueError(
                f"laptop.{axis} = {value:.6g} m: no table within [{lo}, {hi}] m holds it "
                f"(allowed [{lo - s:.6g}, {hi + s:.6g}] m)"
            )
        out.append(float(np.clip(np.clip(centre, value - s, value + s), lo, hi)))
    return out[0], out[1]
