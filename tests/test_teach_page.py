"""The teaching page headless (issue 49): a trace starts where the page shows the cup, can be
cancelled and is drawn; a person may stop early or set their traces aside, knowingly; the heat
map means the same before and after learning, on the current table, and comes back after a
reload or a resume; the person's panel speaks in words.

A tab is a websocket (``drive.SocketTab``), a drag is the handle's position set as the browser
would and the page's own drag handler, a click the button's own handler (see
``test_interact_page.py``). The hurried person with a mouse is ``bench teach``."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from test_interact_page import served  # noqa: F401 (a fixture, used by name)

from corrections_sim.pages.teach import (
    MAP_GRID,
    MAP_SHAPE,
    MAP_UNSURE,
    off_laptop,
    want_colours,
    want_probability,
)
from corrections_sim.people.teacher import Teacher
from corrections_sim.people.users import make_user
from corrections_sim.scene import geometry as g
from corrections_sim.scene.robot import cup_pose
from corrections_sim.session.log import StudyLog
from corrections_sim.session.session import Session
from corrections_sim.session.simulate import simulate
from corrections_sim.session.teaching import MIN_TRACES
from corrections_sim.study.schema import parse_study
from scripted_people import drive

STUDY = {
    "environments": ["s0-t0-l1", "s0-t0-l2", "s1-t1-l0"],
    "theta_star": [1.0, -1.0],
    "learners": ["KF-CRX"],
    "seed": 5,
    "iterations": 3,
}
PARAMS = {"expand_traces": 4, "expand_after": 1, "expand_below": 0.99}
#: What a person's panel must not show (an expert folder may).
SYMBOLS = ("θ", "β", "ρ", "ξ", "γ", "Φ", "φ", "σ", "eq. (")


@pytest.fixture
def teaching(served, tmp_path):  # noqa: F811 (the imported fixture, by name)
    """A function (session=None) -> (session, page, url): ``session`` served, else a KF-CRX
    session one correction in, asking for four traces; its log and server closed after the
    test (``served``'s)."""

    def make(session=None):  # (the folder: make.folder)
        if session is None:
            log = StudyLog(tmp_path / "teach.sqlite")
            session = Session.start(
                parse_study(STUDY, name="teach"), log, learner="KF-CRX", params=PARAMS
            )
            simulate(session, make_user("biased"), (1.0, -1.0), 1)
        return served(session=session)

    make.folder = tmp_path
    return make


def _ready(page) -> None:
    drive.wait_for(lambda: page.teach_handle is not None and page.teaching, "the teaching")
    with page._lock:
        pass


def _click(page, name: str) -> None:
    button = getattr(page, name)
    (handler,) = button._impl.update_cb
    handler(SimpleNamespace(client=page.client, target=button))


def _drag(page, to, *, end: bool = True) -> None:
    """A drag of the teaching handle to ``to`` (3,), its positions on the way reported."""
    handle = page.teach_handle
    start = np.array(handle.position, float)
    for f in (0.5, 1.0):
        handle.position = start + f * (np.asarray(to, float) - start)
        page._teach_moved(SimpleNamespace(phase="update", target=handle))
    if end:
        page._teach_moved(SimpleNamespace(phase="end", target=handle))


def _cup(page) -> np.ndarray:
    return cup_pose(page.teach_q)[1]


def _person_text(page) -> str:
    return " ".join(
        [page.title.content, page.status.content, page.map_caption.content, page.where.content]
    )


def _trace(page, to) -> None:
    _click(page, "start_trace")
    assert page.recording, page.last_message
    _drag(page, to)
    _click(page, "end_trace")


def test_a_trace_starts_only_where_the_page_shows_the_cup(teaching):
    session, page, url = teaching()
    with drive.SocketTab(url):
        _ready(page)
        assert page.title.content.startswith("### Teach me what you mind")
        assert not page.waypoint.visible and not page.submit_button.visible  # stepped aside
        assert not page.preference_folder.visible
        here = _cup(page)
        # A drag under way (not ended): the arm has not followed, Start is refused.
        _drag(page, here + [0.0, 0.08, 0.0], end=False)
        _click(page, "start_trace")
        assert not page.recording and "still checking" in page.last_message
        assert session.open_trace is None and session.log.events(session.id, "trace_start") == []
        # A drag the arm cannot reach: the cup goes back, and Start says why.
        _drag(page, here + [1.5, 0.0, 0.0])
        assert page.teach_refused and "Out of reach" in page.last_message
        np.testing.assert_allclose(page.teach_handle.position, here, atol=1e-9)
        _click(page, "start_trace")
        assert not page.recording and "went back" in page.last_message
        # A drag it can reach: the message moves on, Start starts there.
        _drag(page, here + [0.0, 0.08, 0.0])
        assert "Out of reach" not in page.last_message
        shown = np.array(page.teach_handle.position, float)
        _click(page, "start_trace")
        assert page.recording
        (start,) = session.log.events(session.id, "trace_start")
        assert np.linalg.norm(np.array(start["detail"]["cup"]) - shown) < 0.01
        # Recording: an out-of-reach drag adds nothing, a reachable one is drawn.
        before = list(page.trace_points)
        _drag(page, here + [1.5, 0.0, 0.0])
        assert len(page.trace_points) == len(before) and page.end_trace.disabled
        assert not page.cancel_trace.disabled
        _drag(page, shown + [-0.1, 0.0, -0.05])
        assert len(page.trace_points) >= 2 and not page.end_trace.disabled
        _click(page, "end_trace")
        (trace,) = session.log.events(session.id, "trace")
        first = cup_pose(np.array(trace["detail"]["states"][0]))[1]
        assert np.linalg.norm(first - shown) < 0.01  # the logged trace starts where shown
        assert "Trace 1 kept" in page.last_message and "1 given, 3 to go" in page.title.content


def test_a_started_trace_can_be_cancelled(teaching):
    session, page, url = teaching()
    with drive.SocketTab(url):
        _ready(page)
        _click(page, "start_trace")
        assert page.recording and page.end_trace.disabled and not page.cancel_trace.disabled
        assert page.decline.disabled and page.start_trace.disabled
        _drag(page, _cup(page) + [0.0, -0.1, 0.0])
        _click(page, "cancel_trace")
        assert not page.recording and page.trace_points == []
        assert "cancelled" in page.last_message
        kinds = [e["kind"] for e in session.log.events(session.id)]
        assert kinds[-2:] == ["trace_start", "trace_cancelled"] and "trace" not in kinds
        assert not page.start_trace.disabled


def test_a_person_may_stop_after_the_fewest_traces(teaching):
    session, page, url = teaching()
    with drive.SocketTab(url):
        _ready(page)
        assert f"You may stop after {MIN_TRACES}" in page.title.content
        for i in range(MIN_TRACES):
            assert page.learn_now.disabled
            _trace(page, _cup(page) + [0.0, 0.1 * (-1) ** i, -0.04])
        assert len(session.traces) == MIN_TRACES and not page.learn_now.disabled
        _click(page, "learn_now")
        drive.wait_for(lambda: page.proposal is not None, "the plan over the feature", 120)
        assert not page.teaching and session.belief.dim == 3
        (learnt,) = session.log.events(session.id, "learnt")
        assert learnt["detail"]["traces"] == MIN_TRACES
        assert f"Learnt from your {MIN_TRACES} traces" in page.last_message
        assert page.waypoint.visible and page.submit_button.visible  # back to correcting


def test_i_cannot_show_it_asks_before_setting_traces_aside_and_says_how_many(teaching):
    session, page, url = teaching()
    with drive.SocketTab(url):
        _ready(page)
        _trace(page, _cup(page) + [0.0, 0.1, -0.04])
        events = len(session.log.events(session.id))
        _click(page, "decline")
        assert page.teaching and len(session.log.events(session.id)) == events  # only asked
        assert "You gave 1 trace" in page.last_message and page.set_aside.visible
        assert not page.set_aside.disabled
        _click(page, "set_aside")
        drive.wait_for(lambda: page.proposal is not None, "the next plan", 120)
        (declined,) = session.log.events(session.id, "traces")
        assert declined["detail"] == {"declined": True, "set_aside": 1}
        assert "Your 1 trace is set aside" in page.last_message
        assert not page.set_aside.visible and session.wanted == 0


def test_the_heat_map_is_how_sure_the_robot_is_that_it_wants_the_cup_there():
    """The probability under N(θ̂, P) that a place's reward is above the table's mean: blue
    (sure it would), red (sure it would not), nothing where it cannot tell; a constant offset
    and a feature the same everywhere change nothing (their uncertainty is no difference
    between places)."""
    phi = np.array([[0.0, 1.0, 2.0, 3.0], [5.0, 5.0, 5.0, 5.0]])  # the second: uniform
    p = want_probability([1.0, 7.0], np.diag([0.01, 100.0]), phi)
    np.testing.assert_allclose(p, [0.0, 0.0, 1.0, 1.0], atol=1e-6)
    colours, drawn = want_colours([1.0, 7.0], np.diag([0.01, 100.0]), phi)
    assert drawn.all() and colours[3, 2] > colours[3, 0] and colours[0, 0] > colours[0, 2]
    vague = want_probability([0.1, 0.0], np.eye(2), phi)  # sd ≫ the differences
    assert np.all(np.abs(vague - 0.5) < 0.1)
    assert not want_colours([0.1, 0.0], np.eye(2), phi)[1].any()
    assert np.abs(want_probability([0.1, 0.0], np.eye(2), phi)[0] - 0.5) <= MAP_UNSURE
    assert want_colours([1.0, 0.0], None, phi)[1].tolist() == [True, True, True, True]


def test_the_heat_map_stays_on_the_current_table_and_comes_back(teaching):
    session, page, url = teaching()
    with drive.SocketTab(url):
        _ready(page)
        caption = page.map_caption.content
        assert "What I want now" in caption and "cannot tell yet" in caption
        _on_the_table(page.map_points, page._map_env())
        page.map_height.value = 0.1
        page._redraw_map()
        assert "0.10 m above the table" in page.map_caption.content
        for i in range(MIN_TRACES):
            _trace(page, _cup(page) + [0.0, 0.1 * (-1) ** i, -0.04])
        _click(page, "learn_now")
        drive.wait_for(lambda: page.proposal is not None, "the plan", 120)
        # The same meaning after learning, on the plan's table, the caption not overwritten.
        assert "What I want now" in page.map_caption.content
        _on_the_table(page.map_points, page.proposal.env)
        page.map_mode.value = MAP_SHAPE
        page._redraw_map()
        assert "What you showed me" in page.map_caption.content
        page.map_mode.value = "What the robot wants now"
        page._redraw_map()
        for text in (_person_text(page),):
            assert not any(sym in text for sym in SYMBOLS), text
    # A reload: the map comes back.
    drive.wait_for(lambda: page.owner is None, "the tab closed")
    with drive.SocketTab(url):
        drive.wait_for(lambda: page.owner is not None and page.proposal is not None, "reload")
        drive.wait_for(lambda: "What I want now" in page.map_caption.content, "the map again")


def _on_the_table(points, env) -> None:
    """The heat map's drawn tiles lie on ``env``'s table top and none over its laptop."""
    assert len(points) > 0
    hx, hy = g.TABLE_HALF_SIZE
    assert np.all(np.abs(points[:, :2] - env.table) <= [hx + 1e-9, hy + 1e-9])
    assert np.all(points[:, 2] == pytest.approx(g.TABLE_TOP_Z + 0.004, abs=2e-3))
    assert off_laptop(points, env).all()


def test_after_learning_the_heat_map_shows_what_the_robot_is_sure_of(teaching):
    """Learnt from four traces, then two corrections: the map was all grey ("All grey: I
    cannot tell yet"), covering the table and the laptop's keyboard, through four corrections
    after learning (a reward against zero under the new weight's sd ≈ 1). It now draws where
    the robot is sure it wants the cup, or not, and leaves the laptop and the rest of the
    table in sight."""
    log = StudyLog(teaching.folder / "learnt.sqlite")
    session = Session.start(parse_study(STUDY, name="teach"), log, learner="KF-CRX", params=PARAMS)
    simulate(session, make_user("biased"), (1.0, -1.0), 1)
    env = session.envs[session.last_env]
    for trace in Teacher().traces("human", PARAMS["expand_traces"], env, np.random.default_rng(0)):
        session.start_trace({"q": trace[0].tolist()})
        session.add_trace(trace)
    session.learn_feature()
    simulate(session, make_user("biased"), (1.0, -1.0), 2)
    _, page, url = teaching(session)
    with drive.SocketTab(url):
        drive.wait_for(lambda: page.proposal is not None and page.map_points is not None, "map")
        with page._lock:
            points, caption = page.map_points, page.map_caption.content
        _on_the_table(points, page.proposal.env)
        assert len(points) >= 0.5 * MAP_GRID[0] * MAP_GRID[1], len(points)
        assert "the surer I am" in caption and "nothing is drawn (" in caption, caption


def test_a_resume_after_a_kill_mid_trace_says_so_and_puts_the_cup_where_it_began(teaching):
    session, page, url = teaching()
    with drive.SocketTab(url):
        _ready(page)
        _trace(page, _cup(page) + [0.0, 0.1, -0.04])
        _drag(page, _cup(page) + [0.0, -0.08, 0.02])
        began = page.teach_q.copy()
        _click(page, "start_trace")
        _drag(page, _cup(page) + [0.0, 0.1, -0.04])  # the server is killed here
    resumed = Session.resume(session.log, session.id)
    assert len(resumed.traces) == 1 and resumed.lost_trace["index"] == 1
    _, page2, url2 = teaching(resumed)
    with drive.SocketTab(url2):
        _ready(page2)
        assert "Trace 2 was cut short" in page2.last_message
        np.testing.assert_allclose(page2.teach_q, began)
        assert not any(sym in _person_text(page2) for sym in SYMBOLS)
        assert "What I want now" in page2.map_caption.content


def test_a_reload_while_recording_goes_on_recording(teaching):
    session, page, url = teaching()
    with drive.SocketTab(url):
        _ready(page)
        _click(page, "start_trace")
        _drag(page, _cup(page) + [0.0, 0.1, -0.04])
        points = list(page.trace_points)
    drive.wait_for(lambda: page.owner is None, "the tab closed")
    with drive.SocketTab(url):
        drive.wait_for(lambda: page.owner is not None, "the reload")
        _ready(page)
        assert page.recording and len(page.trace_points) == len(points)
        assert "Still recording" in page.last_message
        _click(page, "end_trace")
        assert len(session.log.events(session.id, "trace")) == 1
