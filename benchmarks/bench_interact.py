"""``python -m benchmarks.bench interact``: how fast the page answers a person.

For each learner: a session on fig. 4's paper settings (the 48 environments), served by viser
in this process and driven in Debian's chromium by Playwright with the mouse, as a person with
a stated preference θ = (+1, −1) over (laptop, table) would: at the waypoint shown, drag the
cup part of the way toward the laptop (x, then y) and lift it off the table top (z), then
submit. Latency is from the mouse press on "Submit" to the DOM change that shows the next
plan's title, both on the browser's own clock (a MutationObserver in the page); beside it the
same span as the driver sees it (polled every 50 ms, each poll a round trip to the browser),
and the server's own time for the learner's update and the next plan.

Every session is logged to ``--db``; ``run replay DB`` replays it through any learners.
"""

from __future__ import annotations

import socket
import time
from pathlib import Path

import numpy as np

from corrections_sim.figures.presets import EXPERIMENTS_DIR
from corrections_sim.pages.server import serve
from corrections_sim.session.log import StudyLog
from corrections_sim.session.session import Session
from corrections_sim.study.schema import load_study
from scripted_people import drive

STATED = (1.0, -1.0)
#: Environments in a row the scripted person may fail to correct (each skipped) before the
#: benchmark gives up with an error rather than loop.
MAX_SKIPS_IN_A_ROW = 5

#: In the page, before a submit: the browser's own clock at the mouse press and at the first
#: DOM change that shows the next plan's title (argument: the title's start), so the latency
#: is the page's and not the driver's polling (every 50 ms, each poll a round trip).
_WATCH = """title => {
  const t = window.__latency = {click: null, shown: null};
  document.addEventListener("mousedown", () => { t.click = performance.now(); },
                            {capture: true, once: true});
  const seen = new MutationObserver(() => {
    if (t.shown === null && document.body.textContent.includes(title)) {
      t.shown = performance.now();
      seen.disconnect();
    }
  });
  seen.observe(document.body, {childList: true, subtree: true, characterData: true});
}"""


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _correct(tab, page, session) -> tuple[bool, int]:
    """One correction by the scripted person: (a drag was accepted, drags that missed)."""
    env = session.proposal().env
    _, cup = drive.cup_position(tab)
    toward = np.clip(0.5 * (env.laptop[:2] - cup[:2]), -0.15, 0.15)
    missed = 0
    for axis, metres in ((0, toward[0]), (1, toward[1]), (2, 0.06)):
        if abs(metres) < 0.03:  # a few pixels: too short a drag to grab and move
            continue
        drags = page.drags
        try:
            drive.until_landed(
                lambda axis=axis, m=float(metres): drive.move_cup(tab, axis, m),
                lambda drags=drags: page.drags > drags,
                timeout=10.0,
            )
        except TimeoutError:  # the arrow seen nearly end-on: this axis is left out
            missed += 1
    return page.corrected is not None, missed


