"""Relevance (issue 29): people who weigh features the robot lacks, corrections that carry no
preference, and learners that estimate per correction whether it is explainable at all."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from corrections_sim.belief import Belief
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import make_learner
from corrections_sim.learning.exact import bayes as ref
from corrections_sim.learning.relevance.judge import Relevance, explain
from corrections_sim.metrics import roc_auc
from corrections_sim.people.corrections import WaypointCorrection
from corrections_sim.people.users import Situation, make_user
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import PlannerConfig, shared_planner, smoothness_cost
from corrections_sim.plans.book import PlanBook, Target, evaluate
from corrections_sim.scene.environments import paper_environments
from corrections_sim.study import schema

FEATURES = ("laptop", "table")
THETA_STAR = np.array([1.0, -1.0])


@pytest.fixture(scope="module")
def task(planner):
    env = paper_environments()[5]
    return env, planner.solve(np.zeros(2), env), planner.solve(THETA_STAR, env)


# ---- β̂ from ρ ------------------------------------------------------------------------


def test_both_models_of_rho_are_densities():
    model = Relevance()
    relevant, _ = integrate.quad(model.relevant_density, 0.0, np.inf)
    irrelevant, _ = integrate.quad(model.irrelevant_density, 0.0, 1.0, points=[1e-3])
    assert relevant == pytest.approx(1.0, abs=1e-6)
    assert irrelevant == pytest.approx(1.0, abs=1e-4)


def test_irrelevant_model_is_the_unexplained_fraction_of_a_random_direction(rng):
    """ρ² of a uniformly random direction in 7 dimensions against a 2-dimensional subspace
    follows Beta(5/2, 1): the density's median matches the sampled median."""
    d = rng.normal(size=(20000, 7))
    rho = np.linalg.norm(d[:, 2:], axis=1) / np.linalg.norm(d, axis=1)
    model = Relevance(k=2)
    cdf = integrate.quad(model.irrelevant_density, 0.0, float(np.median(rho)))[0]
    assert cdf == pytest.approx(0.5, abs=0.01)


def test_relevance_falls_with_rho_and_follows_its_prior():
    model = Relevance(prior=0.5, spread=0.05)
    rhos = np.linspace(0.001, 0.999, 200)
    betas = np.array([model.probability(r) for r in rhos])
    assert np.all(np.diff(betas) <= 1e-15)
    assert betas[0] > 0.999 and betas[-1] < 1e-3
    low, high = Relevance(prior=0.1, spread=0.05), Relevance(prior=0.9, spread=0.05)
    assert low.probability(0.15) < model.probability(0.15) < high.probability(0.15)


@pytest.mark.parametrize("prior", [0.0, 1.0, -0.2, 1.5, float("nan"), True])
def test_a_prior_outside_zero_one_is_one_line_naming_its_key_path(prior):
    with pytest.raises(
        ValueError, match=r"^learners\.KF-CR\.relevance_prior: must lie in \(0, 1\)"
    ):
        make_learner("KF-CR", {"relevance_prior": prior})
    with pytest.raises(ParameterError):
        Relevance(prior=prior)


def test_roc_auc_is_the_pairwise_probability_with_ties_halved(rng):
    scores = rng.integers(0, 5, size=60).astype(float)
    labels = rng.integers(0, 2, size=60)
    pos, neg = scores[labels == 1], scores[labels == 0]
    brute = np.mean([(a > b) + 0.5 * (a == b) for a in pos for b in neg])
    assert roc_auc(scores, labels) == pytest.approx(brute)
    assert roc_auc(scores, np.ones(60)) is None


# ---- explaining a correction ---------------------------------------------------------


def _starts(theta, cov):
    from corrections_sim.learning.kalman.filter import SigmaPoints

    return SigmaPoints().points(np.asarray(theta, float), np.asarray(cov, float))


