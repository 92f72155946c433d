"""A person who minds what the robot lacks corrects it at the page, then teaches it the
feature when it asks: scripted, with the mouse, in chromium (issue 39).

    python -m scripted_people.teach --db results/interact/teach.sqlite --hurried

A session of fig. 4's study (the robot knows laptop and table) with KF-CRX is served; a
headless chromium opens its page. The scripted person minds only the coffee coming close to
them (`human`, θ* = −5 over laptop, table, human): each correction drags the cup at the
waypoint where their own plan's cup is farthest from the robot's, ``reach`` of the way there
(drawn per correction), one arrow at a time with the hand's noise of
:mod:`~scripted_people.labelled`. When the robot asks for traces (the page turns to
teaching), each trace is: the cup dragged near the person (where `human` is high: a place
drawn around (0.72, 0, 0.38) m), "Start a trace here", the cup dragged away from them (a
place drawn around (0.35, ±0.3, 0.2) m), one arrow at a time, "End the trace". After the last
trace the page learns the feature and plans over it; the script makes ``--after`` more
corrections and ends the session. Everything random flows from ``--seed``.

With ``--hurried`` the person presses Start within 0.2 s of their last drag, and half the
time first drags the cup where the arm cannot hold it (the page must refuse those Starts: a
trace begins only where the page shows the cup). The person's truth is logged (a ``truth``
event), so a replay reports the learnt feature's quality against `human`;
:func:`report` gives, from the log alone, each trace's start against where the page showed
the cup at Start, the learnt feature's Spearman ρ against `human`, and the plans' closest
approach to the person before and after the teaching.

The session replays (``python -m corrections_sim.run replay LOG``): KF-CRX retrains the
feature from the logged traces. Needs the ``dev`` extra and a chromium (see
:mod:`~scripted_people.drive`).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from corrections_sim.pages.drawing import CAMERA_FOV, CAMERA_LOOK_AT, CAMERA_POSITION, cup_path
from corrections_sim.pages.server import serve
from corrections_sim.pages.teach import MAP_REWARD, MAP_SHAPE
from corrections_sim.people.physical import worst_cup_waypoint
from corrections_sim.planning.features import HUMAN_POSITION
from corrections_sim.planning.planner import PlannerConfig, shared_planner
from corrections_sim.plans.book import PlanBook
from corrections_sim.scene.robot import cup_pose
from corrections_sim.session.log import StudyLog
from corrections_sim.session.session import Session
from scripted_people import drive
from scripted_people.labelled import NOTHING, WAYPOINT_BOX, Hand, arrow, skip

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


#: Where a hurried person first drags the cup, past a high place: beyond the arm's reach.
BEYOND = np.array([0.45, 0.0, 0.3])


def _move_teach_handle(page, hand, target: np.ndarray, *, hurried: bool = False) -> None:
    """Drag the teaching handle toward ``target`` (world), one arrow at a time in a random
    order (a drag the arm cannot follow puts the cup back: the hand goes on). ``hurried``:
    the last arrow's drag is not waited for (the hand goes straight on)."""
    axes = list(hand.rng.permutation(3))
    for n, a in enumerate(axes):
        if hurried and n == len(axes) - 1:
            position = np.array(page.teach_handle.position, float)
            step = float(target[a] - position[a])
            grab = arrow(position, int(a))
            seen = np.linalg.norm(hand.pixel(grab) - hand.pixel(position)) >= SHORT
            if abs(step) >= 0.01 and seen:
                hand.drag(grab, grab + step * np.eye(3)[a])
            return
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


#: The teaching buttons a person must see without scrolling.
TEACH_BUTTONS = (
    "Start a trace here",
    "End the trace",
    "Cancel this trace",
    "Learn from the traces I gave",
    "I cannot show it",
)


def below_the_fold(tab, labels=TEACH_BUTTONS) -> list[str]:
    """The buttons among ``labels`` that are not within the tab's first screen (its
    viewport, not scrolled), waited for until the page lays them out."""
    height = tab.viewport_size["height"]
    out = []
    for label in labels:
        button = tab.get_by_role("button", name=label, exact=True)
        button.wait_for(state="visible", timeout=30_000)
        box = button.bounding_box()
        if box is None or box["y"] < 0 or box["y"] + box["height"] > height:
            out.append(label)
    return out


