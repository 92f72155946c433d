"""Simulated users who know the true preference θ* and correct the robot.

A simulated user is a correction model (:mod:`corrections_sim.people.corrections`) applied
toward its own plan ξ* = ξ*(θ*, E), plus, for some, noise:

* :class:`BiasedUser` ("biased") — the paper's user (§6): the one waypoint of the robot's ξᵗ
  with the largest joint-space error moves a fraction ``step`` of the way toward ξ*'s (the
  "waypoint" model; with ``waypoints`` > 1, that many). A biased, partial improvement, which
  violates the Kalman filter's Gaussian observation model (K2) on purpose.
* :class:`DeformingUser` ("deform") — pushes its worst waypoint toward ξ* and the trajectory
  follows in a smooth minimum-jerk deformation (the "deform" model), as a person physically
  pushing the arm would.
* :class:`NoisyOptimalUser` ("noisy") — the Kalman filter's own assumption: Φ(ξ*) + n,
  n ~ N(0, σ²I) (the "optimal" model plus feature noise).
* :class:`ModelUser` ("model") — any registered correction model, plug-ins included, with
  optional feature noise: ``[user] name = "model", model = { name = "deform", step = 0.5 }``.

All return Φ(ξ_h, E), the features of the correction, which is all the learners see. A user's
``stochastic`` says whether it draws from its generator (then every learner, active learning
included, runs as many times as the others).

A user is a :class:`User` subclass, a frozen dataclass whose fields are its parameters,
registered by name (:data:`USERS`, ``@register_user``); :func:`make_user` builds one by name
through :func:`corrections_sim.components.build`, refusing unknown names and parameters.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from corrections_sim import components
from corrections_sim.components import ParameterError
from corrections_sim.people.corrections import (
    CORRECTIONS,
    CorrectionModel,
    DeformCorrection,
    OptimalCorrection,
    WaypointCorrection,
)
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


@dataclass(frozen=True, eq=False)
class TaskOutcome:
    """What one task of a user gave: the correction's features, and for a user who corrects
    during the motion (:mod:`corrections_sim.people.physical`) the motion the person got.

    Attributes:
        phi_h: Φ(ξ_h, E), shape (k,), what the learners see.
        executed: the executed motion at the plan's waypoint times (T, 7), or None (a user who
            corrects a plan rather than a motion).
        executed_kept: with online replanning, the motion the robot would have made had it kept
            its plan after the push (T, 7), from the same state; else None.
        extras: per-task numbers for the records (``effort``, ``push_time``, …).
        corrected: the corrected trajectory ξ_h (T, 7) the robot observed, for learners that
            judge a correction in joint space (relevance); None where the person shows
            features rather than a trajectory (feature noise).
        relevant: the ground truth for scoring relevance estimates: False for a correction
            that carries no preference (a nudge), True for one made toward the person's plan,
            None for a user that never makes irrelevant ones (no label recorded).
    """

    phi_h: np.ndarray
    executed: np.ndarray | None = None
    executed_kept: np.ndarray | None = None
    extras: Mapping[str, float] = field(default_factory=dict)
    corrected: np.ndarray | None = None
    relevant: bool | None = None


class User(abc.ABC):
    """A simulated user: turns the robot's trajectory into a correction.

    Implement :meth:`correct` (the corrected trajectory ξ_h, (T, 7)); the learners see its
    features, :meth:`correction_features`, which a user that shows features rather than a
    trajectory (e.g. with observation noise) overrides instead. ``stochastic`` says whether
    it draws from its generator (then every learner, active ones included, runs ``runs``
    times).
    """

    stochastic: ClassVar[bool] = False
    #: Corrects during the motion (then :meth:`perform` takes ``replan`` and a study may learn
    #: online), rather than a plan.
    during_motion: ClassVar[bool] = False

    @abc.abstractmethod
    def correct(self, situation: Situation, rng: np.random.Generator) -> np.ndarray:
        """ξ_h, (T, 7): the corrected trajectory."""

    def observe(
        self, corrected: np.ndarray, situation: Situation, rng: np.random.Generator
    ) -> np.ndarray:
        """What the learners see of the correction ``corrected``: Φ(ξ_h, E), shape (k,), by
        default; a user with feature noise adds it here."""
        return feature_counts(corrected, situation.env, situation.features)

    def shows_trajectory(self) -> bool:
        """Whether the learners may read the corrected trajectory itself (not when what they
        see is noisy features of it)."""
        return True

    def correction_features(self, situation: Situation, rng: np.random.Generator) -> np.ndarray:
        """Φ(ξ_h, E), shape (k,), what the learners see."""
        return self.observe(self.correct(situation, rng), situation, rng)

    def perform(self, situation: Situation, rng: np.random.Generator, replan=None) -> TaskOutcome:
        """The whole task: by default the correction, its features and the corrected
        trajectory. A user who corrects during the motion overrides it and calls ``replan``
        (online learning) when its correction is over; others ignore ``replan``."""
        corrected = self.correct(situation, rng)
        return TaskOutcome(
            phi_h=self.observe(corrected, situation, rng),
            corrected=corrected if self.shows_trajectory() else None,
        )

    def check(self, n_waypoints: int) -> None:
        """Refuse parameters that do not fit trajectories of ``n_waypoints`` waypoints."""
        return None


class CorrectingUser(User):
    """A user who corrects with a correction model toward ξ*(θ*, E), deterministically."""

    def model(self) -> CorrectionModel:
        """The correction model this user corrects with."""
        raise NotImplementedError

    def correct(self, situation: Situation, rng: np.random.Generator) -> np.ndarray:
        """ξ_h = C(ξᵗ, ξ*) (T, 7)."""
        return self.corrected_trajectory(situation.robot, situation.intended)

    def corrected_trajectory(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        """ξ_h (T, 7) for the robot's ξ (T, 7) and the user's own plan ξ* (T, 7)."""
        return self.model().apply(robot, intended)

    def check(self, n_waypoints: int) -> None:
        self.model().check(n_waypoints)


USERS: Registry[type[User]] = Registry("user", base=User)
"""Every simulated user by name."""


def register_user(name: str, *, replace: bool = False):
    """Class decorator: register a :class:`User` subclass (a dataclass) under ``name``."""
    return USERS.decorator(name, replace=replace)


def user_parameters(name: str) -> dict[str, Any]:
    """The parameters of user ``name`` with their defaults (``dataclasses.MISSING`` if none)."""
    return components.defaults(USERS[name])


def make_user(name: str, params: Mapping[str, Any] | None = None, *, where: str = "user") -> User:
    """The registered user ``name`` with ``params``.

    Raises:
        ValueError: an unknown user or parameter, or a bad value; one line naming its key
            path (``user.step: must lie in (0, 1], got 2``).
    """
    return components.build(USERS, name, params, where=where)


@register_user("biased")
@dataclass(frozen=True)
class BiasedUser(CorrectingUser):
    """Corrects its worst waypoint(s) toward its intended trajectory ("waypoint" model).

    Attributes:
        step: fraction in (0, 1] of the way the worst waypoint moves toward ξ*'s
            (default 1: the user puts that waypoint where they want it).
        waypoints: how many of the worst waypoints it moves (default 1, the paper's user).
    """

    step: float = 1.0
    waypoints: int = 1

    def __post_init__(self) -> None:
        self.model()

    def model(self) -> WaypointCorrection:
        return WaypointCorrection(self.step, self.waypoints)


@register_user("deform")
@dataclass(frozen=True)
class DeformingUser(CorrectingUser):
    """Pushes its worst waypoint ``step`` of the way toward ξ*'s; the rest deforms smoothly.

    Attributes:
        step: fraction in (0, 1] of the way the worst waypoint moves.
    """

    step: float = 1.0

    def __post_init__(self) -> None:
        self.model()

    def model(self) -> DeformCorrection:
        return DeformCorrection(self.step)


def _check_noise(noise) -> None:
    number = isinstance(noise, int | float) and not isinstance(noise, bool)
    if not (number and np.isfinite(noise) and noise >= 0):
        raise ParameterError("noise", f"must be finite and >= 0, got {noise!r}")


@register_user("noisy")
@dataclass(frozen=True)
class NoisyOptimalUser(User):
    """Shows its optimal trajectory's features with Gaussian noise of std ``noise`` per feature.

    Attributes:
        noise: σ, the std of the noise per feature. Default 0.5 = √0.25: the filters' default
            observation noise N = 0.25 I, so by default this user is the KF's own model.
    """

    noise: float = 0.5
    stochastic: ClassVar[bool] = True

    def __post_init__(self) -> None:
        _check_noise(self.noise)

    def correct(self, situation: Situation, rng: np.random.Generator) -> np.ndarray:
        """ξ*(θ*, E): the trajectory it shows (its features are observed with noise)."""
        return OptimalCorrection().apply(situation.robot, situation.intended)

    def observe(
        self, corrected: np.ndarray, situation: Situation, rng: np.random.Generator
    ) -> np.ndarray:
        """Φ(ξ*, E) + n, shape (k,)."""
        phi = feature_counts(corrected, situation.env, situation.features)
        return phi + rng.normal(0.0, self.noise, size=phi.shape)

    def shows_trajectory(self) -> bool:
        return False


@register_user("model")
@dataclass(frozen=True)
class ModelUser(CorrectingUser):
    """Corrects with any registered correction model, plus Gaussian feature noise.

    Attributes:
        correction: the correction model, a name or a table (``{ name = "deform", step = 0.5 }``).
        noise: σ ≥ 0 of Gaussian noise added to Φ(ξ_h) per feature (0: none, deterministic).
    """

    correction: CorrectionModel = components.nested(CORRECTIONS, WaypointCorrection())
    noise: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.correction, CorrectionModel):
            raise ParameterError(
                "correction", f"expected a correction model, got {self.correction!r}"
            )
        _check_noise(self.noise)

    @property
    def stochastic(self) -> bool:  # type: ignore[override]
        return self.noise > 0

    def model(self) -> CorrectionModel:
        return self.correction

    def observe(
        self, corrected: np.ndarray, situation: Situation, rng: np.random.Generator
    ) -> np.ndarray:
        phi = super().observe(corrected, situation, rng)
        if self.noise > 0:
            phi = phi + rng.normal(0.0, self.noise, size=phi.shape)
        return phi

    def shows_trajectory(self) -> bool:
        return self.noise == 0


@register_user("distracted")
@dataclass(frozen=True)
class DistractedUser(BiasedUser):
    """The biased user, whose correction is, a ``fraction`` of the time, a nudge that carries
    no preference: each waypoint the biased correction would have moved (the worst one, or
    ``waypoints`` of them) moves as far, in one uniformly random joint-space direction
    (something the robot cannot represent, or nothing at all). Each correction is labelled
    relevant or not (``relevant`` in the records).

    Attributes:
        fraction: the probability in [0, 1] that a correction is such a nudge.
        step, waypoints: the relevant correction's, as the biased user's.
    """

    fraction: float = 0.3
    stochastic: ClassVar[bool] = True

    def __post_init__(self) -> None:
        super().__post_init__()
        number = isinstance(self.fraction, int | float) and not isinstance(self.fraction, bool)
        if not (number and np.isfinite(self.fraction) and 0.0 <= self.fraction <= 1.0):
            raise ParameterError("fraction", f"must lie in [0, 1], got {self.fraction!r}")

    def nudge(self, situation: Situation, rng: np.random.Generator) -> tuple[np.ndarray, bool]:
        """(ξ_h, relevant): the biased correction, or the nudge in its place. Both draws (the
        coin and the direction) are made every time, so the stream does not depend on them."""
        relevant = self.corrected_trajectory(situation.robot, situation.intended)
        coin = rng.random()
        direction = rng.normal(size=relevant.shape[1])
        if coin >= self.fraction:
            return relevant, True
        moved = np.linalg.norm(relevant - situation.robot, axis=1)
        out = situation.robot.copy()
        for i in np.flatnonzero(moved > 0.0):
            out[i] += moved[i] * direction / np.linalg.norm(direction)
        return out, False

    def correct(self, situation: Situation, rng: np.random.Generator) -> np.ndarray:
        return self.nudge(situation, rng)[0]

    def perform(self, situation: Situation, rng: np.random.Generator, replan=None) -> TaskOutcome:
        corrected, relevant = self.nudge(situation, rng)
        return TaskOutcome(
            phi_h=self.observe(corrected, situation, rng), corrected=corrected, relevant=relevant
        )