def test_a_correction_toward_a_plan_is_explained_and_a_nudge_is_not(planner, task, rng):
    env, mine, star = task
    model = WaypointCorrection()
    corrected = model.apply(mine.trajectory, star.trajectory)
    book = PlanBook(planner, warm_start=True)
    book.plan(np.zeros(2), env)
    found = explain(book, env, mine.trajectory, corrected, model, _starts([0, 0], np.eye(2)))
    assert found.rho < 0.05
    moved = corrected - mine.trajectory
    row = int(np.argmax(np.linalg.norm(moved, axis=1)))
    nudged = mine.trajectory.copy()
    direction = rng.normal(size=7)
    nudged[row] += np.linalg.norm(moved[row]) * direction / np.linalg.norm(direction)
    other = explain(book, env, mine.trajectory, nudged, model, _starts([0, 0], np.eye(2)))
    assert other.rho > 3 * found.rho and other.rho > 0.2


def test_no_move_is_fully_explained(planner, task):
    env, mine, _ = task
    book = PlanBook(planner)
    found = explain(
        book, env, mine.trajectory, mine.trajectory, WaypointCorrection(), np.zeros((1, 2))
    )
    assert found.rho == 0.0 and found.solves == 0


# ---- learners ------------------------------------------------------------------------


def _context(planner, corrected, alphas=None):
    from corrections_sim.belief import KalmanNoise
    from corrections_sim.learning.base import LearnerContext
    from corrections_sim.learning.kalman.filter import SigmaPoints

    return LearnerContext(
        book=PlanBook(planner, warm_start=True),
        envs=paper_environments(),
        features=FEATURES,
        n_waypoints=planner.config.n_waypoints,
        alphas=alphas,
        rng=np.random.default_rng(0),
        noise=KalmanNoise.isotropic(2, 1e-4, 0.25),
        sigma=SigmaPoints(),
        corrected=corrected,
    )


def test_relevance_aware_kalman_is_kf_c_on_a_relevant_correction_and_still_on_a_nudge(
    planner, task, rng
):
    env, mine, star = task
    belief = Belief(theta=np.zeros(2), cov=np.eye(2))
    corrected = WaypointCorrection().apply(mine.trajectory, star.trajectory)
    phi = feature_counts(corrected, env, FEATURES)
    twin = make_learner("KF-C").update(_context(planner, corrected), belief, env, mine, phi)
    step = make_learner("KF-CR").update(_context(planner, corrected), belief, env, mine, phi)
    assert step.relevance > 0.99 and step.residual < 0.05
    np.testing.assert_allclose(step.belief.theta, twin.belief.theta, atol=0.02)

    user = make_user("distracted", {"fraction": 1.0})
    seen = Situation(mine.trajectory, star.trajectory, env, FEATURES, THETA_STAR)
    outcome = user.perform(seen, rng)
    assert outcome.relevant is False
    step = make_learner("KF-CR").update(
        _context(planner, outcome.corrected), belief, env, mine, outcome.phi_h
    )
    assert step.relevance < 0.01
    assert np.abs(step.belief.theta).sum() < 0.01


def test_without_a_trajectory_the_relevance_is_the_prior(planner, task):
    env, mine, star = task
    belief = Belief(theta=np.zeros(2), cov=np.eye(2))
    phi = feature_counts(star.trajectory, env, FEATURES)
    learner = make_learner("PP-R", {"relevance_prior": 0.3})
    step = learner.update(_context(planner, None, np.array([0.5])), belief, env, mine, phi)
    assert step.relevance == pytest.approx(0.3)
    np.testing.assert_allclose(step.belief.theta, 0.5 * 0.3 * (phi - mine.features))


def test_one_feature_at_a_time_moves_only_the_largest_change(planner, task):
    env, mine, _ = task
    belief = Belief(theta=np.zeros(2), cov=np.eye(2))
    phi = mine.features + np.array([0.3, -1.2])
    step = make_learner("PP-MAX").update(
        _context(planner, None, np.array([0.5])), belief, env, mine, phi
    )
    np.testing.assert_allclose(step.belief.theta, [0.0, -0.6])


# ---- people --------------------------------------------------------------------------


