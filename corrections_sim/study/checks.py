"""A settings file's values checked one by one: a number in its range, an integer, a vector of
its length, bounds, a covariance, a cup position in the workspace, feature names; each refusal
a ``ValueError`` whose one line starts with the key's name. Every settings file uses them
(study files, figs. 1–3, a user study's protocol)."""

from __future__ import annotations

import math

import numpy as np

from corrections_sim.belief import Belief
from corrections_sim.planning.features import FEATURES
from corrections_sim.scene.environments import CUP_WORKSPACE, configuration_at


def take(values: dict, name: str, prefix: str = ""):
    """Pop a required field; a missing one is refused by name."""
    if name not in values:
        raise ValueError(f"{prefix}{name}: missing")
    return values.pop(name)


def reject_unknown(values: dict, prefix: str = "") -> None:
    """Refuse fields nobody reads (a misspelt key would otherwise be ignored)."""
    if values:
        raise ValueError(f"{prefix or 'settings'}: unknown keys {sorted(values)}")


def number(name: str, value, *, low: float = -math.inf, high: float = math.inf) -> float:
    """A finite float in [low, high]."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name} = {value!r}: expected a number")
    if not (math.isfinite(value) and low <= value <= high):
        raise ValueError(f"{name} = {value!r}: expected a finite number in [{low}, {high}]")
    return float(value)


def integer(name: str, value, *, low: int, high: int) -> int:
    """An int in [low, high]."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{name} = {value!r}: expected an integer")
    if not low <= value <= high:
        raise ValueError(f"{name} = {value}: expected an integer in [{low}, {high}]")
    return int(value)


def vector(name: str, value, length: int | None = None) -> tuple[float, ...]:
    """A tuple of finite floats, of ``length`` if given."""
    if not isinstance(value, list | tuple) or not value:
        raise ValueError(f"{name} = {value!r}: expected a list of numbers")
    if length is not None and len(value) != length:
        raise ValueError(f"{name}: expected {length} values, got {len(value)}")
    return tuple(number(f"{name}[{i}]", v) for i, v in enumerate(value))


def bounds(name: str, value, low: float, high: float) -> tuple[float, float]:
    """(lo, hi) with low <= lo < hi <= high."""
    lo, hi = vector(name, value, 2)
    if not lo < hi:
        raise ValueError(f"{name} = [{lo}, {hi}]: the lower bound must be below the upper")
    if lo < low or hi > high:
        raise ValueError(
            f"{name} = [{lo}, {hi}] m leaves the allowed range [{low:.6g}, {high:.6g}] m"
        )
    return lo, hi


def covariance(name: str, value, k: int) -> tuple[tuple[float, ...], ...]:
    """A k × k symmetric positive definite matrix, as nested tuples."""
    if not isinstance(value, list | tuple) or len(value) != k:
        raise ValueError(f"{name}: expected a {k} x {k} matrix (a list of {k} rows)")
    rows = tuple(vector(f"{name}[{i}]", row, k) for i, row in enumerate(value))
    try:
        Belief(theta=np.zeros(k), cov=np.array(rows))
    except ValueError as exc:
        raise ValueError(str(exc).replace("Belief.cov", name)) from None
    return rows


def cup_position(name: str, value) -> tuple[float, float, float]:
    """A cup position (x, y, z) inside :data:`CUP_WORKSPACE` that the arm reaches."""
    point = vector(name, value, 3)
    for axis, v, (lo, hi) in zip("xyz", point, CUP_WORKSPACE, strict=True):
        if not lo <= v <= hi:
            raise ValueError(f"{name}.{axis} = {v} m leaves the arm's workspace [{lo}, {hi}] m")
    try:
        configuration_at(point)
    except ValueError:
        raise ValueError(
            f"{name} = {list(point)}: unreachable with the hand down (no IK)"
        ) from None
    return point  # type: ignore[return-value]


def check_features(value, key: str = "features") -> tuple[str, ...]:
    """A non-empty ordered list of distinct names from ``features.FEATURES`` (the paper's
    three and any registered plug-in); ``key`` names it in errors."""
    if not isinstance(value, list | tuple) or not value:
        raise ValueError(f"{key} = {value!r}: expected a non-empty list of feature names")
    for i, name in enumerate(value):
        if name not in FEATURES:
            raise ValueError(
                f"{key}[{i}] = {name!r}: unknown feature (choose from {', '.join(FEATURES)})"
            )
    if len(set(value)) != len(value):
        raise ValueError(f"{key} = {list(value)}: each feature at most once")
    return tuple(value)


def check_user_features(value, features: tuple[str, ...]) -> tuple[str, ...]:
    """The features the simulated person weighs: every one the learners have (in any order)
    and any others the scene knows. Refused in one line when the person's list lacks one of
    the learners' features (the robot would learn a weight the person cannot have)."""
    own = check_features(value, "user_features")
    missing = [name for name in features if name not in own]
    if missing:
        raise ValueError(
            f"user_features = {list(own)}: must contain every learner feature "
            f"({', '.join(features)}); missing {', '.join(missing)}"
        )
    return own
