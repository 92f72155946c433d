"""The study loop (paper §6) on a small problem: settings refuse bad input, plans are solved
once per run, regret vanishes at θ*, and PP, KF and AL runs produce the documented records,
improve on an easy setting, and are reproducible from the seed."""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.defaults import DEFAULTS
from corrections_sim.learning.observation import CorrectedPlanFeatures
from corrections_sim.people.users import BiasedUser, NoisyOptimalUser
from corrections_sim.planning.planner import Plan, Planner, PlannerConfig, PlanningError
from corrections_sim.plans.book import PlanBook, Target, TrailBook, evaluate
from corrections_sim.scene.environments import Environment, paper_environments
from corrections_sim.study import schema
from corrections_sim.study.loop import run_learner
from corrections_sim.study.settings import StudySettings

THETA_STAR = (1.0, -1.0)
THETA0 = (0.0, 0.0)
COV0 = ((1.0, 0.0), (0.0, 1.0))
ITERATIONS = 3
ALPHA = 0.1
# Five of the 48 environments: every start, all table positions, every laptop pose.
ENV_NAMES = ("s0-t0-l0", "s0-t2-l1", "s1-t1-l2", "s2-t0-l3", "s3-t0-l0")
COLUMNS = {
    "learner",
    "run",
    "iteration",
    "environment",
    "estimate_error",
    "regret",
    "regret_paper",
    "regret_failures",
    "update_skipped",
    "theta_0",
    "theta_1",
    "cov_00",
    "cov_01",
    "cov_11",
    "nees",
    "nis",
}


#: The built-in learners: every test's settings hold them all, so any can run.
BUILT_IN = ["PP", "KF", "AL", "PP-C", "KF-C", "AL-C", "KF-A", "BP"]


def settings(**overrides) -> StudySettings:
    """Study settings through the schema, as a study file gives them; flat keys such as
    ``correction_model`` are the older files' keys (translated by the schema)."""
    values = dict(
        theta_star=THETA_STAR,
        theta0=THETA0,
        cov0=COV0,
        iterations=ITERATIONS,
        runs=1,
        seed=0,
        learners=BUILT_IN,
        fixed_alpha=ALPHA,
    )
    values.update(overrides)
    return schema.parse_study(values).study


@pytest.fixture(scope="module")
def planner() -> Planner:
    return Planner()


@pytest.fixture(scope="module")
def failing_planner() -> Planner:
    # jit=False: a one-off config builds in a fraction of a second without gcc; one IPOPT
    # iteration never converges, so every solve raises PlanningError.
    return Planner(PlannerConfig(max_iter=1, jit=False))


@pytest.fixture(scope="module")
def envs() -> tuple[Environment, ...]:
    by_name = {e.name: e for e in paper_environments()}
    return tuple(by_name[n] for n in ENV_NAMES)


@pytest.fixture(scope="module")
def target(planner, envs) -> Target:
    return Target.solve(planner, THETA_STAR, envs)


def run(learner, planner, envs, target, seed=0, user=None, s=None):
    s = s or settings()
    return run_learner(
        learner,
        0,
        s,
        planner,
        envs,
        target,
        user or BiasedUser(),
        np.random.default_rng(seed),
        alphas=np.full(s.iterations, ALPHA) if learner == "PP" else None,
    )


@pytest.fixture(scope="module")
def kf_run(planner, envs, target):
    return run("KF", planner, envs, target)


@pytest.fixture(scope="module")
def pp_run(planner, envs, target):
    return run("PP", planner, envs, target)


