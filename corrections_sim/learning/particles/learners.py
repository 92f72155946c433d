"""PF-C: the posterior over θ as resample-move particles under KF-C's model of a correction
(:mod:`corrections_sim.learning.particles.cloud`), and AL-PF, active learning over them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief, KalmanNoise, symmetrize
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import Learner, LearnerContext, Step
from corrections_sim.learning.exact.bayes import gaussian_log_likelihood as particle_likelihood
from corrections_sim.learning.exact.grid import GRID_MODELS
from corrections_sim.learning.history import CorrectionEntry, PriorEntry
from corrections_sim.learning.kalman.active import ActiveMixin
from corrections_sim.learning.kalman.learners import CorrectionAwareKalman
from corrections_sim.learning.observation import Observe
from corrections_sim.learning.params import require_count
from corrections_sim.learning.particles.cloud import correct as particles_correct
from corrections_sim.learning.particles.cloud import draw as particles_draw
from corrections_sim.learning.particles.state import ParticleState
from corrections_sim.people.corrections import OptimalCorrection
from corrections_sim.planning.planner import Plan, PlanningError
from corrections_sim.plans.interpolation import (
    check_tolerance,
    waypoint_table,
)
from corrections_sim.scene.environments import Environment


@dataclass(frozen=True)
class ParticleCorrectionAware(CorrectionAwareKalman):
    """A particle learner under KF-C's model: particles over θ from the prior, each weighed
    by every correction's likelihood N(Φ_h; hₜ(θ), N), resampled when the effective sample
    size falls below ``resample_below`` × the count, and then moved by ``moves`` random-walk
    Metropolis steps that re-evaluate every past correction
    (:mod:`~corrections_sim.learning.particles.cloud`). Its mean and covariance are the belief every
    consumer reads. θ is static (no process noise M, as in the exact reference); its random
    draws come from a child of the run's generator (``rng.spawn``), so the person's draws are
    the same as for every other learner.

    hₜ at a particle: one plan a particle from the run's plan book (on a study with a plan
    atlas, the atlas's answer). With ``interpolation`` set, on a study with an atlas, read off
    the atlas instead (:func:`~corrections_sim.plans.interpolation.waypoint_table`):
    multilinear within the cells where that is within ``interpolation`` noise sds of the
    solved plans' at every probe (edge midpoints, centre), cells cut down to ``max_level``
    where it is not, a solve of its own where a cell stays untrusted (docs/atlas.md says what
    that costs on fig. 4: more than it saves, for now).

    Attributes:
        particles: how many (>= 2).
        moves: Metropolis steps per particle after a resample (>= 0).
        resample_below: resample once ESS < this × the count, in (0, 1].
        interpolation: the interpolation's error bound, in sds of the noise N (> 0); None
            (the default): every particle's plan solved (the atlas's answer).
        max_level: the finest interpolation cell, the atlas's spacing / 2^max_level.
    """

    label = "Particle filter, KF-C's model (PF-C)"
    question = (
        "Does a particle posterior under KF-C's model, its likelihood read off the plan "
        "atlas, reach the exact posterior at a filter's price?"
    )
    style = ("#bcbd22", "--")

    particles: int = 200
    moves: int = 2
    resample_below: float = 0.5
    interpolation: float | None = None
    max_level: int = 4

    def __post_init__(self) -> None:
        super().__post_init__()
        require_count("particles", self.particles, 2)
        require_count("moves", self.moves, 0)
        require_count("max_level", self.max_level, 0)
        if self.interpolation is not None:
            try:
                check_tolerance(self.interpolation)
            except ValueError:
                raise ParameterError(
                    "interpolation",
                    f"an error bound must be a number > 0 (or absent), got {self.interpolation!r}",
                ) from None
        threshold = self.resample_below
        ok = isinstance(threshold, int | float) and not isinstance(threshold, bool)
        if not (ok and 0.0 < threshold <= 1.0):
            raise ParameterError("resample_below", f"must be in (0, 1], got {threshold!r}")
        if self.iterate != "none":
            raise ParameterError("iterate", "a particle learner is not linearised")
        if self.noise != "fixed":
            raise ParameterError("noise", "PF-C keeps N fixed (its likelihood is N(h(θ), N))")

    def initial(self, belief: Belief, noise: KalmanNoise) -> Belief:
        prior = PriorEntry(belief.theta, belief.cov)
        return Belief(theta=belief.theta, cov=belief.cov, state=ParticleState(history=(prior,)))

    @staticmethod
    def predict(observe: Observe, thetas: np.ndarray) -> np.ndarray:
        """h(θ) at each of ``thetas`` (n, k), a row of NaN where the planner finds no plan."""
        h = np.full(thetas.shape, np.nan)
        for i, theta in enumerate(thetas):
            try:
                h[i] = observe(theta[None, :])[0]
            except PlanningError:
                continue
        return h

    def likelihood_means(
        self, ctx: LearnerContext, env: Environment, robot: np.ndarray
    ) -> Callable[[np.ndarray], np.ndarray]:
        """hₜ at particles (n, k) -> (n, k), NaN where no plan exists, for a correction in
        ``env`` to ``robot`` (T, 7): off the study's atlas where it has one (class docstring),
        else a plan per particle from the run's book."""
        atlas = ctx.book.atlas
        if atlas is None or self.interpolation is None:
            observe = self.observer_of(ctx, env, robot)
            return lambda thetas: self.predict(observe, thetas)
        observation, names = self._observation(), tuple(ctx.features)
        sd = np.sqrt(np.diag(ctx.noise.observation))
        table = waypoint_table(atlas, env, names, sd, self.interpolation, self.max_level)
        T = atlas.planner.config.n_waypoints

        def h(thetas: np.ndarray) -> np.ndarray:
            values = table(thetas)
            plans = values[:, : T * 7].reshape(-1, T, 7)
            features = values[:, T * 7 :].reshape(-1, T, len(names))
            return observation.at_waypoints(plans, features, robot, env, names)

        return h

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        rng = ctx.rng.spawn(1)[0]
        state = ParticleState.of(belief)
        first = state.history[0] if state.history else PriorEntry(belief.theta, belief.cov)
        prior = Belief(theta=first.theta, cov=first.cov)
        cloud = state.particles or particles_draw(prior, self.particles, rng)
        z = np.asarray(phi_h, float)
        noise = ctx.noise.observation
        h = self.likelihood_means(ctx, env, plan.trajectory)(cloud.thetas)
        # What it expected before the correction: the particles' predictive mean and spread.
        seen = np.all(np.isfinite(h), axis=1)
        if not seen.any():
            raise PlanningError(f"{env.name}: no particle's plan exists; the update is skipped")
        w = cloud.weights()[seen] / cloud.weights()[seen].sum()
        expected = w @ h[seen]
        spread = (w[:, None] * (h[seen] - expected)).T @ (h[seen] - expected)
        entry = CorrectionEntry(env, plan.trajectory, z, noise)
        past = [*state.history[1:], entry]
        means = [(self.likelihood_means(ctx, s.env, s.robot), s.phi_h, s.noise) for s in past]

        def log_total(thetas: np.ndarray) -> tuple[np.ndarray, int]:
            total = np.zeros(len(thetas))
            for h_i, zi, ni in means:
                total += particle_likelihood(zi, h_i(thetas), ni)
            return total, len(thetas) * len(means)

        inverse = np.linalg.inv(prior.cov)

        def log_prior(thetas: np.ndarray) -> np.ndarray:
            d = thetas - prior.theta
            return -0.5 * np.einsum("ni,ij,nj->n", d, inverse, d)

        moved = particles_correct(
            cloud,
            particle_likelihood(z, h, noise),
            log_prior,
            log_total,
            rng,
            moves=self.moves,
            threshold=self.resample_below,
        )
        mean, cov = moved.particles.moments()
        kept = ParticleState(moved.particles, (first, *past))
        return Step(
            Belief(theta=mean, cov=cov, state=kept),
            None,
            z - plan.features,
            symmetrize(spread + noise),
        )


