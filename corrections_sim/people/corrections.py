"""How a person corrects a trajectory: pure functions on waypoints, shared by simulated users
and by the robot's *model* of a correction (the correction-aware filter, KF-C).

Given the robot's trajectory ξ (T, 7) and the trajectory the person intends, ξ* (T, 7), with
the first and last waypoints fixed, a correction returns ξ_h (T, 7):

* :func:`waypoint_correction` — the paper's §6 user: the ``count`` waypoints with the largest
  joint-space error ‖ξ*ᵢ − ξᵢ‖ move a fraction ``step`` of the way onto ξ*'s.
* :func:`deformation_correction` — a smooth local deformation around the worst waypoint i,
  in the style of Bajcsy et al. (2017) and Losey & O'Malley's trajectory deformations:
  ξ_h = ξ + μ A⁻¹ u, where A = KᵀK penalizes the jerk of the deformation (K: third finite
  differences, full convolution over the free waypoints, which makes A invertible), u pushes
  waypoint i along δ = ξ*ᵢ − ξᵢ, and μ is chosen so that waypoint i moves by ``step``·δ. The
  neighbours follow smoothly; the fixed start and goal do not move.

:class:`CorrectionModel` is one of them with its parameters, a frozen dataclass registered
by name in :data:`CORRECTIONS` ("waypoint", "deform", "optimal" — the intended trajectory
itself, the paper's Kalman filter's model of a correction —, and plug-ins). The same models
serve simulated users (:mod:`corrections_sim.people.users`: a user is a correction model
toward its own plan ξ*(θ*, E)) and the correction-aware learners' model of a person (KF-C).
"""

from __future__ import annotations

import abc
import functools
from dataclasses import dataclass

import numpy as np

from corrections_sim.components import ParameterError
from corrections_sim.registry import Registry

#: A waypoint counts as moved when it moved more than this (rad): what a learner reading a
#: correction takes for the waypoints the person moved.
MOVED = 1e-9


def _check_pair(robot, intended) -> tuple[np.ndarray, np.ndarray]:
    robot = np.asarray(robot, dtype=float)
    intended = np.asarray(intended, dtype=float)
    if robot.ndim != 2 or robot.shape != intended.shape or robot.shape[0] < 3:
        raise ValueError(
            f"robot {robot.shape} and intended {intended.shape}: expected two trajectories "
            "of one shape (T, n) with T >= 3"
        )
    return robot, intended


def _many(robot, intended) -> tuple[np.ndarray, np.ndarray]:
    """One robot trajectory (T, n) and many intended ones (m, T, n), checked."""
    robot = np.asarray(robot, dtype=float)
    intended = np.asarray(intended, dtype=float)
    if intended.ndim != 3 or intended.shape[1:] != robot.shape or robot.ndim != 2:
        raise ValueError(
            f"robot {robot.shape} and intended {intended.shape}: expected (T, n) and (m, T, n)"
        )
    _check_pair(robot, intended[0] if len(intended) else robot)
    return robot, intended


def _worst(robot: np.ndarray, intended: np.ndarray, count: int) -> np.ndarray:
    """(m, count): the ``count`` free waypoints of each intended (m, T, n) farthest from the
    robot's (T, n), worst first, ties to the lower index — :func:`worst_waypoints` for many
    at once."""
    errors = np.linalg.norm(intended - robot[None], axis=2)
    errors[:, 0] = errors[:, -1] = -np.inf  # start and goal are fixed
    return np.argsort(-errors, axis=1, kind="stable")[:, :count]


def _worst_mask(robot: np.ndarray, intended: np.ndarray, count: int) -> np.ndarray:
    """(m, T) bool: :func:`_worst`'s waypoints."""
    mask = np.zeros(intended.shape[:2], bool)
    np.put_along_axis(mask, _worst(robot, intended, count), True, axis=1)
    return mask


