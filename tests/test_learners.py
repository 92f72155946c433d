"""Learners against the paper's equations and the linear Kalman filter (the oracle).

Everything here is pure numpy: observation models are small closed-form functions standing in
for "features of the optimal trajectory", so no planner is built.
"""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.learning import (
    COV_FLOOR_RTOL,
    Belief,
    KalmanNoise,
    SigmaPoints,
    ekf_predicted_covariance,
    ekf_update,
    finite_difference_jacobian,
    frobenius,
    learning_rate_schedule,
    perceptron_update,
    select_environment,
    symmetrize,
    ukf_predicted_covariance,
    ukf_update,
)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20180829)


def random_spd(rng: np.random.Generator, k: int, scale: float = 1.0) -> np.ndarray:
    b = rng.normal(size=(k, k))
    return scale * (b @ b.T / k + 0.1 * np.eye(k))


def linear_observe(a: np.ndarray, b: np.ndarray | None = None):
    offset = np.zeros(a.shape[0]) if b is None else b
    return lambda thetas: thetas @ a.T + offset


def linear_kf(theta, cov, a, b, z, m, n):
    """Textbook Kalman filter for θ' = θ + m, z = A θ + b + n."""
    prior = cov + m
    s = a @ prior @ a.T + n
    gain = prior @ a.T @ np.linalg.inv(s)
    return theta + gain @ (z - a @ theta - b), (np.eye(len(theta)) - gain @ a) @ prior


def assert_spd(cov: np.ndarray) -> None:
    assert np.array_equal(cov, cov.T)
    assert np.linalg.eigvalsh(cov)[0] > 0.0
    np.linalg.cholesky(cov)


# --------------------------------------------------------------------------- sigma points


def test_default_sigma_weights_for_two_features():
    wm, wc = SigmaPoints().weights(2)
    # α = 1, κ = 0 ⇒ λ = 0: no weight on the centre for the mean, W_c0 = 1 − α² + β = 2.
    np.testing.assert_array_equal(wm, [0.0, 0.25, 0.25, 0.25, 0.25])
    np.testing.assert_array_equal(wc, [2.0, 0.25, 0.25, 0.25, 0.25])


@pytest.mark.parametrize(
    "sigma",
    [SigmaPoints(), SigmaPoints(alpha=1e-3), SigmaPoints(alpha=0.5, beta=0.0, kappa=1.0)],
)
def test_sigma_points_reproduce_mean_and_covariance(rng, sigma):
    k = 3
    mean = rng.normal(size=k)
    cov = random_spd(rng, k)
    points = sigma.points(mean, cov)
    wm, wc = sigma.weights(k)
    assert points.shape == (2 * k + 1, k)
    assert wm.sum() == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(wm @ points, mean, atol=1e-9)
    centred = points - mean
    np.testing.assert_allclose((wc[:, None] * centred).T @ centred, cov, atol=1e-12)


# --------------------------------------------------------------------------- oracles


@pytest.mark.parametrize(
    ("sigma", "tol"),
    [
        (SigmaPoints(), 1e-10),
        (SigmaPoints(alpha=0.5, beta=2.0, kappa=1.0), 1e-10),
        # W_m0 ≈ −10⁶ costs six digits of ẑ to cancellation.
        (SigmaPoints(alpha=1e-3), 1e-6),
    ],
)
def test_ukf_equals_linear_kalman_filter(rng, sigma, tol):
    k = 3
    theta, cov = rng.normal(size=k), random_spd(rng, k)
    belief = Belief(theta, cov)
    noise = KalmanNoise(random_spd(rng, k, 0.01), random_spd(rng, k, 0.1))
    for _ in range(8):
        a, b, z = rng.normal(size=(k, k)), rng.normal(size=k), rng.normal(size=k)
        belief = ukf_update(belief, linear_observe(a, b), z, noise, sigma).belief
        theta, cov = linear_kf(theta, cov, a, b, z, noise.process, noise.observation)
        np.testing.assert_allclose(belief.theta, theta, rtol=0, atol=tol)
        np.testing.assert_allclose(belief.cov, cov, rtol=0, atol=tol)


