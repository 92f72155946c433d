"""Labelled corrections made through the page with the mouse, by a scripted person (issue 38).

    python -m scripted_people.labelled --mode drag --corrections 20 \\
        --db results/interact/labelled.sqlite
    python -m scripted_people.labelled --mode physical --corrections 20 \\
        --db results/interact/labelled.sqlite

A session of fig. 4's study is started with ``--corrections`` labelled corrections asked for
(:func:`~corrections_sim.session.session.make_asks`: half toward the stated preference, half
nudges, in a seeded order) and served; a headless chromium opens its page, and for each
correction the script reads what the page asks and does it with the mouse, as a hand would:

* toward the preference: the cup moved to (drag) or pushed toward (physical) where the plan of
  the stated preference has it, at the waypoint where the two cup paths are farthest apart,
  ``reach`` of the way there (drawn per correction); a push pulls the handle's vertical arrow,
  up or down as the preference's cup is higher or lower (an environment where it differs
  mostly sideways is skipped);
* a nudge: a waypoint drawn at random (drag) or a moment of the motion (physical), the cup
  moved as far as the toward correction would have moved it, in a random direction (a push:
  up or down at random).

The hand's noise: every mouse path wanders (a few pixels, smoothed), its timing varies (each
move waits a random 8–40 ms), the end point misses its target by a random few pixels, and a
drag is made one arrow (axis) at a time in a random order. A drag the page refuses (out of
reach, a collision) is tried again shorter, then in another direction. Everything random flows
from ``--seed``. The learner is the page's default (KF-CL); the labels are scored by replaying
the session through the relevance-aware learners (``python -m
corrections_sim.session.relevance_scores``). Needs the ``dev`` extra and a chromium (see
:mod:`~scripted_people.drive`).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from corrections_sim.pages.drawing import HANDLE_SCALE, project
from corrections_sim.pages.server import serve
from corrections_sim.people.physical import worst_cup_waypoint
from corrections_sim.plans.book import PlanBook
from corrections_sim.scene.robot import cup_pose
from corrections_sim.session.log import StudyLog
from corrections_sim.session.session import Session, make_asks
from scripted_people import drive

#: The waypoint slider's number box on the drag page (after one per feature).
WAYPOINT_BOX = 2
#: A toward correction smaller than this (m, the cup) is nothing to correct: the environment
#: is skipped, as a person would.
NOTHING = 0.02
#: How far (m) the hand pulls the handle in a push, at least and at most: a firm push (the
#: 300 N/m spring reaches its 30 N cap at 10 cm).
PULL_MIN, PULL_MAX = 0.05, 0.15
#: Pixels a hand's path wanders, and by which its end point misses.
WANDER = 3.0
MISS = 2.5


class Hand:
    """The scripted person's hand: mouse paths with wander, timing and aim noise."""

    def __init__(self, tab, rng: np.random.Generator) -> None:
        self.tab = tab
        self.rng = rng

    def box(self):
        return self.tab.locator("canvas").first.bounding_box()

    def pixel(self, point) -> np.ndarray:
        box = self.box()
        x, y = project(np.asarray(point, float), box["width"], box["height"])
        return np.array([box["x"] + x, box["y"] + y])

    def path(self, start, end, steps: int) -> None:
        """Move the pressed mouse from ``start`` to ``end`` (pixels) as a hand would."""
        wander = np.cumsum(self.rng.normal(0.0, WANDER / 2, size=(steps, 2)), axis=0)
        wander -= np.linspace(0, 1, steps)[:, None] * wander[-1]  # arrive where aimed
        for i in range(1, steps + 1):
            f = 0.5 - 0.5 * np.cos(np.pi * i / steps)  # slow, fast, slow
            point = start + f * (end - start) + (wander[i - 1] if i < steps else 0.0)
            self.tab.mouse.move(float(point[0]), float(point[1]))
            time.sleep(float(self.rng.uniform(0.008, 0.04)))

    def drag(self, grab_point, end_point, *, hold: float = 0.0) -> None:
        """Reach the handle's point ``grab_point`` (world), press, drag to the screen point
        of world ``end_point`` (missing it by a little), hold ``hold`` s, let go."""
        start = self.pixel(grab_point)
        end = self.pixel(end_point) + self.rng.normal(0.0, MISS, size=2)
        approach = start + self.rng.normal(0.0, 60.0, size=2) + np.array([-90.0, 70.0])
        self.tab.mouse.move(float(approach[0]), float(approach[1]))
        self.path(approach, start, 8)
        self.tab.mouse.down()
        self.path(start, end, int(self.rng.integers(10, 18)))
        time.sleep(hold)
        self.tab.mouse.up()


