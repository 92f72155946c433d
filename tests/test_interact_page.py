"""Every control of the pages at the moments a person can press it, on the server's state
(issue 37): a tab is a websocket that speaks viser's protocol (``drive.SocketTab``), so the
page is built as for a browser, and a click is the page's own click handler. What only a
browser shows (the page after Done, a hand's grab of the moving handle) is in
``test_interact_browser.py``."""

from __future__ import annotations

import asyncio
import sqlite3
from types import SimpleNamespace

import numpy as np
import pytest
from test_interact_browser import STUDY, _free_port

from benchmarks.bench_catch import physical_session
from corrections_sim.pages.server import serve
from corrections_sim.session.log import StudyLog
from corrections_sim.session.session import Session
from corrections_sim.study.schema import parse_study
from scripted_people import drive


@pytest.fixture
def served(tmp_path):
    """A function (physical=False, speed=1.0, session=None) -> (session, page, url) on a fresh
    server: ``session`` served (its log closed after the test), else a new KF-C or physical
    one."""
    made = []

    def make(*, physical: bool = False, speed: float = 1.0, session=None):
        if session is None:
            log = StudyLog(tmp_path / f"s{len(made)}.sqlite")
            if physical:
                session = physical_session(log, "p")
            else:
                session = Session.start(parse_study(STUDY, name="t"), log, learner="KF-C")
        server, page = serve(session, port=_free_port(), speed=speed)
        made.append((server, page, session.log))
        return session, page, f"http://127.0.0.1:{server.get_port()}"

    yield make
    for server, page, log in made:
        page.settle()
        server.stop()
        log.close()


def _ready(page) -> None:
    """The first plan is on the page and every control is set for it: the page draws the plan
    and sets its controls one by one under its lock, so Play may be enabled before Skip and
    Done are (a check between the two failed once under the parallel suite)."""
    drive.wait_for(lambda: page.proposal is not None and not page.play.disabled, "the plan")
    with page._lock:
        pass


def _click(page, name: str) -> None:
    """What a click on the button does on the server (the handler the page registered)."""
    button = getattr(page, name)
    (handler,) = button._impl.update_cb
    handler(SimpleNamespace(client=page.client, target=button))


def _enabled(page) -> dict:
    return {name: not getattr(page, name).disabled for name in _BUTTONS if hasattr(page, name)}


_BUTTONS = ("state_button", "play", "submit_button", "reset_button", "skip_button", "done_button")


def test_done_at_rest_shows_the_deployment_and_keeps_it_for_a_reload(served):
    session, page, url = served()
    with drive.SocketTab(url):
        _ready(page)
        assert _enabled(page) == {
            "state_button": True,
            "play": True,
            "submit_button": False,  # nothing dragged yet
            "reset_button": False,
            "skip_button": True,
            "done_button": True,
        }
        _click(page, "done_button")
        assert page.finished.is_set() and session.ended
        assert not page.left.is_set()  # the tab that shows the end is still open
        assert [e["kind"] for e in session.log.events(session.id)][-1] == "done"
        assert page.deployment is not None
        assert "Session ended after 0 corrections" in page.last_message
        assert "close this tab" in page.last_message
        assert not any(_enabled(page).values())
        assert not page.handle.visible
        # A late click on Done or Skip (crossing the message that disabled it) does nothing.
        events = len(session.log.events(session.id))
        _click(page, "skip_button")
        _click(page, "done_button")
        assert len(session.log.events(session.id)) == events
    drive.wait_for(page.left.is_set, "the tab that showed the end closing")
    # A reload after Done shows the end again (it used to fail: the session has no plan).
    with drive.SocketTab(url):
        drive.wait_for(lambda: page.owner is not None, "the reloaded tab")
        drive.wait_for(lambda: "has ended" in page.title.content, "the end on the reload")
        assert not any(_enabled(page).values())


def test_a_click_that_arrives_while_the_robot_works_is_dropped_and_said(served):
    session, page, url = served()
    with drive.SocketTab(url):
        _ready(page)
        shown = page.proposal
        skips = len(session.log.events(session.id, "skip"))
        with page._action:  # the learner's update and the next plan are being worked on
            _click(page, "skip_button")
            _click(page, "done_button")
        assert page.dropped == 2 and "that click was not taken" in page.last_message
        assert page.proposal is shown and not session.ended
        assert len(session.log.events(session.id, "skip")) == skips
        # A submit with nothing dragged (its button disabled) records nothing.
        _click(page, "submit_button")
        assert session.log.corrections(session.id) == []


