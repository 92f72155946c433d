"""A study's server: several participants at once on one viser server, each through their own
protocol (:mod:`corrections_sim.interact.participant`), and the experimenter's view.

**Who gets in.** Each browser connection is judged by the path of its websocket, which the
link sets (``?websocket=ws://HOST:PORT/p/SECRET``: viser's client connects to the server
named by that parameter):

* ``/p/SECRET`` — the participant whose link secret it is (its SHA-256 is in the log; the
  secret itself is shown once, to the experimenter). They get their own tab, scene, session
  and learner; nothing of anyone else's is ever sent to their connection.
* ``/x/SECRET`` — the experimenter's view, with the secret this server printed when it
  started (it is not in the log; a restarted server prints a new one).
* anything else — one line saying the link is not valid; no scene, no control.

A participant's second tab is told their page is open elsewhere. Messages are routed by viser
to the connection that sent them, so a client can only move the controls viser made for its
own connection: replaying another participant's messages on one's own connection touches
nothing of theirs.

**A participant's page.** The code they were given, typed → their step: instructions and
"Continue"; a trial (the drag page or the physical page of the trial's session, which ends
after the protocol's corrections, or with "Done"), then "Continue"; a questionnaire (each
Likert item a choice of its points with its anchors, the raw NASA-TLX as six sliders, free
text), "Submit answers"; the end. Every step is in the log before the page moves on; a
reload, a closed tab or a restarted server shows the same step. A participant who has begun
and returns (a new tab after the server restarted, or another day) waits until the
experimenter lets them continue.

**The experimenter's view.** Who is where (refreshed every second), enrolling a participant
(their link is shown there once), letting a returning participant continue, aborting a
trial (it starts over with a new session; the aborted one is kept, marked), withdrawing a
participant (their rows leave the analysis) or deleting their rows.
"""

from __future__ import annotations

import hmac
import secrets
import threading
from collections.abc import Callable

from corrections_sim.interact.log import StudyError
from corrections_sim.interact.page import plural
from corrections_sim.interact.participant import Participant, StudyRun
from corrections_sim.interact.server import configure, make_page
from corrections_sim.study.protocol import TLX_SCALES, TLX_TEXT, Step

#: The placeholder of a Likert choice not yet made.
UNANSWERED = "(choose)"
#: Seconds between refreshes of the experimenter's view.
REFRESH = 1.0


def connection_path(server, client) -> str | None:
    """The path of ``client``'s websocket (viser 1.1.1 keeps the connection by client id);
    None if it cannot be read, which lets no one in."""
    try:
        connection = server._websock_server._live_connections[client.client_id]
        return str(connection.request.path)
    except (AttributeError, KeyError, TypeError):
        return None


def _same(given: str, secret: str) -> bool:
    """``given == secret`` in constant time (any text: a path or a typed code may hold
    characters that are not ASCII)."""
    return hmac.compare_digest(given.encode("utf-8"), secret.encode("utf-8"))


