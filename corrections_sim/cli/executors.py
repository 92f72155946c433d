"""Where a figure's runs execute, and how the command stops when asked to.

A terminal's Ctrl-C sends SIGINT to every process of its foreground group, and a worker that
is interrupted mid-task prints a traceback while its pool waits for it. So only the command
decides: its workers ignore SIGINT and each runs in its own process group (with anything it
starts, such as gcc building a planner), and on SIGINT or SIGTERM the command kills those
groups and never waits for a pool to drain. A worker whose command died (even by SIGKILL)
is killed by the kernel (``PR_SET_PDEATHSIG`` on Linux), so none outlives it.

Nothing here computes results: it is the command line's edge (see ``run.py``).
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import re
import signal
import threading
from collections.abc import Iterator
from concurrent.futures import Executor, ProcessPoolExecutor
from functools import partial
from multiprocessing.managers import BaseManager

_SIGNALS = {signal.SIGINT, signal.SIGTERM}
#: prctl(2) option: the signal a process gets when its parent dies (Linux).
_PR_SET_PDEATHSIG = 1


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM reached the command (a KeyboardInterrupt, so nothing swallows it)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


#: How ctypes names an interrupt raised while it converted a foreign call's argument.
_IN_CTYPES = re.compile(r"Interrupted: (SIGINT|SIGTERM)$")


def interruption(exc: BaseException | None) -> KeyboardInterrupt | None:
    """The interrupt behind ``exc``, if any: ``exc`` itself or an exception it was raised
    from or while handling (an extension module interrupted while it loads reports an
    ImportError whose context is the interrupt)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        if isinstance(exc, ctypes.ArgumentError):  # raised in a foreign call's argument:
            found = _IN_CTYPES.search(str(exc))  # ctypes names it and does not chain it
            if found:
                return Interrupted(signal.Signals[found[1]])
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


@contextlib.contextmanager
def interrupts() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM raise :class:`Interrupted` in the main thread.

    After the first signal both stay ignored for the rest of the process, so the cleanup
    that follows (killing workers, removing a staging folder) runs to its end and no second
    signal prints a traceback; otherwise the previous handlers are restored on leaving.
    Outside the main thread this does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    hit = []

    def handler(signum, frame):
        for s in _SIGNALS:
            signal.signal(s, signal.SIG_IGN)
        hit.append(signum)
        _PENDING[:] = [signum]
        raise Interrupted(signum)

    previous = {s: signal.signal(s, handler) for s in _SIGNALS}
    try:
        yield
    finally:
        _PENDING.clear()
        if not hit:
            for s, h in previous.items():
                signal.signal(s, h)


#: The signal an :func:`interrupts` block received whose interrupt has not been taken yet
#: (:func:`taken`, where the command says it was interrupted).
_PENDING: list[int] = []


def taken() -> None:
    """The command has the interrupt in hand (it is cleaning up): :func:`check_interrupted`
    raises nothing more."""
    _PENDING.clear()


def check_interrupted() -> None:
    """Raise again an interrupt the command received and never took (:func:`taken`).

    A library that imports an optional dependency inside ``try: … except ImportError`` swallows
    an interrupt that lands in that import (an interrupted extension module reports an
    ImportError), and since the first signal leaves both ignored, the command would run to its
    end deaf to Ctrl-C: seen once in the suite, a SIGINT 0.7 s after the start of a study under
    load, which then ran all its runs and exited 0. The command's edges call this between
    steps (before its pool starts, at every progress report), so such an interrupt stops the
    command there."""
    if _PENDING:
        raise Interrupted(_PENDING.pop())


@contextlib.contextmanager
def uninterrupted() -> Iterator[None]:
    """SIGINT and SIGTERM wait until the block is done (e.g. moving a figure's files in, so an
    interrupt never leaves half of an old figure and half of a new one)."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _worker_init(parent: int) -> None:
    """Runs first in every worker; SIGINT and SIGTERM arrive blocked (see ``_QuietPool``)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # also discards a pending Ctrl-C
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    os.setpgid(0, 0)
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:  # the command died before prctl took effect
        os._exit(1)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _SIGNALS)


class _QuietPool(ProcessPoolExecutor):
    """A process pool whose workers are never interrupted before ``_worker_init`` ran.

    Workers are started inside ``submit``; blocking SIGINT and SIGTERM around it makes every
    new worker start with them blocked (a child inherits the signal mask), so a Ctrl-C that
    lands while a (replacement) pool is starting stays pending and is discarded there.
    """

    def submit(self, fn, /, *args, **kwargs):
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
        try:
            return super().submit(fn, *args, **kwargs)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def kill_workers(pool: ProcessPoolExecutor) -> None:
    """Kill every worker of ``pool`` and its process group, then drop the pool unwaited."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        for kill in (os.killpg, os.kill):  # the group, or the worker if it has none yet
            with contextlib.suppress(ProcessLookupError, PermissionError):
                kill(process.pid, signal.SIGKILL)
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.join(timeout=1.0)


class _ExchangeManager(BaseManager):
    """Serves plan exchanges to a process pool's workers from a process of its own."""


def _new_exchange():
    from corrections_sim.plans.spread import PlanExchange

    return PlanExchange(shared_files=True)  # a pool's workers share this machine's store


_ExchangeManager.register("PlanExchange", _new_exchange)


