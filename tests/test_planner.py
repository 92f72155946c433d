"""The trajectory optimizer ξ*(θ, E): convergence and safety on all 48 environments, the
effect of θ, the reported reward, warm and multi-start solves, and refusal of bad input."""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import (
    Plan,
    Planner,
    PlannerConfig,
    PlanningError,
    build_key,
    check_theta,
    initial_guesses,
    stage_nlp,
)
from corrections_sim.scene import robot
from corrections_sim.scene import world as scene
from corrections_sim.scene.environments import Environment, paper_environments

CONVERGED = {"Solve_Succeeded", "Solved_To_Acceptable_Level"}
NEUTRAL, LAPTOP_LOVER, TABLE_LOVER = (0.0, 0.0), (1.0, -1.0), (-1.0, 1.0)
THETAS = (NEUTRAL, LAPTOP_LOVER, TABLE_LOVER)
N_ENVS = len(paper_environments())


@pytest.fixture(scope="module")
def planner() -> Planner:
    # The first build on a machine compiles for ~30 s; later ones load the cached solver.
    return Planner()


@pytest.fixture(scope="module")
def envs() -> tuple[Environment, ...]:
    return paper_environments()


@pytest.fixture(scope="module")
def plans(planner, envs) -> dict[tuple[tuple[float, float], int], Plan]:
    """Default solves of every (θ, environment) pair, shared by the tests below."""
    return {(theta, i): planner.solve(theta, env) for theta in THETAS for i, env in enumerate(envs)}


def _cup_path(trajectory: np.ndarray) -> np.ndarray:
    return np.array([robot.cup_pose(q)[1] for q in trajectory])  # (T, 3)


@pytest.mark.parametrize("theta", THETAS)
def test_every_environment_converges_to_a_safe_trajectory(planner, envs, plans, theta):
    checker = scene.CollisionChecker()
    lo, hi = robot.joint_limits()
    T = planner.config.n_waypoints
    for i, env in enumerate(envs):
        plan = plans[theta, i]
        assert plan.status in CONVERGED, (env.name, plan.status)
        assert plan.trajectory.shape == (T, robot.N_ARM_JOINTS)
        np.testing.assert_array_equal(plan.trajectory[0], env.q_start)
        np.testing.assert_array_equal(plan.trajectory[-1], env.q_goal)
        assert np.all((plan.trajectory >= lo) & (plan.trajectory <= hi)), env.name
        # denser than the planner's own check (8 samples per segment)
        report = checker.check_trajectory(plan.trajectory, env, substeps=16)
        assert report.collision_free, (env.name, report.contacts[:3])
        assert plan.iterations >= 1 and plan.starts == planner.config.n_starts


def test_reward_is_theta_dot_features_minus_smoothness(planner, envs, plans):
    lam = planner.config.smoothness
    for (theta, i), plan in plans.items():
        env = envs[i]
        phi = feature_counts(plan.trajectory, env.params(), planner.config.features)
        smooth = np.sum((plan.trajectory[1:] - plan.trajectory[:-1]) ** 2)
        expected = float(np.dot(theta, phi) - lam * smooth)
        np.testing.assert_allclose(plan.features, phi, rtol=0, atol=1e-12)
        assert plan.reward == pytest.approx(expected, rel=1e-12, abs=1e-12)
        assert planner.reward(theta, plan.trajectory, env) == pytest.approx(expected, abs=1e-12)


def test_laptop_weight_changes_the_path(envs, plans):
    deviations = np.array(
        [
            np.linalg.norm(
                _cup_path(plans[LAPTOP_LOVER, i].trajectory)
                - _cup_path(plans[NEUTRAL, i].trajectory),
                axis=1,
            ).max()
            for i in range(len(envs))
        ]
    )
    assert np.mean(deviations > 0.05) >= 0.8, np.round(deviations, 3)
    for i, env in enumerate(envs):
        neutral, lover = plans[NEUTRAL, i].features, plans[LAPTOP_LOVER, i].features
        assert lover[0] > neutral[0], (env.name, neutral, lover)  # more over the laptop
        assert lover[1] < neutral[1], (env.name, neutral, lover)  # less near the table


def test_table_weight_pulls_the_path_down_to_the_table(envs, plans):
    for i, env in enumerate(envs):
        neutral, lover = plans[NEUTRAL, i].features, plans[TABLE_LOVER, i].features
        assert lover[1] > neutral[1], (env.name, neutral, lover)


