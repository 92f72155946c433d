"""What a learner is to the study loop, and the registry of learners by name.

A learner, at every iteration t of a run (:func:`corrections_sim.study.loop.run_learner`):

1. chooses the environment Eᵗ (:meth:`Learner.choose`; by default the run's random draw, which
   every learner on the same ``stream`` shares run by run);
2. after the robot planned ξᵗ = ξ*(θ̂ᵗ, Eᵗ) and the user corrected it, turns its belief
   N(θ̂ᵗ, Pᵗ) and the correction's features Φ_h into the next belief (:meth:`Learner.update`),
   reporting what calibration needs (:class:`Step`).

It reaches the planner and the study's shared filter settings (M, N, sigma points) only
through :class:`LearnerContext`. Class attributes describe it to the figures (label, style,
stream, whether its P means something, whose Kalman gains give its learning rate). A learner
is a :class:`Learner` subclass, a frozen dataclass whose fields are its own parameters
(defaults and checks in the class), registered by name::

    @register_learner("MINE")
    @dataclass(frozen=True)
    class Mine(Learner):
        label = "My learner"
        step: float = 0.25          # a parameter: [learners.MINE] step = 0.5

        def update(self, ctx, belief, env, plan, phi_h):
            ...
            return Step(new_belief, gain=None, innovation=phi_h - plan.features)

:func:`make_learner` builds one by name from its parameters (a study file's
``[learners.MINE]`` table). The built-in learners are registered in
:mod:`corrections_sim.learning.roster`, which the package imports first, so they come first
in the registry's order.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np

from corrections_sim import components
from corrections_sim.belief import Belief, KalmanNoise
from corrections_sim.learning.observation import Observation, Observe
from corrections_sim.learning.step import Step  # noqa: F401  (what update returns)
from corrections_sim.planning.planner import Plan
from corrections_sim.registry import Registry
from corrections_sim.scene.environments import Environment

if TYPE_CHECKING:  # annotations only
    from corrections_sim.people.corrections import CorrectionModel
    from corrections_sim.plans.book import PlanBook


class SigmaRule(Protocol):
    """The study's unscented transform as a learner reads it; the Kalman family's
    :class:`~corrections_sim.learning.kalman.filter.SigmaPoints` is the one studies build
    (named here by its shape: families import this module, not the other way)."""

    def points(self, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """The 2k + 1 sigma points of N(``mean``, ``cov``), (2k + 1, k)."""
        ...

    def weights(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The mean's and the covariance's weights, each (2k + 1,)."""
        ...


@dataclass(frozen=True, eq=False)
class LearnerContext:
    """What one run offers its learner.

    Attributes:
        book: this run's memoized planner, ``book.plan(θ, E)`` and ``book.observe(E)``
            (h(θ) = Φ(ξ*(θ, E), E) as a batch callable (n, k) -> (n, k)).
        envs: the study's environments; :meth:`Learner.choose` returns an index into them.
        features: the feature names θ weighs, in order.
        n_waypoints: T of every trajectory.
        alphas: learning rate per iteration (iterations,) for a learner with ``rate_from``
            (see :attr:`Learner.needs_rates`), else None.
        rng: the run's generator (shared with the user's noise: drawing from it changes the
            user's draws too).
        noise: the study's filter noise, M (process) and N (observation).
        sigma: the study's unscented transform (:class:`SigmaRule`).
        iteration: t, the correction being processed (0-based).
        corrected: the corrected trajectory ξ_h (T, 7) when the person showed one (a learner
            that judges whether a correction is explainable reads it), else None.
        declined: indices of the environments passed over since the last correction (a person
            skipped them, or their plan failed); a learner that chooses Eᵗ itself leaves them
            out, or it would offer the same environment again.
        teach: asks the person for feature traces, ``teach(n, env)`` -> n traces (states, 7)
            from where the feature they mind most and the robot lacks is high to where it is
            low, or None (nobody to ask, or nothing they mind that the robot lacks); None when
            the setting offers no teacher.
    """

    book: PlanBook
    envs: Sequence[Environment]
    features: tuple[str, ...]
    n_waypoints: int
    alphas: np.ndarray | None
    rng: np.random.Generator
    noise: KalmanNoise
    sigma: SigmaRule
    iteration: int = 0
    corrected: np.ndarray | None = None
    declined: frozenset[int] = frozenset()
    teach: Callable[[int, Environment], list[np.ndarray] | None] | None = None


@dataclass(frozen=True)
class Likelihood:
    """What a learner assumes a correction tells about θ: the model its exact reference is
    computed under (:mod:`corrections_sim.figures.reference`), read instead of its class.

    Attributes:
        kind: the model's name, registered by the learner's family
            (:data:`~corrections_sim.learning.exact.grid.GRID_MODELS`): "gaussian", Φ_h ~
            N(h(θ), N) with N known; "gaussian-learnt-noise", N integrated out under the
            learner's prior; "boltzmann", BP's P(ξ_h ≻ ξᵗ | θ); "relevance-per-correction",
            N / β̂ with β̂ as the learner judged it; "relevance-person", θ with the
            person's rate and precision.
        correction: C in hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E))); None: h(θ) = Φ(ξ*(θ, E)) itself.
        max_level: how many times the learner itself cuts an atlas cell in half (an exact
            learner's ``max_level``; 4 for the others): a refined reference goes one finer.
        axes: how the learner cuts a cell ("all" or "narrow", an exact learner's ``axes``):
            a refined reference cuts its cells the same way.
    """

    kind: str
    correction: CorrectionModel | None = None
    max_level: int = 4
    axes: str = "all"


