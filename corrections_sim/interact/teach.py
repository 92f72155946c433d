"""A person who minds what the robot lacks corrects it at the page, then teaches it the
feature when it asks: scripted, with the mouse, in chromium (issue 39).

    python -m corrections_sim.interact.teach --db results/interact/teach.sqlite

A session of fig. 4's study (the robot knows laptop and table) with KF-CRX is served; a
headless chromium opens its page. The scripted person minds only the coffee coming close to
them (`human`, θ* = −5 over laptop, table, human): each correction drags the cup at the
waypoint where their own plan's cup is farthest from the robot's, ``reach`` of the way there
(drawn per correction), one arrow at a time with the hand's noise of
:mod:`~corrections_sim.interact.labelled`. When the robot asks for traces (the page turns to
teaching), each trace is: the cup dragged near the person (where `human` is high: a place
drawn around (0.72, 0, 0.38) m), "Start a trace here", the cup dragged away from them (a
place drawn around (0.35, ±0.3, 0.2) m), one arrow at a time, "End the trace". After the last
trace the page learns the feature and plans over it; the script makes ``--after`` more
corrections and ends the session. Everything random flows from ``--seed``.

The session replays (``python -m corrections_sim.run replay LOG``): KF-CRX retrains the
feature from the logged traces. Needs the ``dev`` extra and a chromium (see
:mod:`~corrections_sim.interact.drive`).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from corrections_sim.interact import drive
from corrections_sim.interact.labelled import NOTHING, WAYPOINT_BOX, Hand, _skip, arrow
from corrections_sim.interact.log import StudyLog
from corrections_sim.interact.page import CAMERA_FOV, CAMERA_LOOK_AT, CAMERA_POSITION
from corrections_sim.interact.server import serve
from corrections_sim.interact.session import Session
from corrections_sim.people.physical import worst_cup_waypoint
from corrections_sim.planning.planner import PlannerConfig, shared_planner
from corrections_sim.planning.plans import PlanBook
from corrections_sim.scene.robot import cup_pose

#: The person: what they weigh, over which features.
PERSON_FEATURES = ("laptop", "table", "human")
PERSON_THETA = (0.0, 0.0, -5.0)
#: Where the person starts a trace (near themselves) and ends it (away), m, and how far a
#: drawn place strays from these (sd per axis).
HIGH = np.array([0.72, 0.0, 0.38])
LOW = np.array([0.35, 0.3, 0.2])
STRAY = 0.04
#: An arrow shorter than this on the screen (pixels) points at the eye: not grabbed.
SHORT = 25.0


def _their_plan(settings, env) -> np.ndarray:
    config = PlannerConfig(features=PERSON_FEATURES, **dict(settings.planner))
    return PlanBook(shared_planner(config)).plan(np.array(PERSON_THETA), env).trajectory


def _correct(session, page, hand, rng) -> bool | None:
    """One correction toward the person's plan and its submit (False: the page refused every
    try; None: nothing to correct here)."""
    proposal = session.proposal()
    robot, env = proposal.plan.trajectory, proposal.env
    i, theirs = worst_cup_waypoint(robot, _their_plan(session.settings, env))
    cup = cup_pose(robot[i])[1]
    move = float(rng.uniform(0.7, 1.0)) * (theirs[i] - cup)
    if np.linalg.norm(move) < NOTHING:
        return None
    drive.set_number(hand.tab, WAYPOINT_BOX, i)
    drive.wait_for(lambda: (drive.cup_position(hand.tab) or (None,))[0] == i, "the waypoint")
    for _ in range(3):
        before = page.drags
        position = np.array(page.handle.position, float)
        for a in [a for a in rng.permutation(3) if abs(move[a]) > 0.005]:
            grab = arrow(position, a)
            hand.drag(grab, grab + move[a] * np.eye(3)[a])
            drive.wait_for(lambda n=before: page.drags > n, "the drag reaching the server", 30)
            before = page.drags
            if page.corrected is None:
                break
            position = np.array(page.handle.position, float)
        if page.corrected is not None:
            break
        move = 0.6 * move
    if page.corrected is None:
        return False
    count = session.iteration
    drive.click(hand.tab, "Submit correction")
    drive.wait_for(lambda: session.iteration > count, "the submit", 180)
    drive.wait_for(lambda: page.teaching or page.proposal is not None, "the next step", 180)
    return True


def _move_teach_handle(page, hand, target: np.ndarray) -> None:
    """Drag the teaching handle toward ``target`` (world), one arrow at a time in a random
    order (a drag the arm cannot follow puts the cup back: the hand goes on)."""
    for a in hand.rng.permutation(3):
        position = np.array(page.teach_handle.position, float)
        step = float(target[a] - position[a])
        if abs(step) < 0.01:
            continue
        before = page.teach_moves
        grab = arrow(position, int(a))
        if np.linalg.norm(hand.pixel(grab) - hand.pixel(position)) < SHORT:
            continue  # the arrow points at the eye: a hand moves along the others
        try:
            drive.until_landed(
                lambda grab=grab, a=a, step=step: hand.drag(grab, grab + step * np.eye(3)[a]),
                lambda n=before: page.teach_moves > n,
                attempts=3,
                timeout=8.0,
            )
        except TimeoutError:  # missed: the drag turned the view; put it back, go on
            hand.tab.screenshot(path=str(Path(tempfile.gettempdir()) / "teach-missed.png"))
            _reset_view(page)
            continue


def _reset_view(page) -> None:
    """The page's first view again (a drag that misses the handle orbits the camera)."""
    camera = page.client.camera
    camera.position, camera.look_at = CAMERA_POSITION, CAMERA_LOOK_AT
    camera.up_direction = (0.0, 0.0, 1.0)
    camera.fov = CAMERA_FOV