# --------------------------------------------------------------------------- settings


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"iterations": 0}, "iterations"),
        ({"iterations": -3}, "iterations"),
        ({"runs": 0}, "runs"),
        ({"runs": -1}, "runs"),
        ({"theta0": (0.0, 0.0, 0.0)}, "theta0"),
        ({"theta0": (0.0,)}, "theta0"),
        ({"theta0": (0.0, float("nan"))}, "theta0"),
        ({"cov0": ((1.0, 2.0), (2.0, 1.0))}, "cov0"),  # symmetric, eigenvalues 3 and −1
        ({"cov0": ((1.0, 0.0), (0.0, 0.0))}, "cov0"),  # singular
        ({"cov0": ((1.0, 0.5), (0.0, 1.0))}, "cov0"),  # not symmetric
        ({"cov0": ((1.0, 0.0, 0.0),) * 3}, "cov0"),  # wrong shape
        ({"learners": ("KF", "UKF")}, "learners"),
        ({"learners": ()}, "learners"),
        ({"process_noise": -1e-4}, "process_noise"),
        ({"observation_noise": -0.25}, "observation_noise"),
        ({"observation_noise": 0.0}, "observation_noise"),
        ({"process_noise": float("nan")}, "process_noise"),
        ({"fixed_alpha": 0.0}, "fixed_alpha"),
    ],
)
def test_settings_refuse_bad_values_naming_the_field(overrides, field):
    with pytest.raises(ValueError, match=field):
        settings(**overrides)


def test_settings_build_the_filters_values():
    s = settings(process_noise=1e-3, observation_noise=0.5, runs=4)
    assert s.k == 2
    np.testing.assert_array_equal(s.prior().theta, THETA0)
    np.testing.assert_array_equal(s.prior().cov, np.eye(2))
    np.testing.assert_array_equal(s.noise().process, 1e-3 * np.eye(2))
    np.testing.assert_array_equal(s.noise().observation, 0.5 * np.eye(2))
    assert tuple(s.learners) == tuple(BUILT_IN)
    assert tuple(schema.parse_study({"theta_star": [1, -1]}).study.learners) == DEFAULTS["study"]
    settings(process_noise=0.0)  # preferences exactly constant is allowed


# --------------------------------------------------------------------------- PlanBook


def test_plan_book_solves_each_problem_once(planner, envs):
    book = PlanBook(planner)
    first = book.plan(np.array([0.5, -0.5]), envs[0])
    again = book.plan([0.5, -0.5], envs[0])  # a list with the same values is the same key
    assert again is first
    assert (book.solves, book.failures) == (1, 0)
    book.plan(np.array([0.5, -0.5]), envs[1])
    book.plan(np.array([0.5, -0.4]), envs[0])
    assert book.solves == 3
    # A copy of an environment (equal contents) hits the cache too.
    twin = Environment(
        q_start=envs[0].q_start, q_goal=envs[0].q_goal, laptop=envs[0].laptop, table=envs[0].table
    )
    assert book.plan(np.array([0.5, -0.5]), twin) is first
    assert book.solves == 3


def test_plan_book_starts_from_the_first_solved_of_the_nearest_thetas(planner, envs):
    """The warm start's neighbour, one vectorized search, is the one a θ-by-θ search finds
    (ties on a grid of θ included: the first solved wins)."""
    rng = np.random.default_rng(3)
    thetas = rng.integers(-3, 4, size=(60, 2)) / 2.0  # many equal distances
    plans = {}
    for i, t in enumerate(thetas):
        plan = Plan(np.full((3, 7), float(i)), np.zeros(2), 0.0, "known", 0, 0.0, 1)
        plans.setdefault((t.tobytes(), envs[0].key()), plan)
    book = PlanBook(planner, plans, warm_start=True)
    solved = [(np.frombuffer(key[0]), plan) for key, plan in plans.items()]
    for query in rng.integers(-4, 5, size=(40, 2)) / 2.0 + rng.choice([0.0, 0.25], (40, 2)):
        one_by_one = [float(np.sum((t - query) ** 2)) for t, _ in solved]
        theta, plan = book.nearest(query, envs[0])
        assert plan is solved[int(np.argmin(one_by_one))][1]
        np.testing.assert_array_equal(theta, solved[int(np.argmin(one_by_one))][0])
    assert book.nearest(thetas[0], envs[1]) is None  # no plan in that environment yet
    assert PlanBook(planner, plans).nearest(thetas[0], envs[0]) is None  # no warm starts


