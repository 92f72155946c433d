"""A study's server: several participants at once on one viser server, each through their own
protocol (:mod:`corrections_sim.userstudy.participant`), and the experimenter's view.

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

**A participant's page.** The code they were given, typed (in any case) → their step:
instructions and "Continue"; a trial (the drag page or the physical page of the trial's
session, in a participant's words: their stated preference first where the primary outcome
needs it, then the protocol's corrections; "Done" only once it has ``min_corrections``), then
"This trial is over" and "Continue"; a questionnaire, then the end. Every step is in the log
before the page moves on; a reload, a closed tab or a restarted server shows the same step,
and a reload on the same server goes straight back to it. A participant who has begun and
returns to a restarted server waits until the experimenter lets them continue. At every step
"Need to stop?" offers a way out (end this trial early; leave the study), each confirmed
first and logged as such.

**Only what the participant gave is an answer.** A questionnaire shows every question with
its own anchors (the TLX's six questions written out, each scale with its own ends:
performance runs from perfect to failure). A Likert item starts at "(choose)" and a slider
counts only once the participant has moved it; under each control the page says what the
server has received ("not answered yet", or the value). viser's client sends the panel's
changes through one 50 ms throttle that keeps only the latest message, so a value set in the
same 50 ms as another control's (or as the Submit click) never reaches the server. So Submit
never writes by itself: it redraws the questionnaire from what the server holds (a value
that did not arrive shows as unanswered, or as its older value), refuses while a required
item is unanswered, and otherwise shows the answers as received with "Yes, submit these
answers" and "Change an answer"; only the confirmation writes them. What was set and not
yet submitted survives a reload on the same server.

**The experimenter's view.** Who is where (refreshed every second), enrolling a participant
(their link is shown there once), letting a returning participant continue, aborting a
trial (it starts over with a new session; the aborted one is kept, marked), withdrawing a
participant (their rows leave the analysis) or deleting their rows. The three that end or
delete something ask for confirmation, naming the participant.
"""

from __future__ import annotations

import hmac
import secrets
import threading
from collections.abc import Callable

from corrections_sim.pages.drawing import clear, plural
from corrections_sim.pages.server import configure, make_page
from corrections_sim.session.log import StudyError
from corrections_sim.userstudy.participant import Participant, StudyRun, check_answers
from corrections_sim.userstudy.protocol import TLX_ANCHORS, TLX_TEXT, TLX_TITLES, Question, Step
from corrections_sim.userstudy.typed import as_typed

#: The placeholder of a Likert choice not yet made.
UNANSWERED = "(choose)"
#: Seconds between refreshes of the experimenter's view.
REFRESH = 1.0
#: The experimenter's actions that end or delete something, each with what it does (asked
#: again before it is done).
DESTRUCTIVE = {
    "Abort the trial": "Their current trial starts over with a new session (the aborted one "
    "is kept, marked, and left out of the analysis).",
    "Withdraw": "They leave the study; their rows stay, marked, and leave every analysis.",
    "Withdraw and delete their rows": "Every row of theirs (sessions, corrections, answers) "
    "is deleted for good; only the code stays taken. This cannot be undone.",
}


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


def likert_options(question: Question) -> list[str]:
    """A Likert item's choices: the placeholder, then each point, the ends with their
    anchors ("1: Strongly disagree", "2", …)."""
    low, high = question.anchors
    return [UNANSWERED] + [
        f"{i}" + (f": {low}" if i == 1 else f": {high}" if i == question.points else "")
        for i in range(1, question.points + 1)
    ]


