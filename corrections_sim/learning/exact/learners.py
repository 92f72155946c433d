"""EX-C and EX-CL: the exact posterior over θ under KF-C's and KF-CL's models, on the nodes
of the study's plan atlas (:mod:`corrections_sim.plans.atlas`).

A correction in E is weighed at every node θ of the atlas's grid by hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E))),
ξ*(θ, E) the atlas's plan there: no solve, one feature count of every node's corrected plan.
The posterior is the grid's (:mod:`corrections_sim.learning.exact.bayes`, the functions
the exact reference of ``run reference`` uses), so on the atlas's grid it *is* that reference;
its moments are the belief every consumer reads. θ is static (no process noise M, as in the
reference); the grid truncates the prior to the atlas's box (θ̂⁰ ± ``width`` sd).

Where the posterior grows narrower than the atlas's spacing resolves (fewer than
``resolution`` nodes in its narrowest sd), the cells of its core are cut finer
(:class:`~corrections_sim.learning.exact.bayes.Refinement`; the integrals are the
trapezoid rule's on every cell, :class:`~corrections_sim.learning.exact.cells.Cells`):
ξ*(θ, E) at each new node from the atlas (:meth:`Atlas.plans
<corrections_sim.plans.atlas.Atlas.plans>`, warm from the best corner of its atlas cell),
and every correction so far weighed again there (the learner keeps them). The reference tool
refines the same way, at twice the resolution.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief, KalmanNoise, floored, symmetrize
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import LearnerContext, Likelihood, Step
from corrections_sim.learning.exact import bayes as ref
from corrections_sim.learning.exact.cells import Cells, cell_moments
from corrections_sim.learning.exact.state import ExactState, GridPosterior
from corrections_sim.learning.history import CorrectionEntry, PriorEntry
from corrections_sim.learning.kalman.learners import CorrectionAwareKalman
from corrections_sim.learning.kalman.state import NoisePosterior
from corrections_sim.learning.params import require_count
from corrections_sim.planning.planner import Plan, PlanningError
from corrections_sim.scene.environments import Environment

#: What an exact learner's P is (:attr:`ExactCorrectionAware.spread`).
SPREADS = ("nodes", "cells")


@dataclass(frozen=True)
class ExactCorrectionAware(CorrectionAwareKalman):
    """The posterior of KF-C's model, exactly, on the study's atlas grid (module docstring):
    p(θ | z₁…zₜ) ∝ N(θ; θ̂⁰, P⁰) Πᵢ N(zᵢ; hᵢ(θ), N), N the study's (``noise = "fixed"``) or,
    with ``noise = "learnt"``, integrated out under KF-CL's prior IW(ν₀, V₀):
    Πᵢ → |V₀ + Σᵢ rᵢ rᵢᵀ|^(−(ν₀ + t)/2), rᵢ = zᵢ − hᵢ(θ).

    Attributes:
        resolution: grid nodes the posterior's narrowest sd needs before the grid is refined
            (0: the atlas's nodes only; module docstring).
        cut: the posterior's core, whose cells are refined: where its density is within
            ``cut`` (in log) of its peak (9.2: 1e-4 of it).
        max_level: the finest refinement, the atlas's spacing / 2^max_level.
        axes: how a cell is cut: "all" (in 2^k) or "narrow" (along the axis across which the
            posterior is narrowest; :class:`~corrections_sim.learning.exact.bayes.Refinement`).
        spread: what the belief's P is: "nodes", the covariance of the nodes' trapezoid
            weights (point masses), or "cells", E[(θ − θ̂)(θ − θ̂)ᵀ] under the density the
            cells interpolate (the one its draws come from,
            :func:`~corrections_sim.learning.exact.cells.cell_moments`), which adds what the
            finest cells cannot resolve. θ̂ is the trapezoid rule's mean either way.
    """

    label = "Exact posterior, KF-C's model (EX-C)"
    question = (
        "What does KF-C's model give when computed exactly, the reference that KF-C, KF-CI "
        "and PF-C, its approximations, are judged against?"
    )
    style = ("#393b79", "-")
    needs_atlas = True  # its grid is the study's plan atlas

    resolution: float = 1.0
    cut: float = 9.2
    max_level: int = 4
    axes: str = "all"
    spread: str = "nodes"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.iterate != "none":
            raise ParameterError("iterate", "an exact learner is not linearised")
        if not (isinstance(self.resolution, int | float) and 0 <= self.resolution < np.inf):
            raise ParameterError("resolution", f"must be a number >= 0, got {self.resolution!r}")
        require_count("max_level", self.max_level, 0)
        if not (isinstance(self.cut, int | float) and 0 < self.cut < np.inf):
            raise ParameterError("cut", f"must be a number > 0, got {self.cut!r}")
        if self.axes not in ref.REFINED_AXES:
            choices = " or ".join(f'"{a}"' for a in ref.REFINED_AXES)
            raise ParameterError("axes", f"must be {choices}, got {self.axes!r}")
        if self.spread not in SPREADS:
            choices = " or ".join(f'"{a}"' for a in SPREADS)
            raise ParameterError("spread", f"must be {choices}, got {self.spread!r}")

    def likelihood(self) -> Likelihood:
        return dataclasses.replace(super().likelihood(), max_level=self.max_level, axes=self.axes)

    def noise_prior(self, belief: Belief, noise: KalmanNoise) -> NoisePosterior | None:
        """KF-CL's prior over N; its degrees of freedom above k + 1, where N's posterior mean
        (the predicted spread of a correction, :meth:`_noise_means`) exists."""
        prior = super().noise_prior(belief, noise)
        if prior is not None and not prior.dof > belief.dim + 1:
            raise ParameterError(
                "noise_dof",
                f"must be > k + 1 = {belief.dim + 1} for an exact learner (N's posterior mean "
                f"predicts a correction's spread), got {prior.dof:g}",
            )
        return prior

    def initial(self, belief: Belief, noise: KalmanNoise) -> Belief:
        prior = PriorEntry(belief.theta, belief.cov)  # what a refined grid weighs again
        state = ExactState(noise=self.noise_prior(belief, noise), history=(prior,))
        return Belief(theta=belief.theta, cov=belief.cov, state=state)

    def _opened(self, ctx: LearnerContext, belief: Belief):
        """(the study's atlas, the exact state, its history with the prior first): what an
        update starts from; refused in one line without an atlas."""
        atlas = ctx.book.atlas
        if atlas is None:
            raise ValueError(f"{type(self).__name__}: needs the study's plan atlas (atlas = true)")
        state = ExactState.of(belief)
        return atlas, state, state.history or (PriorEntry(belief.theta, belief.cov),)

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        atlas, state, history = self._opened(ctx, belief)
        noise_prior = state.noise  # N's prior, kept as the run started (EX-CL)
        before = state.grid
        if before is None:
            g = atlas.grid
            cells = Cells.base(g.lows, g.highs, g.counts, self.max_level)
            log_d, scatter = self._fresh(history[:1], ctx, cells.thetas())
            known = np.zeros(len(log_d), np.int64)
            before = GridPosterior(cells.thetas(), log_d, scatter, 0, cells, known)
        coefficients = before.cells.coefficients
        log_before = self._log_posterior(before, noise_prior)
        weights = ref.posterior(log_before, coefficients)
        # The correction is weighed now where the posterior is within the margin of its peak;
        # elsewhere it waits (GridPosterior.known) until the peak comes near (_settled).
        at = ref.near_peak(log_before)
        plans = atlas.plans(before.thetas[at], env)
        h = self.observation().at_plans(plans, plan.trajectory, env, ctx.features)
        z = np.asarray(phi_h, float)
        seen = np.all(np.isfinite(h), axis=1) & (weights[at] > 0)
        if not seen.any():
            raise PlanningError(
                f"{env.name}: the atlas has no plan where the posterior lives; update skipped"
            )
        noise_n = ctx.noise.observation
        # What it expected before the correction: the predictive mean and spread of h.
        w = weights[at][seen] / weights[at][seen].sum()
        expected = w @ h[seen]
        spread = (w[:, None] * (h[seen] - expected)).T @ (h[seen] - expected)
        if self.noise == "learnt":
            means = self._noise_means(before, noise_prior)[at][seen]
            noise_mean = w @ means.reshape(len(w), -1)
            noise = noise_mean.reshape(z.size, z.size)
        else:
            noise = noise_n
        history = (*history, CorrectionEntry(env, plan.trajectory, z, noise_n))
        after = self._taken_in(before, at, h, z, noise_n)
        after = self._settled(ctx, after, history, noise_prior)
        after = self._refined(ctx, after, history, noise_prior)
        mean, cov = self.moments(after, self._log_posterior(after, noise_prior))
        kept = ExactState(noise=noise_prior, grid=after, history=history)
        new = Belief(theta=mean, cov=cov, state=kept)
        return ExactStep(
            new, None, z - plan.features, symmetrize(spread + noise), expected=expected
        )

    def _taken_in(
        self, grid: GridPosterior, at: np.ndarray, h: np.ndarray, z: np.ndarray, noise
    ) -> GridPosterior:
        """``grid`` after one more correction (z, its hₜ ``h`` at the nodes ``at``), weighed
        at ``at`` only: every other node waits for it (``known``)."""
        log_d = np.array(grid.log_density)
        scatter = None if grid.scatter is None else np.array(grid.scatter)
        self._weighed_at(log_d, scatter, at, z, h, noise)
        known = grid.counts()
        known[at] = grid.count + 1
        after = GridPosterior(grid.thetas, log_d, scatter, grid.count + 1, grid.cells, known)
        return after.made_from(grid)

    def _settled(
        self,
        ctx: LearnerContext,
        grid: GridPosterior,
        history: tuple,
        noise_prior: NoisePosterior | None,
    ) -> GridPosterior:
        """``grid`` with every waiting correction weighed at each node that the peak may come
        within :data:`~corrections_sim.learning.exact.bayes.LAZY_MARGIN` of
        (:func:`~corrections_sim.learning.exact.bayes.pending_needed`), in the order they came:
        the numbers at those nodes are those of weighing every correction as it came."""
        while (need := ref.pending_needed(self._bound(grid, noise_prior), grid.pending())).any():
            log_d = np.array(grid.log_density)
            scatter = None if grid.scatter is None else np.array(grid.scatter)
            known = grid.counts()
            for j in range(int(known[need].min()), grid.count):
                seen = history[1 + j]
                at = np.flatnonzero(need & (known <= j))
                plans = ctx.book.atlas.plans(grid.thetas[at], seen.env)
                h = self.observation().at_plans(plans, seen.robot, seen.env, ctx.features)
                self._weighed_at(log_d, scatter, at, seen.phi_h, h, seen.noise)
            known[need] = grid.count
            settled = GridPosterior(grid.thetas, log_d, scatter, grid.count, grid.cells, known)
            grid = settled.made_from(grid)
        return grid

    def _refined(
        self,
        ctx: LearnerContext,
        grid: GridPosterior,
        history: tuple,
        noise_prior: NoisePosterior | None,
    ) -> GridPosterior:
        """``grid``, its cells cut finer while the posterior needs it (class docstring): at
        each new node, the prior and every correction in ``history``."""
        refine = ref.Refinement(self.resolution, self.cut, self.axes)
        while (
            cells := refine.finer(grid.cells, self._log_posterior(grid, noise_prior))
        ) is not None:
            new = cells.thetas()[len(grid.thetas) :]
            log_d, scatter = self._fresh(history, ctx, new)
            if scatter is not None:
                scatter = np.concatenate([grid.scatter, scatter])
            log_d = np.concatenate([grid.log_density, log_d])
            known = np.concatenate([grid.counts(), np.full(len(new), grid.count)])
            finer = GridPosterior(cells.thetas(), log_d, scatter, grid.count, cells, known)
            grid = finer.made_from(grid)
        return grid

    def _fresh(self, history: tuple, ctx: LearnerContext, thetas: np.ndarray):
        """(log density, scatter) at ``thetas``: the prior (``history[0]``) and every
        correction after it (the scatter None with N fixed)."""
        prior = history[0]
        log_d = ref.gaussian_log_prior(thetas, Belief(theta=prior.theta, cov=prior.cov))
        k = thetas.shape[1]
        scatter = np.zeros((len(thetas), k, k)) if self.noise == "learnt" else None
        for seen in history[1:]:
            plans = ctx.book.atlas.plans(thetas, seen.env)
            h = self.observation().at_plans(plans, seen.robot, seen.env, ctx.features)
            log_d, scatter = self._weighed(log_d, scatter, seen.phi_h, h, seen.noise)
        return log_d, scatter

    @classmethod
    def _weighed_at(cls, log_d: np.ndarray, scatter, at: np.ndarray, z, h, noise) -> None:
        """:meth:`_weighed` at the nodes ``at`` of ``log_d`` and ``scatter``, in place."""
        part = None if scatter is None else scatter[at]
        log_d[at], part = cls._weighed(log_d[at], part, z, h, noise)
        if scatter is not None:
            scatter[at] = part

    @staticmethod
    def _weighed(log_d: np.ndarray, scatter, z: np.ndarray, h: np.ndarray, noise: np.ndarray):
        """(log density, scatter) with one more correction z, predicted h, taken in."""
        if scatter is None:
            return log_d + ref.gaussian_log_likelihood(z, h, noise), None
        r = np.asarray(z, float)[None, :] - h
        bad = ~np.all(np.isfinite(r), axis=1)
        r[bad] = 0.0
        return np.where(bad, -np.inf, log_d), scatter + np.einsum("ni,nj->nij", r, r)

    def moments(self, grid: GridPosterior, log_post: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The belief's θ̂ and P from the log posterior ``log_post`` at ``grid``'s nodes:
        the trapezoid rule's mean, and the spread ``spread`` names (class docstring); P kept
        positive definite where the mass sits on one node or one line of nodes."""
        mean, cov = ref.moments(grid.thetas, ref.posterior(log_post, grid.cells.coefficients))
        if self.spread == "cells":
            _, cov = cell_moments(grid.cells, log_post, about=mean)
        return mean, floored(cov)

    def state_log_posterior(self, state: ExactState) -> np.ndarray:
        """The log posterior at every node of ``state``'s grid, up to the constants every
        correction model shares (what EX-M's evidence integrates)."""
        return self._log_posterior(state.grid, state.noise)

    def _log_posterior(self, grid: GridPosterior, prior: NoisePosterior | None) -> np.ndarray:
        """The log posterior at every node, −inf where corrections wait (their weight is 0 to
        a double's precision: :meth:`_settled`)."""
        return np.where(grid.pending(), -np.inf, self._bound(grid, prior))

    def _bound(self, grid: GridPosterior, prior: NoisePosterior | None) -> np.ndarray:
        """The log posterior where every correction is weighed, an upper bound of it where
        some wait."""
        if grid.scatter is None:
            return grid.log_density
        return grid.log_density + self._noise_log_marginal(grid, prior)

    def _noise_log_marginal(self, grid: GridPosterior, prior: NoisePosterior) -> np.ndarray:
        """log p(r₁…rₜ | θ) at every node with N integrated out under IW(ν₀, V₀), up to the
        constants that are the same at every node (:func:`iw_log_marginal`), kept with the
        grid (:meth:`GridPosterior.memo`)."""
        key = ("noise_log_marginal", (1.0,), prior.scale.tobytes(), prior.dof)
        return grid.memo(key, lambda: iw_log_marginal(grid, prior))

    def _noise_means(self, grid: GridPosterior, prior: NoisePosterior) -> np.ndarray:
        """E[N | θ, corrections] = (V₀ + Σ r rᵀ) / (ν₀ + t − k − 1) at every node."""
        k = grid.thetas.shape[1]
        return (prior.scale[None] + grid.scatter) / (prior.dof + grid.count - k - 1)


@dataclass(frozen=True)
class ExactCorrectionAwareLearntNoise(ExactCorrectionAware):
    """EX-C with N integrated out under KF-CL's prior (``noise = "learnt"``)."""

    label = "Exact posterior, KF-CL's model (EX-CL)"
    question = (
        "What does KF-CL's model give when computed exactly (N integrated out), the "
        "reference KF-CL is judged against, and how much does exactness gain over the filters?"
    )
    style = ("#5254a3", ":")

    noise: str = "learnt"


@dataclass(frozen=True, eq=False)
class ExactStep(Step):
    """An exact learner's :class:`Step` with the mean it predicted the correction's features
    at (what a posterior over several of its models mixes, :mod:`.mixture`).

    Attributes:
        expected: E[hₜ(θ)] under the posterior before the correction (k,).
    """

    expected: np.ndarray | None = None


def iw_log_marginal(grid: GridPosterior, prior: NoisePosterior, scale: float = 1.0) -> np.ndarray:
    """log p(r₁…rₜ | θ) at every node of ``grid`` with N integrated out under IW(ν₀, c V₀),
    c = ``scale``, up to the constants that are the same at every node and every c:
    (kν₀/2) log c − (ν₀ + t)/2 log|c V₀ + Σ r rᵀ| (an upper bound where some rᵢ wait: the
    determinant only grows with them)."""
    logdet = scatter_logdets(grid, prior, (scale,))[:, 0]
    return iw_log_term(grid, prior, scale, logdet)


def iw_log_term(
    grid: GridPosterior, prior: NoisePosterior, scale: float, logdet: np.ndarray
) -> np.ndarray:
    """:func:`iw_log_marginal` from the log-determinants ``logdet`` (n,) of c V₀ + Σ r rᵀ."""
    k = grid.thetas.shape[1]
    return 0.5 * k * prior.dof * np.log(scale) - 0.5 * (prior.dof + grid.count) * logdet


def scatter_logdets(
    grid: GridPosterior, prior: NoisePosterior, scales: tuple[float, ...]
) -> np.ndarray:
    """log|c V₀ + Σ r rᵀ| at every node of ``grid`` for each c of ``scales`` (n, C), kept with
    the grid. A node whose scatter is the one it had in the grid this one was made from
    (:meth:`GridPosterior.made_from`) takes that grid's value: a node's determinant depends
    on its own matrix alone, so the bits are those of computing it again, and an update
    computes it only where a correction was weighed or a node is new."""
    key = ("scatter_logdets", tuple(scales), prior.scale.tobytes())

    def make() -> np.ndarray:
        scatter = grid.scatter
        out = np.empty((len(scatter), len(scales)))
        todo = np.ones(len(scatter), bool)
        if (parent := grid.parent_memo(key)) is not None:
            old, values = parent
            same = np.all(scatter[: len(old)] == old, axis=(1, 2))
            out[: len(old)][same] = values[same]
            todo[: len(old)] = ~same
        if todo.any():
            for j, c in enumerate(scales):
                sign, logdet = np.linalg.slogdet(c * prior.scale[None, :, :] + scatter[todo])
                if np.any(sign <= 0):
                    raise ValueError("EX-CL: c V0 + sum r r^T must stay positive definite")
                out[todo, j] = logdet
        return out

    return grid.memo(key, make)
