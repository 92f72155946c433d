"""A participant's way through a protocol: the state machine the study page and the
simulated cohort share.

:class:`StudyRun` holds a protocol (:mod:`corrections_sim.userstudy.protocol`) and its study log;
it enrolls participants (a code, the next index, a link secret whose SHA-256 alone is logged)
and finds them again by code or by link. :class:`Participant` knows where one participant is:
the first step of their protocol that has not finished, read from the log each time, so a
crash, a reload or a closed tab resumes exactly there. A step moves on only through:

* :meth:`Participant.proceed` — an instructions step read;
* :meth:`Participant.session` / :meth:`Participant.finish_trial` — a trial's session (a new
  one, or the one logged for this step resumed from its corrections), ended after the
  protocol's number of corrections (or the page's "Done" once it has ``min_corrections``);
* :meth:`Participant.stop_trial` — the participant ends a trial early (logged as such; the
  analysis leaves the trial out of the primary outcome and counts it);
* :meth:`Participant.answer` — a questionnaire's answers, checked item by item, written with
  the step's end and what each item asked in one transaction (a second post is refused, the
  first kept);
* :meth:`Participant.leave` — the participant withdraws from their own page.

Nothing here draws or plans by itself: a trial is a :class:`~corrections_sim.session.session.
Session` like any other, so a study's trials replay and resume like single sessions.

:func:`simulate_participant` takes a simulated participant (θ* drawn from the protocol's
population) through the very same steps headless: the trials by the study's simulated user
(:func:`~corrections_sim.session.simulate.simulate`), the questionnaires answered from the
protocol's response model of what they experienced. Their rows say they are simulated.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import secrets
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from corrections_sim.metrics import regret_terms
from corrections_sim.people.users import make_user
from corrections_sim.planning.planner import PlanningError, shared_planner, smoothness_cost
from corrections_sim.plans.book import PlanBook
from corrections_sim.session.log import StudyError, StudyLog, check_participant, now
from corrections_sim.session.session import Session, physical_learner
from corrections_sim.session.simulate import simulate
from corrections_sim.study.settings import FigureSettings
from corrections_sim.userstudy.protocol import (
    Protocol,
    Step,
    design_fingerprint,
    likert_value,
    tlx_value,
)


def token_hash(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def trial_seed(protocol: Protocol, index: int, key: str) -> int:
    """The seed of participant ``index``'s trial ``key`` (its environment draws)."""
    digest = hashlib.sha256(f"{protocol.seed}/{index}/{key}".encode()).digest()
    return int.from_bytes(digest[:6], "big")


def participant_rng(protocol: Protocol, index: int) -> np.random.Generator:
    """The generator of simulated participant ``index`` (θ*, answers)."""
    return np.random.default_rng(np.random.SeedSequence([protocol.seed, 42, index]))


def correction_of(protocol: Protocol, name: str) -> str:
    """The correction model of condition ``name``'s sessions."""
    return "physical" if protocol.condition(name).mode == "physical" else "waypoint"


def learner_params_of(protocol: Protocol, settings_of: Mapping, name: str) -> dict | None:
    """Condition ``name``'s learner parameters: a physical condition's learner takes the
    ``physical`` model of a push where it takes a model (as ``interact --mode physical``)."""
    condition = protocol.condition(name)
    if condition.mode != "physical":
        return None
    given = any(k.startswith(f"learners.{condition.learner}.model") for k, _ in condition.set)
    return physical_learner(settings_of[name], condition.learner, model_set=given)


def check_conditions(protocol: Protocol, settings_of: Mapping[str, FigureSettings]) -> None:
    """Every condition (and the practice) has study settings and a learner and correction
    model its sessions can start with (Session.prepare's checks; nothing is written).

    Raises:
        ValueError: one line naming the condition or the learner.
    """
    names = [*protocol.names, *([protocol.practice.name] if protocol.practice else [])]
    missing = [n for n in names if n not in settings_of]
    if missing:
        raise ValueError(f"condition {missing[0]}: no study settings for it")
    for name in names:
        Session.prepare(
            settings_of[name],
            protocol.condition(name).learner,
            learner_params_of(protocol, settings_of, name),
            correction_of(protocol, name),
        )


