"""``python -m benchmarks.bench study``: several participants at once on one study server.

Four participants (``--participants``) each go through a protocol of one KF-CL condition in
drag mode (fig. 4's paper settings, the 48 environments) on one server in this process, each
driven by a scripted websocket client that speaks viser's messages as a browser's tab does:
the participant's code and "Start", "Continue", then per correction a drag of the cup's
handle (lifted 6 cm at the waypoint shown) and a click on "Submit correction". The four
submit at the same moment (a barrier), the worst case for one server. Latency is the
server's: from the submit's arrival to the next plan sent (``Page.last_submit``), per
correction and participant. Isolation: each participant's page holds only their own session,
and each session's logged θ̂ is the one their page showed last.

With ``--browser`` the fourth participant is a chromium tab driven with the mouse, and the
report says whether its page showed its own next plan after each submit (its correction's
number, and the cup where that participant's plan has it). Each states a preference first, as
the page asks before the first correction.

It prints figures and never asserts.
"""

from __future__ import annotations

import socket
import statistics
import tempfile
import threading
import time
from pathlib import Path

import msgspec
import numpy as np

from benchmarks.sizes import toml_value
from corrections_sim.pages.server import open_server
from corrections_sim.pages.study import StudyServer
from corrections_sim.scene.robot import cup_pose
from corrections_sim.userstudy.cohort import open_run
from scripted_people import drive

PROTOCOL = """description = "bench: {n} at once"
study = "fig4"
seed = 5
corrections = {corrections}
welcome = "Bench."
[[conditions]]
name = "CL"
learner = "{learner}"
{set}"""


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _send(tab, message: dict) -> None:
    tab.socket.send(msgspec.msgpack.encode(message))


def _click(tab, handle) -> None:
    _send(tab, {"type": "GuiUpdateMessage", "uuid": handle._impl.uuid, "updates": {"value": True}})


def _participant(study, code, link, corrections, barrier, out, errors) -> None:
    try:
        ws = "http://" + link.split("ws://")[1]
        with drive.SocketTab(ws) as tab:
            view = drive.wait_for(lambda: study.participant_views().get(code), "the view")
            box = drive.wait_for(lambda: view.controls.get("code"), "the code box")
            _send(
                tab,
                {"type": "GuiUpdateMessage", "uuid": box._impl.uuid, "updates": {"value": code}},
            )
            drive.wait_for(lambda: box.value == code, "the code typed")
            _click(tab, view.controls["start"])
            button = drive.wait_for(lambda: view.controls.get("continue"), "the welcome")
            _click(tab, button)
            page = drive.wait_for(lambda: view.page, "the trial's page", timeout=300)
            # The stated preference first (the page asks for it before the first correction).
            drive.wait_for(lambda: page.proposal is not None, "the first plan", timeout=300)
            for slider, value in zip(page.sliders, (1.0, -1.0), strict=True):
                _send(
                    tab,
                    {
                        "type": "GuiUpdateMessage",
                        "uuid": slider._impl.uuid,
                        "updates": {"value": value},
                    },
                )
            drive.wait_for(lambda: "-1.0" in page.pref_echo.content, "the preference received")
            _click(tab, page.state_button)
            drive.wait_for(lambda: "recorded as" in page.last_message, "the preference recorded")
            spans = []
            for _ in range(corrections):
                # The plan and its handle on the page (the handle comes after the plan).
                drive.wait_for(
                    lambda: (
                        page.handle is not None and not page._busy and page.proposal is not None
                    ),
                    "the plan",
                    timeout=300,
                )
                plan = page.proposal.plan.trajectory
                i = int(page.waypoint.value)
                cup = cup_pose(plan[i])[1] + np.array([0.0, 0.0, 0.06])
                drags = page.drags
                # A client echoes the owner of the node it moves: its connection's id.
                owner = str(view.client.client_id)
                _send(
                    tab,
                    {
                        "type": "TransformControlsDragStartMessage",
                        "name": "/handle",
                        "owner": owner,
                    },
                )
                _send(
                    tab,
                    {
                        "type": "TransformControlsUpdateMessage",
                        "name": "/handle",
                        "wxyz": [1.0, 0.0, 0.0, 0.0],
                        "position": cup.tolist(),
                        "owner": owner,
                    },
                )
                _send(
                    tab,
                    {"type": "TransformControlsDragEndMessage", "name": "/handle", "owner": owner},
                )
                try:
                    drive.wait_for(lambda d=drags: page.drags > d, "the drag", timeout=60)
                except TimeoutError:
                    raise TimeoutError(
                        f"drag: handle {page.handle.position} sent {cup} owner {owner} "
                        f"scene {view.client.scene._owner_id} msg {page.last_message!r}"
                    ) from None
                if page.corrected is None:
                    _click(tab, page.skip_button)
                    drive.wait_for(lambda: not page.skip_button.disabled, "skipped", 120)
                    continue
                submitted = page.submitted
                barrier.wait(timeout=600)
                _click(tab, page.submit_button)
                drive.wait_for(lambda s=submitted: page.submitted > s, "the submit", 300)
                drive.wait_for(lambda: not page._busy, "the next plan", 300)
                arrived, sent = page.last_submit
                spans.append(sent - arrived)
            out[code] = {
                "spans": spans,
                "session": page.session.id,
                "theta": page.session.belief.theta.copy(),
            }
    except Exception as exc:  # reported, and the others are let go
        errors.append(f"{code}: {exc!r}")
        barrier.abort()


