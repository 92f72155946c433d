"""EX-M that may ask for feature traces (issues 66 and 69): the exact posterior over the person
(:class:`~corrections_sim.learning.exact.mixture.ExactPersonModel`) that, when the person's
corrections are judged mostly unexplained across them, asks for feature traces and goes on over
k + 1 features with the learner available there.

When to ask is KF-CRP's judgement (:meth:`PersonRelevanceKalman.judged
<corrections_sim.learning.relevance.learners.PersonRelevanceKalman.judged>`: where in joint
space each correction is explained, and how much of it; one belief over the person's rate of
relevant corrections), fed EX-M's own belief before and after each correction. EX-M's own
evidence cannot say it: judged in feature space, a person who minds only what the robot lacks
looks like a noisy person (their NIS is a noisy-optimal person's), and EX-M's exact relevance
(``relevance = true``) believes their corrections relevant (β̂ 0.73 on average; docs/
person-models.md). The judgement decides when to ask only: EX-M's posterior is the same to
the bit whether it asks or not, until the person teaches.

After teaching, it is KF-CRX after expansion: the past read again over k + 1 features from the
prior, the learnt weight's prior variance and its noise chosen by their evidence, and KF-C's
update from then on (:class:`~.expansion.ExpandingRelevanceKalman`). The exact posterior at
k + 1 needs a plan atlas over the learnt feature, which no run can build for a feature it has
just learnt (docs/learnt-features.md: about 8 minutes an atlas); the filter is the best learner
there is at k + 1 in a run.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief, KalmanNoise
from corrections_sim.learning.base import LearnerContext, Step
from corrections_sim.learning.exact.mixture import ExactPersonModel, MixtureState
from corrections_sim.learning.relevance.expansion import ExpandingRelevanceKalman, FeatureAsking
from corrections_sim.learning.relevance.state import RelevanceState
from corrections_sim.planning.planner import Plan
from corrections_sim.scene.environments import Environment

#: The parameters of asking (:class:`~.expansion.FeatureAsking`'s).
ASKING_KEYS = tuple(f.name for f in dataclasses.fields(FeatureAsking))


@dataclass(frozen=True, eq=False)
class AskingState(MixtureState):
    """EX-M's state while it may ask: the posterior over θ, N and the model, and KF-CRP's
    belief over the person (their rate of relevant corrections), whether it asked, and the
    corrections kept to be read again over a learnt feature.

    Attributes:
        asking: that belief, as KF-CRX keeps it (:class:`RelevanceState`).
    """

    asking: RelevanceState = dataclasses.field(default_factory=RelevanceState)

    @property
    def asked(self) -> bool:
        """Whether it has asked for traces (it asks once)."""
        return self.asking.asked

    def columns(self) -> dict[str, float]:
        return super().columns() | self.asking.columns()


@functools.lru_cache(maxsize=16)
def _asker(values: tuple) -> ExpandingRelevanceKalman:
    return ExpandingRelevanceKalman(**dict(zip(ASKING_KEYS, values, strict=True)))


@dataclass(frozen=True)
class AskingPersonModel(FeatureAsking, ExactPersonModel):
    """EX-M (:class:`ExactPersonModel`, its attributes) that may ask its person for feature
    traces (module docstring), with :class:`~.expansion.FeatureAsking`'s ``expand_*``
    parameters, KF-CRX's defaults but ``expand_traces``: 0, never asking, by default, and
    then it is :class:`ExactPersonModel` to the bit.
    """

    question = (
        "The robot we recommend: what is learnt when θ, the person's noise and their way of "
        "correcting are all left to the posterior, for people it was not tuned on?"
    )  # EX-M's, registered from here (ExactPersonModel is its posterior, without asking)

    expand_traces: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        self.check_asking()

    def asker(self) -> ExpandingRelevanceKalman:
        """KF-CRX with these asking parameters: the judgement, the asking and the filter over
        k + 1 features after teaching."""
        return _asker(tuple(getattr(self, name) for name in ASKING_KEYS))

    def initial(self, belief: Belief, noise: KalmanNoise) -> Belief:
        start = super().initial(belief, noise)
        if not self.expand_traces:
            return start
        asking = RelevanceState.of(self.asker().initial(belief, noise))
        return dataclasses.replace(start, state=_with(start.state, asking))

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        if belief.extra:  # taught: the filter over k + 1 it went on with
            return self.asker().update(ctx, belief, env, plan, phi_h)
        step = super().update(ctx, belief, env, plan, phi_h)
        if not self.expand_traces:
            return step
        asker = self.asker()
        asking = _asking(belief, asker, ctx.noise)
        person = asking.person or asker.person()
        if ctx.corrected is None:  # nothing to judge: the prior rate
            beta, rho = person.rate_mean, None
        else:
            found = asker.judged(ctx, belief, step.belief, env, plan, person)
            beta, rho, person = found.relevance, found.rho, found.person
        asking = dataclasses.replace(asking, person=person)
        judged = Belief(step.belief.theta, step.belief.cov, state=asking)
        grown, expansion = asker.expand(ctx, judged, env, plan)
        if grown.extra:  # taught: from here on the filter over k + 1 features
            after = grown
        else:
            after = dataclasses.replace(
                step.belief, state=_with(step.belief.state, RelevanceState.of(grown))
            )
        relevance = step.relevance if step.relevance is not None else beta
        residual = step.residual if step.residual is not None else rho
        return dataclasses.replace(
            step, belief=after, relevance=relevance, residual=residual, expansion=expansion
        )

    def wants_traces(self, belief: Belief, corrections: int) -> int:
        if belief.extra or not self.expand_traces:
            return 0
        return self.asker().wants_traces(_judged_belief(belief), corrections)

    def declined(self, belief: Belief) -> Belief:
        if belief.extra or not isinstance(belief.state, AskingState):
            return belief
        asking = RelevanceState.of(self.asker().declined(_judged_belief(belief)))
        return dataclasses.replace(belief, state=_with(belief.state, asking))

    def grow(
        self,
        belief: Belief,
        env: Environment,
        traces,
        rng: np.random.Generator,
        ctx: LearnerContext,
    ) -> tuple[Belief, dict]:
        """The belief over k + 1 features after learning a feature from ``traces`` given in
        ``env``: KF-CRX's (:meth:`~.expansion.ExpandingRelevanceKalman.grow`), from the
        corrections it kept."""
        return self.asker().grow(_judged_belief(belief), env, traces, rng, ctx)


def _with(state: MixtureState, asking: RelevanceState) -> AskingState:
    """EX-M's ``state`` with the belief over the person ``asking``."""
    fields = {f.name: getattr(state, f.name) for f in dataclasses.fields(MixtureState)}
    return AskingState(**fields, asking=asking)


def _asking(belief: Belief, asker: ExpandingRelevanceKalman, noise: KalmanNoise) -> RelevanceState:
    """The belief over the person that ``belief`` holds (the prior's where it holds none)."""
    if isinstance(belief.state, AskingState):
        return belief.state.asking
    return RelevanceState.of(asker.initial(Belief(belief.theta, belief.cov), noise))


def _judged_belief(belief: Belief) -> Belief:
    """EX-M's moments with its belief over the person: what KF-CRX's asking reads."""
    state = belief.state.asking if isinstance(belief.state, AskingState) else RelevanceState()
    return Belief(belief.theta, belief.cov, state=state)
