"""Learning the person's observation noise N jointly with θ (variational Bayes in the UKF).

Oracles: with a prior held with infinite weight it is the fixed-N UKF; on a linear-Gaussian
problem with a known N it finds that N, larger for a noisier person; through the study loop a
noise-learning learner records its N̂ per iteration.
"""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.belief import Belief, KalmanNoise
from corrections_sim.learning.kalman.filter import SigmaPoints, ukf_update
from corrections_sim.learning.kalman.learnt_noise import vb_ukf_update
from corrections_sim.learning.kalman.state import NoisePosterior, NoiseState
from corrections_sim.study import schema


def _noisy(noise: NoisePosterior) -> Belief:
    """N(0, I) over θ with ``noise`` the posterior over N."""
    return Belief(np.zeros(2), np.eye(2), state=NoiseState(noise))


def _problem(rng: np.random.Generator):
    a = rng.normal(size=(2, 2))
    return lambda th: np.tanh(np.atleast_2d(th) @ a.T)


def test_a_prior_held_with_infinite_weight_is_the_fixed_noise_ukf():
    rng = np.random.default_rng(1)
    for _ in range(50):
        h = _problem(rng)
        n = np.diag(rng.uniform(0.05, 1.0, size=2))
        noise = KalmanNoise(process=1e-4 * np.eye(2), observation=n)
        cov = np.array([[1.0, 0.3], [0.3, 0.5]])
        prior = Belief(theta=rng.normal(size=2), cov=cov)
        z, ref = rng.normal(size=2), rng.normal(size=2)
        fixed = ukf_update(prior, h, z, noise, SigmaPoints(), reference=ref)
        learnt = vb_ukf_update(
            Belief(prior.theta, prior.cov, state=NoiseState(NoisePosterior.around(n, 1e13))),
            h,
            z,
            noise,
            SigmaPoints(),
            reference=ref,
        )
        np.testing.assert_allclose(learnt.belief.theta, fixed.belief.theta, atol=1e-10)
        np.testing.assert_allclose(learnt.belief.cov, fixed.belief.cov, atol=1e-10)
        np.testing.assert_allclose(learnt.gain, fixed.gain, atol=1e-10)
        np.testing.assert_allclose(learnt.innovation_cov, fixed.innovation_cov, atol=1e-10)


def _learn(true_noise: float, seed: int, corrections: int = 400) -> Belief:
    """A linear-Gaussian person, Φ_h = A θ* + n with n ~ N(0, true_noise · I), A random."""
    rng = np.random.default_rng(seed)
    theta_star = np.array([1.0, -1.0])
    noise = KalmanNoise(process=np.zeros((2, 2)), observation=0.25 * np.eye(2))
    belief = _noisy(NoisePosterior.around(0.25 * np.eye(2), 4.0))
    for _ in range(corrections):
        a = rng.normal(size=(2, 2))
        z = a @ theta_star + rng.normal(0.0, np.sqrt(true_noise), size=2)
        belief = vb_ukf_update(belief, lambda th, a=a: np.atleast_2d(th) @ a.T, z, noise).belief
    return belief


@pytest.mark.parametrize("true_noise", [0.05, 0.5])
def test_on_a_linear_gaussian_person_the_noise_is_found(true_noise):
    belief = _learn(true_noise, seed=3)
    estimate = belief.state.noise_estimate()
    np.testing.assert_allclose(np.diag(estimate), true_noise, rtol=0.15)
    assert abs(estimate[0, 1]) < 0.15 * true_noise
    np.testing.assert_allclose(belief.theta, [1.0, -1.0], atol=0.1)


def test_a_noisier_person_gives_a_larger_estimate_and_the_fixed_point_converges():
    quiet, loud = (_learn(n, seed=5, corrections=60) for n in (0.05, 0.5))
    assert np.all(np.diag(loud.state.noise_estimate()) > 2 * np.diag(quiet.state.noise_estimate()))
    h = _problem(np.random.default_rng(2))
    noise = KalmanNoise.isotropic(2, 1e-4, 0.25)
    belief = _noisy(NoisePosterior.around(0.25 * np.eye(2), 4.0))
    step = vb_ukf_update(belief, h, np.array([0.4, -0.3]), noise, iterations=30)
    assert step.fixed_point_change < 1e-10
    assert step.belief.state.noise.dof == 5.0