class StudyServer:
    """A study on a viser server (see the module)."""

    def __init__(self, server, run: StudyRun, *, host: str, speed: float = 1.0) -> None:
        self.server = server
        self.run = run
        self.host = host
        self.speed = float(speed)
        self.secret = secrets.token_urlsafe(24)
        self._lock = threading.RLock()
        self.views: dict[int, ParticipantView | ExperimenterView] = {}
        #: participant code -> the client id of the tab that shows their page
        self.active: dict[str, int] = {}
        #: returning participants the experimenter let continue (on this server)
        self.confirmed: set[str] = set()
        #: participants who typed their code on this server and have not been let in yet
        self.waiting: set[str] = set()
        #: participants who went on from their code on this server (a reload goes on too)
        self.entered: set[str] = set()
        self.refused = 0  # connections with no valid link (tests count them)
        configure(server)
        server.on_client_connect(self._connect)
        server.on_client_disconnect(self._disconnect)

    # --- links -----------------------------------------------------------------------------

    def _url(self, path: str) -> str:
        host = self.host if ":" not in self.host else f"[{self.host}]"
        port = self.server.get_port()
        return f"http://{host}:{port}/?websocket=ws://{host}:{port}{path}"

    def participant_link(self, token: str) -> str:
        return self._url(f"/p/{token}")

    def experimenter_link(self) -> str:
        return self._url(f"/x/{self.secret}")

    def enroll(self, code: str) -> str:
        """Enroll ``code``; their link (shown once)."""
        _, token = self.run.enroll(code)
        return self.participant_link(token)

    # --- connections -----------------------------------------------------------------------

    def _connect(self, client) -> None:
        path = connection_path(self.server, client) or ""
        kind, _, secret = path.strip("/").partition("/")
        if kind == "x" and secret and _same(secret, self.secret):
            view: ParticipantView | ExperimenterView = ExperimenterView(self, client)
        elif kind == "p" and (person := self.run.by_token(secret)) is not None:
            with self._lock:
                if person.code in self.active:
                    client.gui.add_markdown(
                        "**Your page is open in another tab.** Close it, then reload this one."
                    )
                    return
                self.active[person.code] = client.client_id
            view = ParticipantView(self, client, person)
        else:
            with self._lock:
                self.refused += 1
            client.gui.add_markdown("**This link is not valid.** Ask the experimenter for yours.")
            return
        with self._lock:
            self.views[client.client_id] = view
        view.start()

    def _disconnect(self, client) -> None:
        with self._lock:
            view = self.views.pop(client.client_id, None)
            if isinstance(view, ParticipantView) and self.active.get(view.code) == client.client_id:
                self.active.pop(view.code)
        if view is not None:
            view.stop()

    def participant_views(self) -> dict[str, ParticipantView]:
        with self._lock:
            return {v.code: v for v in self.views.values() if isinstance(v, ParticipantView)}

    def let_continue(self, code: str) -> None:
        """The experimenter lets a returning participant continue."""
        with self._lock:
            self.confirmed.add(code)
            self.waiting.discard(code)
            view = self.participant_views().get(code)
        if view is not None:
            view.render()

    def abort_trial(self, code: str) -> int | None:
        view = self.participant_views().get(code)
        aborted = self.run.participant(code).abort_trial()
        if view is not None:
            view.render()
        return aborted

    def withdraw(self, code: str, *, delete: bool = False) -> None:
        view = self.participant_views().get(code)
        self.run.withdraw(code, delete=delete)
        if view is not None:
            view.render()

    def status(self) -> list[dict]:
        """Who is where, with whether their page is open and whether they wait."""
        out = []
        with self._lock:
            active, waiting = set(self.active), set(self.waiting)
        for where in self.run.status():
            out.append(
                {
                    "code": where.code,
                    "index": where.index,
                    "step": where.step.key,
                    "position": where.position + 1,
                    "total": where.total,
                    "withdrawn": where.withdrawn,
                    "connected": where.code in active,
                    "waiting": where.code in waiting,
                    "session": where.session_id,
                }
            )
        return out


