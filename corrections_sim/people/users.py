"""Simulated users who know the true preference θ* and correct the robot.

* :class:`BiasedUser` — the paper's user (§6): looks at the robot's trajectory ξᵗ and its
  own intended trajectory ξ* = ξ*(θ*, E), picks the one waypoint with the largest joint-space
  error, and moves it a fraction ``step`` of the way toward the matching waypoint of ξ*.
  Its feature counts are a biased, partial improvement, which violates the Kalman filter's
  Gaussian observation model (K2) on purpose.
  With ``waypoints`` > 1 it moves that many of its worst waypoints.
* :class:`DeformingUser` — pushes its worst waypoint toward ξ* and the trajectory follows in
  a smooth minimum-jerk deformation (:func:`corrections_sim.people.corrections.deformation_correction`),
  as a person physically pushing the arm would.
* :class:`NoisyOptimalUser` — the Kalman filter's own assumption: Φ(ξ*) + n, n ~ N(0, σ²I).

All return Φ(ξ_h, E), the features of the correction, which is all the learners see. A user's
``stochastic`` says whether it draws from its generator (then every learner, active learning
included, runs as many times as the others).

A user is a :class:`User` subclass registered by name (:data:`USERS`, ``@register_user``);
its parameters are its dataclass fields, validated in ``__post_init__`` with messages that
name them. :func:`make_user` builds one by name, refusing unknown names and parameters.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from corrections_sim.people.corrections import deformation_correction, waypoint_correction
from corrections_sim.planning.features import feature_counts
from corrections_sim.registry import Registry
from corrections_sim.scene.environments import Environment


@dataclass(frozen=True, eq=False)
class Situation:
    """What a simulated user sees when it corrects the robot.

    Attributes:
        robot: the robot's trajectory ξᵗ = ξ*(θ̂ᵗ, E), (T, 7).
        intended: the user's own plan ξ*(θ*, E), (T, 7), same start and goal.
        env: the environment E.
        features: names of the features θ weighs, in order.
        theta_star: the user's true preference θ* (k,).
    """

    robot: np.ndarray
    intended: np.ndarray
    env: Environment
    features: tuple[str, ...]
    theta_star: np.ndarray


class User(abc.ABC):
    """A simulated user: turns the robot's trajectory into a correction.

    Implement :meth:`correct` (the corrected trajectory ξ_h, (T, 7)); the learners see its
    features, :meth:`correction_features`, which a user that shows features rather than a
    trajectory (e.g. with observation noise) overrides instead. ``stochastic`` says whether
    it draws from its generator (then every learner, active ones included, runs ``runs``
    times).
    """

    stochastic: ClassVar[bool] = False

    @abc.abstractmethod
    def correct(self, situation: Situation, rng: np.random.Generator) -> np.ndarray:
        """ξ_h, (T, 7): the corrected trajectory."""

    def correction_features(self, situation: Situation, rng: np.random.Generator) -> np.ndarray:
        """Φ(ξ_h, E), shape (k,), what the learners see."""
        return feature_counts(self.correct(situation, rng), situation.env, situation.features)


USERS: Registry[type[User]] = Registry("user", check=Registry.subclass_of(User))
"""Every simulated user by name."""


def register_user(name: str, *, replace: bool = False):
    """Class decorator: register a :class:`User` subclass (a dataclass) under ``name``."""
    return USERS.decorator(name, replace=replace)


def user_parameters(name: str) -> dict[str, Any]:
    """The parameters of user ``name`` with their defaults (``dataclasses.MISSING`` if none)."""
    cls = USERS[name]
    if not dataclasses.is_dataclass(cls):
        return {}
    return {
        f.name: f.default
        if f.default is not dataclasses.MISSING
        else (f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default)
        for f in dataclasses.fields(cls)
        if f.init
    }


def make_user(name: str, params: Mapping[str, Any] | None = None) -> User:
    """The registered user ``name`` with ``params``.

    Raises:
        ValueError: an unknown user or parameter, or a bad value; one line naming it.
    """
    cls = USERS[name]
    params = dict(params or {})
    known = user_parameters(name)
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise ValueError(
            f"user {name}: unknown parameter {unknown[0]!r} (known: {', '.join(known) or 'none'})"
        )
    try:
        return cls(**params)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"user {name}: {exc}") from None


class _EditingUser(User):
    """A user who edits the robot's trajectory deterministically (``corrected_trajectory``)."""

    def corrected_trajectory(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def correct(self, situation: Situation, rng: np.random.Generator) -> np.ndarray:
        """ξ_h (T, 7); deterministic, ``rng`` is unused."""
        return self.corrected_trajectory(situation.robot, situation.intended)


@register_user("biased")
@dataclass(frozen=True)
class BiasedUser(_EditingUser):
    """Corrects its worst waypoint(s) toward its intended trajectory.

    Attributes:
        step: fraction in (0, 1] of the way the worst waypoint moves toward ξ*'s
            (default 1: the user puts that waypoint where they want it).
        waypoints: how many of the worst waypoints it moves (default 1, the paper's user).
    """

    step: float = 1.0
    waypoints: int = 1

    def __post_init__(self) -> None:
        if not (isinstance(self.step, int | float) and 0.0 < self.step <= 1.0):
            raise ValueError(f"step = {self.step!r} must lie in (0, 1]")
        if isinstance(self.waypoints, bool) or not isinstance(self.waypoints, int):
            raise ValueError(f"waypoints = {self.waypoints!r} must be an integer")
        if self.waypoints < 1:
            raise ValueError(f"waypoints = {self.waypoints} must be >= 1")

    def corrected_trajectory(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        """ξ_h (T, 7): ``robot`` (T, 7) with its worst waypoint(s) moved toward ``intended``."""
        robot = np.asarray(robot, float)
        if self.waypoints > robot.shape[0] - 2:
            raise ValueError(
                f"waypoints = {self.waypoints}: more than the {robot.shape[0] - 2} free waypoints"
            )
        return waypoint_correction(robot, intended, self.step, self.waypoints)


@register_user("deform")
@dataclass(frozen=True)
class DeformingUser(_EditingUser):
    """Pushes its worst waypoint ``step`` of the way toward ξ*'s; the rest deforms smoothly.

    Attributes:
        step: fraction in (0, 1] of the way the worst waypoint moves.
    """

    step: float = 1.0

    def __post_init__(self) -> None:
        if not (isinstance(self.step, int | float) and 0.0 < self.step <= 1.0):
            raise ValueError(f"step = {self.step!r} must lie in (0, 1]")

    def corrected_trajectory(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        """ξ_h (T, 7), see :func:`corrections_sim.people.corrections.deformation_correction`."""
        return deformation_correction(robot, intended, self.step)


@register_user("noisy")
@dataclass(frozen=True)
class NoisyOptimalUser(User):
    """Shows its optimal trajectory's features with Gaussian noise of std ``noise`` per feature."""

    noise: float = 0.1
    stochastic: ClassVar[bool] = True

    def __post_init__(self) -> None:
        number = isinstance(self.noise, int | float) and not isinstance(self.noise, bool)
        if not (number and np.isfinite(self.noise) and self.noise >= 0):
            raise ValueError(f"noise = {self.noise!r} must be finite and >= 0")

    def correct(self, situation: Situation, rng: np.random.Generator) -> np.ndarray:
        """ξ*(θ*, E): the trajectory it shows (its features are observed with noise)."""
        return np.array(situation.intended, dtype=float)

    def correction_features(self, situation: Situation, rng: np.random.Generator) -> np.ndarray:
        """Φ(ξ*, E) + n, shape (k,)."""
        phi = feature_counts(situation.intended, situation.env, situation.features)
        return phi + rng.normal(0.0, self.noise, size=phi.shape)