def test_ekf_with_exact_jacobian_equals_linear_kalman_filter(rng):
    k = 3
    theta, cov = rng.normal(size=k), random_spd(rng, k)
    belief = Belief(theta, cov)
    noise = KalmanNoise(random_spd(rng, k, 0.01), random_spd(rng, k, 0.1))
    for _ in range(8):
        a, b, z = rng.normal(size=(k, k)), rng.normal(size=k), rng.normal(size=k)
        step = ekf_update(belief, a, a @ belief.theta + b, z, noise)
        theta, cov = linear_kf(theta, cov, a, b, z, noise.process, noise.observation)
        np.testing.assert_allclose(step.belief.theta, theta, rtol=0, atol=1e-10)
        np.testing.assert_allclose(step.belief.cov, cov, rtol=0, atol=1e-10)
        assert not step.repaired
        belief = step.belief


def test_ukf_gain_and_statistics_on_a_linear_problem(rng):
    k = 2
    a, b = rng.normal(size=(k, k)), rng.normal(size=k)
    belief = Belief(rng.normal(size=k), random_spd(rng, k))
    noise = KalmanNoise(np.zeros((k, k)), 0.2 * np.eye(k))
    z = rng.normal(size=k)
    step = ukf_update(belief, linear_observe(a, b), z, noise)
    expected_gain = belief.cov @ a.T @ np.linalg.inv(a @ belief.cov @ a.T + noise.observation)
    np.testing.assert_allclose(step.gain, expected_gain, atol=1e-12)
    np.testing.assert_allclose(step.predicted_obs, a @ belief.theta + b, atol=1e-12)
    np.testing.assert_allclose(step.innovation, z - a @ belief.theta - b, atol=1e-12)
    # Row 0 is h(θ̂): the robot's own trajectory, reusable by the caller.
    np.testing.assert_array_equal(step.sigma_points[0], belief.theta)
    np.testing.assert_allclose(step.sigma_obs, step.sigma_points @ a.T + b, atol=1e-12)
    assert not step.repaired


def test_perceptron_is_equation_b5(rng):
    k = 3
    belief = Belief(rng.normal(size=k), random_spd(rng, k))
    phi, phi_h = rng.uniform(0, 10, size=k), rng.uniform(0, 10, size=k)
    new = perceptron_update(belief, phi, phi_h, 0.37)
    np.testing.assert_array_equal(new.theta, belief.theta + 0.37 * (phi_h - phi))
    np.testing.assert_array_equal(new.cov, belief.cov)
    new_np = perceptron_update(belief, phi, phi_h, np.float64(0.37))
    np.testing.assert_array_equal(new_np.theta, new.theta)


def test_learning_rate_schedule_is_mean_gain_diagonal():
    gains = np.zeros((2, 3, 2, 2))
    gains[0, :, 0, 0] = [1.0, 2.0, 3.0]
    gains[0, :, 1, 1] = [3.0, 2.0, 1.0]
    gains[1, :, 0, 0] = [0.0, 0.0, 4.0]
    gains[1, :, 1, 1] = [4.0, 0.0, 0.0]
    gains[:, :, 0, 1] = 100.0  # off-diagonal entries do not count
    np.testing.assert_allclose(learning_rate_schedule(gains), [2.0, 1.0, 2.0])


def test_finite_difference_jacobian_in_one_batched_call():
    w = np.array([[1.0, 2.0, 0.0], [0.5, -1.0, 3.0], [0.0, 0.0, 1.0]])
    calls = []

    def observe(thetas):
        calls.append(thetas.shape)
        return np.sin(thetas @ w.T)

    theta = np.array([0.1, -0.2, 0.3])
    jac = finite_difference_jacobian(observe, theta, 1e-5)
    analytic = np.cos(w @ theta)[:, None] * w
    np.testing.assert_allclose(jac, analytic, atol=1e-9)
    assert calls == [(6, 3)]
    per_weight = finite_difference_jacobian(observe, theta, np.array([1e-5, 2e-5, 3e-5]))
    np.testing.assert_allclose(per_weight, analytic, atol=1e-8)


