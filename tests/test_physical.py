"""Physical corrections: the arm under impedance, what it senses, how a push becomes a
correction, the simulated physical person and online learning (issue 28)."""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.components import ParameterError
from corrections_sim.people import physical
from corrections_sim.people.corrections import deformation_correction, held_deformation
from corrections_sim.people.users import Situation, make_user
from corrections_sim.planning.features import feature_counts
from corrections_sim.scene import dynamics
from corrections_sim.scene.environments import paper_environments

FEATURES = ("laptop", "table")
THETA_STAR = np.array([1.0, -1.0])


@pytest.fixture(scope="module")
def task(planner):
    """The robot's plan at θ̂ = 0 and the person's at θ* in one paper environment."""
    env = paper_environments()[3]
    mine = planner.solve(np.zeros(2), env)
    star = planner.solve(THETA_STAR, env)
    return Situation(mine.trajectory, star.trajectory, env, FEATURES, THETA_STAR)


def test_model_has_the_panda_actuation():
    model = dynamics.dynamics_model()
    assert model.nu == 7 and model.opt.timestep == pytest.approx(1e-3)
    assert np.allclose(model.jnt_actfrcrange[:, 1], dynamics.TORQUE_LIMITS)
    assert np.allclose(model.dof_armature, dynamics.ARMATURE)


def test_tracks_its_plan_within_a_centimetre_without_a_push(task):
    reference = dynamics.TimedTrajectory(task.robot, 5.0)
    sim = dynamics.ArmSimulation(task.env)
    sim.reset(task.robot[0])
    chunks = [sim.advance(reference, 50) for _ in range(100)]
    times = np.concatenate([c.times for c in chunks])
    cup = np.vstack([c.cup for c in chunks])
    planned, _ = dynamics.cup_kinematics(reference.at(times)[0])
    gap = np.linalg.norm(cup - planned, axis=1)
    assert gap.max() < 0.01
    # Nothing pushes: what the robot senses is small against a push's torques (≥ 5 N·m).
    assert np.abs(np.vstack([c.tau_sensed for c in chunks])).max() < 0.5


def test_sensed_torque_matches_the_applied_push(task):
    reference = dynamics.TimedTrajectory(task.robot, 5.0)
    sim = dynamics.ArmSimulation(task.env)
    sim.reset(task.robot[0])
    sim.advance(reference, 1000)
    push = [sim.advance(reference, 10, np.array([0.0, 15.0, -10.0])) for _ in range(80)]
    sensed = np.vstack([c.tau_sensed for c in push])[100:]  # past the filter's rise
    applied = np.vstack([c.tau_applied for c in push])[100:]
    relative = np.sqrt(np.mean((sensed - applied) ** 2)) / np.sqrt(np.mean(applied**2))
    assert relative < 0.10
    assert np.abs(applied).max() > 5.0


def test_held_deformation_of_one_waypoint_is_the_deform_model(rng):
    robot = rng.normal(size=(12, 7))
    held = np.zeros_like(robot)
    held[5] = rng.normal(size=7) * 0.2
    intended = robot.copy()
    intended[5] += held[5]
    assert np.allclose(held_deformation(robot, held), deformation_correction(robot, intended))
    # Start and goal never move; several held waypoints are fitted in the least-squares sense.
    held[6] = held[5]
    deformed = held_deformation(robot, held)
    assert np.allclose(deformed[[0, -1]], robot[[0, -1]])
    assert np.linalg.norm(deformed[5:7] - robot[5:7] - held[5:7]) < np.linalg.norm(held[5:7])


def test_a_push_teaches_the_right_direction(task, rng):
    person = make_user("physical")
    outcome = person.perform(task, rng)
    change = outcome.phi_h - feature_counts(task.robot, task.env, FEATURES)
    # The perceptron's step θ̂ += α (Φ_H − Φ_R) moves toward θ* from θ̂ = 0.
    assert change @ THETA_STAR > 0
    assert outcome.extras["sense_error"] < 0.10
    assert outcome.extras["push_time"] == pytest.approx(person.hold, abs=0.02)
    assert 0 < outcome.extras["effort"] <= person.force_cap * person.hold + 1e-9
    # The robot's model of a push predicts a change in the same direction.
    model = feature_counts(person.model().apply(task.robot, task.intended), task.env, FEATURES)
    predicted = model - feature_counts(task.robot, task.env, FEATURES)
    cosine = predicted @ change / np.linalg.norm(predicted) / np.linalg.norm(change)
    assert cosine > 0.8