def arrow(position, axis: int, sign: float = 1.0) -> np.ndarray:
    """The point a hand grabs on the handle's ``axis`` arrow at ``position``."""
    return np.asarray(position, float) + sign * 0.7 * HANDLE_SCALE * np.eye(3)[axis]


def toward_target(session: Session, robot: np.ndarray, env) -> tuple[int, np.ndarray]:
    """(waypoint, the cup there in the plan of the stated preference). Solved in a book of
    its own: the session's warm starts stay the session's."""
    ideal = PlanBook(session.planner).plan(session.preference, env).trajectory
    i, theirs = worst_cup_waypoint(robot, ideal)
    return i, theirs[i]


def _drag_once(session, page, hand, rng) -> bool | None:
    """One labelled drag and submit; False if no drag was taken, None if there is nothing to
    correct here (then the page is skipped)."""
    asked = session.ask()
    proposal = session.proposal()
    robot, env = proposal.plan.trajectory, proposal.env
    i, goal = toward_target(session, robot, env)
    cup = cup_pose(robot[i])[1]
    if np.linalg.norm(goal - cup) < NOTHING:
        return None
    reach = float(rng.uniform(0.7, 1.0))
    move = reach * (goal - cup)
    size = float(np.linalg.norm(move))
    if asked["kind"] == "nudge":
        i = int(rng.integers(1, session.n_waypoints - 1))
        cup = cup_pose(robot[i])[1]
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    if asked["kind"] == "nudge":
        move = size * direction
    drive.set_number(hand.tab, WAYPOINT_BOX, i)
    drive.wait_for(lambda: (drive.cup_position(hand.tab) or (None,))[0] == i, "the waypoint")
    for attempt in range(4):
        before = page.drags
        position = np.array(page.handle.position, float)
        axes = [a for a in rng.permutation(3) if abs(move[a]) > 0.005]
        for a in axes:
            grab = arrow(position, a)
            hand.drag(grab, grab + move[a] * np.eye(3)[a])
            drive.wait_for(lambda n=before: page.drags > n, "the drag reaching the server", 30)
            before = page.drags
            if page.corrected is None:  # refused: the handle went back
                break
            position = np.array(page.handle.position, float)
        if page.corrected is not None:
            break
        # Refused: shorter, then (for a nudge) another direction.
        move = 0.6 * move
        if asked["kind"] == "nudge" and attempt >= 1:
            turn = rng.normal(size=3)
            move = float(np.linalg.norm(move)) * turn / np.linalg.norm(turn)
    if page.corrected is None:
        return False
    count = session.iteration
    drive.click(hand.tab, "Submit correction")
    drive.wait_for(lambda: session.iteration > count and page.proposal is not None, "the submit")
    drive.wait_for(lambda: drive.cup_position(hand.tab), "the next plan on the page")
    return True


def _push_once(session, page, hand, rng, speed: float) -> bool | None:
    """One labelled push during the motion; False if no push was learnt, None if there is
    nothing to correct here (then the page is skipped)."""
    asked = session.ask()
    proposal = session.proposal()
    robot, env = proposal.plan.trajectory, proposal.env
    i, goal = toward_target(session, robot, env)
    gap = goal - cup_pose(robot[i])[1]
    if np.linalg.norm(gap) < NOTHING:
        return None
    # The hand pulls the handle's vertical arrow (the one a hand catches during the motion:
    # the scripted pointer did not land a grab on the x or y arrows of the waiting handle
    # there), up or down: toward the preference where its cup is higher or lower than the
    # robot's, about as far as the cups are apart (at least PULL_MIN, at most PULL_MAX: the
    # spring is capped anyway). A preference whose cup differs mostly sideways here gives
    # nothing this hand can correct: skipped.
    if abs(gap[2]) < 0.3 * np.linalg.norm(gap):
        return None
    a = 2
    size = float(np.clip(rng.uniform(0.7, 1.0) * np.linalg.norm(gap), PULL_MIN, PULL_MAX))
    pull = size * float(np.sign(gap[2]))
    if asked["kind"] == "nudge":
        i = int(rng.integers(2, session.n_waypoints - 2))
        pull = size * float(rng.choice([-1.0, 1.0]))
    when = i / (session.n_waypoints - 1) * page.duration + float(rng.normal(0.0, 0.15))
    lead = 0.35  # the hand starts to reach this long (simulated) before
    count, before = page.pushes, page.motion
    drive.wait_for(lambda: not page._in_motion, "the last motion's end", 120)
    drive.click(hand.tab, "Play: push the cup while it moves")
    # The click reaches the server a little later: wait for this motion, not the last one.
    drive.wait_for(lambda: page.motion is not None and page.motion is not before, "the motion", 60)
    drive.wait_for(
        lambda: page.motion.time >= max(0.2, when - lead) or page.motion.done, "the moment", 120
    )
    grabs = page.grabs
    if not page.motion.done:
        grab = arrow(np.array(page.handle.position, float), a)
        hand.drag(grab, grab + pull * np.eye(3)[a], hold=float(rng.uniform(0.5, 0.9)) / speed)
    drive.wait_for(lambda: not page._in_motion, "the end of the motion", 120)
    if page.pushes == count:
        why = "no grab" if page.grabs == grabs else f"a grab, {abs(pull):.2f} m on axis {a}"
        print(f"  {asked['kind']}: no push felt ({why})", file=sys.stderr)
    return page.pushes > count


