"""Settings of figs. 1–3 as data: the TOML presets, the fixed scene, and checks of each field.

Every value is checked where it enters, and a bad one is refused with a one-line
``ValueError`` that names its field as written in ``experiments/<figure>.toml`` (e.g.
``maps[1].cov``), so a typo never becomes a NaN in a heat map.
"""

from __future__ import annotations

import functools
import importlib
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim.learning import Belief
from corrections_sim.planning.features import check_feature_names
from corrections_sim.scene.environments import (
    CUP_WORKSPACE,
    Environment,
    configuration_at,
    table_holding,
)


def _experiments_dir():
    """The repository's ``experiments/`` folder, installed (editable or from a wheel) as the
    package data ``corrections_sim.experiments`` (pyproject.toml); a source tree that is not
    installed at all (``PYTHONPATH=.``) reads the folder beside the package."""
    try:
        return resources.files("corrections_sim.experiments")
    except ModuleNotFoundError:
        return Path(__file__).resolve().parents[2] / "experiments"


#: Where the presets are read from: the same files from a clone and from a wheel.
EXPERIMENTS_DIR = _experiments_dir()


def read_preset(figure: str, quick: bool) -> dict:
    """The ``[paper]`` or ``[quick]`` table of ``experiments/<figure>.toml``."""
    with (EXPERIMENTS_DIR / f"{figure}.toml").open("rb") as fh:
        presets = tomllib.load(fh)
    return dict(presets["quick" if quick else "paper"])


def load_values(
    figure: str, figures: tuple[str, ...], quick: bool, overrides: dict | None, table: str
) -> tuple[dict, tuple[str, ...], tuple[float, ...]]:
    """A figure's preset with overrides applied, and its checked features and θ̂.

    Args:
        figure: the figure asked for, one of ``figures``.
        quick: the quick preset instead of the paper-scale one.
        overrides: top-level fields to replace (None values are ignored); ``table`` (the
            list of maps or panels) and ``seed`` (these figures draw no random numbers)
            cannot be overridden.

    Returns:
        (the remaining fields, the feature names, θ̂ of their length).
    """
    if figure not in figures:
        raise ValueError(f"figure {figure!r}: choose one of {', '.join(figures)}")
    values = read_preset(figure, quick)
    for key, value in (overrides or {}).items():
        if value is None:
            continue
        if key == "seed":
            raise ValueError(f"seed: {figure} draws no random numbers, it takes no seed")
        if key not in values or key == table:
            raise ValueError(f"{key}: not a setting of {figure} that can be overridden")
        values[key] = value
    features = take(values, "features")
    if not isinstance(features, list | tuple):
        raise ValueError(f"features = {features!r}: expected a list of feature names")
    features = check_feature_names(tuple(features))
    theta = vector("theta", take(values, "theta"), len(features))
    return values, features, theta


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


@dataclass(frozen=True)
class Scene:
    """A figure's fixed scene: where the cup starts and ends, where laptop and table are.

    Attributes:
        start: cup centre at the start (x, y, z), m.
        goal: cup centre at the goal (x, y, z), m.
        laptop: keyboard centre and yaw (x, y, yaw), m and rad.
        table: table centre (x, y), m.
    """

    start: tuple[float, float, float]
    goal: tuple[float, float, float]
    laptop: tuple[float, float, float]
    table: tuple[float, float]

    @classmethod
    def parse(cls, values: dict) -> Scene:
        """Take ``start``, ``goal``, ``laptop`` and ``table`` from ``values`` and check them."""
        scene = cls(
            start=cup_position("start", take(values, "start")),
            goal=cup_position("goal", take(values, "goal")),
            laptop=vector("laptop", take(values, "laptop"), 3),  # type: ignore[arg-type]
            table=vector("table", take(values, "table"), 2),  # type: ignore[arg-type]
        )
        scene.environment()  # the laptop on the table, the table in its range
        return scene

    def environment(
        self,
        *,
        start: tuple[float, float, float] | None = None,
        laptop: tuple[float, float, float] | None = None,
        name: str = "",
    ) -> Environment:
        """The scene's environment, optionally with another cup start or laptop position.

        A moved laptop takes the table along only as far as it must to stay on it
        (:func:`corrections_sim.scene.environments.table_holding`).

        Raises:
            ValueError: an unreachable start (no IK) or a laptop no table can hold.
        """
        if laptop is None:
            laptop, table = self.laptop, self.table
        else:
            table = table_holding(laptop, self.table)
        return Environment(
            q_start=_configuration(self.start if start is None else start),
            q_goal=_configuration(self.goal),
            laptop=laptop,
            table=table,
            name=name,
        )


@functools.cache
def _cached_configuration(position: tuple[float, ...]) -> np.ndarray:
    q = configuration_at(position)
    q.setflags(write=False)
    return q


def _configuration(position) -> np.ndarray:
    """configuration_at, memoized per process (the goal recurs in every grid cell)."""
    return _cached_configuration(tuple(float(v) for v in position))


@dataclass(frozen=True)
class PresetFigure:
    """Figs. 1–3 as registered figures: a module with ``load_settings(figure, quick=,
    overrides=)``, ``run(settings, executor, progress)`` and ``write(settings, result,
    folder)``, looked up when called; ``shown`` names the result's fields that the summary
    records (what the figure shows)."""

    name: str
    help: str
    module: str
    shown: tuple[str, ...]
    options: tuple[str, ...] = ()
    unit: str = "task"
    in_all: bool = True

    def _module(self):
        return importlib.import_module(self.module)

    def load(self, *, quick: bool, overrides: Mapping[str, Any]):
        return self._module().load_settings(self.name, quick=quick, overrides=dict(overrides))

    def folder(self, settings) -> str:
        return self.name

    def cache_keys(self, settings) -> dict[str, dict]:
        return {}  # a few minutes at most: not resumable

    def recorded(self, settings, *, quick: bool) -> dict:
        from corrections_sim import provenance

        return provenance.plain(read_preset(self.name, quick))

    def run(self, settings, executor, progress, cache):
        return self._module().run(settings, executor, progress)

    def write(self, settings, result, folder: Path) -> dict:
        from corrections_sim import provenance

        self._module().write(settings, result, folder)
        return {
            "planner": provenance.plain(settings.planner_config()),
            "results": provenance.plain({k: getattr(result, k) for k in self.shown}),
        }