def adopt_protocol(log: StudyLog, protocol: Protocol) -> None:
    """Tie ``log`` to ``protocol`` (a new log) or check that it is tied to the same design
    (:func:`~corrections_sim.userstudy.protocol.design_fingerprint`): a protocol whose prose was
    corrected is adopted, the earlier wording kept in ``meta`` (``protocol_versions``).

    Raises:
        ValueError: the log belongs to another design (one line).
    """
    stored = log.meta("protocol")
    if stored is None:
        log.set_meta("protocol", json.dumps(protocol.source, sort_keys=True))
        log.set_meta("protocol_sha256", protocol.fingerprint())
        return
    source = json.loads(stored)
    found = design_fingerprint(source)
    if found != protocol.design_fingerprint():
        raise ValueError(
            f"{log.path}: this log belongs to another protocol (its design's SHA-256 "
            f"{found[:12]}…, this one's {protocol.design_fingerprint()[:12]}…; only the "
            "wording of instructions and questions may change within a study); use a new --db"
        )
    if log.meta("protocol_sha256") == protocol.fingerprint():
        return
    versions = json.loads(log.meta("protocol_versions") or "[]")
    versions.append({"until": now(), "sha256": log.meta("protocol_sha256"), "source": source})
    log.set_meta("protocol_versions", json.dumps(versions, sort_keys=True))
    log.set_meta("protocol", json.dumps(protocol.source, sort_keys=True))
    log.set_meta("protocol_sha256", protocol.fingerprint())


@dataclass(frozen=True)
class Where:
    """Where a participant is: the step, its position among ``total``, whether withdrawn."""

    code: str
    index: int
    position: int
    total: int
    step: Step
    withdrawn: bool
    session_id: int | None


class StudyRun:
    """A protocol and its study log (see the module). Thread-safe.

    Args:
        settings_of: the study settings of a condition (name -> FigureSettings), made by the
            caller (the command line reads the protocol's study file); checked up front.
    """

    def __init__(
        self,
        protocol: Protocol,
        log: StudyLog,
        settings_of: Mapping[str, FigureSettings],
    ) -> None:
        self.protocol = protocol
        self.log = log
        self.settings_of = dict(settings_of)
        check_conditions(protocol, self.settings_of)
        adopt_protocol(log, protocol)
        log.prepare_study()
        self._lock = threading.RLock()
        #: Every session of this run plans under it (see Session's ``lock``).
        self.planning = threading.RLock()
        self._sessions: dict[tuple[str, int], Session] = {}

    def read_plans(self) -> int:
        """Every condition's plan atlas and the plans kept between its nodes, read into this
        process before participants come (a server's first submits would otherwise wait for
        them: 1.8 million stored plans of fig. 4's environments take seconds); how many plans
        between nodes are held. No number depends on it."""
        held, seen = 0, set()
        for settings in self.settings_of.values():
            atlas = settings.atlas()
            if atlas is None or id(atlas) in seen:
                continue
            seen.add(id(atlas))
            held += sum(atlas.read(env) for env in settings.envs())
        return held

    # --- conditions ------------------------------------------------------------------------

    def correction(self, name: str) -> str:
        return correction_of(self.protocol, name)

    def learner_params(self, name: str) -> dict | None:
        return learner_params_of(self.protocol, self.settings_of, name)

    # --- participants ----------------------------------------------------------------------

    def enroll(
        self, code: str, *, simulated: Mapping | None = None, index: int | None = None
    ) -> tuple[Participant, str]:
        """A new participant under ``code`` (``index``: the next one by default; a simulated
        cohort split over workers gives its own) and their link's secret (shown once, never
        logged). Raises StudyError for a used code."""
        check_participant(code)
        with self._lock:
            if index is None:
                index = max((p["index"] for p in self.log.participants()), default=-1) + 1
            token = secrets.token_urlsafe(24)
            self.log.enroll(code, index, token_hash(token), simulated)
            return self.participant(code), token

    def participant(self, code: str) -> Participant:
        row = self.log.participant(code)
        if row is None:
            raise StudyError(f"participant {code}: not enrolled in {self.log.path.name}")
        return Participant(self, row["code"], int(row["index"]))

    def by_token(self, token: str) -> Participant | None:
        """The participant whose link carries ``token`` (compared in constant time), or None."""
        if not isinstance(token, str) or not token:
            return None
        wanted = token_hash(token)
        for row in self.log.participants():
            if hmac.compare_digest(row["token_hash"], wanted) and row["withdrawn"] is None:
                return Participant(self, row["code"], int(row["index"]))
        return None

    def new_link(self, code: str) -> str:
        """A new link secret for ``code``; the old link stops working."""
        self.participant(code)
        token = secrets.token_urlsafe(24)
        self.log.set_token(code, token_hash(token))
        return token

    def status(self) -> list[Where]:
        """Where every participant is, by index."""
        return [self.participant(row["code"]).where() for row in self.log.participants()]

    def withdraw(self, code: str, *, delete: bool = False, by: str = "experimenter") -> None:
        """Withdraw ``code`` (``by``: who asked, the experimenter or the participant): their
        rows leave every analysis; with ``delete`` they are deleted."""
        with self._lock:
            for key in [k for k in self._sessions if k[0] == code]:
                held = self._sessions.pop(key)
                if not held.ended:
                    held.log.add_event(held.id, held.iteration, "withdrawn", {"by": by})
                    held.log.end_session(held.id)
                    held.ended = True
            self.log.withdraw(code, delete=delete)  # refuses a code not in the log
            if not delete:
                self.log.add_participant_event(code, "withdrew", {"by": by})


