"""The Newton warm re-solve (``PlannerConfig.warm = "newton"``) against the reference path.

The fixture ``data/warm_problems.csv`` holds 300 warm problems captured from fig. 4 runs by
``python -m benchmarks.bench_warm --fixture tests/data/warm_problems.csv`` (θ it starts from,
θ, environment); each start is the planner's plan at the first θ.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from corrections_sim.planning import newton
from corrections_sim.planning.planner import Planner, PlannerConfig, feature_counts
from corrections_sim.scene.environments import paper_environments
from corrections_sim.scene.world import Contact

FIXTURE = Path(__file__).parent / "data" / "warm_problems.csv"


def _read_fixture():
    import csv

    with FIXTURE.open() as f:
        rows = list(csv.DictReader(f))
    return [
        (
            np.array([float(r["theta_from_0"]), float(r["theta_from_1"])]),
            np.array([float(r["theta_0"]), float(r["theta_1"])]),
            int(r["env"]),
        )
        for r in rows
    ]


@pytest.fixture(scope="module")
def planners() -> dict[str, Planner]:
    return {w: Planner(PlannerConfig(n_starts=1, warm=w)) for w in ("solver", "newton")}


@pytest.fixture(scope="module")
def solved(planners):
    """Per fixture problem: (θ, env, start, the reference path's plan, Newton's answer)."""
    envs = paper_environments()
    reference, path = planners["solver"], planners["newton"]._newton_path()
    out = []
    for theta_from, theta, e in _read_fixture():
        env = envs[e]
        start = reference.solve(theta_from, env).trajectory
        plan = reference.solve(theta, env, inits=[start])
        found = path.solve(start[1:-1].ravel(), reference._params(theta, env))
        out.append((theta, env, start, plan, found))
    return out


def test_the_fixture_is_a_few_hundred_warm_problems_of_fig4():
    problems = _read_fixture()
    assert len(problems) == 300
    steps = [np.linalg.norm(t - f) for f, t, _ in problems]
    assert 0 < np.median(steps) < 0.2 and max(steps) > 0.5  # small steps and some big ones
    assert {e for _, _, e in problems} <= set(range(48))


def test_newtons_answers_are_the_reference_optimum_or_better(solved, planners):
    reference = planners["solver"]
    accepted = [(t, env, plan, found) for t, env, _, plan, found in solved if found is not None]
    # Measured: 275 of 300 certified, 34 of them by the continuation (the rest are mostly
    # |Δθ| > 0.3). A path that stops
    # certifying (or certifies nothing) fails here rather than only getting slower.
    assert len(accepted) >= 200
    for theta, env, plan, found in accepted:
        traj = np.vstack([env.q_start, found.x.reshape(-1, 7), env.q_goal])
        reward = reference.reward(theta, traj, env)
        assert reward >= plan.reward - 1e-6  # the same optimum (within the solver's tolerance)
        assert reward <= plan.reward + 1e-5  # ... and not another basin
        assert np.max(np.abs(traj - plan.trajectory)) < 1e-3
        # The NLP's objective counts the free waypoints' features (the ends are fixed).
        ends = feature_counts(traj[[0, -1]], env.params(), ("laptop", "table"))
        assert found.objective == pytest.approx(-(reward - theta @ ends), abs=1e-9)
        assert np.allclose(found.features, feature_counts(traj, env.params(), ("laptop", "table")))


def test_the_compiled_loop_is_the_python_loop(solved, planners):
    """``newton.c`` (one C call, W assembled by waypoint) against the Python loop on every
    fixture problem: the same outcome (certified, or why not) and the same answer to round-off
    (measured 2e-13). Some answers need the reduced Hessian (W indefinite, checked in Python)."""
    path = planners["newton"]._newton_path()
    assert path._native is not None
    outcomes = {}
    for theta, env, start, _, found in solved:
        p = planners["newton"]._params(theta, env)
        compiled_outcome, answer = path.attempt(start[1:-1].ravel(), p, continuation=False)
        python_outcome, expected = path._solve_python(start[1:-1].ravel(), p)
        assert compiled_outcome == python_outcome
        outcomes[compiled_outcome] = outcomes.get(compiled_outcome, 0) + 1
        assert (answer is None) == (expected is None)
        if found is None:
            assert answer is None
        if answer is not None:
            assert answer.steps == expected.steps
            assert np.max(np.abs(answer.x - expected.x)) < 1e-10
            assert answer.objective == pytest.approx(expected.objective, abs=1e-10)
            assert np.allclose(answer.features, expected.features, atol=1e-10)
    assert outcomes.keys() == {"certified", "stalled", "gate"}  # 241, 43, 16


def test_the_continuation_answers_big_steps_at_the_reference_optimum(solved, planners):
    """Where the plain attempt gives up (the gate, or no quadratic convergence), the tilted
    continuation walks the start to the new θ in stages. Measured on the fixture: 34 of the 59
    answered, every one within 8.2e-7 of the reference path's reward from the same start (no
    other basin), in 2-16 stages; the rest go to the solver as before."""
    path, reference = planners["newton"]._newton_path(), planners["solver"]
    continued = 0
    for theta, env, start, plan, found in solved:
        if found is None or found.stages == 0:
            continue
        plain, _ = path.attempt(start[1:-1].ravel(), reference._params(theta, env), False)
        assert plain in ("gate", "stalled")
        assert 2 <= found.stages <= newton.MAX_STAGES
        traj = np.vstack([env.q_start, found.x.reshape(-1, 7), env.q_goal])
        assert reference.reward(theta, traj, env) >= plan.reward - 1e-6
        assert np.max(np.abs(traj - plan.trajectory)) < 1e-3
        continued += 1
    assert continued >= 20


def test_the_compiled_loop_assembles_the_nlps_terms(planners):
    """W, ∇f and f assembled by waypoint in C (with the clearances' curvature only where μ is
    nonzero) are the whole NLP's: from the solver's plan of the same θ the loop certifies it
    (steps of 1e-4 rad at most) with the objective the monolithic evaluation gives."""
    planner = planners["newton"]
    path = planner._newton_path()
    env = paper_environments()[7]
    plan = planners["solver"].solve(np.array([0.8, -0.4]), env)
    p = planner._params(np.array([0.8, -0.4]), env)
    outcome, answer = path.attempt(plan.trajectory[1:-1].ravel(), p)
    assert outcome == "certified"
    f, grad, c, _, _ = path.terms(answer.x, p, np.zeros(path.n_c))
    assert answer.objective == pytest.approx(f, abs=1e-12)
    assert np.max(np.abs(answer.x - plan.trajectory[1:-1].ravel())) < 1e-4


def test_every_certified_answer_is_a_strict_local_minimum_of_the_nlp(solved, planners):
    """Checked again from scratch at the answer: feasible, stationary with multipliers >= 0
    on the tight clearances, and no feasible descent along their null space."""
    path = planners["newton"]._newton_path()
    checked = 0
    for theta, env, _, _, found in solved[::10]:
        if found is None:
            continue
        p = planners["newton"]._params(theta, env)
        grad, c, jac_nz = path._first(found.x, p)
        assert np.all(c >= -1e-9)
        assert np.all(found.x >= path.lower) and np.all(found.x <= path.upper)
        tight = np.flatnonzero(c < 1e-7)
        jac = path._jacobian(jac_nz)[tight]
        mu = np.linalg.lstsq(jac.T, grad, rcond=None)[0] if tight.size else np.zeros(0)
        assert np.all(mu >= -1e-9)
        assert np.max(np.abs(grad - jac.T @ mu)) < 1e-6
        _, _, _, _, hess_nz = path.terms(found.x, p, np.bincount(tight, mu, minlength=c.size))
        w = path.hessian(hess_nz)
        if tight.size:
            q, _ = np.linalg.qr(jac.T, mode="complete")
            w = q[:, tight.size :].T @ w @ q[:, tight.size :]
        assert np.linalg.eigvalsh(w).min() > 0
        checked += 1
    assert checked >= 20


def test_the_planner_answers_small_steps_by_newton_and_big_ones_by_the_solver(solved, planners):
    planner = planners["newton"]
    by = {"newton": 0, "fatrop": 0}
    for theta, env, start, plan, found in solved[:40]:
        got = planner.solve(theta, env, inits=[start])
        assert got.solver == ("newton" if found is not None else "fatrop")
        by[got.solver] += 1
        assert got.reward >= plan.reward - 1e-6
        if got.solver == "newton":
            assert got.status == "Newton_Converged" and got.starts == 1
            assert np.allclose(got.trajectory[[0, -1]], [env.q_start, env.q_goal])
    assert by["newton"] > 0 and by["fatrop"] > 0
    # A cold solve never takes the Newton path.
    cold = planner.solve(solved[0][0], solved[0][1])
    assert cold.solver != "newton"


def test_a_newton_answer_that_collides_goes_to_the_solver(solved, planners, monkeypatch):
    planner = Planner(PlannerConfig(n_starts=1, warm="newton"))
    theta, env, start, plan, found = next(s for s in solved if s[4] is not None)
    report = planner._checker.check_trajectory(plan.trajectory, env)
    calls = []

    def colliding(trajectory, environment):
        calls.append(trajectory)
        if len(calls) == 1:  # the Newton answer: pretend MuJoCo found a contact
            hit = Contact(sample=3, time=1.0, body_a="hand", body_b="laptop", depth=1e-3)
            return dataclasses.replace(report, contacts=(hit,))
        return report

    monkeypatch.setattr(planner._checker, "check_trajectory", colliding)
    got = planner.solve(theta, env, inits=[start])
    assert got.solver == "fatrop" and len(calls) >= 2
    assert got.reward == pytest.approx(plan.reward, abs=1e-9)


def test_the_gate_and_a_far_start_leave_the_solve_to_the_solver(planners):
    envs = paper_environments()
    env = envs[5]
    reference = planners["solver"]
    start = reference.solve(np.array([1.0, -1.0]), env).trajectory
    path = planners["newton"]._newton_path()
    far = path.solve(start[1:-1].ravel(), reference._params(np.array([-3.0, 3.0]), env))
    assert far is None
    got = planners["newton"].solve(np.array([-3.0, 3.0]), env, inits=[start])
    assert got.solver == "fatrop"
    assert got.reward == pytest.approx(reference.solve([-3.0, 3.0], env, inits=[start]).reward)


def test_the_start_residual_is_the_gate(solved, planners):
    """``residual`` is small at the reference plan of the same θ, grows with the θ step, and
    Newton is never tried above the gate (the small-step benchmark gates on it too).
    Measured at the plans: median 9e-6, at most 0.037 where fatrop leaves a clearance with
    a multiplier above ACTIVE (its barrier's slack), so not guessed active. Above the gate
    only the continuation answers, and above its stages' reach nothing."""
    path, reference = planners["newton"]._newton_path(), planners["solver"]
    at_plan, steps, residuals = [], [], []
    for (theta_from, _, _), (theta, env, start, plan, found) in list(
        zip(_read_fixture(), solved, strict=True)
    )[::5]:
        p = reference._params(theta, env)
        at_plan.append(path.residual(plan.trajectory[1:-1].ravel(), p))
        residuals.append(path.residual(start[1:-1].ravel(), p))
        steps.append(np.linalg.norm(theta - theta_from))
        if residuals[-1] > newton.GATE:  # only the continuation, and only up to its reach
            assert found is None or found.stages > 0
        if residuals[-1] > newton.STAGE_RESIDUAL * newton.MAX_STAGES:
            assert found is None
    assert max(residuals) > newton.GATE  # the gate's check above ran (4 of these 60)
    assert np.median(at_plan) < 1e-4 and max(at_plan) < 0.1 * newton.GATE
    assert np.corrcoef(steps, residuals)[0, 1] > 0.9  # measured 0.98


def test_the_warm_mode_is_checked_and_named_in_a_study():
    from corrections_sim.figures import learning_study

    with pytest.raises(ValueError, match="warm"):
        PlannerConfig(warm="fast")
    s = learning_study.load_settings("fig4", quick=True, overrides={"set": ["planner.warm=newton"]})
    assert s.planner_config().warm == "newton"
    assert learning_study.load_settings("fig4", quick=True).planner_config().warm == "newton"
    s = learning_study.load_settings("fig4", quick=True, overrides={"set": ["planner.warm=solver"]})
    assert s.planner_config().warm == "solver"
    with pytest.raises(ValueError, match="planner.warm"):
        learning_study.load_settings("fig4", quick=True, overrides={"set": ["planner.warm=fast"]})


def test_the_band_holds_the_whole_hessian():
    """The Hessian's half-bandwidth in the waypoint ordering is 7 (the banded Cholesky relies
    on it; the constructor refuses a wider one)."""
    planner = Planner(PlannerConfig(n_starts=1, warm="newton"))
    path = planner._newton_path()
    env = paper_environments()[0]
    start = planner.solve(np.array([1.0, -1.0]), env).trajectory
    p = planner._params(np.array([1.0, -1.0]), env)
    _, _, _, _, hess_nz = path.terms(start[1:-1].ravel(), p, np.ones(path.n_c))
    w = path.hessian(hess_nz)
    rows, cols = np.nonzero(w)
    assert np.max(np.abs(rows - cols)) == newton.BANDWIDTH
    band = path._band(hess_nz, np.arange(path.n))
    for d in range(newton.BANDWIDTH + 1):
        assert np.array_equal(band[d, : path.n - d], np.diagonal(w, -d))