class ParticipantView:
    """One participant's tab (see the module)."""

    def __init__(self, study: StudyServer, client, person: Participant) -> None:
        self.study = study
        self.client = client
        self.person = person
        self.code = person.code
        self.page = None
        self.entered = False
        self.message = ""
        self._busy = threading.Lock()
        self._lock = threading.RLock()
        self.shown: Step | None = None  # the step on the page (tests wait on it)
        #: the controls of the step on the page by name (a scripted driver addresses them)
        self.controls: dict = {}
        #: the line where a refused click says why (each step draws its own)
        self.error = None

    def start(self) -> None:
        self.render()

    def stop(self) -> None:
        with self._lock:
            if self.page is not None:
                self.page.disconnect(self.client)
                self.page.close()
                self.page = None
            self.client = None

    def _clear(self) -> None:
        if self.page is not None:
            self.page.close()
            self.page = None
        self.client.gui.reset()
        self.client.scene.reset()

    def render(self) -> None:
        """Draw the participant's current step (from the log)."""
        with self._lock:
            if self.client is None:
                return
            self._clear()
            self.controls = {}
            gui = self.client.gui
            if self.person.withdrawn():
                gui.add_markdown("**This session has ended.** Thank you.")
                self.shown = None
                return
            study = self.study
            if not self.entered:
                self._code_entry()
                return
            if self.code in study.waiting:
                gui.add_markdown(
                    "**Welcome back.** The experimenter will let you continue where you were."
                )
                return
            step = self.person.current()
            self.shown = step
            total = len(self.person.steps)
            gui.add_markdown(f"Step {self.person.position() + 1} of {total}")
            if step.kind == "instructions":
                gui.add_markdown(step.text)
                button = gui.add_button("Continue")
                self.controls["continue"] = button
                button.on_click(self._guarded(lambda: self.person.proceed(step.key)))
            elif step.kind == "trial":
                self._trial(step)
            elif step.kind == "questions":
                self._questions(step)
            else:
                gui.add_markdown(step.text)

    def _guarded(self, action: Callable[[], object]) -> Callable:
        """A click handler: one action at a time, errors on the page in one line, then the
        step the log says the participant is at."""

        def on_click(_event) -> None:
            if not self._busy.acquire(blocking=False):
                return
            try:
                try:
                    action()
                    self.message = ""
                except (StudyError, ValueError) as exc:
                    self.message = str(exc).splitlines()[0]
                    if self.error is not None and self.client is not None:
                        self.error.content = f"**Not taken**: {self.message}"
                    return
                self.render()
            finally:
                self._busy.release()

        return on_click

    def _code_entry(self) -> None:
        gui = self.client.gui
        gui.add_markdown("**Welcome.** Type the participant code the experimenter gave you.")
        code = gui.add_text("Participant code", initial_value="")
        self.error = gui.add_markdown("")

        def enter() -> None:
            if not _same(code.value.strip(), self.code):
                raise ValueError("that is not the code of this link")
            self.entered = True
            begun = any(r["finished"] for r in self.person.log.steps(self.code))
            with self.study._lock:
                known = self.code in self.study.confirmed or self.code in self.study.entered
                if begun and not known:
                    self.study.waiting.add(self.code)  # returning: the experimenter confirms
                else:
                    self.study.entered.add(self.code)  # a reload on this server goes on

        start = gui.add_button("Start")
        start.on_click(self._guarded(enter))
        self.controls |= {"code": code, "start": start}

    def _trial(self, step: Step) -> None:
        gui = self.client.gui
        gui.add_markdown(step.text)
        session = self.person.session(step.key)
        limit = self.person.corrections(step)
        gui.add_markdown(
            f"This trial ends after {limit} {plural(limit, 'correction')} (or when you press Done)."
        )
        self.page = make_page(
            self.study.server,
            session,
            speed=self.study.speed,
            attach=False,
            blind=True,
            limit=limit,
            on_end=lambda: self._trial_over(step),
        )
        self.page.connect(self.client)

    def _trial_over(self, step: Step) -> None:
        client = self.client
        if client is None:
            return
        self.error = client.gui.add_markdown("")
        button = client.gui.add_button("Continue to the next step")
        button.on_click(self._guarded(lambda: self.person.finish_trial(step.key)))

    def _questions(self, step: Step) -> None:
        gui = self.client.gui
        gui.add_markdown(step.text)
        fields: dict[str, Callable[[], object]] = {}
        for q in step.questions:
            if q.kind == "likert":
                gui.add_markdown(q.text)
                low, high = q.anchors
                options = [UNANSWERED] + [
                    f"{i}" + (f" ({low})" if i == 1 else f" ({high})" if i == q.points else "")
                    for i in range(1, q.points + 1)
                ]
                choice = gui.add_dropdown(q.id, options=options, initial_value=UNANSWERED)
                fields[q.id] = lambda c=choice: (
                    None if c.value == UNANSWERED else int(c.value.split(" ")[0])
                )
            elif q.kind == "tlx":
                gui.add_markdown("**NASA-TLX**: 0 very low … 100 very high.")
                for scale in TLX_SCALES:
                    slider = gui.add_slider(
                        scale, min=0, max=100, step=5, initial_value=50, hint=TLX_TEXT[scale]
                    )
                    fields[f"{q.id}.{scale}"] = lambda s=slider: int(s.value)
            else:
                gui.add_markdown(q.text)
                box = gui.add_text(q.id, initial_value="")
                fields[q.id] = lambda b=box: b.value
        self.error = gui.add_markdown("")
        submit = gui.add_button("Submit answers")
        submit.on_click(
            self._guarded(lambda: self.person.answer({k: f() for k, f in fields.items()}, step.key))
        )


