"""Study files: a learning study described in one TOML file (figs. 4–5 are two of them).

A study file's top-level keys are the study's settings, by the same names as the command
line's options (``theta_star`` is ``--theta-star``); an optional ``[quick]`` table overrides
any of them for ``--quick``. README ("Study files") lists every key with its default.

Everything is checked here, before a run starts: unknown keys, feature names, θ's length,
P⁰ (symmetric positive definite), every count against a limit (nothing is allocated for an
impossible size), and each environment of the user's own (its start reachable by IK, the
laptop on the table, no collision at start or goal). A bad value is a ``ValueError`` whose
one-line message names the key, e.g. ``environments[2].start``.

The names of users and learners are looked up in :func:`user_names` and :func:`learner_names`
only (today ``study.USERS`` and ``study.LEARNERS``).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import math
import re
import sys
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from corrections_sim.planning.features import FEATURES
from corrections_sim.scene.environments import (
    GOAL_POSITION,
    LAPTOP_OFFSETS,
    START_POSITIONS,
    TABLE_POSITIONS,
    Environment,
    paper_environments,
    tilted,
)

#: Planner settings a study file takes, with their defaults: passed to
#: :class:`~corrections_sim.planning.planner.PlannerConfig` by name (which checks them). A new one is
#: a line here (and, for the command line, an option whose destination is in
#: ``learning.OPTIONS``).
PLANNER_SETTINGS: dict[str, Any] = {"n_starts": 1, "solver": "fatrop"}
#: Keys of a study file that are not :class:`~corrections_sim.study.loop.StudySettings` fields.
STUDY_KEYS = ("description", "plugins", "features", "environments", *PLANNER_SETTINGS)
#: ``environments`` value meaning the paper's 48 (the default).
PAPER = "paper"
#: Keys of one environment of the user's own (``goal``, ``like`` and ``tilt`` are optional;
#: with ``like``, a paper environment's name, ``start``, ``laptop`` and ``table`` are too).
ENVIRONMENT_KEYS = ("name", "start", "laptop", "table", "goal", "like", "tilt")
#: Integer keys and their allowed ranges: beyond these a study cannot finish (or fit).
INTEGER_LIMITS: dict[str, tuple[int, int]] = {
    "runs": (1, 100_000),
    "iterations": (1, 10_000),
    "seed": (0, 2**63 - 1),
    "n_starts": (1, 1_000),  # the planner's own limit is checked by PlannerConfig
    "user_waypoints": (1, 1_000),
    "correction_waypoints": (1, 1_000),
    "attenuation_points": (1, 10_000),
    "beta_points": (1, 10_000),
}
#: Environments a study may list (each is checked by IK and a collision test up front).
MAX_ENVIRONMENTS = 10_000
#: Planner solves a study may need, ≈ runs × learners × iterations × (environments + 2k + 2):
#: about a week on one machine at 5 ms a solve. Refused beyond, before anything runs.
MAX_SOLVES = 100_000_000


def user_names() -> tuple[str, ...]:
    """The simulated users a study may name (``user``)."""
    from corrections_sim.study.loop import USERS

    return tuple(USERS)


def learner_names() -> tuple[str, ...]:
    """The learners a study may name (``learners``)."""
    from corrections_sim.study.loop import LEARNERS

    return tuple(LEARNERS)


@dataclass(frozen=True)
class PluginFile:
    """A Python file a study imports before anything else (it registers users, learners or
    features): its absolute path and the SHA-256 of its bytes (so a changed plug-in never
    resumes runs made with the old one)."""

    path: str
    sha256: str

    def as_dict(self) -> dict:
        return {"path": self.path, "sha256": self.sha256}


def parse_plugins(value, base: Path | None) -> tuple[PluginFile, ...]:
    """``plugins`` of a study file: a list of Python files, relative to the study file's
    folder (``base``) unless absolute. Each is imported here (once per process).

    Raises:
        ValueError: names the item: a missing file, or the exception its import raised.
    """
    if isinstance(value, tuple) and all(isinstance(v, PluginFile) for v in value):
        load_plugins(value)
        return value
    if not isinstance(value, list | tuple) or not all(isinstance(v, str) for v in value):
        raise ValueError(f"plugins = {value!r}: expected a list of Python file paths")
    out = []
    for i, item in enumerate(value):
        path = Path(item).expanduser()
        if not path.is_absolute():
            path = (base or Path.cwd()) / path
        try:
            data = path.resolve().read_bytes()
        except OSError as exc:
            raise ValueError(f"plugins[{i}] = {item!r}: cannot read it ({exc.strerror})") from None
        plugin = PluginFile(str(path.resolve()), hashlib.sha256(data).hexdigest())
        try:
            load_plugins((plugin,))
        except Exception as exc:  # a plug-in's own error, reported in one line
            message = str(exc).splitlines()[0] if str(exc) else ""
            raise ValueError(
                f"plugins[{i}] = {item!r}: importing it raised {type(exc).__name__}: {message}"
            ) from None
        out.append(plugin)
    return tuple(out)


def load_plugins(plugins: tuple[PluginFile, ...]) -> None:
    """Import each plug-in file once per process (workers call this before a task, so
    registrations reach every worker, forked, spawned or on Dask)."""
    for plugin in plugins:
        module = f"corrections_sim_plugin_{hashlib.sha256(plugin.path.encode()).hexdigest()[:12]}"
        if module in sys.modules:
            continue
        spec = importlib.util.spec_from_file_location(module, plugin.path)
        if spec is None or spec.loader is None:
            raise ImportError(f"{plugin.path} is not a Python file")
        loaded = importlib.util.module_from_spec(spec)
        sys.modules[module] = loaded
        try:
            spec.loader.exec_module(loaded)
        except BaseException:
            del sys.modules[module]
            raise


def settings_keys() -> tuple[str, ...]:
    """Every key a study file may hold (besides ``[quick]``)."""
    from corrections_sim.study.loop import StudySettings

    return (*STUDY_KEYS, *(f.name for f in fields(StudySettings)))


def read(path, *, quick: bool) -> dict:
    """The values of a study file, with its ``[quick]`` table applied when ``quick``.

    Raises:
        ValueError: unreadable file, a TOML syntax error (the message has its line), an
            unknown key (the message names it).
    """
    path = path if hasattr(path, "read_text") else Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(
            f"cannot read the file ({getattr(exc, 'strerror', None) or exc})"
        ) from None
    try:
        values = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"invalid TOML: {exc}") from None
    overrides = values.pop("quick", {})
    if not isinstance(overrides, dict):
        raise ValueError("quick: expected a table of keys to override with --quick")
    check_keys(values)
    check_keys(overrides, "quick.")
    if quick:
        values.update(overrides)
    return values


def check_keys(values: Mapping[str, Any], prefix: str = "") -> None:
    """Refuse a key nobody reads (a misspelt one would otherwise be silently ignored)."""
    known = settings_keys()
    unknown = [k for k in values if k not in known]
    if unknown:
        raise ValueError(
            f"{prefix}{unknown[0]}: unknown key (a study file takes {', '.join(known)})"
        )


def check_sizes(values: Mapping[str, Any], n_environments: int, n_learners: int) -> None:
    """Refuse counts that cannot fit, one key at a time, then their product (planner solves).

    Raises:
        ValueError: names the key (or the keys of the product) and the limit.
    """
    for key, (low, high) in INTEGER_LIMITS.items():
        if key not in values or values[key] is None:
            continue
        value = values[key]
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{key} = {value!r}: expected an integer in [{low}, {high:,}]")
        if not low <= value <= high:
            shown = f"{value:,}" if abs(value) < 10**30 else f"{value:.3g}"
            raise ValueError(f"{key} = {shown}: expected an integer in [{low}, {high:,}]")
    if n_environments > MAX_ENVIRONMENTS:
        raise ValueError(f"environments: {n_environments:,} listed, at most {MAX_ENVIRONMENTS:,}")
    runs, iterations = values.get("runs"), values.get("iterations")
    if isinstance(runs, int) and isinstance(iterations, int):
        from corrections_sim.study.loop import MAX_RECORDS

        records = runs * (iterations + 1) * max(n_learners, 1)
        if records > MAX_RECORDS:
            raise ValueError(
                f"runs = {runs:,}, iterations = {iterations:,}: {records:,} records for "
                f"{n_learners} learners, at most {MAX_RECORDS:,} (they are held in memory)"
            )
        k = len(values.get("theta_star") or ()) or 3
        solves = runs * max(n_learners, 1) * iterations * (n_environments + 2 * k + 2)
        if solves > MAX_SOLVES:
            raise ValueError(
                f"runs = {runs:,}, iterations = {iterations:,}, environments = "
                f"{n_environments:,}: ≈ {solves:,} planner solves for {n_learners} learners, "
                f"at most {MAX_SOLVES:,} (about a week at 5 ms a solve)"
            )


# --- environments ------------------------------------------------------------------------------


@dataclass(frozen=True)
class EnvironmentSpec:
    """An environment of the user's own, as written: where the cup starts and ends (cup
    centre, m), the laptop's pose (x, y, yaw; m, rad), the table's centre (x, y; m), and how
    far (rad) the wrist is turned at start and goal (``tilt``: 0 holds the cup upright;
    :func:`~corrections_sim.scene.environments.tilted`)."""

    name: str
    start: tuple[float, float, float]
    laptop: tuple[float, float, float]
    table: tuple[float, float]
    goal: tuple[float, float, float] = GOAL_POSITION
    tilt: float = 0.0

    def environment(self) -> Environment:
        """The :class:`Environment` (IK for start and goal; raises ValueError)."""
        q_start, q_goal = _configuration(self.start), _configuration(self.goal)
        if self.tilt:
            q_start, q_goal = tilted(q_start, self.tilt), tilted(q_goal, self.tilt)
        return Environment(
            q_start=q_start,
            q_goal=q_goal,
            laptop=self.laptop,
            table=self.table,
            name=self.name,
        )

    def as_dict(self) -> dict:
        out = {
            "name": self.name,
            "start": list(self.start),
            "laptop": list(self.laptop),
            "table": list(self.table),
            "goal": list(self.goal),
        }
        if self.tilt:
            out["tilt"] = self.tilt
        return out


#: ``environments`` as settings hold it: "paper", or each a paper environment's name or a spec.
Environments = str | tuple[str | EnvironmentSpec, ...]


@functools.cache
def _configuration(position: tuple[float, ...]):
    from corrections_sim.scene.environments import configuration_at

    q = configuration_at(position)
    q.setflags(write=False)
    return q


@functools.cache
def resolve(environments: Environments) -> tuple[Environment, ...]:
    """The environments a study runs in, memoized per process (workers resolve them too)."""
    if environments == PAPER:
        return paper_environments()
    by_name = {e.name: e for e in paper_environments()}
    return tuple(by_name[e] if isinstance(e, str) else e.environment() for e in environments)


def as_data(environments: Environments):
    """``environments`` as plain data (for summary.json and the run cache's key)."""
    if isinstance(environments, str):
        return environments
    return [e if isinstance(e, str) else e.as_dict() for e in environments]


def _vector(key: str, value, length: int) -> tuple[float, ...]:
    if (
        not isinstance(value, list | tuple)
        or len(value) != length
        or not all(not isinstance(v, bool) and isinstance(v, int | float) for v in value)
        or not all(math.isfinite(v) for v in value)
    ):
        raise ValueError(f"{key} = {value!r}: expected {length} finite numbers")
    return tuple(float(v) for v in value)


def parse_environments(value) -> Environments:
    """``environments`` of a study file: "paper", or a list whose items are paper environment
    names or tables of ``name``, ``start``, ``laptop``, ``table`` (and ``goal``).

    Raises:
        ValueError: names the item, e.g. ``environments[1].laptop``.
    """
    if value == PAPER:
        return PAPER
    if isinstance(value, tuple) and all(isinstance(v, str | EnvironmentSpec) for v in value):
        value = as_data(value)
    if not isinstance(value, list) or not value:
        raise ValueError(
            f'environments = {value!r}: expected "paper" or a non-empty list of names and tables'
        )
    if len(value) > MAX_ENVIRONMENTS:
        raise ValueError(f"environments: {len(value):,} listed, at most {MAX_ENVIRONMENTS:,}")
    paper = {e.name for e in paper_environments()}
    out: list[str | EnvironmentSpec] = []
    names: set[str] = set()
    for i, item in enumerate(value):
        key = f"environments[{i}]"
        if isinstance(item, str):
            if item not in paper:
                raise ValueError(
                    f"{key} = {item!r}: not one of the paper's environments (s0-t0-l0 … s3-t2-l3)"
                )
            spec: str | EnvironmentSpec = item
            name = item
        elif isinstance(item, dict):
            spec = _environment_spec(key, item)
            name = spec.name
        else:
            raise ValueError(f"{key} = {item!r}: expected a name or a table")
        if name in names:
            raise ValueError(f"{key}.name = {name!r}: listed twice")
        names.add(name)
        out.append(spec)
    return tuple(out)


def _environment_spec(key: str, item: dict) -> EnvironmentSpec:
    from corrections_sim.scene.world import check_configuration

    unknown = [k for k in item if k not in ENVIRONMENT_KEYS]
    if unknown:
        raise ValueError(f"{key}.{unknown[0]}: unknown key (takes {', '.join(ENVIRONMENT_KEYS)})")
    if "like" in item:
        item = {**_paper_positions(f"{key}.like", item["like"]), **item}
    for required in ("start", "laptop", "table"):
        if required not in item:
            raise ValueError(f"{key}.{required}: missing (or name a paper environment in like)")
    tilt = item.get("tilt", 0.0)
    if isinstance(tilt, bool) or not isinstance(tilt, int | float) or not math.isfinite(tilt):
        raise ValueError(f"{key}.tilt = {tilt!r}: expected a finite angle in rad")
    name = item.get("name", f"env{key[len('environments[') : -1]}")
    if not isinstance(name, str) or not name:
        raise ValueError(f"{key}.name = {name!r}: expected a non-empty string")
    spec = EnvironmentSpec(
        name=name,
        start=_vector(f"{key}.start", item["start"], 3),  # type: ignore[arg-type]
        laptop=_vector(f"{key}.laptop", item["laptop"], 3),  # type: ignore[arg-type]
        table=_vector(f"{key}.table", item["table"], 2),  # type: ignore[arg-type]
        goal=_vector(f"{key}.goal", item.get("goal", GOAL_POSITION), 3),  # type: ignore[arg-type]
        tilt=float(tilt),
    )
    for part in ("start", "goal"):
        try:
            _configuration(getattr(spec, part))
        except ValueError:
            raise ValueError(
                f"{key}.{part} = {list(getattr(spec, part))}: unreachable with the hand down "
                "(no IK solution within the joint limits)"
            ) from None
    try:
        env = spec.environment()
    except ValueError as exc:
        if str(exc).startswith("tilted"):
            raise ValueError(f"{key}.tilt = {spec.tilt}: {exc}") from None
        field = "laptop" if str(exc).startswith("laptop") else "table"
        raise ValueError(f"{key}.{field}: {exc}") from None
    for part, q in (("start", env.q_start), ("goal", env.q_goal)):
        report = check_configuration(q, env)
        if not report.collision_free:
            pairs = ", ".join("–".join(p) for p in sorted(report.body_pairs())[:2])
            raise ValueError(f"{key}.{part}: the arm collides there ({pairs})")
    return spec


def _paper_positions(key: str, name) -> dict:
    """The positions a paper environment ``s{i}-t{j}-l{k}`` is built from, as a study file
    writes them (start, laptop, table; the goal is the paper's)."""
    match = re.fullmatch(r"s(\d)-t(\d)-l(\d)", name) if isinstance(name, str) else None
    if match is None or name not in {e.name for e in paper_environments()}:
        raise ValueError(
            f"{key} = {name!r}: not one of the paper's environments (s0-t0-l0 … s3-t2-l3)"
        )
    i, j, k = (int(d) for d in match.groups())
    (tx, ty), (dx, dy, yaw) = TABLE_POSITIONS[j], LAPTOP_OFFSETS[k]
    return {
        "start": list(START_POSITIONS[i]),
        "laptop": [tx + dx, ty + dy, yaw],
        "table": [tx, ty],
    }


def check_features(value) -> tuple[str, ...]:
    """A non-empty ordered list of distinct names from ``features.FEATURES`` (the paper's
    three and any registered plug-in)."""
    if not isinstance(value, list | tuple) or not value:
        raise ValueError(f"features = {value!r}: expected a non-empty list of feature names")
    for i, name in enumerate(value):
        if name not in FEATURES:
            raise ValueError(
                f"features[{i}] = {name!r}: unknown feature (choose from {', '.join(FEATURES)})"
            )
    if len(set(value)) != len(value):
        raise ValueError(f"features = {list(value)}: each feature at most once")
    return tuple(value)