@dataclass(frozen=True)
class ParticleActive(ActiveMixin, ParticleCorrectionAware):
    """PF-C with environments chosen by eq. (A1): the UKF's predicted covariance from the
    particles' mean and covariance (2k + 1 plans per candidate environment; the particles'
    own predicted posterior would cost a plan per particle per environment)."""

    label = "AL on PF-C's belief (AL-PF)"
    question = (
        "Does active learning help when the belief it predicts from is the particle posterior?"
    )
    style = ("#ff7f0e", ":")


def particle_reference(learner: Learner, name: str, count: int) -> ParticleCorrectionAware:
    """PF-C with ``count`` particles under ``learner``'s likelihood (KF's is KF-C's with the
    correction C = ξ*), as the reference of a learner at k > 2 where no grid is; ValueError
    (one line, naming the learner ``name``) for a count < 2 or a likelihood particles cannot
    carry (N learnt, relevance judged)."""
    if isinstance(count, bool) or not isinstance(count, int) or count < 2:
        raise ValueError(f"--particles {count!r}: expected an integer >= 2")
    likelihood = learner.likelihood()
    if likelihood is None or not GRID_MODELS[likelihood.kind].plain:
        raise ValueError(
            f"learner {name}: a particle reference needs a KF or KF-C type learner, N fixed"
        )
    correction = likelihood.correction or OptimalCorrection()
    if not isinstance(learner, ParticleCorrectionAware):
        return ParticleCorrectionAware(model=correction, particles=count)
    # The learner's own moves and interpolation, ``count`` particles.
    kept = ("moves", "resample_below", "interpolation", "max_level")
    return ParticleCorrectionAware(
        model=correction, particles=count, **{name: getattr(learner, name) for name in kept}
    )
