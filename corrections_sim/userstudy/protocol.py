"""A user study's protocol: conditions, trials, a practice trial, instructions, questionnaires,
the order of conditions per participant, and (for piloting) the simulated population.

A protocol file (TOML, ``experiments/protocol.toml``) is checked here key by key, with the
same one-line errors as study files (``conditions[1].learner: unknown learner 'KF-X' …``).
Nothing here runs a trial: :func:`steps` lists what a participant goes through, in order,
and :mod:`corrections_sim.userstudy.participant` walks it (the page and the simulated cohort
alike).

The order of conditions is a balanced Latin square (:func:`latin_square`): Williams' design
(Williams 1949; Bradley 1958) where every condition stands at every position once per square
and, for an even number of conditions, follows every other condition once (for an odd number
two squares, the second mirrored, give the same balance over 2n participants). Participant i
(0-based, the order they were enrolled in) takes row ``i mod rows`` of the square whose rows
are shuffled by the protocol's seed, so any participant's order is reproducible from their
index and the seed.
"""

from __future__ import annotations

import hashlib
import json
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim.learning.base import LEARNERS
from corrections_sim.study.checks import integer, number, reject_unknown, vector

#: How a condition's trials are shown: dragging a waypoint's cup, or pushing the moving arm.
MODES = ("drag", "physical")
#: Question kinds: a Likert item, the raw NASA-TLX (six subscales, 0-100), free text.
QUESTION_KINDS = ("likert", "tlx", "text")
#: The raw NASA-TLX's subscales (Hart 1988), each 0-100 in steps of 5.
TLX_SCALES = ("mental", "physical", "temporal", "performance", "effort", "frustration")
TLX_TEXT = {
    "mental": "How mentally demanding was the task?",
    "physical": "How physically demanding was the task?",
    "temporal": "How hurried or rushed was the pace of the task?",
    "performance": "How successful were you in accomplishing what you were asked to do?",
    "effort": "How hard did you have to work to accomplish your level of performance?",
    "frustration": "How insecure, discouraged, irritated, stressed and annoyed were you?",
}
#: Each TLX scale's own anchors (low, high): performance runs from perfect to failure.
TLX_ANCHORS = {
    scale: ("Perfect", "Failure") if scale == "performance" else ("Very low", "Very high")
    for scale in TLX_SCALES
}
#: The TLX scales' names as a participant reads them.
TLX_TITLES = {
    "mental": "Mental demand",
    "physical": "Physical demand",
    "temporal": "Temporal demand",
    "performance": "Performance",
    "effort": "Effort",
    "frustration": "Frustration",
}
#: Likert scales may have 2 to 11 points.
LIKERT_POINTS = (2, 11)
#: Orders of conditions: a balanced Latin square (Williams), or every participant the same.
ORDERS = ("williams", "fixed")
#: What a simulated participant's answers may depend on (per trial, mean over its
#: corrections): the regret of the plans they were shown, the estimate's final error.
RESPONSE_MEASURES = ("regret", "error")
#: The outcome measures of a trial, as the analysis names them.
OUTCOMES = ("final_error", "mean_regret", "seconds")

PROTOCOL_KEYS = (
    "description",
    "study",
    "seed",
    "order",
    "corrections",
    "min_corrections",
    "trials",
    "primary",
    "min_participants",
    "welcome",
    "end",
    "practice",
    "conditions",
    "questionnaires",
    "simulation",
)


