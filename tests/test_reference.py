"""The exact grid reference against closed forms: on a linear-Gaussian problem it is the
Kalman filter's posterior (moments and KL ≈ 0), halving the spacing moves nothing, the
learnt-noise likelihood tends to the fixed-noise one as the prior's weight grows."""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.belief import Belief, KalmanNoise
from corrections_sim.learning.exact import bayes as ref
from corrections_sim.learning.kalman.filter import ukf_update

PRIOR = Belief(theta=np.zeros(2), cov=np.eye(2))
N = np.array([[0.3, 0.05], [0.05, 0.2]])


def _linear_problem(seed: int, t: int = 4):
    rng = np.random.default_rng(seed)
    theta_star = np.array([1.0, -1.0])
    mats = [rng.normal(size=(2, 2)) for _ in range(t)]
    zs = np.array([a @ theta_star + rng.multivariate_normal(np.zeros(2), N) for a in mats])
    return mats, zs


def _kalman(mats, zs) -> Belief:
    belief, noise = PRIOR, KalmanNoise(process=np.zeros((2, 2)), observation=N)
    for a, z in zip(mats, zs, strict=True):
        belief = ukf_update(belief, lambda th, a=a: np.atleast_2d(th) @ a.T, z, noise).belief
    return belief


def _reference(grid: ref.Grid, mats, zs):
    thetas = grid.thetas()
    log_p = ref.gaussian_log_prior(thetas, PRIOR)
    for a, z in zip(mats, zs, strict=True):
        log_p = log_p + ref.gaussian_log_likelihood(z, thetas @ a.T, N)
    return thetas, ref.posterior(log_p)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_on_a_linear_gaussian_problem_the_grid_posterior_is_the_kalman_filters(seed):
    mats, zs = _linear_problem(seed)
    kf = _kalman(mats, zs)
    grid = ref.Grid(
        tuple(kf.theta - 6 * np.sqrt(np.diag(kf.cov))),
        tuple(kf.theta + 6 * np.sqrt(np.diag(kf.cov))),
        121,
    )
    thetas, w = _reference(grid, mats, zs)
    mean, cov = ref.moments(thetas, w)
    np.testing.assert_allclose(mean, kf.theta, atol=1e-4)
    np.testing.assert_allclose(cov, kf.cov, rtol=1e-3, atol=1e-6)
    assert abs(ref.kl_to_gaussian(grid, thetas, w, kf)) < 1e-3
    # A Gaussian that is off by a shift has a KL of about half its squared Mahalanobis shift.
    shifted = Belief(theta=kf.theta + np.sqrt(np.diag(kf.cov)) * [1.0, 0.0], cov=kf.cov)
    expected = (
        0.5
        * (np.sqrt(np.diag(kf.cov)) * [1.0, 0.0])
        @ np.linalg.solve(kf.cov, np.sqrt(np.diag(kf.cov)) * [1.0, 0.0])
    )
    assert ref.kl_to_gaussian(grid, thetas, w, shifted) == pytest.approx(expected, rel=1e-2)


def test_halving_the_spacing_moves_mean_and_covariance_by_less_than_one_percent():
    mats, zs = _linear_problem(3)
    grid = ref.Grid((-3.0, -3.0), (3.0, 3.0), 61)
    a = ref.moments(*_reference(grid, mats, zs))
    b = ref.moments(*_reference(grid.halved(), mats, zs))
    scale = np.sqrt(np.diag(b[1]))
    assert np.all(np.abs(a[0] - b[0]) < 0.01 * scale)
    np.testing.assert_allclose(a[1], b[1], rtol=0.01, atol=1e-4)


def test_integrating_the_noise_out_tends_to_the_known_noise_as_the_prior_hardens():
    mats, zs = _linear_problem(4)
    grid = ref.Grid((-3.0, -3.0), (3.0, 3.0), 61)
    thetas = grid.thetas()
    hs = np.array([thetas @ a.T for a in mats])
    _, fixed = _reference(grid, mats, zs)
    log_prior = ref.gaussian_log_prior(thetas, PRIOR)
    hard = ref.posterior(log_prior + ref.learnt_noise_log_likelihood(zs, hs, 1e7, 1e7 * N))
    np.testing.assert_allclose(hard, fixed, atol=1e-6)
    soft = ref.posterior(log_prior + ref.learnt_noise_log_likelihood(zs, hs, 4.0, 4.0 * N))
    assert np.abs(soft - fixed).sum() > 1e-3  # with few degrees of freedom it differs


def test_the_boltzmann_likelihood_is_a_half_where_theta_is_indifferent():
    thetas = np.array([[1.0, 1.0], [2.0, -1.0], [-2.0, 1.0]])
    delta = np.array([1.0, -1.0])  # θ·Δ = 0, 3, −3
    log_l = ref.boltzmann_log_likelihood(thetas, delta, np.array([0.3, 3.0, 30.0]), lapse=0.1)
    assert log_l[0] == pytest.approx(np.log(0.5))
    assert log_l[1] > np.log(0.5) > log_l[2]
    assert log_l[2] > np.log(0.05)  # the lapse keeps every correction possible


def test_a_bad_grid_is_refused():
    with pytest.raises(ValueError, match="points"):
        ref.Grid((0.0, 0.0), (1.0, 1.0), 2)
    with pytest.raises(ValueError, match="exceed"):
        ref.Grid((0.0, 1.0), (1.0, 1.0), 5)


def test_the_gaussian_part_of_the_kl_is_the_grids_for_a_gaussian_reference():
    grid = ref.Grid((-4.0, -4.0), (4.0, 4.0), 161)
    thetas = grid.thetas()
    truth = Belief(theta=np.array([0.3, -0.2]), cov=np.array([[0.5, 0.1], [0.1, 0.3]]))
    weights = ref.posterior(ref.gaussian_log_prior(thetas, truth))
    mean, cov = ref.moments(thetas, weights)
    learner = Belief(theta=np.array([0.0, 0.1]), cov=np.array([[0.8, 0.0], [0.0, 0.6]]))
    assert ref.gaussian_kl(mean, cov, learner) == pytest.approx(
        ref.kl_to_gaussian(grid, thetas, weights, learner), abs=2e-3
    )
    assert ref.gaussian_kl(truth.theta, truth.cov, truth) == pytest.approx(0.0, abs=1e-12)
