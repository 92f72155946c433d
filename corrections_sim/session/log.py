"""The log of a user study: one SQLite file (stdlib ``sqlite3``, WAL mode).

Tables (``SCHEMA_VERSION`` 1):

* ``meta`` — ``schema_version`` and the package version that made the file.
* ``sessions`` — one row per session: the participant's pseudonym (typed by the experimenter,
  never a name), start and end time (UTC, ISO 8601), the study's settings (JSON, the same
  dictionary a study's ``summary.json`` records), the learner and correction model with their
  parameters, the seed, who corrected (``"person"`` or a simulated user's table), the stated
  preference θ (JSON, or NULL), the package version and commit.
* ``corrections`` — one row per confirmed correction, in order: the environment (index and
  name), the draw that chose it, ξᵗ and ξ_h (every waypoint), Φ of both, θ̂ and P before and
  after (and N̂ after, for a learner that learns the noise), the drag as the page reported it,
  the seconds from showing the plan to submitting, and why an update was skipped, if it was.
* ``events`` — everything else a page reports: ``stated``, ``skip``, ``undo``, ``refused``
  (a drag the page refused, with the reason), ``done``.

A user study run from a protocol (:mod:`corrections_sim.userstudy.participant`) adds three
tables, created the first time a participant is enrolled (a log of single sessions keeps its
four, so older readers and committed logs are untouched), and the protocol in ``meta``:

* ``participants`` — one row per participant: the code (a pseudonym), the index that fixes
  their order of conditions, the SHA-256 of their link's secret (never the secret), when they
  were enrolled, what a simulated participant was drawn as (JSON; NULL for a person), and
  when they were withdrawn.
* ``steps`` — one row per step a participant has begun (by position in their protocol): its
  key, when it began and finished, the session of a trial, and the sessions of trials the
  experimenter aborted.
* ``answers`` — one row per answered item (participant, step, item), the value as JSON;
  written with the step's end in one transaction, so a questionnaire is all there or not.
  Only what the participant gave is an answer: an optional item left unanswered has no row.
* ``asked`` — beside each answer, what was asked (the item's text, anchors and scale, JSON),
  so an answer keeps its meaning if the protocol's wording is corrected later (logs made
  before this table have none: their protocol in ``meta`` says what was asked).
* ``participant_events`` — what happened to a participant outside a session: ``stopped``
  (they ended a trial early, with its step and corrections), ``withdrew`` (they left the
  study from their page, or the experimenter withdrew them: ``by``).

Every write commits before it returns, so a confirmed correction survives the server being
killed at any moment after. Arrays are stored as JSON lists of floats (``repr`` round trip,
so replays see the very numbers the session used).
"""

from __future__ import annotations

import contextlib
import json
import re
import sqlite3
import threading
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim.study import legacy

SCHEMA_VERSION = 1

#: A participant's pseudonym: letters, digits, ``-`` and ``_``, 1 to 40 of them.
PARTICIPANT = re.compile(r"[A-Za-z0-9_-]{1,40}")

