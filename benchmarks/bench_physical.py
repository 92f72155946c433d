"""Physical corrections, measured: the simulation's real-time factor, what the robot senses
against the applied Jᵀ F, and one physical correction end to end (a 5 s motion at 1 kHz with
the person's push, sensing, deformation, KF-C's update and the replan of the rest), in CPU
seconds, over paper environments."""

from __future__ import annotations

import time

import numpy as np

from corrections_sim.belief import Belief, KalmanNoise
from corrections_sim.learning import correction
from corrections_sim.learning.base import make_learner
from corrections_sim.learning.kalman.filter import SigmaPoints
from corrections_sim.people.users import Situation, make_user
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import PlannerConfig, shared_planner
from corrections_sim.plans.book import PlanBook
from corrections_sim.scene import dynamics
from corrections_sim.scene.environments import paper_environments

FEATURES = ("laptop", "table")
THETA_STAR = np.array([1.0, -1.0])


def _percentiles(values) -> str:
    v = np.asarray(values, float)
    return f"median {np.median(v):.3f}, max {v.max():.3f}"


def run_bench(tasks: int = 12, seed: int = 0) -> list[str]:
    """The benchmark's table as lines."""
    envs = paper_environments()
    planner = shared_planner(PlannerConfig(n_starts=4))
    rng = np.random.default_rng(seed)
    picks = rng.choice(len(envs), size=tasks, replace=False)
    lines = ["physical corrections (2-core machine, one process)", ""]

    # Real-time factor: a 5 s plan tracked at 1 kHz, no push, sensing on.
    env = envs[int(picks[0])]
    plan = planner.solve(np.zeros(2), env).trajectory
    reference = dynamics.TimedTrajectory(plan, 5.0)
    sim = dynamics.ArmSimulation(env)
    factors = []
    for _ in range(3):
        sim.reset(plan[0])
        t0 = time.perf_counter()
        for _ in range(500):
            sim.advance(reference, 10)
        factors.append(5.0 / (time.perf_counter() - t0))
    lines.append(
        f"simulation: 5 s at 1 kHz with sensing, real-time factor {np.median(factors):.1f}x "
        f"({5000 * np.median(factors) / 5.0:,.0f} steps/s)"
    )

    person = make_user("physical")
    learner = make_learner("KF-C", {"model": "physical"})
    noise = KalmanNoise.isotropic(2, 1e-4, 0.25)
    cpu, paired, sense, moved = [], [], [], []

    def task(env, keep: bool):
        """One push in ``env`` with KF-C learning online: its CPU time, outcome, θ̂ after."""
        book = PlanBook(planner, None, warm_start=True)
        belief = Belief(theta=np.zeros(2), cov=np.eye(2))
        mine = book.plan(belief.theta, env)
        star = planner.solve(THETA_STAR, env)
        situation = Situation(mine.trajectory, star.trajectory, env, FEATURES, THETA_STAR)
        ctx = correction.context(
            belief,
            noise,
            book=book,
            envs=envs,
            features=FEATURES,
            n_waypoints=12,
            alphas=None,
            rng=rng,
            sigma=SigmaPoints(),
            iteration=0,
        )
        after = []

        def replan(deformed, q_now, t_now):
            phi = feature_counts(deformed, env, FEATURES)
            step = correction.step(learner, ctx, belief, env, mine, phi)
            after.append(step.belief.theta)
            return book.plan(step.belief.theta, env).trajectory  # warm, as the study loop

        t0 = time.process_time()
        outcome = person.perform(situation, rng, replan, keep=keep)
        return time.process_time() - t0, outcome, after

    task(envs[int(picks[0])], keep=True)  # untimed: builds this process's arm and caches
    for idx in picks:
        env = envs[int(idx)]
        seconds, outcome, after = task(env, keep=False)
        cpu.append(seconds)
        paired.append(task(env, keep=True)[0])
        sense.append(outcome.extras["sense_error"])
        if after:
            moved.append(float(np.sum(np.abs(after[0] - THETA_STAR))))
    lines += [
        f"one physical correction end to end (motion, push, sensing, deformation, KF-C update, "
        f"replan; {tasks} environments): CPU s {_percentiles(cpu)} (target <= 0.5)",
        f"  the same with the old plan's motion played too (the study's paired measure): "
        f"{_percentiles(paired)}",
        f"sensed tau_h against the applied J^T F, relative RMS over the push: "
        f"{_percentiles(sense)} (target <= 0.10)",
        f"KF-C's error after one push from theta0 = 0 (2.0 before): {_percentiles(moved)}",
    ]
    return lines


