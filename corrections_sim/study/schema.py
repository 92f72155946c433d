"""One schema for every settings file: figs. 1–6 and study files, read and checked here.

**The dialect.** A settings file's top-level keys are its paper-scale settings; an optional
``[quick]`` table replaces any of them (key by key) for ``--quick``. Figs. 1–3 add their maps
or panels (:mod:`corrections_sim.figures.selection`, ``deployment``), fig. 6 its columns.

**A study** (figs. 4–5, fig. 6's columns, ``run study FILE``) takes the keys of
:data:`STUDY_KEYS`. Components own their parameters: ``user`` is a name or a table
``{ name = "biased", step = 0.5 }``; ``learners`` a list of names or a table of tables
``[learners.KF-A] attenuation_min = 0.1`` (a learner with ``{}`` takes its defaults). The
filters' shared M, N and sigma points are the ``[filter]`` table, the planner's settings the
``[planner]`` table. Study files written before components owned their parameters (flat keys
``user_step``, ``correction_model``, ``attenuation_min``, ``n_starts``, …) still run: each
such key is translated to its place by :data:`LEGACY_KEYS` (:func:`translate_legacy`).

Every value is checked before anything runs, and a bad one is a ``ValueError`` whose one-line
message starts with its key path (``learners.KF-A.attenuation_min: must be > 0, got -1``,
``environments[2].start: the arm collides there (…)``). The command line's options reach the
same keys: ``--set learners.KF-C.model=deform``; ``--runs 5`` is ``--set runs=5``.
:func:`reference_markdown` writes the key-by-key reference (the docs page) from this module.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim import components
from corrections_sim.belief import Belief
from corrections_sim.learning.base import LEARNERS, make_learner
from corrections_sim.people.corrections import CORRECTIONS
from corrections_sim.people.teacher import Teacher
from corrections_sim.people.users import USERS, make_user
from corrections_sim.planning.features import FEATURES, check_feature_names
from corrections_sim.planning.planner import PlannerConfig
from corrections_sim.registry import Registry
from corrections_sim.scene.environments import (
    CUP_WORKSPACE,
    configuration_at,
    paper_environments,
)
from corrections_sim.study.environments import (  # noqa: F401  (part of the schema's API)
    MAX_ENVIRONMENTS,
    PAPER,
    EnvironmentSpec,
    as_data,
    parse_environments,
    resolve,
)
from corrections_sim.study.plugins import PluginFile, load_plugins, parse_plugins  # noqa: F401
from corrections_sim.study.settings import (
    DEFAULT_LEARNERS,
    MAX_COUNT,
    MAX_RECORDS,
    FigureSettings,
    FilterSettings,
    StudySettings,
)

#: The planner's settings a study takes (the ``[planner]`` table), with their defaults; passed
#: to :class:`~corrections_sim.planning.planner.PlannerConfig` by name (which checks them).
PLANNER_SETTINGS: dict[str, Any] = dict(FigureSettings.__dataclass_fields__["planner"].default)
#: Every key of a study, with its default (None: required, or computed) and meaning: the one
#: list the parser, the error messages and the reference page read.
STUDY_KEYS: dict[str, tuple[Any, str]] = {
    "description": ("", "a line for the plot's title"),
    "plugins": (
        [],
        "Python files (relative to the file) imported first, in every worker, to "
        "register users, learners, correction models or features; their SHA-256 is "
        "part of the run cache's key",
    ),
    "features": (
        ["laptop", "table"],
        "the features θ weighs, in order: a non-empty subset of the registered features",
    ),
    "user_features": (
        None,
        "the features the simulated person weighs (default: the learners' features): all of "
        "them and any others the scene knows, e.g. the learners know laptop and table, the "
        "person also minds coffee; the person plans over these, the learners see theirs",
    ),
    "theta_star": (
        None,
        "the simulated user's true weights θ*, one per feature of user_features (required)",
    ),
    "theta0": ("zeros", "the robot's initial estimate θ̂⁰"),
    "cov0": ("identity", "P⁰, k × k rows, symmetric positive definite"),
    "environments": (
        PAPER,
        '"paper" (the 48), or a list of paper names ("s0-t0-l1") and '
        "tables { name, start, laptop, table, goal, like, tilt }",
    ),
    "runs": (10, "runs of each learner (an active learner with a deterministic user runs once)"),
    "iterations": (12, "corrections per run"),
    "seed": (0, "root of every random draw"),
    "learners": (
        list(DEFAULT_LEARNERS),
        "a list of learner names, or a table of learners "
        "with their parameters ([learners.KF-A] attenuation_min = 0.1)",
    ),
    "user": (
        "biased",
        "the simulated user: a name, or a table with its name and parameters "
        '({ name = "biased", step = 0.5 })',
    ),
    "filter": (
        {},
        "the filters' shared settings: process_noise (M = m·I, 1e-4), "
        "observation_noise (N = n·I, 0.25), sigma_alpha, sigma_beta, sigma_kappa (1, 2, 0)",
    ),
    "planner": (
        dict(PLANNER_SETTINGS),
        "the planner: n_starts (cold starts per solve, 1-10; 10 where θ may take any sign), "
        "solver (fatrop or ipopt), warm (how a warm start is re-solved: newton, Newton steps "
        "in one compiled call first and the solver where they cannot certify an answer; or "
        "solver, the solver alone, the reference path), "
        "certificate (true: skip MuJoCo's check of a plan the compiled clearance bound "
        "proves collision-free; never changes a number)",
    ),
    "warm_start": (False, "start each solve from the run's nearest solved θ̂ (faster)"),
    "online": (
        False,
        "learn during the motion: when a physical user's push ends, the learner updates and "
        "the robot replans the rest of the motion (needs user physical)",
    ),
    "teacher": (
        {},
        "how the person gives feature traces when a learner asks (KF-CRX): states (per trace, "
        "12), candidates (places they look at to pick a start and an end, 20), path_noise "
        "(rad, 0.1), label_noise (sd of their misjudged quantile, 0.1)",
    ),
}
#: Integer keys and their allowed ranges: beyond these a study cannot finish (or fit).
INTEGER_LIMITS: dict[str, tuple[int, int]] = {
    "runs": (1, MAX_COUNT["runs"]),
    "iterations": (1, MAX_COUNT["iterations"]),
    "seed": (0, 2**63 - 1),
}
#: Planner solves a study may need, ≈ runs × learners × iterations × (environments + 2k + 2):
#: about a week on one machine at 5 ms a solve. Refused beyond, before anything runs.
MAX_SOLVES = 100_000_000

#: Flat keys of study files written before components owned their parameters -> where they go
#: now: ("filter" | "planner" | "user", parameter), or ("learners", (learners…), parameter)
#: for the built-in learners that read them. A learner key applies to those of the named
#: learners the study runs. ``user_params``/``learner_params`` are whole tables.
LEGACY_KEYS: dict[str, tuple] = {
    "process_noise": ("filter", "process_noise"),
    "observation_noise": ("filter", "observation_noise"),
    "sigma_alpha": ("filter", "sigma_alpha"),
    "sigma_beta": ("filter", "sigma_beta"),
    "sigma_kappa": ("filter", "sigma_kappa"),
    "n_starts": ("planner", "n_starts"),
    "solver": ("planner", "solver"),
    "user_step": ("user", "step"),
    "user_waypoints": ("user", "waypoints"),
    "user_params": ("user", None),
    "learner_params": ("learners", None, None),
    "fixed_alpha": ("learners", ("PP", "PP-C"), "fixed_alpha"),
    "ekf_step": ("learners", ("EKF",), "step"),
    "attenuation_min": ("learners", ("KF-A",), "attenuation_min"),
    "attenuation_max": ("learners", ("KF-A",), "attenuation_max"),
    "attenuation_points": ("learners", ("KF-A",), "attenuation_points"),
    "beta_min": ("learners", ("BP",), "beta_min"),
    "beta_max": ("learners", ("BP",), "beta_max"),
    "beta_points": ("learners", ("BP",), "beta_points"),
    "lapse": ("learners", ("BP",), "lapse"),
    "correction_model": ("learners", ("KF-C", "AL-C"), "model"),
    "correction_step": ("learners", ("KF-C", "AL-C"), "model"),
    "correction_waypoints": ("learners", ("KF-C", "AL-C"), "model"),
}
#: The old flat keys' defaults: a legacy key at its old default is dropped where its target
#: does not take it or does not run (an old summary recorded them all, whichever user or
#: learners ran); at another value it is refused there, since it would change nothing.
_LEGACY_DEFAULTS = {
    "user_step": 1.0,
    "user_waypoints": 1,
    "correction_model": "waypoint",
    "correction_step": 1.0,
    "correction_waypoints": 1,
    "fixed_alpha": None,
    "ekf_step": 0.05,
    "attenuation_min": 0.05,
    "attenuation_max": 1.0,
    "attenuation_points": 12,
    "beta_min": 0.3,
    "beta_max": 30.0,
    "beta_points": 15,
    "lapse": 0.0,
}


# --- files --------------------------------------------------------------------------------------


def read(path, *, quick: bool, keys=None) -> dict:
    """The values of a settings file, with its ``[quick]`` table applied when ``quick``.

    Args:
        keys: the top-level keys the file may hold, if the caller checks them here (a key
            of ``[quick]`` is checked whether or not ``quick`` is given).

    Raises:
        ValueError: unreadable file, a TOML syntax error (the message has its line), an
            unknown key (named, ``quick.runz``).
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
    if keys is not None:
        for prefix, table in (("", values), ("quick.", overrides)):
            unknown = [k for k in table if k not in keys]
            if unknown:
                raise ValueError(
                    f"{prefix}{unknown[0]}: unknown key (the file takes {', '.join(keys)})"
                )
    if quick:
        values.update(overrides)
    return values