def test_each_optimum_beats_the_others_plans_under_its_own_theta(planner, envs, plans):
    """ξ*(θ) scores at least as well under θ as ξ*(θ') does: a local check of optimality."""
    worse = 0
    for i, env in enumerate(envs):
        for theta in THETAS:
            own = plans[theta, i].reward
            others = [planner.reward(theta, plans[t, i].trajectory, env) for t in THETAS]
            worse += own < max(others) - 1e-6
    # Local optima may rarely lose to another θ's plan; most must not.
    assert worse <= 0.05 * len(envs) * len(THETAS)


def test_warm_start_from_the_solution_returns_the_same_optimum(planner, envs, plans):
    for i in range(0, N_ENVS, 4):
        plan = plans[LAPTOP_LOVER, i]
        warm = planner.solve(LAPTOP_LOVER, envs[i], inits=[plan.trajectory])
        # Answered by the default warm path's Newton steps (certified), not the solver.
        assert warm.status == "Newton_Converged" and warm.solver == "newton"
        assert warm.starts == 1
        assert warm.reward == pytest.approx(plan.reward, abs=1e-6)
        np.testing.assert_allclose(warm.trajectory, plan.trajectory, atol=1e-3)


def test_default_multi_start_is_no_worse_than_a_single_start(planner, envs, plans):
    T = planner.config.n_waypoints
    for theta in (LAPTOP_LOVER, TABLE_LOVER):
        for i in range(0, N_ENVS, 3):
            single = planner.solve(theta, envs[i], inits=initial_guesses(envs[i], T, 1))
            assert single.starts == 1
            assert plans[theta, i].reward >= single.reward - 1e-9


def test_solves_are_deterministic(planner, envs, plans):
    again = planner.solve(LAPTOP_LOVER, envs[5])
    np.testing.assert_array_equal(again.trajectory, plans[LAPTOP_LOVER, 5].trajectory)


def test_initial_guesses_join_start_and_goal_within_limits(planner, envs):
    lo, hi = robot.joint_limits()
    T = planner.config.n_waypoints
    env = envs[7]
    guesses = initial_guesses(env, T, 4)
    assert len(guesses) == 4
    # bends of the straight line: at most 0.45 rad from it anywhere
    s = np.linspace(0.0, 1.0, T)[:, None]
    line = (1 - s) * env.q_start + s * env.q_goal
    assert all(np.abs(g - line).max() <= 0.45 + 1e-12 for g in guesses)
    for guess in guesses:
        assert guess.shape == (T, robot.N_ARM_JOINTS)
        np.testing.assert_allclose(guess[0], env.q_start, atol=1e-12)
        np.testing.assert_allclose(guess[-1], env.q_goal, atol=1e-12)
        assert np.all((guess >= lo) & (guess <= hi))
    assert not np.allclose(guesses[1], guesses[0])


@pytest.mark.parametrize(
    "theta", [(1.0,), (1.0, 2.0, 3.0), np.ones((2, 1)), (np.nan, 0.0), (0.0, np.inf)]
)
def test_bad_theta_raises_naming_theta(planner, envs, theta):
    with pytest.raises(ValueError, match="theta"):
        planner.solve(theta, envs[0])
    with pytest.raises(ValueError, match="theta"):
        check_theta(theta, 2)


def test_wrong_init_shape_raises(planner, envs):
    with pytest.raises(ValueError, match="inits"):
        planner.solve(NEUTRAL, envs[0], inits=[np.zeros((5, robot.N_ARM_JOINTS))])


def test_unconverged_nlp_raises_with_the_status(envs):
    # jit=False: a one-off config builds in a fraction of a second without gcc
    planner = Planner(PlannerConfig(max_iter=1, jit=False))
    with pytest.raises(PlanningError, match="Maximum_Iterations_Exceeded") as info:
        planner.solve(LAPTOP_LOVER, envs[0])
    assert envs[0].name in str(info.value)


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"smoothness": 0.0}, "smoothness"),
        ({"smoothness": -1.0}, "smoothness"),
        ({"smoothness": float("nan")}, "smoothness"),
        ({"smoothness": float("inf")}, "smoothness"),
        ({"n_waypoints": 2}, "n_waypoints"),
        ({"n_waypoints": 0}, "n_waypoints"),
        ({"features": ("laptop", "sofa")}, "features"),
        ({"features": ()}, "features"),
        ({"features": ("table", "table")}, "features"),
        ({"n_starts": 0}, "n_starts"),
        ({"max_iter": 0}, "max_iter"),
        ({"solver": "snopt"}, "solver = 'snopt'"),
        ({"solver": "fatrop", "n_waypoints": 3}, "n_waypoints"),
        ({"tol": -1e-6}, "tol"),
    ],
)
def test_planner_config_refuses_bad_values(changes, field):
    with pytest.raises(ValueError, match=field):
        PlannerConfig(**changes)


