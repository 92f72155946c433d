"""Learners that ask whether a correction is about what they know (Bobu et al. 2018): KF-CR and
PP-R (β̂ per correction), KF-CRP (the person's rate and precision learnt with θ).
"""

from __future__ import annotations

import dataclasses
import functools
import time
from dataclasses import dataclass

import numpy as np

from corrections_sim import components
from corrections_sim.belief import Belief, KalmanNoise
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import LearnerContext, Likelihood, Step
from corrections_sim.learning.history import PriorEntry, ShownEntry
from corrections_sim.learning.kalman.learners import (
    CorrectionAwareKalman,
    model_fits,
    require_model,
)
from corrections_sim.learning.params import require_count, require_positive
from corrections_sim.learning.perceptron.learners import Perceptron
from corrections_sim.learning.perceptron.update import perceptron_update
from corrections_sim.learning.relevance.judge import SPACES, Relevance, explain, judge, load_fit
from corrections_sim.learning.relevance.state import PersonBelief, RelevanceState
from corrections_sim.learnt.training import Network, learn
from corrections_sim.learnt.training import register as register_learnt
from corrections_sim.people.corrections import (
    CORRECTIONS,
    CorrectionModel,
    WaypointCorrection,
)
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import Plan, PlanningError, shared_planner
from corrections_sim.plans.book import PlanBook
from corrections_sim.scene.environments import Environment


def _judge(
    ctx: LearnerContext,
    belief: Belief,
    env: Environment,
    plan: Plan,
    model: CorrectionModel,
    relevance: Relevance,
) -> tuple[float, float | None]:
    """(β̂, ρ) of the correction in ``ctx``: the relevance model's posterior from ρ, the
    unexplained fraction of the move under ``model`` (:func:`~.relevance.explain`, started
    from θ̂ and the sigma points of N(θ̂, P + M), the plans the UKF solves anyway). Without a
    trajectory to judge (a person who shows noisy features) it is the prior."""
    if ctx.corrected is None:
        return relevance.prior, None
    starts = ctx.sigma.points(belief.theta, belief.cov + ctx.noise.process)
    found = explain(ctx.book, env, plan.trajectory, ctx.corrected, model, starts)
    return relevance.probability(found.rho), found.rho


class _RelevanceAware:
    """Mix-in: the parameters of a learner that weighs each correction by its relevance β̂
    (:mod:`corrections_sim.learning.relevance.judge`)."""

    relevance_prior: float
    relevance_spread: float

    def relevance(self, k: int) -> Relevance:
        """Its model of ρ under relevant and irrelevant corrections."""
        return Relevance(prior=self.relevance_prior, spread=self.relevance_spread, k=k)


@dataclass(frozen=True)
class RelevanceAwareKalman(_RelevanceAware, CorrectionAwareKalman):
    """KF-C that weighs each correction by its relevance β̂ (Bobu et al., CoRL 2018): the
    observation noise of the update is N / β̂.

    Attributes:
        relevance_prior: p in (0, 1), the prior probability that a correction is relevant.
        relevance_spread: σ > 0 of the unexplained fraction ρ of a relevant correction.
    """

    label = "Relevance-aware KF-C (KF-CR)"
    style = ("#e377c2", "--")

    relevance_prior: float = 0.5
    relevance_spread: float = 0.05

    def __post_init__(self) -> None:
        super().__post_init__()
        self.relevance(2)

    def likelihood(self) -> Likelihood:
        return dataclasses.replace(super().likelihood(), kind="relevance-per-correction")

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        beta, rho = _judge(ctx, belief, env, plan, self.model, self.relevance(belief.dim))
        noise = KalmanNoise(process=ctx.noise.process, observation=ctx.noise.observation / beta)
        step = super().update(dataclasses.replace(ctx, noise=noise), belief, env, plan, phi_h)
        return dataclasses.replace(step, relevance=beta, residual=rho)