_TABLES = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS sessions (
    id INTEGER PRIMARY KEY,
    participant TEXT NOT NULL,
    started TEXT NOT NULL,
    ended TEXT,
    settings TEXT NOT NULL,
    learner TEXT NOT NULL,
    learner_params TEXT NOT NULL,
    correction TEXT NOT NULL,
    seed INTEGER NOT NULL,
    corrector TEXT NOT NULL,
    stated_theta TEXT,
    version TEXT NOT NULL,
    git_commit TEXT
);
CREATE TABLE IF NOT EXISTS corrections (
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    iteration INTEGER NOT NULL,
    draw INTEGER NOT NULL,
    env_index INTEGER NOT NULL,
    env_name TEXT NOT NULL,
    xi_robot TEXT NOT NULL,
    xi_h TEXT NOT NULL,
    phi_robot TEXT NOT NULL,
    phi_h TEXT NOT NULL,
    theta_before TEXT NOT NULL,
    cov_before TEXT NOT NULL,
    theta_after TEXT NOT NULL,
    cov_after TEXT NOT NULL,
    noise_after TEXT,
    nis REAL,
    drag TEXT NOT NULL,
    shown_at TEXT NOT NULL,
    submitted_at TEXT NOT NULL,
    seconds REAL NOT NULL,
    update_skipped TEXT NOT NULL,
    PRIMARY KEY (session_id, iteration)
);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY,
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    iteration INTEGER NOT NULL,
    kind TEXT NOT NULL,
    at TEXT NOT NULL,
    detail TEXT NOT NULL
);
"""

_STUDY_TABLES = """
CREATE TABLE IF NOT EXISTS participants (
    code TEXT PRIMARY KEY,
    idx INTEGER NOT NULL UNIQUE,
    token_hash TEXT NOT NULL UNIQUE,
    enrolled TEXT NOT NULL,
    simulated TEXT,
    withdrawn TEXT
);
CREATE TABLE IF NOT EXISTS steps (
    code TEXT NOT NULL REFERENCES participants(code),
    position INTEGER NOT NULL,
    key TEXT NOT NULL,
    started TEXT NOT NULL,
    finished TEXT,
    session_id INTEGER,
    aborted TEXT NOT NULL DEFAULT '[]',
    PRIMARY KEY (code, position)
);
CREATE TABLE IF NOT EXISTS answers (
    code TEXT NOT NULL REFERENCES participants(code),
    step TEXT NOT NULL,
    item TEXT NOT NULL,
    value TEXT NOT NULL,
    at TEXT NOT NULL,
    PRIMARY KEY (code, step, item)
);
CREATE TABLE IF NOT EXISTS asked (
    code TEXT NOT NULL REFERENCES participants(code),
    step TEXT NOT NULL,
    item TEXT NOT NULL,
    question TEXT NOT NULL,
    PRIMARY KEY (code, step, item)
);
CREATE TABLE IF NOT EXISTS participant_events (
    id INTEGER PRIMARY KEY,
    code TEXT NOT NULL REFERENCES participants(code),
    kind TEXT NOT NULL,
    at TEXT NOT NULL,
    detail TEXT NOT NULL
);
"""

_ARRAYS = ("xi_robot", "xi_h", "phi_robot", "phi_h", "theta_before", "cov_before")
_ARRAYS += ("theta_after", "cov_after", "noise_after")


#: The kinds of correction a session may ask its person for, and the label each gets.
ASK_KINDS = {"toward": 1, "nudge": 0}


class LogError(ValueError):
    """A database that is not a study log of this version, or a session that is not in it."""


class StudyError(ValueError):
    """A participant or an answer the study log refuses (a used code, an answer posted twice,
    a step out of turn); the message is one line."""


def now() -> str:
    """The time now, UTC, ISO 8601 with microseconds."""
    return datetime.now(UTC).isoformat(timespec="microseconds")


def _dump(value) -> str:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    return json.dumps(value, allow_nan=True)


def _array(text: str | None) -> np.ndarray | None:
    return None if text is None else np.array(json.loads(text), dtype=float)


@dataclass(frozen=True)
class SessionRow:
    """A session as logged (see the module's ``sessions`` table)."""

    id: int
    participant: str
    started: str
    ended: str | None
    settings: dict
    learner: str
    learner_params: dict
    correction: dict
    seed: int
    corrector: Any
    stated_theta: np.ndarray | None
    version: str
    git_commit: str | None


def check_participant(participant: str) -> str:
    """Refuse a pseudonym with anything but letters, digits, ``-`` and ``_`` (1-40)."""
    if not isinstance(participant, str) or not PARTICIPANT.fullmatch(participant):
        raise ValueError(
            f"participant {participant!r}: use a pseudonym of 1-40 letters, digits, - or _ "
            "(never a person's name)"
        )
    return participant


class StudyLog:
    """One study log file; safe to share between threads (one connection, one lock)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if self.path.exists() and self.path.is_dir():
            raise LogError(f"{self.path}: is a folder, not a database file")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._check_or_create()
        except sqlite3.DatabaseError as exc:
            raise LogError(f"{self.path}: not a study log ({exc})") from None
        self._lock = threading.Lock()
        self._closed = False

    def close(self) -> None:
        """Close the file once no other thread is inside a query (a page's callback thread may
        still be answering a click when its server stops); a query after this raises
        sqlite3.ProgrammingError, never touches a closed handle mid-statement."""
        with self._lock:
            self._db.close()
            self._closed = True

    @property
    def closed(self) -> bool:
        return self._closed

    @contextlib.contextmanager
    def unless_closed(self) -> Iterator[None]:
        """A block that may run on while the log is closed under it (a page's callback still
        answering a click, or a tab connecting, as its server stops): a query there ends the
        block quietly, for nothing it did could be kept. Any other error, or one while the log
        is open, is raised."""
        try:
            yield
        except sqlite3.ProgrammingError:
            if not self._closed:
                raise

    def __enter__(self) -> StudyLog:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _check_or_create(self) -> None:
        tables = {r[0] for r in self._db.execute("SELECT name FROM sqlite_master")}
        if not tables:
            from corrections_sim.provenance import versions

            self._db.executescript("BEGIN;" + _TABLES + "COMMIT;")
            self._db.execute(
                "INSERT INTO meta VALUES ('schema_version', ?), ('created_by', ?)",
                (str(SCHEMA_VERSION), versions().get("corrections_sim", "")),
            )
            return
        if "meta" not in tables:
            raise LogError(f"{self.path}: a SQLite file, but not a study log (no meta table)")
        row = self._db.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
        found = int(row[0]) if row else 0
        if found > SCHEMA_VERSION:
            raise LogError(
                f"{self.path}: schema version {found} is newer than this package's "
                f"{SCHEMA_VERSION}; update corrections_sim to read it"
            )
        if found < SCHEMA_VERSION:  # no older version exists yet: nothing to migrate from
            raise LogError(f"{self.path}: schema version {found}, no migration to {SCHEMA_VERSION}")

    def _write(self, sql: str, values: Sequence) -> int:
        with self._lock:
            cursor = self._db.execute(sql, tuple(values))  # autocommit: durable on return
            return int(cursor.lastrowid or 0)

    # --- sessions --------------------------------------------------------------------------

    def new_session(
        self,
        *,
        participant: str,
        settings: Mapping,
        learner: str,
        learner_params: Mapping,
        correction: Mapping,
        seed: int,
        corrector: Any,
    ) -> int:
        """A new session's id."""
        from corrections_sim import provenance

        check_participant(participant)
        git = provenance.git_commit()
        commit = None if git is None else _dump(git)
        return self._write(
            "INSERT INTO sessions (participant, started, settings, learner, learner_params, "
            "correction, seed, corrector, version, git_commit) VALUES (?,?,?,?,?,?,?,?,?,?)",
            (
                participant,
                now(),
                _dump(dict(settings)),
                learner,
                _dump(dict(learner_params)),
                _dump(dict(correction)),
                int(seed),
                _dump(corrector),
                provenance.versions().get("corrections_sim", ""),
                commit,
            ),
        )

    def session(self, session_id: int) -> SessionRow:
        with self._lock:
            row = self._db.execute("SELECT * FROM sessions WHERE id = ?", (session_id,)).fetchone()
        if row is None:
            known = ", ".join(str(s) for s in self.session_ids()) or "none"
            raise LogError(f"session {session_id}: not in {self.path} (sessions: {known})")
        (sid, participant, started, ended, settings, learner, params, correction, seed) = row[:9]
        corrector, stated, version, commit = row[9:]
        return SessionRow(
            id=sid,
            participant=participant,
            started=started,
            ended=ended,
            settings=json.loads(settings),
            learner=learner,
            # In today's form: a log made before a parameter was renamed still resumes and
            # replays (KF-CRX's expand_variance, issue 69).
            learner_params=legacy.current_learner_params(learner, json.loads(params)),
            correction=json.loads(correction),
            seed=seed,
            corrector=json.loads(corrector),
            stated_theta=_array(stated),
            version=version,
            git_commit=commit,
        )

    def session_ids(self) -> list[int]:
        with self._lock:
            return [r[0] for r in self._db.execute("SELECT id FROM sessions ORDER BY id")]

    def state_theta(self, session_id: int, theta) -> None:
        """Log the person's stated preference θ (the session's reference for error and NEES)."""
        theta = np.asarray(theta, dtype=float)
        self._write("UPDATE sessions SET stated_theta = ? WHERE id = ?", (_dump(theta), session_id))
        self.add_event(session_id, -1, "stated", {"theta": theta.tolist()})

    def end_session(self, session_id: int) -> None:
        self._write("UPDATE sessions SET ended = ? WHERE id = ?", (now(), session_id))

    # --- corrections and events ------------------------------------------------------------

    def add_correction(self, session_id: int, row: Mapping[str, Any]) -> None:
        """Log one confirmed correction (keys: the ``corrections`` table's columns but
        ``session_id``); committed when this returns."""
        columns = [
            "iteration",
            "draw",
            "env_index",
            "env_name",
            *_ARRAYS,
            "nis",
            "drag",
            "shown_at",
            "submitted_at",
            "seconds",
            "update_skipped",
        ]
        values = [session_id]
        for c in columns:
            value = row.get(c)
            if c in _ARRAYS or c == "drag":
                value = None if value is None else _dump(value)
            values.append(value)
        marks = ",".join("?" * len(values))
        self._write(
            f"INSERT INTO corrections (session_id, {', '.join(columns)}) VALUES ({marks})", values
        )

    def corrections(self, session_id: int) -> list[dict]:
        """Every logged correction of the session, in order, arrays as numpy arrays."""
        with self._lock:
            cursor = self._db.execute(
                "SELECT * FROM corrections WHERE session_id = ? ORDER BY iteration",
                (session_id,),
            )
            names = [d[0] for d in cursor.description]
            rows = cursor.fetchall()
        out = []
        for row in rows:
            rec = dict(zip(names, row, strict=True))
            for c in _ARRAYS:
                rec[c] = _array(rec[c])
            rec["drag"] = json.loads(rec["drag"])
            out.append(rec)
        return out

    def add_event(self, session_id: int, iteration: int, kind: str, detail: Mapping) -> None:
        self._write(
            "INSERT INTO events (session_id, iteration, kind, at, detail) VALUES (?,?,?,?,?)",
            (session_id, iteration, kind, now(), _dump(dict(detail))),
        )

    # --- a study's participants, steps and answers ----------------------------------------------

    def prepare_study(self) -> None:
        """Create the study tables this log lacks (a study run opens a log with it)."""
        self._study()

    def _study(self) -> None:
        """Create the study tables if this log has none yet (see the module)."""
        with self._lock:
            self._db.executescript("BEGIN;" + _STUDY_TABLES + "COMMIT;")

    def has_study(self) -> bool:
        with self._lock:
            row = self._db.execute(
                "SELECT 1 FROM sqlite_master WHERE name = 'participants'"
            ).fetchone()
        return row is not None

    def meta(self, key: str) -> str | None:
        with self._lock:
            row = self._db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return None if row is None else row[0]

    def set_meta(self, key: str, value: str) -> None:
        self._write("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, value))

    def enroll(
        self, code: str, index: int, token_hash: str, simulated: Mapping | None = None
    ) -> None:
        """A new participant; refused (one line) if the code or the index is taken."""
        check_participant(code)
        self._study()
        for row in self.participants():
            if row["code"].casefold() == code.casefold() and row["code"] != code:
                raise StudyError(
                    f"participant {code}: {row['code']} is enrolled already (codes are read "
                    "without regard to case)"
                )
        try:
            self._write(
                "INSERT INTO participants (code, idx, token_hash, enrolled, simulated) "
                "VALUES (?,?,?,?,?)",
                (
                    code,
                    int(index),
                    token_hash,
                    now(),
                    None if simulated is None else _dump(dict(simulated)),
                ),
            )
        except sqlite3.IntegrityError:
            if self.participant(code) is not None:
                raise StudyError(
                    f"participant {code}: the code is already used in {self.path.name} (a "
                    "returning participant resumes through their link; a new one needs a "
                    "new code)"
                ) from None
            raise StudyError(f"participant index {index}: already taken") from None

    def participant(self, code: str) -> dict | None:
        """A participant's row ({code, index, token_hash, enrolled, simulated, withdrawn})."""
        if not self.has_study():
            return None
        with self._lock:
            row = self._db.execute(
                "SELECT code, idx, token_hash, enrolled, simulated, withdrawn FROM "
                "participants WHERE code = ?",
                (code,),
            ).fetchone()
        return None if row is None else _participant(row)

    def participants(self) -> list[dict]:
        """Every participant, by index."""
        if not self.has_study():
            return []
        with self._lock:
            rows = self._db.execute(
                "SELECT code, idx, token_hash, enrolled, simulated, withdrawn FROM "
                "participants ORDER BY idx"
            ).fetchall()
        return [_participant(r) for r in rows]

    def set_token(self, code: str, token_hash: str) -> None:
        """A new link secret for ``code`` (the old link stops working)."""
        self._write("UPDATE participants SET token_hash = ? WHERE code = ?", (token_hash, code))

    def withdraw(self, code: str, *, delete: bool = False) -> None:
        """Withdraw a participant: their rows stay, marked, and leave every analysis; with
        ``delete`` every row of theirs (sessions, corrections, events, steps, answers) is
        deleted in one transaction."""
        if self.participant(code) is None:
            raise StudyError(f"participant {code}: not in {self.path.name}")
        if not delete:
            self._write("UPDATE participants SET withdrawn = ? WHERE code = ?", (now(), code))
            return
        self._study()  # an older log may lack a table the deletion empties
        with self._lock:
            db = self._db
            db.execute("BEGIN IMMEDIATE")
            try:
                ids = [
                    r[0]
                    for r in db.execute("SELECT id FROM sessions WHERE participant = ?", (code,))
                ]
                for sid in ids:
                    db.execute("DELETE FROM corrections WHERE session_id = ?", (sid,))
                    db.execute("DELETE FROM events WHERE session_id = ?", (sid,))
                db.execute("DELETE FROM sessions WHERE participant = ?", (code,))
                for table in ("answers", "asked", "participant_events", "steps"):
                    db.execute(f"DELETE FROM {table} WHERE code = ?", (code,))
                # The row stays, emptied, so the code and the index are not given again.
                db.execute(
                    "UPDATE participants SET simulated = NULL, withdrawn = ?, token_hash = ? "
                    "WHERE code = ?",
                    (now(), f"deleted:{code}", code),
                )
                db.execute("COMMIT")
            except BaseException:
                db.execute("ROLLBACK")
                raise

    def steps(self, code: str) -> list[dict]:
        """The steps ``code`` has begun, by position."""
        if not self.has_study():
            return []
        with self._lock:
            rows = self._db.execute(
                "SELECT position, key, started, finished, session_id, aborted FROM steps "
                "WHERE code = ? ORDER BY position",
                (code,),
            ).fetchall()
        return [
            {
                "position": p,
                "key": k,
                "started": s,
                "finished": f,
                "session_id": sid,
                "aborted": json.loads(a),
            }
            for p, k, s, f, sid, a in rows
        ]

    def begin_step(self, code: str, position: int, key: str) -> None:
        """Mark step ``position`` begun (nothing if it is)."""
        self._write(
            "INSERT OR IGNORE INTO steps (code, position, key, started) VALUES (?,?,?,?)",
            (code, position, key, now()),
        )

    def set_step_session(self, code: str, position: int, session_id: int | None) -> None:
        self._write(
            "UPDATE steps SET session_id = ? WHERE code = ? AND position = ?",
            (session_id, code, position),
        )

    def abort_step(self, code: str, position: int) -> int | None:
        """The trial at ``position`` starts over: its session joins the aborted ones."""
        with self._lock:
            row = self._db.execute(
                "SELECT session_id, aborted FROM steps WHERE code = ? AND position = ?",
                (code, position),
            ).fetchone()
        if row is None or row[0] is None:
            return None
        aborted = [*json.loads(row[1]), row[0]]
        self._write(
            "UPDATE steps SET session_id = NULL, aborted = ? WHERE code = ? AND position = ?",
            (_dump(aborted), code, position),
        )
        return int(row[0])

    def finish_step(
        self,
        code: str,
        position: int,
        key: str,
        answers: Mapping[str, Any] | None = None,
        asked: Mapping[str, Mapping] | None = None,
    ) -> None:
        """End step ``position``, with its answers and what each item asked (``asked``:
        item -> the question as shown), in one transaction.

        Raises:
            StudyError: the step has ended already (an answer posted twice), or it was never
                begun.
        """
        with self._lock:
            db = self._db
            db.execute("BEGIN IMMEDIATE")
            try:
                row = db.execute(
                    "SELECT finished FROM steps WHERE code = ? AND position = ?", (code, position)
                ).fetchone()
                if row is None:
                    raise StudyError(f"participant {code}: step {key} was never begun")
                if row[0] is not None:
                    raise StudyError(
                        f"participant {code}: step {key} ended at {row[0]}; its answers are "
                        "kept as first given (posted twice?)"
                    )
                at = now()
                for item, value in (answers or {}).items():
                    db.execute(
                        "INSERT INTO answers (code, step, item, value, at) VALUES (?,?,?,?,?)",
                        (code, key, item, _dump(value), at),
                    )
                for item, question in (asked or {}).items():
                    db.execute(
                        "INSERT INTO asked (code, step, item, question) VALUES (?,?,?,?)",
                        (code, key, item, _dump(dict(question))),
                    )
                db.execute(
                    "UPDATE steps SET finished = ? WHERE code = ? AND position = ?",
                    (at, code, position),
                )
                db.execute("COMMIT")
            except BaseException:
                db.execute("ROLLBACK")
                raise

    def answers(self, code: str | None = None) -> list[dict]:
        """Every answer (of ``code``, or of everyone), in the order given."""
        if not self.has_study():
            return []
        sql = "SELECT code, step, item, value, at FROM answers"
        args: tuple = ()
        if code is not None:
            sql += " WHERE code = ?"
            args = (code,)
        with self._lock:
            rows = self._db.execute(sql + " ORDER BY at, rowid", args).fetchall()
        return [
            {"code": c, "step": s, "item": i, "value": json.loads(v), "at": at}
            for c, s, i, v, at in rows
        ]

    def _has(self, table: str) -> bool:
        with self._lock:
            row = self._db.execute(
                "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?", (table,)
            ).fetchone()
        return row is not None

    def asked(self, code: str | None = None) -> dict[tuple[str, str, str], dict]:
        """What was asked beside each answer: (code, step, item) -> the question as shown
        (empty for a log made before answers kept it)."""
        if not self._has("asked"):
            return {}
        sql, args = "SELECT code, step, item, question FROM asked", ()
        if code is not None:
            sql, args = sql + " WHERE code = ?", (code,)
        with self._lock:
            rows = self._db.execute(sql, args).fetchall()
        return {(c, s, i): json.loads(q) for c, s, i, q in rows}

    def add_participant_event(self, code: str, kind: str, detail: Mapping) -> None:
        """Something that happened to ``code`` outside a session (see the module)."""
        self._study()
        self._write(
            "INSERT INTO participant_events (code, kind, at, detail) VALUES (?,?,?,?)",
            (code, kind, now(), _dump(dict(detail))),
        )

    def participant_events(self, code: str | None = None, kind: str | None = None) -> list[dict]:
        """The events of ``code`` (or everyone's), of ``kind`` (or every kind), in order."""
        if not self._has("participant_events"):
            return []
        sql, args = "SELECT code, kind, at, detail FROM participant_events WHERE 1", ()
        if code is not None:
            sql, args = sql + " AND code = ?", (*args, code)
        if kind is not None:
            sql, args = sql + " AND kind = ?", (*args, kind)
        with self._lock:
            rows = self._db.execute(sql + " ORDER BY id", args).fetchall()
        return [{"code": c, "kind": k, "at": at, "detail": json.loads(d)} for c, k, at, d in rows]

    def labels(self, session_id: int) -> dict[int, dict]:
        """The label of each labelled correction by iteration (the last ``label`` event of
        each iteration: {kind, label, preference}).

        Raises:
            LogError: a label event the log's readers do not know (a kind other than
                "toward" or "nudge", or a label that does not match its kind).
        """
        out = {}
        for event in self.events(session_id, "label"):
            detail = event["detail"]
            kind = detail.get("kind") if isinstance(detail, dict) else None
            if kind not in ASK_KINDS or detail.get("label") != ASK_KINDS[kind]:
                raise LogError(
                    f"session {session_id}: correction {event['iteration']} has label "
                    f"{json.dumps(detail)}, not one this log knows (toward: 1, nudge: 0)"
                )
            out[int(event["iteration"])] = detail
        return out

    def events(self, session_id: int, kind: str | None = None) -> list[dict]:
        sql = "SELECT iteration, kind, at, detail FROM events WHERE session_id = ?"
        args: tuple = (session_id,)
        if kind is not None:
            sql += " AND kind = ?"
            args += (kind,)
        with self._lock:
            rows = self._db.execute(sql + " ORDER BY id", args).fetchall()
        return [
            {"iteration": i, "kind": k, "at": at, "detail": json.loads(d)} for i, k, at, d in rows
        ]


def _participant(row) -> dict:
    code, index, token_hash, enrolled, simulated, withdrawn = row
    return {
        "code": code,
        "index": index,
        "token_hash": token_hash,
        "enrolled": enrolled,
        "simulated": None if simulated is None else json.loads(simulated),
        "withdrawn": withdrawn,
    }