def bench_learner(
    browser,
    log: StudyLog,
    learner: str,
    corrections: int,
    shot: Path | None,
    smaller: dict | None = None,
):
    overrides = dict(smaller or {})
    path = EXPERIMENTS_DIR / "fig4.toml"
    settings = load_study(path, name="fig4", quick=False, overrides=overrides)
    t0 = time.perf_counter()
    session = Session.start(settings, log, learner=learner, participant=f"bench-{learner}")
    ready = time.perf_counter() - t0
    server, page = serve(session, port=_port())
    try:
        tab = drive.open_page(browser, f"http://127.0.0.1:{server.get_port()}")
        drive.set_number(tab, 0, STATED[0])
        drive.set_number(tab, 1, STATED[1])
        drive.click(tab, "State my preference")
        drive.wait_for(lambda: log.session(session.id).stated_theta is not None, "stated θ")
        browser_s, polled_s, server_s, parts, skipped, missed_drags = [], [], [], [], 0, 0
        in_a_row = 0
        while len(browser_s) < corrections:
            accepted, missed = _correct(tab, page, session)
            missed_drags += missed
            if not accepted:
                skipped += 1
                in_a_row += 1
                if in_a_row > MAX_SKIPS_IN_A_ROW:
                    raise RuntimeError(
                        f"{learner}: the scripted person could not correct {in_a_row} "
                        f"environments in a row (session {session.id}: its refused events and "
                        "skips are in the log)"
                    )
                draws = session.draws
                drive.click(tab, "Skip this environment")
                drive.wait_for(
                    lambda d=draws: session.draws > d and not page._action.locked(),
                    "the next plan",
                )
                continue
            in_a_row = 0
            # The status line the page writes once the next plan is on it.
            nxt = f"Correction {session.iteration + 1} recorded"
            # A plain mouse click on the button, as a person's (Playwright's click() would
            # first wait for the element to be stable over animation frames).
            button = tab.get_by_role("button", name="Submit correction").bounding_box()
            drive.wait_for(lambda: not page.submit_button.disabled, "submit enabled")
            tab.evaluate(_WATCH, nxt)
            t1 = time.perf_counter()
            tab.mouse.click(button["x"] + button["width"] / 2, button["y"] + button["height"] / 2)
            drive.wait_for(lambda n=nxt: n in drive.status(tab), "the next plan", timeout=120)
            t2 = time.perf_counter()
            arrived, sent = page.last_submit
            seen = tab.evaluate("window.__latency")
            browser_s.append((seen["shown"] - seen["click"]) / 1000)
            polled_s.append(t2 - t1)
            server_s.append(sent - arrived)
            parts.append((arrived - t1, sent - arrived, t2 - sent))
        if shot is not None:
            shot.parent.mkdir(parents=True, exist_ok=True)
            tab.screenshot(path=str(shot))
        tab.close()
    finally:
        server.stop()
    error = float(np.abs(session.belief.theta - STATED).sum())
    return {
        "learner": learner,
        "session": session.id,
        "ready_s": ready,
        "browser_s": browser_s,
        "polled_s": polled_s,
        "server_s": server_s,
        "skipped": skipped,
        "missed": missed_drags,
        "parts": np.array(parts),
        "theta": session.belief.theta,
        "error": error,
    }


def run_bench(
    learners: list[str],
    corrections: int,
    db: Path,
    shot: Path | None,
    smaller: dict | None = None,
) -> list[str]:
    """The page's latency per learner (module docstring); ``smaller``: overrides that shrink
    fig. 4's study (:mod:`benchmarks.sizes`)."""
    from playwright.sync_api import sync_playwright

    lines = [
        f"interact benchmark: fig. 4's 48 environments, {corrections} corrections per learner, "
        f"chromium {drive.chromium()} (software WebGL), log {db}",
        f"{'learner':8} {'submit -> next plan on page (s)':>34} {'server (s)':>18} "
        f"{'skips':>6} {'final θ̂':>18} {'error vs stated':>16}",
    ]
    with StudyLog(db) as log, sync_playwright() as p:
        browser = drive.launch(p)
        for i, learner in enumerate(learners):
            shown = shot if i == 0 else None
            r = bench_learner(browser, log, learner, corrections, shown, smaller)
            b, s = np.array(r["browser_s"]), np.array(r["server_s"])
            polled = np.array(r["polled_s"])
            click, _, show = np.median(r["parts"], axis=0)
            lines.append(
                f"{learner:8} median {np.median(b):5.2f} p90 {np.percentile(b, 90):5.2f} "
                f"max {b.max():5.2f}   median {np.median(s):5.2f} max {s.max():5.2f} "
                f"{r['skipped']:6d} {np.round(r['theta'], 3)!s:>18} {r['error']:16.3f}"
                f"   (session {r['session']})"
            )
            lines.append(
                f"{'':8} as the driver polls it: median {np.median(polled):.2f} p90 "
                f"{np.percentile(polled, 90):.2f} max {polled.max():.2f} s"
            )
            lines.append(
                f"{'':8} median parts: click reaches the server {click:.2f} s, server "
                f"{np.median(s):.2f} s, update reaches the page's text {show:.2f} s; "
                f"session ready in {r['ready_s']:.1f} s; {r['missed']} drags missed the handle"
            )
        browser.close()
    return lines
