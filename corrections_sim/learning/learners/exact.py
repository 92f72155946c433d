"""EX-C and EX-CL: the exact posterior over θ under KF-C's and KF-CL's models, on the nodes
of the study's plan atlas (:mod:`corrections_sim.planning.atlas`).

A correction in E is weighed at every node θ of the atlas's grid by hₜ(θ) = Φ(C(ξᵗ, ξ*(θ, E))),
ξ*(θ, E) the atlas's plan there: no solve, one feature count of every node's corrected plan.
The posterior is the grid's (:mod:`corrections_sim.learning.exact_posterior`, the functions
the exact reference of ``run reference`` uses), so on the atlas's grid it *is* that reference;
its moments are the belief every consumer reads. θ is static (no process noise M, as in the
reference); the grid truncates the prior to the atlas's box (θ̂⁰ ± ``width`` sd).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import Belief, GridPosterior, floored, symmetrize
from corrections_sim.components import ParameterError
from corrections_sim.learning import exact_posterior as ref
from corrections_sim.learning.base import LearnerContext, Step
from corrections_sim.learning.learners.kalman import CorrectionAwareKalman
from corrections_sim.planning.planner import Plan, PlanningError
from corrections_sim.scene.environments import Environment


@dataclass(frozen=True)
class ExactCorrectionAware(CorrectionAwareKalman):
    """The posterior of KF-C's model, exactly, on the study's atlas grid (module docstring):
    p(θ | z₁…zₜ) ∝ N(θ; θ̂⁰, P⁰) Πᵢ N(zᵢ; hᵢ(θ), N), N the study's (``noise = "fixed"``) or,
    with ``noise = "learnt"``, integrated out under KF-CL's prior IW(ν₀, V₀):
    Πᵢ → |V₀ + Σᵢ rᵢ rᵢᵀ|^(−(ν₀ + t)/2), rᵢ = zᵢ − hᵢ(θ)."""

    label = "Exact posterior, KF-C's model (EX-C)"
    style = ("#393b79", "-")
    needs_atlas = True  # its grid is the study's plan atlas

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.iterate != "none":
            raise ParameterError("iterate", "an exact learner is not linearised")

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        atlas = ctx.book.atlas
        if atlas is None:
            raise ValueError(f"{type(self).__name__}: needs the study's plan atlas (atlas = true)")
        before = belief.grid or self._prior_grid(belief, atlas.grid.thetas())
        plans = atlas.environment(env).trajectories
        h = self.observation().at_plans(plans, plan.trajectory, env, ctx.features)
        z = np.asarray(phi_h, float)
        weights = ref.posterior(self._log_posterior(before, belief))
        seen = np.all(np.isfinite(h), axis=1) & (weights > 0)
        if not seen.any():
            raise PlanningError(
                f"{env.name}: the atlas has no plan where the posterior lives; update skipped"
            )
        # What it expected before the correction: the predictive mean and spread of h.
        w = weights[seen] / weights[seen].sum()
        expected = w @ h[seen]
        spread = (w[:, None] * (h[seen] - expected)).T @ (h[seen] - expected)
        if self.noise == "learnt":
            r = z[None, :] - h
            bad = ~np.all(np.isfinite(r), axis=1)
            r[bad] = 0.0
            scatter = before.scatter + np.einsum("ni,nj->nij", r, r)
            log_d = np.where(bad, -np.inf, before.log_density)
            after = GridPosterior(before.thetas, log_d, scatter, before.count + 1)
            noise_mean = w @ self._noise_means(before, belief)[seen].reshape(len(w), -1)
            noise = noise_mean.reshape(z.size, z.size)
        else:
            noise = ctx.noise.observation
            log_l = ref.gaussian_log_likelihood(z, h, noise)
            after = GridPosterior(before.thetas, before.log_density + log_l, None, before.count + 1)
        mean, cov = _moments(after.thetas, ref.posterior(self._log_posterior(after, belief)))
        new = Belief(
            theta=mean,
            cov=cov,
            noise=belief.noise,
            history=belief.history,
            grid=after,
        )
        return Step(new, None, z - plan.features, symmetrize(spread + noise))

    def _prior_grid(self, belief: Belief, thetas: np.ndarray) -> GridPosterior:
        log_prior = ref.gaussian_log_prior(thetas, Belief(theta=belief.theta, cov=belief.cov))
        k = thetas.shape[1]
        scatter = np.zeros((len(thetas), k, k)) if self.noise == "learnt" else None
        return GridPosterior(thetas, log_prior, scatter, 0)

    @staticmethod
    def _log_posterior(grid: GridPosterior, belief: Belief) -> np.ndarray:
        if grid.scatter is None:
            return grid.log_density
        prior = belief.noise  # the IW prior, kept as the run started
        spread = prior.scale[None, :, :] + grid.scatter
        sign, logdet = np.linalg.slogdet(spread)
        if np.any(sign <= 0):
            raise ValueError("EX-CL: V0 + sum r r^T must stay positive definite")
        return grid.log_density - 0.5 * (prior.dof + grid.count) * logdet

    @staticmethod
    def _noise_means(grid: GridPosterior, belief: Belief) -> np.ndarray:
        """E[N | θ, corrections] = (V₀ + Σ r rᵀ) / (ν₀ + t − k − 1) at every node."""
        prior = belief.noise
        k = grid.thetas.shape[1]
        return (prior.scale[None] + grid.scatter) / (prior.dof + grid.count - k - 1)


@dataclass(frozen=True)
class ExactCorrectionAwareLearntNoise(ExactCorrectionAware):
    """EX-C with N integrated out under KF-CL's prior (``noise = "learnt"``)."""

    label = "Exact posterior, KF-CL's model (EX-CL)"
    style = ("#5254a3", ":")

    noise: str = "learnt"


def _moments(thetas: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The grid posterior's mean and covariance (the reference's, :func:`ref.moments`), the
    covariance kept positive definite where the mass sits on one node or one line of nodes."""
    mean, cov = ref.moments(thetas, weights)
    return mean, floored(cov)