def _check_step(step: float) -> float:
    if isinstance(step, bool) or not (
        isinstance(step, int | float | np.number) and 0.0 < float(step) <= 1.0
    ):
        raise ParameterError("step", f"must lie in (0, 1], got {step!r}")
    return float(step)


def worst_waypoints(robot: np.ndarray, intended: np.ndarray, count: int = 1) -> np.ndarray:
    """Indices of the ``count`` free waypoints with the largest ‖intended − robot‖, worst first.

    Ties go to the lower index (a stable sort), so the choice is deterministic.
    """
    robot, intended = _check_pair(robot, intended)
    errors = np.linalg.norm(intended - robot, axis=1)
    errors[0] = errors[-1] = -np.inf  # start and goal are fixed
    order = np.argsort(-errors, kind="stable")
    return order[:count]


def waypoint_correction(
    robot: np.ndarray, intended: np.ndarray, step: float = 1.0, count: int = 1
) -> np.ndarray:
    """ξ_h (T, n): the ``count`` worst waypoints moved ``step`` of the way onto ``intended``.

    Args:
        robot: the robot's trajectory ξ, (T, n).
        intended: the person's intended trajectory ξ*, (T, n), same start and goal.
        step: fraction in (0, 1] of the way each corrected waypoint moves.
        count: how many waypoints change, 1 … T − 2.
    """
    robot, intended = _check_pair(robot, intended)
    step = _check_step(step)
    _check_count(count, robot.shape[0])
    out = robot.copy()
    for i in worst_waypoints(robot, intended, count):
        out[i] += step * (intended[i] - robot[i])
    return out


@functools.cache
def jerk_inverse(n_waypoints: int) -> np.ndarray:
    """A⁻¹ (T, T) of the minimum-jerk deformation, zero in the rows and columns of the fixed
    start and goal: A = KᵀK over the T − 2 free waypoints, K the full-convolution third
    difference [−1, 3, −3, 1] (T + 1 rows), so A is symmetric positive definite."""
    free = n_waypoints - 2
    k = np.zeros((free + 3, free))
    for j in range(free):
        k[j : j + 4, j] = (-1.0, 3.0, -3.0, 1.0)
    out = np.zeros((n_waypoints, n_waypoints))
    out[1:-1, 1:-1] = np.linalg.inv(k.T @ k)
    out.setflags(write=False)
    return out


@functools.cache
def deformation_shapes(n_waypoints: int) -> np.ndarray:
    """Columns A⁻¹eᵢ / (A⁻¹)ᵢᵢ of the minimum-jerk deformation, shape (T, T).

    Column i is how much each waypoint moves when waypoint i moves by one unit: 1 at row i,
    0 at the fixed start and goal (rows and columns 0 and T − 1 are zero), smooth between.
    A = KᵀK over the T − 2 free waypoints, K the full-convolution third difference
    [−1, 3, −3, 1] (T + 1 rows), so A is symmetric positive definite.
    """
    inverse = jerk_inverse(n_waypoints)
    diagonal = np.diag(inverse).copy()
    diagonal[[0, -1]] = 1.0  # start and goal columns are zero
    shapes = inverse / diagonal[None, :]
    shapes.setflags(write=False)
    return shapes


def deformation_correction(
    robot: np.ndarray, intended: np.ndarray, step: float = 1.0
) -> np.ndarray:
    """ξ_h = ξ + step · A⁻¹eᵢ/(A⁻¹)ᵢᵢ ⊗ (ξ*ᵢ − ξᵢ), i the worst waypoint; shape (T, n).

    Args:
        robot: the robot's trajectory ξ, (T, n).
        intended: the person's intended trajectory ξ*, (T, n).
        step: fraction in (0, 1] of the way the worst waypoint moves; the others follow the
            minimum-jerk shape of :func:`deformation_shapes`.
    """
    robot, intended = _check_pair(robot, intended)
    step = _check_step(step)
    i = int(worst_waypoints(robot, intended, 1)[0])
    shape = deformation_shapes(robot.shape[0])[:, i]
    return robot + step * np.outer(shape, intended[i] - robot[i])