class Participant:
    """One participant of a :class:`StudyRun` (see the module)."""

    def __init__(self, run: StudyRun, code: str, index: int) -> None:
        self.run = run
        self.code = code
        self.index = index
        self.steps = run.protocol.steps(index)
        self._felt: dict[int, dict] = {}

    @property
    def log(self) -> StudyLog:
        return self.run.log

    def _rows(self) -> dict[int, dict]:
        return {r["position"]: r for r in self.log.steps(self.code)}

    def position(self) -> int:
        """The first step not finished (len(steps) - 1 at the end, which never finishes)."""
        rows = self._rows()
        for position in range(len(self.steps)):
            row = rows.get(position)
            if row is None or row["finished"] is None:
                return position
        return len(self.steps) - 1

    def withdrawn(self) -> bool:
        row = self.log.participant(self.code)
        return row is None or row["withdrawn"] is not None

    def where(self) -> Where:
        position = self.position()
        row = self._rows().get(position)
        return Where(
            self.code,
            self.index,
            position,
            len(self.steps),
            self.steps[position],
            self.withdrawn(),
            None if row is None else row["session_id"],
        )

    def current(self) -> Step:
        """The step the participant is at (begun in the log when first asked)."""
        if self.withdrawn():
            raise StudyError(f"participant {self.code}: withdrawn")
        position = self.position()
        step = self.steps[position]
        self.log.begin_step(self.code, position, step.key)
        return step

    def _expect(self, kind: str, key: str | None) -> tuple[int, Step]:
        step = self.current()
        if step.kind != kind or (key is not None and step.key != key):
            raise StudyError(
                f"participant {self.code}: at step {step.key} ({step.kind}), not {key or kind}"
            )
        return self.position(), step

    def proceed(self, key: str | None = None) -> Step:
        """An instructions step read (``key``: the step the page showed; a stale click from
        another step is refused); the next step."""
        position, step = self._expect("instructions", key)
        self.log.finish_step(self.code, position, step.key)
        return self.current()

    # --- trials ----------------------------------------------------------------------------

    def corrections(self, step: Step) -> int:
        p = self.run.protocol
        return p.practice_corrections if step.trial == 0 else p.corrections

    def minimum(self, step: Step) -> int:
        """Corrections the trial ``step`` needs before it may end (the practice: all)."""
        p = self.run.protocol
        return p.practice_corrections if step.trial == 0 else p.minimum

    @property
    def needs_stated(self) -> bool:
        """The protocol's primary outcome is measured against the stated preference, so a
        trial's page asks for it before the first correction."""
        return self.run.protocol.primary in ("final_error", "mean_regret")

    def session(self, key: str | None = None, *, corrector: Any = "person") -> Session:
        """The session of the current trial step: the one this server holds, the one the log
        has for it (resumed from its corrections), or a new one."""
        run = self.run
        with run._lock:
            position, step = self._expect("trial", key)
            held = run._sessions.get((self.code, position))
            row = self._rows()[position]
            if held is not None and held.id == row["session_id"]:
                return held
            name = step.condition
            settings = run.settings_of[name]
            if row["session_id"] is not None:
                session = Session.resume(self.log, row["session_id"], lock=run.planning)
            else:
                condition = run.protocol.condition(name)
                session = Session.start(
                    settings,
                    self.log,
                    learner=condition.learner,
                    params=run.learner_params(name),
                    correction=run.correction(name),
                    participant=self.code,
                    corrector=corrector,
                    seed=trial_seed(run.protocol, self.index, step.key),
                    lock=run.planning,
                )
                self.log.add_event(
                    session.id,
                    -1,
                    "trial",
                    {
                        "step": step.key,
                        "condition": name,
                        "trial": step.trial,
                        "position": position,
                    },
                )
                self.log.set_step_session(self.code, position, session.id)
            run._sessions[(self.code, position)] = session
            return session

    def finish_trial(self, key: str | None = None) -> Step:
        """End the current trial (its session is finished first if it is not); the next step.

        Raises:
            StudyError: not at a trial, or the trial has fewer corrections than it needs
                (:meth:`minimum`; a participant who wants to stop uses :meth:`stop_trial`).
        """
        run = self.run
        with run._lock:
            position, step = self._expect("trial", key)
            session = self.session(step.key)
            # A stop whose step never finished (the server died in between) ends it here.
            stopped = bool(self.log.events(session.id, "stopped"))
            if session.iteration < self.minimum(step) and not stopped:
                raise StudyError(
                    f"participant {self.code}: trial {step.key} has {session.iteration} of "
                    f"the {self.minimum(step)} corrections it needs"
                )
            if not session.ended:
                session.finish()
            self.log.finish_step(self.code, position, step.key)
            run._sessions.pop((self.code, position), None)
        return self.current()

    def stop_trial(self, key: str | None = None) -> Step:
        """The participant ends the current trial early: its session ends, marked
        ``stopped`` (with its corrections) in the session and the participant's events; the
        trial counts as ended early and leaves the primary analysis. The next step."""
        run = self.run
        with run._lock:
            position, step = self._expect("trial", key)
            session = self.session(step.key)
            detail = {"step": step.key, "corrections": session.iteration, "by": "participant"}
            self.log.add_event(session.id, session.iteration, "stopped", detail)
            self.log.add_participant_event(self.code, "stopped", detail)
            if not session.ended:
                session.finish()
            self.log.finish_step(self.code, position, step.key)
            run._sessions.pop((self.code, position), None)
        return self.current()

    def leave(self) -> None:
        """The participant withdraws from their own page (rows kept, marked, out of every
        analysis; the experimenter may still delete them)."""
        self.run.withdraw(self.code, by="participant")

    def abort_trial(self) -> int | None:
        """The experimenter aborts the current trial: its session ends (kept, marked aborted
        and left out of every analysis) and the trial starts over with a new one."""
        run = self.run
        with run._lock:
            position, step = self._expect("trial", None)
            held = run._sessions.pop((self.code, position), None)
            aborted = self.log.abort_step(self.code, position)
            if aborted is not None:
                self.log.add_event(aborted, -1, "aborted", {"step": step.key})
                if held is None or not held.ended:
                    self.log.end_session(aborted)
                if held is not None:
                    held.ended = True
            return aborted

    def trial_sessions(self, condition: str | None = None) -> list[tuple[Step, int]]:
        """(step, session id) of every finished trial (of ``condition``), aborted ones not."""
        rows = self._rows()
        out = []
        for position, step in enumerate(self.steps):
            row = rows.get(position)
            if step.kind != "trial" or row is None or row["finished"] is None:
                continue
            if step.trial == 0 or (condition is not None and step.condition != condition):
                continue
            out.append((step, int(row["session_id"])))
        return out

    def experienced(self, theta_star, condition: str | None = None) -> dict:
        """The mean over the finished trials (of ``condition``) of :func:`experienced`."""
        theta_star = np.asarray(theta_star, float)
        felt = []
        for step, sid in self.trial_sessions(condition):
            if sid not in self._felt:
                logged = logged_experience(self.log.events(sid, "experienced"))
                if logged is not None:
                    self._felt[sid] = logged
                else:
                    settings = self.run.settings_of[step.condition]
                    rows = self.log.corrections(sid)
                    self._felt[sid] = experienced(settings, rows, theta_star)
                    # Kept beside the trial: the analysis reads the very numbers the
                    # simulated answers came from (a person's are computed there).
                    self.log.add_event(sid, len(rows), "experienced", self._felt[sid])
            felt.append(self._felt[sid])
        if not felt:
            return {"regret": 0.0, "error": 0.0}
        return {m: float(np.nanmean([f[m] for f in felt])) for m in ("regret", "error")}

    # --- questionnaires --------------------------------------------------------------------

    def answer(self, answers: Mapping[str, Any], key: str | None = None) -> Step:
        """The current questionnaire's answers (item -> value; a TLX's items are
        ``id.scale``), checked and logged with the step's end; the next step.

        Raises:
            StudyError: not at a questionnaire, or it was answered already.
            ValueError: an unknown item, a missing required one, or a value off its scale.
        """
        position, step = self._expect("questions", key)
        checked = check_answers(step, answers)
        asked = {
            item: q.asked(item) for q in step.questions for item in q.items() if item in checked
        }
        self.log.finish_step(self.code, position, step.key, checked, asked)
        return self.current()


