"""Ctrl-C and SIGTERM end the command within seconds at any moment (issue 13).

Each case starts the real command in its own session, interrupts it at one moment (while the
planner is compiled, mid-run, while a replacement pool starts after a worker died, on a Dask
cluster, during start-up), and checks: exit status 130, one "interrupted: N finished runs
kept in ..." line and no traceback on stderr, an exit within ``PROMPT_S`` of the signal, and
no process of the command's session left (workers, gcc).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

#: Seconds from the signal to the command's exit that count as prompt.
PROMPT_S = 5.0
ARGV = ["fig4", "--quick", "--runs", "3", "--iterations", "2"]


def _session(sid: int) -> list[tuple[int, str]]:
    """(pid, name) of every live process of session ``sid``."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        state, _ppid, _pgrp, session = stat[stat.rindex(")") + 2 :].split()[:4]
        if int(session) == sid and state != "Z":
            found.append((int(entry), name))
    return found


class Command:
    """The command in a new session, its stderr read line by line as it comes."""

    def __init__(self, argv: list[str], out: Path, **env: str) -> None:
        self.out = out
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "corrections_sim.run", *argv, "--out", str(out)],
            start_new_session=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, **env},
        )
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stderr:
            self.lines.append(line)

    def wait_for(self, condition, what: str, timeout: float = 120.0) -> None:
        deadline = time.monotonic() + timeout
        while not condition():
            assert self.proc.poll() is None, f"ended before {what}: {''.join(self.lines)}"
            assert time.monotonic() < deadline, f"no {what} within {timeout} s"
            time.sleep(0.02)

    def finished_runs(self) -> int:
        return len(list((self.out / ".runs" / "fig4").glob("*/*-*.json")))

    def children(self) -> list[int]:
        return [pid for pid, _ in _session(self.proc.pid) if pid != self.proc.pid]

    def interrupt(self, sig: int = signal.SIGINT, group: bool = True) -> float:
        """Send ``sig`` (to the whole foreground group, as a terminal's Ctrl-C does, or to
        the command alone, as ``kill`` does); seconds until the command exited."""
        start = time.monotonic()
        (os.killpg if group else os.kill)(self.proc.pid, sig)
        try:
            self.proc.wait(timeout=60)
        finally:
            elapsed = time.monotonic() - start
            self._cleanup()
        self._reader.join(timeout=5)
        return elapsed

    def _cleanup(self) -> None:
        for pid, _ in _session(self.proc.pid):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        with contextlib.suppress(ProcessLookupError):
            self.proc.kill()
        self.proc.wait()

    def check_stopped(self, elapsed: float) -> None:
        err = "".join(self.lines)
        assert self.proc.returncode == 130, err
        assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
        assert self.lines[-1].startswith("interrupted: "), err
        assert sum(line.startswith("interrupted") for line in self.lines) == 1, err
        if (self.out / ".runs").exists():
            assert f"{self.finished_runs()} finished run" in self.lines[-1], err
        deadline = time.monotonic() + 2.0  # the kernel reparents and reaps the killed
        while (left := _session(self.proc.pid)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not left, f"processes left behind: {left}"
        assert elapsed < PROMPT_S, f"took {elapsed:.1f} s to stop"
        print(f"[interrupt] {elapsed:.2f} s from signal to exit")


@pytest.fixture
def command(tmp_path):
    started: list[Command] = []

    def start(argv=ARGV, **env):
        started.append(Command(argv, tmp_path / f"out{len(started)}", **env))
        return started[-1]

    yield start
    for c in started:
        if c.proc.returncode is None:
            c._cleanup()


def test_ctrl_c_while_the_planner_is_compiled(command, tmp_path):
    cache = tmp_path / "empty-cache"
    c = command([*ARGV, "--workers", "1"], CORRECTIONS_SIM_CACHE=str(cache))
    compilers = {"gcc", "cc1", "as", "collect2", "ld"}
    c.wait_for(lambda: {name for _, name in _session(c.proc.pid)} & compilers, "gcc")
    c.check_stopped(c.interrupt())
    assert not list(cache.glob("*.so"))  # no half-built library under the final name


@pytest.mark.parametrize(
    ("sig", "group"), [(signal.SIGINT, True), (signal.SIGTERM, False)], ids=["INT", "TERM"]
)
def test_interrupt_mid_run_keeps_the_finished_runs(command, sig, group):
    c = command([*ARGV, "--workers", "2"])
    c.wait_for(lambda: c.finished_runs() >= 1, "finished run")
    c.check_stopped(c.interrupt(sig, group))
    assert c.finished_runs() >= 1


@pytest.mark.parametrize("delay", [0.0, 0.3])
def test_ctrl_c_while_a_replacement_pool_starts(command, delay):
    c = command([*ARGV, "--workers", "2"])
    c.wait_for(lambda: c.finished_runs() >= 1 and c.children(), "finished run")
    os.kill(c.children()[0], signal.SIGKILL)
    c.wait_for(lambda: any("a worker died" in line for line in c.lines), "replacement pool")
    time.sleep(delay)  # at once: the new pool is being made; 0.3 s: its workers are starting
    c.check_stopped(c.interrupt())


@pytest.mark.parametrize("after", [0.7, 1.5])
def test_ctrl_c_during_start_up(command, after):
    c = command([*ARGV, "--workers", "2"])
    # 0.7 s: the planner's stack (CasADi, MuJoCo, pinocchio) is loading, where an interrupted
    # extension module reports an ImportError; 1.5 s: settings read, the pool starting.
    time.sleep(after)
    c.check_stopped(c.interrupt())


def test_ctrl_c_on_a_dask_cluster(command):
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None
    ) as cluster:
        c = command([*ARGV, "--scheduler", cluster.scheduler_address])
        c.wait_for(lambda: c.finished_runs() >= 1, "finished run")
        c.check_stopped(c.interrupt())