@dataclass(frozen=True)
class Question:
    """One item: ``kind`` likert (``points``, ``anchors`` (low, high)), tlx (six subscales,
    answered as ``id.scale``), text (free)."""

    id: str
    kind: str
    text: str = ""
    points: int = 7
    anchors: tuple[str, str] = ("Strongly disagree", "Strongly agree")
    required: bool = True
    #: An end item that compares the two conditions by the participant's order: its low
    #: anchor is the robot they met first, its high anchor the one they met second (the
    #: analysis maps each answer to the conditions).
    compare: bool = False

    def items(self) -> tuple[str, ...]:
        """The answer keys this question takes (a TLX question takes six)."""
        if self.kind == "tlx":
            return tuple(f"{self.id}.{s}" for s in TLX_SCALES)
        return (self.id,)

    def asked(self, item: str) -> dict:
        """What the participant was asked for ``item``, as the log keeps it beside the answer
        (the text and the anchors give an answer its meaning; a protocol's wording may be
        corrected between participants)."""
        if self.kind == "tlx":
            scale = item.split(".", 1)[1]
            return {
                "kind": "tlx",
                "text": TLX_TEXT[scale],
                "title": TLX_TITLES[scale],
                "anchors": list(TLX_ANCHORS[scale]),
                "scale": [0, 100],
            }
        if self.kind == "likert":
            return {
                "kind": "likert",
                "text": self.text,
                "anchors": list(self.anchors),
                "scale": [1, self.points],
                "compare": self.compare,
            }
        return {"kind": "text", "text": self.text}

    def check_answer(self, item: str, value: Any) -> Any:
        """``value`` as logged for ``item``; a one-line ValueError if it is not an answer."""
        if self.kind == "likert":
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{item}: expected a whole number 1-{self.points}, got {value!r}")
            if value != int(value) or not 1 <= value <= self.points:
                raise ValueError(f"{item}: expected a whole number 1-{self.points}, got {value!r}")
            return int(value)
        if self.kind == "tlx":
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{item}: expected 0-100 in steps of 5, got {value!r}")
            if not 0 <= value <= 100 or value % 5:
                raise ValueError(f"{item}: expected 0-100 in steps of 5, got {value!r}")
            return int(value)
        if not isinstance(value, str) or len(value) > 4000:
            raise ValueError(f"{item}: expected text of at most 4000 characters")
        return value


@dataclass(frozen=True)
class Condition:
    """One condition: a learner, a mode, and any study keys (``set``: key path -> value)."""

    name: str
    learner: str
    mode: str = "drag"
    set: tuple[tuple[str, Any], ...] = ()
    instructions: str = ""

    def overrides(self) -> dict[str, Any]:
        return dict(self.set)


def templated(text: str, robot: int, robots: int) -> str:
    """A condition's text for a participant who meets it as robot ``robot`` of ``robots``
    (``{robot}`` and ``{robots}`` replaced; nothing else in the text is touched)."""
    return text.replace("{robot}", str(robot)).replace("{robots}", str(robots))


#: A robot named by its number in a condition's text ("Robot 2"): the number is each
#: participant's own (their order), so a protocol writes {robot} instead.
_ROBOT_NUMBER = re.compile(r"\brobots?\s*(?:no\.?\s*|number\s*|#\s*)?\d+", re.IGNORECASE)


@dataclass(frozen=True)
class Response:
    """A simulated answer: intercept + slope · measure + N(0, noise²), rounded and clipped to
    the item's scale (``measure`` one of :data:`RESPONSE_MEASURES`)."""

    measure: str = "regret"
    intercept: float = 4.0
    slope: float = -1.0
    noise: float = 1.0


@dataclass(frozen=True)
class Simulation:
    """The simulated population a pilot or a power analysis draws participants from: θ* ~
    N(mean, diag(sd²)) per participant, the simulated user (a name or a table, as a study's
    ``user``) in drag conditions and ``physical_user`` in physical ones, and a response model
    per question id (``default`` for the rest)."""

    mean: tuple[float, ...]
    sd: tuple[float, ...]
    user: Any = "noisy"
    responses: tuple[tuple[str, Response], ...] = ()
    #: who pushes the moving arm in a physical condition (``user`` corrects in the others)
    physical_user: Any = "physical"

    def response(self, question_id: str) -> Response:
        table = dict(self.responses)
        return table.get(question_id, table.get("default", Response()))


@dataclass(frozen=True)
class Step:
    """One step of a participant's way through the protocol.

    Attributes:
        key: unique within the protocol ("welcome", "practice", "A.instructions",
            "A.trial1", "A.questions", "end.questions", "end").
        kind: "instructions", "trial", "questions" or "end".
        condition: the condition's name (None for the welcome, the end and the practice).
        trial: the trial's number within its condition (1-based; 0 the practice).
        text: what the page says at this step.
        questions: the questionnaire of a "questions" step.
    """

    key: str
    kind: str
    condition: str | None = None
    trial: int = 0
    text: str = ""
    questions: tuple[Question, ...] = ()