def _settled(page) -> bool:
    """The page has handled every drag it was sent (the handle is where the arm holds the
    cup, or was put back) and runs no action."""
    if page._action.locked() or page.teach_handle is None:
        return False
    with page._lock:
        cup = cup_pose(page.teach_q)[1]
        return np.linalg.norm(np.array(page.teach_handle.position, float) - cup) < 1e-3


def _start(page, hand, rng, high, *, hurried: bool, shot=None) -> int:
    """Press Start until the trace starts (a hurried person within 0.2 s of the last drag,
    first dragging out of reach half the time); returns the Starts the page refused."""
    if hurried and rng.random() < 0.5:
        _move_teach_handle(page, hand, high + BEYOND, hurried=True)
    else:
        _move_teach_handle(page, hand, high, hurried=hurried)
    refused = 0
    for _ in range(8):
        if hurried:
            time.sleep(float(rng.uniform(0.0, 0.2)))
        else:
            drive.wait_for(lambda: _settled(page), "the cup placed")
        before = page.starts_refused
        drive.click(hand.tab, "Start a trace here")
        drive.wait_for(
            lambda n=before: page.recording or page.starts_refused > n, "Start's answer", 60
        )
        if page.recording:
            return refused
        refused += 1
        if shot is not None:
            shot("1a-start-refused")
            shot = None
        drive.wait_for(lambda: _settled(page), "the cup settled", 60)
        if page.teach_refused:  # it went back: put it somewhere the arm can hold it
            _move_teach_handle(page, hand, high, hurried=hurried)
    raise RuntimeError("eight Starts refused in a row")


def _teach_one(
    session, page, hand, rng, *, hurried: bool = False, shot=None, shot_refused=None
) -> int:
    """One trace: to a high place, start, to a low place, end; the Starts refused."""
    drive.wait_for(
        lambda: page.teach_handle is not None and not page._action.locked(), "the teaching page"
    )
    high = HIGH + rng.normal(0.0, STRAY, 3)
    low = LOW * np.array([1.0, rng.choice([-1.0, 1.0]), 1.0]) + rng.normal(0.0, STRAY, 3)
    refused = _start(page, hand, rng, high, hurried=hurried, shot=shot_refused)
    _move_teach_handle(page, hand, low)
    drive.wait_for(lambda: not page.end_trace.disabled, "a trace to end")
    if shot is not None:
        shot()
    taken = page.traces_taken
    drive.click(hand.tab, "End the trace")
    drive.wait_for(  # taken (or refused), and the learning done when it was the last
        lambda: (page.traces_taken > taken or not page.recording) and not page._action.locked(),
        "the trace reaching the server",
        120,
    )
    return refused


