"""A simulated user corrects a :class:`~corrections_sim.session.session.Session` through the
same steps as a person at the page: the user plans their own ξ*(θ*, E) (kept out of the
session's plan book), corrects the robot's plan (or pushes the moving arm, for a physical
user), and the session learns and logs each correction as it would a person's. Used by
``run interact --headless``, by the user study's simulated cohort and by the tests that compare
a logged human session with a simulated one line by line.
"""

from __future__ import annotations

import numpy as np

from corrections_sim.people.users import Situation, User
from corrections_sim.planning.planner import PlanningError, shared_planner
from corrections_sim.plans.book import PlanBook
from corrections_sim.session.session import Session


def simulate(session: Session, user: User, theta_star, corrections: int) -> list[dict]:
    """``corrections`` corrections of ``session`` by the simulated ``user`` whose preference is
    ``theta_star``, through the same steps as a person's (the user's noise from its own
    seeded generator); returns the logged rows."""
    if session.settings.user_features:
        raise ValueError(
            "user_features: a simulated session plans the person over the robot's features; "
            "a person with features of their own is simulated in a study (run study FILE)"
        )
    theta_star = np.asarray(theta_star, dtype=float)
    session.state(theta_star)
    rng = np.random.default_rng(np.random.SeedSequence([session.seed, 22]))
    # The user's plans stay out of the session's history, over the study's features; with
    # the study's plan atlas they are the atlas's, as the robot's are (a function of (θ, E)).
    settings = session.settings
    own = PlanBook(shared_planner(settings.planner_config()), atlas=settings.atlas())
    rows = []
    while len(rows) < corrections:
        pending = session.proposal()
        try:
            intended = own.plan(theta_star, pending.env).trajectory
        except PlanningError as exc:
            session.skip(f"the user's plan failed: {str(exc).splitlines()[0]}")
            continue
        situation = Situation(
            robot=pending.plan.trajectory,
            intended=intended,
            env=pending.env,
            features=session.settings.features,
            theta_star=theta_star,
        )
        if user.during_motion:
            rows.append(_simulate_push(session, user, situation, rng))
            continue
        outcome = user.perform(situation, rng)  # one draw for the trajectory and its features
        corrected = outcome.corrected
        if corrected is None:  # a user that shows noisy features: the trajectory it shows
            corrected = user.correct(situation, rng)
        drag = {"simulated": True}
        if outcome.relevant is not None:
            drag["relevant"] = bool(outcome.relevant)
        # Φ over the learner's features when it has learnt more (a noiseless user's Φ_h is
        # Φ(ξ_h) itself; a user with feature noise is simulated before any expansion).
        phi_h = None if session.belief.extra else outcome.phi_h
        rows.append(session.submit(corrected, drag=drag, phi_h=phi_h))
    return rows


def _simulate_push(session: Session, user: User, situation: Situation, rng) -> dict:
    """One push of a simulated physical ``user`` through the session's steps: the motion, the
    push, the update and its log row, and the rest replanned from where the arm is."""
    if not session.physical:
        raise ValueError(
            f"user: the physical user pushes the moving arm; start the session with "
            f"--mode physical (its correction model is {session.correction_name})"
        )
    rows = []

    def replan(deformed, q_now, t_now):
        rows.append(session.submit(deformed, drag={"simulated": True, "released_at": t_now}))
        return session.replan(q_now, t_now, rows[-1]["iteration"])

    outcome = user.perform(situation, rng, replan)
    if not rows:  # no push found: the deformation is none, learnt after the motion
        rows.append(session.submit(outcome.deformed, drag={"simulated": True}))
    return rows[0]