# --------------------------------------------------------------------------- SPD under stress


def _stress_observe(rng: np.random.Generator, k: int):
    # Bounded, like real feature counts (k features in [0, 1] summed over waypoints), but
    # with slopes from 1e-9 to 1e3 and regions where they vanish.
    w = rng.normal(size=(k, k)) * 10.0 ** rng.uniform(-1, 2)
    c = rng.normal(size=k)
    kind = rng.integers(6)
    if kind == 0:  # saturating: flat almost everywhere
        return lambda th: np.tanh(th @ w.T + c)
    if kind == 1:  # near-zero Jacobian
        return lambda th: 1e-9 * np.sin(th @ w.T) + c
    if kind == 2:  # zero Jacobian: the feature ignores θ (laptop far from the path)
        return lambda th: np.broadcast_to(c, th.shape).copy()
    if kind == 3:  # a step: steep sigmoid of slope up to 1e3
        return lambda th: 20.0 / (1.0 + np.exp(-np.clip(10.0 * (th @ w.T + c), -500, 500)))
    if kind == 4:  # one feature only, the others flat
        return lambda th: np.column_stack([np.tanh(th @ w[0]), np.zeros((len(th), k - 1))])
    return lambda th: np.sin(th @ w.T) + np.cos(th @ w.T) ** 2


def _stress_noise(rng: np.random.Generator, k: int) -> KalmanNoise:
    m = np.zeros((k, k)) if rng.random() < 0.3 else random_spd(rng, k, 10.0 ** rng.uniform(-8, 0))
    n = random_spd(rng, k, 10.0 ** rng.uniform(-12, 1))
    return KalmanNoise(m, n)


STRESS_SIGMAS = [
    SigmaPoints(),
    SigmaPoints(alpha=1e-3),
    SigmaPoints(alpha=1e-3, beta=0.0),  # W_c0 < 0 and β < α²: indefinite P_zz happens
    SigmaPoints(alpha=0.3, beta=2.0, kappa=1.0),
]


def test_ukf_covariance_stays_spd_over_thousands_of_updates(rng):
    updates = repairs = 0
    for _ in range(200):
        k = int(rng.integers(1, 5))
        belief = Belief(rng.normal(size=k), random_spd(rng, k, 10.0 ** rng.uniform(-4, 2)))
        sigma = STRESS_SIGMAS[int(rng.integers(len(STRESS_SIGMAS)))]
        for _ in range(15):
            observe = _stress_observe(rng, k)
            phi_h = rng.uniform(-1.0, 20.0, size=k)
            step = ukf_update(belief, observe, phi_h, _stress_noise(rng, k), sigma)
            belief = step.belief
            assert_spd(belief.cov)
            assert np.all(np.isfinite(belief.theta))
            updates += 1
            repairs += step.repaired
    assert updates == 3000
    # The stress cases really reach the repair path, and most updates do not need it.
    assert 0 < repairs < updates // 2


def test_ekf_covariance_stays_spd_over_thousands_of_updates(rng):
    updates = 0
    for _ in range(200):
        k = int(rng.integers(1, 5))
        belief = Belief(rng.normal(size=k), random_spd(rng, k, 10.0 ** rng.uniform(-4, 2)))
        for _ in range(15):
            observe = _stress_observe(rng, k)
            if rng.random() < 0.5:
                jac = finite_difference_jacobian(observe, belief.theta, 1e-4)
            else:
                jac = rng.normal(size=(k, k)) * 10.0 ** rng.uniform(-10, 6)
            phi = observe(belief.theta[None, :])[0]
            phi_h = phi + rng.normal(size=k)
            belief = ekf_update(belief, jac, phi, phi_h, _stress_noise(rng, k)).belief
            assert_spd(belief.cov)
            assert np.all(np.isfinite(belief.theta))
            updates += 1
    assert updates == 3000