def test_a_drag_submitted_then_skip_and_reset_keep_the_log_consistent(served):
    session, page, url = served()
    with drive.SocketTab(url):
        _ready(page)
        i = int(page.waypoint.value)
        cup = session.waypoint_cup(i) + np.array([0.0, 0.0, 0.05])
        page.handle.position = cup
        page._dragged()
        assert page.corrected is not None
        assert _enabled(page)["submit_button"] and _enabled(page)["reset_button"]
        _click(page, "skip_button")  # a drag left unsubmitted is undone, then skipped
        kinds = [e["kind"] for e in session.log.events(session.id)]
        assert kinds[-2:] == ["undo", "skip"] and page.corrected is None
        assert not _enabled(page)["submit_button"]
        page.handle.position = session.waypoint_cup(i) + np.array([0.0, 0.0, 0.05])
        page._dragged()
        _click(page, "submit_button")
        assert page.submitted == 1 and len(session.log.corrections(session.id)) == 1
        assert not _enabled(page)["state_button"]  # a preference is stated before correcting
        assert "After **1** correction:" in page.belief_text.content


def _grab(page, phase: str, position) -> None:
    event = SimpleNamespace(phase=phase, target=SimpleNamespace(position=tuple(position)))
    asyncio.run(page._grabbed(event))


def test_during_a_motion_only_the_handle_works_and_a_hold_past_the_end_is_a_push(served):
    session, page, url = served(physical=True)
    with drive.SocketTab(url):
        _ready(page)
        _click(page, "play")
        drive.wait_for(lambda: page.motion is not None and page.motion.time > 0.5, "the motion")
        assert not any(_enabled(page).values())  # Play, Skip and Done wait for the end
        _click(page, "done_button")
        _click(page, "skip_button")
        _click(page, "play")
        assert not session.ended and session.log.events(session.id, "skip") == []
        # The handle waits where the motion started; the hand holds the cup where it is at
        # the grab (a clutch): no force until the hand moves, then the spring of the move.
        handle = np.asarray(page.handle.position, float)
        assert np.linalg.norm(handle - page.motion.cup()) > 0.01
        _grab(page, "start", handle)
        assert page.grabs == 1
        assert np.linalg.norm(page.hand_force(page._hold)) == 0.0
        _grab(page, "update", handle + (0.0, 0.0, 0.05))
        np.testing.assert_allclose(page.hand_force(page._hold), (0.0, 0.0, 0.05 * 300.0))
        # ... and never let go: the motion ends with the cup held.
        drive.wait_for(lambda: page.pushes == 1, "the push learnt at the end", timeout=30)
        (row,) = session.log.corrections(session.id)
        assert row["drag"]["released_at"] == pytest.approx(page.duration, abs=0.02)
        assert row["drag"]["peak_force"] > 5.0
        assert session.log.events(session.id, "replan") == []  # nothing left to replan
        drive.wait_for(lambda: _enabled(page)["done_button"], "Done after the motion")
        assert page.grab is None  # the end let go of the cup
        assert "Push 1 learnt" in page.last_message and page.where.content == ""
        _click(page, "done_button")
        assert session.ended and page.finished.is_set()


def test_a_tab_closed_during_a_push_lets_go_and_the_next_tab_waits_for_the_motion(served):
    session, page, url = served(physical=True)
    tab = drive.SocketTab(url)
    _ready(page)
    _click(page, "play")
    drive.wait_for(lambda: page.motion is not None and page.motion.time > 0.5, "the motion")
    handle = np.asarray(page.handle.position, float)
    _grab(page, "start", handle)
    _grab(page, "update", handle + (0.0, 0.0, 0.05))
    drive.wait_for(lambda: page.motion.pushed, "the robot feeling the push")
    tab.close()
    drive.wait_for(lambda: page.owner is None, "the tab closing")
    assert page.grab is None  # no hand holds on for the rest of the motion
    with drive.SocketTab(url):
        # The new page waits for the motion to end: the push is learnt and logged by then.
        drive.wait_for(lambda: page.owner is not None, "the next tab", timeout=30)
        assert page.motion.done and page.pushes == 1
        assert len(session.log.corrections(session.id)) == 1
        _ready(page)
        assert page.proposal.iteration == 1 and "Push 2" in page.title.content


