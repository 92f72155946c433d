"""The browser page (viser): the person sees ξᵗ, drags a waypoint's cup, submits.

The thin edge over :class:`corrections_sim.session.session.Session`: it draws the scene and
the plan, turns a handle's drag into :meth:`Session.drag`, and buttons into
:meth:`Session.submit`, :meth:`Session.skip`, :meth:`Session.finish`. Nothing here learns or
logs by itself.

One person at a time: the first browser tab to connect owns the session; a second tab open at
the same time is told the server is busy (a user study has one participant per session; the
experimenter starts another server, with another port, for a second one). When the owner's tab
closes, the next tab to connect takes the session over where it stands (a reload loses
nothing).

Every control is safe at every moment. A control is enabled only where its action can be
taken (:meth:`Page._refresh`), and the page says why the others are not; the server checks
again when a click arrives, since a click can cross the message that disabled its button. One
action runs at a time: a click that arrives while another is being worked on (the learner's
update, the next plan, the deployment) is dropped and the page says so, rather than queued to
act on a plan the person no longer sees. After "Done" the page shows the deployment until its
tab closes (:attr:`Page.finished`, :attr:`Page.left`); a reload shows it again.

When the learner asks for feature traces (KF-CRX), the page turns to teaching before the next
plan, and a heat map on the table shows what the robot wants
(:mod:`corrections_sim.pages.teach`, the part of :class:`Page` that does both). The
estimates themselves (θ̂, σ, β̂, the deployment's γ) are in a folder for the
researcher, closed at the start; the person's panel speaks in words.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping

import numpy as np

from corrections_sim.pages.drawing import (
    AVERSE_RGB,
    CAMERA_FOV,
    CAMERA_LOOK_AT,
    CAMERA_POSITION,
    CORRECTION_RGB,
    MESH_MATERIAL,
    PLAN_RGB,
    clear,
    cup_path,
    draw_path,
    plural,
)
from corrections_sim.pages.meshes import Poser, pieces
from corrections_sim.pages.teach import Teaching
from corrections_sim.scene.robot import cup_pose
from corrections_sim.scene.world import interpolate
from corrections_sim.session.session import Deployment, Refused, Session

#: pyplot is not safe from two threads at once (several participants' pages on one server).
_DRAWING = threading.Lock()
#: The line a participant's page shows above the first correction until they have stated
#: their preference.
FIRST_LINE = "**First state your preference (below).**\n"
#: The skip button's label, and on a participant's page.
SKIP = "Skip this environment"
SKIP_BLIND = "Skip: show me another scene"


def ask_text(ask: Mapping, features, *, physical: bool = False) -> str:
    """What the page asks of its person for a labelled correction (a drag, or with
    ``physical`` a push of the moving arm)."""
    move = "Push the cup" if physical else "Move the cup"
    if ask["kind"] == "nudge":
        return (
            f"**Asked: a nudge.** {move} a little anywhere, for no reason at all (this "
            "correction is a test and carries no preference)."
        )
    weights = ", ".join(f"{n} {w:+.1f}" for n, w in zip(features, ask["preference"], strict=True))
    where = "toward where" if physical else "to where"
    return (
        f"**Asked: correct toward the preference ({weights}).** {move} {where} a person with "
        "it would want it here."
    )


def render_belief(theta: np.ndarray, cov: np.ndarray | None, features, stated=None) -> np.ndarray:
    """θ̂ with its uncertainty: the 1σ and 2σ ellipses for k = 2, bars with ±σ otherwise; an
    RGB image (H, W, 3) straight from the canvas (no PNG in between: the page encodes it)."""
    with _DRAWING:
        return _render_belief(theta, cov, features, stated)


def _render_belief(theta, cov, features, stated) -> np.ndarray:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(3.2, 2.6), dpi=90)
    k = len(theta)
    if k == 2 and cov is not None:
        values, vectors = np.linalg.eigh(cov)
        angles = np.linspace(0, 2 * np.pi, 100)
        circle = np.stack([np.cos(angles), np.sin(angles)])
        for n_sigma, alpha in ((1, 0.35), (2, 0.15)):
            shape = vectors @ (n_sigma * np.sqrt(np.maximum(values, 0))[:, None] * circle)
            ax.fill(theta[0] + shape[0], theta[1] + shape[1], color="C0", alpha=alpha, lw=0)
        ax.plot(*theta, "o", color="C0", label="θ̂")
        if stated is not None:
            ax.plot(*stated, "*", color="C3", ms=10, label="stated")
        ax.set_xlabel(f"θ {features[0]}")
        ax.set_ylabel(f"θ {features[1]}")
        ax.axhline(0, color="0.8", lw=0.6)
        ax.axvline(0, color="0.8", lw=0.6)
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(fontsize=7, loc="best")
    else:
        sigma = np.zeros(k) if cov is None else np.sqrt(np.maximum(np.diag(cov), 0))
        ax.bar(range(k), theta, yerr=sigma, color="C0", capsize=4)
        if stated is not None:
            ax.plot(range(k), stated, "*", color="C3", ms=10)
        ax.set_xticks(range(k), features, fontsize=8)
        ax.axhline(0, color="0.5", lw=0.6)
    ax.tick_params(labelsize=7)
    fig.tight_layout()
    fig.canvas.draw()
    rgb = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return rgb


def relevance_note(row: dict) -> str:
    """For a relevance-aware learner, how far it believed the correction (β̂), for the
    status line; else nothing."""
    if not row.get("relevance"):
        return ""
    beta = row["relevance"]["beta"]
    if beta >= 0.5:
        return " (it fits what I know: I learnt from it)"
    return " (it does not fit what I know: I learnt little from it)"


class Page(Teaching):
    """The page of one session on a viser server (see the module)."""

    def __init__(
        self,
        server,
        session: Session,
        *,
        attach: bool = True,
        limit: int | None = None,
        on_end: Callable[[], None] | None = None,
        blind: bool = False,
        minimum: int | None = None,
        require_stated: bool = False,
    ):
        """``attach``: the page takes the server's connections (a study's server hands each
        participant's tab to their page itself, :meth:`connect`); ``limit``: the session ends
        (as "Done") after this many corrections, a study's trial; ``on_end``: called once the
        end is on the page; ``blind``: the page speaks to a participant (no learner, no
        environment names, no symbols, no estimate; a study's participant is blind to the
        condition); ``minimum``: corrections before "Done" is offered (default: any, or with
        ``limit`` none: the trial ends at its limit); ``require_stated``: the person states
        their preference before the first correction (a study whose outcome is measured
        against it)."""
        self.blind = blind
        if minimum is None:
            minimum = limit if limit is not None else 0
        self.minimum = int(minimum)
        self.require_stated = bool(require_stated)
        self.server = server
        self.session = session
        self.limit = limit
        self.on_end = on_end
        #: The page has left its tab (a study moved on to its next step): no more drawing.
        self.closed = False
        self.owner = None
        self.client = None
        self._lock = threading.RLock()
        # Held while an action runs; a click that finds it taken is dropped (see the module).
        self._action = threading.Lock()
        self.poser = Poser()
        self.proposal = None
        self.corrected: np.ndarray | None = None
        self.drag_info: dict = {}
        self.stated: np.ndarray | None = None
        self.submitted = 0  # corrections submitted through this page (tests wait on it)
        self.drags = 0  # drags handled, accepted or refused
        self.dropped = 0  # clicks dropped because another action was running
        #: perf_counter() when the last submit's click arrived and when its next plan was sent.
        self.last_submit = (float("nan"), float("nan"))
        self._clicked: float | None = None
        self.last_message = ""
        self.deployment: Deployment | None = None
        #: Set when "Done" has ended the session and the page shows the deployment.
        self.finished = threading.Event()
        #: Set when the tab that showed the end has closed (the server may stop then).
        self.left = threading.Event()
        self._busy = ""  # what the running action is doing, for the page ("" when idle)
        self._playing = False
        #: teaching a feature (the learner asked for traces), recording a trace, the cup
        #: positions of the trace so far, where the arm is (q) and where the trace began
        self.teaching = False
        self.recording = False
        self.trace_points: list[np.ndarray] = []
        self.drag_points: list[np.ndarray] = []  # the drag under way while recording
        self.teach_refused = False  # the last teaching drag went out of reach
        self.confirming = False  # "I cannot show it" with traces given: asked to confirm
        self.teach_q: np.ndarray | None = None
        self.trace_start_q: np.ndarray | None = None
        self.traces_taken = 0  # traces submitted through this page (tests wait on it)
        self.teach_moves = 0  # teaching drags handled (tests wait on it)
        self.starts_refused = 0  # Start clicks refused (a script waits on it)
        self.teach_handle = None
        self.teach_env = None  # the environment the traces are given in
        #: the heat map's drawn tiles (centres (n, 3), colours (n, 3)) once drawn
        self.map_points: np.ndarray | None = None
        self.map_colours: np.ndarray | None = None
        server.initial_camera.position = CAMERA_POSITION
        server.initial_camera.look_at = CAMERA_LOOK_AT
        server.initial_camera.up = (0.0, 0.0, 1.0)
        server.initial_camera.fov = CAMERA_FOV
        if attach:
            server.on_client_connect(self._connect)
            server.on_client_disconnect(self._disconnect)

    def connect(self, client) -> None:
        """Show the page on ``client`` (a study's server, which chose the tab)."""
        self._connect(client)

    def disconnect(self, client) -> None:
        self._disconnect(client)

    def settle(self, timeout: float | None = None) -> bool:
        """Wait until nothing of this page's still runs on the server; whether nothing does
        (a drag page learns on viser's handlers: nothing outlives them)."""
        return True

    def close(self) -> None:
        """Leave the tab to whoever draws on it next (nothing of this page is drawn again)."""
        with self._lock:
            self.closed = True
            self.client = None
            self.owner = None

    # --- clients ---------------------------------------------------------------------------

    def _connect(self, client) -> None:
        with self._lock:
            if self.owner is not None:
                client.gui.add_markdown(
                    "**The server is busy**: another tab holds this session. One person at a "
                    "time; close the other tab and reload this one."
                )
                return
            self.owner = client
        try:
            with self._lock, self.session.log.unless_closed():  # the server may be stopping
                self.handle = None  # the handles of a closed tab are not this one's
                self._build(client)
        except Exception:
            with self._lock:
                self.owner = None
            raise

    def _disconnect(self, client) -> None:
        with self._lock:
            if self.owner is not None and client.client_id == self.owner.client_id:
                self.owner = None
                self.client = None
                self.corrected = None
                self._let_go()
                if self.session.ended:
                    self.left.set()

    def _let_go(self) -> None:
        """The person's hand leaves the page (a physical page lets go of the cup)."""

    # --- building the page -----------------------------------------------------------------

    def _build(self, client) -> None:
        s = self.session
        self.client = client
        scene, gui = client.scene, client.gui
        self._add_meshes(scene)
        self._add_texts(gui)
        self._add_preference(gui)
        n = s.n_waypoints
        self.waypoint = gui.add_slider(
            "Point to move" if self.blind else "Waypoint to move",
            min=1,
            max=n - 2,
            step=1,
            initial_value=(n - 1) // 2,
        )
        # Disabled until the first plan is on the page (its solve may take seconds).
        self.play = gui.add_button("Play the plan", disabled=True)
        self.submit_button = gui.add_button("Submit correction", disabled=True)
        self.reset_button = gui.add_button("Reset the drag", disabled=True)
        self.skip_button = gui.add_button(SKIP_BLIND if self.blind else SKIP, disabled=True)
        self.done_button = self._add_done(gui)
        self._teach_folder(gui)
        self._add_belief_panel(gui)
        self.waypoint.on_update(lambda _: self._show_waypoint())
        self.play.on_click(lambda _: self._play())
        self.submit_button.on_click(self._act(self.submit_button, self._submit, "learning"))
        self.reset_button.on_click(self._act(self.reset_button, lambda: self._reset(log=True)))
        self.skip_button.on_click(self._act(self.skip_button, self._skip, "planning"))
        self.done_button.on_click(self._act(self.done_button, self._done, "deploying"))
        self._first_view()

    def _add_preference(self, gui) -> None:
        """The stated preference: a slider per feature of the study, and its button. A slider
        counts only once the person has moved it (its start, 0, is no answer); a session that
        has one (a resumed one) shows it."""
        s = self.session
        features = s.settings.features  # the stated preference is over the study's
        logged = s.log.session(s.id).stated_theta
        if logged is not None:
            self.stated = np.asarray(logged, float)
        if self.blind:
            title = "Your preference (before your first correction)"
            text = (
                "How much do you want the cup near each thing? **−2**: far from it, **0**: "
                "you do not mind, **+2**: near it. Set every slider to your answer (move it, "
                "or type a number into its box and press Enter; 0 too), then press **State "
                "my preference**."
            )
        else:
            title = "Your preference (before the first correction)"
            text = "How much do you want the cup near each thing? −2 far … +2 near."
        self.preference_folder = gui.add_folder(title)
        with self.preference_folder:
            gui.add_markdown(text)
            self.sliders = [
                gui.add_slider(
                    name,
                    min=-2.0,
                    max=2.0,
                    step=0.1,
                    initial_value=0.0 if self.stated is None else float(self.stated[i]),
                )
                for i, name in enumerate(features)
            ]
            if self.blind and self.stated is None:  # a participant's: no answer yet
                for slider in self.sliders:
                    clear(slider)
            self.state_button = gui.add_button("State my preference", disabled=True)
            # What the server has received of the sliders (a participant's page).
            self.pref_echo = gui.add_markdown("", visible=self.blind)
        # A slider the person moved has a newer update time than it was made with (viser sets
        # it on its event loop before any callback runs, so a click cannot overtake it).
        self._made = [slider.update_timestamp for slider in self.sliders]
        self.state_button.on_click(self._act(self.state_button, self._state))
        for slider in self.sliders:
            slider.on_update(lambda _: self._echo_preference())
        self._echo_preference()

    def _echo_preference(self) -> None:
        """The line under the preference sliders: each value as the server has it."""
        if not self.blind or self.client is None or self.closed:
            return
        names = self.session.settings.features
        parts = [
            f"{name} {slider.value:+.1f}"
            if slider.update_timestamp != made or self.stated is not None
            else f"{name} (not moved yet)"
            for name, slider, made in zip(names, self.sliders, self._made, strict=True)
        ]
        self.pref_echo.content = "We have: " + ", ".join(parts)

    def _show_values(self, theta: np.ndarray) -> None:
        """The preference sliders show ``theta``, the values the server holds (a change the
        page showed but never sent is undone on the page); they stay as they were: moved or
        not."""
        for i, slider in enumerate(self.sliders):
            touched = slider.update_timestamp != self._made[i]
            # viser sends a value only when it changes on the server: a step away and back
            # makes the page redraw the slider at the server's value.
            slider.value = float(theta[i]) + (0.1 if theta[i] < 2.0 else -0.1)
            slider.value = float(theta[i])
            if not touched:
                self._made[i] = slider.update_timestamp
        self._echo_preference()

    def _add_done(self, gui):
        """The button that ends the session: "Done: deploy", or on a participant's page
        "Done with this robot" once the trial has its minimum (hidden where the trial simply
        ends at its limit)."""
        label = "Done with this robot" if self.blind else "Done: deploy"
        self._done_shown = self.limit is None or self.minimum < self.limit
        return gui.add_button(label, disabled=True, visible=self._done_shown)

    def _add_texts(self, gui) -> None:
        """The title, the status line and the line that says where the cup is."""
        self.title = gui.add_markdown("")
        self.status = gui.add_markdown("")
        self.where = gui.add_markdown("")
        self.probe = gui.add_html("") if self.blind else None

    def _first_view(self) -> None:
        """What a tab that connects sees first: the end, the teaching, or the plan (once it
        is solved)."""
        if self.session.ended:
            self._show_end()
            if self.on_end is not None:
                self.on_end()
            return
        if self.session.wanted > len(self.session.traces) and not self.session.physical:
            self._start_teaching()  # the physical page does not teach (not built)
            return
        if self.teaching:  # a reload after the teaching's last action: not taught any more
            self.teaching = self.recording = False
        self._say("Planning the robot's path…")
        self._new_proposal()
        given = self.session.learnt_before_stop
        if given is not None:
            self._say(
                f"**Welcome back.** The robot's server stopped after you gave your "
                f"{given} {plural(given, 'trace')}; none is lost: I have learnt what you mind "
                "from them, and this plan takes it into account. Correct it as before."
            )

    def _add_meshes(self, scene) -> None:
        """The scene's visual pieces, kept by geom for posing the arm."""
        self.meshes = {
            piece.geom: scene.add_mesh_simple(
                f"/world/{piece.name}",
                piece.vertices,
                piece.faces,
                color=piece.rgb,
                material=MESH_MATERIAL,
            )
            for piece in pieces()
        }
        self._moving = {piece.geom for piece in pieces() if piece.moves}

    def _add_belief_panel(self, gui) -> None:
        """θ̂ and its uncertainty: a picture and a table (see :meth:`_show_belief`); not on a
        participant's page (what the robot believes is the study's to analyse, not theirs to
        read)."""
        self.researcher_folder = gui.add_folder(
            "For the researcher: the robot's estimates", expand_by_default=False,
            visible=not self.blind,
        )  # fmt: skip
        with self.researcher_folder:
            self.researcher_text = gui.add_markdown("", visible=not self.blind)
            self.belief_image = gui.add_image(
                np.full((10, 10, 3), 255, np.uint8),
                label="θ̂ and its uncertainty",
                visible=not self.blind,
            )
            self.belief_text = gui.add_markdown("", visible=not self.blind)

    def _say(self, text: str) -> None:
        self.last_message = text
        if self.client is not None and not self.closed:
            self.status.content = text

    def _pose_arm(self, q: np.ndarray, *, moving_only: bool = False) -> None:
        """Every piece at its pose for the arm at ``q`` (7,); with ``moving_only`` only the
        arm's and the cup's (the props stay where the environment put them)."""
        client = self.client
        if client is None:
            return
        env = self.proposal.env if self.proposal is not None else self.teach_env
        with client.atomic():
            for geom, (position, wxyz) in self.poser.poses(q, env).items():
                if moving_only and geom not in self._moving:
                    continue
                handle = self.meshes[geom]
                handle.position = position
                handle.wxyz = wxyz

    # --- which controls work now -----------------------------------------------------------

    def _controls(self) -> list[tuple]:
        """Each control of the page with whether it works now (not ended, not busy, a plan
        on the page, and its own condition)."""
        s = self.session
        teach = self.teaching and not s.ended and not self._busy
        ready = self.proposal is not None and not s.ended and not self._busy and not self.teaching
        first = ready and s.iteration == 0  # stated (again) until the first correction
        stated = self.stated is not None or not self.require_stated
        enough = s.iteration >= self.minimum or self.limit is None
        given = len(s.traces)
        return [
            (self.start_trace, teach and not self.recording),
            (self.end_trace, teach and self.recording and len(self.trace_points) >= 2),
            (self.cancel_trace, teach and self.recording),
            (self.learn_now, teach and not self.recording and s.fewest_traces <= given < s.wanted),
            (self.decline, teach and not self.recording),
            (self.set_aside, teach and not self.recording and self.confirming),
            (self.state_button, first),
            *((slider, first) for slider in self.sliders),
            (self.waypoint, ready),
            (self.play, ready),
            (self.submit_button, ready and stated and self.corrected is not None),
            (self.reset_button, ready and self.corrected is not None),
            (self.skip_button, ready),
            (self.done_button, ready and enough),
        ]

    def _refresh(self) -> None:
        """Enable what works now, disable the rest (see :meth:`_controls`)."""
        if self.client is None or self.closed:
            return
        for control, works in self._controls():
            control.disabled = not works

    def _act(self, button, action: Callable[[], None], doing: str = "") -> Callable:
        """A click handler for ``button`` that runs ``action`` only when nothing else runs
        and the button was enabled when the click arrived; while it runs (``doing``: what the
        page says it is doing) every control is disabled."""

        def on_click(_event) -> None:
            if not self._action.acquire(blocking=False):
                self.dropped += 1
                self._say(f"**Busy** {self._busy or 'working'}: that click was not taken.")
                return
            try:
                with self._lock, self.session.log.unless_closed():  # the server may be stopping
                    if button.disabled or self.session.ended or self.client is None:
                        return  # pressed before the page showed it disabled
                    self._busy = doing
                    if doing:
                        self._refresh()
                    try:
                        action()
                    finally:
                        self._busy = ""
                        self._refresh()
            finally:
                self._action.release()

        return on_click

    # --- the plan on the page --------------------------------------------------------------

    def _new_proposal(self) -> None:
        s = self.session
        self.proposal = s.proposal()
        self.corrected = None
        self.drag_info = {}
        plan = self.proposal.plan.trajectory
        client = self.client
        if client is None:
            return  # the tab closed: the next one draws it
        scene = client.scene
        path = cup_path(plan)
        scene.add_spline_catmull_rom(
            "/plan/path", path, thickness=3.0, thickness_units="screen", color=PLAN_RGB
        )
        scene.add_point_cloud(
            "/plan/waypoints",
            np.array([cup_pose(q)[1] for q in plan]),
            colors=PLAN_RGB,
            point_size=0.014,
            point_shape="circle",
        )
        for name in ("/correction/path", "/deploy/plain", "/deploy/averse"):
            scene.add_spline_catmull_rom(name, path[:2], color=CORRECTION_RGB, visible=False)
        self._make_handle()
        k = s.iteration
        if self.blind:
            of = "" if self.limit is None else f" of {self.limit}"
            self.title.content = (
                f"### Correction {k + 1}{of}\n{self._first_line()}Drag the arrows on the cup "
                "to move it where you want it at the chosen point of the path, then press "
                "**Submit correction**." + self._ask_line()
            )
        else:
            self.title.content = (
                f"### Correction {k + 1}\n"
                "Drag the arrows on the cup to move it where you want it at the chosen point "
                "of the path, then submit it." + self._ask_line()
            )
            self.researcher_text.content = (
                f"Learner **{s.learner}**, correction model **{s.correction_name}**, "
                f"environment **{self.proposal.env.name}**."
            )
        if self._clicked is not None:  # set before the title can reach a reader of the page
            self.last_submit = (self._clicked, time.perf_counter())
            self._clicked = None
        self._show_belief()
        self._redraw_map()
        self._refresh()
        self._say("The robot's plan is the blue path. Move the cup where you want it.")

    def _first_line(self) -> str:
        """The line that asks for the stated preference while it is missing ("" after)."""
        return FIRST_LINE if self.require_stated and self.stated is None else ""

    def _show_where(self, i: int, cup, moved: bool = False) -> None:
        """The line under the title: which point of the path, and (for a researcher) where
        the cup is; a participant's page keeps the numbers out of sight, in an element a
        script reads (``data-cup``), never shown."""
        verb = " moved to" if moved else ""
        line = f"Cup at waypoint {i}{verb}: ({cup[0]:.3f}, {cup[1]:.3f}, {cup[2]:.3f}) m"
        if self.blind:
            self.where.content = f"Point {i} of the path" + (": moved" if moved else "")
            self.probe.content = f'<span hidden data-cup="{line}"></span>'
        else:
            self.where.content = line

    def _ask_line(self) -> str:
        """The labelled correction the session asks for now, as a paragraph ("" if none)."""
        asked = self.session.ask()
        if asked is None:
            return ""
        return "\n\n" + ask_text(asked, self.session.features, physical=self.session.physical)

    def _make_handle(self) -> None:
        i = int(self.waypoint.value)
        cup = cup_pose(self.proposal.plan.trajectory[i])[1]
        self.handle = self._cup_handle("/handle", cup)
        self.handle.on_update(lambda event: self._dragged() if event.phase == "end" else None)
        self._show_where(i, cup)
        self._pose_arm(self.proposal.plan.trajectory[i])

    def _show_waypoint(self) -> None:
        with self._lock:
            if self.proposal is None or self.session.ended or self.client is None:
                return
            if self.corrected is not None:
                self._reset(log=True)
            self._make_handle()
            self._refresh()

    def _show_belief(self) -> None:
        if self.blind:
            return
        s = self.session
        b = s.belief
        cov = b.cov if s.has_covariance else None
        stated = self.stated
        if stated is not None and b.dim > stated.size:  # no stated weight for a learnt one
            stated = np.concatenate([stated, np.full(b.dim - stated.size, np.nan)])
        self.belief_image.image = render_belief(b.theta, cov, s.features, stated)
        sigma = np.sqrt(np.diag(b.cov)) if cov is not None else None
        rows = "\n".join(
            f"| {name} | {b.theta[i]:+.3f} | "
            + (f"±{sigma[i]:.3f}" if sigma is not None else "–")
            + " |"
            for i, name in enumerate(s.features)
        )
        relevance = ""
        if s.last_relevance is not None:
            beta, rho = s.last_relevance["beta"], s.last_relevance["rho"]
            relevance = (
                f"\n\nThe last correction: relevant with probability **β̂ = {beta:.2f}**"
                + ("" if rho is None else f", the fraction the features do not span ρ = {rho:.2f}")
                + "; learnt from in proportion."
            )
        learnt = b.state.describe()  # what its family learnt beyond θ̂ and P (the person, …)
        if learnt and s.iteration > 0:
            relevance += "\n\n" + learnt
        self.belief_text.content = (
            f"After **{s.iteration}** {plural(s.iteration, 'correction')}:\n\n"
            f"| feature | θ̂ | σ |\n|---|---|---|\n{rows}" + relevance
        )

    # --- actions ---------------------------------------------------------------------------

    def _state(self) -> None:
        theta = np.array([s.value for s in self.sliders], float)
        names = self.session.settings.features
        if self.blind:
            untouched = [
                name
                for name, slider, made in zip(names, self.sliders, self._made, strict=True)
                if slider.update_timestamp == made and self.stated is None
            ]
            if untouched:
                # What the page shows may be ahead of what arrived (viser drops a change sent
                # in the same 50 ms as another): the sliders show the server's values again.
                self._show_values(theta)
                self._say(
                    f"**Not yet**: set the slider of {', '.join(untouched)} to your answer "
                    "(0 too), then press State my preference again."
                )
                return
        try:
            self.stated = self.session.state(theta)
        except Refused as exc:
            self._say(f"**Refused**: {exc}")
            return
        self._show_belief()
        if self.blind:
            self._show_values(theta)
            values = ", ".join(f"{n} {v:+.1f}" for n, v in zip(names, theta, strict=True))
            self._say(
                f"Your preference is recorded as: **{values}**. You can change it until your "
                "first correction."
            )
            self.title.content = self.title.content.replace(FIRST_LINE, "")
        else:
            self._say(f"Stated preference θ = {np.round(theta, 2).tolist()} recorded.")

    def _dragged(self) -> None:
        if not self._action.acquire(blocking=False):
            # The robot is working on the last click: this drag was made on a page that is
            # about to change; put the handle back rather than take it.
            with self._lock:
                self.dropped += 1
                if self.client is not None and self.proposal is not None:
                    self._make_handle()
                self._say(f"**Busy** {self._busy or 'working'}: drag again when it is done.")
            return
        try:
            with self._lock:
                if self.session.ended or self.client is None or self.proposal is None:
                    return
                self._take_drag()
        finally:
            self._action.release()

    def _take_drag(self) -> None:
        i = int(self.waypoint.value)
        if self.require_stated and self.stated is None:
            self._make_handle()  # back where it was
            self._refresh()
            self._say("**First state your preference** (below); then move the cup.")
            self.drags += 1
            return
        position = np.array(self.handle.position, float)
        try:
            corrected = self.session.drag(i, position)
        except Refused as exc:
            self.corrected = None
            self._make_handle()  # back where it was
            self._refresh()
            self._say(f"**Refused**: {exc}. Nothing was recorded; try another position.")
            self.drags += 1
            return
        self.corrected = corrected
        self.drag_info = {"waypoint": i, "handle": position.tolist()}
        draw_path(self.client.scene, "/correction/path", corrected, CORRECTION_RGB)
        self._pose_arm(corrected[i])
        self._refresh()
        self._show_where(i, position, moved=True)
        self._say("Your correction is the orange path. Submit it, or drag again.")
        self.drags += 1

    def _reset(self, *, log: bool) -> None:
        if log and self.corrected is not None:
            self.session.undo()
        self.corrected = None
        self.client.scene.add_spline_catmull_rom(
            "/correction/path", np.zeros((2, 3)), visible=False
        )
        self._make_handle()
        self._refresh()

    def _submit(self) -> None:
        if self.corrected is None:
            self._say("Drag the cup first.")
            return
        t0 = time.perf_counter()
        self._say("Learning from your correction…")
        try:
            row = self.session.submit(self.corrected, drag=self.drag_info)
        except Refused as exc:
            self._say(f"**Refused**: {exc}")
            return
        self.corrected = None
        self._busy = "planning"
        self._clicked = t0
        if self.limit is not None and self.session.iteration >= self.limit:
            self.submitted += 1
            self._done()  # the trial has its corrections
            return
        if self.session.wanted:
            self._start_teaching()
            self.submitted += 1
            self._say(
                f"Correction {row['iteration'] + 1} recorded{relevance_note(row)}. Before the "
                "next plan, I need your help (above)."
            )
            return
        self._new_proposal()
        self.submitted += 1
        if self.blind:
            self._say(f"Correction {row['iteration'] + 1} recorded. Here is the next plan.")
            return
        skipped = f" (update skipped: {row['update_skipped']})" if row["update_skipped"] else ""
        self._say(
            f"Correction {row['iteration'] + 1} recorded{skipped}{relevance_note(row)}; "
            f"next plan in {time.perf_counter() - t0:.2f} s."
        )

    def _skip(self) -> None:
        if self.corrected is not None:
            self.session.undo()
        self._say("Skipped; planning in the next environment…")
        self.session.skip()
        self._new_proposal()

    def _play(self) -> None:
        """Animate the plan (nothing is logged or learnt); the arm ends where the page had it."""
        with self._lock:
            if self._playing or self.proposal is None or self.play.disabled:
                return
            self._playing = True
            proposal = self.proposal
        try:
            for q in interpolate(proposal.plan.trajectory, 6):
                if self.proposal is not proposal or self.client is None or self.session.ended:
                    return  # a new plan, or the end, is on the page: it shows itself
                self._pose_arm(q)
                time.sleep(0.05)
            with self._lock:
                if self.proposal is proposal and self.client is not None and not self.session.ended:
                    i = int(self.waypoint.value)
                    shown = proposal.plan.trajectory if self.corrected is None else self.corrected
                    self._pose_arm(shown[i])
        finally:
            self._playing = False

    def _done(self) -> None:
        """End the session: the deployment is planned, logged and shown; the page stays."""
        s = self.session
        self._say("Ending the session: planning the deployment…")
        if self.corrected is not None:
            s.undo()
            self.corrected = None
        self.deployment = s.finish()
        self._show_end()
        self.finished.set()
        if self.on_end is not None:
            self.on_end()

    def _ended_text(self) -> str:
        s, deployment = self.session, self.deployment
        if self.blind:
            return "This trial is over. Thank you."
        done = f"Session ended after {s.iteration} {plural(s.iteration, 'correction')}."
        if deployment is None:
            why = (
                "no plan to deploy"
                if s.has_covariance
                else "this robot keeps no measure of its uncertainty to be careful with"
            )
            return f"**{done}** Nothing deployed ({why}). You may close this tab."
        f = s.features

        def phi(plan) -> str:
            return ", ".join(f"{n} {v:.2f}" for n, v in zip(f, plan.features, strict=True))

        self.researcher_text.content = (
            f"Deployed in {deployment.env.name}: the plain plan ξ*(θ̂) (Φ: "
            f"{phi(deployment.plain)}); the risk-averse plan of eq. (A4), γ = "
            f"{np.round(deployment.gamma, 2).tolist()} (Φ: {phi(deployment.averse)})."
        )
        return (
            f"**{done}** Blue: the path I would take now. Green: a more careful path, which "
            "keeps away from what I am still unsure of. You may close this tab."
        )

    def _show_end(self) -> None:
        """The ended session: the deployment drawn, every control disabled, the handle gone."""
        client = self.client
        if client is None:
            return
        scene = client.scene
        for control, _ in self._controls():
            control.disabled = True
        if self.handle is not None:
            self.handle.visible = False
        scene.add_spline_catmull_rom("/correction/path", np.zeros((2, 3)), visible=False)
        deployment = self.deployment
        if deployment is not None:
            self._pose_arm(deployment.plain.trajectory[0])
            draw_path(scene, "/plan/path", deployment.plain.trajectory, PLAN_RGB)
            draw_path(scene, "/deploy/averse", deployment.averse.trajectory, AVERSE_RGB)
        self.title.content = (
            "### This trial is over" if self.blind else f"### Session {self.session.id} has ended"
        )
        self.where.content = ""
        self._show_belief()
        self._say(self._ended_text())