def test_ukf_repairs_a_posterior_lost_to_cancellation():
    # N ≪ H P Hᵀ: the exact posterior N/(1+N) ≈ 1e-14 is below the floor 1e-9·λ_max(P⁻).
    belief = Belief(np.zeros(2), np.eye(2))
    noise = KalmanNoise(np.zeros((2, 2)), 1e-14 * np.eye(2))
    step = ukf_update(belief, linear_observe(np.eye(2)), np.ones(2), noise)
    assert step.repaired
    np.testing.assert_allclose(np.linalg.eigvalsh(step.belief.cov), COV_FLOOR_RTOL, rtol=1e-6)
    np.testing.assert_allclose(step.belief.theta, np.ones(2), atol=1e-12)


# --------------------------------------------------------------------------- learning


@pytest.mark.parametrize("learner", ["pp", "ukf", "ekf"])
def test_estimate_error_falls_over_iterations(rng, learner):
    k = 3
    theta_star = np.array([1.0, -0.5, 0.3])
    belief = Belief(np.zeros(k), np.eye(k))
    noise = KalmanNoise(1e-4 * np.eye(k), 1e-2 * np.eye(k))
    errors = [np.abs(belief.theta - theta_star).sum()]
    for _ in range(30):
        # A new environment each iteration. ∂Φ*/∂θ is the Hessian of the convex value
        # function max_ξ θ·Φ(ξ), so it is PSD: draw A symmetric positive definite.
        q, _ = np.linalg.qr(rng.normal(size=(k, k)))
        a = q @ np.diag(rng.uniform(0.2, 1.0, size=k)) @ q.T
        phi_h = a @ theta_star + 0.01 * rng.normal(size=k)
        phi = a @ belief.theta
        if learner == "pp":
            belief = perceptron_update(belief, phi, phi_h, 0.5)
        elif learner == "ukf":
            belief = ukf_update(belief, linear_observe(a), phi_h, noise).belief
        else:
            belief = ekf_update(belief, a, phi, phi_h, noise).belief
        errors.append(np.abs(belief.theta - theta_star).sum())
    errors = np.array(errors)
    assert errors[0] == pytest.approx(1.8)
    # Fast at first, then down at the noise floor (0.01 per feature).
    assert errors[5] < 0.5 * errors[0]
    assert errors[-1] < 0.05 * errors[0]
    assert errors[:5].mean() > 5.0 * errors[-10:].mean()


# --------------------------------------------------------------------------- prediction


def test_ukf_predicted_covariance_is_the_update_covariance(rng):
    k = 3
    w = rng.normal(size=(k, k))

    def observe(th):
        return np.tanh(th @ w.T) + 0.3 * (th @ w.T) ** 2

    belief = Belief(rng.normal(size=k), random_spd(rng, k))
    noise = KalmanNoise(random_spd(rng, k, 0.01), random_spd(rng, k, 0.1))
    predicted = ukf_predicted_covariance(belief, observe, noise)
    for _ in range(5):
        phi_h = rng.normal(size=k) * 10.0
        np.testing.assert_array_equal(
            ukf_update(belief, observe, phi_h, noise).belief.cov, predicted
        )


def test_ekf_predicted_covariance_is_the_update_covariance_and_a1(rng):
    k = 3
    jac = rng.normal(size=(k, k))
    belief = Belief(rng.normal(size=k), random_spd(rng, k))
    noise = KalmanNoise(random_spd(rng, k, 0.01), random_spd(rng, k, 0.1))
    predicted = ekf_predicted_covariance(belief, jac, noise)
    for _ in range(5):
        phi, phi_h = rng.normal(size=k), rng.normal(size=k) * 10.0
        step = ekf_update(belief, jac, phi, phi_h, noise)
        np.testing.assert_array_equal(step.belief.cov, predicted)
    # Eq. (A1)/(K7): (I − K H)(P + M), which the Joseph form equals for the optimal K.
    prior = belief.cov + noise.process
    np.testing.assert_allclose(predicted, (np.eye(k) - step.gain @ jac) @ prior, atol=1e-12)


# --------------------------------------------------------------------------- active learning