@dataclass(frozen=True)
class PersonRelevanceKalman(CorrectionAwareKalman):
    """KF-C that judges relevance across a person's corrections (in the spirit of Bobu et al.,
    T-RO 2020): one belief over the person's rate r of relevant corrections and the precision
    τ of those (:class:`~corrections_sim.belief.PersonBelief`, a grid updated exactly; prior
    Beta and Gamma), shared by all of their corrections, and each correction judged by where
    it is explained as well as by how much: a correction explained only by θ's the belief
    rules out is not believed (:func:`~.relevance.judge`). The observation noise of the
    update is N / β̂, as KF-CR's.

    Attributes:
        relevance_prior: E[r] before any correction, in (0, 1).
        relevance_count: how many corrections' worth the prior on r holds (> 0).
        relevance_spread: σ̂ before any correction (> 0) where no fit is used: τ's prior mean
            is 1 / σ̂² (with a fit, τ's prior is the fit's).
        spread_count: how many relevant corrections' worth that prior on τ holds (> 0).
        space: where ρ is measured: "joint" (the arm's joints, what a simulated person moves)
            or "task" (the cup's path, what a person at the page drags or pushes).
        fit: a fit file of the densities of ρ* and of the scatter of irrelevant
            explanations (``python -m corrections_sim.run relevance-fit``); "" is the
            shipped fit, except that in joint space f₀ is then the random direction's
            Beta((7 − k)/2, k/2) and σ̂ is ``relevance_spread``.
        expand_traces: feature expansion (FERL; :mod:`corrections_sim.learnt.training`): how
            many feature traces to ask the person for when their corrections are not
            explained; 0 never asks.
        expand_below: ask once E[r], the person's believed rate of relevant corrections,
            falls below this, in (0, 1).
        expand_after: and no sooner than after this many corrections (>= 1).
        expand_variance: the learnt feature's weight starts at N(0, this) (P⁰'s diagonal in
            every study here), uncorrelated with the others.
        expand_inputs: what the learnt feature's network reads (``learnt.INPUTS``).
        expand_hidden: its hidden layers' widths.
    """

    label = "Person-level relevance KF-C (KF-CRP)"
    style = ("#d62728", "-.")

    relevance_prior: float = 0.5
    relevance_count: float = 2.0
    relevance_spread: float = 0.05
    spread_count: float = 2.0
    space: str = "joint"
    fit: str = ""
    expand_traces: int = 0
    expand_below: float = 0.35
    expand_after: int = 3
    expand_variance: float = 1.0
    expand_inputs: tuple[str, ...] = Network().inputs
    expand_hidden: tuple[int, ...] = Network().hidden

    def likelihood(self) -> Likelihood:
        return dataclasses.replace(super().likelihood(), kind="relevance-person")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.noise != "fixed":
            raise ParameterError("noise", "KF-CRP keeps N fixed (N / β̂ is its update)")
        if self.iterate != "none":
            raise ParameterError("iterate", "KF-CRP's update is not iterated (its own history)")
        require_count("expand_traces", self.expand_traces, 0)
        require_count("expand_after", self.expand_after, 1)
        if not (isinstance(self.expand_below, int | float) and 0 < self.expand_below < 1):
            raise ParameterError("expand_below", f"must lie in (0, 1), got {self.expand_below!r}")
        require_positive("expand_variance", self.expand_variance)
        for name in ("expand_inputs", "expand_hidden"):
            value = getattr(self, name)
            if not isinstance(value, list | tuple):
                raise ParameterError(name, f"must be a list, got {value!r}")
            object.__setattr__(self, name, tuple(value))
        try:
            self.network()
        except ValueError as exc:
            raise ParameterError("expand_inputs", str(exc)) from None
        Relevance(prior=self.relevance_prior, spread=self.relevance_spread)
        require_positive("relevance_count", self.relevance_count)
        require_positive("spread_count", self.spread_count)
        if self.space not in SPACES:
            raise ParameterError("space", f"must be one of {', '.join(SPACES)}, got {self.space!r}")
        if not isinstance(self.fit, str):
            raise ParameterError("fit", f"must be a file name, got {self.fit!r}")
        try:
            self.densities()
        except ValueError as exc:
            raise ParameterError("fit", str(exc)) from None

    def network(self) -> Network:
        """The shape of the feature it learns when it expands."""
        return Network(inputs=self.expand_inputs, hidden=self.expand_hidden)

    def densities(self) -> tuple[tuple[float, float] | None, tuple[float, float], tuple]:
        """In this learner's space: the Beta (a, b) of an irrelevant ρ*² (None: the random
        direction's), the Gamma (shape, rate) of τ before any correction, and the scatter of
        irrelevant explanations ((weight, sd), … ; always from the fit)."""
        fitted = _fit(self.fit)
        if self.space not in fitted:
            where = self.fit or "the shipped fit"
            raise ValueError(f"{where}: has no densities for space {self.space!r}")
        mine = fitted[self.space]
        if self.space == "joint" and not self.fit:
            shape = 0.5 * self.spread_count
            return None, (shape, shape * self.relevance_spread**2), mine.scatter
        return mine.irrelevant, mine.precision, mine.scatter

    def person(self) -> PersonBelief:
        """The prior belief over the person."""
        _, (shape, rate), _ = self.densities()
        return PersonBelief.prior(
            shape,
            rate,
            self.relevance_prior * self.relevance_count,
            (1.0 - self.relevance_prior) * self.relevance_count,
        )

    def initial(self, belief: Belief, noise: KalmanNoise) -> Belief:
        # A learner that may learn a feature keeps the prior and its corrections, to read
        # them again over the new feature (see :meth:`grow`).
        kept = (PriorEntry(belief.theta, belief.cov),) if self.expand_traces else ()
        state = RelevanceState(person=self.person(), history=kept)
        return Belief(theta=belief.theta, cov=belief.cov, state=state)

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        state = self._state(belief)
        person = state.person or self.person()
        prior = Belief(theta=belief.theta, cov=belief.cov)
        if belief.extra:
            # Expanded: the person taught what their corrections were about, so they are
            # taken as relevant (KF-C's update over k + 1 features). Judged one by one, a
            # learnt feature that ranks like the person's (Spearman 0.88-0.92) still leaves
            # most of a joint-space correction unexplained: β̂ stayed below 1e-4 (measured).
            step = super().update(ctx, prior, env, plan, phi_h)
            kept = dataclasses.replace(belief, theta=step.belief.theta, cov=step.belief.cov)
            return dataclasses.replace(step, belief=kept, relevance=1.0)
        if ctx.corrected is None:  # nothing to judge: the prior rate
            beta, found = person.rate_mean, None
        else:
            full = super().update(ctx, prior, env, plan, phi_h).belief  # p(θ | z), β̂ = 1
            irrelevant, _, scatter = self.densities()
            found = judge(
                ctx.book,
                env,
                plan.trajectory,
                ctx.corrected,
                self.model,
                full.theta,
                full.cov,
                ctx.sigma.points(belief.theta, belief.cov + ctx.noise.process),
                person=person,
                scatter=[(w, sd**2 * np.eye(belief.dim)) for w, sd in scatter],
                scatter_center=belief.theta,
                irrelevant=irrelevant,
                space=self.space,
            )
            beta = found.relevance
        noise = KalmanNoise(process=ctx.noise.process, observation=ctx.noise.observation / beta)
        step = super().update(dataclasses.replace(ctx, noise=noise), prior, env, plan, phi_h)
        if found is not None:
            person = found.person
        history = state.history
        if history and not state.asked and ctx.corrected is not None:
            shown = ShownEntry(env, plan.trajectory, np.asarray(ctx.corrected, float))
            history = (*history, shown)
        kept = RelevanceState(person=person, asked=state.asked, history=history)
        after = Belief(theta=step.belief.theta, cov=step.belief.cov, extra=belief.extra, state=kept)
        after, expansion = self.expand(ctx, after, env)
        return dataclasses.replace(
            step,
            belief=after,
            relevance=beta,
            residual=None if found is None else found.rho,
            expansion=expansion,
        )

    def expand(
        self, ctx: LearnerContext, belief: Belief, env: Environment
    ) -> tuple[Belief, dict | None]:
        """Feature expansion (FERL): once the person's corrections are believed mostly
        unexplained (E[r] < ``expand_below`` after ``expand_after`` corrections), ask them for
        ``expand_traces`` feature traces in ``env``, learn the feature, and go on over k + 1
        features: its weight N(0, ``expand_variance``) beside the belief so far; from then on
        the person's corrections are taken as relevant (see :meth:`update`)."""
        wanted = self.wants_traces(belief, ctx.iteration + 1)
        if not wanted or ctx.teach is None:  # no teacher here: a session asks its person
            return belief, None
        traces = ctx.teach(wanted, env)
        if traces is None:
            return self.declined(belief), {"asked": True, "taught": False}
        return self.grow(belief, env, traces, ctx.rng, ctx)

    def learns_features(self) -> bool:
        return self.expand_traces > 0

    def wants_traces(self, belief: Belief, corrections: int) -> int:
        """How many feature traces it asks for after ``corrections`` corrections with
        ``belief`` (0: none; it asks once)."""
        state = self._state(belief)
        due = (
            self.expand_traces > 0
            and not state.asked
            and corrections >= self.expand_after
            and state.person is not None
            and state.person.rate_mean < self.expand_below
        )
        return self.expand_traces if due else 0

    def declined(self, belief: Belief) -> Belief:
        state = dataclasses.replace(self._state(belief), asked=True, history=())
        return dataclasses.replace(belief, state=state)

    @staticmethod
    def _state(belief: Belief) -> RelevanceState:
        """Its own state in ``belief`` (a fresh one for a belief it did not make)."""
        return belief.state if isinstance(belief.state, RelevanceState) else RelevanceState()

    def grow(
        self,
        belief: Belief,
        env: Environment,
        traces,
        rng: np.random.Generator,
        ctx: LearnerContext,
    ) -> tuple[Belief, dict]:
        """The belief over k + 1 features after learning a feature from ``traces`` given in
        ``env`` (registered under its name; the expansion's facts beside it).

        The past is read again over the new features: from the prior (θ̂⁰, P⁰) extended by
        N(0, ``expand_variance``) for the new weight, each kept correction updates the belief
        as KF-C does (the person has shown what their corrections were about, so all are
        taken as relevant), planned over k + 1 features with ``ctx``'s planner settings."""
        start = time.process_time()
        learnt = learn(traces, env, rng, network=self.network())
        name = register_learnt(learnt)
        first, *past = self._state(belief).history or (PriorEntry(belief.theta, belief.cov),)
        theta0, cov0 = first.theta, first.cov
        k = len(theta0)
        cov = np.zeros((k + 1, k + 1))
        cov[:k, :k] = cov0
        cov[k, k] = self.expand_variance
        grown = Belief(theta=np.append(theta0, 0.0), cov=cov)
        features = (*ctx.features, name)
        config = dataclasses.replace(ctx.book.planner.config, features=features)
        book = PlanBook(shared_planner(config), warm_start=ctx.book.warm_start)
        for shown in past:
            env_i, robot, corrected = shown.env, shown.robot, shown.corrected
            seen = dataclasses.replace(
                ctx, book=book, features=features, noise=ctx.noise.grown(k + 1),
                corrected=corrected,
            )  # fmt: skip
            plan = Plan(  # the plan the person corrected then, its Φ over k + 1 features
                trajectory=robot,
                features=feature_counts(robot, env_i, features),
                reward=float("nan"),
                status="kept",
                iterations=0,
                solve_time=0.0,
                starts=0,
            )
            try:
                phi_h = feature_counts(corrected, env_i, features)
                grown = CorrectionAwareKalman.update(self, seen, grown, env_i, plan, phi_h).belief
            except PlanningError:
                continue  # skipped, as the loop skips an update whose plans fail
        asked = RelevanceState(asked=True)
        grown = Belief(theta=grown.theta, cov=grown.cov, extra=(*belief.extra, name), state=asked)
        return grown, {
            "asked": True,
            "taught": True,
            "feature": name,
            "traces": len(traces),
            "reread": len(past),
            "loss": learnt.loss,
            "seconds": time.process_time() - start,
        }


