"""What one correction tells about θ at every point of a grid, one model a registered name.

A learner names the model it assumes (:meth:`Learner.likelihood
<corrections_sim.learning.base.Learner.likelihood>`, a
:class:`~corrections_sim.learning.base.Likelihood` whose ``kind`` is a name here); the exact
reference (:mod:`corrections_sim.figures.reference`) computes that learner's posterior on a
grid under the model registered by that name (:data:`GRID_MODELS`), each family registering
its own: ``gaussian`` and ``gaussian-learnt-noise`` here (the Kalman, particle and exact
families'), ``boltzmann`` in :mod:`corrections_sim.learning.boltzmann.grid`, and the
relevance models in :mod:`corrections_sim.learning.relevance.grid`.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from corrections_sim.belief import Belief, KalmanNoise
from corrections_sim.learning.exact import bayes
from corrections_sim.registry import Registry


@dataclass(frozen=True, eq=False)
class Seen:
    """One correction as a grid model reads it.

    Attributes:
        z: Φ_h, the correction's features (k,).
        robot: the robot's plan ξᵗ (a :class:`~corrections_sim.planning.planner.Plan`).
        plans: ξ*(θ, E) at the grid's points (n, T, 7), or None for a model that reads none.
        h: hₜ(θ) at the grid's points (n, k), or None likewise.
        corrected: the person's ξ_h (T, 7).
        row: the learner's record after this correction (its β̂, its ρ).
        before: the learner's belief before it.
    """

    z: np.ndarray
    robot: Any
    plans: np.ndarray | None
    h: np.ndarray | None
    corrected: np.ndarray
    row: dict
    before: Belief


class GridModel(abc.ABC):
    """A correction model on a grid: the log density of θ (prior times every correction's
    likelihood, unnormalised) at the grid's points, one correction at a time.

    Class attributes:
        plain: Gaussian with N fixed and nothing judged: a particle reference can carry it.
        filtered: a Kalman filter step with :meth:`filter_noise` is the learner's own, so the
            reference's ``--one-step`` and ``--restart`` can start one from its moments.
        refinable: its grid may be cut finer where the posterior lives (:meth:`refined`).
        needs_plans: it reads hₜ(θ) (ξ*(θ, E) at every point); else only Φ_h and ξᵗ.
    """

    plain: ClassVar[bool] = False
    filtered: ClassVar[bool] = False
    refinable: ClassVar[bool] = False
    needs_plans: ClassVar[bool] = True

    def __init__(
        self, name: str, likelihood, learner, study, thetas: np.ndarray, log_prior: np.ndarray
    ):
        """The model of ``likelihood`` (its correction model C) for ``learner`` (its own
        parameters) in ``study`` (N), from the log prior ``log_prior`` at ``thetas``.

        Raises:
            ValueError: one line naming the learner ``name``, for parameters the model cannot
                carry.
        """
        self.learner, self.study, self.correction = learner, study, likelihood.correction
        self.noise = study.noise().observation
        self.thetas = thetas
        self.log_p = log_prior  # the prior times every correction's likelihood taken in
        self.judged: dict = {}  # what the last correction's columns add (the exact β̂)

    @abc.abstractmethod
    def correct(self, seen: Seen) -> np.ndarray:
        """The log posterior (unnormalised) at the grid's points after ``seen``."""

    def refined(
        self, new_thetas: np.ndarray, new_prior: np.ndarray, new_hs: list[np.ndarray]
    ) -> np.ndarray:
        """The log posterior after the grid gained the points ``new_thetas`` (after its own;
        their log prior ``new_prior``, and hₜ there of every correction so far, ``new_hs``,
        in order)."""
        if not self.refinable:
            raise TypeError(f"{type(self).__name__}: its grid is not refined")
        self.thetas = np.concatenate([self.thetas, new_thetas])
        return self._refined(new_prior, new_hs)

    def _refined(self, new_prior: np.ndarray, new_hs: list[np.ndarray]) -> np.ndarray:
        raise NotImplementedError

    def density(self) -> np.ndarray:
        """The log density the filter-step tools start from (prior times likelihoods)."""
        return self.log_p

    # A refinable model weighs a correction lazily (``correct``'s ``at``): at the other points
    # it waits (``known``) until the posterior's peak may come within
    # bayes.LAZY_MARGIN of them (:meth:`settle`), as an exact learner's does.

    def pending(self) -> np.ndarray:
        """The points (n,) where some correction is not weighed yet."""
        return self.known < len(self.zs)

    def bound(self) -> np.ndarray:
        """The log posterior, an upper bound of it where corrections wait."""
        raise NotImplementedError

    def posterior(self) -> np.ndarray:
        """The log posterior at every point, −inf where corrections wait (their weight is 0 to
        a double's precision)."""
        return np.where(self.pending(), -np.inf, self.bound())

    def settle(self, observe) -> np.ndarray:
        """Weigh the waiting corrections, in the order they came, at every point the peak may
        come within the margin of (:func:`~corrections_sim.learning.exact.bayes.pending_needed`);
        ``observe(j, points)`` is hₜ of correction j there. Returns :meth:`posterior`."""
        while (need := bayes.pending_needed(self.bound(), self.pending())).any():
            for j in range(int(self.known[need].min()), len(self.zs)):
                at = np.flatnonzero(need & (self.known <= j))
                self._weigh(j, at, observe(j, at))
            self.known[need] = len(self.zs)
        return self.posterior()

    def _weigh(self, j: int, at: np.ndarray, h: np.ndarray) -> None:
        raise NotImplementedError

    def filter_noise(self, noise: KalmanNoise, row: dict) -> KalmanNoise:
        """The noise of the learner's filter step for the correction of ``row`` (a
        :attr:`filtered` model's): the study's."""
        return noise