def test_select_environment_takes_smallest_frobenius_norm_lowest_index_on_ties():
    covs = [np.diag([3.0, 0.0]), np.diag([1.0, 1.0]), np.diag([2.0, 0.0]), np.diag([1.0, 1.0])]
    assert frobenius(covs[1]) == pytest.approx(np.sqrt(2.0))
    assert select_environment(covs) == 1
    assert select_environment([np.eye(2), np.eye(2)]) == 0
    assert select_environment([2 * np.eye(2), np.eye(2), np.eye(2)]) == 1


@pytest.mark.parametrize("filter_", ["ukf", "ekf"])
@pytest.mark.parametrize(("variances", "expected"), [((0.01, 1.0), 1), ((1.0, 0.01), 0)])
def test_active_learning_asks_about_the_uncertain_feature(filter_, variances, expected):
    # Environment A only reveals feature 1, environment B only feature 2 (figs. 2 and 5).
    belief = Belief(np.array([0.5, 0.5]), np.diag(variances))
    noise = KalmanNoise(np.zeros((2, 2)), 0.01 * np.eye(2))
    environments = [np.diag([1.0, 0.0]), np.diag([0.0, 1.0])]
    if filter_ == "ukf":
        covs = [ukf_predicted_covariance(belief, linear_observe(a), noise) for a in environments]
    else:
        covs = [ekf_predicted_covariance(belief, a, noise) for a in environments]
    assert select_environment(covs) == expected
    # Learning the well-known feature halves 0.01 but leaves the variance 1 alone; learning
    # the uncertain one takes 1 down to N / (1 + N) = 0.01 / 1.01.
    chosen, other = covs[expected], covs[1 - expected]
    assert frobenius(other) == pytest.approx(np.hypot(0.01 * 0.01 / 0.02, 1.0), rel=1e-9)
    assert frobenius(chosen) == pytest.approx(np.hypot(0.01, 0.01 / 1.01), rel=1e-9)


# --------------------------------------------------------------------------- values and bad input


def test_belief_copies_symmetrizes_and_freezes():
    theta, cov = np.array([1.0, 2.0]), np.array([[2.0, 0.5 + 1e-12], [0.5, 1.0]])
    belief = Belief(theta, cov)
    theta[0] = 99.0
    assert belief.theta[0] == 1.0
    assert np.array_equal(belief.cov, belief.cov.T)
    assert belief.dim == 2
    with pytest.raises(ValueError, match="read-only"):
        belief.theta[0] = 3.0
    np.testing.assert_array_equal(symmetrize([[1.0, 2.0], [0.0, 1.0]]), [[1.0, 1.0], [1.0, 1.0]])


@pytest.mark.parametrize(
    ("theta", "cov", "field"),
    [
        ([0.0, 0.0], [[1.0, 2.0], [2.0, 1.0]], "Belief.cov"),  # indefinite
        ([0.0, 0.0], [[1.0, 0.0], [0.0, 0.0]], "Belief.cov"),  # singular
        ([0.0, 0.0], [[1.0, 0.5], [0.0, 1.0]], "Belief.cov"),  # not symmetric
        ([0.0, 0.0], np.eye(3), "Belief.cov"),  # shape mismatch
        ([0.0, 0.0], [1.0, 1.0], "Belief.cov"),  # not a matrix
        ([[0.0, 0.0]], np.eye(2), "Belief.theta"),  # not a vector
        ([0.0, np.nan], np.eye(2), "Belief.theta"),
        ([0.0, 0.0], [[1.0, np.nan], [np.nan, 1.0]], "Belief.cov"),
    ],
)
def test_belief_refuses_bad_input(theta, cov, field):
    with pytest.raises(ValueError, match=field):
        Belief(theta, cov)


@pytest.mark.parametrize(
    ("process", "observation", "field"),
    [
        (np.zeros((2, 2)), np.zeros((2, 2)), "KalmanNoise.observation"),  # N must be PD
        (-np.eye(2), np.eye(2), "KalmanNoise.process"),
        (np.eye(2), np.eye(3), "KalmanNoise.observation"),
        (np.full((2, 2), np.inf), np.eye(2), "KalmanNoise.process"),
    ],
)
def test_noise_refuses_bad_input(process, observation, field):
    with pytest.raises(ValueError, match=field):
        KalmanNoise(process, observation)