def run(
    db: Path,
    *,
    after: int = 3,
    seed: int = 39,
    port: int = 8094,
    params: dict | None = None,
    most: int = 12,
    browser=None,
    hurried: bool = False,
    shots: Path | None = None,
    overrides: dict | None = None,
) -> int:
    """A session of ``db`` corrected and taught through the page; its id. ``params`` are
    KF-CRX's (e.g. fewer traces); ``most`` corrections at most before it must have asked;
    ``hurried``: see the module; ``shots``: a folder for a screenshot of every step;
    ``overrides``: changes to fig. 4's study (``load_study``'s, e.g. a smaller plan atlas)."""
    if browser is None:
        from playwright.sync_api import sync_playwright

        with sync_playwright() as p:
            browser = drive.launch(p)
            try:
                return run(
                    db, after=after, seed=seed, port=port, params=params, most=most,
                    browser=browser, hurried=hurried, shots=shots, overrides=overrides,
                )  # fmt: skip
            finally:
                browser.close()
    from corrections_sim.figures.presets import EXPERIMENTS_DIR
    from corrections_sim.study import schema

    settings = schema.load_study(
        EXPERIMENTS_DIR / "fig4.toml", name="fig4", quick=False, overrides=overrides
    )
    rng = np.random.default_rng([seed, 2])
    with StudyLog(db) as log:
        session = Session.start(
            settings, log, learner="KF-CRX", params=params, participant="scripted-teacher"
        )
        truth = {"features": list(PERSON_FEATURES), "theta": list(PERSON_THETA)}
        log.add_event(session.id, -1, "truth", truth | {"hurried": hurried})
        server, page = serve(session, port=port)
        try:
            tab = drive.open_page(browser, f"http://127.0.0.1:{port}")
            hand = Hand(tab, rng)
            drive.wait_for(lambda: page.proposal is not None, "the first plan")
            taught_at = None
            skips = 0

            def shot(name: str) -> None:
                if shots is not None:
                    shots.mkdir(parents=True, exist_ok=True)
                    drive.wait_for(lambda: not page._action.locked(), "the page at rest", 120)
                    tab.screenshot(path=str(shots / f"{name}.png"))

            shot("0-first-plan")
            refusal_shot = False
            while taught_at is None or session.iteration < taught_at + after:
                if page.teaching:
                    shot("1-asked-to-teach")
                    hidden = below_the_fold(tab)
                    if hidden:  # this person does not scroll: the page failed them
                        raise RuntimeError(f"below the first screen: {', '.join(hidden)}")
                    while page.teaching:
                        first = len(session.traces) == 0
                        refused = _teach_one(
                            session, page, hand, rng, hurried=hurried,
                            shot=(lambda: shot("2-recording-a-trace")) if first else None,
                            shot_refused=None if refusal_shot else shot,
                        )  # fmt: skip
                        refusal_shot = refusal_shot or refused > 0
                        print(
                            f"trace {len(session.traces)}/{session.wanted} "
                            f"({refused} Starts refused)",
                            file=sys.stderr,
                        )
                        if len(session.traces) == 1:
                            shot("3-one-trace-kept")
                    taught_at = session.iteration
                    drive.wait_for(lambda: page.proposal is not None, "the plan over it", 180)
                    shot("4-plan-over-the-learnt-feature")
                    if shots is not None:  # the other heat map, for the pictures only
                        page.map_mode.value = MAP_SHAPE
                        page._redraw_map()
                        shot("4a-what-you-showed-it")
                        page.map_mode.value = MAP_REWARD
                        page._redraw_map()
                    continue
                if taught_at is None and session.iteration >= most:
                    raise RuntimeError(f"{most} corrections and the robot never asked")
                done = _correct(session, page, hand, rng)
                print(f"correction {session.iteration}", file=sys.stderr)
                if done is not True:
                    skips += 1
                    if skips > 40:
                        raise RuntimeError("40 environments skipped: nothing to correct")
                    skip(tab, page, session, False)
            drive.click(tab, "Done: deploy")
            drive.wait_for(page.finished.is_set, "the end", 180)
            shot("5-the-end")
            tab.close()
        finally:
            server.stop()
        return session.id


