"""The page's server: a viser server showing a session's page, the drag page or, for a
physical session, the page where the person pushes the moving arm.

The address is checked before anything is written (:func:`check_address`): a host that does
not resolve within :data:`RESOLVE_TIMEOUT`, an address that is not this machine's, or a port
in use is refused in one line. viser itself would try the next port, silently (a participant
told port P then finds nothing there, or someone else's session), and on an address it cannot
bind would try a thousand ports and never return.
"""

from __future__ import annotations

import contextlib
import errno
import io
import logging
import os
import socket
import threading
from pathlib import Path

from corrections_sim.pages.page import Page
from corrections_sim.pages.physical import PhysicalPage
from corrections_sim.session.session import Session

#: Seconds a host name may take to resolve (a machine without a name server would otherwise
#: wait for the resolver's own timeouts, or for ever).
RESOLVE_TIMEOUT = 3.0


class AddressError(ValueError):
    """A host or port the page cannot be served on; the message is one line naming it."""


def resolve(host: str, timeout: float = RESOLVE_TIMEOUT) -> str:
    """The numeric address ``host`` names, found within ``timeout`` seconds.

    Raises:
        AddressError: it does not resolve, or not in time.
    """
    if not host.strip():
        raise AddressError(f"--host {host!r}: does not resolve (an empty name)")
    found: list = []
    answered = threading.Event()

    def look_up() -> None:
        try:
            found.append(socket.getaddrinfo(host, None, type=socket.SOCK_STREAM))
        except (OSError, UnicodeError) as exc:
            found.append(exc)
        answered.set()

    # A daemon thread: a resolver that hangs is left behind, not waited for.
    threading.Thread(target=look_up, name="resolve", daemon=True).start()
    if not answered.wait(timeout):
        raise AddressError(f"--host {host}: did not resolve within {timeout:.0f} s")
    if isinstance(found[0], BaseException):
        reason = getattr(found[0], "strerror", None) or found[0]
        raise AddressError(f"--host {host}: does not resolve ({reason})")
    return found[0][0][4][0]


def check_address(host: str, port: int) -> str:
    """The numeric address to serve on, once ``port`` is known to be free there.

    Raises:
        AddressError: the host does not resolve, is not an address of this machine, or the
            port is in use (or not ours to take).
    """
    address = resolve(host)
    family = socket.AF_INET6 if ":" in address else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        # As the server will bind it (asyncio sets SO_REUSEADDR on POSIX): a port left in
        # TIME_WAIT by a server that just stopped is free, one that is listening is not.
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((address, port))
            probe.listen(1)
        except OSError as exc:
            reason = exc.strerror or str(exc)
            if exc.errno == errno.EADDRINUSE:
                reason = "in use (another server, or another session's page?)"
                raise AddressError(f"--port {port}: {reason}") from None
            if exc.errno == errno.EACCES:
                reason = "not this user's to take (ports below 1024 need root)"
                raise AddressError(f"--port {port}: {reason}") from None
            where = f"{address}:{port}"
            raise AddressError(f"--host {host}: cannot serve on {where} ({reason})") from None
    return address


class _ClosedBeforeRequest(logging.Filter):
    """Drops websockets' "opening handshake failed" when the client closed the connection
    before sending a request line (a browser's speculative connection, a tab closed while it
    connected): nothing failed, and its traceback on stderr read as a crash. Every other
    handshake failure is still logged."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.getMessage() != "opening handshake failed" or not record.exc_info:
            return True
        cause = record.exc_info[1]
        while cause is not None and not isinstance(cause, EOFError):
            cause = cause.__cause__
        return cause is None


def open_server(host: str = "127.0.0.1", port: int = 8080):
    """A viser server on ``host:port``, checked first (see the module); no page on it yet.

    Raises:
        AddressError: see :func:`check_address`; or the port was taken between the check and
            the server's start.
        RuntimeError: viser is not installed (``pip install "corrections_sim[interact]"``).
    """
    try:
        import viser
    except ImportError:
        raise RuntimeError(
            'interact needs viser: pip install -e ".[interact]" (or pip install viser==1.1.1)'
        ) from None
    address = check_address(host, port)
    quiet = logging.getLogger("websockets.server")
    if not any(isinstance(f, _ClosedBeforeRequest) for f in quiet.filters):
        quiet.addFilter(_ClosedBeforeRequest())
    # viser prints a panel of its URLs whatever verbose says; the command line prints its own.
    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host=address, port=port, verbose=False)
    if server.get_port() != port:  # taken in between: viser moved on to the next one
        stop(server)
        raise AddressError(f"--port {port}: in use (taken while the server started)")
    return server


def stop(server) -> None:
    """Stop ``server`` without viser's "Server stopped" on the standard output."""
    with contextlib.redirect_stdout(io.StringIO()):
        server.stop()


def configure(server) -> None:
    """The page's theme and lights on ``server`` (every tab's)."""
    server.gui.configure_theme(control_width="large", show_share_button=False)
    server.gui.main_panel.dock_right()
    # No shadow maps: a second render pass per light that people rarely miss in this scene and
    # that chromium's software WebGL pays at every frame (5 → 9.7 frames/s during a motion).
    server.scene.configure_default_lights(enabled=True, cast_shadow=False)


def make_page(server, session: Session, *, speed: float = 1.0, **options) -> Page:
    """The page that shows ``session`` (the physical one for a physical session)."""
    if session.physical:
        model = session.correction
        return PhysicalPage(
            server,
            session,
            speed=speed,
            stiffness=model.stiffness,
            force_cap=model.force_cap,
            **options,
        )
    return Page(server, session, **options)


def show(server, session: Session, *, speed: float = 1.0) -> Page:
    """``session``'s page on ``server``: a physical session's page plays its motions at
    ``speed`` (simulated seconds per real second)."""
    configure(server)
    page = make_page(server, session, speed=speed)
    # How the session is shown, so that --resume plays a physical session at its speed.
    mode = "physical" if session.physical else "drag"
    detail = {"mode": mode, "speed": float(speed), "port": int(server.get_port())}
    detail |= {"host": socket.gethostname(), "pid": os.getpid()}
    session.log.add_event(session.id, session.iteration, "page", detail)
    return page


def serving(log, session_id: int) -> int | None:
    """The process on this machine whose page still serves session ``session_id`` (from its
    last ``page`` event), or None: a second server on one session would interleave two
    people's corrections in one log."""
    pages = log.events(session_id, "page")
    if not pages:
        return None
    last = pages[-1]["detail"]
    pid = last.get("pid")
    if pid is None or last.get("host") != socket.gethostname() or pid == os.getpid():
        return None
    try:
        command = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:  # gone (or no /proc: then nothing is known, and nothing refused)
        return None
    return pid if b"corrections_sim" in command else None


def serve(session: Session, host: str = "127.0.0.1", port: int = 8080, *, speed: float = 1.0):
    """A viser server on ``host:port`` showing ``session``'s page; (server, page). A physical
    session's page plays its motions at ``speed`` (simulated seconds per real second).

    Raises:
        AddressError: see :func:`open_server`.
        RuntimeError: viser is not installed.
    """
    server = open_server(host, port)
    try:
        return server, show(server, session, speed=speed)
    except BaseException:
        stop(server)
        raise
