"""The page's server: a viser server showing a session's page, the drag page or, for a
physical session, the page where the person pushes the moving arm."""

from __future__ import annotations

from corrections_sim.interact.page import Page
from corrections_sim.interact.physical_page import PhysicalPage
from corrections_sim.interact.session import Session


def serve(session: Session, host: str = "127.0.0.1", port: int = 8080, *, speed: float = 1.0):
    """A viser server on ``host:port`` showing ``session``'s page; (server, page). A physical
    session's page plays its motions at ``speed`` (simulated seconds per real second).

    Raises:
        RuntimeError: viser is not installed (``pip install "corrections_sim[interact]"``).
    """
    try:
        import viser
    except ImportError:
        raise RuntimeError(
            'interact needs viser: pip install -e ".[interact]" (or pip install viser==1.1.1)'
        ) from None
    server = viser.ViserServer(host=host, port=port, verbose=False)
    server.gui.configure_theme(control_width="large", show_share_button=False)
    server.gui.main_panel.dock_right()
    # No shadow maps: a second render pass per light that people rarely miss in this scene and
    # that chromium's software WebGL pays at every frame (5 → 9.7 frames/s during a motion).
    server.scene.configure_default_lights(enabled=True, cast_shadow=False)
    if session.physical:
        model = session.correction
        page = PhysicalPage(
            server, session, speed=speed, stiffness=model.stiffness, force_cap=model.force_cap
        )
        return server, page
    return server, Page(server, session)
