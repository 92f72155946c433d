"""What a study is, as values: :class:`StudySettings` (the people, the prior, the counts) and
:class:`FigureSettings` (that, plus features, environments, planner and plug-ins).

A learner, a user and a correction model own their parameters (their dataclass fields, see
:mod:`corrections_sim.components`); these settings hold the built components, not their
parameters. What every filter shares — M, N and the sigma points — is :class:`FilterSettings`,
handed to each learner through its context. Settings are checked where they are built; the
study file's schema (:mod:`corrections_sim.study.schema`) names the key path of a bad value.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from corrections_sim import components
from corrections_sim.belief import Belief, KalmanNoise
from corrections_sim.components import ParameterError
from corrections_sim.defaults import DEFAULTS
from corrections_sim.learning.base import LEARNERS, Learner, make_learner
from corrections_sim.learning.kalman.filter import SigmaPoints
from corrections_sim.people.teacher import Teacher
from corrections_sim.people.users import USERS, BiasedUser, User
from corrections_sim.planning.planner import PlannerConfig, shared_planner
from corrections_sim.plans.atlas import AtlasGrid
from corrections_sim.plans.book import Target
from corrections_sim.plans.spread import AtlasSpec
from corrections_sim.plans.targets import TargetStore
from corrections_sim.scene.environments import Environment
from corrections_sim.study import environments

#: A study's learners when its file names none (:data:`~corrections_sim.defaults.DEFAULTS`).
DEFAULT_LEARNERS = DEFAULTS["study"]
#: Largest counts accepted: a run is ~50 planner solves per iteration (≈ 0.1 s), so these are
#: far beyond a week on one machine, and refusing them up front beats running out of memory.
MAX_COUNT = {"runs": 100_000, "iterations": 10_000}
#: Random starts of the person's plans ξ*(θ*, E) in a study with a plan atlas, beside the
#: planner's cold starts and the atlas's answer (issue 52: "≥ 30 starts"); a study without one
#: gives them none unless it sets ``person_restarts``.
PERSON_RESTARTS = 30
#: Records (learner × run × iteration) a study may hold in memory (≈ 2 kB each).
MAX_RECORDS = 2_000_000


def _finite(name: str, value, *, low: float, strict: bool = False) -> float:
    number = isinstance(value, int | float | np.number) and not isinstance(value, bool)
    ok = number and np.isfinite(value) and (value > low if strict else value >= low)
    if not ok:
        raise ParameterError(
            name, f"must be finite and {'>' if strict else '>='} {low}, got {value!r}"
        )
    return float(value)


@dataclass(frozen=True)
class FilterSettings:
    """What the study's Gaussian filters share: M = process_noise · I, N = observation_noise · I
    and the unscented transform's sigma points (α, β, κ)."""

    process_noise: float = 1e-4
    observation_noise: float = 0.25
    sigma_alpha: float = 1.0
    sigma_beta: float = 2.0
    sigma_kappa: float = 0.0

    def __post_init__(self) -> None:
        _finite("process_noise", self.process_noise, low=0.0)
        _finite("observation_noise", self.observation_noise, low=0.0, strict=True)
        try:
            self.sigma()
        except ValueError as exc:
            message = str(exc)
            for name in ("alpha", "beta", "kappa"):
                if message.startswith(f"SigmaPoints.{name}"):
                    text = message.split(":", 1)[-1].strip()
                    raise ParameterError(f"sigma_{name}", text) from None
            raise

    def noise(self, k: int) -> KalmanNoise:
        return KalmanNoise.isotropic(k, self.process_noise, self.observation_noise)

    def sigma(self) -> SigmaPoints:
        return SigmaPoints(alpha=self.sigma_alpha, beta=self.sigma_beta, kappa=self.sigma_kappa)