def _teach_one(session, page, hand, rng) -> None:
    """One trace: to a high place, start, to a low place, end."""
    drive.wait_for(
        lambda: page.teach_handle is not None and not page._action.locked(), "the teaching page"
    )
    high = HIGH + rng.normal(0.0, STRAY, 3)
    low = LOW * np.array([1.0, rng.choice([-1.0, 1.0]), 1.0]) + rng.normal(0.0, STRAY, 3)
    _move_teach_handle(page, hand, high)
    drive.click(hand.tab, "Start a trace here")
    drive.wait_for(lambda: page.recording, "the recording")
    _move_teach_handle(page, hand, low)
    drive.wait_for(lambda: not page.end_trace.disabled, "a trace to end")
    taken = page.traces_taken
    drive.click(hand.tab, "End the trace")
    drive.wait_for(  # taken (or refused), and the learning done when it was the last
        lambda: (page.traces_taken > taken or not page.recording) and not page._action.locked(),
        "the trace reaching the server",
        120,
    )


def run(
    db: Path,
    *,
    after: int = 3,
    seed: int = 39,
    port: int = 8094,
    params: dict | None = None,
    most: int = 12,
    browser=None,
) -> int:
    """A session of ``db`` corrected and taught through the page; its id. ``params`` are
    KF-CRX's (e.g. fewer traces); ``most`` corrections at most before it must have asked."""
    if browser is None:
        from playwright.sync_api import sync_playwright

        with sync_playwright() as p:
            browser = drive.launch(p)
            try:
                return run(
                    db, after=after, seed=seed, port=port, params=params, most=most,
                    browser=browser,
                )  # fmt: skip
            finally:
                browser.close()
    from corrections_sim.figures.presets import EXPERIMENTS_DIR
    from corrections_sim.study import schema

    settings = schema.load_study(EXPERIMENTS_DIR / "fig4.toml", name="fig4", quick=False)
    rng = np.random.default_rng([seed, 2])
    with StudyLog(db) as log:
        session = Session.start(
            settings, log, learner="KF-CRX", params=params, participant="scripted-teacher"
        )
        server, page = serve(session, port=port)
        try:
            tab = drive.open_page(browser, f"http://127.0.0.1:{port}")
            hand = Hand(tab, rng)
            drive.wait_for(lambda: page.proposal is not None, "the first plan")
            taught_at = None
            skips = 0
            while taught_at is None or session.iteration < taught_at + after:
                if page.teaching:
                    while page.teaching:
                        _teach_one(session, page, hand, rng)
                        print(f"trace {len(session.traces)}/{session.wanted}", file=sys.stderr)
                    taught_at = session.iteration
                    drive.wait_for(lambda: page.proposal is not None, "the plan over it", 180)
                    continue
                if taught_at is None and session.iteration >= most:
                    raise RuntimeError(f"{most} corrections and the robot never asked")
                done = _correct(session, page, hand, rng)
                print(f"correction {session.iteration}", file=sys.stderr)
                if done is not True:
                    skips += 1
                    if skips > 40:
                        raise RuntimeError("40 environments skipped: nothing to correct")
                    _skip(tab, page, session, False)
            session.finish()
            tab.close()
        finally:
            server.stop()
        return session.id


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m corrections_sim.interact.teach", description=__doc__.split("\n\n")[0]
    )
    p.add_argument("--db", type=Path, required=True)
    p.add_argument("--after", type=int, default=3, help="corrections after the teaching")
    p.add_argument("--seed", type=int, default=39)
    p.add_argument("--port", type=int, default=8094)
    args = p.parse_args(argv)
    if args.after < 1:
        print(f"error: --after {args.after}: at least 1", file=sys.stderr)
        return 2
    args.db.parent.mkdir(parents=True, exist_ok=True)
    session_id = run(args.db, after=args.after, seed=args.seed, port=args.port)
    print(f"session {session_id} of {args.db}: corrected, taught, corrected")
    return 0


if __name__ == "__main__":
    sys.exit(main())