def _browser_participant(study, code, link, corrections, barrier, out, errors, browser):
    """The same participant in chromium, with the mouse (this thread: Playwright's sync API
    stays in the thread that made it); also checks that the page shows this participant's
    own next plan (its correction count and environment) after each submit."""
    tab = browser.new_page(viewport=drive.VIEWPORT)
    try:
        tab.goto(link)
        tab.get_by_text("Type the participant code").wait_for(timeout=120_000)
        drive.fill_text(tab, 0, code)
        drive.click(tab, "Start")
        tab.get_by_role("button", name="Continue").wait_for(timeout=60_000)
        drive.click(tab, "Continue")
        view = study.participant_views()[code]
        page = drive.wait_for(lambda: view.page, "the trial's page", timeout=300)
        spans, shown = [], 0
        tab.get_by_role("button", name="Submit correction").wait_for(timeout=300_000)
        drive.state_preference(tab, [1.0, -1.0])
        for _ in range(corrections):
            tab.get_by_role("button", name="Submit correction").wait_for(timeout=300_000)
            drive.wait_for(lambda: page.handle is not None and not page._busy, "the plan", 300)
            drive.wait_for(lambda: drive.cup_position(tab), "the cup on the page")
            try:
                drive.until_landed(
                    lambda: drive.drag_cup(tab, 50),
                    lambda: "orange path" in drive.status(tab),
                    timeout=20.0,
                )
            except TimeoutError:
                drive.click(tab, "Skip: show me another scene")
                continue
            submitted = page.submitted
            barrier.wait(timeout=600)
            drive.click(tab, "Submit correction")
            drive.wait_for(lambda s=submitted: page.submitted > s, "the submit", 300)
            drive.wait_for(lambda: not page._busy, "the next plan", 300)
            arrived, sent = page.last_submit
            spans.append(sent - arrived)
            # Its own next plan: the correction's number, and the cup where its plan has it.
            # (the trial's length is the page's: the protocol gives it 20 corrections more
            # than are made, so that no trial ends during the benchmark)
            title = f"Correction {page.session.iteration + 1} of {page.limit}"
            plan = page.proposal.plan.trajectory
            cup = cup_pose(plan[int(page.waypoint.value)])[1]

            def own(t=title, cup=cup) -> bool:
                at = drive.cup_position(tab)
                return (
                    t in drive.status(tab) and at is not None and np.allclose(at[1], cup, atol=2e-3)
                )

            try:
                drive.wait_for(own, "its own plan", 60)
                shown += 1
            except TimeoutError:
                pass
        out[code] = {
            "spans": spans,
            "session": page.session.id,
            "theta": page.session.belief.theta.copy(),
            "shown": shown,
        }
    except Exception as exc:  # reported, and the others are let go
        errors.append(f"{code} (chromium): {exc!r}")
        barrier.abort()
    finally:
        tab.close()


