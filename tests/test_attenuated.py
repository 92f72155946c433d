"""The attenuated-correction UKF against the paper's UKF, the linear KF and a grid posterior."""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.learning import (
    Attenuation,
    Belief,
    KalmanNoise,
    attenuated_update,
    ukf_update,
)


def _linear(h: np.ndarray, c: np.ndarray):
    return lambda thetas: thetas @ h.T + c


def test_a_single_full_fraction_is_the_papers_ukf(rng, random_belief):
    # h nonlinear; a = 1 only: the update must be ukf_update with reference = Φ(ξᵗ).
    noise = KalmanNoise.isotropic(2, 1e-4, 0.25)
    a = rng.normal(size=(2, 2))

    def observe(thetas):
        return np.tanh(thetas @ a.T) + 0.1 * thetas**2

    for _ in range(10):
        belief = random_belief(rng, 2)
        phi_robot = observe(belief.theta[None])[0]
        phi_human = phi_robot + rng.normal(size=2)
        mine = attenuated_update(
            belief, observe, phi_robot, phi_human, noise, Attenuation(1.0, 1.0, 1)
        )
        paper = ukf_update(belief, observe, phi_human, noise, reference=phi_robot)
        np.testing.assert_allclose(mine.belief.theta, paper.belief.theta, atol=1e-12)
        np.testing.assert_allclose(mine.belief.cov, paper.belief.cov, atol=1e-12)
        np.testing.assert_allclose(mine.gain, paper.gain, atol=1e-12)


def test_a_known_fraction_on_a_linear_problem_is_the_linear_kalman_filter(rng, random_belief):
    # Φ_h − Φ_r = a (Hθ + c − Φ_r) + n: a linear observation with matrix aH.
    k, frac = 3, 0.3
    h, c = rng.normal(size=(k, k)), rng.normal(size=k)
    noise = KalmanNoise(0.01 * np.eye(k), np.diag([0.2, 0.3, 0.4]))
    belief = random_belief(rng, k)
    phi_robot, phi_human = rng.normal(size=k), rng.normal(size=k)
    step = attenuated_update(
        belief, _linear(h, c), phi_robot, phi_human, noise, Attenuation(frac, frac, 1)
    )
    p = belief.cov + noise.process
    ha = frac * h
    s = ha @ p @ ha.T + noise.observation
    gain = p @ ha.T @ np.linalg.inv(s)
    residual = (phi_human - phi_robot) - frac * (h @ belief.theta + c - phi_robot)
    np.testing.assert_allclose(step.belief.theta, belief.theta + gain @ residual, atol=1e-10)
    np.testing.assert_allclose(step.belief.cov, p - gain @ s @ gain.T, atol=1e-10)
    np.testing.assert_allclose(step.innovation_cov, s, atol=1e-10)


def test_the_collapsed_posterior_has_the_moments_of_the_exact_posterior(rng):
    # Linear h, k = 2: p(θ | Φ_h) ∝ N(θ; θ̂, P⁻) Σ_j N(Φ_h − Φ_r; a_j (Hθ + c − Φ_r), N),
    # integrated on a grid; the Gaussian-sum filter's collapse must have its mean and cov.
    prior_a = Attenuation(0.1, 1.0, 5)
    noise = KalmanNoise(1e-3 * np.eye(2), 0.05 * np.eye(2))
    h, c = np.array([[1.0, 0.4], [-0.3, 0.8]]), np.array([0.2, -0.1])
    belief = Belief(theta=np.array([0.3, -0.2]), cov=np.array([[0.5, 0.1], [0.1, 0.3]]))
    phi_robot = np.array([0.4, 0.1])
    phi_human = phi_robot + np.array([0.25, -0.15])
    step = attenuated_update(belief, _linear(h, c), phi_robot, phi_human, noise, prior_a)

    p = belief.cov + noise.process
    axes = [
        np.linspace(m - 8 * s, m + 8 * s, 801)
        for m, s in zip(belief.theta, np.sqrt(np.diag(p)), strict=True)
    ]
    gx, gy = np.meshgrid(*axes, indexing="ij")
    pts = np.c_[gx.ravel(), gy.ravel()]
    dev = pts - belief.theta
    log_prior = -0.5 * np.sum(dev @ np.linalg.inv(p) * dev, axis=1)
    n_inv = np.linalg.inv(noise.observation)
    change = pts @ h.T + c - phi_robot
    lik = np.zeros(len(pts))
    for a in prior_a.values:
        r = (phi_human - phi_robot) - a * change
        lik += np.exp(-0.5 * np.sum(r @ n_inv * r, axis=1))
    w = np.exp(log_prior) * lik
    w /= w.sum()
    mean = w @ pts
    cov = (w[:, None] * (pts - mean)).T @ (pts - mean)
    np.testing.assert_allclose(step.belief.theta, mean, atol=1e-6)
    np.testing.assert_allclose(step.belief.cov, cov, atol=1e-6)
    assert step.weights.shape == (5,) and step.weights.sum() == pytest.approx(1.0)


def test_a_small_change_keeps_more_uncertainty_than_the_papers_ukf(rng):
    # The mechanism of issue 9: a correction that shows a fifth of the intended change.
    h, c = np.eye(2), np.zeros(2)
    noise = KalmanNoise.isotropic(2, 1e-4, 0.25)
    theta_star = np.array([1.0, -1.0])
    mine = paper = Belief(theta=np.zeros(2), cov=np.eye(2))
    for _ in range(10):
        for which in ("mine", "paper"):
            b = mine if which == "mine" else paper
            phi_robot = b.theta
            phi_human = phi_robot + 0.2 * (theta_star - b.theta)
            if which == "mine":
                mine = attenuated_update(b, _linear(h, c), phi_robot, phi_human, noise).belief
            else:
                paper = ukf_update(b, _linear(h, c), phi_human, noise, reference=phi_robot).belief

    def nees(b):
        e = b.theta - theta_star
        return e @ np.linalg.solve(b.cov, e)

    assert nees(mine) < 2 * 2 < nees(paper)
    assert np.abs(mine.theta - theta_star).sum() < np.abs(paper.theta - theta_star).sum()


def test_observe_is_called_once_with_the_sigma_points():
    calls = []

    def observe(thetas):
        calls.append(thetas.shape)
        return thetas.copy()

    belief = Belief(theta=np.zeros(2), cov=np.eye(2))
    attenuated_update(belief, observe, np.zeros(2), np.ones(2), KalmanNoise.isotropic(2, 0, 1))
    assert calls == [(5, 2)]


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"a_min": 0.0}, "a_min"),
        ({"a_min": float("inf")}, "a_min"),
        ({"a_max": 0.01}, "a_max"),
        ({"n_a": 0}, "n_a"),
        ({"n_a": 1.5}, "n_a"),
        ({"a_min": 0.5, "a_max": 0.5, "n_a": 2}, "n_a"),
    ],
)
def test_bad_parameters_are_refused_naming_the_field(kwargs, field):
    with pytest.raises(ValueError, match=f"Attenuation.{field}"):
        Attenuation(**kwargs)


def test_bad_features_are_refused_naming_the_field():
    belief = Belief(theta=np.zeros(2), cov=np.eye(2))
    noise = KalmanNoise.isotropic(2, 0, 1)
    with pytest.raises(ValueError, match="phi_human"):
        attenuated_update(belief, _linear(np.eye(2), np.zeros(2)), np.zeros(2), np.ones(3), noise)
