"""The run store: exact round trips, settings keys, the write lock and SIGKILL at any time."""

from __future__ import annotations

import contextlib
import json
import math
import os
import pickle
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator

import numpy as np
import pytest

from corrections_sim.study.loop import RunResult
from corrections_sim.study.store import CorruptRun, RunStore, StoreLocked, settings_key

SETTINGS = {
    "figure": "fig4",
    "theta_star": (0.5, 1.0),
    "cov0": ((1.0, 0.0), (0.0, 1.0)),
    "iterations": 2,
    "runs": 3,
    "seed": 0,
    "fixed_alpha": None,
}

# Every child script starts by opening the store given on its command line.
PRELUDE = """
import json, os, pickle, signal, sys
from pathlib import Path
from corrections_sim.study.store import RunStore
store = RunStore(Path(sys.argv[1]), json.loads(sys.argv[2]))
"""

HOLD_LOCK = """
with store.lock():
    print("locked", flush=True)
    sys.stdin.read()
print("released", flush=True)
"""

# The lock holder forks a child (as a process pool does) that outlives it.
# The forked child says its pid once it runs: by then the at-fork hook has closed the
# descriptors it inherited (the hook runs before fork() returns in the child). Waiting for the
# parent's word instead raced the hook on a loaded machine (a CI run failed so).
HOLD_LOCK_AND_FORK = """
with store.lock():
    if os.fork() == 0:
        print(os.getpid(), flush=True)
        signal.pause()
        os._exit(0)
    sys.stdin.read()
"""

# Saves every result of the pickle as runs 0, 1, ..., then blocks inside the next save, after
# its temporary file is written and before it is renamed.
SAVE_THEN_BLOCK = """
results = pickle.loads(Path(sys.argv[3]).read_bytes())
with store.lock():
    for run, result in enumerate(results[:-1]):
        store.save("KF", run, result)
        print("saved", run, flush=True)
    def blocked_fsync(fd):
        print("writing", flush=True)
        signal.pause()
    os.fsync = blocked_fsync
    store.save("KF", len(results) - 1, results[-1])
"""

# Saves runs without end, cycling through the pickled results.
SAVE_FOREVER = """
results = pickle.loads(Path(sys.argv[3]).read_bytes())
with store.lock():
    run = 0
    while True:
        store.save("KF", run, results[run % len(results)])
        print("saved", run, flush=True)
        run += 1
"""


def make_result(run: int) -> RunResult:
    """A run whose records and gains hold every kind of value the store must keep exactly."""
    records = tuple(
        {
            "learner": "KF",
            "run": run,
            "iteration": t,
            "environment": f"s{t}-t0-l2" if t else "",
            "estimate_error": 0.1 + 0.2 + t / 3,
            "regret": -0.0 if t == 0 else float("nan"),
            "regret_paper": (math.inf, -math.inf, 5e-324)[t],
            "regret_failures": 2**70 if t == 2 else 0,
            "update_skipped": 'PlanningError: "ipopt" ⟂\n\udcff' if t == 1 else "",
            "converged": t == 2,
            "one": 1.0,
            "theta_0": float(np.nextafter(0.5, 1.0)) * (run + 1),
        }
        for t in range(3)
    )
    gains = np.full((2, 2, 2), np.nan)
    gains[1] = [[-0.0, np.inf], [5e-324, 2 / 3 + run]]
    gains[0, 1, 0] = np.array([0x7FF8000000000123], dtype=np.uint64).view(np.float64)[0]
    return RunResult(records=records, gains=gains, solves=7 + run)


def assert_identical(got: RunResult, want: RunResult) -> None:
    """Same values, same types, same key order, same bits (NaN payloads included)."""
    assert got.solves == want.solves and type(got.solves) is int
    assert len(got.records) == len(want.records)
    for g, w in zip(got.records, want.records, strict=True):
        assert list(g) == list(w)
        for name in w:
            assert type(g[name]) is type(w[name]), name
            # repr is what the CSV holds; for a float it is exact, so equal repr = equal bits.
            assert repr(g[name]) == repr(w[name]), name
    assert got.gains.dtype == want.gains.dtype
    assert got.gains.shape == want.gains.shape
    assert got.gains.tobytes() == want.gains.tobytes()


