"""A participant's page, driven headless by websocket messages as its controls send them: what
it says (plain words, no researcher's internals), what it requires (the stated preference, the
minimum corrections), the way out, and a questionnaire whose answers are only what the
participant gave, shown back before they are written, kept over a reload."""

from __future__ import annotations

import socket
from types import SimpleNamespace

import msgspec
import numpy as np
import pytest

from corrections_sim.pages.server import open_server
from corrections_sim.pages.study import StudyServer
from corrections_sim.userstudy.cohort import open_run
from corrections_sim.userstudy.protocol import TLX_SCALES
from scripted_people import drive

STUDY = """environments = ["s0-t0-l1", "s0-t0-l2", "s1-t1-l0"]
theta_star = [1.0, -1.0]
learners = ["KF-C"]
seed = 3
iterations = 3
"""
PROTOCOL = """description = "the page"
study = "small.toml"
seed = 3
corrections = 3
min_corrections = 1
welcome = "Hello."
[[conditions]]
name = "C"
learner = "KF-C"
[[conditions]]
name = "CL"
learner = "KF-CL"
[[questionnaires.condition]]
kind = "tlx"
"""


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def study(tmp_path):
    (tmp_path / "small.toml").write_text(STUDY)
    (tmp_path / "protocol.toml").write_text(PROTOCOL)
    run = open_run(tmp_path / "protocol.toml", tmp_path / "study.sqlite")
    server = open_server("127.0.0.1", _port())
    served = StudyServer(server, run, host="127.0.0.1")
    yield served
    server.stop()
    run.log.close()


class Tab(drive.SocketTab):
    def send(self, handle, value) -> None:
        message = {
            "type": "GuiUpdateMessage",
            "uuid": handle._impl.uuid,
            "updates": {"value": value},
        }
        self.socket.send(msgspec.msgpack.encode(message))


def _tab(link: str) -> Tab:
    return Tab("http://" + link.split("ws://")[1])


def _view(study, code: str, after=None):
    return drive.wait_for(
        lambda: (v := study.participant_views().get(code)) is not None and v is not after and v,
        "the participant's page",
    )


def _closed(study, code: str, view) -> None:
    """Wait until the server has seen ``view``'s tab close: a reload before that is told "your
    page is open in another tab", and a test that reads the participant's view would find the
    closed one (its controls no longer on any page)."""
    drive.wait_for(lambda: study.participant_views().get(code) is not view, "the tab closed")


def _planned(page) -> bool:
    """The page shows its plan (its title is written after the plan is made)."""
    return hasattr(page, "title") and "Correction" in page.title.content


def test_a_trial_page_speaks_to_a_participant_and_requires_what_the_study_needs(study):
    link = study.enroll("P1")
    with _tab(link) as tab:
        view = _view(study, "P1")
        tab.send(drive.wait_for(lambda: view.controls.get("code"), "the code box"), "p1")
        drive.wait_for(lambda: view.controls["code"].value == "p1", "the code typed")
        tab.send(view.controls["start"], True)  # any case will do
        tab.send(drive.wait_for(lambda: view.controls.get("continue"), "the welcome"), True)
        page = drive.wait_for(lambda: view.page, "the trial's page", timeout=120)
        drive.wait_for(lambda: _planned(page), "the plan on the page", timeout=120)
        # Plain words: no environment's name, no learner, no estimate, no teaching.
        title = page.title.content
        assert title.startswith("### Correction 1 of 3") and "environment" not in title
        assert "First state your preference" in title and "Learner" not in title
        assert not page.belief_image.visible and not page.teach_folder.visible
        assert page.waypoint.label == "Point to move" and "Point" in page.where.content
        assert "(" not in page.where.content  # no coordinates on the page
        # Done is there (the minimum is 1 of 3) but not before the first correction.
        assert page.done_button.visible and page.done_button.disabled
        # A drag before the stated preference is put back.
        page.handle.position = page.handle.position + np.array([0.0, 0.0, 0.06])
        page._dragged()
        assert "First state your preference" in page.last_message and page.corrected is None
        # The preference: sliders not moved are no answer.
        tab.send(page.state_button, True)
        drive.wait_for(lambda: "Not yet" in page.last_message, "the refusal")
        assert "laptop, table" in page.last_message
        assert study.run.log.session(page.session.id).stated_theta is None
        tab.send(page.sliders[0], 1.0)
        tab.send(page.sliders[1], -1.0)
        drive.wait_for(lambda: "table -1.0" in page.pref_echo.content, "the echo")
        tab.send(page.state_button, True)
        drive.wait_for(lambda: "recorded as" in page.last_message, "the record")
        logged = study.run.log.session(page.session.id).stated_theta
        np.testing.assert_array_equal(logged, [1.0, -1.0])
        assert "First state" not in page.title.content
    # A reload on the same server: straight back to the trial (no code again), the stated
    # preference on its sliders as the log has it.
    _closed(study, "P1", view)
    with _tab(link) as tab:
        view = _view(study, "P1", after=view)
        page = drive.wait_for(lambda: view.page, "the trial's page again", timeout=120)
        drive.wait_for(lambda: _planned(page), "the plan on the page", timeout=120)
        assert "code" not in view.controls
        assert [s.value for s in page.sliders] == [1.0, -1.0]
        assert "First state" not in page.title.content
        page.handle.position = page.handle.position + np.array([0.0, 0.0, 0.06])
        page._dragged()
        assert page.corrected is not None
        tab.send(page.submit_button, True)
        drive.wait_for(lambda: page.session.iteration == 1, "the correction", timeout=120)
        drive.wait_for(lambda: not page.done_button.disabled, "Done offered after the minimum")
        # The way out: asked again, then the trial ends early and is logged as such.
        tab.send(view.controls["stop"], True)
        drive.wait_for(lambda: view.controls.get("confirm_leave"), "the question")
        assert study.run.participant("P1").current().kind == "trial"
        tab.send(view.controls["confirm_leave"], True)
        drive.wait_for(lambda: study.run.participant("P1").current().kind == "questions", "on")
        (stopped,) = study.run.log.participant_events("P1", "stopped")
        assert stopped["detail"]["corrections"] == 1