def test_build_key_tracks_what_shapes_the_compiled_library():
    base = PlannerConfig()
    assert build_key(base) == build_key(PlannerConfig())
    keys = {
        build_key(dataclasses.replace(base, **change))
        for change in (
            {},
            {"smoothness": 10.0},
            {"n_waypoints": 10},
            {"features": ("laptop", "table", "coffee")},
            {"solver": "ipopt"},
        )
    }
    assert len(keys) == 5
    # solver options are given when the library is loaded: no rebuild for them
    for change in ({"max_iter": 100}, {"tol": 1e-5}, {"n_starts": 1}, {"jit": False}):
        assert build_key(dataclasses.replace(base, **change)) == build_key(base)


# --- the fatrop path against the IPOPT path ---------------------------------------------------


@pytest.fixture(scope="module")
def one_start() -> dict[str, Planner]:
    """Both solvers at figs. 4-5's single start."""
    return {s: Planner(PlannerConfig(n_starts=1, solver=s)) for s in ("fatrop", "ipopt")}


def test_stage_form_is_the_waypoint_form(rng):
    """Same objective and clearances at w(x); the step constraints vanish there."""
    cfg = PlannerConfig(jit=False)
    planner = Planner(dataclasses.replace(cfg, solver="ipopt"))
    waypoint, _ = Planner._nlp(cfg)
    stages = stage_nlp(cfg)
    f_way = ca.Function("f", [waypoint["x"], waypoint["p"]], [waypoint["f"], waypoint["g"]])
    f_stage = ca.Function("f", [stages["x"], stages["p"]], [stages["f"], stages["g"]])
    J, n = robot.N_ARM_JOINTS, cfg.n_waypoints - 2
    for _ in range(5):
        x, p = rng.normal(size=n * J), rng.normal(size=waypoint["p"].numel())
        w = planner._to_stages(x)
        np.testing.assert_array_equal(planner._from_stages(w), x)
        fw, gw = (np.array(v).ravel() for v in f_way(x, p))
        fs, gs = (np.array(v).ravel() for v in f_stage(w, p))
        assert fs[0] == pytest.approx(fw[0], rel=1e-12, abs=1e-9)
        steps = gs[: (J + 2) * (n - 1)].reshape(n - 1, J + 2)
        np.testing.assert_allclose(steps[:, :J], 0.0, atol=1e-12)
        clearances = np.concatenate([steps[:, J:].ravel(), gs[(J + 2) * (n - 1) :]])
        np.testing.assert_allclose(clearances, gw, rtol=1e-12, atol=1e-12)


def test_fatrop_finds_ipopts_optima(envs, one_start):
    """From the same start both solvers converge to the same local optimum (up to rare
    exceptions where they take different basins)."""
    rng = np.random.default_rng(11)
    same = 0
    for theta, i in zip(rng.uniform(-1.5, 1.5, (24, 2)), rng.integers(0, N_ENVS, 24), strict=True):
        fat, ipo = (one_start[s].solve(theta, envs[i]) for s in ("fatrop", "ipopt"))
        assert fat.solver == "fatrop" and ipo.solver == "ipopt"
        # Compare the optimal values: the optimum is so flat (the arm's redundancy, features
        # traded against smoothness) that points within the tolerance differ by ~0.02 in Φ.
        same += fat.reward == pytest.approx(ipo.reward, rel=1e-5, abs=1e-6)
    assert same >= 22


#: The issue's off-grid problems where one straight-line start found a worse basin (or none):
#: θ, environment, best reward of 30 random restarts (None: the old single start failed).
OFF_GRID = (
    ((-1.571, 1.048), "s1-t1-l3", -7.763),
    ((-1.293, 0.757), "s0-t1-l3", -11.120),
    ((-1.8748, 1.8223), "s2-t1-l1", None),
)


