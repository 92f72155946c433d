"""Lazy weighing (issue 65): an exact posterior on a grid weighs a correction only where the
posterior may come within ``bayes.LAZY_MARGIN`` of its peak; elsewhere the correction waits.
The posterior it gives is the eager one's — the same bits at every point it weighed, and 0
where the eager one's weight is below e^-margin of the peak — at a fraction of the plans."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from corrections_sim.belief import Belief
from corrections_sim.learning.exact import bayes
from corrections_sim.learning.exact.grid import GaussianGrid, LearntNoiseGrid, Seen


def test_pending_points_are_needed_only_within_the_margin_of_the_peak():
    bound = np.array([0.0, -50.0, -99.0, -101.0, -np.inf, -3.0])
    pending = np.array([False, True, True, True, True, False])
    assert bayes.pending_needed(bound, pending, margin=100.0).tolist() == [
        False, True, True, False, False, False,
    ]  # fmt: skip
    # A bound above the peak is needed, and with it whatever is within the margin of it.
    bound = np.array([-10.0, 5.0, -80.0, -200.0])
    pending = np.array([False, True, True, True])
    assert bayes.pending_needed(bound, pending, margin=100.0).tolist() == [
        False, True, True, False,
    ]  # fmt: skip
    assert not bayes.pending_needed(bound, np.zeros(4, bool)).any()


def _grid(kind, thetas):
    """A grid model over ``thetas`` with a linear h and N = 0.01 I (no planner: h is given)."""
    k = thetas.shape[1]
    study = SimpleNamespace(
        noise=lambda: SimpleNamespace(observation=0.01 * np.eye(k)),
        prior=lambda: Belief(theta=np.zeros(k), cov=np.eye(k)),
    )
    learner = SimpleNamespace(
        noise_prior=lambda prior, noise: SimpleNamespace(dof=k + 3.0, scale=0.02 * np.eye(k))
    )
    prior = bayes.gaussian_log_prior(thetas, study.prior())
    return kind("test", SimpleNamespace(correction=None), learner, study, thetas, prior)


@pytest.mark.parametrize(
    "kind, share",
    # N integrated out leaves heavy tails (log|V₀ + Σ r rᵀ| grows slowly): little waits there.
    [(GaussianGrid, 0.6), (LearntNoiseGrid, 1.0)],
)
def test_lazy_weighing_gives_the_eager_posterior_with_fewer_observations(kind, share):
    rng = np.random.default_rng(65)
    axis = np.linspace(-5.0, 5.0, 41)
    thetas = np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1).reshape(-1, 2)
    maps = [rng.normal(size=(2, 2)) for _ in range(8)]
    truth = np.array([1.0, -1.0])
    zs = [a @ truth + 0.1 * rng.normal(size=2) for a in maps]
    eager, lazy = _grid(kind, thetas), _grid(kind, thetas)
    observed = 0

    def observe(j, points):
        nonlocal observed
        observed += len(points)
        return thetas[points] @ maps[j].T

    for j, z in enumerate(zs):
        seen = Seen(z, None, None, thetas @ maps[j].T, None, {}, None)
        want = eager.correct(seen)
        at = bayes.near_peak(lazy.posterior())
        observed += len(at)
        lazy.correct(Seen(z, None, None, thetas[at] @ maps[j].T, None, {}, None), at)
        got = lazy.settle(observe)
        weighed = np.isfinite(got)
        assert np.array_equal(got[weighed], want[weighed])  # the same bits where weighed
        assert np.all(want[~weighed] < want.max() - bayes.LAZY_MARGIN)
        # The moments: what a double holds of them does not see points e^-100 below the peak.
        for a, b in zip(
            bayes.moments(thetas, bayes.posterior(got)),
            bayes.moments(thetas, bayes.posterior(want)),
            strict=True,
        ):
            np.testing.assert_array_equal(a, b)
    # Eager: every point, every correction; lazy: fewer (about half with N known).
    assert observed < share * len(thetas) * len(zs)
    assert lazy.pending().any()