def skip(tab, page, session, physical: bool) -> None:
    """Skip this environment on the page and wait for the next plan there."""
    draws = session.draws
    drive.click(tab, "Skip this environment")
    drive.wait_for(lambda: session.draws > draws and page.proposal is not None, "the next plan")
    if not physical:
        drive.wait_for(lambda: drive.cup_position(tab), "the next plan on the page")


def run(
    db: Path,
    mode: str,
    corrections: int,
    seed: int,
    speed: float,
    port: int,
    *,
    browser=None,
    overrides: dict | None = None,
) -> int:
    """Make ``corrections`` labelled corrections in a new session of ``db``; its id. With no
    ``browser`` (a Playwright chromium), one is launched for the session; ``overrides``:
    changes to fig. 4's study (``load_study``'s, e.g. a smaller plan atlas)."""
    if browser is None:
        from playwright.sync_api import sync_playwright

        with sync_playwright() as p:
            browser = drive.launch(p)
            try:
                return run(
                    db, mode, corrections, seed, speed, port, browser=browser, overrides=overrides
                )
            finally:
                browser.close()
    from corrections_sim.figures.presets import EXPERIMENTS_DIR
    from corrections_sim.study import schema

    settings = schema.load_study(
        EXPERIMENTS_DIR / "fig4.toml", name="fig4", quick=False, overrides=overrides
    )
    physical = mode == "physical"
    rng = np.random.default_rng([seed, 0 if physical else 1])
    with StudyLog(db) as log:
        session = Session.start(
            settings,
            log,
            learner="KF-CL",
            params={"model": "physical"} if physical else None,
            correction="physical" if physical else "waypoint",
            participant=f"scripted-{mode}",
            asks=make_asks(corrections, seed),
        )
        server, page = serve(session, port=port, speed=speed)
        try:
            tab = drive.open_page(browser, f"http://127.0.0.1:{port}", physical=physical)
            hand = Hand(tab, rng)
            misses = skips = 0
            while session.iteration < corrections:
                done = (
                    _push_once(session, page, hand, rng, speed)
                    if physical
                    else _drag_once(session, page, hand, rng)
                )
                note = {True: "", False: " (missed: again)", None: " (nothing to correct: skip)"}
                print(f"{mode} {session.iteration}/{corrections}{note[done]}", file=sys.stderr)
                misses += done is False
                skips += done is None
                if misses > 3 * corrections:
                    raise RuntimeError(f"{misses} corrections missed: the page is not driven")
                if skips > 20 * corrections:
                    raise RuntimeError(f"{skips} environments skipped: nothing to correct")
                if done is None or (done is False and not physical):
                    skip(tab, page, session, physical)
            session.finish()
            tab.close()
        finally:
            server.stop()
        return session.id


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m scripted_people.labelled", description=__doc__.split("\n\n")[0]
    )
    p.add_argument("--db", type=Path, required=True)
    p.add_argument("--mode", choices=("drag", "physical"), default="drag")
    p.add_argument("--corrections", type=int, default=20)
    p.add_argument("--seed", type=int, default=38)
    p.add_argument("--speed", type=float, default=0.5, help="physical: simulated s per real s")
    p.add_argument("--port", type=int, default=8093)
    args = p.parse_args(argv)
    if args.corrections < 2:
        print(f"error: --corrections {args.corrections}: at least 2", file=sys.stderr)
        return 2
    if not 0.0 < args.speed <= 1.0:
        print(f"error: --speed {args.speed}: must lie in (0, 1]", file=sys.stderr)
        return 2
    args.db.parent.mkdir(parents=True, exist_ok=True)
    session_id = run(args.db, args.mode, args.corrections, args.seed, args.speed, args.port)
    print(f"session {session_id} of {args.db}: {args.corrections} labelled corrections")
    return 0


if __name__ == "__main__":
    sys.exit(main())