def parse_value(text: str) -> Any:
    """A command-line value as TOML (``0.5``, ``[1, -1]``, ``true``, ``{ name = "x" }``), or
    the text itself when it is not TOML (``deform``)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def set_path(values: dict, path: str, value: Any) -> None:
    """Set ``values[a][b]… = value`` for ``path`` "a.b…" (``--set``); a name where a table is
    needed becomes ``{name = …}`` (``user``), a list of learners a table of them.

    Raises:
        ValueError: an empty path, or one through a value that is not a table.
    """
    parts = path.split(".")
    if not all(parts):
        raise ValueError(f"--set {path}: expected KEY.PATH=VALUE, e.g. user.step=0.5")
    node = values
    for depth, key in enumerate(parts[:-1]):
        where = ".".join(parts[: depth + 1])
        child = node.get(key)
        if child is None:
            child = {"name": "biased"} if where == "user" else {}
        elif (
            isinstance(child, str)
            and where in ("user",)
            or (isinstance(child, str) and depth > 0 and parts[0] == "learners")
        ):
            child = {"name": child}
        elif isinstance(child, list) and where == "learners":
            child = {name: {} for name in child}
        elif not isinstance(child, dict):
            raise ValueError(f"--set {path}: {where} is {child!r}, not a table")
        if where.startswith("learners.") and depth == 1 and key not in node:
            raise ValueError(
                f"--set {path}: {key} is not one of the study's learners ({', '.join(node)})"
            )
        node[key] = child
        node = child
    node[parts[-1]] = value


def _table(value, where: str) -> dict:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ValueError(f"{where} = {value!r}: expected a table")
    return dict(value)


def translate_legacy(values: dict) -> dict:
    """``values`` with the flat keys of :data:`LEGACY_KEYS` moved to their places (an explicit
    nested value wins over a flat one).

    Raises:
        ValueError: a flat key that fits nowhere, named (``user_step = 0.5: the noisy user
            has no parameter step``).
    """
    values = dict(values)
    legacy = {k: values.pop(k) for k in list(values) if k in LEGACY_KEYS}
    if not legacy:
        return values
    for group in ("filter", "planner"):
        given = {LEGACY_KEYS[k][1]: v for k, v in legacy.items() if LEGACY_KEYS[k][0] == group}
        if given:
            values[group] = {**given, **_table(values.get(group), group)}
    user = values.get("user", "biased")
    user = {"name": user} if isinstance(user, str) else _table(user, "user")
    name = user.get("name", "biased")
    taken = components.defaults(USERS[name]) if name in USERS else {}
    extra = dict(_table(legacy.get("user_params"), "user_params"))
    for key in ("user_step", "user_waypoints"):
        if key not in legacy or legacy[key] is None:
            continue
        param = LEGACY_KEYS[key][1]
        if param in taken:
            extra.setdefault(param, legacy[key])
        elif legacy[key] != _LEGACY_DEFAULTS[key]:
            raise ValueError(f"{key} = {legacy[key]!r}: the {name} user has no parameter {param}")
    if name == "noisy" and "observation_noise" in legacy and "noise" not in extra:
        # Before users owned their parameters, the noisy user's σ was √N of the filters.
        extra["noise"] = math.sqrt(float(legacy["observation_noise"]))
    if extra:
        values["user"] = {**user, **{k: v for k, v in extra.items() if k not in user}}
    learners = values.get("learners", list(DEFAULT_LEARNERS))
    table = (
        {n: {} for n in learners}
        if isinstance(learners, list | tuple)
        else {n: dict(_table(p, f"learners.{n}")) for n, p in _table(learners, "learners").items()}
    )
    for name, params in _table(legacy.get("learner_params"), "learner_params").items():
        if name not in table:
            raise ValueError(f"learner_params: {name!r} is not one of the learners")
        table[name] = {**_table(params, f"learner_params.{name}"), **table[name]}
    model = legacy.get("correction_model")
    for key, value in legacy.items():
        target = LEGACY_KEYS[key]
        if target[0] != "learners" or target[1] is None or value is None:
            continue
        if not any(n in table for n in target[1]) and value != _LEGACY_DEFAULTS[key]:
            raise ValueError(
                f"{key} = {value!r}: it sets {' and '.join(target[1])}, which the study does not "
                f"run (learners: {', '.join(table)})"
            )
        for learner in target[1]:
            if learner not in table:
                continue
            params = table[learner]
            if target[2] == "model":
                spec = params.get("model", {"name": model or "waypoint"})
                spec = {"name": spec} if isinstance(spec, str) else dict(spec)
                if key == "correction_model":
                    spec["name"] = spec.get("name", value) if "model" in params else value
                else:
                    param = key.removeprefix("correction_")
                    kind = spec.get("name", "waypoint")
                    if param in components.defaults(CORRECTIONS[kind]):
                        spec.setdefault(param, value)
                    elif value != _LEGACY_DEFAULTS[key]:
                        raise ValueError(
                            f"{key} = {value!r}: the {kind} correction model has no {param}"
                        )
                params["model"] = spec
            else:
                params.setdefault(target[2], value)
    values["learners"] = table
    return values


def normalize_recorded(settings: Mapping[str, Any]) -> dict:
    """Settings recorded in an older ``summary.json`` (flat keys) in today's nested form, so an
    output folder made before components owned their parameters compares equal when its
    settings are. Anything that does not translate is returned as it was."""
    try:
        values = translate_legacy(dict(settings))
    except (ValueError, KeyError, TypeError):
        return dict(settings)
    if isinstance(values.get("user"), str):
        values["user"] = {"name": values["user"]}
    user = values.get("user")
    if isinstance(user, dict) and user.get("name") in USERS:
        try:
            built = make_user(user["name"], {k: v for k, v in user.items() if k != "name"})
            values["user"] = {"name": user["name"], **components.params(built)}
        except ValueError:
            pass
    learners = values.get("learners")
    if isinstance(learners, dict):
        out = {}
        for name, params in learners.items():
            try:
                out[name] = components.params(make_learner(name, params))
            except (ValueError, KeyError):
                out[name] = params
        values["learners"] = out
    planner = values.get("planner")
    if isinstance(planner, dict):
        values["planner"] = {**PLANNER_SETTINGS, **planner}
    if isinstance(values.get("filter"), dict):
        values["filter"] = components.params(FilterSettings(**values["filter"]))
    return values


# --- sizes ---------------------------------------------------------------------------------------


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


# --- a study -------------------------------------------------------------------------------------


def _numbers(key: str, value, length: int | None = None) -> tuple[float, ...]:
    if not isinstance(value, list | tuple) or not all(
        not isinstance(v, bool) and isinstance(v, int | float) for v in value
    ):
        raise ValueError(f"{key} = {value!r}: expected a list of numbers")
    if length is not None and len(value) != length:
        raise ValueError(f"{key}: expected {length} numbers, got {len(value)}")
    return tuple(float(v) for v in value)


def _learners(value) -> dict:
    """``learners``: names, or a table name -> parameters; built and checked by name."""
    if isinstance(value, list | tuple):
        table = {}
        for i, name in enumerate(value):
            if not isinstance(name, str) or name not in LEARNERS:
                raise ValueError(
                    f"learners[{i}] = {name!r}: unknown learner (choose from {', '.join(LEARNERS)})"
                )
            if name in table:
                raise ValueError(f"learners[{i}] = {name!r}: listed twice")
            table[name] = {}
        value = table
    value = _table(value, "learners")
    if not value:
        raise ValueError("learners: name at least one learner")
    return {
        name: make_learner(name, _table(params, f"learners.{name}"), where=f"learners.{name}")
        for name, params in value.items()
    }


def _user(value):
    if isinstance(value, str):
        value = {"name": value}
    value = _table(value, "user")
    name = value.pop("name", None)
    if not isinstance(name, str):
        raise ValueError(f"user.name: missing (which user: {', '.join(USERS)})")
    if name not in USERS:
        raise ValueError(f"user = {name!r}: unknown user (choose from {', '.join(USERS)})")
    return name, make_user(name, value, where="user")


def _filter(value) -> FilterSettings:
    value = _table(value, "filter")
    known = components.defaults(FilterSettings)
    for key in value:
        if key not in known:
            raise ValueError(f"filter.{key}: unknown key (takes {', '.join(known)})")
    try:
        return FilterSettings(**value)
    except components.ParameterError as exc:
        raise ValueError(f"filter.{exc.name}: {exc.message}") from None


def _planner(value) -> tuple[tuple[str, Any], ...]:
    value = _table(value, "planner")
    for key in value:
        if key not in PLANNER_SETTINGS:
            raise ValueError(f"planner.{key}: unknown key (takes {', '.join(PLANNER_SETTINGS)})")
    n_starts = value.get("n_starts", PLANNER_SETTINGS["n_starts"])
    if isinstance(n_starts, bool) or not isinstance(n_starts, int) or not 1 <= n_starts <= 1000:
        raise ValueError(f"planner.n_starts = {n_starts!r}: expected an integer in [1, 1,000]")
    settings = tuple((k, value.get(k, v)) for k, v in PLANNER_SETTINGS.items())
    try:  # PlannerConfig checks its own fields; the study names where they came from
        PlannerConfig(**dict(settings))
    except ValueError as exc:
        raise ValueError(f"planner.{exc}") from None
    return settings


def _teacher(value) -> Teacher:
    """The ``teacher`` table."""
    value = _table(value, "teacher")
    known = Teacher.__dataclass_fields__
    for key in value:
        if key not in known:
            raise ValueError(f"teacher.{key}: unknown key (a teacher takes {', '.join(known)})")
    try:
        return Teacher(**value)
    except (TypeError, ValueError) as exc:
        raise ValueError(str(exc)) from None


def parse_study(
    values: Mapping[str, Any], *, name: str = "", base: Path | None = None
) -> FigureSettings:
    """A study's settings from a settings file's values (legacy flat keys allowed).

    Plug-ins load first (they register the names the rest uses); sizes are checked before
    anything is built, so nothing is allocated for a study that cannot fit.

    Raises:
        ValueError: an unknown key or a bad value; the message starts with its key path.
    """
    values = dict(values)
    plugins = parse_plugins(values.pop("plugins", ()), base)
    values = translate_legacy(values)
    unknown = [k for k in values if k not in STUDY_KEYS]
    if unknown:
        legacy = ", ".join(LEGACY_KEYS)
        raise ValueError(
            f"{unknown[0]}: unknown key (a study takes {', '.join(STUDY_KEYS)}; and, from "
            f"older study files, {legacy})"
        )
    description = values.get("description", "")
    if not isinstance(description, str):
        raise ValueError(f"description = {description!r}: expected a string")
    features = check_features(values.get("features", STUDY_KEYS["features"][0]))
    k = len(features)
    learners_value = values.get("learners", list(DEFAULT_LEARNERS))
    raw_envs = values.get("environments", PAPER)
    n_envs = len(raw_envs) if isinstance(raw_envs, list | tuple) else len(paper_environments())
    values.setdefault("runs", STUDY_KEYS["runs"][0])
    values.setdefault("iterations", STUDY_KEYS["iterations"][0])
    n_learners = len(learners_value) if isinstance(learners_value, list | tuple | dict) else 1
    check_sizes(values, n_envs, n_learners)
    planner = _planner(values.get("planner"))
    if "theta_star" not in values:
        raise ValueError("theta_star: missing (the simulated user's true weights)")
    own = values.get("user_features")
    own = features if own is None else check_user_features(own, features)
    theta_star = values["theta_star"]
    if not isinstance(theta_star, list | tuple) or len(theta_star) != len(own):
        raise ValueError(
            f"theta_star: expected {len(own)} weights for the features {list(own)}, got "
            f"{len(theta_star) if isinstance(theta_star, list | tuple) else repr(theta_star)}"
        )
    theta_star = _numbers("theta_star", theta_star)
    person = theta_star if own != features else ()
    theta_star = tuple(theta_star[own.index(name)] for name in features)
    theta0 = _numbers("theta0", values.get("theta0", [0.0] * k))
    cov0 = values.get("cov0", [[float(i == j) for j in range(k)] for i in range(k)])
    if not isinstance(cov0, list | tuple) or not all(isinstance(r, list | tuple) for r in cov0):
        raise ValueError(f"cov0 = {cov0!r}: expected a {k} x {k} matrix (a list of rows)")
    if len(cov0) != k or any(len(row) != k for row in cov0):
        raise ValueError(f"cov0: expected a {k} x {k} matrix for the features {features}")
    cov0 = tuple(_numbers(f"cov0[{i}]", row) for i, row in enumerate(cov0))
    learners = _learners(learners_value)
    user_name, user = _user(values.get("user", STUDY_KEYS["user"][0]))
    warm_start = values.get("warm_start", False)
    if not isinstance(warm_start, bool):
        raise ValueError(f"warm_start = {warm_start!r}: expected true or false")
    online = values.get("online", False)
    if not isinstance(online, bool):
        raise ValueError(f"online = {online!r}: expected true or false")
    teacher = _teacher(values.get("teacher", {}))
    study = StudySettings(
        theta_star=theta_star,
        user_theta=person,
        theta0=theta0,
        cov0=cov0,
        iterations=values["iterations"],
        runs=values["runs"],
        seed=values.get("seed", 0),
        learners=learners,
        user=user,
        user_name=user_name,
        filter=_filter(values.get("filter")),
        warm_start=warm_start,
        online=online,
        teacher=teacher,
    )
    return FigureSettings(
        study=study,
        planner=planner,
        features=features,
        user_features=own if own != features else (),
        environments=parse_environments(raw_envs),
        plugins=plugins,
        name=name,
        description=description,
    )


def load_study(
    source, *, name: str, quick: bool, overrides: Mapping[str, Any] | None = None
) -> FigureSettings:
    """A study from its file (a path, or a resource of the installed package) with the
    command line's overrides (key paths -> values; see :func:`apply_overrides`)."""
    values = read(source, quick=quick, keys=(*STUDY_KEYS, *LEGACY_KEYS))
    values = apply_overrides(values, overrides or {})
    base = Path(source).resolve().parent if isinstance(source, str | Path) else None
    return parse_study(values, name=name, base=base)


