"""Confidence that matches exact Bayes: the iterated posterior linearisation (IPLF, one
correction and all of them) and the particle learner's machinery, against closed forms and
the grid posterior; bad input is one line."""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.belief import Belief, KalmanNoise
from corrections_sim.learning.base import make_learner
from corrections_sim.learning.exact import bayes as ref
from corrections_sim.learning.kalman.filter import ukf_update
from corrections_sim.learning.kalman.iterated import (
    gaussian_kl,
    iterated_update,
    linear_posterior,
    linearise,
)
from corrections_sim.learning.particles import cloud as smc
from corrections_sim.learning.particles.state import Particles

PRIOR = Belief(theta=np.zeros(2), cov=np.eye(2))
N = np.array([[0.25, 0.0], [0.0, 0.25]])
NOISE = KalmanNoise(process=np.zeros((2, 2)), observation=N)


def linear(a: np.ndarray, b: np.ndarray):
    return lambda th: np.atleast_2d(th) @ a.T + b


def bent(th: np.ndarray) -> np.ndarray:
    """A saturating, coupled h, like a planner's features (flat far away, steep nearby)."""
    th = np.atleast_2d(th)
    return np.stack([np.tanh(2.0 * th[:, 0]) + 0.3 * th[:, 1], np.tanh(th[:, 1] - th[:, 0])], 1)


def grid_posterior(observers, zs, points: int = 241):
    grid = ref.Grid((-4.0, -4.0), (4.0, 4.0), points)
    thetas = grid.thetas()
    log_p = ref.gaussian_log_prior(thetas, PRIOR)
    for observe, z in zip(observers, zs, strict=True):
        log_p = log_p + ref.gaussian_log_likelihood(z, observe(thetas), N)
    w = ref.posterior(log_p)
    mean, cov = ref.moments(thetas, w)
    return grid, thetas, w, Belief(theta=mean, cov=cov)


def test_one_pass_of_the_iterated_update_is_the_ukf():
    z = np.array([0.4, -0.2])
    ukf = ukf_update(PRIOR, bent, z, NOISE, reference=bent(PRIOR.theta)[0])
    one = iterated_update(PRIOR, bent, z, NOISE, reference=bent(PRIOR.theta)[0], iterations=1)
    np.testing.assert_array_equal(one.belief.theta, ukf.belief.theta)
    np.testing.assert_array_equal(one.belief.cov, ukf.belief.cov)
    assert one.passes == 1 and one.change == 0.0
    np.testing.assert_array_equal(one.innovation_cov, ukf.innovation_cov)


def test_on_a_linear_observation_iterating_changes_nothing_and_batch_is_the_joint_kalman():
    rng = np.random.default_rng(0)
    mats = [rng.normal(size=(2, 2)) for _ in range(4)]
    offsets = [rng.normal(size=2) for _ in range(4)]
    zs = [
        a @ [1.0, -1.0] + b + rng.normal(scale=0.5, size=2)
        for a, b in zip(mats, offsets, strict=True)
    ]
    belief = PRIOR
    for a, b, z in zip(mats, offsets, zs, strict=True):
        step = iterated_update(belief, linear(a, b), z, NOISE, iterations=5)
        plain = ukf_update(belief, linear(a, b), z, NOISE)
        np.testing.assert_allclose(step.belief.theta, plain.belief.theta, atol=1e-10)
        np.testing.assert_allclose(step.belief.cov, plain.belief.cov, atol=1e-10)
        assert step.passes == 2 and step.change < 1e-12  # the second pass confirms the first
        belief = step.belief
    # All four at once in information form: the same posterior (θ is static, h linear).
    lins = [linearise(PRIOR, linear(a, b)) for a, b in zip(mats, offsets, strict=True)]
    joint = linear_posterior(PRIOR, lins, zs, [N] * 4)
    np.testing.assert_allclose(joint.theta, belief.theta, atol=1e-10)
    np.testing.assert_allclose(joint.cov, belief.cov, atol=1e-10)