def report(log: StudyLog, session_id: int) -> dict:
    """From the log: each trace's start against where the page showed the cup when Start was
    taken (m), the learnt feature's quality against `human` (Spearman's ρ, R²), the plans'
    closest approach of the cup to the person (m) before and after the teaching, and how far
    the teaching moved the plan away from the person: in each environment planned after it,
    the closest approach of that plan minus that of the plan the robot would have made there
    with its belief just before (planned again, over the study's features; issue 69)."""
    from corrections_sim.learnt.training import quality, register_logged
    from corrections_sim.session.session import settings_from_log

    events = log.events(session_id)
    starts = [e["detail"] for e in events if e["kind"] == "trace_start"]
    taken, pending = {}, None
    for e in events:  # the start each kept trace began with (a log older than the page's
        if e["kind"] == "trace_start":  # starts has none)
            pending = e["detail"]
        elif e["kind"] in ("trace_cancelled", "trace_lost"):
            pending = None
        elif e["kind"] == "trace":
            taken[e["detail"]["index"]] = (pending, e["detail"])
            pending = None
    gaps = [
        float(np.linalg.norm(cup_pose(np.array(t["states"][0]))[1] - np.array(st["shown"])))
        for st, t in taken.values()
        if st is not None and "shown" in st
    ]
    learnt = [e for e in events if e["kind"] == "learnt"]
    rows = log.corrections(session_id)
    person = np.array(HUMAN_POSITION)

    def closest(row) -> float:
        return float(np.min(np.linalg.norm(cup_path(row["xi_robot"]) - person, axis=1)))

    out: dict = {
        "traces": len(taken),
        "starts": len(starts),
        "start_gap_max_m": max(gaps, default=None),
        "starts_within_1cm": sum(g <= 0.01 for g in gaps),
    }
    if learnt:
        after = int(learnt[0]["iteration"])
        detail = learnt[0]["detail"]
        settings = settings_from_log(log.session(session_id).settings)
        q = quality(register_logged(detail), "human", settings.envs()[int(detail["env_index"])])
        out["spearman_vs_human"], out["r2_vs_human"] = q.spearman, q.r2
        out["feature"] = detail["feature"]
        out["closest_before_m"] = [round(closest(r), 3) for r in rows if r["iteration"] < after]
        out["closest_after_m"] = [round(closest(r), 3) for r in rows if r["iteration"] >= after]
        moved = _moved_away(settings, rows, after, person)
        out["moved_away_m"] = [round(m, 3) for m in moved]
        out["moved_away_mean_m"] = round(float(np.mean(moved)), 3) if moved else None
    return out


def _moved_away(settings, rows, after: int, person: np.ndarray) -> list[float]:
    """Per correction from ``after`` on: the closest approach of its plan to ``person`` minus
    that of the plan at the belief of the last correction before ``after`` in its
    environment (m; positive: away from them)."""
    before = [r for r in rows if r["iteration"] < after]
    if not before:
        return []
    k = len(settings.features)
    theta = np.asarray(before[-1]["theta_after"], float)[:k]
    config = PlannerConfig(features=settings.features, **dict(settings.planner))
    book = PlanBook(shared_planner(config))
    envs = settings.envs()

    def closest(xi) -> float:
        return float(np.min(np.linalg.norm(cup_path(np.asarray(xi)) - person, axis=1)))

    out = []
    for r in rows:
        if r["iteration"] >= after:
            was = book.plan(theta, envs[int(r["env_index"])]).trajectory
            out.append(closest(r["xi_robot"]) - closest(was))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m scripted_people.teach", description=__doc__.split("\n\n")[0]
    )
    p.add_argument("--db", type=Path, required=True)
    p.add_argument("--after", type=int, default=3, help="corrections after the teaching")
    p.add_argument(
        "--traces", type=int, help="the traces KF-CRX asks for (its expand_traces; default 10)"
    )
    p.add_argument("--seed", type=int, default=39)
    p.add_argument("--port", type=int, default=8094)
    p.add_argument("--hurried", action="store_true", help="Start within 0.2 s of a drag")
    p.add_argument("--shots", type=Path, help="a folder for a screenshot of every step")
    args = p.parse_args(argv)
    if args.after < 1:
        print(f"error: --after {args.after}: at least 1", file=sys.stderr)
        return 2
    if args.traces is not None and args.traces < 1:
        print(
            f"error: --traces {args.traces}: at least 1 (0: the robot never asks)", file=sys.stderr
        )
        return 2
    args.db.parent.mkdir(parents=True, exist_ok=True)
    params = None if args.traces is None else {"expand_traces": args.traces}
    session_id = run(
        args.db, after=args.after, seed=args.seed, port=args.port, hurried=args.hurried,
        shots=args.shots, params=params,
    )  # fmt: skip
    print(f"session {session_id} of {args.db}: corrected, taught, corrected")
    with StudyLog(args.db) as log:
        text = json.dumps(report(log, session_id), indent=1) + "\n"
    path = args.db.with_name(args.db.stem + "-report.json")
    path.write_text(text)
    print(text + f"(written to {path})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