def test_bad_noise_settings_are_refused_by_their_key_path():
    with pytest.raises(ValueError, match="learners.KF-C.noise: must be one of fixed, learnt"):
        schema.parse_study({"theta_star": [1, -1], "learners": {"KF-C": {"noise": "guessed"}}})
    with pytest.raises(ValueError, match="learners.KF.noise_dof: must be a finite number > 0"):
        schema.parse_study({"theta_star": [1, -1], "learners": {"KF": {"noise_dof": -1}}})
    with pytest.raises(ValueError, match="belief.state"):
        vb_ukf_update(
            Belief(np.zeros(2), np.eye(2)), lambda t: t, np.zeros(2), KalmanNoise.isotropic(2, 0, 1)
        )
    with pytest.raises(ValueError, match="NoisePosterior.dof"):
        NoisePosterior(dof=0.5, scale=np.eye(2))
    with pytest.raises(
        ValueError, match=r"NoiseState.noise: a posterior over 2 x 2 noise, expected 3"
    ):
        Belief(np.zeros(3), np.eye(3), state=NoiseState(NoisePosterior.around(np.eye(2), 4.0)))
    with pytest.raises(ValueError, match="Belief.state: expected a FamilyState"):
        Belief(np.zeros(2), np.eye(2), state=NoisePosterior.around(np.eye(2), 4.0))


def test_a_noise_learning_learner_records_its_estimate_and_others_leave_it_empty(tmp_path):
    from corrections_sim.figures.output import write_records
    from corrections_sim.planning.planner import Planner, PlannerConfig
    from corrections_sim.plans.book import Target
    from corrections_sim.scene.environments import paper_environments
    from corrections_sim.study.loop import run_learner

    settings = schema.parse_study(
        {"theta_star": [1.0, -1.0], "iterations": 2, "runs": 1, "learners": ["KF-C", "KF-CL"]}
    ).study
    assert settings.learners["KF-CL"].noise == "learnt"
    planner = Planner(PlannerConfig(features=("laptop", "table"), n_starts=1))
    envs = paper_environments()[::16]
    target = Target.solve(planner, np.array(settings.theta_star), envs)
    records = []
    for name in ("KF-C", "KF-CL"):
        rng = np.random.default_rng(4)
        records += run_learner(name, 0, settings, planner, envs, target, settings.user, rng).records
    learnt = [r for r in records if r["learner"] == "KF-CL"]
    assert all({"noise_00", "noise_01", "noise_11"} <= set(r) for r in learnt)
    assert learnt[0]["noise_00"] == pytest.approx(0.25)  # the prior's estimate: the study's N
    assert learnt[-1]["noise_00"] != learnt[0]["noise_00"]
    assert not any("noise_00" in r for r in records if r["learner"] == "KF-C")
    path = write_records(tmp_path / "curves.csv", records)
    header, first = path.read_text().splitlines()[:2]
    assert header.endswith("noise_00,noise_01,noise_11") and first.endswith(",,")


def test_quick_fig4_learnt_noise_raises_nis_lowers_the_noise_and_learns_no_worse():
    """CI's regression guard for learning N (fig. 4's quick preset, KF-C beside KF-CL):
    measured, KF-CL's mean NIS over t = 3..4 is 1.3x KF-C's, N-hat falls from 0.25 to
    (0.19, 0.15) and the final error is 0.78 against 0.84."""
    from concurrent.futures import ThreadPoolExecutor

    from corrections_sim.figures import learning_study
    from corrections_sim.study import analysis, runner

    settings = learning_study.load_settings(
        "fig4", quick=True, overrides={"learners": ["KF-C", "KF-CL"]}
    )
    with ThreadPoolExecutor(max_workers=1) as executor:
        result = runner.run(settings, executor, mean_estimate=False)
    stats = analysis.summarize(settings, result)
    fixed, learnt = stats["calibration"]["KF-C"], stats["calibration"]["KF-CL"]
    assert np.mean(learnt["mean_nis"][2:]) > 1.15 * np.mean(fixed["mean_nis"][2:])
    assert "mean_noise" not in fixed
    assert max(learnt["mean_noise"]["noise_00"][-1], learnt["mean_noise"]["noise_11"][-1]) < 0.225
    final = stats["final"]
    assert (
        final["KF-CL"]["estimate_error"]["mean"] <= final["KF-C"]["estimate_error"]["mean"] + 0.02
    )


def test_a_learners_override_given_as_a_table_keeps_its_parameters():
    """Python callers may name learners with parameters: they reach the learner (they were
    dropped silently before), on top of the study file's, and a non-table is refused."""
    from corrections_sim.figures import learning_study

    table = {"KF-CL": {"noise_dof": 1.5}, "KF": {"noise": "learnt"}}
    s = learning_study.load_settings("fig4", quick=True, overrides={"learners": table}).study
    assert list(s.learners) == ["KF-CL", "KF"]
    assert s.learners["KF"].noise == "learnt"
    assert (s.learners["KF-CL"].noise, s.learners["KF-CL"].noise_dof) == ("learnt", 1.5)
    listed = learning_study.load_settings("fig4", quick=True, overrides={"learners": ["KF"]}).study
    assert listed.learners["KF"].noise == "fixed"
    with pytest.raises(ValueError, match="learners.KF: expected a table of parameters"):
        learning_study.load_settings("fig4", quick=True, overrides={"learners": {"KF": "learnt"}})