def test_the_linearisation_is_exact_for_a_linear_h_and_its_residual_is_psd():
    a, b = np.array([[1.0, 2.0], [0.5, -1.0]]), np.array([0.1, 0.2])
    lin = linearise(Belief(theta=np.array([0.3, 0.1]), cov=np.diag([0.5, 2.0])), linear(a, b))
    np.testing.assert_allclose(lin.matrix, a, atol=1e-12)
    np.testing.assert_allclose(lin.offset, b, atol=1e-12)
    np.testing.assert_allclose(lin.residual, 0.0, atol=1e-12)
    bent_lin = linearise(PRIOR, bent)
    assert np.linalg.eigvalsh(bent_lin.residual)[0] >= 0.0
    # One linear observation in information form is the Kalman update.
    post = linear_posterior(PRIOR, [lin], [np.array([1.0, 0.0])], [N])
    kf = ukf_update(PRIOR, linear(a, b), np.array([1.0, 0.0]), NOISE)
    np.testing.assert_allclose(post.theta, kf.belief.theta, atol=1e-10)


def test_iterating_brings_a_nonlinear_update_nearer_the_exact_posterior():
    """Three corrections through a saturating h from a broad prior: the UKF's Gaussian is
    further from the exact posterior's moments than the iterated one's."""
    zs = [bent(np.array([1.0, -1.0]))[0] + d for d in ([0.1, -0.05], [-0.05, 0.1], [0.0, 0.0])]
    _, _, _, exact = grid_posterior([bent] * 3, zs)
    ukf, iplf = PRIOR, PRIOR
    for z in zs:
        ukf = ukf_update(ukf, bent, z, NOISE).belief
        iplf = iterated_update(iplf, bent, z, NOISE, iterations=10, tolerance=1e-6).belief
    assert gaussian_kl(exact, iplf) < 0.75 * gaussian_kl(exact, ukf)  # 0.185 against 0.280


def test_particles_with_moves_reach_the_exact_posterior_of_a_nonlinear_model():
    """Resample-move over three corrections: 4000 particles' moments within a tenth of an sd
    (mean) and 10% (variances) of the grid's, and the KL from the grid to them (smoothed)
    small; the same seed gives
    the same particles."""
    zs = [bent(np.array([1.0, -1.0]))[0] + d for d in ([0.1, -0.05], [-0.05, 0.1], [0.0, 0.0])]
    _, _, _, exact = grid_posterior([bent] * 3, zs)

    def log_prior(th):
        return -0.5 * np.sum(th**2, axis=1)

    def run(seed: int) -> Particles:
        rng = np.random.default_rng(seed)
        cloud = smc.draw(PRIOR, 4000, rng)
        for t, z in enumerate(zs):

            def total(th, t=t):
                return sum(ref.gaussian_log_likelihood(zi, bent(th), N) for zi in zs[: t + 1]), 0

            like = ref.gaussian_log_likelihood(z, bent(cloud.thetas), N)
            cloud = smc.correct(cloud, like, log_prior, total, rng, moves=4).particles
        return cloud

    cloud = run(1)
    mean, cov = cloud.moments()
    sd = np.sqrt(np.diag(exact.cov))
    assert np.all(np.abs(mean - exact.theta) < 0.1 * sd)
    np.testing.assert_allclose(np.diag(cov), np.diag(exact.cov), rtol=0.1)
    _, coarse, coarse_w, _ = grid_posterior([bent] * 3, zs, points=81)
    assert smc.smoothed_kl(coarse, coarse_w, cloud) < 0.02
    np.testing.assert_array_equal(run(1).thetas, cloud.thetas)


def test_systematic_resampling_keeps_each_particle_about_n_w_times():
    w = np.array([0.5, 0.25, 0.125, 0.125])
    counts = np.bincount(smc.systematic(w, np.random.default_rng(3)), minlength=4)
    assert counts.sum() == 4 and np.all(np.abs(counts - 4 * w) < 1)