def shown_value(question: Question, item: str, value) -> str:
    """An answer as the page shows it back to the participant."""
    if value is None or value == "":
        return "not answered" if question.kind != "text" else "(nothing)"
    if question.kind == "likert":
        return likert_options(question)[int(value)]
    if question.kind == "tlx":
        low, high = TLX_ANCHORS[item.split(".", 1)[1]]
        return f"{value} (0: {low.lower()}, 100: {high.lower()})"
    return f"“{as_typed(value)}”"


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
        #: (code, step key) -> item -> the value the server received and the participant
        #: has not submitted yet (a reload on this server shows them again)
        self.drafts: dict[tuple[str, str], dict[str, object]] = {}
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
        elif kind == "x":
            with self._lock:
                self.refused += 1
            client.gui.add_markdown(
                "**This experimenter link is from an earlier run of the server.** Use the "
                "experimenter link the server printed when it started."
            )
            return
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

    def withdraw(self, code: str, *, delete: bool = False, by: str = "experimenter") -> None:
        view = self.participant_views().get(code)
        self.run.withdraw(code, delete=delete, by=by)
        with self._lock:
            for key in [k for k in self.drafts if k[0] == code]:
                self.drafts.pop(key)
        if view is not None:
            view.render()

    def settle(self) -> None:
        """Wait until no participant's page still runs anything on the server (a push
        being learnt is logged): call it before the log closes."""
        with self._lock:
            views = list(self.views.values())
        for view in views:
            page = getattr(view, "page", None)  # the experimenter's view has none
            if page is not None:
                page.settle()

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
        # A reload on this server goes straight back (the link is the credential; the code
        # is typed once per server, to catch a link opened by the wrong person).
        with study._lock:
            self.entered = person.code in study.entered or person.code in study.confirmed
        self.message = ""
        #: the questionnaire's answers shown for confirmation (None while editing)
        self.pending: dict | None = None
        #: a way out the participant pressed and has not confirmed yet ("stop" or "leave")
        self.leaving: str | None = None
        self.exit_folder = None
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
        self.exit_folder = None  # gone with the reset below
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
                gui.add_markdown(
                    "**Your part in the study has ended.** Thank you; you may close this page."
                )
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
                return
            self._way_out(step)

    def _way_out(self, step: Step) -> None:
        """The way out, "Need to stop?": end this trial early (at a trial) or leave the
        study, each asked again before it is done (the folder is redrawn alone: a trial's
        page stays as it is)."""
        gui = self.client.gui
        if self.exit_folder is not None:  # redrawn in place (a reset of the panel clears it)
            self.exit_folder.remove()
        self.exit_folder = gui.add_folder(
            "Need to stop?", expand_by_default=self.leaving is not None
        )
        with self.exit_folder:
            if self.leaving is None:
                if step.kind == "trial" and not self._trial_ended(step):
                    stop = gui.add_button("Stop this trial early")
                    stop.on_click(
                        self._guarded(lambda: self._ask_leave("stop", step), redraw=False)
                    )
                    self.controls["stop"] = stop
                leave = gui.add_button("Leave the study")
                leave.on_click(self._guarded(lambda: self._ask_leave("leave", step), redraw=False))
                self.controls["leave"] = leave
                return
            if self.leaving == "stop":
                gui.add_markdown(
                    "**End this trial now?** The robot stops learning from you here and we go "
                    "on to the next step. Your corrections so far are kept."
                )
                yes = gui.add_button("Yes, stop this trial", color="red")
                yes.on_click(self._guarded(lambda: self._leave(step)))
            else:
                gui.add_markdown(
                    "**Leave the study?** You can stop at any time, with no need to say why. "
                    "What you gave so far is kept unless you ask the experimenter to delete it."
                )
                yes = gui.add_button("Yes, leave the study", color="red")
                yes.on_click(self._guarded(lambda: self._leave(step)))
            no = gui.add_button("No, go on")
            no.on_click(self._guarded(lambda: self._ask_leave(None, step), redraw=False))
            self.controls |= {"confirm_leave": yes, "go_on": no}

    def _ask_leave(self, what: str | None, step: Step) -> None:
        with self._lock:
            self.leaving = what
            if self.client is not None:
                self._way_out(step)

    def _leave(self, step: Step) -> None:
        what, self.leaving = self.leaving, None
        if what == "stop":
            self.person.stop_trial(step.key)
        elif what == "leave":
            self.study.withdraw(self.code, by="participant")

    def _trial_ended(self, step: Step) -> bool:
        """The current trial's session has ended (its page showed its end, or it was
        stopped) and the step waits for Continue."""
        session_id = self.person.where().session_id
        return session_id is not None and self.person.log.session(session_id).ended is not None

    def _guarded(
        self, action: Callable[[], object], *, redraw: bool = True, redraw_refused: bool = False
    ) -> Callable:
        """A click handler: one action at a time, errors on the page in one line, then (with
        ``redraw``) the step the log says the participant is at; ``redraw_refused``: a
        refusal redraws too (the questionnaire then shows what the server holds)."""

        def on_click(_event) -> None:
            if not self._busy.acquire(blocking=False):
                return
            try:
                with self.study.run.log.unless_closed():  # the server may be stopping
                    try:
                        action()
                        self.message = ""
                    except (StudyError, ValueError) as exc:
                        self.message = str(exc).splitlines()[0]
                        if redraw_refused:
                            self.render()
                        elif self.error is not None and self.client is not None:
                            self.error.content = f"**Not taken**: {as_typed(self.message)}"
                        return
                    if redraw:
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
            typed = code.value.strip().casefold()
            if not _same(typed, self.code.casefold()):
                raise ValueError(
                    "that is not the code of this link: check it with the experimenter"
                )
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
        if self._trial_ended(step):
            self._trial_over(step)
            return
        gui.add_markdown(step.text)
        limit = self.person.corrections(step)
        minimum = self.person.minimum(step)
        physical = self.study.run.protocol.condition(step.condition).mode == "physical"
        move = "push" if physical else "correction"
        ends = f"This trial has {limit} {plural(limit, move)}"
        if minimum < limit:
            ends += f"; after {minimum} you may press Done"
        gui.add_markdown(ends + ".")
        ready = gui.add_markdown("_The robot is getting ready…_")
        session = self.person.session(step.key)
        self.page = make_page(
            self.study.server,
            session,
            speed=self.study.speed,
            attach=False,
            blind=True,
            limit=limit,
            minimum=minimum,
            require_stated=self.person.needs_stated,
            on_end=lambda: self._ended(step),
        )
        self.page.connect(self.client)  # until its first plan is on the page
        ready.remove()

    def _ended(self, step: Step) -> None:
        """The trial's page showed its end: the panel is drawn again, as "This trial is
        over" (from another thread: the page's action that ended it holds the page)."""
        threading.Thread(target=self.render, name="trial-over", daemon=True).start()

    def _trial_over(self, step: Step) -> None:
        gui = self.client.gui
        gui.add_markdown("**This trial is over.** Thank you. Press Continue to go on.")
        self.error = gui.add_markdown("")
        button = gui.add_button("Continue")
        button.on_click(self._guarded(lambda: self.person.finish_trial(step.key)))
        self.controls["continue"] = button

    def _draft(self, step: Step) -> dict:
        with self.study._lock:
            return self.study.drafts.setdefault((self.code, step.key), {})

    def _questions(self, step: Step) -> None:
        """The questionnaire (see the module): editing, or the answers as received shown for
        confirmation (:attr:`pending`)."""
        gui = self.client.gui
        gui.add_markdown(step.text)
        draft = self._draft(step)
        confirming = self.pending is not None
        readers: dict[str, Callable[[], object]] = {}
        for q in step.questions:
            for item in q.items():
                readers[item] = self._question(q, item, draft, confirming)
        self.error = gui.add_markdown(
            f"**Not taken**: {as_typed(self.message)}" if self.message else ""
        )
        if confirming:
            rows = "\n".join(
                f"| {self._label(q, item)} | {shown_value(q, item, self.pending.get(item))} |"
                for q in step.questions
                for item in q.items()
            )
            gui.add_markdown(
                "**Please check your answers as we received them.** If one is not what you "
                f"chose, press Change an answer.\n\n| question | your answer |\n|---|---|\n{rows}"
            )
            confirm = gui.add_button("Yes, submit these answers", color="green")
            change = gui.add_button("Change an answer")
            confirm.on_click(self._guarded(lambda: self._confirm(step)))
            change.on_click(self._guarded(lambda: self._change()))
            self.controls |= {"confirm": confirm, "change": change}
            return
        submit = gui.add_button("Submit answers")
        submit.on_click(self._guarded(lambda: self._submit(step, readers), redraw_refused=True))
        self.controls["submit"] = submit

    @staticmethod
    def _label(q: Question, item: str) -> str:
        if q.kind == "tlx":
            return TLX_TITLES[item.split(".", 1)[1]]
        return q.text

    def _question(self, q: Question, item: str, draft: dict, confirming: bool) -> Callable:
        """One item's control, its text and the line that says what the server has; the
        function that reads the item's value as the server holds it."""
        gui = self.client.gui
        value = draft.get(item)
        if q.kind == "tlx":
            scale = item.split(".", 1)[1]
            low, high = TLX_ANCHORS[scale]
            gui.add_markdown(f"**{TLX_TITLES[scale]}.** {TLX_TEXT[scale]}")
            control = gui.add_slider(
                TLX_TITLES[scale],
                min=0.0,
                max=100.0,
                step=5.0,
                initial_value=50.0 if value is None else float(value),
                marks=((0, low), (100, high)),
                disabled=confirming,
            )
            if value is None:  # no 50 at rest to take for an answer: an empty box
                clear(control)
        elif q.kind == "likert":
            gui.add_markdown(f"**{q.text}**")
            options = likert_options(q)
            control = gui.add_dropdown(
                "Your answer",
                options=options,
                initial_value=UNANSWERED if value is None else options[int(value)],
                disabled=confirming,
            )
        else:
            gui.add_markdown(f"**{q.text}**" + ("" if q.required else " (optional)"))
            control = gui.add_text(
                "Your answer",
                initial_value="" if value is None else str(value),
                disabled=confirming,
            )
        echo = gui.add_markdown(self._echo(q, item, value))
        made = control.update_timestamp
        self.controls[item] = control

        def read(c=control, made=made) -> object:
            """The value the server holds for the item (None: not answered): a control the
            participant has not moved has none, unless a draft gave it one."""
            if c.update_timestamp == made:
                return value
            if q.kind == "likert":
                return None if c.value == UNANSWERED else int(c.value.split(":")[0])
            if q.kind == "tlx":
                return int(c.value)
            return c.value

        def moved(_event) -> None:
            got = read()
            with self.study._lock:
                if got is None or got == "":
                    draft.pop(item, None)
                else:
                    draft[item] = got
            try:
                echo.content = self._echo(q, item, got)
            except Exception:  # the step left the page meanwhile
                pass

        control.on_update(moved)
        return read

    @staticmethod
    def _echo(q: Question, item: str, value) -> str:
        if value is None or value == "":
            if q.kind == "text":
                return "_Nothing written yet._"
            how = (
                "choose one"
                if q.kind == "likert"
                else "move the slider, or type a number into its box and press Enter"
            )
            return f"_Not answered yet: {how}._"
        return f"Received: **{shown_value(q, item, value)}**"

    def _submit(self, step: Step, readers: dict) -> None:
        """Submit: the answers as the server has them, kept as the draft; refused while a
        required one is missing, else shown for confirmation."""
        got = {item: read() for item, read in readers.items()}
        draft = self._draft(step)
        with self.study._lock:
            draft.clear()
            draft.update({k: v for k, v in got.items() if v is not None and v != ""})
        missing = [
            self._label(q, item)
            for q in step.questions
            for item in q.items()
            if q.required and got.get(item) in (None, "")
        ]
        if missing:
            raise ValueError(
                f"not answered yet: {', '.join(missing)} (the page now shows what we have received)"
            )
        self.pending = check_answers(step, got)

    def _change(self) -> None:
        self.pending = None

    def _confirm(self, step: Step) -> None:
        answers, self.pending = self.pending, None
        self.person.answer(answers, step.key)
        with self.study._lock:
            self.study.drafts.pop((self.code, step.key), None)


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
        b: dict = {}  # self.buttons once every control is made (a test waits on it)
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
            }
            for label, action in actions.items():
                b[label] = gui.add_button(label)
                b[label].on_click(lambda _, a=action: self._do(a))
            # What ends or deletes something is asked again, naming the participant.
            for label in DESTRUCTIVE:
                b[label] = gui.add_button(label, color="red" if "delete" in label else None)
                b[label].on_click(lambda _, label=label: self._do(lambda: self._arm(label)))
            self.question = gui.add_markdown("", visible=False)
            b["confirm"] = gui.add_button("Confirm", color="red", visible=False)
            b["cancel"] = gui.add_button("Cancel", visible=False)
            b["confirm"].on_click(lambda _: self._do(self._confirmed))
            b["cancel"].on_click(lambda _: self._do(self._disarm))
        #: (action, code) pressed and not yet confirmed
        self.armed: tuple[str, str] | None = None
        self.said = gui.add_markdown("")
        self.buttons = b
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

    def _arm(self, label: str) -> None:
        code = self._code()
        self.armed = (label, code)
        self.question.content = f"**{label}: {code}?** {DESTRUCTIVE[label]}"
        self.buttons["confirm"].label = f"Confirm: {label.lower()} {code}"
        for part in (self.question, self.buttons["confirm"], self.buttons["cancel"]):
            part.visible = True

    def _disarm(self) -> None:
        self.armed = None
        for part in (self.question, self.buttons["confirm"], self.buttons["cancel"]):
            part.visible = False

    def _confirmed(self) -> None:
        if self.armed is None:
            raise StudyError("nothing to confirm")
        (label, code), self.armed = self.armed, None
        self._disarm()
        if label == "Abort the trial":
            self.study.abort_trial(code)
        else:
            self.study.withdraw(code, delete=label != "Withdraw")
        self.said.content = f"Done: {label.lower()} {code}."

    def _code(self) -> str:
        code = self.who.value.strip()
        if self.study.run.log.participant(code) is None:
            raise StudyError(f"participant “{code}”: not enrolled")
        return code

    def _do(self, action: Callable[[], object]) -> None:
        try:
            self.said.content = ""
            action()
        except (StudyError, ValueError) as exc:  # (it may quote what was typed: as typed)
            self.said.content = f"**Not done**: {as_typed(str(exc).splitlines()[0])}"
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