GRID_MODELS: Registry[type[GridModel]] = Registry("likelihood", base=GridModel)
"""Every grid model by the name a learner's :class:`Likelihood` gives."""


@GRID_MODELS.decorator("gaussian")
class GaussianGrid(GridModel):
    """Φ_h ~ N(hₜ(θ), N), N known: KF/AL's h = Φ(ξ*), KF-C's Φ(C(ξᵗ, ξ*)), PF-C's, EX-C's."""

    plain = True
    filtered = True
    refinable = True

    def __init__(self, name, likelihood, learner, study, thetas, log_prior):
        super().__init__(name, likelihood, learner, study, thetas, log_prior)
        self.zs: list[np.ndarray] = []
        self.known = np.zeros(len(thetas), np.int64)

    def correct(self, seen: Seen, at: np.ndarray | None = None) -> np.ndarray:
        """With ``at`` (point indices; ``seen.h`` there only), weighed there alone: call
        :meth:`settle` before reading the posterior."""
        self.zs.append(seen.z)
        at = np.arange(len(self.log_p)) if at is None else at
        self.log_p = np.array(self.log_p)  # the prior may be shared: weighed in a copy
        self._weigh(len(self.zs) - 1, at, seen.h)
        self.known[at] = len(self.zs)
        return self.posterior()

    def bound(self) -> np.ndarray:
        return self.log_p

    def density(self) -> np.ndarray:
        return self.posterior()

    def _weigh(self, j, at, h):
        self.log_p[at] = self.log_p[at] + bayes.gaussian_log_likelihood(self.zs[j], h, self.noise)

    def _refined(self, new_prior, new_hs):
        for z, h in zip(self.zs, new_hs, strict=True):
            new_prior = new_prior + bayes.gaussian_log_likelihood(z, h, self.noise)
        self.log_p = np.concatenate([self.log_p, new_prior])
        self.known = np.concatenate([self.known, np.full(len(new_prior), len(self.zs))])
        return self.posterior()


@GRID_MODELS.decorator("gaussian-learnt-noise")
class LearntNoiseGrid(GridModel):
    """Φ_h ~ N(hₜ(θ), N) with N integrated out under the learner's inverse-Wishart prior
    (KF-CL, EX-CL): every correction so far enters together."""

    refinable = True

    def __init__(self, name, likelihood, learner, study, thetas, log_prior):
        super().__init__(name, likelihood, learner, study, thetas, log_prior)
        self.prior_noise = learner.noise_prior(study.prior(), study.noise())
        self.zs: list[np.ndarray] = []
        self.hs: list[np.ndarray] = []  # NaN where a correction waits
        self.known = np.zeros(len(thetas), np.int64)

    def bound(self) -> np.ndarray:
        noise = self.prior_noise
        zs, hs = np.array(self.zs), np.array(self.hs)
        if not len(zs):
            return self.log_p
        # A waiting correction's residual taken as 0: weighing it can only raise |V₀ + Σ r rᵀ|.
        waiting = np.arange(len(zs))[:, None] >= self.known[None, :]
        hs = np.where(waiting[:, :, None], zs[:, None, :], hs)
        return self.log_p + bayes.learnt_noise_log_likelihood(zs, hs, noise.dof, noise.scale)

    def correct(self, seen: Seen, at: np.ndarray | None = None) -> np.ndarray:
        """With ``at`` (point indices; ``seen.h`` there only), weighed there alone: call
        :meth:`settle` before reading the posterior."""
        self.zs.append(seen.z)
        at = np.arange(len(self.log_p)) if at is None else at
        self.hs.append(np.full((len(self.log_p), len(seen.z)), np.nan))
        self._weigh(len(self.zs) - 1, at, seen.h)
        self.known[at] = len(self.zs)
        return self.posterior()

    def _weigh(self, j, at, h):
        self.hs[j][at] = h

    def _refined(self, new_prior, new_hs):
        self.hs = [np.concatenate(pair) for pair in zip(self.hs, new_hs, strict=True)]
        self.log_p = np.concatenate([self.log_p, new_prior])
        self.known = np.concatenate([self.known, np.full(len(new_prior), len(self.zs))])
        return self.posterior()
