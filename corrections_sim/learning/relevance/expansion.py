"""KF-CRX: KF-CRP that, when corrections keep going unexplained, asks its person for feature
traces and learns the feature it lacks (FERL, :mod:`corrections_sim.learnt.training`); and what
a study measures of it: which feature its person lacks (:func:`missing_feature`), the learnt
feature against that one (:func:`quality_of`) and its record's columns (:func:`columns`).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief, KalmanNoise
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import LearnerContext
from corrections_sim.learning.exact.bayes import gaussian_log_density
from corrections_sim.learning.history import PriorEntry, ShownEntry
from corrections_sim.learning.kalman.learners import CorrectionAwareKalman
from corrections_sim.learning.params import require_count, require_positive
from corrections_sim.learning.relevance.learners import PersonRelevanceKalman
from corrections_sim.learning.relevance.state import RelevanceState
from corrections_sim.learning.step import Step
from corrections_sim.learnt.training import Network, learn, quality
from corrections_sim.learnt.training import register as register_learnt
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import Plan, PlanningError, shared_planner
from corrections_sim.plans.book import TrailBook
from corrections_sim.scene.environments import Environment


@dataclass(frozen=True)
class FeatureAsking:
    """Mix-in: the parameters of a learner that may ask its person for feature traces and go
    on over the feature it learns from them (KF-CRX; EX-M, :mod:`.asking`).

    Attributes:
        expand_traces: how many feature traces to ask the person for when their corrections
            are not explained (:mod:`corrections_sim.learnt.training`); 0 never asks.
        expand_below: ask once E[r], the person's believed rate of relevant corrections,
            falls below this, in (0, 1).
        expand_after: and no sooner than after this many corrections (>= 1).
        expand_variances: the prior variances the learnt feature's weight may start from,
            N(0, v) uncorrelated with the others; the one under which the person's corrections
            so far were likeliest is kept (see :meth:`ExpandingRelevanceKalman.grow`). One
            value: that prior.
        expand_noises: the learnt feature's observation noise, as shares of the study's (its
            mean diagonal entry, :meth:`~corrections_sim.belief.KalmanNoise.grown`): the
            learnt feature's values are the ranking network's, so how much a correction moves
            them is not known beforehand; chosen with the variance, the pair under which the
            corrections so far were likeliest. One value: that share.
        expand_inputs: what the learnt feature's network reads (``learnt.INPUTS``).
        expand_hidden: its hidden layers' widths.
    """

    expand_traces: int = 10
    expand_below: float = 0.35
    expand_after: int = 3
    expand_variances: tuple[float, ...] = (1.0, 4.0, 16.0, 64.0)
    expand_noises: tuple[float, ...] = (1.0, 1.0 / 16.0, 1.0 / 64.0, 1.0 / 256.0)
    expand_inputs: tuple[str, ...] = Network().inputs
    expand_hidden: tuple[int, ...] = Network().hidden

    def check_asking(self) -> None:
        """Its asking parameters checked, each refused in one line naming its key; lists
        kept as tuples."""
        require_count("expand_traces", self.expand_traces, 0)
        require_count("expand_after", self.expand_after, 1)
        if not (isinstance(self.expand_below, int | float) and 0 < self.expand_below < 1):
            raise ParameterError("expand_below", f"must lie in (0, 1), got {self.expand_below!r}")
        for name in ("expand_inputs", "expand_hidden", "expand_variances", "expand_noises"):
            value = getattr(self, name)
            if not isinstance(value, list | tuple):
                raise ParameterError(name, f"must be a list, got {value!r}")
            object.__setattr__(self, name, tuple(value))
        for name, what in (("expand_variances", "variance"), ("expand_noises", "share")):
            values = getattr(self, name)
            if not values:
                raise ParameterError(name, f"must hold at least one {what}")
            for v in values:
                require_positive(name, v)
            object.__setattr__(self, name, tuple(float(v) for v in values))
        try:
            self.network()
        except ValueError as exc:
            raise ParameterError("expand_inputs", str(exc)) from None

    def network(self) -> Network:
        """The shape of the feature it learns when it expands."""
        return Network(inputs=self.expand_inputs, hidden=self.expand_hidden)

    def learns_features(self) -> bool:
        return self.expand_traces > 0


@dataclass(frozen=True)
class ExpandingRelevanceKalman(FeatureAsking, PersonRelevanceKalman):
    """KF-CRP that learns the feature it lacks (FERL): when the person's corrections are
    believed mostly unexplained, it asks for feature traces, learns a feature from them and
    learns its weight from the corrections that follow (see :meth:`expand`). Its ``expand_*``
    parameters are :class:`FeatureAsking`'s.
    """

    label = "KF-CRP with feature expansion (KF-CRX)"
    question = (
        "When most corrections are unexplained, can the robot ask for feature traces, learn "
        "the feature it lacks (FERL) and go on learning with it?"
    )
    style = ("#17becf", "-")

    def __post_init__(self) -> None:
        super().__post_init__()
        self.check_asking()

    def initial(self, belief: Belief, noise: KalmanNoise) -> Belief:
        # It keeps the prior and the corrections, to read them again over a learnt feature
        # (see :meth:`grow`).
        start = super().initial(belief, noise)
        if not self.expand_traces:
            return start
        kept = (PriorEntry(belief.theta, belief.cov),)
        return dataclasses.replace(start, state=dataclasses.replace(start.state, history=kept))

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        if not belief.extra:
            return super().update(ctx, belief, env, plan, phi_h)
        # Expanded: the person taught what their corrections were about, so they are taken
        # as relevant (KF-C's update over k + 1 features). Judged one by one, a learnt feature
        # that ranks like the person's (Spearman 0.88-0.92) still leaves most of a joint-space
        # correction unexplained: β̂ stayed below 1e-4 (measured). The learnt feature's noise
        # in ``ctx`` is the share chosen when it was learnt (RelevanceState.learnt_share).
        prior = Belief(theta=belief.theta, cov=belief.cov)
        step = CorrectionAwareKalman.update(self, ctx, prior, env, plan, phi_h)
        kept = dataclasses.replace(belief, theta=step.belief.theta, cov=step.belief.cov)
        return dataclasses.replace(step, belief=kept, relevance=1.0)

    def expand(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan
    ) -> tuple[Belief, dict | None]:
        """Feature expansion (FERL): the correction kept to be read again; once the person's
        corrections are believed mostly unexplained (E[r] < ``expand_below`` after
        ``expand_after`` corrections), ask them for ``expand_traces`` feature traces in
        ``env``, learn the feature, and go on over k + 1 features: its weight
        N(0, v) beside the belief so far (v of ``expand_variances``); from then on the person's
        corrections are taken as relevant (see :meth:`update`)."""
        state = RelevanceState.of(belief)
        if state.history and not state.asked and ctx.corrected is not None:
            shown = ShownEntry(env, plan.trajectory, np.asarray(ctx.corrected, float))
            history = (*state.history, shown)
            belief = dataclasses.replace(belief, state=dataclasses.replace(state, history=history))
        wanted = self.wants_traces(belief, ctx.iteration + 1)
        if not wanted or ctx.teach is None:  # no teacher here: a session asks its person
            return belief, None
        traces = ctx.teach(wanted, env)
        if traces is None:
            return self.declined(belief), {"asked": True, "taught": False}
        return self.grow(belief, env, traces, ctx.rng, ctx)

    def wants_traces(self, belief: Belief, corrections: int) -> int:
        """How many feature traces it asks for after ``corrections`` corrections with
        ``belief`` (0: none; it asks once)."""
        state = RelevanceState.of(belief)
        due = (
            self.expand_traces > 0
            and not state.asked
            and corrections >= self.expand_after
            and state.person is not None
            and state.person.rate_mean < self.expand_below
        )
        return self.expand_traces if due else 0

    def declined(self, belief: Belief) -> Belief:
        state = dataclasses.replace(RelevanceState.of(belief), asked=True, history=())
        return dataclasses.replace(belief, state=state)

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
        N(0, v) for the new weight, each kept correction updates the belief as KF-C does (the
        person has shown what their corrections were about, so all are taken as relevant),
        planned over k + 1 features with ``ctx``'s planner settings.

        The learnt feature's scale is the ranking network's (0 to 1 over the workspace), not
        the person's, so how large its weight may be, and how much a correction moves its
        values, are fitted from the person's own corrections: the past is read again under
        each pair of a share s of ``expand_noises`` (its observation noise s times the study's)
        and a prior variance v of ``expand_variances``, and the pair under which the filter
        predicted the corrections best is kept — the evidence Σᵢ log N(νᵢ; 0, Sᵢ) of the
        innovations over all k + 1 features (the same numbers under every pair; ties keep the
        first, shares outer, in the order given)."""
        start = time.process_time()
        learnt = learn(traces, env, rng, network=self.network())
        name = register_learnt(learnt)
        first, *past = RelevanceState.of(belief).history or (PriorEntry(belief.theta, belief.cov),)
        best, evidences = None, []
        solved: dict = {}  # the plans the re-reads share (TrailBook): the same bits, fewer solves
        for share in self.expand_noises:
            for variance in self.expand_variances:
                grown, evidence = self._reread(first, past, name, variance, ctx, share, solved)
                evidences.append(evidence)
                if best is None or evidence > best[1]:
                    best = (grown, evidence, variance, share)
        grown, _, variance, share = best
        asked = RelevanceState(asked=True, learnt_noise=share)
        grown = Belief(theta=grown.theta, cov=grown.cov, extra=(*belief.extra, name), state=asked)
        return grown, {
            "asked": True,
            "taught": True,
            "feature": name,
            "traces": len(traces),
            "reread": len(past),
            "loss": learnt.loss,
            "variance": variance,
            "noise": share,
            "candidates": [[s, v] for s in self.expand_noises for v in self.expand_variances],
            "evidence": evidences,
            "seconds": time.process_time() - start,
        }

    def _reread(
        self,
        first: PriorEntry,
        past,
        name: str,
        variance: float,
        ctx: LearnerContext,
        share: float = 1.0,
        solved: dict | None = None,
    ) -> tuple[Belief, float]:
        """The belief over k + 1 features (the learnt one, ``name``, last, its weight's prior
        N(0, ``variance``), its observation noise ``share`` times the study's) after reading
        the kept corrections ``past`` again from the prior ``first``, and the evidence
        Σᵢ log N(νᵢ; 0, Sᵢ) of their innovations."""
        theta0, cov0 = first.theta, first.cov
        k = len(theta0)
        cov = np.zeros((k + 1, k + 1))
        cov[:k, :k] = cov0
        cov[k, k] = variance
        grown = Belief(theta=np.append(theta0, 0.0), cov=cov)
        features = (*ctx.features, name)
        config = dataclasses.replace(ctx.book.planner.config, features=features)
        # The re-reads under every share and variance ask the same first problems (a share
        # enters after the first correction's plans): they share those solves (TrailBook).
        book = TrailBook(shared_planner(config), {} if solved is None else solved,
                         warm_start=ctx.book.warm_start)  # fmt: skip
        evidence = 0.0
        for shown in past:
            env_i, robot, corrected = shown.env, shown.robot, shown.corrected
            seen = dataclasses.replace(
                ctx, book=book, features=features, noise=ctx.noise.grown(k + 1, share),
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
                step = CorrectionAwareKalman.update(self, seen, grown, env_i, plan, phi_h)
            except PlanningError:
                continue  # skipped, as the loop skips an update whose plans fail
            grown = step.belief
            evidence += gaussian_log_density(step.innovation, 0.0, step.innovation_cov)
        return grown, evidence


def missing_feature(target, current: tuple[str, ...]) -> str | None:
    """The feature the person minds most (largest |θ*|) that ``current`` lacks, or None."""
    theirs = target.features or current
    weights = {n: abs(float(w)) for n, w in zip(theirs, target.theta_star, strict=True)}
    lacking = [n for n in theirs if n not in current and weights[n] > 0]
    return max(lacking, key=lambda n: weights[n]) if lacking else None


def quality_of(name: str, target, current: tuple[str, ...], env: Environment) -> dict:
    """A learnt feature against the person's feature it was taught for: Spearman ρ and the
    affine fit true ≈ a·learnt + b over random reachable configurations of the environment
    it was taught in; the person's weight maps to a·θ* on the learnt feature."""
    true = missing_feature(target, current)
    if true is None:
        return {}
    q = quality(name, true, env)
    weight = float(target.theta_star[list(target.features or current).index(true)])
    return {"spearman": q.spearman, "r2": q.r2, "target": weight * q.scale}


def columns(belief, step: Step | None, learnt: dict, k: int) -> dict:
    """Columns of a learner that can learn features: whether it asked, whether it has
    expanded (and at which correction), the learnt feature's quality against the person's
    (Spearman ρ, R² of the best affine fit), its weight θ̂ and the weight the person's maps
    to through that fit (θ*·a), the prior variance of its weight and the share of the
    study's observation noise its values are given that it chose, for every record after it
    expanded. Whether it asked is its state's ``asked`` (KF-CRX's, or EX-M's while it may ask).
    """
    asked = bool(getattr(belief.state, "asked", False))
    if not (asked or (step is not None and step.expansion is not None)):
        return {}
    out: dict = {"asked": float(asked), "expanded": float(bool(belief.extra))}
    if belief.extra and learnt:
        out |= {
            "expanded_at": learnt["expanded_at"],
            "learnt_spearman": learnt.get("spearman"),
            "learnt_r2": learnt.get("r2"),
            "learnt_weight": float(belief.theta[k]),
            "learnt_weight_target": learnt.get("target"),
            "learnt_variance": learnt.get("variance"),
            "learnt_noise": learnt.get("noise"),
        }
    return out
