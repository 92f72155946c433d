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
such key is translated to its place by :mod:`corrections_sim.study.legacy`.

Every value is checked before anything runs, and a bad one is a ``ValueError`` whose one-line
message starts with its key path (``learners.KF-A.attenuation_min: must be > 0, got -1``,
``environments[2].start: the arm collides there (…)``). The command line's options reach the
same keys: ``--set learners.KF-C.model=deform``; ``--runs 5`` is ``--set runs=5``.
:mod:`corrections_sim.study.key_reference` writes the key-by-key reference (the docs page) from it.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from corrections_sim import components
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import LEARNERS, make_learner
from corrections_sim.people.teacher import Teacher
from corrections_sim.people.users import USERS, make_user
from corrections_sim.planning.planner import PlannerConfig
from corrections_sim.scene.environments import (
    paper_environments,
)
from corrections_sim.study.checks import check_features, check_user_features
from corrections_sim.study.environments import (  # noqa: F401  (part of the schema's API)
    MAX_ENVIRONMENTS,
    PAPER,
    EnvironmentSpec,
    as_data,
    parse_environments,
    resolve,
)
from corrections_sim.study.files import as_table, parse_value, read, set_path
from corrections_sim.study.legacy import LEGACY_KEYS, note_older_spellings, translate_legacy
from corrections_sim.study.plugins import PluginFile, load_plugins, parse_plugins  # noqa: F401
from corrections_sim.study.settings import (
    DEFAULT_LEARNERS,
    MAX_COUNT,
    MAX_RECORDS,
    NEEDED,
    PLANNER_SETTINGS,
    AtlasSettings,
    FigureSettings,
    FilterSettings,
    StudySettings,
)

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
    "atlas": (
        NEEDED,
        "plans from a plan atlas (docs/atlas.md), every plan a function of (θ, E) alone: true, "
        "or a table of width (the box θ̂⁰ ± width sd, 5), points (a weight, 31), cold_stride "
        "(cold starts on every n-th node, 10); false: each run's own plan book; not given: "
        "true where a learner needs it (the exact learners, the recommended robot), else false",
    ),
    "person_restarts": (
        None,
        "random starts of the person's own plans ξ*(θ*, E), what regret is measured against, "
        "beside the planner's cold starts (an integer >= 0; default 30 with an atlas, 0 "
        "without)",
    ),
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
    "person_restarts": (0, 1000),
}
#: Planner solves a study may need, ≈ runs × learners × iterations × (environments + 2k + 2):
#: about a week on one machine at 5 ms a solve. Refused beyond, before anything runs.
MAX_SOLVES = 100_000_000


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
            if (why := LEARNERS.retired(name)) is not None:
                raise ValueError(f"learners[{i}] = {name!r}: {why}")
            if not isinstance(name, str) or name not in LEARNERS:
                raise ValueError(
                    f"learners[{i}] = {name!r}: unknown learner (choose from {', '.join(LEARNERS)})"
                )
            if name in table:
                raise ValueError(f"learners[{i}] = {name!r}: listed twice")
            table[name] = {}
        value = table
    value = as_table(value, "learners")
    if not value:
        raise ValueError("learners: name at least one learner")
    return {
        name: make_learner(name, as_table(params, f"learners.{name}"), where=f"learners.{name}")
        for name, params in value.items()
    }


def _user(value):
    if isinstance(value, str):
        value = {"name": value}
    value = as_table(value, "user")
    name = value.pop("name", None)
    if not isinstance(name, str):
        raise ValueError(f"user.name: missing (which user: {', '.join(USERS)})")
    if name not in USERS:
        raise ValueError(f"user = {name!r}: unknown user (choose from {', '.join(USERS)})")
    return name, make_user(name, value, where="user")


def _filter(value) -> FilterSettings:
    value = as_table(value, "filter")
    known = components.defaults(FilterSettings)
    for key in value:
        if key not in known:
            raise ValueError(f"filter.{key}: unknown key (takes {', '.join(known)})")
    try:
        return FilterSettings(**value)
    except components.ParameterError as exc:
        raise ValueError(f"filter.{exc.name}: {exc.message}") from None


def _planner(value) -> tuple[tuple[str, Any], ...]:
    value = as_table(value, "planner")
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


def _fields_table(value, name: str, cls, who: str) -> dict:
    """``value`` as the table ``name`` of the dataclass ``cls``'s fields (``who``: "a
    teacher"), an unknown key refused in one line naming it."""
    value = as_table(value, name)
    known = cls.__dataclass_fields__
    for key in value:
        if key not in known:
            raise ValueError(f"{name}.{key}: unknown key ({who} takes {', '.join(known)})")
    return value


def _teacher(value) -> Teacher:
    """The ``teacher`` table."""
    value = _fields_table(value, "teacher", Teacher, "a teacher")
    try:
        return Teacher(**value)
    except (TypeError, ValueError) as exc:
        raise ValueError(str(exc)) from None


def _atlas(value) -> AtlasSettings | str | None:
    """The ``atlas`` key: false (each run's plan book), true (the defaults) or a table; absent
    (None): :data:`~corrections_sim.study.settings.NEEDED`, an atlas where a learner needs it."""
    if value is None:
        return NEEDED
    if value is False:
        return None
    if value is True:
        return AtlasSettings()
    value = _fields_table(value, "atlas", AtlasSettings, "an atlas")
    try:
        return AtlasSettings(**value)
    except ParameterError as exc:
        raise ValueError(f"atlas.{exc.name}: {exc.message}") from None


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
    atlas = _atlas(values.get("atlas"))
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
        atlas=atlas,
        person_restarts=values.get("person_restarts"),
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
    given = dict(values)
    values = apply_overrides(values, overrides or {})
    base = Path(source).resolve().parent if isinstance(source, str | Path) else None
    settings = parse_study(values, name=name, base=base)
    note_older_spellings(given, str(source))  # a file that loads: an error is its one line
    return settings


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
    file's); ``--user`` replaces the user; ``session_learner`` (a session's learner) is added
    to the learners with its defaults if the file does not name it."""
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
    if "session_learner" in given:
        # A session's learner (interact --learner) is one of its study's, with its defaults
        # where the file names it not, so --set learners.NAME.… reaches it.
        name = given.pop("session_learner")
        named = values.get("learners", [])
        table = dict(named) if isinstance(named, Mapping) else {n: {} for n in named}
        if isinstance(name, str) and name not in table:
            values["learners"] = {**table, name: {}}
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