def test_a_dask_connection_closed_under_a_pending_future_logs_no_traceback():
    """What tornado logged once in CI on Ctrl-C with a Dask cluster (a CommClosedError raised
    from a StreamClosedError, in a callback of the client's loop) is dropped; any other error
    it logs is kept."""
    import logging

    from distributed.comm.core import CommClosedError
    from tornado.iostream import StreamClosedError

    from corrections_sim.cli.executors import ClosedConnections

    def logged(exc: BaseException) -> logging.LogRecord:
        try:
            raise exc
        except BaseException:
            info = sys.exc_info()
        return logging.LogRecord("tornado.application", logging.ERROR, __file__, 1,
                                 "Exception in callback %r", ("cascade",), info)  # fmt: skip

    try:
        try:
            raise StreamClosedError()
        except StreamClosedError as closed:
            raise CommClosedError("in <TCP (closed) ConnectionPool.gather>") from closed
    except CommClosedError as exc:
        chained = exc
    quiet = ClosedConnections()
    assert not quiet.filter(logged(chained))
    assert not quiet.filter(logged(StreamClosedError()))
    assert quiet.filter(logged(ValueError("a real error")))
    assert quiet.filter(logging.LogRecord("tornado.application", 40, "", 1, "no exc", (), None))


def test_an_interrupt_inside_a_foreign_call_is_still_an_interrupt():
    """A Ctrl-C that lands while ctypes converts an argument (``import mujoco`` calls EGL so)
    reaches the command as ctypes' ArgumentError naming it, unchained: still an interrupt."""
    import ctypes
    import signal

    from corrections_sim.cli.executors import interruption

    found = interruption(ctypes.ArgumentError("argument 1: Interrupted: SIGINT"))
    assert found is not None and found.signum == signal.SIGINT
    assert interruption(ctypes.ArgumentError("argument 1: TypeError: wrong type")) is None


def test_an_interrupt_a_library_swallowed_stops_the_command_at_its_next_step(capsys):
    """A SIGINT that lands in a library's ``try: import … except ImportError`` is lost to the
    exception, and the command's signals are ignored after the first: the next step the command
    takes (a progress report, the start of its pool) raises it again, once; once the command
    has taken it (where it says it was interrupted), nothing more; a block that received no
    signal raises nothing."""
    from corrections_sim.cli.common import Progress
    from corrections_sim.cli.executors import Interrupted, check_interrupted, interrupts, taken

    def swallowed() -> None:  # as a library's optional import swallows it
        with contextlib.suppress(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1.0)

    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with interrupts():
            swallowed()
            assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
            with pytest.raises(Interrupted, match="SIGINT"):
                Progress("fig4")(0, 3)
            check_interrupted()  # raised once: the command has it now
        with interrupts():
            swallowed()
            taken()
            check_interrupted()
        with interrupts():
            check_interrupted()
            Progress("fig4")(1, 3)
    finally:
        for s, h in before.items():
            signal.signal(s, h)
    capsys.readouterr()