def run(
    participants: int = 4,
    corrections: int = 6,
    learner: str = "KF-CL",
    *,
    chromium: bool = False,
    smaller: dict | None = None,
) -> dict:
    """``chromium``: the last participant is a chromium tab driven with the mouse;
    ``smaller``: the study made smaller (:func:`~benchmarks.sizes.study_overrides`), as the
    condition's ``set``."""
    folder = Path(tempfile.mkdtemp(prefix="bench-study-"))
    protocol = folder / "protocol.toml"
    changed = "".join(f"set.{k} = {toml_value(v)}\n" for k, v in (smaller or {}).items())
    protocol.write_text(
        PROTOCOL.format(n=participants, corrections=corrections + 20, learner=learner, set=changed)
    )
    run_ = open_run(protocol, folder / "study.sqlite")
    run_.read_plans()  # as serve-study does before participants come
    server = open_server("127.0.0.1", _port())
    study = StudyServer(server, run_, host="127.0.0.1")
    links = {f"B{i}": study.enroll(f"B{i}") for i in range(participants)}
    barrier = threading.Barrier(participants)
    out: dict = {}
    errors: list[str] = []
    scripted = dict(links)
    in_browser = scripted.popitem() if chromium else None
    threads = [
        threading.Thread(
            target=_participant, args=(study, code, link, corrections, barrier, out, errors)
        )
        for code, link in scripted.items()
    ]
    started = time.perf_counter()
    for t in threads:
        t.start()
    if in_browser is not None:
        from playwright.sync_api import sync_playwright

        with sync_playwright() as p:
            browser = drive.launch(p)
            try:
                _browser_participant(study, *in_browser, corrections, barrier, out, errors, browser)
            finally:
                browser.close()
    for t in threads:
        t.join()
    wall = time.perf_counter() - started
    isolated = len({r["session"] for r in out.values()}) == len(out)
    for code, r in out.items():
        rows = run_.log.corrections(r["session"])
        isolated &= run_.log.session(r["session"]).participant == code
        isolated &= bool(rows) and np.array_equal(rows[-1]["theta_after"], r["theta"])
    server.stop()
    run_.log.close()
    spans = [s for r in out.values() for s in r["spans"]]
    return {
        "spans": spans,
        "shown": {c: (r["shown"], len(r["spans"])) for c, r in out.items() if "shown" in r},
        "per": {c: r["spans"] for c, r in out.items()},
        "wall": wall,
        "errors": errors,
        "isolated": isolated,
        "learner": learner,
        "participants": participants,
        "smaller": dict(smaller or {}),
    }


def _smaller(smaller: dict | None) -> str:
    """What a smaller study changed, in words (nothing for the paper's settings)."""
    said = []
    if smaller and "atlas" in smaller:
        said.append(f"the atlas at {smaller['atlas']['points']} points a weight")
    if smaller and "environments" in smaller:
        said.append(f"{len(smaller['environments'])} environments")
    return f" ({', '.join(said)})" if said else ""


def report(result: dict) -> list[str]:
    spans = np.array(result["spans"])
    lines = [
        f"{result['participants']} participants at once, {result['learner']} drag, "
        f"fig. 4 settings{_smaller(result['smaller'])}, submits together (a barrier); "
        f"{len(spans)} corrections, "
        f"{result['wall']:.0f} s",
    ]
    if len(spans):
        lines.append(
            f"server submit -> next plan: median {np.median(spans):.3f} s (target <= 0.6), "
            f"p90 {np.percentile(spans, 90):.3f} s, max {spans.max():.3f} s"
        )
        for code, per in result["per"].items():
            lines.append(f"  {code}: median {statistics.median(per):.3f} s over {len(per)}")
    lines.append(f"isolation (own session, own θ̂ logged): {result['isolated']}")
    for code, (shown, of) in result.get("shown", {}).items():
        lines.append(f"{code} in chromium: its own next plan on the page after {shown} of {of}")
    lines += [f"error: {e}" for e in result["errors"]]
    return lines


if __name__ == "__main__":
    print("\n".join(report(run())))
