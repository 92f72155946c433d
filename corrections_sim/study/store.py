"""Finished runs on disk, so that a killed batch command resumes where it stopped.

Layout under a ``root`` such as ``results/.runs/fig4``::

    root/.lock                  flock'ed by the one command writing under root
    root/<key>/settings.json    the resolved settings that <key> hashes (for humans)
    root/<key>/PP-0.json        one finished run: learner "PP", run 0
    root/<key>/.PP-1.json.*.tmp a run being written (or left by a killed writer)

``key = settings_key(settings)``, so runs made under different settings never mix: a change
of any setting, down to the last bit of a float, gives a new folder. Whatever else changes
the results (a code version, say) must be in ``settings`` too: the key is all that separates.

A run file appears under its final name only through ``os.replace`` of a complete, fsync'ed
temporary file in the same folder, so a SIGKILL at any instant leaves either the finished
file or no file (plus, perhaps, a stray ``.tmp`` that is never read and is removed by the
next :meth:`RunStore.lock`). A final file that does not parse (a disk fault, an edit) is
not silently redone: :meth:`RunStore.load` raises :class:`CorruptRun` naming the file.

Format: one JSON document per run. Python's ``json`` writes a float as its shortest
round-trip ``repr`` and reads it back bit for bit (also ``-0.0``; NaN and ±inf as the
tokens ``NaN``/``Infinity``, which Python reads back), keeps ``1`` (int), ``1.0`` (float)
and ``true`` (bool) apart and preserves the order of a record's keys, which becomes the
order of the CSV columns. The gains array is stored as base64 of its raw bytes with dtype
and shape, so every bit (NaN payloads included) survives. JSON over ``npz``: one file per
run is one atomic replace, and the records stay readable with a text editor.
"""

from __future__ import annotations

import base64
import contextlib
import fcntl
import hashlib
import json
import os
import re
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim.study.loop import RunResult

FORMAT = 1
_LEARNER = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]*")
_RUN_FILE = re.compile(r"(?P<learner>[A-Za-z0-9_][A-Za-z0-9_-]*)-(?P<run>0|[1-9][0-9]*)\.json")
_RUN_TEMP = re.compile(r"\.[A-Za-z0-9_][A-Za-z0-9_-]*-(0|[1-9][0-9]*)\.json\..*\.tmp")
_RECORD_TYPES = (str, int, float, bool, type(None))

# Lock descriptors this process holds. A forked child (a process-pool worker) inherits them,
# and flock is only released when every copy is closed: a worker outliving a SIGKILLed parent
# would keep the folder locked. So each child closes its copies at once (the parent keeps
# the lock).
_HELD_LOCK_FDS: set[int] = set()


def _close_inherited_locks() -> None:
    for fd in _HELD_LOCK_FDS:
        with contextlib.suppress(OSError):
            os.close(fd)
    _HELD_LOCK_FDS.clear()


os.register_at_fork(after_in_child=_close_inherited_locks)


class StoreLocked(RuntimeError):
    """Another process is writing runs under the same folder."""


class CorruptRun(ValueError):
    """A file under a finished run's name that is not a readable run."""


def _plain(value: Any, where: str) -> Any:
    """``value`` as JSON data: mappings with str keys, lists, str, int, float, bool, None."""
    if isinstance(value, Mapping):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise TypeError(f"settings{where}: key {k!r} must be a str")
            out[k] = _plain(v, f"{where}[{k!r}]")
        return out
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, list | tuple):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, np.generic) and value.dtype.kind in "biuf":
        return value.item()
    if isinstance(value, _RECORD_TYPES):
        return value
    raise TypeError(
        f"settings{where}: {type(value).__name__} is not plain data "
        "(mapping, list, tuple, str, int, float, bool or None)"
    )


def _canonical(settings: Mapping[str, Any]) -> str:
    return json.dumps(_plain(settings, ""), sort_keys=True, separators=(",", ":"))


def settings_key(settings: Mapping[str, Any]) -> str:
    """The first 16 hex digits of the SHA-256 of ``settings`` as canonical JSON.

    Canonical: keys sorted, no whitespace, floats as their exact shortest ``repr``, tuples
    and lists alike (both are JSON arrays), numpy scalars and arrays as Python values. The
    key is the same in every process and Python session, and changes with any value.

    Raises:
        TypeError: a value is not plain data; the message names its place in ``settings``.
    """
    return hashlib.sha256(_canonical(settings).encode()).hexdigest()[:16]