@dataclass(frozen=True)
class AtlasSettings:
    """Where a study's plans come from when they come from a plan atlas
    (:mod:`corrections_sim.plans.atlas`): a grid of ``points`` values a weight over the
    prior's box θ̂⁰ ± ``width`` sd, built with cold starts on every ``cold_stride``-th node."""

    width: float = 5.0
    points: int = 31
    cold_stride: int = 10

    def __post_init__(self) -> None:
        _finite("width", self.width, low=0.0, strict=True)
        for name, low in (("points", 3), ("cold_stride", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < low:
                raise ParameterError(name, f"must be an integer >= {low}, got {v!r}")

    def grid(self, theta0, cov0) -> AtlasGrid:
        """The box θ̂⁰ ± width · sd (sd from P⁰'s diagonal), ``points`` nodes a weight."""
        sd = np.sqrt(np.diag(np.asarray(cov0, float)))
        return AtlasGrid.around(theta0, sd, width=self.width, count=self.points)


#: ``atlas``'s default: a plan atlas with its default settings where one of the study's
#: learners needs it (the recommended robot does), none where none does.
NEEDED = "needed"


def _default_learners() -> dict[str, Learner]:
    return {name: make_learner(name) for name in DEFAULT_LEARNERS}


@dataclass(frozen=True)
class StudySettings:
    """Resolved settings of one study (a figure's learning curves).

    Attributes:
        theta_star: the user's true preferences θ* (k,) over the learners' features (the
            part of the person's θ* the learners can learn; error and NEES against it).
        user_theta: the person's whole θ* over their own features (``user_features`` of the
            figure) when they weigh features the learners lack; () when they do not.
        theta0: the robot's initial estimate θ̂⁰ (k,).
        cov0: initial covariance P⁰ (k, k), symmetric positive definite.
        iterations: corrections per run.
        runs: runs of each learner (an active learner with a deterministic user runs once).
        seed: root of every random draw.
        learners: the learners the study runs, name -> the learner with its parameters, in
            the order given.
        user: the simulated user (with its parameters); ``user_name`` its registered name.
        filter: M, N and sigma points, shared by the filters.
        warm_start: start each new solve of a run from its nearest solved θ in the same
            environment (see :class:`~corrections_sim.plans.book.PlanBook`); faster, and
            history-dependent at the level of the solver's tolerance.
        online: learn during the motion (the IJRR 2022 setting): when the user's correction
            ends, the learner updates and the robot replans the rest of the motion from its
            current state. Needs a user who corrects during the motion (``physical``).
        teacher: how the person gives feature traces when a learner asks for them
            (:class:`~corrections_sim.people.teacher.Teacher`).
        atlas: plans from a plan atlas over the prior's box (:class:`AtlasSettings`): every
            plan a function of (θ, E) alone, and ``warm_start`` moot; None: each run's own
            plan book; :data:`NEEDED` (the default): ``AtlasSettings()`` where a learner needs
            it, else None (resolved on construction: the attribute is never :data:`NEEDED`).
        person_restarts: random starts of the person's own plans beside the planner's cold
            starts (what regret is measured against); None: :data:`PERSON_RESTARTS` with an
            atlas, none without (see :meth:`restarts`). A matrix whose columns plan with and
            without an atlas sets it so that every column's person is planned alike.
    """

    theta_star: tuple[float, ...]
    theta0: tuple[float, ...]
    cov0: tuple[tuple[float, ...], ...]
    iterations: int
    runs: int
    seed: int = 0
    learners: Mapping[str, Learner] = field(default_factory=_default_learners)
    user: User = field(default_factory=BiasedUser)
    user_name: str = "biased"
    filter: FilterSettings = field(default_factory=FilterSettings)
    warm_start: bool = False
    online: bool = False
    user_theta: tuple[float, ...] = ()
    teacher: Teacher = field(default_factory=Teacher)
    atlas: AtlasSettings | None = NEEDED  # type: ignore[assignment]  (resolved below)
    person_restarts: int | None = None

    def restarts(self) -> int:
        """The random starts the person's own plans get (``person_restarts``, or its
        default: :data:`PERSON_RESTARTS` with an atlas, none without)."""
        return self._default_restarts() if self.person_restarts is None else self.person_restarts

    def _default_restarts(self) -> int:
        return PERSON_RESTARTS if self.atlas is not None else 0

    def __post_init__(self) -> None:
        if isinstance(self.atlas, str) and self.atlas == NEEDED:
            needed = any(getattr(x, "needs_atlas", False) for x in self.learners.values())
            object.__setattr__(self, "atlas", AtlasSettings() if needed else None)
        if not np.all(np.isfinite(np.asarray(self.user_theta, float))):
            raise ValueError(f"theta_star: all weights must be finite, got {self.user_theta}")
        k = len(self.theta_star)
        if len(self.theta0) != k:
            raise ValueError(
                f"theta0: expected {k} weights like theta_star, got {len(self.theta0)}"
            )
        if not np.all(np.isfinite(np.asarray(self.theta_star, float))):
            raise ValueError(f"theta_star: all weights must be finite, got {self.theta_star}")
        for name in ("iterations", "runs"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
                raise ValueError(f"{name} = {v!r} must be an integer >= 1")
            if v > MAX_COUNT[name]:
                raise ValueError(f"{name} = {v}: at most {MAX_COUNT[name]:,}")
        if not self.learners:
            raise ValueError("learners: name at least one")
        records = self.runs * (self.iterations + 1) * len(self.learners)
        if records > MAX_RECORDS:
            raise ValueError(
                f"runs = {self.runs}, iterations = {self.iterations}: {records:,} records for "
                f"{len(self.learners)} learners, at most {MAX_RECORDS:,} (they are held in memory)"
            )
        for name, learner in self.learners.items():
            if not isinstance(learner, LEARNERS[name]):
                raise ValueError(f"learners.{name}: {learner!r} is not a {name} learner")
            source = learner.rate_source()
            if source and source not in self.learners:
                raise ValueError(
                    f"learners: {name} takes its learning rate from {source}'s gains; add "
                    f"{source} or set learners.{name}.fixed_alpha (--fixed-alpha)"
                )
            if learner.needs_atlas and self.atlas is None:
                raise ValueError(
                    f"learners.{name}: its grid is the study's plan atlas; set atlas = true "
                    "(docs/atlas.md)"
                )
        if not isinstance(self.user, USERS[self.user_name]):
            raise ValueError(f"user: {self.user!r} is not a {self.user_name} user")
        if not isinstance(self.online, bool):
            raise ValueError(f"online = {self.online!r}: expected true or false")
        if self.online and not self.user.during_motion:
            raise ValueError(
                f"online: the {self.user_name} user corrects a plan, not a motion; online "
                "learning needs a user who corrects during the motion (physical)"
            )
        # Validates P⁰ (symmetric positive definite) and θ̂⁰ where they enter, under the
        # names the caller used rather than Belief's.
        try:
            self.prior()
        except ValueError as exc:
            message = str(exc).replace("Belief.theta", "theta0").replace("Belief.cov", "cov0")
            raise ValueError(message) from None

    @property
    def k(self) -> int:
        return len(self.theta_star)

    def person(self) -> np.ndarray:
        """The person's whole θ*, over their own features."""
        return np.array(self.user_theta or self.theta_star, float)

    def prior(self) -> Belief:
        return Belief(theta=np.array(self.theta0, float), cov=np.array(self.cov0, float))

    def noise(self) -> KalmanNoise:
        return self.filter.noise(self.k)

    def sigma(self) -> SigmaPoints:
        return self.filter.sigma()

    def runs_of(self, learner: str) -> int:
        """How many runs ``learner`` makes: an active learner's run is deterministic unless
        the user draws random numbers, so it runs once then, ``runs`` times otherwise."""
        if LEARNERS[learner].active and not self.user.stochastic:
            return 1
        return self.runs

    def check(self, n_waypoints: int) -> None:
        """Refuse a user's or learner's parameters that do not fit T = ``n_waypoints``."""
        for where, component in (
            ("user", self.user),
            *((f"learners.{n}", v) for n, v in self.learners.items()),
        ):
            try:
                component.check(n_waypoints)
            except ParameterError as exc:
                raise ValueError(f"{where}.{exc.name}: {exc.message}") from None

    def learner_params(self) -> dict[str, dict[str, Any]]:
        """name -> the learner's parameters, as plain data."""
        return {name: components.params(v) for name, v in self.learners.items()}

    def user_params(self) -> dict[str, Any]:
        """The user as plain data: its name and parameters."""
        return {"name": self.user_name, **components.params(self.user)}

    def as_dict(self) -> dict[str, Any]:
        """The settings as plain data (``summary.json``; the study file's nested form)."""
        return {
            "theta_star": self.user_theta or self.theta_star,
            "theta0": self.theta0,
            "cov0": self.cov0,
            "iterations": self.iterations,
            "runs": self.runs,
            "seed": self.seed,
            "learners": self.learner_params(),
            "user": self.user_params(),
            "filter": components.params(self.filter),
            "warm_start": self.warm_start,
            # Only when set, so that the run keys of studies without it stay as they were.
            **({"online": True} if self.online else {}),
            **({"teacher": asdict(self.teacher)} if self.teacher != Teacher() else {}),
            **({"atlas": asdict(self.atlas)} if self.atlas is not None else {}),
            # Only where it differs from its default (the atlas's 30, else none): the same.
            **(
                {"person_restarts": self.restarts()}
                if self.restarts() != self._default_restarts()
                else {}
            ),
        }


Environments = environments.Environments


@dataclass(frozen=True)
class FigureSettings:
    """A learning study: its study settings, features, environments and planner settings.

    Attributes:
        study: learners, user, prior, counts (see :class:`StudySettings`).
        planner: planner settings as (name, value) pairs, passed to ``PlannerConfig``
            (``n_starts``, the multi-start count, ``solver``, ``warm`` and ``certificate``).
        features: the features θ weighs, in order (k of them).
        user_features: the features the simulated person weighs, when not the learners'
            (then ``study.user_theta`` is their θ* over them); () when the same.
        environments: "paper" (the 48), or paper environment names and specs of the user's own
            (see :mod:`corrections_sim.study.schema`).
        plugins: the plug-in files the study imports first.
        name: the figure or study file's name (output folder, titles); not a setting.
        description: a line for the plot's title; not a setting.
    """

    study: StudySettings
    planner: tuple[tuple[str, Any], ...] = (
        ("n_starts", 1),
        ("solver", "fatrop"),
        ("warm", "newton"),
        ("certificate", True),
    )
    features: tuple[str, ...] = ("laptop", "table")
    user_features: tuple[str, ...] = ()
    environments: Environments = "paper"
    plugins: tuple = ()
    name: str = field(default="", compare=False)
    description: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if self.user_features:
            missing = [name for name in self.features if name not in self.user_features]
            if missing:
                raise ValueError(f"user_features: missing the learners' {', '.join(missing)}")
            if len(self.study.user_theta) != len(self.user_features):
                raise ValueError(
                    f"theta_star: expected {len(self.user_features)} weights for the person's "
                    f"features {list(self.user_features)}, got {len(self.study.user_theta)}"
                )
            known = tuple(self.study.user_theta[self.user_features.index(n)] for n in self.features)
            if known != tuple(self.study.theta_star):
                raise ValueError(
                    f"theta_star: the learners' part {list(self.study.theta_star)} is not the "
                    f"person's weights on {list(self.features)}, {list(known)}"
                )
        elif self.study.user_theta:
            raise ValueError("theta_star: the person's own weights need user_features")
        self.study.check(self.planner_config().n_waypoints)

    def planner_config(self) -> PlannerConfig:
        return PlannerConfig(features=self.features, **dict(self.planner))

    def atlas_spec(self) -> AtlasSpec | None:
        """The study's plan atlas as picklable data (None: plans from each run's book)."""
        a = self.study.atlas
        if a is None:
            return None
        grid = a.grid(self.study.theta0, self.study.cov0)
        return AtlasSpec(self.planner_config(), grid, a.cold_stride)

    def atlas(self):
        """This process's atlas of the study (:class:`~.planning.atlas.Atlas`), or None."""
        spec = self.atlas_spec()
        return None if spec is None else spec.atlas()

    def user_planner_config(self) -> PlannerConfig:
        """The planner the simulated person plans with: the learners' over the person's own
        features (the same smoothness, waypoints and solver)."""
        return PlannerConfig(features=self.user_features or self.features, **dict(self.planner))

    def person_target(self, envs: Sequence[Environment] | None = None) -> Target:
        """The person's side: their θ* and plans ξ*(θ*, E) over their own features, in
        ``envs`` (default: the study's). Every figure that needs the person's plans solves
        them here, so a person with features of their own is planned alike everywhere."""
        config = self.user_planner_config()
        envs = tuple(self.envs() if envs is None else envs)
        restarts = self.study.restarts()
        # With an atlas, the person's plans get the atlas (when the person weighs the robot's
        # features) and the restarts a global answer needs.
        spec = self.atlas_spec() if config == self.planner_config() else None
        theta = self.study.person()
        key = (config, theta.tobytes(), tuple(e.key() for e in envs), restarts, spec)
        with _TARGETS_LOCK:
            found = _TARGETS.get(key)
        if found is None:
            planner = shared_planner(config)
            atlas = None if spec is None else self.atlas()
            store = TargetStore() if restarts else None  # worth keeping: the searched ones
            found = Target.solve(planner, theta, envs, atlas=atlas, restarts=restarts, store=store)
            with _TARGETS_LOCK:
                _TARGETS[key] = found
                while len(_TARGETS) > _TARGETS_KEPT:
                    _TARGETS.pop(next(iter(_TARGETS)))
        return found

    def envs(self) -> tuple[Environment, ...]:
        """The study's environments (memoized per process)."""
        return environments.resolve(self.environments)

    def as_dict(self) -> dict:
        d = self.study.as_dict()
        d["planner"] = dict(self.planner)
        d["features"] = list(self.features)
        if self.user_features:
            d["user_features"] = list(self.user_features)
        d["environments"] = environments.as_data(self.environments)
        if self.plugins:
            d["plugins"] = [p.as_dict() for p in self.plugins]
        return d


#: The person's plans this process has solved (:meth:`FigureSettings.person_target`), by all
#: they depend on: the person's planner, θ*, the environments, the restarts and the atlas that
#: answers with them (its spec). Target.solve is a function of these alone (cold starts, the
#: environment's own random starts and the atlas's answer are each fixed by them), so a study
#: whose columns share a person (the FERL study's people and the robots that know their
#: feature; the relevance study's nudger and the paper's person) solves them once. Kept for the
#: last :data:`_TARGETS_KEPT`, oldest first out.
_TARGETS: dict[tuple, Target] = {}
_TARGETS_KEPT = 16
_TARGETS_LOCK = threading.Lock()  # a figure's columns may prepare in threads of one process


#: The planner's settings a study takes (the ``[planner]`` table), with their defaults; passed
#: to :class:`~corrections_sim.planning.planner.PlannerConfig` by name (which checks them).
PLANNER_SETTINGS: dict[str, Any] = dict(FigureSettings.__dataclass_fields__["planner"].default)