def check_answers(step: Step, answers: Mapping[str, Any]) -> dict:
    """``answers`` (item -> value) of the questionnaire ``step`` as logged: each value on its
    item's scale, a missing required item refused, a missing optional one left out (never
    stored as a value the participant did not give).

    Raises:
        ValueError: an unknown item, a missing required one, or a value off its scale.
    """
    by_item = {item: q for q in step.questions for item in q.items()}
    unknown = [item for item in answers if item not in by_item]
    if unknown:
        raise ValueError(f"{unknown[0]}: not an item of {step.key}")
    checked = {}
    for item, question in by_item.items():
        value = answers.get(item)
        if value is None or value == "":
            if question.required:
                raise ValueError(f"{item}: not answered (required)")
            continue
        checked[item] = question.check_answer(item, value)
    return checked


# --- a simulated participant -------------------------------------------------------------


def draw_simulated(protocol: Protocol, index: int, k: int) -> dict:
    """Simulated participant ``index``'s θ* (k,) and user, from the protocol's population."""
    sim = protocol.simulation
    if sim is None:
        raise ValueError("simulation: the protocol states no simulated population")
    if len(sim.mean) != k:
        raise ValueError(f"simulation.mean: expected {k} weights (the study's features)")
    rng = participant_rng(protocol, index)
    theta = np.asarray(sim.mean) + np.asarray(sim.sd) * rng.standard_normal(k)
    drawn = {"theta_star": theta.tolist(), "user": sim.user, "simulated": True}
    if any(c.mode == "physical" for c in (*protocol.conditions, protocol.practice) if c):
        drawn["physical_user"] = sim.physical_user
    return drawn