def test_a_questionnaire_stores_only_what_was_given_and_shows_it_back_first(study):
    from benchmarks.bench_questionnaire import at_questionnaire

    link = at_questionnaire(study, "P1")  # through the trial headless, let in
    values = [70, 10, 40, 30, 60, 75]
    with _tab(link) as tab:
        view = _view(study, "P1")
        submit = drive.wait_for(lambda: view.controls.get("submit"), "the questionnaire")
        items = [f"tlx.{s}" for s in TLX_SCALES]
        # Nothing moved: Submit is refused, naming every scale, and nothing is stored.
        tab.send(submit, True)
        # Refused, and drawn again: a new Submit button, drawn after every item's control
        # (the message alone comes before the redraw; a suite run read the items half-drawn).
        drive.wait_for(
            lambda: (
                "not answered yet: Mental demand" in view.message
                and view.controls.get("submit") not in (None, submit)
            ),
            "refused, and the page drawn again",
        )
        assert study.run.log.answers("P1") == []
        for item, value in zip(items[:2], values[:2], strict=True):
            tab.send(view.controls[item], value)
        draft = study.drafts[("P1", "C.questions")]
        drive.wait_for(lambda: len(draft) == 2, "two answers received")
    # A reload on the same server: straight back, the two answers kept, the rest not.
    _closed(study, "P1", view)
    with _tab(link) as tab:
        view = _view(study, "P1", after=view)
        drive.wait_for(lambda: view.controls.get("submit"), "the questionnaire again")
        assert [view.controls[i].value for i in items[:2]] == values[:2]
        for item, value in zip(items[2:], values[2:], strict=True):
            tab.send(view.controls[item], value)
        drive.wait_for(lambda: len(study.drafts[("P1", "C.questions")]) == 6, "all received")
        tab.send(view.controls["submit"], True)
        # The confirmation's button is drawn after every item's control: waiting for it, not
        # for pending alone, waits for the whole redraw (a suite run once read the controls
        # half-drawn).
        drive.wait_for(
            lambda: view.pending is not None and view.controls.get("confirm"),
            "the answers shown back",
        )
        assert view.pending == dict(zip(items, values, strict=True))
        assert study.run.log.answers("P1") == []  # not written before the confirmation
        assert all(view.controls[i].disabled for i in items)
        tab.send(view.controls["confirm"], True)
        drive.wait_for(lambda: study.run.log.answers("P1"), "written")
    stored = {a["item"]: a["value"] for a in study.run.log.answers("P1")}
    assert stored == dict(zip(items, values, strict=True))
    asked = study.run.log.asked("P1")
    assert asked[("P1", "C.questions", "tlx.performance")]["anchors"] == ["Perfect", "Failure"]


def test_an_experimenters_link_of_an_earlier_server_says_so(study, monkeypatch):
    from corrections_sim.pages import study as study_page

    said = []

    class Gui:
        def add_markdown(self, text):
            said.append(text)

    class Client:
        client_id = 99
        gui = Gui()

    monkeypatch.setattr(study_page, "connection_path", lambda server, client: "/x/an-old-one")
    study._connect(Client())
    assert said == [
        "**This experimenter link is from an earlier run of the server.** Use the "
        "experimenter link the server printed when it started."
    ]
    assert study.refused == 1


def test_a_click_while_the_server_stops_ends_quietly(study):
    """Continue pressed as the command closes the study log (Ctrl-C): the click ends without
    an error, as nothing it did could be kept."""
    link = study.enroll("P1")
    with _tab(link) as tab:
        view = _view(study, "P1")
        tab.send(drive.wait_for(lambda: view.controls.get("code"), "the code box"), "p1")
        drive.wait_for(lambda: view.controls["code"].value == "p1", "the code typed")
        tab.send(view.controls["start"], True)
        button = drive.wait_for(lambda: view.controls.get("continue"), "the welcome")
        study.run.log.close()
        (handler,) = button._impl.update_cb
        handler(SimpleNamespace(client=view.client, target=button))  # would write the log
        assert study.run.log.closed