class _PoolExchanges:
    """The plan exchanges of one process pool (``pool.exchange()``): each a handle on a
    :class:`~corrections_sim.plans.spread.PlanExchange` held by one manager process, started
    when the first is asked for, quiet like a worker (no Ctrl-C; it dies with the command)."""

    def __init__(self) -> None:
        self.manager: _ExchangeManager | None = None

    def make(self):
        if self.manager is None:
            manager = _ExchangeManager()
            previous = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
            try:
                manager.start(initializer=_worker_init, initargs=(os.getpid(),))
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, previous)
            self.manager = manager
        return self.manager.PlanExchange()

    def close(self) -> None:
        if self.manager is not None:
            with contextlib.suppress(OSError, EOFError):
                self.manager.shutdown()
            self.manager = None


@contextlib.contextmanager
def process_pool(workers: int) -> Iterator[Executor]:
    """A local process pool that shuts down cleanly, or is killed on any exception.

    Leaving normally waits for the workers; leaving by an exception (an interrupt, a dead
    worker, a failed run) kills them at once instead of waiting for queued tasks. Its workers
    hand each other the plans they solve between an atlas's nodes through an exchange
    (``pool.exchange()``, a manager process's), as a cluster's do: the shared store alone
    reaches a worker only when it first asks about an environment.
    """
    pool = _QuietPool(max_workers=workers, initializer=_worker_init, initargs=(os.getpid(),))
    exchanges = _PoolExchanges()
    pool.exchange = exchanges.make
    try:
        yield pool
        pool.shutdown(wait=True)
    except BaseException:
        kill_workers(pool)
        raise
    finally:
        exchanges.close()


_ADDRESS = re.compile(r"(?:(?:tcp|tls|ws|wss|ucx)://)?(?:\[[0-9a-fA-F:.]+\]|[^\s:/\[\]]+):\d{1,5}")


def check_scheduler_address(address: str) -> str:
    """``address`` if it reads as a Dask scheduler's ``[scheme://]HOST:PORT``.

    Raises:
        ValueError: anything else (checked before any connection is tried).
    """
    if not _ADDRESS.fullmatch(address):
        raise ValueError(f"{address!r} is not an address like tcp://HOST:PORT")
    return address


#: The exceptions of a Dask connection closed under a pending future, by name (so that this
#: module does not import tornado or distributed unless a cluster is used).
_CLOSED = {"CommClosedError", "StreamClosedError"}


class ClosedConnections(logging.Filter):
    """Drops what tornado logs when a Dask connection closes under a pending future: on
    Ctrl-C (the client closes with this command's tasks still out) it printed a traceback
    before the command's one-line "interrupted:" (seen once in a CI run of the suite). The
    command says what happened in its own words; a connection lost while the runs go on still
    fails their futures, which the command reports."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        while exc is not None:
            if type(exc).__name__ in _CLOSED:
                return False
            exc = exc.__cause__ or exc.__context__
        return True


def _quiet_closed_connections() -> None:
    """Install :class:`ClosedConnections` on tornado's callback logger, once per process
    (its callbacks may run after the client is closed, so it stays)."""
    logger = logging.getLogger("tornado.application")
    if not any(isinstance(f, ClosedConnections) for f in logger.filters):
        logger.addFilter(ClosedConnections())


def _exchange(client, held: list | None = None):
    """A :class:`~corrections_sim.plans.spread.PlanExchange` held on ``client``'s cluster
    (a Dask actor), its handle. The actor lives while the future that made it does: kept in
    ``held`` (the executor's, for the command's life), since the handle alone keeps it only
    when ``client`` is the process's default client."""
    from corrections_sim.plans.spread import PlanExchange

    future = client.submit(PlanExchange, actor=True, pure=False)
    if held is not None:
        held.append(future)
    exchange = future.result()
    # A handle binds to the client current at its first call, for good: this one (the command's
    # client is not the process's default), so that this process can call it later too.
    with client.as_current():
        exchange.since(0).result()
    return exchange


@contextlib.contextmanager
def dask_executor(address: str, timeout_s: float) -> Iterator[tuple[Executor, int]]:
    """An executor on the Dask cluster at ``address`` and its number of workers.

    Raises:
        ValueError: a malformed address.
        ConnectionError: no scheduler answered within ``timeout_s`` (the message says why).
    """
    from distributed import Client

    check_scheduler_address(address)
    _quiet_closed_connections()
    try:
        client = Client(address, timeout=f"{timeout_s}s", set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConnectionError(message) from None
    try:
        n = len(client.scheduler_info(n_workers=-1).get("workers", {}))
        executor = client.get_executor(pure=False)
        # The cluster's workers may not share this machine's files (its plan atlases): the
        # runner hands them what they need once each (scattered to every worker), a handle a
        # task takes as an argument in its place.
        executor.share = partial(client.scatter, broadcast=True, hash=False)
        # ... and hand each other the plans they solve between the atlas's nodes, through
        # one exchange held on the cluster (an actor; its handle is a task's argument).
        executor.exchange = partial(_exchange, client, [])
        yield executor, n
    finally:
        # The cluster's workers belong to the cluster; closing the client releases this
        # command's tasks there, and no signal may leave the client half closed.
        with uninterrupted(), contextlib.suppress(OSError, TimeoutError):
            client.close(timeout=timeout_s)