@functools.lru_cache(maxsize=16)
def _fit(path: str):
    return load_fit(path or None)


@dataclass(frozen=True)
class RelevanceAwarePerceptron(_RelevanceAware, Perceptron):
    """PP whose rate is scaled by the correction's relevance β̂: θ̂ += αᵗ β̂ (Φ_h − Φ(ξᵗ)).

    Attributes:
        model: C, the correction model β̂ explains corrections with (KF-C's default).
        relevance_prior: p in (0, 1), the prior probability that a correction is relevant.
        relevance_spread: σ > 0 of the unexplained fraction ρ of a relevant correction.
    """

    label = "Relevance-aware PP (PP-R)"
    style = ("#bcbd22", "-")

    model: CorrectionModel = components.nested(CORRECTIONS, WaypointCorrection())
    relevance_prior: float = 0.5
    relevance_spread: float = 0.05

    def assumed_correction(self) -> CorrectionModel:
        return self.model

    def __post_init__(self) -> None:
        super().__post_init__()
        require_model(self.model)
        self.relevance(2)

    def check(self, n_waypoints: int) -> None:
        model_fits(self.model, n_waypoints)

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        beta, rho = _judge(ctx, belief, env, plan, self.model, self.relevance(belief.dim))
        alpha = float(ctx.alphas[ctx.iteration]) * beta
        new = perceptron_update(belief, plan.features, phi_h, alpha)
        return Step(new, None, phi_h - plan.features, None, relevance=beta, residual=rho)