def _moving(motion) -> bool:
    """A motion under way for 0.3 s (None before the page has made it)."""
    return motion is not None and motion.time > 0.3


def run_page_bench(speed: float = 0.25, pushes: int = 2, screenshot=None, db=None) -> list[str]:
    """The physical page in chromium (software WebGL): arm poses the server sends per second
    during a motion, frames the page draws per second, and from letting go of the handle to
    the new path on the page; ``pushes`` pushes, one per plan; the page after the first push
    saved to ``screenshot`` if given; the session logged to ``db`` (default a temporary
    file)."""
    import socket
    import tempfile
    from pathlib import Path

    from playwright.sync_api import sync_playwright

    from corrections_sim.pages.server import serve, stop
    from corrections_sim.session.log import StudyLog
    from corrections_sim.session.session import Session
    from corrections_sim.study.schema import parse_study
    from scripted_people import drive

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    study = {"theta_star": [1.0, -1.0], "learners": ["KF-CL"], "seed": 5, "iterations": pushes}
    log = StudyLog(Path(db) if db else Path(tempfile.mkdtemp()) / "bench.sqlite")
    session = Session.start(
        parse_study(study, name="bench"),
        log,
        learner="KF-CL",
        params={"model": "physical"},
        correction="physical",
        participant="bench-physical",
    )
    server, page = serve(session, port=port, speed=speed)
    poses, drawn, latency, server_side = [], [], [], []
    try:
        with sync_playwright() as p:
            browser = drive.launch(p)
            tab = drive.open_page(browser, f"http://127.0.0.1:{port}", physical=True)
            for k in range(pushes):
                drive.click(tab, "Play: push the cup while it moves")
                drive.wait_for(lambda: page._in_motion and _moving(page.motion), "motion")
                frames0, t0 = page.frames, time.perf_counter()
                drawn.append(drive.frame_rate(tab, 2.0))
                poses.append((page.frames - frames0) / (time.perf_counter() - t0))
                for _ in range(5):
                    drive.push_cup(tab, np.asarray(page.handle.position), 150, hold=1.0)
                    let_go = time.perf_counter()
                    if page.max_force > 0:
                        break
                drive.wait_for(lambda k=k: page.pushes > k, "the push learnt", timeout=120)
                drive.wait_for(lambda: "learnt" in drive.status(tab), "the new path shown")
                latency.append(time.perf_counter() - let_go)
                if screenshot is not None and k == 0:
                    tab.screenshot(path=str(screenshot))
                server_side.append(page.last_push[1] - page.last_push[0])
                if not page.settle(120):
                    raise TimeoutError("the motion did not end within 120 s")
                page.max_force = 0.0
            browser.close()
    finally:
        page.settle()  # a push still learning ends before the log closes under it
        stop(server)
        log.close()
    return [
        f"physical page at speed {speed} ({pushes} pushes, chromium, software WebGL; session "
        f"{session.id} of {log.path})",
        f"arm poses sent per second during a motion: {_percentiles(poses)} (target >= 30)",
        f"frames the page draws per second during a motion: {_percentiles(drawn)} (target >= 20)",
        f"letting go -> the learnt push and new path on the page: {_percentiles(latency)} s "
        f"(includes the robot's {0.05 / speed:.2f} s wait for quiet; target <= 1)",
        f"  of which on the server (push found -> learnt, logged, replanned, drawn): "
        f"{_percentiles(server_side)} s",
    ]