@pytest.mark.parametrize(("theta", "name", "best"), OFF_GRID)
def test_off_grid_problems_reach_the_restarts_best(envs, theta, name, best):
    """At figs. 4-5's settings (4 starts)."""
    env = next(e for e in envs if e.name == name)
    plan = Planner(PlannerConfig(n_starts=4)).solve(theta, env)
    assert plan.status in CONVERGED
    if best is not None:
        assert plan.reward >= best - 0.01 * abs(best)


def test_fatrop_failure_falls_back_to_ipopt(envs, one_start, monkeypatch):
    fat = Planner(PlannerConfig(n_starts=1))
    expected = one_start["ipopt"].solve(LAPTOP_LOVER, envs[2])
    monkeypatch.setattr(fat, "_fatrop_starts", lambda starts, p, env: (None, ["fatrop:1"]))
    plan = fat.solve(LAPTOP_LOVER, envs[2])
    assert plan.solver == "ipopt"
    np.testing.assert_array_equal(plan.trajectory, expected.trajectory)


def test_a_failure_names_both_solvers_statuses_on_one_line(envs):
    planner = Planner(PlannerConfig(max_iter=1, jit=False))
    with pytest.raises(PlanningError) as info:
        planner.solve(LAPTOP_LOVER, envs[0])
    message = str(info.value)
    assert "\n" not in message
    assert "fatrop:" in message and "Maximum_Iterations_Exceeded" in message


def _random_bends(env, count: int, rng: np.random.Generator) -> list[np.ndarray]:
    """The straight line and ``count - 1`` smooth random bends of it (3 sine modes per
    joint, 0.4 rad std for the first), clipped to the limits: the restarts that judge a
    cold solve."""
    s = np.linspace(0.0, 1.0, 12)[:, None]
    line = (1 - s) * env.q_start + s * env.q_goal
    lo, hi = robot.joint_limits()
    modes = np.arange(1, 4)
    bends = [line]
    for _ in range(count - 1):
        coeffs = rng.normal(0.0, 0.4 / modes[:, None], (3, robot.N_ARM_JOINTS))
        bends.append(np.clip(line + np.sin(np.pi * s * modes) @ coeffs, lo, hi))
    return bends


@pytest.mark.parametrize(
    ("theta", "name"),
    [((-1.61, 0.98), "s3-t2-l1"), ((-1.47, 1.19, -0.79), "s3-t1-l1")],
)
def test_seven_starts_reach_the_restarts_best_where_theta_laptop_is_below_zero_below_theta_table(
    envs, theta, name
):
    """Two of the misses of the first four guesses (θ_laptop < 0 < θ_table, k = 2 and 3):
    the three deep bumps reach the best of 30 random restarts within 1%."""
    features = ("laptop", "table", "coffee")[: len(theta)]
    env = next(e for e in envs if e.name == name)
    one = Planner(PlannerConfig(features=features, n_starts=1))
    best = one.solve(theta, env, inits=_random_bends(env, 30, np.random.default_rng(3))).reward
    four = Planner(PlannerConfig(features=features, n_starts=4)).solve(theta, env).reward
    seven = Planner(PlannerConfig(features=features, n_starts=7)).solve(theta, env).reward
    assert four < best - 0.01 * abs(best)  # the miss the deep bumps were added for
    assert seven >= best - 0.01 * abs(best)
    assert len(initial_guesses(env, 12, 7)) == 7
    np.testing.assert_array_equal(initial_guesses(env, 12, 7)[:4], initial_guesses(env, 12, 4))


def _build_slowly(path, log):
    """A build that takes a while and says each time it runs (for the race below)."""
    import time

    with open(log, "a") as f:
        f.write("built\n")
    time.sleep(0.5)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("library")
    tmp.replace(path)


def _race(path, log, barrier):
    from corrections_sim.planning.compiled import build_once

    barrier.wait()
    build_once(path, lambda target: _build_slowly(target, log))
    return path.read_text()


def test_two_processes_build_a_cached_library_once_and_both_load_it(tmp_path):
    """Two test workers on a fresh machine ask for the same library at once: one builds, the
    other waits and loads the finished file (never half of it, never a second gcc)."""
    import multiprocessing

    context = multiprocessing.get_context("spawn")
    path, log = tmp_path / "cache" / "lib.so", tmp_path / "log"
    with context.Manager() as manager, context.Pool(2) as pool:
        got = pool.starmap(_race, [(path, log, manager.Barrier(2))] * 2)
    assert got == ["library", "library"]
    assert log.read_text() == "built\n"