def test_the_learners_refuse_bad_counts_in_one_line():
    with pytest.raises(ValueError, match="particles: must be an integer >= 2"):
        make_learner("PF-C", {"particles": 1})
    with pytest.raises(ValueError, match="iterations: must be an integer >= 1"):
        make_learner("KF-CI", {"iterations": 0})
    with pytest.raises(ValueError, match="tolerance"):
        make_learner("KF-CI", {"tolerance": 0})
    with pytest.raises(ValueError, match="iterate: must be one of none, each, got 'twice'"):
        make_learner("KF-C", {"iterate": "twice"})
    with pytest.raises(ValueError, match="iterate: must be one of none, each, got 'all'"):
        make_learner("KF-C", {"iterate": "all"})  # KF-CB's batch form, removed
    with pytest.raises(ValueError, match='needs noise = "fixed"'):
        make_learner("KF-CL", {"iterate": "each"})
    with pytest.raises(ValueError, match="learners.PF-C.noise: PF-C keeps N fixed"):
        make_learner("PF-C", {"noise": "learnt"})
    with pytest.raises(ValueError, match="learners.KF-CRX.expand_after: must be an integer >= 1"):
        make_learner("KF-CRX", {"expand_after": 0})
    with pytest.raises(ValueError, match="resample_below"):
        make_learner("PF-C", {"resample_below": 0})
    with pytest.raises(ValueError, match="particles = 1: expected an integer >= 2"):
        smc.draw(PRIOR, 1, np.random.default_rng(0))
    with pytest.raises(ValueError, match="iterations = 0"):
        iterated_update(PRIOR, bent, np.zeros(2), NOISE, iterations=0)


def test_a_correction_no_particle_explains_is_one_line():
    cloud = smc.draw(PRIOR, 4, np.random.default_rng(0))
    with pytest.raises(ValueError, match="no particle explains the correction"):
        smc.correct(
            cloud, np.full(4, -np.inf), lambda t: np.zeros(len(t)), None, np.random.default_rng(0)
        )


@pytest.mark.parametrize("learner", ["KF-CI", "PF-C", "AL-PF"])
def test_a_session_with_an_iterated_or_particle_learner_resumes_exactly(tmp_path, learner):
    """The page's session: the belief after three corrections (the particles and the past
    re-read) comes back byte for byte on resume, and replay (which plans cold, as this
    session does) reproduces the log exactly."""
    from corrections_sim.people.users import make_user
    from corrections_sim.session.log import StudyLog
    from corrections_sim.session.replay import replay
    from corrections_sim.session.session import Session
    from corrections_sim.session.simulate import simulate
    from corrections_sim.study.schema import parse_study

    settings = parse_study(
        {
            "environments": ["s0-t0-l1", "s0-t0-l2", "s1-t1-l0", "s2-t0-l1"],
            "theta_star": [1.0, -1.0],
            "learners": {learner: {"particles": 24} if "P" in learner else {}},
            "seed": 5,
        },
        name="exact",
    )
    with StudyLog(tmp_path / "s.sqlite") as log:
        session = Session.start(settings, log, learner=learner)
        simulate(session, make_user("biased"), (1.0, -1.0), 3)
        resumed = Session.resume(log, session.id)
        np.testing.assert_array_equal(resumed.belief.theta, session.belief.theta)
        np.testing.assert_array_equal(resumed.belief.cov, session.belief.cov)
        if "P" in learner:
            np.testing.assert_array_equal(
                resumed.belief.state.particles.thetas, session.belief.state.particles.thetas
            )
            assert session.belief.state.particles.count == 24
        if learner != "KF-CI":  # the particles read the past again
            assert len(session.belief.state.history) == 4  # the prior and three corrections
        _, _, facts = replay(log, session.id, [learner])
        assert facts["max_gap_to_log"] == 0.0