def test_noise_accepts_zero_process_noise():
    assert KalmanNoise(np.zeros((2, 2)), np.eye(2)).dim == 2


def test_grown_noise_gives_a_learnt_feature_a_share_of_the_observation_noise():
    """Grown to k + 1 features, the learnt one's noise is the mean diagonal entry (M and N
    alike), its observation noise times ``share`` (KF-CRX fits it, issue 69); a share of 1
    is the noise it always had, byte for byte."""
    noise = KalmanNoise(np.diag([0.01, 0.03]), np.diag([0.2, 0.3]))
    plain = noise.grown(3)
    np.testing.assert_array_equal(plain.observation, np.diag([0.2, 0.3, 0.25]))
    np.testing.assert_array_equal(plain.process, np.diag([0.01, 0.03, 0.02]))
    assert noise.grown(3, 1.0).observation.tobytes() == plain.observation.tobytes()
    shared = noise.grown(3, 1 / 16)
    np.testing.assert_allclose(shared.observation, np.diag([0.2, 0.3, 0.25 / 16]), rtol=1e-15)
    np.testing.assert_array_equal(shared.process, plain.process)
    assert noise.grown(2, 1 / 16) is noise
    for share in (0.0, -1.0, np.nan):
        with pytest.raises(ValueError, match="share"):
            noise.grown(3, share)


@pytest.mark.parametrize("alpha", [0.0, -0.1, np.nan, np.inf, np.array([0.1, 0.2]), "0.1"])
def test_perceptron_refuses_bad_alpha(alpha):
    belief = Belief(np.zeros(2), np.eye(2))
    with pytest.raises(ValueError, match="alpha"):
        perceptron_update(belief, np.zeros(2), np.ones(2), alpha)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"alpha": 0.0}, "SigmaPoints.alpha"),
        ({"beta": -1.0}, "SigmaPoints.beta"),
        ({"kappa": np.nan}, "SigmaPoints.kappa"),
    ],
)
def test_sigma_points_refuse_bad_parameters(kwargs, field):
    with pytest.raises(ValueError, match=field):
        SigmaPoints(**kwargs)


def test_sigma_points_refuse_imaginary_spread():
    with pytest.raises(ValueError, match="SigmaPoints.kappa"):
        SigmaPoints(kappa=-3.0).weights(2)


def test_updates_refuse_bad_input():
    belief = Belief(np.zeros(2), np.eye(2))
    noise = KalmanNoise(np.zeros((2, 2)), np.eye(2))
    ident = linear_observe(np.eye(2))
    with pytest.raises(ValueError, match="phi_human"):
        ukf_update(belief, ident, np.ones(3), noise)
    with pytest.raises(ValueError, match="phi_human"):
        ukf_update(belief, ident, np.array([1.0, np.nan]), noise)
    with pytest.raises(ValueError, match="observe"):
        ukf_update(belief, lambda th: np.full_like(th, np.nan), np.ones(2), noise)
    with pytest.raises(ValueError, match="observe"):
        ukf_update(belief, lambda th: th[:, :1], np.ones(2), noise)
    with pytest.raises(ValueError, match="observe"):
        ukf_update(belief, lambda th: 1e200 * th, np.ones(2), noise)
    with pytest.raises(ValueError, match="noise"):
        ukf_update(belief, ident, np.ones(2), KalmanNoise(np.zeros((3, 3)), np.eye(3)))
    with pytest.raises(ValueError, match="jacobian"):
        ekf_update(belief, np.eye(3), np.zeros(2), np.ones(2), noise)
    with pytest.raises(ValueError, match="jacobian"):
        ekf_predicted_covariance(belief, np.full((2, 2), np.nan), noise)
    with pytest.raises(ValueError, match="phi_robot"):
        ekf_update(belief, np.eye(2), np.zeros(1), np.ones(2), noise)
    with pytest.raises(ValueError, match="phi_robot"):
        perceptron_update(belief, [np.inf, 0.0], np.ones(2), 0.1)
    with pytest.raises(ValueError, match="step"):
        finite_difference_jacobian(ident, np.zeros(2), 0.0)
    with pytest.raises(ValueError, match="step"):
        finite_difference_jacobian(ident, np.zeros(2), np.ones(3))
    with pytest.raises(ValueError, match="gains"):
        learning_rate_schedule(np.zeros((3, 2, 2)))
    with pytest.raises(ValueError, match="predicted_covs"):
        select_environment([])
    with pytest.raises(ValueError, match="predicted_covs"):
        select_environment([np.eye(2), np.eye(3)])
    with pytest.raises(ValueError, match="cov"):
        frobenius(np.ones(3))