def _user(spec):
    """A simulated user from a name or a table {name, params...}."""
    if isinstance(spec, str):
        return make_user(spec)
    return make_user(spec["name"], {k: v for k, v in spec.items() if k != "name"})


#: What a logged ``experienced`` event's regret measures: events without it (logged before
#: the regret was the planner's full objective, 2026-11-30, θ*·Φ alone) are not read but
#: computed again, so a resumed pool or an old log never mixes the two.
REGRET_MEASURE = "full objective"


def logged_experience(events: list[dict]) -> dict | None:
    """The last of a trial's ``experienced`` events whose regret is today's measure
    (:data:`REGRET_MEASURE`), or None."""
    kept = [e["detail"] for e in events if e["detail"].get("measure") == REGRET_MEASURE]
    return kept[-1] if kept else None


def experienced(settings: FigureSettings, rows: list[dict], theta_star: np.ndarray) -> dict:
    """What a participant with preference ``theta_star`` experienced in a trial (its logged
    ``rows``): the mean regret of the plans shown under the planner's full objective, as the
    studies' ``regret`` (:mod:`corrections_sim.metrics`): R*(ξ) = θ*·Φ(ξ, E) − λ·S(ξ), regret
    R*(ξ*) − R*(ξᵗ) ≥ 0 with ξ* their own optimal plan in each environment (from the study's
    plan atlas when it has one, as the robot's plans are). θ*·Φ alone goes below zero
    wherever the robot's plan buys θ*'s features with a less smooth path. Also the final
    error ‖θ̂ − θ*‖₁ / ‖θ*‖₁."""
    book = PlanBook(shared_planner(settings.planner_config()), atlas=settings.atlas())
    lam = book.planner.config.smoothness
    envs = settings.envs()
    regrets = []
    for row in rows:
        env = envs[int(row["env_index"])]
        try:
            best = book.plan(theta_star, env)
        except PlanningError:
            continue
        full, _ = regret_terms(
            theta_star,
            best.features,
            smoothness_cost(best.trajectory),
            np.asarray(row["phi_robot"]),
            smoothness_cost(np.asarray(row["xi_robot"])),
            lam,
        )
        regrets.append(full)
    theta = rows[-1]["theta_after"] if rows else np.zeros_like(theta_star)
    scale = max(float(np.sum(np.abs(theta_star))), 1e-12)
    error = float(np.sum(np.abs(np.asarray(theta) - theta_star)) / scale)
    regret = float(np.mean(regrets)) if regrets else float("nan")
    return {"regret": regret, "error": error, "measure": REGRET_MEASURE}