def _write_atomically(path: Path, data: bytes) -> None:
    """Replace ``path`` by ``data`` so that a reader sees the old file or the whole new one."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    # The rename itself must reach the disk for the run to survive a power cut.
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def _check_record(where: str, record: Any) -> None:
    if not isinstance(record, dict):
        raise TypeError(f"{where}: must be a dict, got {type(record).__name__}")
    for name, value in record.items():
        if not isinstance(name, str):
            raise TypeError(f"{where}: key {name!r} must be a str")
        # Exact types: an np.float64 would come back as float, whose repr (in the CSV) differs.
        if type(value) not in _RECORD_TYPES:
            raise TypeError(
                f"{where}[{name!r}]: {type(value).__name__} is not stored exactly; "
                "use str, int, float, bool or None (convert numpy scalars with float() or int())"
            )


class RunStore:
    """The finished runs, keyed by (learner, run), of one set of settings under ``root``.

    Reading needs nothing; writing needs :meth:`lock`, which one process at a time holds
    for the whole of ``root`` (every settings key under it), because commands writing
    under the same root share one output folder.

    Attributes:
        root: the folder of all settings keys, e.g. ``results/.runs/fig4``.
        key: ``settings_key(settings)``.
        folder: ``root / key``, where the runs are.
    """

    def __init__(self, root: Path | str, settings: Mapping[str, Any]):
        """Open (creating if needed) the folder of ``settings`` under ``root``.

        Raises:
            TypeError: ``settings`` is not plain data.
            ValueError: ``folder/settings.json`` holds other settings (edited by hand, or a
                hash collision); the message names the file.
        """
        self.root = Path(root)
        self.key = settings_key(settings)
        self.folder = self.root / self.key
        self._lock_owner: int | None = None
        self.folder.mkdir(parents=True, exist_ok=True)
        canonical = _canonical(settings)
        path = self.folder / "settings.json"
        if path.exists():
            try:
                stored = _canonical(json.loads(path.read_text()))
            except (ValueError, TypeError) as exc:
                raise ValueError(f"{path}: unreadable settings ({exc})") from None
            if stored != canonical:
                raise ValueError(
                    f"{path}: holds other settings than those hashing to {self.key}; "
                    "move the folder away to rerun"
                )
        else:
            text = json.dumps(json.loads(canonical), indent=2, sort_keys=True) + "\n"
            _write_atomically(path, text.encode())

    @property
    def lock_path(self) -> Path:
        """The file whose flock guards every settings key under :attr:`root`."""
        return self.root / ".lock"

    @contextlib.contextmanager
    def lock(self) -> Iterator[None]:
        """Hold the exclusive write lock of :attr:`root`; refuse at once if it is taken.

        ``fcntl.flock``, so the kernel releases it when the holder exits or is killed, and
        a forked child does not keep it (see ``_close_inherited_locks``). On entry, the
        temporary files of writers that died are removed. The lock file itself stays: deleting
        it while another process waits on it would let two processes hold "the" lock.

        Raises:
            StoreLocked: another process holds it (or this process, through another store).
        """
        if self._lock_owner == os.getpid():
            raise RuntimeError(f"{self.root}: this store already holds the lock")
        fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip()
            os.close(fd)
            who = f"another run (pid {holder})" if holder.isdigit() else "another run"
            raise StoreLocked(
                f"{self.root}: {who} is writing there; wait for it to finish "
                "or choose another output folder"
            ) from None
        except BaseException:
            os.close(fd)
            raise
        _HELD_LOCK_FDS.add(fd)
        owner = os.getpid()
        self._lock_owner = owner
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{owner}\n".encode(), 0)
            for entry in os.scandir(self.folder):
                if _RUN_TEMP.fullmatch(entry.name):
                    os.unlink(entry.path)
            yield
        finally:
            # A forked child leaving this block must not close a descriptor it no longer has.
            if os.getpid() == owner:
                self._lock_owner = None
                _HELD_LOCK_FDS.discard(fd)
                os.close(fd)

    def path(self, learner: str, run: int) -> Path:
        """The file of a finished run.

        Raises:
            ValueError: ``learner`` is not letters, digits, underscores and hyphens (not
                first), or ``run`` is not a non-negative int.
        """
        if not isinstance(learner, str) or not _LEARNER.fullmatch(learner):
            raise ValueError(
                f"learner {learner!r}: must be letters, digits, underscores and hyphens"
            )
        if type(run) is not int or run < 0:
            raise ValueError(f"run {run!r}: must be a non-negative int")
        return self.folder / f"{learner}-{run}.json"

    def done(self) -> set[tuple[str, int]]:
        """(learner, run) of every finished run on disk.

        Only names are read; temporary and unrelated files are ignored. :meth:`load_all`
        also checks that each file is readable.
        """
        found = set()
        for entry in os.scandir(self.folder):
            match = _RUN_FILE.fullmatch(entry.name)
            if match and entry.is_file():
                found.add((match["learner"], int(match["run"])))
        return found

    def save(self, learner: str, run: int, result: RunResult) -> Path:
        """Write one finished run atomically; returns its file.

        Raises:
            RuntimeError: this process does not hold :meth:`lock`.
            TypeError: a record is not a dict of str to str, int, float, bool or None, or
                ``gains`` is not a numeric array; the message names the field.
        """
        path = self.path(learner, run)
        if self._lock_owner != os.getpid():
            raise RuntimeError(f"{self.folder}: save() needs the lock (`with store.lock():`)")
        for i, record in enumerate(result.records):
            _check_record(f"{learner} run {run}: records[{i}]", record)
        gains = result.gains
        if not isinstance(gains, np.ndarray) or gains.dtype.kind not in "biufc":
            raise TypeError(f"{learner} run {run}: gains must be a numeric numpy array")
        if type(result.solves) is not int:
            raise TypeError(f"{learner} run {run}: solves must be an int")
        doc = {
            "format": FORMAT,
            "learner": learner,
            "run": run,
            "solves": result.solves,
            "records": list(result.records),
            "gains": {
                "dtype": gains.dtype.str,
                "shape": list(gains.shape),
                "data": base64.b64encode(np.ascontiguousarray(gains).tobytes()).decode(),
            },
        }
        _write_atomically(path, json.dumps(doc).encode())
        return path

    def load(self, learner: str, run: int) -> RunResult:
        """One finished run, exactly as it was saved.

        Raises:
            FileNotFoundError: the run is not done.
            CorruptRun: the file is not a complete run; the message names it.
        """
        path = self.path(learner, run)
        data = path.read_bytes()
        try:
            doc = json.loads(data)
            if doc["format"] != FORMAT:
                raise ValueError(f"format {doc['format']!r}, expected {FORMAT}")
            if (doc["learner"], doc["run"]) != (learner, run):
                raise ValueError(f"holds {doc['learner']} run {doc['run']}")
            records = doc["records"]
            if not isinstance(records, list) or not all(isinstance(r, dict) for r in records):
                raise ValueError("records must be a list of objects")
            if type(doc["solves"]) is not int:
                raise ValueError("solves must be an int")
            blob = doc["gains"]
            dtype, shape = np.dtype(blob["dtype"]), tuple(blob["shape"])
            raw = base64.b64decode(blob["data"], validate=True)
            if len(raw) != dtype.itemsize * int(np.prod(shape, dtype=np.int64)):
                raise ValueError(f"gains: {len(raw)} bytes do not make {blob['dtype']} {shape}")
            gains = np.frombuffer(raw, dtype=dtype).reshape(shape).copy()
        except (ValueError, TypeError, KeyError) as exc:
            raise CorruptRun(
                f"{path}: not a complete run ({exc}); delete it to redo the run"
            ) from None
        return RunResult(records=tuple(records), gains=gains, solves=doc["solves"])

    def load_all(self) -> dict[tuple[str, int], RunResult]:
        """Every finished run, sorted by (learner, run).

        Raises:
            CorruptRun: a file is not a complete run; the message names it.
        """
        return {key: self.load(*key) for key in sorted(self.done())}