class ExperimenterView:
    """The experimenter's tab (see the module)."""

    def __init__(self, study: StudyServer, client) -> None:
        self.study = study
        self.client = client
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.last_link = ""

    def start(self) -> None:
        gui = self.client.gui
        gui.add_markdown(f"### Study: {self.study.run.protocol.description or 'protocol'}")
        self.table = gui.add_markdown("")
        b = self.buttons = {}
        with gui.add_folder("Enroll a participant"):
            self.new_code = gui.add_text("New code", initial_value="")
            b["enroll"] = gui.add_button("Enroll")
            b["enroll"].on_click(lambda _: self._do(self._enroll))
            self.link = gui.add_markdown("")
        with gui.add_folder("A participant"):
            self.who = gui.add_text("Code", initial_value="")
            actions = {
                "Let continue": lambda: self.study.let_continue(self._code()),
                "New link": self._new_link,
                "Abort the trial": lambda: self.study.abort_trial(self._code()),
                "Withdraw": lambda: self.study.withdraw(self._code()),
                "Withdraw and delete their rows": lambda: self.study.withdraw(
                    self._code(), delete=True
                ),
            }
            for label, action in actions.items():
                b[label] = gui.add_button(label)
                b[label].on_click(lambda _, a=action: self._do(a))
        self.said = gui.add_markdown("")
        self.refresh()
        self._thread = threading.Thread(target=self._loop, name="experimenter", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _loop(self) -> None:
        while not self._stop.wait(REFRESH):
            try:
                self.refresh()
            except Exception:  # the tab went while drawing: the next connect draws again
                if self._stop.is_set():
                    return

    def _code(self) -> str:
        code = self.who.value.strip()
        if self.study.run.log.participant(code) is None:
            raise StudyError(f"participant {code!r}: not enrolled")
        return code

    def _do(self, action: Callable[[], object]) -> None:
        try:
            action()
            self.said.content = ""
        except (StudyError, ValueError) as exc:
            self.said.content = f"**Not done**: {str(exc).splitlines()[0]}"
        self.refresh()

    def _enroll(self) -> None:
        code = self.new_code.value.strip()
        link = self.study.enroll(code)
        self.last_link = link
        self.link.content = f"Link for **{code}** (shown once): `{link}`"

    def _new_link(self) -> None:
        code = self._code()
        link = self.study.participant_link(self.study.run.new_link(code))
        self.last_link = link
        self.link.content = f"New link for **{code}** (the old one no longer works): `{link}`"

    def refresh(self) -> None:
        rows = self.study.status()
        lines = ["| code | step | where | page |", "|---|---|---|---|"]
        for r in rows:
            state = (
                "withdrawn"
                if r["withdrawn"]
                else ("waiting to continue" if r["waiting"] else "open" if r["connected"] else "—")
            )
            lines.append(f"| {r['code']} | {r['step']} | {r['position']}/{r['total']} | {state} |")
        if not rows:
            lines.append("| (none yet) | | | |")
        self.table.content = "\n".join(lines)
