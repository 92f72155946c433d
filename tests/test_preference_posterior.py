"""The Boltzmann-correction posterior against analytic and numerically integrated answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.stats import norm

from corrections_sim.learning import (
    Belief,
    BoltzmannCorrection,
    posterior_moment_match,
    posterior_update,
    tilted_moments,
)


def _grid_posterior(belief: Belief, delta: np.ndarray, model: BoltzmannCorrection):
    """Mean and covariance of N(θ̂, P) ℓ(θ·Δ) by brute force on a 2-D grid (k = 2)."""
    sd = np.sqrt(np.diag(belief.cov))
    axes = [np.linspace(m - 9 * s, m + 9 * s, 1201) for m, s in zip(belief.theta, sd, strict=True)]
    gx, gy = np.meshgrid(*axes, indexing="ij")
    pts = np.c_[gx.ravel(), gy.ravel()]
    dev = pts - belief.theta
    log_w = -0.5 * np.sum(dev @ np.linalg.inv(belief.cov) * dev, axis=1)
    log_w += model.log_likelihood(pts @ delta)
    w = np.exp(log_w - log_w.max())
    w /= w.sum()
    mean = w @ pts
    centred = pts - mean
    return mean, (w[:, None] * centred).T @ centred


@pytest.mark.parametrize(
    "model",
    [
        BoltzmannCorrection.fixed(3.0),
        BoltzmannCorrection(),
        BoltzmannCorrection(beta_min=1.0, beta_max=20.0, n_beta=4, lapse=0.2),
    ],
)
def test_update_equals_numerical_integration_of_the_posterior(rng, random_belief, model):
    for _ in range(5):
        belief = random_belief(rng, 2)
        phi_robot = rng.normal(size=2)
        phi_human = phi_robot + rng.normal(scale=0.7, size=2)
        step = posterior_update(belief, None, phi_robot, phi_human, model)
        mean, cov = _grid_posterior(belief, phi_human - phi_robot, model)
        np.testing.assert_allclose(step.belief.theta, mean, atol=1e-6)
        np.testing.assert_allclose(step.belief.cov, cov, atol=1e-6)


def test_gaussian_likelihood_gives_the_linear_kalman_filter(rng, random_belief):
    # ℓ(s) = N(y; s, r): a scalar observation y = dᵀθ + n, n ~ N(0, r), for which moment
    # matching is exact and must equal the Kalman filter with H = dᵀ.
    for k in (1, 2, 3):
        belief = random_belief(rng, k)
        d = rng.normal(size=k)
        y, r = float(rng.normal(scale=3.0)), float(rng.uniform(0.01, 2.0))
        step = posterior_moment_match(
            belief, d, lambda s, y=y, r=r: -0.5 * (s - y) ** 2 / r, center=y
        )
        p, h = belief.cov, d[None, :]
        gain = p @ h.T / (h @ p @ h.T + r)
        np.testing.assert_allclose(
            step.belief.theta, belief.theta + gain[:, 0] * (y - d @ belief.theta), atol=1e-9
        )
        np.testing.assert_allclose(step.belief.cov, p - gain @ h @ p, atol=1e-9)
        assert step.log_evidence == pytest.approx(
            -0.5 * (y - d @ belief.theta) ** 2 / (d @ p @ d + r)
            - 0.5 * np.log(2 * np.pi * (d @ p @ d + r))
            + 0.5 * np.log(2 * np.pi * r),
            abs=1e-9,
        )


@pytest.mark.parametrize(
    ("mean", "var", "beta"), [(-8.0, 1.0, 50.0), (0.3, 0.02, 30.0), (5.0, 4.0, 0.3)]
)
def test_tilted_moments_equal_adaptive_quadrature(mean, var, beta):
    # Far in the tail (a thin sliver above 0), a narrow prior, a flat likelihood.
    def log_f(s):
        return -np.logaddexp(0.0, -beta * s)

    log_z, mu, tau2 = tilted_moments(mean, var, log_f)
    sd = np.sqrt(var)
    lo, hi = min(mean, 0.0) - 20 * sd, max(mean, 0.0) + 20 * sd
    scale = np.exp(log_f(np.array([max(mean, 0.0)]))[0])

    def moment(p):
        def f(s):
            return s**p * np.exp(log_f(np.array([s]))[0]) * norm.pdf(s, mean, sd) / scale

        return quad(f, lo, hi, points=[0.0, mean], limit=500, epsabs=0, epsrel=1e-12)[0]

    z, m1, m2 = moment(0), moment(1), moment(2)
    assert log_z == pytest.approx(np.log(z * scale), rel=1e-8, abs=1e-10)
    assert mu == pytest.approx(m1 / z, rel=1e-7, abs=1e-10)
    assert tau2 == pytest.approx(m2 / z - (m1 / z) ** 2, rel=1e-6)


def test_gain_reproduces_the_mean_update_and_innovation_is_delta(rng, random_belief):
    belief = random_belief(rng, 3)
    phi_robot, phi_human = rng.normal(size=3), rng.normal(size=3)
    step = posterior_update(belief, None, phi_robot, phi_human)
    np.testing.assert_allclose(step.innovation, phi_human - phi_robot)
    np.testing.assert_allclose(
        step.belief.theta, belief.theta + step.gain @ (phi_human - phi_robot), atol=1e-12
    )
    assert step.innovation_cov is None
    assert step.log_evidence <= 0.0


def test_a_correction_moves_the_estimate_toward_it_and_shrinks_the_variance_along_it(rng):
    belief = Belief(theta=np.zeros(2), cov=np.eye(2))
    delta = np.array([0.6, -0.2])
    for _ in range(6):
        step = posterior_update(belief, None, np.zeros(2), delta, BoltzmannCorrection.fixed(3.0))
        assert step.belief.theta @ delta > belief.theta @ delta
        assert delta @ step.belief.cov @ delta < delta @ belief.cov @ delta
        belief = step.belief


def test_no_change_is_no_information_beyond_the_process_noise():
    belief = Belief(theta=np.array([0.5, -1.0]), cov=np.eye(2))
    model = BoltzmannCorrection(process_noise=0.01)
    step = posterior_update(belief, None, np.ones(2), np.ones(2), model)
    np.testing.assert_array_equal(step.belief.theta, belief.theta)
    np.testing.assert_allclose(step.belief.cov, 1.01 * np.eye(2))
    np.testing.assert_array_equal(step.gain, np.zeros((2, 2)))


def test_log_likelihood_is_the_lapsed_mixture_of_logistics():
    s = np.linspace(-3.0, 3.0, 13)
    sigmoid = lambda x: 1.0 / (1.0 + np.exp(-x))  # noqa: E731
    model = BoltzmannCorrection(beta_min=0.5, beta_max=8.0, n_beta=5, lapse=0.1)
    expected = 0.05 + 0.9 * np.mean([sigmoid(b * s) for b in (0.5, 1.0, 2.0, 4.0, 8.0)], axis=0)
    np.testing.assert_allclose(np.exp(model.log_likelihood(s)), expected, rtol=1e-12)
    np.testing.assert_allclose(
        BoltzmannCorrection.fixed(2.0).log_likelihood(np.array([-800.0, 0.0])),
        [-1600.0, np.log(0.5)],
    )


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"beta_min": 0.0}, "beta_min"),
        ({"beta_min": float("nan")}, "beta_min"),
        ({"beta_max": 0.1}, "beta_max"),
        ({"n_beta": 0}, "n_beta"),
        ({"n_beta": 2.5}, "n_beta"),
        ({"beta_min": 2.0, "beta_max": 2.0, "n_beta": 3}, "n_beta"),
        ({"lapse": 1.0}, "lapse"),
        ({"lapse": -0.1}, "lapse"),
        ({"process_noise": -1e-3}, "process_noise"),
    ],
)
def test_bad_parameters_are_refused_naming_the_field(kwargs, field):
    with pytest.raises(ValueError, match=f"BoltzmannCorrection.{field}"):
        BoltzmannCorrection(**kwargs)


@pytest.mark.parametrize(
    ("phi_robot", "phi_human", "field"),
    [
        (np.zeros(3), np.ones(2), "phi_robot"),
        (np.zeros(2), np.array([1.0, np.nan]), "phi_human"),
    ],
)
def test_bad_features_are_refused_naming_the_field(phi_robot, phi_human, field):
    belief = Belief(theta=np.zeros(2), cov=np.eye(2))
    with pytest.raises(ValueError, match=field):
        posterior_update(belief, None, phi_robot, phi_human)
