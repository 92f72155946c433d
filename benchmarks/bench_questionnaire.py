"""``python -m benchmarks.bench questionnaire``: does every answer a participant sets reach the
log, however fast they set it?

viser's client sends the panel's changes through one 50 ms throttle that keeps only the
latest message (``client/src/WebsocketUtils.ts``), so of six TLX sliders set within 50 ms and
a Submit clicked in the same moment, the server may see only the first slider and the click.
The study page therefore never writes on Submit: it shows what it received (refusing while a
required item is missing) and writes only what the participant confirms
(:mod:`corrections_sim.pages.study`).

Here a scripted participant in chromium (the system's, through Playwright) answers the raw
NASA-TLX ``--problems`` times (default 20), each time on a new participant's page: the six
values (multiples of 5, seeded) typed into the sliders' boxes and Submit clicked from one
script in the page, as fast as it takes input (the page times the window from the first value
to the click), then it reads what the page says it received, mends what differs (waiting on
the page's echo of each value, never on time) and confirms. Reported: per questionnaire the
window in ms, how many of the six values the first Submit did not carry (lost to the
throttle), the rounds to a confirmation, and whether the log holds exactly the six values
set. Before the first, one participant leaves a slider untouched and presses Submit, and the
report says whether anything was stored.

It prints figures and never asserts.
"""

from __future__ import annotations

import socket
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from corrections_sim.pages.server import open_server
from corrections_sim.pages.study import StudyServer
from corrections_sim.people.users import make_user
from corrections_sim.session.simulate import simulate
from corrections_sim.userstudy.cohort import open_run
from corrections_sim.userstudy.protocol import TLX_SCALES
from scripted_people import drive

STUDY = """environments = ["s0-t0-l1", "s0-t0-l2"]
theta_star = [1.0, -1.0]
learners = ["KF-C"]
seed = 3
iterations = 1
"""
PROTOCOL = """description = "the TLX, as fast as the page takes it"
study = "small.toml"
seed = 3
corrections = 1
primary = "mean_regret"
welcome = "Bench."
[[conditions]]
name = "C"
learner = "KF-C"
[[questionnaires.condition]]
kind = "tlx"
"""


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def open_study(folder: Path) -> tuple[StudyServer, object]:
    """A study of one short condition and the TLX, served on a free port in this process;
    (the study server, the viser server)."""
    (folder / "small.toml").write_text(STUDY)
    (folder / "protocol.toml").write_text(PROTOCOL)
    run = open_run(folder / "protocol.toml", folder / "study.sqlite")
    server = open_server("127.0.0.1", _port())
    return StudyServer(server, run, host="127.0.0.1"), server


def at_questionnaire(study: StudyServer, code: str) -> str:
    """Enroll ``code`` and take them (headless, a simulated user) through the welcome and
    the trial to the questionnaire; their link."""
    link = study.enroll(code)
    person = study.run.participant(code)
    person.proceed("welcome")
    step = person.current()
    session = person.session(step.key)
    simulate(session, make_user("noisy", {"noise": 0.5}), [1.0, -1.0], 1)
    person.finish_trial(step.key)
    assert person.current().kind == "questions"
    study.let_continue(code)  # as the experimenter would for one who had begun elsewhere
    return link


def open_questionnaire(browser, link: str):
    """A chromium tab on ``link`` once the questionnaire is on it."""
    tab = browser.new_page(viewport=drive.VIEWPORT)
    tab.goto(link)
    tab.get_by_text("Submit answers").wait_for(timeout=60_000)
    drive.wait_for(lambda: drive.number_boxes(tab).count() >= len(TLX_SCALES), "the sliders")
    return tab


def logged(study: StudyServer, code: str) -> list[int]:
    """The TLX values the log holds for ``code``, in the scales' order."""
    answers = {a["item"]: a["value"] for a in study.run.log.answers(code)}
    return [answers.get(f"tlx.{s}") for s in TLX_SCALES]


def untouched(study: StudyServer, browser) -> dict:
    """A participant who moves five sliders and presses Submit: what the page said and
    whether anything was stored."""
    link = at_questionnaire(study, "U0")
    tab = open_questionnaire(browser, link)
    try:
        for i, value in enumerate((70, 10, 40, 30, 60)):
            drive.set_number(tab, i, value)
            drive.wait_for(lambda i=i, v=value: drive._echo_at(tab, i) == str(v), "the echo")
        drive.click(tab, "Submit answers")
        said = drive.wait_for(
            lambda: "Not taken" in drive.status(tab) and drive.status(tab), "the refusal"
        )
        stored = study.run.log.answers("U0")
    finally:
        tab.close()
    return {"refused": "Frustration" in said, "stored": len(stored)}


def questionnaire(study: StudyServer, browser, code: str, values: list[int]) -> dict:
    """One participant's TLX answered fast (see the module); its figures."""
    link = at_questionnaire(study, code)
    tab = open_questionnaire(browser, link)
    try:
        started = time.perf_counter()
        outcome = drive.answer_sliders(tab, values)
        drive.wait_for(lambda: study.run.participant(code).current().kind == "end", "the end")
        outcome["seconds"] = time.perf_counter() - started
    finally:
        tab.close()
    outcome["exact"] = logged(study, code) == values
    return outcome


def run(count: int = 20, seed: int = 0) -> dict:
    """``count`` questionnaires and the untouched check (see the module)."""
    from playwright.sync_api import sync_playwright

    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as folder, sync_playwright() as p:
        study, server = open_study(Path(folder))
        browser = drive.launch(p)
        try:
            left = untouched(study, browser)
            rows = []
            for i in range(count):
                values = [int(5 * v) for v in rng.integers(0, 21, len(TLX_SCALES))]
                rows.append(questionnaire(study, browser, f"Q{i:02d}", values))
        finally:
            browser.close()
            server.stop()
            study.run.log.close()
    return {"untouched": left, "rows": rows}


def report(result: dict) -> list[str]:
    rows = result["rows"]
    windows = [r["window_ms"] for r in rows]
    lost = [r["lost"] for r in rows]
    left = result["untouched"]
    return [
        f"questionnaire: {len(rows)} raw NASA-TLX answered in chromium as fast as the page takes "
        "input (six values and Submit from one script in the page)",
        f"  first value to Submit by the page's clock: median {statistics.median(windows):.1f} "
        f"ms, max {max(windows):.1f} ms (inside 50 ms: {sum(w < 50 for w in windows)} of "
        f"{len(rows)}); each in one script task, so the throttle's timer could not fire between "
        "them: one window",
        f"  values the first Submit did not carry (lost to viser's throttle): "
        f"{sum(lost)} of {6 * len(rows)} ({sum(x > 0 for x in lost)} questionnaires)",
        f"  rounds to a confirmation: median {statistics.median(r['rounds'] for r in rows):.0f}, "
        f"max {max(r['rounds'] for r in rows)}; seconds each: median "
        f"{statistics.median(r['seconds'] for r in rows):.1f}",
        f"  the log holds exactly the values set: {sum(r['exact'] for r in rows)} of {len(rows)}",
        f"  one slider left untouched: Submit refused naming it: {left['refused']}; answers "
        f"stored: {left['stored']}",
    ]
