"""A study's environments: "paper" (the 48), paper environments by name, and environments of
the user's own as a settings file writes them (:class:`EnvironmentSpec`), each checked before
anything runs (IK for start and goal, the laptop on the table, no collision)."""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass

from corrections_sim.scene.environments import (
    ENV_PARAMETERS,
    GOAL_POSITION,
    LAPTOP_OFFSETS,
    START_POSITIONS,
    TABLE_POSITIONS,
    Environment,
    paper_environments,
    tilted,
)

#: ``environments`` value meaning the paper's 48 (the default).
PAPER = "paper"
#: Keys of one environment of the user's own (``goal``, ``like`` and ``tilt`` are optional;
#: with ``like``, a paper environment's name, ``start``, ``laptop`` and ``table`` are too).
ENVIRONMENT_KEYS = ("name", "start", "laptop", "table", "goal", "like", "tilt", "extra")
#: Environments a study may list (each is checked by IK and a collision test up front).
MAX_ENVIRONMENTS = 10_000


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
    extra: tuple[tuple[str, float], ...] = ()

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
            extra=dict(self.extra),
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
        if self.extra:
            out["extra"] = dict(self.extra)
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
    extra = item.get("extra", {})
    if not isinstance(extra, dict):
        raise ValueError(f"{key}.extra = {extra!r}: expected a table of environment parameters")
    for param, value in extra.items():
        spec = ENV_PARAMETERS.get(param)
        if spec is None or spec.default is None:
            plugins = [n for n, s in ENV_PARAMETERS.items() if s.default is not None]
            raise ValueError(
                f"{key}.extra.{param}: not a registered extra environment parameter "
                f"(registered: {', '.join(plugins) or 'none'}; a plug-in registers one)"
            )
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if not (number and math.isfinite(value)):
            raise ValueError(f"{key}.extra.{param} = {value!r}: expected a finite number")
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
        extra=tuple(sorted((k, float(v)) for k, v in extra.items())),
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