def test_trail_books_share_what_the_same_sequence_solved_and_no_more(planner, envs):
    """Warm-started books asked the same new problems in the same order hold the same plans:
    a TrailBook behind another on the same trail takes every plan from it and answers as a
    PlanBook would, to the bit; once its problems differ it solves its own (and still answers as a
    PlanBook asked the same sequence)."""
    asked = [np.array([0.5, -0.5]), np.array([0.6, -0.4]), np.array([0.4, -0.7])]
    memo: dict = {}

    def run(book, thetas):
        return [book.plan(t, envs[0]) for t in thetas]

    first = TrailBook(planner, memo, warm_start=True)
    plain = run(PlanBook(planner, warm_start=True), asked)
    mine = run(first, asked)
    again = TrailBook(planner, memo, warm_start=True)
    theirs = run(again, asked)
    assert (first.solves, first.taken) == (3, 0) and (again.solves, again.taken) == (3, 3)
    for a, b, c in zip(plain, mine, theirs, strict=True):
        np.testing.assert_array_equal(a.trajectory, b.trajectory)
        assert b is c
    other = [*asked[:2], np.array([-0.3, 0.2])]
    apart = TrailBook(planner, memo, warm_start=True)
    got = run(apart, other)
    assert apart.taken == 2 and got[0] is mine[0]
    expected = run(PlanBook(planner, warm_start=True), other)
    np.testing.assert_array_equal(got[2].trajectory, expected[2].trajectory)


def test_plan_book_observe_is_the_memoized_batch_of_features(planner, envs):
    book = PlanBook(planner)
    h = book.observe(envs[2])
    thetas = np.array([[0.0, 0.0], [1.0, -1.0], [0.0, 0.0]])
    out = h(thetas)
    assert out.shape == (3, 2)
    np.testing.assert_array_equal(out[0], book.plan(thetas[0], envs[2]).features)
    np.testing.assert_array_equal(out[0], out[2])
    assert book.solves == 2
    np.testing.assert_array_equal(h(np.array([1.0, -1.0])), out[1:2])  # one θ: (1, k)
    assert book.solves == 2


def test_plan_book_warm_start_reaches_the_cold_optimum_in_fewer_iterations(planner, envs):
    """Warm start from the nearest solved θ: same optimum (tolerance), fewer iterations."""
    cold, warm = PlanBook(planner), PlanBook(planner, warm_start=True)
    for env in envs[:4]:
        warm.plan(np.array([0.6, -0.6]), env)  # the neighbour to start from
        near = np.array([0.65, -0.62])
        a, b = cold.plan(near, env), warm.plan(near, env)
        assert abs(a.reward - b.reward) <= 1e-5 * abs(a.reward)
        assert b.iterations <= a.iterations
    assert warm.solves == 8 and warm.failures == 0


def test_plan_book_memoizes_failures(failing_planner, envs):
    book = PlanBook(failing_planner)
    with pytest.raises(PlanningError, match="no start converged") as first:
        book.plan(np.array([0.0, 0.0]), envs[0])
    assert (book.solves, book.failures) == (1, 1)
    with pytest.raises(PlanningError) as second:
        book.plan(np.array([0.0, 0.0]), envs[0])
    assert second.value is first.value
    assert (book.solves, book.failures) == (1, 1)


# --------------------------------------------------------------------------- evaluate


def test_regret_vanishes_at_theta_star(planner, envs, target):
    book = PlanBook(planner)
    regret, paper, failed = evaluate(book, target, envs, np.array(THETA_STAR))
    lam = planner.config.smoothness
    theta = np.array(THETA_STAR)
    scale = sum(
        abs(theta @ p.features) + lam * np.sum(np.diff(p.trajectory, axis=0) ** 2)
        for p in target.plans
    )
    assert failed == 0
    assert abs(regret) < 1e-6 * scale
    assert abs(paper) < 1e-6 * scale
    # Regret is never meaningfully negative: ξ*(θ*) is the optimum of the full objective.
    assert regret >= -planner.config.tol * scale
    assert book.solves == len(envs)