def test_distracted_user_nudges_a_fraction_of_the_time_by_the_same_amount(task):
    env, mine, star = task
    user = make_user("distracted", {"fraction": 0.3})
    seen = Situation(mine.trajectory, star.trajectory, env, FEATURES, THETA_STAR)
    rng = np.random.default_rng(7)
    outcomes = [user.perform(seen, rng) for _ in range(400)]
    labels = np.array([o.relevant for o in outcomes])
    assert abs((~labels).mean() - 0.3) < 0.07
    size = np.linalg.norm(star.trajectory - mine.trajectory, axis=1).max()
    for o in outcomes[:20]:
        moved = np.linalg.norm(o.corrected - mine.trajectory, axis=1)
        assert moved.max() == pytest.approx(size) and np.count_nonzero(moved) == 1
    again = user.perform(seen, np.random.default_rng(7))
    np.testing.assert_array_equal(again.corrected, outcomes[0].corrected)


@pytest.mark.parametrize("fraction", [-0.1, 1.5, "x"])
def test_distracted_fraction_is_checked(fraction):
    with pytest.raises(ValueError, match=r"^user\.fraction: must lie in \[0, 1\]"):
        make_user("distracted", {"fraction": fraction})


def test_a_person_with_own_features_is_scored_on_their_whole_objective(planner, task):
    """Regret is the person's: θ*·Φ over their features (human included) − λS, of the
    robot's plan against the person's own plan."""
    env, mine, _ = task
    person = shared_planner(PlannerConfig(n_starts=4, features=(*FEATURES, "human")))
    theta = np.array([1.0, -1.0, -2.0])
    target = Target.solve(person, theta, [env])
    book = PlanBook(planner)
    regret, _, failed = evaluate(book, target, [env], np.zeros(2))
    star = target.plans[0]
    lam = planner.config.smoothness
    theirs = theta @ feature_counts(mine.trajectory, env, target.features)
    expected = (theta @ star.features - lam * smoothness_cost(star.trajectory)) - (
        theirs - lam * smoothness_cost(mine.trajectory)
    )
    assert failed == 0 and regret == pytest.approx(expected)
    assert regret > 0


# ---- study files ---------------------------------------------------------------------

BASE = {"theta_star": [1.0, -1.0, -2.0], "user_features": ["laptop", "table", "human"]}


def test_study_with_the_persons_features_round_trips():
    settings = schema.parse_study(BASE)
    assert settings.features == FEATURES
    assert settings.user_features == ("laptop", "table", "human")
    assert settings.study.theta_star == (1.0, -1.0)
    assert settings.study.user_theta == (1.0, -1.0, -2.0)
    again = schema.parse_study(settings.as_dict())
    assert again.as_dict() == settings.as_dict()
    plain = schema.parse_study({"theta_star": [1.0, -1.0]})
    assert "user_features" not in plain.as_dict() and plain.study.user_theta == ()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            {"user_features": ["laptop", "table", "nose"]},
            r"^user_features\[2\] = 'nose': unknown feature",
        ),
        (
            {"user_features": ["laptop", "human"], "theta_star": [1.0, -2.0]},
            r"^user_features = \['laptop', 'human'\]: must contain every learner feature "
            r"\(laptop, table\); missing table$",
        ),
        ({"theta_star": [1.0, -1.0]}, r"^theta_star: expected 3 weights for the features"),
        ({"user_features": "human"}, r"^user_features = 'human': expected a non-empty list"),
    ],
)
def test_bad_person_features_are_one_line(change, message):
    with pytest.raises(ValueError, match=message) as info:
        schema.parse_study({**BASE, **change})
    assert "\n" not in str(info.value)


def test_relevance_log_likelihood_is_the_gaussian_when_relevant_and_flat_when_not():
    log_g = np.log(np.array([0.1, 0.5, 2.0, 0.01]))
    current = np.zeros(4)
    assert np.array_equal(ref.relevance_log_likelihood(log_g, current, 1.0), log_g)
    nearly = ref.relevance_log_likelihood(log_g, current, 1e-9)
    assert np.ptp(nearly) < 1e-6
    half = ref.posterior(ref.relevance_log_likelihood(log_g, current, 0.5))
    full = ref.posterior(log_g)
    flat = np.full(4, 0.25)
    assert np.all(np.minimum(full, flat) - 1e-12 <= half) and np.all(
        half <= np.maximum(full, flat) + 1e-12
    )
    with pytest.raises(ValueError, match="relevance"):
        ref.relevance_log_likelihood(log_g, current, 0.0)


