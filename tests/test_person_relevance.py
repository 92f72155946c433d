"""Relevance judged across a person's corrections (issue 38): KF-CRP's belief over the person
(rate of relevant corrections, precision of their residual), its judgement of a correction
against the belief over θ, and the exact posterior of its model on a grid."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, stats
from test_relevance import _context

from corrections_sim.belief import Belief
from corrections_sim.learning.base import make_learner
from corrections_sim.learning.exact import bayes as ref
from corrections_sim.learning.kalman.filter import SigmaPoints
from corrections_sim.learning.relevance.judge import judge
from corrections_sim.learning.relevance.state import PersonBelief
from corrections_sim.people.corrections import WaypointCorrection
from corrections_sim.people.users import Situation, make_user
from corrections_sim.planning.features import feature_counts
from corrections_sim.plans.book import PlanBook
from corrections_sim.scene.environments import paper_environments

FEATURES = ("laptop", "table")
THETA_STAR = np.array([1.0, -1.0])


@pytest.fixture(scope="module")
def task(planner):
    env = paper_environments()[5]
    return env, planner.solve(np.zeros(2), env), planner.solve(THETA_STAR, env)


# ---- the belief over the person ------------------------------------------------------------


def test_the_person_belief_learns_rate_and_precision_exactly_on_its_grid():
    prior = make_learner("KF-CRP").person()
    assert prior.rate_mean == pytest.approx(0.5, abs=1e-9)
    assert prior.prior_precision == pytest.approx(400.0, rel=0.05)  # E[τ] = 1 / 0.05²
    taus = prior.taus
    f1 = lambda rho: 0.5 * np.log(2 * taus / np.pi) - 0.5 * taus * rho**2  # noqa: E731
    # A precise relevant correction (ρ* = 0.01) raises E[τ] and the rate ...
    beta, after = prior.update(f1(0.01), np.full(taus.size, np.log(1e-3)))
    assert beta > 0.99 and after.precision > prior.precision and after.rate_mean > 0.5
    # ... a nudge (ρ* = 0.9, likely irrelevant) lowers the rate and leaves τ nearly alone.
    beta, nudged = after.update(f1(0.9), np.full(taus.size, np.log(3.0)))
    assert beta < 1e-3 and nudged.rate_mean < after.rate_mean
    assert nudged.precision == pytest.approx(after.precision, rel=0.01)
    # The update is Bayes' rule on the grid: β̂ is the mixture's posterior weight.
    w = np.exp(after.log_w) / np.exp(after.log_w).sum()
    on = (w * np.exp(f1(0.9))[:, None] * after.rates[None, :]).sum()
    off = (w * 3.0 * (1 - after.rates)[None, :]).sum()
    assert beta == pytest.approx(on / (on + off), rel=1e-9)
    with pytest.raises(ValueError, match="PersonBelief.rate: must be a finite number > 0"):
        PersonBelief.prior(1.0, 0.0, 1.0, 1.0)


@pytest.mark.parametrize(
    "params, key",
    [
        ({"relevance_spread": 0.0}, "relevance_spread"),
        ({"relevance_spread": -1.0}, "relevance_spread"),
        ({"spread_count": 0.0}, "spread_count"),
        ({"relevance_count": float("nan")}, "relevance_count"),
        ({"relevance_prior": 1.0}, "relevance_prior"),
        ({"noise": "learnt"}, "noise"),
    ],
)
def test_bad_parameters_are_one_line_naming_the_key(params, key):
    with pytest.raises(ValueError) as info:
        make_learner("KF-CRP", params)
    message = str(info.value)
    assert f"learners.KF-CRP.{key}" in message and "\n" not in message


def test_the_grid_keeps_the_priors_means_and_spreads_its_nodes_by_probability():
    person = PersonBelief.prior(2.0, 0.01, 3.0, 1.0, tau_points=64, rate_points=50)
    assert person.precision == pytest.approx(200.0, rel=1e-9)  # E[τ] = shape / rate
    assert person.rate_mean == pytest.approx(0.75, rel=1e-9)  # E[r] = a / (a + b)
    edges = stats.gamma(2.0, scale=100.0).ppf(np.arange(65) / 64)
    assert np.all((edges[:-1] < person.taus) & (person.taus < edges[1:]))


# ---- judging a correction ----------------------------------------------------------------


def _judge(book, task, corrected, mean=(0.0, 0.0), cov=((1.0, 0.0), (0.0, 1.0))):
    """``corrected`` judged under N(mean, cov), a new person (τ's prior mean 400) and a
    scatter of irrelevant explanations with a core and a tail around θ̂ = 0."""
    env, mine, _ = task
    return judge(
        book,
        env,
        mine.trajectory,
        corrected,
        WaypointCorrection(),
        np.array(mean, float),
        np.array(cov, float),
        SigmaPoints().points(np.zeros(2), np.eye(2)),
        person=PersonBelief.prior(1.0, 1.0 / 400.0, 1.0, 1.0),
        scatter=[(0.8, np.eye(2)), (0.2, 25.0 * np.eye(2))],
        scatter_center=np.zeros(2),
    )


def test_a_correction_the_belief_explains_is_relevant_and_a_nudge_is_not(planner, task, rng):
    env, mine, star = task
    book = PlanBook(planner, warm_start=True)
    corrected = WaypointCorrection().apply(mine.trajectory, star.trajectory)
    found = _judge(book, task, corrected)
    assert found.relevance > 0.99 and found.rho < 0.05 and found.rho_belief < 0.1
    assert found.solves <= 5 + 12 + 6 + 2 * 3  # starts, ρ*, the belief, W's two parts

    user = make_user("distracted", {"fraction": 1.0})
    nudge = user.perform(
        Situation(mine.trajectory, star.trajectory, env, FEATURES, THETA_STAR), rng
    )
    assert _judge(book, task, nudge.corrected).relevance < 0.01


def test_the_same_correction_is_doubted_where_the_belief_rules_its_explanation_out(planner, task):
    """Explained exactly by θ* = (1, −1): believed under N(0, I), not under a belief
    concentrated at (−2, 2), though ρ* is the same."""
    _, mine, star = task
    corrected = WaypointCorrection().apply(mine.trajectory, star.trajectory)
    near = _judge(PlanBook(planner), task, corrected)
    far = _judge(PlanBook(planner), task, corrected, (-2.0, 2.0), ((0.01, 0.0), (0.0, 0.01)))
    assert far.rho == pytest.approx(near.rho, abs=0.02)
    assert near.log_relevant - far.log_relevant > 10.0
    assert far.relevance < near.relevance


# ---- the learner --------------------------------------------------------------------------


def test_kf_crp_is_kf_c_on_a_relevant_correction_and_learns_the_person(planner, task):
    env, mine, star = task
    learner = make_learner("KF-CRP")
    belief = learner.initial(Belief(theta=np.zeros(2), cov=np.eye(2)), None)
    corrected = WaypointCorrection().apply(mine.trajectory, star.trajectory)
    phi = feature_counts(corrected, env, FEATURES)
    twin = make_learner("KF-C").update(_context(planner, corrected), belief, env, mine, phi)
    step = learner.update(_context(planner, corrected), belief, env, mine, phi)
    assert step.relevance > 0.99
    np.testing.assert_allclose(step.belief.theta, twin.belief.theta, atol=0.02)
    assert step.belief.state.person.rate_mean > belief.state.person.rate_mean
    assert step.belief.state.person.precision > belief.state.person.precision


def test_kf_crp_does_not_move_on_a_nudge_and_lowers_the_persons_rate(planner, task, rng):
    env, mine, star = task
    learner = make_learner("KF-CRP")
    belief = learner.initial(Belief(theta=np.zeros(2), cov=np.eye(2)), None)
    user = make_user("distracted", {"fraction": 1.0})
    seen = Situation(mine.trajectory, star.trajectory, env, FEATURES, THETA_STAR)
    outcome = user.perform(seen, rng)
    step = learner.update(_context(planner, outcome.corrected), belief, env, mine, outcome.phi_h)
    assert step.relevance < 0.01 and np.abs(step.belief.theta).sum() < 0.01
    assert step.belief.state.person.rate_mean < 0.4


def test_without_a_trajectory_kf_crp_uses_the_persons_rate(planner, task):
    env, mine, star = task
    learner = make_learner("KF-CRP", {"relevance_prior": 0.3})
    belief = learner.initial(Belief(theta=np.zeros(2), cov=np.eye(2)), None)
    phi = feature_counts(star.trajectory, env, FEATURES)
    step = learner.update(_context(planner, None), belief, env, mine, phi)
    assert step.relevance == pytest.approx(0.3) and step.residual is None
    assert step.belief.state.person == belief.state.person  # nothing was judged, nothing learnt


# ---- the exact posterior of its model ------------------------------------------------------


def _grid_problem(points=41):
    grid = ref.Grid((-3.0, -3.0), (3.0, 3.0), points)
    thetas = grid.thetas()
    log_prior = ref.gaussian_log_prior(thetas, Belief(theta=np.zeros(2), cov=np.eye(2)))
    return grid, thetas, log_prior


def test_the_exact_posterior_is_the_gaussian_one_when_every_correction_is_certainly_relevant():
    """ρ(θ) = 0 everywhere and r's prior at 1: only the features inform θ, as KF-C's."""
    _, thetas, log_prior = _grid_problem()
    post = ref.PersonPosterior.prior(
        thetas, log_prior, PersonBelief.prior(1.0, 1.0 / 400.0, 1e6, 1e-6, tau_points=8)
    )
    h = thetas @ np.array([[1.0, 0.2], [0.0, 1.0]])  # a linear h(θ)
    z = np.array([0.7, -0.4])
    log_g = ref.gaussian_log_likelihood(z, h, 0.25 * np.eye(2))
    beta = post.correct(log_g, np.zeros(len(thetas)), 0.0, 400.0, math.log(1e-12))
    assert beta == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(post.theta_weights(), ref.posterior(log_prior + log_g), atol=1e-9)


def test_a_correction_no_theta_explains_leaves_theta_alone_and_lowers_the_rate():
    _, thetas, log_prior = _grid_problem()
    post = ref.PersonPosterior.prior(
        thetas, log_prior, PersonBelief.prior(1.0, 1.0 / 400.0, 1.0, 1.0, tau_points=8)
    )
    before = post.theta_weights()
    log_g = ref.gaussian_log_likelihood(np.array([2.0, 2.0]), thetas, 0.25 * np.eye(2))
    beta = post.correct(log_g, np.full(len(thetas), 0.9), 0.9, 400.0, math.log(3.0))
    assert beta < 1e-4  # f₁(0.9) at τ's smallest node, 26, against f₀ = 3
    np.testing.assert_allclose(post.theta_weights(), before, atol=1e-6)
    assert post.rate_mean() == pytest.approx(1.0 / 3.0, abs=1e-3)  # Beta(1, 2)


def test_the_exact_relevance_is_the_mixture_integrated_by_quadrature():
    """One correction, θ integrated on the grid and r, τ by scipy: the grid's β̂."""
    grid, thetas, log_prior = _grid_problem(21)
    person = PersonBelief.prior(2.0, 2.0 / 400.0, 2.0, 3.0, tau_points=256, rate_points=200)
    post = ref.PersonPosterior.prior(thetas, log_prior, person)
    rho = 0.05 + 0.05 * np.linalg.norm(thetas - np.array([1.0, -1.0]), axis=1)
    log_g = ref.gaussian_log_likelihood(np.array([1.0, -1.0]), thetas, np.eye(2))
    log_f0 = math.log(0.5)
    beta = post.correct(log_g, rho, 0.05, 300.0, log_f0)

    w = ref.posterior(log_prior)
    c = float(w @ np.exp(log_g))
    place = float(w @ (np.exp(log_g) * np.exp(-150.0 * (rho**2 - 0.05**2))))

    def f1(tau):
        return np.sqrt(2 * tau / np.pi) * np.exp(-0.5 * tau * 0.05**2)

    gamma = stats.gamma(2.0, scale=200.0)
    on = integrate.quad(lambda t: f1(t) * gamma.pdf(t), 0, np.inf, limit=200)[0] * place * 0.4
    off = c * 0.5 * 0.6  # E[r] = 2/5
    assert beta == pytest.approx(on / (on + off), abs=5e-3)


def test_the_irrelevant_place_is_one_where_every_theta_explains_as_well():
    _, thetas, _ = _grid_problem(21)
    mixture = [(1.0, np.eye(2))]
    flat = ref.irrelevant_place(thetas, np.full(len(thetas), 0.2), 0.2, np.zeros(2), mixture, 400)
    assert flat == pytest.approx(0.0, abs=1e-12)
    # Explained only near (2, 2): likelier under a scatter around (2, 2) than around (−2, −2).
    rho = 0.05 + 0.2 * np.linalg.norm(thetas - 2.0, axis=1)
    near = ref.irrelevant_place(thetas, rho, 0.05, np.full(2, 2.0), mixture, 400)
    far = ref.irrelevant_place(thetas, rho, 0.05, np.full(2, -2.0), mixture, 400)
    assert far < near <= 1e-12