def test_a_huge_push_is_clamped_and_stays_finite(task, rng):
    person = make_user("physical", {"stiffness": 1e6, "force_cap": 40.0, "force_noise": 100.0})
    outcome = person.perform(task, rng)
    forces = np.linalg.norm(outcome.trace.force, axis=1)
    assert forces.max() <= 40.0 + 1e-9 and forces.max() > 39.0
    assert np.all(np.isfinite(outcome.trace.q)) and np.all(np.isfinite(outcome.phi_h))
    assert np.array_equal(physical.cap_force(np.array([np.nan, 1.0, 0.0]), 30.0), np.zeros(3))
    assert np.linalg.norm(physical.cap_force(np.array([500.0, 0.0, 0.0]), 30.0)) == 30.0


def test_same_seed_same_push(task):
    person = make_user("physical", {"force_noise": 2.0, "torque_noise": 0.2})
    a = person.perform(task, np.random.default_rng(7))
    b = person.perform(task, np.random.default_rng(7))
    assert np.array_equal(a.phi_h, b.phi_h) and np.array_equal(a.trace.q, b.trace.q)
    assert person.stochastic


def test_two_threads_push_at_once_as_each_would_alone(task):
    """An arm is not thread-safe, so each thread has its own: two pushes played at the same
    time in two threads (two participants' motions on one study server) give the bits each
    gives alone. With one arm per process they stepped each other's arm."""
    import threading

    person = make_user("physical", {"force_noise": 2.0, "torque_noise": 0.2})
    alone = [person.perform(task, np.random.default_rng(seed)) for seed in (7, 8)]
    together: dict[int, object] = {}
    start = threading.Barrier(2)

    def push(seed: int) -> None:
        start.wait()
        together[seed] = person.perform(task, np.random.default_rng(seed))

    threads = [threading.Thread(target=push, args=(seed,)) for seed in (7, 8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    for seed, outcome in zip((7, 8), alone, strict=True):
        assert np.array_equal(together[seed].phi_h, outcome.phi_h)
        assert np.array_equal(together[seed].trace.q, outcome.trace.q)
    mine = physical._simulation(0.2)
    theirs: list = []
    other = threading.Thread(target=lambda: theirs.append(physical._simulation(0.2)))
    other.start()
    other.join()
    assert physical._simulation(0.2) is mine and theirs[0] is not mine


def test_online_the_arm_joins_the_new_plan_after_the_push(task, planner, rng):
    calls = []

    def replan(deformed, q_now, t_now):
        calls.append((deformed, q_now, t_now))
        return planner.solve(THETA_STAR, task.env).trajectory

    outcome = make_user("physical").perform(task, rng, replan)
    assert len(calls) == 1
    deformed, q_now, t_now = calls[0]
    assert np.allclose(deformed, outcome.deformed)  # the push's deformation, as learnt later
    assert 0 < t_now < 5.0
    assert outcome.extras["replanned"] == 1.0 and outcome.executed_kept is not None
    # The two motions agree up to the push's end and part after it.
    before = np.linspace(0, 5.0, 12) < t_now - 0.05
    assert np.allclose(outcome.executed[before], outcome.executed_kept[before])
    assert not np.allclose(outcome.executed, outcome.executed_kept)


@pytest.mark.parametrize(
    ("params", "where"),
    [
        ({"hold": 6.0}, "user.hold"),
        ({"force_cap": -1.0}, "user.force_cap"),
        ({"ramp": 0.8}, "user.ramp"),
        ({"torque_noise": float("nan")}, "user.torque_noise"),
    ],
)
def test_bad_parameters_name_their_key(params, where):
    with pytest.raises(ValueError, match=f"^{where}: ") as info:
        make_user("physical", params)
    assert "\n" not in str(info.value)


def test_correction_model_refuses_a_bad_span():
    with pytest.raises(ParameterError, match="span"):
        physical.PhysicalCorrection(span=-1)


def test_online_needs_a_user_who_corrects_during_the_motion():
    from corrections_sim.study import schema

    values = {"theta_star": [1.0, -1.0], "online": True, "user": "biased"}
    with pytest.raises(ValueError, match="^online: the biased user corrects a plan"):
        schema.parse_study(values)
    with pytest.raises(ValueError, match="^online = 'yes'"):
        schema.parse_study({**values, "online": "yes", "user": "physical"})


def test_a_push_into_the_table_is_a_contact_the_arm_survives(task):
    reference = dynamics.TimedTrajectory(task.robot, 5.0)
    sim = dynamics.ArmSimulation(task.env)
    sim.reset(task.robot[0])
    sim.advance(reference, 1500)
    down = [sim.advance(reference, 10, np.array([0.0, 0.0, -150.0])) for _ in range(100)]
    assert any(c.contacts for c in down)  # the cup or the arm on the table
    rest = [sim.advance(reference, 10) for _ in range(250)]
    for chunk in (*down, *rest):
        assert np.all(np.isfinite(chunk.q)) and np.all(np.isfinite(chunk.tau_sensed))
    # Pressed on the table, the robot senses less than the push (the table takes the rest),
    # and once let go it tracks its plan again.
    pressed = [c for c in down if c.contacts]
    sensed = np.mean([np.linalg.norm(c.tau_sensed[-1]) for c in pressed])
    applied = np.mean([np.linalg.norm(c.tau_applied[-1]) for c in pressed])
    assert sensed < 0.9 * applied
    planned, _ = dynamics.cup_kinematics(reference.at(rest[-1].times)[0])
    assert np.linalg.norm(rest[-1].cup[-1] - planned[-1]) < 0.02


def test_a_joined_plan_is_continuous_and_keeps_the_timing(task):
    timed = dynamics.TimedTrajectory(task.robot, 5.0)
    t = 2.2
    (here,), _, _ = timed.at(np.array([t]))
    joined = timed.join(task.intended, t, here)
    # Position and velocity continuous at the join; the new plan's later waypoints at the old
    # plan's times (those closer than 0.1 s to the join left out).
    before, velocity, _ = timed.at(np.array([t]))
    after, velocity_after, _ = joined.at(np.array([t]))
    np.testing.assert_allclose(after, before, atol=1e-12)
    np.testing.assert_allclose(velocity_after, velocity, atol=1e-12)
    later = timed.times > t + 0.1
    np.testing.assert_allclose(joined.at(timed.times[later])[0], task.intended[later], atol=1e-9)
    with pytest.raises(ValueError, match="plan"):
        timed.join(task.intended[:5], t, here)


def test_replanning_to_the_same_plan_changes_nothing(task, rng):
    """With θ̂ unchanged the online motion is the kept one (the joined spline differs from the
    old one only by its knots: well under a milliradian): what online replanning gains in the
    study is the learning's, not the join's."""
    outcome = make_user("physical").perform(task, rng, lambda deformed, q, t: task.robot)
    assert outcome.extras["replanned"] == 1.0
    np.testing.assert_allclose(outcome.executed, outcome.executed_kept, atol=5e-4)


def _same_chunks(a, b) -> bool:
    fields = ("times", "q", "qvel", "cup", "tau_sensed", "tau_applied", "force", "contacts")
    return len(a) == len(b) and all(
        np.array_equal(getattr(x, f), getattr(y, f), equal_nan=True)
        for x, y in zip(a, b, strict=True)
        for f in fields
    )


def _through_the_table(task) -> dynamics.TimedTrajectory:
    """The robot's plan with the shoulder lowered: the arm runs into the table (contacts)."""
    low = task.robot.copy()
    low[:, 1] += 0.6
    return dynamics.TimedTrajectory(low, 5.0)


def test_looks_in_one_rollout_are_the_looks_one_at_a_time(task):
    """advance_looks is advance called look by look, to the last bit: the clock, physics with
    contacts (the solver's warm start carried across looks), sensing noise, the filter."""
    reference = _through_the_table(task)
    runs = []
    for batched in (False, True):
        sim = dynamics.ArmSimulation(task.env, torque_noise=0.2)
        sim.reset(reference.waypoints[0])
        rng = np.random.default_rng(3)
        if batched:
            chunks = sim.advance_looks(reference, 10, 150, None, rng)
            chunks += sim.advance_looks(reference, 10, 350, None, rng)
        else:
            chunks = [sim.advance(reference, 10, None, rng) for _ in range(500)]
        runs.append((chunks, sim.time, sim.q(), sim._tau_filtered.copy(), rng.random()))
    (a, *rest_a), (b, *rest_b) = runs
    assert sum(c.contacts > 0 for c in a) > 50  # the table is in the way
    assert _same_chunks(a, b)
    assert all(np.array_equal(x, y) for x, y in zip(rest_a, rest_b, strict=True))
    # Without sensing, the same motion; nothing sensed.
    sim = dynamics.ArmSimulation(task.env, torque_noise=0.2)
    sim.reset(reference.waypoints[0])
    quiet = sim.advance_looks(reference, 10, 500, None, np.random.default_rng(3), sense=False)
    assert all(np.array_equal(x.q, y.q) for x, y in zip(a, quiet, strict=True))
    assert np.all(np.isnan(quiet[-1].tau_sensed))


@pytest.mark.parametrize("into_the_table", [False, True])
def test_coasting_is_looking_one_at_a_time(task, into_the_table):
    """The person's quiet looks run in one rollout: the same motion as look(None) each time.
    Into the table the robot feels the contact, so the coast is run again look by look and
    stops where the robot finds it over."""
    runs = []
    for coasting in (False, True):
        rng = np.random.default_rng(11)
        motion = physical.PushedMotion(task.robot, task.env, 5.0, rng, torque_noise=0.1)
        if into_the_table:
            motion.reference = _through_the_table(task)
        found = []
        while not motion.done:
            left = sum(1 for _ in motion.look_starts())
            if coasting:
                released = motion.coast(min(left, 120))
            else:
                released = motion.look(None)
            if released:
                found.append(motion.time)
        runs.append((motion.chunks, found, motion.pushed, rng.random(), motion.q()))
    (a, found_a, pushed_a, draw_a, q_a), (b, found_b, pushed_b, draw_b, q_b) = runs
    assert _same_chunks(a, b) and _same_chunks(pushed_a, pushed_b)
    assert found_a == found_b and draw_a == draw_b and np.array_equal(q_a, q_b)
    assert len(a) == 500
    assert (len(found_a) == 1) == into_the_table  # the table felt, then let go of
    if into_the_table:  # after that nothing is sensed (one push a task)
        assert np.all(np.isnan(a[-1].tau_sensed))


def test_a_push_that_holds_the_arm_at_a_joint_limit_stays_finite_and_is_found(task):
    """The elbow planned 10 mrad short of its limit and pushed outward (120 N, past what the
    page's handle gives) for 3 s: the limit holds it (MuJoCo's soft constraint lets it in by
    about a milliradian), nothing goes non-finite, and the robot still finds the push and
    lets go of it."""
    straight = task.robot.copy()
    upper = dynamics.dynamics_model().jnt_range[3, 1]
    straight[:, 3] = upper - 0.01
    motion = physical.PushedMotion(straight, task.env, 5.0, np.random.default_rng(0))
    elbow = []
    while not motion.done:
        cup = motion.cup()
        outward = cup * np.array([1.0, 1.0, 0.0]) / np.linalg.norm(cup[:2])
        motion.look(120.0 * outward if 0.5 < motion.time < 3.5 else None)
        elbow.append(motion.q()[3])
    assert upper - 0.005 < max(elbow) < upper + 0.01
    assert motion.released is not None and motion.pushed
    held, deformed = motion.deformation()
    trace = motion.trace()
    assert np.all(np.isfinite(deformed)) and np.all(np.isfinite(trace.q))
    assert np.all(np.isfinite(trace.tau_sensed[: len(trace.times) // 2]))
    assert np.all(np.isfinite(feature_counts(deformed, task.env, FEATURES)))


def test_the_example_push_plans_from_the_atlas_as_the_runs_do():
    """A study with an atlas and only an exact learner (which needs it): the example push
    drawn beside the study plans from the study's atlas (it once planned from a book and
    failed after every run had finished). A small atlas (7 points a weight, as
    test_regression's exact check), the first environment only."""
    from corrections_sim.figures import physical as figure

    settings = figure.PhysicalFigure().load(
        quick=True, overrides={"learners": ["EX-C"], "set": ["atlas={ points = 7 }"]}
    )
    out = figure.example(settings)
    assert out["learner"] == "EX-C"
    before, after = (np.asarray(theta) for theta in out["theta"])
    assert np.all(np.isfinite(after)) and not np.allclose(before, after)
    assert out["new_plan"] is not None and np.all(np.isfinite(out["new_plan"]))


def test_the_physical_figure_keeps_its_legend_off_every_panel(monkeypatch, tmp_path):
    """Five learners and two people (the committed study's size): the one legend sits below
    the panels, covering none of them, and the recommended robot is drawn in black, as no
    other learner is."""
    from matplotlib.colors import to_hex

    from corrections_sim.figures import physical as figure
    from corrections_sim.figures import style

    learners = ("PP", "KF", "KF-C", "KF-CL", "EX-M")
    rng = np.random.default_rng(0)
    curves = {
        user: {
            n: {key: rng.random((3, 13)) + 1.0 for key in ("estimate_error", "regret", "nees")}
            for n in learners
        }
        for user in ("biased (kinematic)", "physical, online")
    }
    tasks = {
        user: {
            n: {
                key: rng.random((3, 12)) if user.startswith("physical") else np.empty((0, 0))
                for key in ("executed_regret", "executed_regret_kept")
            }
            for n in learners
        }
        for user in curves
    }
    seen = {}

    def keep(fig, paths, dpi, rect=None):
        fig.tight_layout(rect=rect)
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        seen["legend"] = fig.legends[0].get_window_extent(renderer)
        seen["axes"] = [ax.get_tightbbox(renderer) for ax in fig.axes]
        seen["black"] = sum(to_hex(line.get_color()) == "#000000" for line in fig.axes[0].lines)
        style.plt.close(fig)

    monkeypatch.setattr(style, "save_and_close", keep)
    figure.plot_physical(curves, tasks, 2, "test", [tmp_path / "p.png"])
    legend = seen["legend"]
    for box in seen["axes"]:
        assert not legend.overlaps(box), (legend, box)
    assert seen["black"] == 2  # EX-M's two people, in the error panel