@contextlib.contextmanager
def child(script: str, *args: object) -> Iterator[subprocess.Popen]:
    """A second Python process running ``script``, killed on exit (or if it hangs 30 s)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", PRELUDE + script, *map(str, args)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    watchdog = threading.Timer(30, proc.kill)
    watchdog.start()
    try:
        yield proc
    finally:
        watchdog.cancel()
        proc.kill()
        proc.wait()
        proc.stdin.close()
        proc.stdout.close()


def sigkill(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGKILL)
    assert proc.wait() == -signal.SIGKILL


# --- settings keys ---------------------------------------------------------------------------


def test_settings_key_is_pinned():
    """A fixed literal: the key depends on nothing but the settings (not the process, not
    the Python session), and a change of its recipe, which would orphan every stored run,
    fails here."""
    assert settings_key(SETTINGS) == "573932da55be0a6c"


def test_settings_key_ignores_key_order_and_container_type():
    shuffled = dict(reversed(SETTINGS.items()))
    as_lists = {**SETTINGS, "theta_star": [0.5, 1.0], "cov0": np.eye(2)}
    numpy_scalars = {**SETTINGS, "runs": np.int64(3), "theta_star": np.array([0.5, 1.0])}
    assert settings_key(shuffled) == settings_key(SETTINGS)
    assert settings_key(as_lists) == settings_key(SETTINGS)
    assert settings_key(numpy_scalars) == settings_key(SETTINGS)
    assert len(settings_key(SETTINGS)) == 16


@pytest.mark.parametrize(
    "change",
    [
        {"theta_star": (float(np.nextafter(0.5, 1.0)), 1.0)},  # last bit of a float
        {"cov0": ((1.0, 0.0), (0.0, float(np.nextafter(1.0, 0.0))))},  # nested tuple
        {"cov0": [[1.0, 0.0], [-0.0, 1.0]]},  # sign of zero, nested list
        {"runs": 4},
        {"runs": 3.0},  # int vs float
        {"seed": False},  # bool vs int
        {"fixed_alpha": 0.0},  # None vs a value
        {"figure": "fig5"},
        {"extra": 0},  # a new setting
    ],
)
def test_settings_key_changes_with_any_value(change):
    assert settings_key({**SETTINGS, **change}) != settings_key(SETTINGS)


def test_settings_key_refuses_what_is_not_plain_data():
    with pytest.raises(TypeError, match=r"settings\['cov0'\]\[1\]: object"):
        settings_key({**SETTINGS, "cov0": ((1.0, 0.0), object())})
    with pytest.raises(TypeError, match="key 1 must be a str"):
        settings_key({1: 2})


# --- round trips -----------------------------------------------------------------------------


def test_save_and_load_are_bit_exact(tmp_path):
    store = RunStore(tmp_path, SETTINGS)
    want = make_result(3)
    with store.lock():
        path = store.save("KF", 3, want)
    assert path == tmp_path / store.key / "KF-3.json"
    got = RunStore(tmp_path, SETTINGS).load("KF", 3)
    assert_identical(got, want)
    assert np.isnan(got.gains[0]).all() and got.gains.flags.writeable
    assert math.copysign(1.0, got.records[0]["regret"]) == -1.0


def test_save_refuses_values_that_would_not_come_back_the_same(tmp_path):
    store = RunStore(tmp_path, SETTINGS)
    good = make_result(0)
    with_numpy = RunResult(({**good.records[0], "regret": np.float64(1.0)},), good.gains, 1)
    with store.lock():
        with pytest.raises(TypeError, match=r"KF run 0: records\[0\]\['regret'\]: float64"):
            store.save("KF", 0, with_numpy)
        with pytest.raises(ValueError, match="learner 'K/F'"):
            store.save("K/F", 0, good)
        for run in (-1, True, 1.0):
            with pytest.raises(ValueError, match="non-negative int"):
                store.save("KF", run, good)
    assert store.done() == set()


def test_save_needs_the_lock(tmp_path):
    store = RunStore(tmp_path, SETTINGS)
    with pytest.raises(RuntimeError, match="needs the lock"):
        store.save("KF", 0, make_result(0))
    with store.lock():
        store.save("KF", 0, make_result(0))
    with pytest.raises(RuntimeError, match="needs the lock"):
        store.save("KF", 1, make_result(1))


# --- what is done ----------------------------------------------------------------------------


def test_done_lists_finished_runs_only(tmp_path):
    store = RunStore(tmp_path, SETTINGS)
    with store.lock():
        for learner, run in [("KF", 0), ("KF", 1), ("PP", 0)]:
            store.save(learner, run, make_result(run))
    complete = (store.folder / "KF-1.json").read_bytes()
    truncated_temp = store.folder / ".KF-2.json.x1y2.tmp"
    truncated_temp.write_bytes(complete[: len(complete) // 2])
    for junk in ("notes.txt", "PP-01.json", "KF-x.json", "KF-3.json.bak"):
        (store.folder / junk).write_text("garbage")
    (store.folder / "AL-0.json").mkdir()

    assert store.done() == {("KF", 0), ("KF", 1), ("PP", 0)}
    loaded = store.load_all()
    assert list(loaded) == [("KF", 0), ("KF", 1), ("PP", 0)]
    assert_identical(loaded[("KF", 1)], make_result(1))
    with store.lock():  # a dead writer's temporary file goes; nothing else does
        assert not truncated_temp.exists()
    assert (store.folder / "notes.txt").exists()


def test_settings_keep_their_runs_apart(tmp_path):
    four = RunStore(tmp_path, SETTINGS)
    five = RunStore(tmp_path, {**SETTINGS, "figure": "fig5"})
    with four.lock():
        four.save("KF", 0, make_result(0))
    assert four.folder != five.folder
    assert four.done() == {("KF", 0)}
    assert five.done() == set()
    stored = json.loads((four.folder / "settings.json").read_text())
    assert settings_key(stored) == four.key
    assert stored["cov0"] == [[1.0, 0.0], [0.0, 1.0]]


def test_edited_settings_file_is_refused(tmp_path):
    store = RunStore(tmp_path, SETTINGS)
    RunStore(tmp_path, SETTINGS)  # reopening with the same settings is fine
    path = store.folder / "settings.json"
    path.write_text(json.dumps({**SETTINGS, "seed": 1}))
    with pytest.raises(ValueError, match=f"{path}: holds other settings"):
        RunStore(tmp_path, SETTINGS)


def test_corrupt_finished_file_is_an_error_naming_it(tmp_path):
    store = RunStore(tmp_path, SETTINGS)
    with store.lock():
        store.save("KF", 0, make_result(0))
        store.save("KF", 1, make_result(1))
    path = store.folder / "KF-0.json"
    complete = path.read_bytes()
    path.write_bytes(complete[:-10])
    assert ("KF", 0) in store.done()
    with pytest.raises(CorruptRun, match=f"{path}: not a complete run .*delete it"):
        store.load("KF", 0)
    with pytest.raises(CorruptRun, match=str(path)):
        store.load_all()
    path.write_bytes((store.folder / "KF-1.json").read_bytes())
    with pytest.raises(CorruptRun, match="holds KF run 1"):
        store.load("KF", 0)
    with pytest.raises(FileNotFoundError):
        store.load("KF", 2)


# --- the lock --------------------------------------------------------------------------------


def test_lock_is_exclusive_within_a_process(tmp_path):
    store = RunStore(tmp_path, SETTINGS)
    with store.lock():
        with pytest.raises(StoreLocked):
            with RunStore(tmp_path, {**SETTINGS, "runs": 9}).lock():
                pass
        with pytest.raises(RuntimeError, match="already holds"):
            with store.lock():
                pass
        store.save("KF", 0, make_result(0))  # the failed attempts did not drop the lock
    with store.lock():
        pass


def test_second_process_is_refused_until_the_first_releases(tmp_path):
    store = RunStore(tmp_path, SETTINGS)
    with child(HOLD_LOCK, tmp_path, json.dumps(SETTINGS)) as proc:
        assert proc.stdout.readline() == "locked\n"
        # The lock covers the whole root: other settings write to the same output folder.
        for settings in (SETTINGS, {**SETTINGS, "runs": 9}):
            with pytest.raises(StoreLocked) as info:
                with RunStore(tmp_path, settings).lock():
                    pass
            message = str(info.value)
            assert message == (
                f"{tmp_path}: another run (pid {proc.pid}) is writing there; "
                "wait for it to finish or choose another output folder"
            )
        proc.stdin.close()
        assert proc.stdout.readline() == "released\n"
        with store.lock():
            store.save("KF", 0, make_result(0))
    assert store.done() == {("KF", 0)}


def test_lock_of_a_killed_process_is_free(tmp_path):
    store = RunStore(tmp_path, SETTINGS)
    with child(HOLD_LOCK, tmp_path, json.dumps(SETTINGS)) as proc:
        assert proc.stdout.readline() == "locked\n"
        sigkill(proc)
    with store.lock():
        pass


def test_forked_child_of_a_killed_holder_does_not_keep_the_lock(tmp_path):
    store = RunStore(tmp_path, SETTINGS)
    with child(HOLD_LOCK_AND_FORK, tmp_path, json.dumps(SETTINGS)) as proc:
        grandchild = int(proc.stdout.readline())
        try:
            with pytest.raises(StoreLocked):  # the parent holds it
                with store.lock():
                    pass
            sigkill(proc)
            os.kill(grandchild, 0)  # still alive, with the holder's descriptors
            with store.lock():
                pass
        finally:
            os.kill(grandchild, signal.SIGKILL)


# --- SIGKILL while writing -------------------------------------------------------------------


def test_sigkill_inside_a_save_leaves_only_complete_runs(tmp_path):
    results = [make_result(run) for run in range(4)]
    pickled = tmp_path / "results.pickle"
    pickled.write_bytes(pickle.dumps(results))
    root = tmp_path / "runs"
    store = RunStore(root, SETTINGS)
    with child(SAVE_THEN_BLOCK, root, json.dumps(SETTINGS), pickled) as proc:
        assert [proc.stdout.readline() for _ in range(4)] == [
            "saved 0\n",
            "saved 1\n",
            "saved 2\n",
            "writing\n",
        ]
        sigkill(proc)
    temps = [p.name for p in store.folder.iterdir() if p.name.endswith(".tmp")]
    assert len(temps) == 1 and temps[0].startswith(".KF-3.json.")
    assert store.done() == {("KF", 0), ("KF", 1), ("KF", 2)}
    for (_, run), got in store.load_all().items():
        assert_identical(got, results[run])
    with store.lock():  # the resumed command: cleans up and redoes run 3 only
        store.save("KF", 3, results[3])
    assert not any(p.name.endswith(".tmp") for p in store.folder.iterdir())
    assert_identical(store.load("KF", 3), results[3])


def test_sigkill_at_a_random_moment_leaves_only_complete_runs(tmp_path):
    results = [make_result(run) for run in range(3)]
    pickled = tmp_path / "results.pickle"
    pickled.write_bytes(pickle.dumps(results))
    root = tmp_path / "runs"
    with child(SAVE_FOREVER, root, json.dumps(SETTINGS), pickled) as proc:
        for run in range(20):
            assert proc.stdout.readline() == f"saved {run}\n"
        sigkill(proc)
    store = RunStore(root, SETTINGS)
    done = store.done()
    assert {("KF", run) for run in range(20)} <= done
    assert {learner for learner, _ in done} == {"KF"}
    for (_, run), got in store.load_all().items():
        assert_identical(got, results[run % 3])
