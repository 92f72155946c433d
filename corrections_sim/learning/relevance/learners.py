"""Learners that ask whether a correction is about what they know (Bobu et al. 2018): KF-CR and
PP-R (β̂ per correction), KF-CRP (the person's rate and precision learnt with θ).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np

from corrections_sim import components
from corrections_sim.belief import Belief, KalmanNoise
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import LearnerContext, Likelihood, Step
from corrections_sim.learning.kalman.learners import (
    CorrectionAwareKalman,
    model_fits,
    require_model,
)
from corrections_sim.learning.params import require_positive
from corrections_sim.learning.perceptron.learners import Perceptron
from corrections_sim.learning.perceptron.update import perceptron_update
from corrections_sim.learning.relevance.judge import (
    SPACES,
    Judgement,
    Relevance,
    explain,
    judge,
    load_fit,
)
from corrections_sim.learning.relevance.state import PersonBelief, RelevanceState
from corrections_sim.people.corrections import (
    CORRECTIONS,
    CorrectionModel,
    WaypointCorrection,
)
from corrections_sim.planning.planner import Plan
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
    question = (
        "Can a filter tell, one correction at a time, whether a correction is about what it "
        "can represent (β̂, Bobu et al. 2018), and learn only from those?"
    )
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
    """

    label = "Person-level relevance KF-C (KF-CRP)"
    question = (
        "Judged across a person's corrections (one belief over how often and how precisely "
        "they correct relevantly), does relevance keep a person who minds only what the robot "
        "lacks from moving it?"
    )
    style = ("#d62728", "-.")

    relevance_prior: float = 0.5
    relevance_count: float = 2.0
    relevance_spread: float = 0.05
    spread_count: float = 2.0
    space: str = "joint"
    fit: str = ""

    def likelihood(self) -> Likelihood:
        return dataclasses.replace(super().likelihood(), kind="relevance-person")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.noise != "fixed":
            raise ParameterError("noise", "KF-CRP keeps N fixed (N / β̂ is its update)")
        if self.iterate != "none":
            raise ParameterError("iterate", "KF-CRP's update is not iterated (its own history)")
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
        return Belief(belief.theta, belief.cov, state=RelevanceState(person=self.person()))

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        state = RelevanceState.of(belief)
        person = state.person or self.person()
        prior = Belief(theta=belief.theta, cov=belief.cov)
        if ctx.corrected is None:  # nothing to judge: the prior rate
            beta, found = person.rate_mean, None
        else:
            full = super().update(ctx, prior, env, plan, phi_h).belief  # p(θ | z), β̂ = 1
            found = self.judged(ctx, prior, full, env, plan, person)
            beta = found.relevance
        noise = KalmanNoise(process=ctx.noise.process, observation=ctx.noise.observation / beta)
        step = super().update(dataclasses.replace(ctx, noise=noise), prior, env, plan, phi_h)
        if found is not None:
            person = found.person
        kept = dataclasses.replace(state, person=person)
        after = Belief(theta=step.belief.theta, cov=step.belief.cov, extra=belief.extra, state=kept)
        after, expansion = self.expand(ctx, after, env, plan)
        return dataclasses.replace(
            step,
            belief=after,
            relevance=beta,
            residual=None if found is None else found.rho,
            expansion=expansion,
        )

    def judged(
        self,
        ctx: LearnerContext,
        prior: Belief,
        full: Belief,
        env: Environment,
        plan: Plan,
        person: PersonBelief,
    ) -> Judgement:
        """The correction in ``ctx`` to ``plan`` judged (:func:`~.relevance.judge`): under the
        belief over θ after taking it in as relevant, ``full``, with the belief before it,
        ``prior`` (its sigma points start the search, its mean centres the scatter of
        irrelevant explanations), and the belief over the ``person`` before it."""
        irrelevant, _, scatter = self.densities()
        return judge(
            ctx.book,
            env,
            plan.trajectory,
            ctx.corrected,
            self.model,
            full.theta,
            full.cov,
            ctx.sigma.points(prior.theta, prior.cov + ctx.noise.process),
            person=person,
            scatter=[(w, sd**2 * np.eye(prior.dim)) for w, sd in scatter],
            scatter_center=prior.theta,
            irrelevant=irrelevant,
            space=self.space,
        )

    def expand(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan
    ) -> tuple[Belief, dict | None]:
        """``belief`` after a correction in ``env`` to ``plan``, and what feature expansion did
        there (None: nothing; KF-CRP learns no feature, KF-CRX does,
        :mod:`~corrections_sim.learning.relevance.expansion`)."""
        return belief, None


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
    question = (
        "FERL's BETA baseline: does scaling the perceptron's step by β̂ keep it from drifting "
        "under corrections it cannot explain?"
    )
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
