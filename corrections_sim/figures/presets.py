"""Settings of figs. 1–3 as data: the TOML presets, the fixed scene, and checks of each field.

Every value is checked where it enters, and a bad one is refused with a one-line
``ValueError`` that names its field as written in ``experiments/<figure>.toml`` (e.g.
``maps[1].cov``), so a typo never becomes a NaN in a heat map.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim.scene.environments import (
    Environment,
    configuration_at,
    table_holding,
)
from corrections_sim.study import checks, files


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
            start=checks.cup_position("start", checks.take(values, "start")),
            goal=checks.cup_position("goal", checks.take(values, "goal")),
            laptop=checks.vector("laptop", checks.take(values, "laptop"), 3),  # type: ignore[arg-type]
            table=checks.vector("table", checks.take(values, "table"), 2),  # type: ignore[arg-type]
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

        return provenance.plain(files.read(EXPERIMENTS_DIR / f"{self.name}.toml", quick=quick))

    def run(self, settings, executor, progress, cache):
        return self._module().run(settings, executor, progress)

    def write(self, settings, result, folder: Path) -> dict:
        from corrections_sim import provenance

        self._module().write(settings, result, folder)
        return {
            "planner": provenance.plain(settings.planner_config()),
            "results": provenance.plain({k: getattr(result, k) for k in self.shown}),
        }