def held_deformation(robot: np.ndarray, held: np.ndarray) -> np.ndarray:
    """ξ_H = ξ_R + μ A⁻¹ Ũ (Losey & O'Malley, T-RO 2018), shape (T, n).

    Args:
        robot: the robot's trajectory ξ_R, (T, n).
        held: Ũ (T, n): at each waypoint where the person held the arm, where they held it
            relative to ξ_R (rows of zeros elsewhere; start and goal rows are ignored).

    μ is the least-squares fit of the deformation at the held waypoints to Ũ there, so the
    trajectory goes where the person held it and the rest follows the minimum-jerk shape of
    :func:`deformation_shapes`. With one held waypoint i this is
    :func:`deformation_correction` toward ξ_R + Ũ (μ = 1 / (A⁻¹)ᵢᵢ).
    """
    robot = np.asarray(robot, dtype=float)
    held = np.array(held, dtype=float)
    if held.shape != robot.shape or robot.ndim != 2 or robot.shape[0] < 3:
        raise ValueError(f"held {held.shape}: expected the robot trajectory's shape {robot.shape}")
    held[[0, -1]] = 0.0
    rows = np.flatnonzero(np.any(held != 0.0, axis=1))
    if rows.size == 0:
        return robot.copy()
    direction = jerk_inverse(robot.shape[0]) @ held
    scale = float(np.sum(direction[rows] ** 2))
    mu = float(np.sum(direction[rows] * held[rows])) / scale if scale > 0 else 0.0
    return robot + mu * direction


def _check_count(count: int, n_waypoints: int) -> int:
    if isinstance(count, bool) or not isinstance(count, int | np.integer):
        raise ParameterError("waypoints", f"must be an integer, got {count!r}")
    if not 1 <= count <= n_waypoints - 2:
        raise ParameterError(
            "waypoints", f"{count} must lie in [1, {n_waypoints - 2}] (the free waypoints)"
        )
    return int(count)