#: Command-line options and the key (path) each sets; ``--set PATH=VALUE`` reaches any other.
OPTION_PATHS = {
    "runs": "runs",
    "iterations": "iterations",
    "seed": "seed",
    "theta_star": "theta_star",
    "theta0": "theta0",
    "cov0": "cov0",
    "learners": "learners",
    "user": "user",
    "user_step": "user.step",
    "user_waypoints": "user.waypoints",
    "warm_start": "warm_start",
    "online": "online",
    "solver": "planner.solver",
    "fixed_alpha": "fixed_alpha",
    "correction_model": "correction_model",
    "correction_step": "correction_step",
    "correction_waypoints": "correction_waypoints",
}


def apply_overrides(values: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict:
    """``values`` with the command line's overrides: its options (:data:`OPTION_PATHS`) and
    ``set`` (a list of "PATH=VALUE"). Flat (legacy) keys are translated first, so an option
    always wins over the file. ``--learners`` keeps the file's parameters of the learners it
    names (given as a table ``{name: {param: value}}``, its parameters are added to the
    file's); ``--user`` replaces the user."""
    values = dict(values)
    given = {k: v for k, v in overrides.items() if v is not None and k != "set"}
    plugins = values.pop("plugins", None)
    for key in ("fixed_alpha", "correction_model", "correction_step", "correction_waypoints"):
        if key in given:
            values[key] = given.pop(key)
    values = translate_legacy(values) if any(k in LEGACY_KEYS for k in values) else values
    if "learners" in given:
        old = values.get("learners", [])
        old = old if isinstance(old, dict) else {n: {} for n in old}
        named = given.pop("learners")
        # A table {name: {param: value}} (from Python) adds its parameters to the file's.
        params = named if isinstance(named, Mapping) else dict.fromkeys(named, {})
        for n, p in params.items():
            if not isinstance(p, Mapping):
                raise ValueError(f"learners.{n}: expected a table of parameters, got {p!r}")
        values["learners"] = {n: {**old.get(n, {}), **p} for n, p in params.items()}
    if "user" in given:
        values["user"] = given.pop("user")
    for key, value in given.items():
        set_path(values, OPTION_PATHS.get(key, key), value)
    for item in overrides.get("set") or ():
        path, sep, text = item.partition("=")
        if not sep:
            raise ValueError(f"--set {item}: expected KEY.PATH=VALUE, e.g. user.step=0.5")
        set_path(values, path.strip(), parse_value(text.strip()))
    if plugins is not None:
        values["plugins"] = plugins
    return values


# --- the reference page --------------------------------------------------------------------------


def _first_line(cls) -> str:
    """A class's docstring's first paragraph, as Markdown (roles and double backticks plain)."""
    doc = " ".join((cls.__doc__ or "").strip().split("\n\n")[0].split())
    doc = re.sub(r":(?:func|class|mod|data|meth):`~?([^`]+)`", r"`\1`", doc)
    return doc.replace("``", "`")


def _toml(value) -> str:
    """A default as a study file writes it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    return repr(value)


def _shown(value, registry: Registry | None = None) -> str:
    if value is None:
        return "absent"
    if value is components.dataclasses.MISSING:
        return "required"
    if registry is not None:
        value = {"name": components.name_of(registry, value), **components.params(value)}
    return f"`{_toml(value)}`"


def reference_markdown() -> str:
    """The study-file reference (a docs page), written from this schema and the registries:
    every key with its default and meaning, then every registered learner, user and
    correction model with its parameters and their defaults."""
    lines = ["| key | default | meaning |", "|---|---|---|"]
    required = {"theta_star": "required", "theta0": "zeros", "cov0": "identity"}
    for key, (default, meaning) in STUDY_KEYS.items():
        lines.append(f"| `{key}` | {required.get(key) or _shown(default)} | {meaning} |")
    lines.append("| `[quick]` | none | a table of any of these keys, applied with `--quick` |")
    for title, registry, where in (
        ("Learners", LEARNERS, "[learners.{name}]"),
        ("Simulated users", USERS, '[user] name = "{name}"'),
        ("Correction models", CORRECTIONS, '{{ name = "{name}", … }}'),
    ):
        lines += [
            "",
            f"### {title}",
            "",
            "| name | parameters (default) | what it is |",
            "|---|---|---|",
        ]
        for name, cls in registry.items():
            nested = components.nested_registries(cls)
            params = (
                ", ".join(
                    f"`{p}` ({_shown(v, nested.get(p))})"
                    for p, v in components.defaults(cls).items()
                )
                or "none"
            )
            lines.append(f"| `{where.format(name=name)}` | {params} | {_first_line(cls)} |")
    lines += [
        "",
        "### Keys of older study files",
        "",
        "Still accepted, each translated to its place:",
        "",
        "| flat key | now |",
        "|---|---|",
    ]
    for key, target in LEGACY_KEYS.items():
        if target[0] in ("filter", "planner", "user"):
            now = f"`{target[0]}.{target[1]}`" if target[1] else f"`{target[0]}` (its table)"
        elif target[1] is None:
            now = "`learners` (its tables)"
        else:
            now = ", ".join(f"`learners.{n}.{target[2]}`" for n in target[1])
        lines.append(f"| `{key}` | {now} |")
    return "\n".join(lines) + "\n"


# --- figs. 1–3: a scene, maps or panels --------------------------------------------------------


def load_values(
    directory,
    figure: str,
    figures: tuple[str, ...],
    quick: bool,
    overrides: dict | None,
    table: str,
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
    values = read(directory / f"{figure}.toml", quick=quick)
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