def test_labels_and_relevance_reach_the_records():
    """A two-correction study of the distracted user: each record after a correction carries
    the label, and KF-CR's β̂ and ρ."""
    from concurrent.futures import ThreadPoolExecutor

    from corrections_sim.study import runner

    settings = schema.parse_study(
        {
            "theta_star": [1.0, -1.0],
            "runs": 1,
            "iterations": 2,
            "learners": ["KF-C", "KF-CR"],
            "user": {"name": "distracted", "fraction": 0.5},
            "environments": ["s0-t0-l0", "s1-t1-l1", "s2-t2-l2"],
            "warm_start": True,
        }
    )
    with ThreadPoolExecutor(1) as ex:
        result = runner.run(settings, ex, mean_estimate=False)
    after = [r for r in result.records if r["iteration"] > 0]
    assert all(r["relevant"] in (0.0, 1.0) for r in after)
    mine = [r for r in after if r["learner"] == "KF-CR"]
    assert all(0.0 < r["relevance"] <= 1.0 and 0.0 <= r["relevance_residual"] <= 1.0 for r in mine)
    assert all("relevance" not in r for r in after if r["learner"] == "KF-C")
    assert not math.isnan(sum(r["estimate_error"] for r in after))


def test_the_learners_part_of_theta_star_must_be_the_persons():
    """Settings built in code: the learners' θ* is the person's on the learners' features."""
    import dataclasses

    settings = schema.parse_study(BASE)
    wrong = dataclasses.replace(settings.study, theta_star=(1.0, 1.0))
    with pytest.raises(ValueError, match=r"^theta_star: the learners' part \[1.0, 1.0\]"):
        dataclasses.replace(settings, study=wrong)


def test_a_simulated_session_refuses_a_person_with_own_features(tmp_path):
    from corrections_sim.session.log import StudyLog
    from corrections_sim.session.session import Session
    from corrections_sim.session.simulate import simulate

    settings = schema.parse_study({**BASE, "environments": ["s0-t0-l1", "s1-t1-l0"]})
    with StudyLog(tmp_path / "s.sqlite") as log:
        session = Session.start(settings, log, learner="KF-C")
        with pytest.raises(ValueError, match=r"^user_features: a simulated session"):
            simulate(session, settings.study.user, settings.study.theta_star, 1)
        assert log.corrections(session.id) == []


def test_the_laplace_widening_is_finite_for_a_jacobian_across_a_jump(rng):
    """log det(I + t Q JᵀJ / s²) from the singular values of J L / s: the determinant's own
    value where it is well conditioned, and finite and >= 0 for a near rank-one J of norm 1e10
    (a secant across a jump of the planner), where the determinant cancelled to 0."""
    from corrections_sim.learning.relevance.judge import widening

    a = rng.normal(size=(2, 2))
    spread = a @ a.T + 0.1 * np.eye(2)
    jac = rng.normal(size=(70, 2))
    for t in (0.5, 40.0):
        direct = np.linalg.slogdet(np.eye(2) + t * spread @ (jac.T @ jac) / 3.0**2)[1]
        assert np.sum(np.log1p(t * widening(jac, spread, 3.0))) == pytest.approx(direct, rel=1e-10)
    # Near rank one, norm 1e10: against the determinant in exact rational arithmetic.
    from fractions import Fraction

    steep = 1e10 * np.outer(rng.normal(size=70), [1.0, 0.026]) + rng.normal(size=(70, 2))
    j = [[Fraction(v) for v in row] for row in steep.tolist()]
    q = [[Fraction(v) for v in row] for row in spread.tolist()]
    g = [[sum(r[a] * r[b] for r in j) for b in range(2)] for a in range(2)]
    m = [[(a == b) + 40 * sum(q[a][c] * g[c][b] for c in range(2)) for b in range(2)]
         for a in range(2)]  # fmt: skip
    exact = math.log(m[0][0] * m[1][1] - m[0][1] * m[1][0])
    assert np.sum(np.log1p(40.0 * widening(steep, spread, 1.0))) == pytest.approx(exact, rel=1e-9)
    assert widening(np.zeros((70, 3)), np.eye(3), 1.0).tolist() == [0.0, 0.0, 0.0]