def test_regret_is_positive_away_from_theta_star(planner, envs, target):
    regret, paper, failed = evaluate(PlanBook(planner), target, envs, np.array(THETA0))
    assert failed == 0
    assert regret > 1.0
    assert paper > regret  # the robot's (0, 0) paths are smoother, which full regret credits


def test_evaluate_counts_failed_environments_instead_of_summing_them(failing_planner, envs, target):
    book = PlanBook(failing_planner)
    assert evaluate(book, target, envs, np.array(THETA0)) == (0.0, 0.0, len(envs))
    assert book.failures == len(envs)


# --------------------------------------------------------------------------- run_learner


@pytest.mark.parametrize("learner", ["KF", "PP"])
def test_records_have_the_documented_columns_and_start_at_the_prior(
    learner, kf_run, pp_run, planner, envs, target
):
    result = {"KF": kf_run, "PP": pp_run}[learner]
    records = result.records
    assert len(records) == ITERATIONS + 1
    assert [r["iteration"] for r in records] == list(range(ITERATIONS + 1))
    for r in records:
        assert set(r) == COLUMNS
        assert r["learner"] == learner and r["run"] == 0
        assert r["regret_failures"] == 0 and r["update_skipped"] == ""
    assert {r["environment"] for r in records[1:]} <= set(ENV_NAMES)

    first = records[0]
    regret0, paper0, _ = evaluate(PlanBook(planner), target, envs, np.array(THETA0))
    assert first["environment"] == ""
    assert (first["theta_0"], first["theta_1"]) == THETA0
    assert (first["cov_00"], first["cov_11"]) == (1.0, 1.0)
    assert first["estimate_error"] == 2.0
    assert first["regret"] == regret0 and first["regret_paper"] == paper0
    assert result.solves > 0


def test_kf_cov_shrinks_and_gains_are_recorded(kf_run):
    records = kf_run.records
    q = settings().filter.process_noise
    for i in range(2):
        cov = [r[f"cov_{i}{i}"] for r in records]
        # Each update can add at most M before it shrinks P.
        assert all(b <= a + q for a, b in zip(cov, cov[1:], strict=False)), cov
        assert cov[-1] < 0.25 * cov[0], cov
    assert kf_run.gains.shape == (ITERATIONS, 2, 2)
    assert np.all(np.isfinite(kf_run.gains))


def test_pp_carries_the_prior_covariance_and_keeps_no_gains(pp_run):
    for r in pp_run.records:
        assert (r["cov_00"], r["cov_11"]) == (1.0, 1.0)
    assert np.all(np.isnan(pp_run.gains))


@pytest.mark.parametrize("learner", ["KF", "PP"])
def test_learners_improve_on_an_easy_setting(learner, kf_run, pp_run):
    """θ* = (+1, −1) from θ̂⁰ = (0, 0): every correction pulls the cup toward the laptop and
    away from the table, so the estimate moves toward θ* and regret falls."""
    records = {"KF": kf_run, "PP": pp_run}[learner].records
    first, last = records[0], records[-1]
    assert last["estimate_error"] < first["estimate_error"]
    assert last["regret"] < first["regret"]
    # The estimate moves in the right direction on both weights.
    assert last["theta_0"] > 0.0 > last["theta_1"]


def test_kf_learns_faster_than_pp_with_a_small_fixed_rate(kf_run, pp_run):
    # Same seed, so both see the same environments (common random numbers).
    assert [r["environment"] for r in kf_run.records] == [r["environment"] for r in pp_run.records]
    assert kf_run.records[-1]["estimate_error"] < pp_run.records[-1]["estimate_error"]