@dataclass(frozen=True)
class Protocol:
    """A checked protocol (see the module)."""

    conditions: tuple[Condition, ...]
    study: str = "fig4"
    seed: int = 0
    order: str = "williams"
    corrections: int = 5
    #: corrections a participant gives before a trial may end ("Done"); default all of them
    min_corrections: int | None = None
    trials: int = 1
    #: below this many participants the report is descriptive only
    min_participants: int = 6
    description: str = ""
    welcome: str = ""
    end: str = ""
    primary: str = "final_error"
    practice: Condition | None = None
    practice_corrections: int = 2
    after_condition: tuple[Question, ...] = ()
    at_end: tuple[Question, ...] = ()
    simulation: Simulation | None = None
    source: dict = field(default_factory=dict, compare=False)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.conditions)

    def condition(self, name: str) -> Condition:
        if self.practice is not None and name == self.practice.name:
            return self.practice
        for c in self.conditions:
            if c.name == name:
                return c
        raise KeyError(name)

    @property
    def minimum(self) -> int:
        """Corrections a trial needs before it may end (``min_corrections``, default all)."""
        return self.corrections if self.min_corrections is None else self.min_corrections

    def fingerprint(self) -> str:
        """SHA-256 of the protocol's values, prose and all (see :func:`design_fingerprint`
        for what a log is tied to)."""
        text = json.dumps(self.source, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()

    def design_fingerprint(self) -> str:
        """SHA-256 of the protocol's design (see :func:`design_fingerprint`)."""
        return design_fingerprint(self.source)

    def square(self) -> list[list[int]]:
        """The rows of condition indices participants take in turn (see the module)."""
        n = len(self.conditions)
        if self.order == "fixed":
            return [list(range(n))]
        rows = latin_square(n)
        shuffle = np.random.default_rng([self.seed, 41]).permutation(len(rows))
        return [rows[i] for i in shuffle]

    def order_of(self, index: int) -> tuple[str, ...]:
        """The conditions' names in the order participant ``index`` (0-based) takes them."""
        if isinstance(index, bool) or not isinstance(index, int) or index < 0:
            raise ValueError(f"participant index {index!r}: expected an integer >= 0")
        rows = self.square()
        return tuple(self.conditions[i].name for i in rows[index % len(rows)])

    def steps(self, index: int) -> tuple[Step, ...]:
        """What participant ``index`` goes through, in order (see :class:`Step`)."""
        out = [Step("welcome", "instructions", text=self.welcome or self.description)]
        if self.practice is not None:
            text = self.practice.instructions or "A practice trial: nothing here is analysed."
            out.append(Step("practice", "trial", self.practice.name, 0, text))
        # The page names a condition by its place in the participant's order ("robot 2"),
        # never by its name or learner: the participant is blind to the condition.
        order = self.order_of(index)
        for k, name in enumerate(order, 1):
            c = self.condition(name)
            if c.instructions:
                text = templated(c.instructions, k, len(order))
                out.append(Step(f"{name}.instructions", "instructions", name, 0, text))
            for t in range(1, self.trials + 1):
                text = f"**Robot {k} of {len(order)}**, trial {t} of {self.trials}."
                out.append(Step(f"{name}.trial{t}", "trial", name, t, text))
            if self.after_condition:
                text = f"About robot {k}, the one you just worked with."
                out.append(
                    Step(f"{name}.questions", "questions", name, 0, text, self.after_condition)
                )
        if self.at_end:
            out.append(
                Step("end.questions", "questions", None, 0, "About the whole session.", self.at_end)
            )
        out.append(Step("end", "end", text=self.end or "Thank you: you are done."))
        return tuple(out)


def latin_square(n: int) -> list[list[int]]:
    """A balanced Latin square of ``n`` conditions (Williams): n rows for even n (and
    n = 1), 2n (the square and its mirror) for odd n > 1. Every condition stands at every
    position equally often, and each immediately follows each other equally often."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"conditions: expected at least one, got {n!r}")
    # The first row 0, 1, n-1, 2, n-2, ...; row r adds r (mod n).
    first, low, high = [0], 1, n - 1
    while len(first) < n:
        first.append(low)
        low += 1
        if len(first) < n:
            first.append(high)
            high -= 1
    rows = [[(c + r) % n for c in first] for r in range(n)]
    if n % 2 and n > 1:
        rows += [row[::-1] for row in rows]
    return rows


#: The prose of a protocol: what the page says, which may be corrected while a study runs
#: (item texts and anchors are kept with each answer). Everything else is its design.
PROSE = ("description", "welcome", "end")


def design_of(source: Mapping[str, Any]) -> dict:
    """A protocol's values without its prose (:data:`PROSE`, every condition's and the
    practice's ``instructions``, every question's ``text`` and ``anchors``)."""
    out = json.loads(json.dumps(dict(source), default=str))
    for key in PROSE:
        out.pop(key, None)
    for table in (*out.get("conditions", []), out.get("practice", {})):
        if isinstance(table, dict):
            table.pop("instructions", None)
    questionnaires = out.get("questionnaires", {})
    if isinstance(questionnaires, dict):
        for questions in questionnaires.values():
            for q in questions if isinstance(questions, list) else []:
                if isinstance(q, dict):
                    q.pop("text", None)
                    q.pop("anchors", None)
    return out


def design_fingerprint(source: Mapping[str, Any]) -> str:
    """SHA-256 of a protocol's design (:func:`design_of`): a study log is tied to it, so its
    prose can be corrected without locking the experimenter out of the log."""
    text = json.dumps(design_of(source), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


# --- reading a protocol file ----------------------------------------------------------------


def _text(name: str, value, default: str = "") -> str:
    if value is None:
        return default
    if not isinstance(value, str):
        raise ValueError(f"{name} = {value!r}: expected a string")
    return value


def _table(name: str, value) -> dict:
    if not isinstance(value, Mapping):
        raise ValueError(f"{name} = {value!r}: expected a table")
    return dict(value)


def _identifier(name: str, value) -> str:
    text = _text(name, value)
    if not text or not all(ch.isalnum() or ch in "-_" for ch in text) or len(text) > 40:
        raise ValueError(f"{name} = {value!r}: expected 1-40 letters, digits, - or _")
    return text


def _condition(name: str, value, default_mode: str, strict: bool = True) -> Condition:
    values = _table(name, value)
    label = _identifier(f"{name}.name", values.pop("name", None))
    learner = values.pop("learner", None)
    if learner not in LEARNERS:
        raise ValueError(
            f"{name}.learner: unknown learner {learner!r} (known: {', '.join(LEARNERS)})"
        )
    mode = values.pop("mode", default_mode)
    if mode not in MODES:
        raise ValueError(f"{name}.mode = {mode!r}: expected one of {', '.join(MODES)}")
    sets = _table(f"{name}.set", values.pop("set", {}))
    instructions = _text(f"{name}.instructions", values.pop("instructions", None))
    found = _ROBOT_NUMBER.search(instructions)
    if found and strict and name != "practice":
        raise ValueError(
            f"{name}.instructions: names a robot by number ({found.group(0)!r}), but each "
            "participant meets the robots in their own order: write {robot} (their number) "
            "instead"
        )
    reject_unknown(values, name)
    return Condition(label, learner, mode, tuple(sorted(sets.items())), instructions)


def _question(name: str, value) -> Question:
    values = _table(name, value)
    kind = values.pop("kind", "likert")
    if kind not in QUESTION_KINDS:
        raise ValueError(f"{name}.kind = {kind!r}: expected one of {', '.join(QUESTION_KINDS)}")
    qid = _identifier(f"{name}.id", values.pop("id", "tlx" if kind == "tlx" else None))
    text = _text(f"{name}.text", values.pop("text", None))
    if kind != "tlx" and not text:
        raise ValueError(f"{name}.text: missing (what the participant is asked)")
    points = 7
    anchors = ("Strongly disagree", "Strongly agree")
    if kind == "likert":
        raw = values.pop("points", 7)
        if (
            isinstance(raw, bool)
            or not isinstance(raw, int)
            or not (LIKERT_POINTS[0] <= raw <= LIKERT_POINTS[1])
        ):
            raise ValueError(
                f"{name}.points = {raw!r}: a Likert scale has {LIKERT_POINTS[0]} to "
                f"{LIKERT_POINTS[1]} points"
            )
        points = raw
        raw = values.pop("anchors", list(anchors))
        if not (isinstance(raw, list) and len(raw) == 2 and all(isinstance(a, str) for a in raw)):
            raise ValueError(f"{name}.anchors = {raw!r}: expected [low label, high label]")
        anchors = (raw[0], raw[1])
    required = values.pop("required", kind != "text")
    if not isinstance(required, bool):
        raise ValueError(f"{name}.required = {required!r}: expected true or false")
    compare = values.pop("compare", False)
    if not isinstance(compare, bool):
        raise ValueError(f"{name}.compare = {compare!r}: expected true or false")
    if compare and kind != "likert":
        raise ValueError(f"{name}.compare: only a Likert item compares the robots")
    reject_unknown(values, name)
    return Question(qid, kind, text, points, anchors, required, compare)


def _questions(name: str, value) -> tuple[Question, ...]:
    if not isinstance(value, list):
        raise ValueError(f"{name}: expected a list of questions ([[{name}]] tables)")
    out = tuple(_question(f"{name}[{i}]", q) for i, q in enumerate(value))
    items = [item for q in out for item in q.items()]
    seen = {i for i in items if items.count(i) > 1}
    if seen:
        raise ValueError(f"{name}: question id {sorted(seen)[0]!r} is used twice")
    return out


def _response(name: str, value) -> Response:
    values = _table(name, value)
    measure = values.pop("measure", "regret")
    if measure not in RESPONSE_MEASURES:
        raise ValueError(
            f"{name}.measure = {measure!r}: expected one of {', '.join(RESPONSE_MEASURES)}"
        )
    out = Response(
        measure,
        number(f"{name}.intercept", values.pop("intercept", 4.0)),
        number(f"{name}.slope", values.pop("slope", -1.0)),
        number(f"{name}.noise", values.pop("noise", 1.0), low=0.0),
    )
    reject_unknown(values, name)
    return out


def _simulation(value, k: int | None) -> Simulation:
    values = _table("simulation", value)
    mean = vector("simulation.mean", values.pop("mean", None), k)
    sd = vector("simulation.sd", values.pop("sd", [0.0] * len(mean)), len(mean))
    if any(s < 0 for s in sd):
        raise ValueError(f"simulation.sd = {list(sd)}: expected numbers >= 0")
    user = values.pop("user", "noisy")
    if not isinstance(user, str | Mapping):
        raise ValueError(f"simulation.user = {user!r}: expected a user's name or table")
    physical = values.pop("physical_user", "physical")
    if not isinstance(physical, str | Mapping):
        raise ValueError(
            f"simulation.physical_user = {physical!r}: expected a user's name or table"
        )
    responses = _table("simulation.responses", values.pop("responses", {}))
    parsed = tuple(
        (qid, _response(f"simulation.responses.{qid}", r)) for qid, r in sorted(responses.items())
    )
    reject_unknown(values, "simulation")
    return Simulation(
        mean,
        sd,
        user if isinstance(user, str) else dict(user),
        parsed,
        physical if isinstance(physical, str) else dict(physical),
    )


def parse_protocol(
    values: Mapping[str, Any], *, k: int | None = None, strict: bool = True
) -> Protocol:
    """A checked protocol from a protocol file's values (``k``: the study's number of
    features, to check the simulated population's θ* against; ``strict``: False for a
    protocol read back from a study log, whose prose was checked by the rules of its day).

    Raises:
        ValueError: one line, starting with the key path of what is wrong.
    """
    source = json.loads(json.dumps(dict(values), default=str))
    values = dict(values)
    unknown = [key for key in values if key not in PROTOCOL_KEYS]
    if unknown:
        raise ValueError(f"{unknown[0]}: unknown key (a protocol takes {', '.join(PROTOCOL_KEYS)})")
    study = _text("study", values.get("study"), "fig4")
    seed = integer("seed", values.get("seed", 0), low=0, high=2**63 - 1)
    order = values.get("order", "williams")
    if order not in ORDERS:
        raise ValueError(f"order = {order!r}: expected one of {', '.join(ORDERS)}")
    corrections = integer("corrections", values.get("corrections", 5), low=1, high=1000)
    minimum = values.get("min_corrections")
    if minimum is not None:
        minimum = integer("min_corrections", minimum, low=1, high=corrections)
    trials = integer("trials", values.get("trials", 1), low=1, high=100)
    min_participants = integer(
        "min_participants", values.get("min_participants", 6), low=2, high=100000
    )
    primary = values.get("primary", "final_error")
    if primary not in OUTCOMES:
        raise ValueError(f"primary = {primary!r}: expected one of {', '.join(OUTCOMES)}")
    raw = values.get("conditions")
    if not isinstance(raw, list) or not raw:
        raise ValueError("conditions: expected at least one [[conditions]] table")
    conditions = tuple(_condition(f"conditions[{i}]", c, "drag", strict) for i, c in enumerate(raw))
    names = [c.name for c in conditions]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"conditions: the name {twice[0]!r} is used twice")
    if len(conditions) > 12:
        raise ValueError(f"conditions: {len(conditions)}, at most 12 (a square of 24 rows)")
    practice = None
    practice_corrections = 2
    if "practice" in values:
        table = _table("practice", values["practice"])
        practice_corrections = integer(
            "practice.corrections", table.pop("corrections", 2), low=1, high=1000
        )
        table.setdefault("name", "practice")
        practice = _condition("practice", table, "drag")
        if practice.name in names:
            raise ValueError(f"practice.name = {practice.name!r}: a condition's name")
    questionnaires = _table("questionnaires", values.get("questionnaires", {}))
    after = _questions("questionnaires.condition", questionnaires.pop("condition", []))
    at_end = _questions("questionnaires.end", questionnaires.pop("end", []))
    for i, q in enumerate(after):
        if q.compare:
            raise ValueError(
                f"questionnaires.condition[{i}].compare: an item after one condition cannot "
                "compare the robots (ask it in questionnaires.end)"
            )
    for i, q in enumerate(at_end):
        if q.compare and len(conditions) != 2:
            raise ValueError(
                f"questionnaires.end[{i}].compare: compares two robots, the protocol has "
                f"{len(conditions)} conditions"
            )
    reject_unknown(questionnaires, "questionnaires")
    simulation = None
    if "simulation" in values:
        simulation = _simulation(values["simulation"], k)
    return Protocol(
        conditions=conditions,
        study=study,
        seed=seed,
        order=order,
        corrections=corrections,
        min_corrections=minimum,
        trials=trials,
        primary=primary,
        min_participants=min_participants,
        description=_text("description", values.get("description")),
        welcome=_text("welcome", values.get("welcome")),
        end=_text("end", values.get("end")),
        practice=practice,
        practice_corrections=practice_corrections,
        after_condition=after,
        at_end=at_end,
        simulation=simulation,
        source=source,
    )


def load_protocol(path) -> Protocol:
    """A protocol from its TOML file (one-line errors name the file and the key)."""
    path = Path(path)
    try:
        values = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: no such protocol file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot read it ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not TOML ({exc})") from None
    try:
        return parse_protocol(values)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def balance(orders: list[tuple[str, ...]]) -> tuple[np.ndarray, np.ndarray]:
    """(position counts (condition × position), carry-over counts (before × after)) of a
    list of orders, over the conditions in the order of their first appearance."""
    names = sorted({n for order in orders for n in order})
    at = {n: i for i, n in enumerate(names)}
    n = len(names)
    positions = np.zeros((n, n), int)
    carry = np.zeros((n, n), int)
    for order in orders:
        for p, name in enumerate(order):
            positions[at[name], p] += 1
        for a, b in zip(order, order[1:], strict=False):
            carry[at[a], at[b]] += 1
    return positions, carry


def likert_value(response: Response, measure: float, points: int, rng) -> int:
    """A simulated Likert answer (see :class:`Response`), 1..points."""
    raw = response.intercept + response.slope * measure + response.noise * rng.standard_normal()
    return int(min(points, max(1, round(raw))))


def tlx_value(response: Response, measure: float, rng) -> int:
    """A simulated raw TLX subscale, 0..100 in steps of 5 (the response model in tens)."""
    raw = 10.0 * (response.intercept + response.slope * measure)
    raw += 10.0 * response.noise * rng.standard_normal()
    return int(min(100, max(0, 5 * round(raw / 5))))