def test_every_gaussian_learner_holds_the_observation_its_likelihood_names():
    """The observation model is a component (``learning/observation.py``): a learner with a
    Gaussian likelihood holds Φ(ξ*(θ, E)) when it takes corrections as they come, and its
    correction model's Φ(C(ξᵗ, ξ*(θ, E))) otherwise — the one its exact reference reads."""
    from corrections_sim.learning.base import LEARNERS, make_learner
    from corrections_sim.learning.exact.grid import GRID_MODELS
    from corrections_sim.learning.observation import CorrectedPlanFeatures, PlanFeatures

    seen = set()
    for name in LEARNERS:
        learner = make_learner(name)
        likelihood = learner.likelihood()
        if likelihood is None or not GRID_MODELS[likelihood.kind].needs_plans:
            continue
        observation = learner.observation()
        if likelihood.correction is None:
            assert observation == PlanFeatures(), name
            assert not observation.needs_robot
        else:
            assert observation == CorrectedPlanFeatures(likelihood.correction), name
            assert observation.needs_robot
        seen.add(type(observation))
    assert seen == {PlanFeatures, CorrectedPlanFeatures}
    assert make_learner("PP").observation() is None


def test_active_learning_over_a_learner_that_predicts_no_covariance_is_refused():
    from dataclasses import dataclass

    from corrections_sim.learning.kalman.active import ActiveMixin
    from corrections_sim.learning.perceptron.learners import Perceptron

    with pytest.raises(TypeError, match="predicts its covariance"):

        @dataclass(frozen=True)
        class ActivePerceptron(ActiveMixin, Perceptron):
            pass


def test_the_correction_step_grows_the_noise_and_shows_the_correction():
    """One correction step for every caller: a learner that learnt a feature (θ̂ over k + 1
    weights) gets the study's M and N grown to its dimension, and the person's ξ_h in its
    context; a belief over the study's k gets the study's noise itself."""
    from dataclasses import dataclass

    from corrections_sim.learning import correction
    from corrections_sim.learning.base import Learner, Step

    seen = []

    @dataclass(frozen=True)
    class Recording(Learner):
        def update(self, ctx, belief, env, plan, phi_h):
            seen.append(ctx)
            return Step(belief, gain=None, innovation=phi_h)

    noise = KalmanNoise.isotropic(2, 1e-4, 0.25)
    fields = dict(book=None, envs=(), features=("laptop", "table"), n_waypoints=12)
    fields |= dict(alphas=None, rng=np.random.default_rng(0), sigma=SigmaPoints())
    grown = Belief(theta=np.zeros(3), cov=np.eye(3), extra=("learnt-0",))
    ctx = correction.context(grown, noise, **fields)
    assert ctx.noise.dim == 3 and ctx.noise.observation[2, 2] == 0.25
    corrected = np.ones((12, 7))
    correction.step(Recording(), ctx, grown, None, None, np.zeros(3), corrected)
    assert seen[-1].noise.dim == 3 and seen[-1].corrected is corrected
    plain = Belief(theta=np.zeros(2), cov=np.eye(2))
    correction.step(
        Recording(), correction.context(plain, noise, **fields), plain, None, None, np.zeros(2)
    )
    assert seen[-1].noise is noise and seen[-1].corrected is None