class Learner(abc.ABC):
    """A learner of θ from corrections; subclass, implement :meth:`update`, register.

    Class attributes (read by the study loop and the figures without building one):
        label: its name in figures ("" means the registered name).
        style: (colour, line style) in figures, or None for the next free colour.
        stream: random stream of its runs: learners on one stream see the same environment
            draws run by run (common random numbers), so they are compared paired.
        active: chooses Eᵗ itself (:meth:`choose`); if the user is deterministic, such a
            learner's run is deterministic and runs once.
        has_covariance: whether its P means something (NEES, the calibration panel).
        rate_from: the learner whose Kalman gains give this learner's rate αᵗ (PP-type);
            its runs go after that learner's, and ``ctx.alphas`` holds the rate.
        needs_atlas: it reads the study's plan atlas (``ctx.book.atlas``; an exact learner
            on its grid), so a study without one refuses it.
        question: the one question a study answers by running it, in a sentence ending in
            "?" (the study-file reference lists it beside the learner); every built-in
            learner states its own, a plug-in's may.
    """

    label: ClassVar[str] = ""
    question: ClassVar[str] = ""
    style: ClassVar[tuple[str, str] | None] = None
    stream: ClassVar[int] = 0
    active: ClassVar[bool] = False
    has_covariance: ClassVar[bool] = True
    rate_from: ClassVar[str | None] = None
    needs_atlas: ClassVar[bool] = False

    @classmethod
    def needs_rates(cls) -> bool:
        """Whether its runs need ``ctx.alphas`` (fixed, or from ``rate_from``'s gains)."""
        return cls.rate_from is not None

    def rate_source(self) -> str | None:
        """The learner whose gains give this one's learning rate, or None when it has none or
        it is fixed (a PP-type learner with ``fixed_alpha``)."""
        return self.rate_from

    def fixed_rate(self) -> float | None:
        """Its fixed learning rate, if it has one."""
        return None

    def check(self, n_waypoints: int) -> None:
        """Refuse parameters that do not fit trajectories of ``n_waypoints`` waypoints
        (called once the planner's T is known, before anything runs)."""
        return None

    def initial(self, belief: Belief, noise: KalmanNoise) -> Belief:
        """The belief a run starts from, given the study's prior N(θ̂⁰, P⁰) and the shared
        filter noise: the prior itself, unless the learner believes more (e.g. about N)."""
        return belief

    def choose(self, ctx: LearnerContext, belief: Belief, draw: int) -> int:
        """Index of Eᵗ in ``ctx.envs``; ``draw`` is the run's random choice."""
        return draw

    def assumed_correction(self) -> CorrectionModel | None:
        """The model C it explains a person's corrections with (KF-C's ``model``), or None
        when it takes Φ_h as it comes."""
        return None

    def likelihood(self) -> Likelihood | None:
        """What it assumes a correction tells about θ (None: no model an exact reference can
        be computed under, e.g. the perceptron's or KF-A's)."""
        return None

    def observation(self) -> Observation | None:
        """The observation model it holds, hₜ(θ) (:mod:`corrections_sim.learning.observation`),
        or None when it reads no function of θ (the perceptron)."""
        return None

    def observer(self, ctx: LearnerContext, belief: Belief, env: Environment) -> Observe:
        """hₜ for a correction not yet made in ``env``: to the plan ξ*(θ̂, E) the robot would
        show now (planned only when the observation model reads it)."""
        observation = self._observation()
        robot = ctx.book.plan(belief.theta, env).trajectory if observation.needs_robot else None
        return observation.observe(ctx.book, env, robot, ctx.features)

    def observer_of(self, ctx: LearnerContext, env: Environment, robot: np.ndarray) -> Observe:
        """hₜ for a correction made in ``env`` to the robot's trajectory ``robot`` (T, 7)."""
        return self._observation().observe(ctx.book, env, robot, ctx.features)

    def _observation(self) -> Observation:
        observation = self.observation()
        if observation is None:
            raise TypeError(f"{type(self).__name__} holds no observation model")
        return observation

    def learns_features(self) -> bool:
        """Whether it may ask its person for feature traces and learn the feature it lacks
        (FERL, :mod:`corrections_sim.learnt.training`): a session then builds the learnt
        feature's planner ahead and shows the teaching controls."""
        return False

    def wants_traces(self, belief: Belief, corrections: int) -> int:
        """How many feature traces it asks for after ``corrections`` corrections with
        ``belief`` (0: none, which a learner that does not learn features always says)."""
        return 0

    def declined(self, belief: Belief) -> Belief:
        """``belief`` once the person has said they cannot give the traces it asked for (it
        does not ask again)."""
        return belief

    @abc.abstractmethod
    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        """The belief after a correction with features ``phi_h`` (k,) of the robot's ``plan``
        ξᵗ in ``env``. May raise ``PlanningError`` (the update is then skipped)."""


LEARNERS: Registry[type[Learner]] = Registry("learner", base=Learner)
"""Every learner by name, in the order figures and tables list them."""


def register_learner(name: str, *, replace: bool = False):
    """Class decorator: register a :class:`Learner` subclass (a dataclass) under ``name``."""
    return LEARNERS.decorator(name, replace=replace)


def make_learner(
    name: str, params: Mapping[str, Any] | None = None, *, where: str | None = None
) -> Learner:
    """The registered learner ``name`` with its ``params``.

    Raises:
        ValueError: an unknown name, an unknown parameter or a bad value, in one line
            naming its key path (``learners.KF-A.attenuation_min: must be > 0, got -1``).
    """
    return components.build(LEARNERS, name, params, where=where or f"learners.{name}")
