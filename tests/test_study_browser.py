"""A study served to several participants at once: each reaches only their own page, a whole
short protocol in chromium for two people side by side, and a killed server that loses no
correction and no answer.

Marked ``browser`` (chromium, as tests/test_interact_browser.py)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import msgspec
import pytest
import viser

from corrections_sim.pages.server import open_server
from corrections_sim.pages.study import StudyServer
from corrections_sim.session.log import StudyLog
from corrections_sim.userstudy.cohort import open_run
from scripted_people import drive

pytestmark = pytest.mark.browser

STUDY = """environments = ["s0-t0-l1", "s0-t0-l2", "s1-t1-l0", "s2-t0-l1"]
theta_star = [1.0, -1.0]
learners = ["KF-C"]
seed = 3
iterations = 3
"""
PROTOCOL = """description = "two robots in a browser"
study = "small.toml"
seed = 3
corrections = CORRECTIONS
welcome = "Hello there."
[practice]
learner = "KF-C"
corrections = 1
[[conditions]]
name = "C"
learner = "KF-C"
[[conditions]]
name = "CL"
learner = "KF-CL"
[[questionnaires.condition]]
id = "understood"
text = "The robot understood me."
points = 5
"""


def _write(folder: Path, corrections: int = 1) -> Path:
    (folder / "small.toml").write_text(STUDY)
    path = folder / "protocol.toml"
    path.write_text(PROTOCOL.replace("CORRECTIONS", str(corrections)))
    return path


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def browser():
    if drive.chromium() is None:
        if os.environ.get("CI"):
            pytest.fail("CI needs chromium for the browser tests (.ci/setup installs it)")
        pytest.skip("no chromium (apt-get install chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        launched = drive.launch(p)
        yield launched
        launched.close()


@pytest.fixture
def study(tmp_path):
    run = open_run(_write(tmp_path), tmp_path / "study.sqlite")
    server = open_server("127.0.0.1", _free_port())
    served = StudyServer(server, run, host="127.0.0.1")
    yield served
    server.stop()
    run.log.close()


def _enter(tab, code: str) -> None:
    tab.get_by_text("Type the participant code").wait_for(timeout=60_000)
    drive.fill_text(tab, 0, code)
    drive.click(tab, "Start")


def _camera(study, code: str):
    """The camera of ``code``'s page as the server knows it, or None (a drag that misses the
    handle orbits the view, so a retry aims through this one)."""
    view = study.participant_views().get(code)
    client = None if view is None else view.client
    return None if client is None else client.camera


def _correct(tab, camera=lambda: None) -> None:
    """One drag of the cup and its submission (the stated preference first, where the page
    asks for it); the trial's end then offers to go on. ``camera()``: the page's camera where
    the server runs in this process (see :func:`_camera`), else None (the initial view)."""
    tab.get_by_role("button", name="Submit correction").wait_for(timeout=120_000)
    drive.wait_for(lambda: drive.cup_position(tab), "the cup on the page")
    if "First state your preference" in drive.status(tab):
        drive.state_preference(tab, [1.0, -1.0])
    drive.until_landed(
        lambda: drive.drag_cup(tab, 50, camera=camera()),
        lambda: "orange path" in drive.status(tab),
    )
    drive.click(tab, "Submit correction")


def test_two_participants_go_through_a_whole_protocol_at_once(browser, study):
    links = {code: study.enroll(code) for code in ("P1", "P2")}
    tabs = {}
    try:
        for code, link in links.items():
            tabs[code] = browser.new_page(viewport=drive.VIEWPORT)
            tabs[code].goto(link)
            _enter(tabs[code], code)
        for tab in tabs.values():
            tab.get_by_text("Hello there.").wait_for(timeout=60_000)
            drive.click(tab, "Continue")
        for round_ in range(3):  # the practice, then each robot
            for code, tab in tabs.items():
                _correct(tab, lambda code=code: _camera(study, code))
            for tab in tabs.values():
                text = drive.wait_for(
                    lambda t=tab: "This trial is over" in drive.status(t) and drive.status(t),
                    "the trial's end",
                )
                # Blind: the page never names the learner, nor shows the robot's estimate.
                assert "KF-C" not in text and "KF-CL" not in text and "θ" not in text
                drive.click(tab, "Continue")
            if round_ == 0:
                continue
            for tab in tabs.values():
                _answer_understood(tab, "4")
        for tab in tabs.values():
            tab.get_by_text("you are done").wait_for(timeout=60_000)
    finally:
        for tab in tabs.values():
            tab.close()
    log = study.run.log
    for code in links:
        where = study.run.participant(code).where()
        assert where.step.kind == "end"
        answers = [a for a in log.answers(code) if a["item"] == "understood"]
        assert [a["value"] for a in answers] == [4, 4]
        sessions = [s for s in log.session_ids() if log.session(s).participant == code]
        assert len(sessions) == 3  # the practice and two trials, each its own session
        assert all(len(log.corrections(s)) == 1 for s in sessions)
    # Counterbalanced: the two participants met the robots in opposite orders.
    assert study.run.protocol.order_of(0) == study.run.protocol.order_of(1)[::-1]


def _answer_understood(tab, value: str) -> None:
    """The questionnaire's one item: Submit unanswered is refused on the page, then the
    answer, what the page received, and its confirmation."""
    tab.get_by_text("The robot understood me.").wait_for(timeout=60_000)
    drive.click(tab, "Submit answers")
    tab.get_by_text("not answered yet: The robot understood me.").wait_for(timeout=30_000)
    drive.choose(tab, 0, value)
    drive.wait_for(lambda: drive.echoes(tab) == [value], "the answer reaching the server")
    drive.click(tab, "Submit answers")
    tab.get_by_text("Please check your answers").wait_for(timeout=30_000)
    assert drive.confirmed_values(tab) == [value]
    drive.click(tab, "Yes, submit these answers")


def test_a_link_reaches_only_its_own_participant(browser, study):
    p1 = study.enroll("P1")
    study.enroll("P2")
    token = re.search(r"/p/([^/]+)$", p1).group(1)
    tabs = []
    try:
        # A guessed link: one line, no scene, no control.
        guessed = browser.new_page()
        tabs.append(guessed)
        guessed.goto(p1.replace(token, token[:-4] + "AAAA"))
        guessed.get_by_text("This link is not valid").wait_for(timeout=60_000)
        assert guessed.get_by_role("button").count() == 0 or "Start" not in drive.status(guessed)
        # Another participant's code typed on one's link is refused.
        mine = browser.new_page()
        tabs.append(mine)
        mine.goto(p1)
        _enter(mine, "P2")
        mine.get_by_text("not the code of this link").wait_for(timeout=30_000)
        drive.fill_text(mine, 0, "P1")
        drive.click(mine, "Start")
        mine.get_by_text("Hello there.").wait_for(timeout=60_000)
        # A second tab of the same link is turned away.
        second = browser.new_page()
        tabs.append(second)
        second.goto(p1)
        second.get_by_text("open in another tab").wait_for(timeout=60_000)
    finally:
        for tab in tabs:
            tab.close()
    assert study.refused >= 1
    assert study.run.participant("P2").where().position == 0


def test_messages_replayed_on_another_connection_change_nothing(study):
    p1, p2 = study.enroll("P1"), study.enroll("P2")
    port = study.server.get_port()

    def ws(link: str) -> str:
        return "http://" + link.split("ws://")[1]

    with drive.SocketTab(ws(p1)):
        view = drive.wait_for(lambda: study.participant_views().get("P1"), "P1's page")
        view.entered = True  # past the code (as typed)
        view.render()
        button = drive.wait_for(lambda: view.controls.get("continue"), "P1's Continue")
        uuid = button._impl.uuid
        click = {"type": "GuiUpdateMessage", "uuid": uuid, "updates": {"value": True}}
        # P2's connection, and one with no valid link, replay P1's click: nothing moves.
        for link in (ws(p2), f"http://127.0.0.1:{port}/p/guess"):
            with drive.SocketTab(link) as other:
                other.socket.send(msgspec.msgpack.encode(click))
                drive.wait_for(lambda o=other: o.received > 0, "the server's answer")
        assert study.run.participant("P1").where().position == 0
        assert study.run.participant("P2").where().position == 0
    assert viser.__version__ == "1.1.1"  # connection_path reads viser 1.1.1's connections


def _serve(protocol: Path, db: Path, port: int, *enroll: str):
    command = [sys.executable, "-m", "corrections_sim.run", "serve-study", str(protocol)]
    command += ["--db", str(db), "--port", str(port)]
    if enroll:
        command += ["--enroll", ",".join(enroll)]
    server = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=Path.cwd()
    )
    links = {}
    while True:  # the links come on the standard output, a line each
        line = server.stdout.readline()
        assert line, "the server ended before serving"
        who, link = line.split(": ", 1)
        if who.startswith("participant "):
            links[who.split()[1]] = link.strip()
        if who == "experimenter":
            links["experimenter"] = link.strip()
            return server, links


def _back_after_a_kill(browser, tab, link: str, protocol: Path, db: Path, port: int):
    """A new server on the log (a new experimenter's secret): the participant's link still
    works, they type their code and wait; the experimenter lets them continue. The server."""
    server, links = _serve(protocol, db, port)
    tab.goto(link)
    _enter(tab, "P1")
    tab.get_by_text("Welcome back").wait_for(timeout=60_000)
    boss = browser.new_page()
    try:
        boss.goto(links["experimenter"])
        boss.get_by_text("P1").first.wait_for(timeout=60_000)
        drive.fill_text(boss, 1, "P1")  # the "Code" box (the first is "New code")
        drive.click(boss, "Let continue")
        drive.wait_for(lambda: "Welcome back" not in drive.status(tab), "let in", timeout=120)
    finally:
        boss.close()
    return server


def test_a_killed_server_loses_nothing_and_the_participant_resumes_at_the_same_step(
    browser, tmp_path
):
    protocol = _write(tmp_path, corrections=2)
    db = tmp_path / "study.sqlite"
    port = _free_port()
    server, links = _serve(protocol, db, port, "P1")
    tab = browser.new_page(viewport=drive.VIEWPORT)
    try:
        tab.goto(links["P1"])
        _enter(tab, "P1")
        tab.get_by_text("Hello there.").wait_for(timeout=60_000)
        drive.click(tab, "Continue")
        _correct(tab)  # the practice's one correction
        # The study's trial-over panel, not the page's own end (its title and status also say
        # "This trial is over" until the panel is drawn).
        tab.get_by_text("Press Continue to go on").wait_for(timeout=120_000)
        drive.click(tab, "Continue")
        _correct(tab)  # the first robot's first of two
        drive.wait_for(lambda: "Correction 2" in drive.status(tab), "the next plan")
        server.send_signal(signal.SIGKILL)  # mid-condition
        server.wait(timeout=30)
        with StudyLog(db) as log:
            session = log.steps("P1")[-1]["session_id"]
            assert len(log.corrections(session)) == 1
        server = _back_after_a_kill(browser, tab, links["P1"], protocol, db, port)
        tab.get_by_text("Correction 2").wait_for(timeout=120_000)  # the same trial, resumed
        _correct(tab)
        tab.get_by_text("Press Continue to go on").wait_for(timeout=120_000)
        drive.click(tab, "Continue")
        tab.get_by_text("The robot understood me.").wait_for(timeout=60_000)
        server.send_signal(signal.SIGKILL)  # mid-questionnaire (nothing submitted yet)
        server.wait(timeout=30)
        server = _back_after_a_kill(browser, tab, links["P1"], protocol, db, port)
        _answer_understood(tab, "5")  # the same step
        tab.get_by_text("Robot 2 of 2").wait_for(timeout=60_000)
        server.send_signal(signal.SIGKILL)  # right after the questionnaire
        server.wait(timeout=30)
    finally:
        tab.close()
        if server.poll() is None:
            server.kill()
    with StudyLog(db) as log:
        assert [a["value"] for a in log.answers("P1")] == [5]
        steps = log.steps("P1")
        trials = [s for s in steps if s["key"].endswith("trial1")]
        assert len(log.corrections(trials[0]["session_id"])) == 2
        asked = [s for s in steps if s["key"].endswith(".questions")]
        assert len(asked) == 1 and asked[0]["finished"] is not None
    run = open_run(protocol, db)
    assert run.participant("P1").current().text.startswith("**Robot 2 of 2**")
    run.log.close()


def test_the_experimenters_page_enrolls_and_withdraws(study):
    """Driven by websocket messages as the page's buttons send them (no browser needed)."""
    with drive.SocketTab("http://" + study.experimenter_link().split("ws://")[1]) as tab:
        view = drive.wait_for(
            lambda: next((v for v in study.views.values() if hasattr(v, "buttons")), None),
            "the experimenter's page",
        )

        def send(handle, value) -> None:
            message = {
                "type": "GuiUpdateMessage",
                "uuid": handle._impl.uuid,
                "updates": {"value": value},
            }
            tab.socket.send(msgspec.msgpack.encode(message))

        send(view.new_code, "P7")
        drive.wait_for(lambda: view.new_code.value == "P7", "the code typed")
        send(view.buttons["enroll"], True)
        drive.wait_for(lambda: "/p/" in view.last_link, "the new participant's link")
        assert study.run.by_token(view.last_link.rsplit("/p/", 1)[1]).code == "P7"
        send(view.buttons["enroll"], True)  # the same code again: refused on the page
        drive.wait_for(lambda: "already used" in view.said.content, "the refusal")
        send(view.who, "P7")
        drive.wait_for(lambda: view.who.value == "P7", "the code typed")
        send(view.buttons["Withdraw and delete their rows"], True)  # asked again first
        drive.wait_for(lambda: "cannot be undone" in view.question.content, "the question")
        assert (
            view.buttons["confirm"].visible and study.run.log.participant("P7")["withdrawn"] is None
        )
        send(view.buttons["cancel"], True)
        drive.wait_for(lambda: not view.buttons["confirm"].visible, "cancelled")
        send(view.buttons["Withdraw"], True)
        drive.wait_for(lambda: view.buttons["confirm"].visible, "the question")
        assert study.run.log.participant("P7")["withdrawn"] is None
        send(view.buttons["confirm"], True)
        drive.wait_for(lambda: study.run.log.participant("P7")["withdrawn"], "withdrawn")
        assert study.run.log.participant("P7")["token_hash"] != "deleted:P7"  # kept, marked
        drive.wait_for(lambda: "withdrawn" in view.table.content, "the table")


def test_a_physical_condition_shows_the_physical_page_blind_to_the_learner(tmp_path):
    from corrections_sim.pages.physical import PhysicalPage

    (tmp_path / "small.toml").write_text(STUDY)
    protocol = tmp_path / "protocol.toml"
    protocol.write_text(
        'study = "small.toml"\nseed = 1\ncorrections = 1\nwelcome = "Hi."\n'
        '[[conditions]]\nname = "P"\nlearner = "KF-C"\nmode = "physical"\n'
    )
    run = open_run(protocol, tmp_path / "study.sqlite")
    server = open_server("127.0.0.1", _free_port())
    study = StudyServer(server, run, host="127.0.0.1")
    try:
        link = study.enroll("P1")
        with drive.SocketTab("http://" + link.split("ws://")[1]) as tab:
            view = drive.wait_for(lambda: study.participant_views().get("P1"), "the page")

            def send(handle, value) -> None:
                message = {
                    "type": "GuiUpdateMessage",
                    "uuid": handle._impl.uuid,
                    "updates": {"value": value},
                }
                tab.socket.send(msgspec.msgpack.encode(message))

            send(drive.wait_for(lambda: view.controls.get("code"), "the code box"), "P1")
            drive.wait_for(lambda: view.controls["code"].value == "P1", "the code typed")
            send(view.controls["start"], True)
            send(drive.wait_for(lambda: view.controls.get("continue"), "the welcome"), True)
            page = drive.wait_for(lambda: view.page, "the trial's page", timeout=120)
            assert isinstance(page, PhysicalPage) and page.limit == 1
            drive.wait_for(lambda: page.proposal is not None, "the plan", timeout=120)
            drive.wait_for(lambda: "Push 1" in page.title.content, "the title")
            assert "KF-C" not in page.title.content and "Learner" not in page.title.content
            assert page.session.correction_name == "physical"
            # The stated preference first, on the physical page too: Play waits for it.
            assert "First state your preference" in page.title.content and page.play.disabled
            for slider, value in zip(page.sliders, (1.0, -1.0), strict=True):
                send(slider, value)
            drive.wait_for(lambda: "table -1.0" in page.pref_echo.content, "the echo")
            send(page.state_button, True)
            drive.wait_for(lambda: not page.play.disabled, "Play once stated")
            logged = run.log.session(page.session.id).stated_theta
            assert list(logged) == [1.0, -1.0]
    finally:
        server.stop()
        run.log.close()


def test_every_tlx_value_set_as_fast_as_the_page_takes_it_reaches_the_log(browser, tmp_path):
    """Two questionnaires of the 20 of ``bench questionnaire``: six values and Submit from one
    script in the page (one throttle window of viser's client, which keeps only its latest
    message), then what the page shows back mended and confirmed; and a slider left untouched
    is refused, never stored."""
    from benchmarks.bench_questionnaire import open_study, questionnaire, untouched

    study, server = open_study(tmp_path)
    try:
        left = untouched(study, browser)
        assert left == {"refused": True, "stored": 0}
        for i, values in enumerate(([70, 10, 40, 30, 60, 75], [50, 50, 0, 100, 5, 95])):
            outcome = questionnaire(study, browser, f"Q{i}", values)
            assert outcome["exact"], outcome
            assert outcome["lost"] >= 1  # the throttle did drop values: the mending mattered
    finally:
        server.stop()
        study.run.log.close()


#: Markup, a script and an image whose error runs one, in a participant's words.
PAYLOAD = (
    "<b>was</b> nicer & *faster* | _x_ <script>window.__typed = 1</script>"
    '<img src=x onerror="window.__typed = 2"> [more](javascript:void(0)) \\o/'
)
#: One robot, one correction: a questionnaire is a stopped trial away.
ONE_ROBOT = """study = "small.toml"
seed = 3
corrections = 1
welcome = "Hello there."
[[conditions]]
name = "C"
learner = "KF-C"
"""
TEXT_PROTOCOL = (
    ONE_ROBOT
    + """[[questionnaires.condition]]
id = "why"
kind = "text"
text = "What did the robot do?"
[[questionnaires.end]]
id = "comments"
kind = "text"
text = "Anything else?"
"""
)


@pytest.fixture
def at_trial(browser, tmp_path):
    """A function (protocol text) -> (tab, study): participant P1's tab at the protocol's
    first trial page; its server and log closed after the test."""
    opened = []

    def open_(text: str):
        (tmp_path / "small.toml").write_text(STUDY)
        protocol = tmp_path / "protocol.toml"
        protocol.write_text(text)
        run = open_run(protocol, tmp_path / "study.sqlite")
        server = open_server("127.0.0.1", _free_port())
        study = StudyServer(server, run, host="127.0.0.1")
        tab = browser.new_page(viewport=drive.VIEWPORT)
        opened.append((tab, server, run))
        tab.goto(study.enroll("P1"))
        _enter(tab, "P1")
        tab.get_by_text("Hello there.").wait_for(timeout=60_000)
        drive.click(tab, "Continue")
        tab.get_by_role("button", name="Submit correction").wait_for(timeout=120_000)
        return tab, study

    yield open_
    for tab, server, run in opened:
        tab.close()
        server.stop()
        run.log.close()


@pytest.fixture
def at_questions(at_trial):
    """A function (protocol text, first question) -> (tab, study): the tab at the protocol's
    first questionnaire, reached by stopping the one trial early."""

    def open_(text: str, first: str):
        tab, study = at_trial(text)
        tab.get_by_text("Need to stop?").click()
        drive.click(tab, "Stop this trial early")
        drive.click(tab, "Yes, stop this trial")  # on to the questionnaire
        tab.get_by_text(first).wait_for(timeout=60_000)
        return tab, study

    return open_


def _shown_as_typed(tab) -> None:
    """The payload on the page as its characters, nothing of it made into an element, no
    script of it run."""
    drive.wait_for(lambda: PAYLOAD in drive.status(tab), "the words as typed")
    made = tab.evaluate(
        """() => ({typed: window.__typed ?? null,
                   bold: Array.from(document.querySelectorAll('b, strong'))
                       .some(e => e.textContent === 'was'),
                   img: document.querySelectorAll('img[src="x"]').length,
                   script: Array.from(document.scripts).some(s => s.text.includes('__typed')),
                   link: document.querySelectorAll('a[href^="javascript"]').length})"""
    )
    assert made == {"typed": None, "bold": False, "img": 0, "script": False, "link": 0}, made


def test_a_participants_words_are_shown_as_typed_everywhere(browser, at_questions, tmp_path):
    """Free text with markup, a <script> and an <img onerror> in every free-text field: the
    page's echo and its confirmation show it as typed and run nothing; the log keeps it raw;
    the report shows it as typed; a code typed on the experimenter's page is told back as
    typed (the confirmation rendered "<b>was</b> nicer & *faster*" bold and emphasised)."""
    from markdown_it import MarkdownIt

    from corrections_sim.userstudy.report import analyze

    tab, study = at_questions(TEXT_PROTOCOL, "What did the robot do?")
    db = study.run.log.path
    boss = browser.new_page(viewport=drive.VIEWPORT)
    try:
        for question in ("What did the robot do?", "Anything else?"):
            tab.get_by_text(question).wait_for(timeout=60_000)
            drive.fill_text(tab, 0, PAYLOAD)
            _shown_as_typed(tab)  # the line under the box: what the server received
            drive.click(tab, "Submit answers")
            tab.get_by_text("Please check your answers").wait_for(timeout=30_000)
            _shown_as_typed(tab)  # the confirmation's table
            drive.click(tab, "Yes, submit these answers")
        tab.get_by_text("Step 5 of 5").wait_for(timeout=60_000)
        boss.goto(study.experimenter_link())
        boss.get_by_text("P1").first.wait_for(timeout=60_000)
        drive.fill_text(boss, 1, PAYLOAD)  # the "Code" box
        drive.wait_for(lambda: study_code_typed(study), "the code typed")
        drive.click(boss, "Let continue")
        boss.get_by_text("not enrolled").wait_for(timeout=30_000)
        _shown_as_typed(boss)
    finally:
        boss.close()
    with StudyLog(db) as log:
        assert [a["value"] for a in log.answers("P1")] == [PAYLOAD, PAYLOAD]  # raw
    analyze(db, tmp_path / "analysis", regret=False)
    html = (
        MarkdownIt("commonmark")
        .enable("table")
        .render((tmp_path / "analysis" / "report.md").read_text())
    )
    assert (
        html.count(
            PAYLOAD.replace("&", "&amp;")
            .replace("<", "&lt;")
            .replace(">", "&gt;")
            .replace('"', "&quot;")
        )
        == 2
    ), html
    assert "<b>" not in html and "<img src=x" not in html and "<script" not in html, html
    assert "javascript:" not in html.replace("(javascript:void(0))", ""), html


def study_code_typed(study) -> bool:
    views = [v for v in study.views.values() if hasattr(v, "who")]
    return bool(views) and views[0].who.value == PAYLOAD


LIKERT_TLX_PROTOCOL = (
    ONE_ROBOT
    + """[[questionnaires.condition]]
id = "understood"
text = "The robot understood me."
points = 5
[[questionnaires.condition]]
kind = "tlx"
"""
)


@pytest.fixture
def questionnaire(at_questions):
    """A participant's tab at a questionnaire of a Likert item and the TLX (in
    experiments/protocol.toml's order)."""
    return at_questions(LIKERT_TLX_PROTOCOL, "The robot understood me.")


def _boxes(tab) -> list[str]:
    return [box.input_value() for box in drive.number_boxes(tab).all()]


def test_a_keyboard_user_answers_50_on_a_tlx_scale(questionnaire):
    """A person who wants 50 and uses the keyboard: the box showed 50 at rest, and Enter in
    it sent nothing (no answer; only a slider move was one). Now an untouched box is empty,
    the line says how to answer, and 50 typed and entered is received."""
    tab, _ = questionnaire
    box = drive.number_boxes(tab).nth(0)
    box.click()
    if box.input_value() != "50":
        box.press_sequentially("50")
    box.press("Enter")
    drive.wait_for(lambda: drive.echoes(tab)[1] == "50", "the 50 reaching the server", 20)
    assert "type a number into its box and press Enter" in drive.status(tab)  # the others


def test_a_box_never_shows_a_value_the_server_does_not_hold_after_submit(questionnaire):
    """Two TLX values typed in the moment a Likert answer is chosen: the second is lost in
    viser's throttle (its client sends the first message of a 50 ms window and the last).
    Submit redraws the questionnaire from what the server holds: each box shows what was
    received, or nothing beside "Not answered yet" (it showed 50, a value nobody gave)."""
    tab, _ = questionnaire
    drive._shown(tab, "input.mantine-Select-input", 0).click()
    tab.get_by_role("option", name="4").first.wait_for()
    tab.evaluate(
        """() => {
        const setter = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, 'value').set;
        const boxes = document.querySelectorAll('input.mantine-NumberInput-input');
        for (const [i, v] of [[1, '30'], [0, '80']]) {
            setter.call(boxes[i], v);
            boxes[i].dispatchEvent(new Event('input', {bubbles: true}));
        }
        Array.from(document.querySelectorAll('[role=option]'))
            .find(o => o.textContent.startsWith('4')).click();
    }"""
    )
    drive.wait_for(lambda: drive.echoes(tab)[:3] == ["4", None, "30"], "what arrived")
    assert _boxes(tab)[:2] == ["80", "30"]  # the 80 was lost on the way
    old = drive._button(tab, "Submit answers")
    old.click()
    drive._redrawn(tab, old)
    tab.get_by_text("Not taken").wait_for(timeout=30_000)
    shown, received = _boxes(tab), drive.echoes(tab)[1:]
    assert len(shown) == len(received) == 6
    for box, got in zip(shown, received, strict=True):
        assert box == (got or ""), (shown, received)


def test_the_scripted_participant_answers_a_tlx_after_a_likert_item(questionnaire):
    """``drive.answer_sliders`` in experiments/protocol.toml's order (Likert items before
    the TLX): it took the page's answer i for slider i, waited for the Likert item's echo to
    become a slider's value, and timed out ("the step away reaching the server")."""
    tab, study = questionnaire
    drive.choose(tab, 0, "4")
    drive.wait_for(lambda: drive.echoes(tab)[0] == "4", "the Likert answer")
    values = [70, 10, 40, 30, 60, 75]
    outcome = drive.answer_sliders(tab, values)
    assert outcome["rounds"] >= 1
    tab.get_by_text("you are done").wait_for(timeout=60_000)
    got = {a["item"]: a["value"] for a in study.run.log.answers("P1")}
    scales = ("mental", "physical", "temporal", "performance", "effort", "frustration")
    assert got == {"understood": 4, **{f"tlx.{s}": v for s, v in zip(scales, values, strict=True)}}


def test_a_keyboard_user_states_a_preference_of_0(at_trial):
    """The stated preference's boxes showed 0 before anything was given, so a person who
    wants 0 for the laptop and pressed Enter in its box sent nothing ("laptop (not moved
    yet)"), as on the TLX. Now the boxes are empty until answered, and 0 typed is 0 received."""
    tab, study = at_trial(ONE_ROBOT)
    tab.get_by_role("button", name="State my preference").wait_for(timeout=120_000)
    for i, value in enumerate(("0", "-1")):
        box = drive.number_boxes(tab).nth(i)
        box.click()
        if box.input_value() != value:
            box.press_sequentially(value)
        box.press("Enter")
    drive.wait_for(
        lambda: "We have: laptop +0.0, table -1.0" in drive.status(tab), "both received", 20
    )
    drive.click(tab, "State my preference")
    drive.wait_for(lambda: "recorded as" in drive.status(tab), "the stated preference")
    log = study.run.log
    assert list(log.session(log.steps("P1")[-1]["session_id"]).stated_theta) == [0.0, -1.0]