def test_active_learning_picks_environments_deterministically(planner, envs, target):
    a = run("AL", planner, envs, target, seed=0).records
    b = run("AL", planner, envs, target, seed=1).records  # the rng draws nothing AL uses
    assert list(a) == list(b)
    assert len(a) == ITERATIONS + 1
    assert {r["environment"] for r in a[1:]} <= set(ENV_NAMES)
    assert a[-1]["estimate_error"] < a[0]["estimate_error"]


def test_same_seed_same_records(planner, envs, target, kf_run):
    again = run("KF", planner, envs, target, seed=0)
    assert list(again.records) == list(kf_run.records)
    # With a noisy user the generator also draws the observations' noise.
    user = NoisyOptimalUser(noise=0.1)
    a = run("KF", planner, envs, target, seed=5, user=user).records
    b = run("KF", planner, envs, target, seed=5, user=user).records
    assert list(a) == list(b)


def test_different_seed_draws_different_environments(planner, envs, target, kf_run):
    other = run("KF", planner, envs, target, seed=1)
    assert [r["environment"] for r in other.records] != [r["environment"] for r in kf_run.records]


def test_run_learner_refuses_unknown_learner_and_pp_without_rates(planner, envs, target):
    with pytest.raises(ValueError, match="learner"):
        run_learner(
            "UKF", 0, settings(), planner, envs, target, BiasedUser(), np.random.default_rng(0)
        )
    with pytest.raises(ValueError, match="alphas"):
        run_learner(
            "PP", 0, settings(), planner, envs, target, BiasedUser(), np.random.default_rng(0)
        )


# ------------------------------------------------------------------ KF-C, AL-C, calibration


def test_kf_c_with_the_optimal_correction_model_is_the_papers_kf(kf_run, planner, envs, target):
    # C(ξ, ξ*) = ξ*: hₜ(θ) = Φ(ξ*(θ, E)), the paper's observation model, so the same numbers.
    other = run("KF-C", planner, envs, target, s=settings(correction_model="optimal"))
    strip = [{k: v for k, v in r.items() if k != "learner"} for r in other.records]
    assert strip == [{k: v for k, v in r.items() if k != "learner"} for r in kf_run.records]
    np.testing.assert_array_equal(other.gains, kf_run.gains)


def test_kf_c_observes_the_modelled_correction(planner, envs, target):
    # Its h at θ* in an environment is exactly the features of the user's correction there.
    from corrections_sim.planning.features import feature_counts

    env = envs[1]
    book = PlanBook(planner)
    robot = book.plan(np.array(THETA0), env).trajectory
    model = settings().learners["KF-C"].model
    h = CorrectedPlanFeatures(model).observe(book, env, robot, planner.config.features)
    phi = h(np.array([THETA_STAR]))[0]
    user = BiasedUser().model().apply(robot, target.plans[1].trajectory)
    np.testing.assert_allclose(phi, feature_counts(user, env.params(), planner.config.features))
    # And at θ̂ itself the modelled correction changes nothing: hₜ(θ̂) = Φ(ξᵗ).
    np.testing.assert_allclose(h(np.array([THETA0]))[0], book.plan(np.array(THETA0), env).features)


def test_records_carry_calibration(kf_run, pp_run):
    first = kf_run.records[0]
    assert first["nees"] == pytest.approx(2.0)  # θ̂⁰ = 0, θ* = (1, −1), P⁰ = I
    assert first["nis"] is None  # no correction yet
    assert all(r["nis"] > 0 and r["nees"] > 0 for r in kf_run.records[1:])
    assert all(r["nees"] is None and r["nis"] is None for r in pp_run.records)