def simulated_answers(
    protocol: Protocol, step: Step, felt: dict, rng, by_order: tuple[dict, ...] = ()
) -> dict:
    """A simulated questionnaire from the protocol's response model (see
    :class:`~corrections_sim.userstudy.protocol.Response`); text items say they are simulated.
    An item that compares the robots answers from ``by_order`` (what the participant
    experienced with each condition, in the order they met them): the measure is the second
    one's minus the first one's."""
    answers: dict[str, Any] = {}
    for q in step.questions:
        response = protocol.simulation.response(q.id)
        measure = felt.get(response.measure, 0.0)
        if q.compare and len(by_order) == 2:
            measure = by_order[1][response.measure] - by_order[0][response.measure]
        if not np.isfinite(measure):
            measure = 0.0
        if q.kind == "likert":
            answers[q.id] = likert_value(response, measure, q.points, rng)
        elif q.kind == "tlx":
            for item in q.items():
                answers[item] = tlx_value(response, measure, rng)
        else:
            answers[q.id] = "(simulated participant)"
    return answers


def simulate_participant(run: StudyRun, code: str, index: int | None = None) -> Participant:
    """Enroll simulated participant ``code`` (``index``: the next by default) and take them
    through the whole protocol (see the module); one enrolled before resumes where they are."""
    protocol = run.protocol
    if run.log.participant(code) is None:
        if index is None:
            index = max((p["index"] for p in run.log.participants()), default=-1) + 1
        any_settings = next(iter(run.settings_of.values()))
        drawn = draw_simulated(protocol, index, any_settings.study.k)
        person, _ = run.enroll(code, simulated=drawn, index=index)
    else:
        person = run.participant(code)
        drawn = run.log.participant(code)["simulated"]
        if drawn is None:
            raise StudyError(f"participant {code}: a person, not a simulated participant")
    theta = np.asarray(drawn["theta_star"], float)
    # Who corrects: the population's user in drag conditions, its physical user (pushing
    # the moving arm) in physical ones.
    users = {
        "drag": _user(drawn["user"]),
        "physical": _user(drawn.get("physical_user", "physical")),
    }
    rng = participant_rng(protocol, person.index)
    rng.standard_normal(len(theta))  # the draw of θ* (draw_simulated's)
    while True:
        step = person.current()
        if step.kind == "end":
            return person
        if step.kind == "instructions":
            person.proceed(step.key)
        elif step.kind == "trial":
            session = person.session(step.key, corrector={"simulated": True, **drawn})
            left = person.corrections(step) - session.iteration
            if left > 0:
                mode = protocol.condition(step.condition).mode
                simulate(session, users[mode], theta, left)
            person.finish_trial(step.key)
        elif step.kind == "questions":
            # What they experienced in the condition's trials (all conditions at the end),
            # read back from the log: a participant resumed after a crash answers the same.
            felt = person.experienced(theta, step.condition)
            by_order = ()
            if any(q.compare for q in step.questions):
                order = protocol.order_of(person.index)
                by_order = tuple(person.experienced(theta, name) for name in order)
            person.answer(simulated_answers(protocol, step, felt, rng, by_order), step.key)