def test_a_push_being_learnt_when_the_server_stops_is_logged_before_the_log_closes(served):
    # What `interact` does on Ctrl-C (and the catch benchmark at its end): settle, stop,
    # close. The last CI run closed the log under a push the physics thread was learning.
    session, page, url = served(physical=True)
    with drive.SocketTab(url):
        _ready(page)
        _click(page, "play")
        drive.wait_for(lambda: page.motion is not None and page.motion.time > 0.5, "the motion")
        handle = np.asarray(page.handle.position, float)
        _grab(page, "start", handle)
        _grab(page, "update", handle + (0.0, 0.0, 0.05))
        drive.wait_for(lambda: page.motion.pushed, "the robot feeling the push")
        assert not page.settle(0.01)  # still moving (and the hand still holds on)
    assert page.settle()
    assert page.pushes == 1 and len(session.log.corrections(session.id)) == 1
    session.log.close()  # as the server's end does; the fixture's second close is harmless
    assert page.settle()


def test_a_motion_with_no_push_puts_the_handle_back_on_the_cup(served):
    session, page, url = served(physical=True)
    with drive.SocketTab(url):
        _ready(page)
        # A drag of the handle at rest moves nothing: the handle goes back on the cup.
        rest = np.asarray(page.handle.position, float)
        _grab(page, "start", rest)
        _grab(page, "update", rest + (0.0, 0.0, 0.1))
        assert page.hand_force(rest) is None
        page.handle.position = rest + (0.0, 0.0, 0.1)
        _grab(page, "end", rest + (0.0, 0.0, 0.1))
        np.testing.assert_allclose(page.handle.position, rest)
        _click(page, "play")
        drive.wait_for(lambda: page.motion is not None, "the motion")
        # The motion's thread ends after it has set the buttons back (``_in_motion`` is
        # cleared first, under the page's lock: a check right after it raced the buttons).
        assert page.settle(30)
        assert "No push was felt" in page.last_message and page.where.content == ""
        np.testing.assert_allclose(page.handle.position, page.motion.cup(), atol=1e-9)
        assert session.log.corrections(session.id) == []
        assert _enabled(page) == {
            "play": True,
            "submit_button": False,
            "skip_button": True,
            "done_button": True,
        }


def test_a_click_while_the_server_stops_ends_quietly_and_logs_nothing(served, capsys):
    """A click the page is still answering when its command closes the log (Ctrl-C while a
    person clicks) ends without a traceback: nothing it did could be kept. A closed database
    elsewhere, the log still open, is still an error."""
    session, page, url = served()
    with drive.SocketTab(url):
        _ready(page)
        session.log.close()
        _click(page, "skip_button")  # would read and write the closed log
        assert "Traceback" not in capsys.readouterr().err
    other = sqlite3.connect(":memory:")
    other.close()
    log = StudyLog(session.log.path)
    with pytest.raises(sqlite3.ProgrammingError), log.unless_closed():
        other.execute("SELECT 1")
    log.close()


def test_a_connection_closed_before_its_request_is_not_logged_as_a_failure():
    """websockets logs "opening handshake failed" with a traceback when a client (a
    browser's speculative connection) closes before sending a request line; the server's
    filter drops exactly that, and keeps every other failure."""
    import logging
    import sys

    from corrections_sim.pages.server import _ClosedBeforeRequest

    def record(exc: BaseException | None, message: str = "opening handshake failed"):
        info = None
        if exc is not None:
            try:
                raise exc
            except BaseException:
                info = sys.exc_info()
        return logging.LogRecord("websockets.server", logging.ERROR, "", 0, message, (), info)

    closed = ValueError("did not receive a valid HTTP request")
    closed.__cause__ = EOFError("connection closed while reading HTTP request line")
    keep = _ClosedBeforeRequest()
    assert not keep.filter(record(closed))
    assert not keep.filter(record(EOFError("stream ends after 0 bytes")))
    assert keep.filter(record(ValueError("invalid Connection header")))
    assert keep.filter(record(None))
    assert keep.filter(record(EOFError("x"), "connection handler failed"))