def test_an_active_learner_runs_as_often_as_the_others_when_the_user_is_random():
    assert settings(runs=5).runs_of("AL-C") == 1
    assert settings(runs=5, user="noisy").runs_of("AL-C") == 5
    assert settings(runs=5, user="noisy").runs_of("AL") == 5
    assert settings(runs=5).runs_of("KF-C") == 5


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        ({"correction_model": "psychic"}, "learners.KF-C.model: unknown correction model"),
        ({"correction_step": 0.0}, r"learners.KF-C.model.step: must lie in \(0, 1\]"),
        ({"correction_waypoints": 11}, "learners.KF-C.model.waypoints: 11 must lie in"),
        ({"correction_model": "deform", "correction_waypoints": 2}, "correction_waypoints"),
        ({"user": "deform", "user_waypoints": 2}, "user_waypoints"),
        ({"user_waypoints": 0}, "user.waypoints: must be >= 1"),
        ({"user": {"name": "biased", "waypoints": 11}}, "user.waypoints: 11 must lie in"),
        ({"learners": {"PP": {}, "KF-C": {"model": {"name": "waypoint", "steps": 1}}}}, "steps"),
        ({"learners": ("PP-C", "KF"), "fixed_alpha": None}, "KF-C"),
    ],
)
def test_bad_correction_settings_are_refused_by_name(overrides, match):
    with pytest.raises(ValueError, match=match):
        settings(**overrides)


def test_kf_a_that_knows_the_whole_change_is_delivered_is_the_papers_kf(kf_run, planner, envs):
    target = Target.solve(planner, THETA_STAR, envs)
    s = settings(attenuation_min=1.0, attenuation_max=1.0, attenuation_points=1)
    other = run("KF-A", planner, envs, target, s=s)
    for a, b in zip(other.records, kf_run.records, strict=True):
        for key in ("estimate_error", "regret", "theta_0", "theta_1", "cov_00", "cov_01", "nees"):
            # The same maths in another order of operations: equal to rounding.
            assert a[key] == pytest.approx(b[key], rel=1e-6, abs=1e-9), key


def test_bp_learns_without_an_innovation_covariance(planner, envs, target):
    records = run("BP", planner, envs, target).records
    assert records[-1]["estimate_error"] < records[0]["estimate_error"]
    assert all(r["nis"] is None for r in records)
    assert all(r["nees"] > 0 for r in records)


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        ({"attenuation_min": 0.0}, "attenuation_min"),
        ({"attenuation_max": 0.01}, "attenuation_max"),
        ({"beta_min": -1.0}, "beta_min"),
        ({"lapse": 1.0}, "lapse"),
    ],
)
def test_bad_remedy_settings_are_refused_by_their_keys(overrides, match):
    with pytest.raises(ValueError, match=match):
        settings(**overrides)


def test_the_mean_estimate_chain_is_the_cold_evaluation_without_warm_starts():
    """Each learner's mean θ̂ᵗ is evaluated in one chain: without ``warm_start`` every θ is
    the cold evaluation it was point by point (a θ met again is not solved again); with it,
    warm from the θ before, here at the cold answer to the solver's tolerance."""
    from corrections_sim.planning.planner import shared_planner
    from corrections_sim.study import runner

    spec = {
        "environments": ["s0-t0-l1", "s1-t1-l0", "s2-t0-l1"],
        "theta_star": [1.0, -1.0],
        "learners": ["KF"],
        "seed": 5,
    }
    thetas = ((0.3, -0.2), (0.35, -0.3), (0.3, -0.2))
    cold = schema.parse_study(spec, name="chain")
    shared = runner.prepare(cold)
    chain = runner.mean_estimate_chain(cold, shared, thetas)
    planner = shared_planner(cold.planner_config())
    for theta, (regret, paper, failed, _) in zip(thetas, chain, strict=True):
        book = PlanBook(planner, shared.prior)
        alone = evaluate(book, shared.target, cold.envs(), np.array(theta))
        assert (regret, paper, failed) == alone
    assert [c[3] for c in chain] == [3, 3, 0]

    warm = schema.parse_study({**spec, "warm_start": True}, name="chain")
    for (regret, *_), (cold_regret, *_) in zip(
        runner.mean_estimate_chain(warm, runner.prepare(warm), thetas), chain, strict=True
    ):
        assert abs(regret - cold_regret) <= 1e-4 * abs(cold_regret)