class CorrectionModel(abc.ABC):
    """A way of correcting: C(ξ, ξ*) -> ξ_h. Subclass as a frozen dataclass whose fields are
    its parameters (checked in ``__post_init__``, raising :class:`ParameterError`), implement
    :meth:`apply`, and register it with ``@register_correction(name)``."""

    @abc.abstractmethod
    def apply(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        """ξ_h (T, n) for the robot's ξ (T, n) and the intended ξ* (T, n)."""

    def apply_many(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        """ξ_h (n, T, n_j) for one robot's ξ (T, n_j) and many intended ξ* (n, T, n_j): what
        an exact learner weighs at every node of its grid. By default :meth:`apply` on each;
        a model may answer all at once, but with the same bits as :meth:`apply`'s."""
        return np.stack([self.apply(robot, one) for one in np.asarray(intended, float)])

    def check(self, n_waypoints: int) -> None:
        """Refuse parameters that do not fit trajectories of ``n_waypoints`` waypoints
        (called once the planner's T is known, before anything runs)."""
        return None

    def at(self, robot: np.ndarray, intended: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """The correction toward ``intended`` at the waypoints ``rows`` (a boolean mask, the
        ones a person was seen to move), (m, n): what explaining an observed correction
        compares with it. By default :meth:`apply` there; a model that chooses which
        waypoints move (the worst ones) answers for the observed ones instead, so that the
        explanation does not jump when another waypoint becomes the worst."""
        return self.apply(robot, intended)[rows]

    def taken(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray | None:
        """Which waypoints of ξ_h are ξ*'s own, for many ξ* at once (``intended`` (n, T, n_j))
        -> (n, T) bool, when every other waypoint is the robot's (then Φ(ξ_h) needs no
        kinematics beyond ξ*'s and ξ's own waypoints); None for a model that moves waypoints
        elsewhere (a deformation, a partial step)."""
        return None


CORRECTIONS: Registry[type[CorrectionModel]] = Registry("correction model", base=CorrectionModel)
"""Every correction model by name."""


def register_correction(name: str, *, replace: bool = False):
    """Class decorator: register a :class:`CorrectionModel` dataclass under ``name``."""
    return CORRECTIONS.decorator(name, replace=replace)


@register_correction("waypoint")
@dataclass(frozen=True)
class WaypointCorrection(CorrectionModel):
    """The paper's §6 correction (:func:`waypoint_correction`).

    Attributes:
        step: fraction in (0, 1] of the way the worst waypoint(s) move onto ξ*'s.
        waypoints: how many of the worst waypoints move, ≥ 1.
    """

    step: float = 1.0
    waypoints: int = 1

    def __post_init__(self) -> None:
        _check_step(self.step)
        if isinstance(self.waypoints, bool) or not isinstance(self.waypoints, int | np.integer):
            raise ParameterError("waypoints", f"must be an integer, got {self.waypoints!r}")
        if self.waypoints < 1:
            raise ParameterError("waypoints", f"must be >= 1, got {self.waypoints}")

    def check(self, n_waypoints: int) -> None:
        _check_count(self.waypoints, n_waypoints)

    def at(self, robot: np.ndarray, intended: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """The observed waypoints moved ``step`` of the way onto ``intended``'s."""
        robot, intended = _check_pair(robot, intended)
        return robot[rows] + self.step * (intended[rows] - robot[rows])

    def apply(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        return waypoint_correction(robot, intended, self.step, self.waypoints)

    def apply_many(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        """:func:`waypoint_correction` toward each of ``intended`` (n, T, n_j) at once, the
        same operations element by element (so the same bits)."""
        robot, intended = _many(robot, intended)
        self.check(robot.shape[0])
        mask = _worst_mask(robot, intended, self.waypoints)
        return np.where(mask[:, :, None], robot[None] + self.step * (intended - robot[None]), robot)

    def taken(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray | None:
        """The worst ``waypoints`` of each ξ*, when the step is whole (ties to the lower
        index, as :func:`worst_waypoints`)."""
        if self.step != 1.0:
            return None
        return _worst_mask(np.asarray(robot, float), np.asarray(intended, float), self.waypoints)


@register_correction("deform")
@dataclass(frozen=True)
class DeformCorrection(CorrectionModel):
    """The minimum-jerk deformation around the worst waypoint (:func:`deformation_correction`).

    Attributes:
        step: fraction in (0, 1] of the way the worst waypoint moves; the rest follows.
    """

    step: float = 1.0

    def __post_init__(self) -> None:
        _check_step(self.step)

    def apply(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        return deformation_correction(robot, intended, self.step)

    def apply_many(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        """:func:`deformation_correction` toward each of ``intended`` (n, T, n_j) at once,
        the same operations element by element (so the same bits)."""
        robot, intended = _many(robot, intended)
        worst = _worst(robot, intended, 1)[:, 0]
        rows = np.arange(len(intended))
        shape = deformation_shapes(robot.shape[0])[:, worst].T  # (n, T)
        delta = intended[rows, worst] - robot[worst]  # (n, n_j)
        return robot[None] + self.step * (shape[:, :, None] * delta[:, None, :])


@register_correction("optimal")
@dataclass(frozen=True)
class OptimalCorrection(CorrectionModel):
    """The person shows ξ* itself (the paper's Kalman filter's model of a correction)."""

    def apply(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        _check_pair(robot, intended)
        return np.array(intended, dtype=float)

    def apply_many(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        _many(robot, intended)
        return np.array(intended, dtype=float)

    def taken(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray | None:
        return np.ones(np.shape(intended)[:2], bool)
