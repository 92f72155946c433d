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

Every write commits before it returns, so a confirmed correction survives the server being
killed at any moment after. Arrays are stored as JSON lists of floats (``repr`` round trip,
so replays see the very numbers the session used).
"""

from __future__ import annotations

import json
import re
import sqlite3
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

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

_ARRAYS = ("xi_robot", "xi_h", "phi_robot", "phi_h", "theta_before", "cov_before")
_ARRAYS += ("theta_after", "cov_after", "noise_after")


#: The kinds of correction a session may ask its person for, and the label each gets.
ASK_KINDS = {"toward": 1, "nudge": 0}


class LogError(ValueError):
    """A database that is not a study log of this version, or a session that is not in it."""


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

    def close(self) -> None:
        self._db.close()

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
            learner_params=json.loads(params),
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
