"""Teaching a feature on the correction page, and the heat map of what the robot wants.

When the learner asks for feature traces (KF-CRX, :attr:`Session.wanted`), the page turns to
teaching before the next plan, and its correction controls step aside. The person drags the cup
to where what they mind is strongest (not recorded) and presses "Start a trace here"; the
trace starts where the arm holds the cup, which is where the page shows it: Start is refused
while a drag is being checked (the handle is not where the arm is) or after a drag the arm could
not reach (the cup went back), and the page says why. They drag it to where it is weakest
(every handle position of a drag the arm can follow is recorded, and the path so far is drawn;
several drags make one trace) and press "End the trace", or "Cancel this trace". The cup's path
becomes arm configurations by IK (the cup kept upright) and a logged trace. With all of them,
or with at least :data:`~corrections_sim.session.teaching.MIN_TRACES` when the person
presses "Learn from the traces I gave", the feature is learnt and the next plan is made over
it. "I cannot show it" declines; traces already given are set aside only after the person
confirms it, and the page says how many. A trace cut short by a crash is named on return,
the cup where it began.

The heat map on the current environment's table shows what the robot wants now, the same way
before and after learning: with the cup at each point of the table, how sure it is that it
would rather have the cup there than elsewhere on this table, the probability under its
belief N(θ̂, P) that θ·(φ(x) − φ̄) > 0 (φ̄: the mean over the table's points): blue where
it is sure it would, red where it is sure it would not, the deeper the surer; nothing is drawn
where it cannot tell (40–60%) nor over the laptop, so the table and its objects show. A
reward against zero (θ̂·φ within two of its sd, grey) was grey everywhere for corrections
after a feature was learnt: the new weight's sd (≈ 1) swamps every place's whole reward, not
the differences between places. A learner without a covariance is shown by the sign and size
of θ̂·(φ(x) − φ̄). Once a feature is learnt, the map can show the feature's own shape instead
(purple: strongest). A slider sets the height of the cup it is computed at.

:class:`Teaching` is the page's part that does both (:class:`~corrections_sim.pages.page.Page`
is built on it); the functions here are what it draws, plain values in and out.
"""

from __future__ import annotations

import numpy as np

from corrections_sim.pages.drawing import (
    CORRECTION_RGB,
    HANDLE_SCALE,
    MESH_MATERIAL,
    plural,
    resample_path,
)
from corrections_sim.planning.features import HUMAN_POSITION, pose_feature_function
from corrections_sim.scene import geometry as g
from corrections_sim.scene.robot import cup_inverse_kinematics, cup_pose
from corrections_sim.session.session import Refused

#: The teaching heat map: a grid over the table (points along x, along y), this high above
#: the table top (m, the cup centre), and the states a trace keeps at most (evenly along the
#: cup's path; FERL's traces had about as many).
MAP_GRID = (28, 18)
MAP_HEIGHT = 0.25
#: The heat map's tiles, a fraction of the grid's spacing: the table shows between them.
MAP_TILE = 0.8
TRACE_STATES = 20
#: The heat map leaves out a point where the robot's probability of wanting the cup there
#: more than elsewhere on the table is within this much of 0.5 (it cannot tell).
MAP_UNSURE = 0.1
#: Points of the heat map left out around the laptop's keyboard and screen (m, beyond their
#: footprint): a square point drawn next to it would cover its edge.
LAPTOP_MARGIN = 0.03
#: What the heat map can show (the second once a feature is learnt).
MAP_REWARD = "What the robot wants now"
MAP_SHAPE = "What you showed it"
MAP_OFF = "Nothing"
#: How near (m) the teaching handle must be to the cup the arm holds for a trace to start
#: there (farther: the page's last drag is still being checked).
START_TOLERANCE = 0.01
#: Where the person whose feature ``human`` is sits (drawn in a teaching session's scene).
PERSON_RGB = (150, 150, 165)
#: How far (m) the cup must move for a recorded handle position to count.
TRACE_STEP = 0.005


def map_features(env, names, rotation: np.ndarray, height: float = MAP_HEIGHT):
    """(points (n, 3), φ (k, n)): the features ``names`` with the cup at each point of a grid
    over the table of ``env``, ``height`` above its top, the hand at ``rotation``."""
    hx, hy = g.TABLE_HALF_SIZE
    tx, ty = env.table
    xs = np.linspace(tx - hx, tx + hx, MAP_GRID[0])
    ys = np.linspace(ty - hy, ty + hy, MAP_GRID[1])
    cups = np.array([(x, y, g.TABLE_TOP_Z + height) for x in xs for y in ys])
    hands = cups - (rotation @ np.array(g.CUP_CENTER_IN_HAND))[None, :]
    f = pose_feature_function(tuple(names)).map(cups.shape[0])
    rots = np.tile(np.asarray(rotation, float).reshape(-1, order="F")[:, None], cups.shape[0])
    phi = np.asarray(f(rots.reshape(3, 3 * cups.shape[0], order="F"), hands.T, env.params()))
    return cups, phi


def want_probability(theta, cov, phi: np.ndarray) -> np.ndarray:
    """(n,) for the features ``phi`` (k, n) at n places: the probability under N(θ̂, P) that
    the reward is above its mean over the places, Φ(θ̂·d / √(dᵀPd)) with d = φ − φ̄."""
    from scipy.special import ndtr

    d = np.asarray(phi, float) - np.asarray(phi, float).mean(axis=1, keepdims=True)
    mean = np.asarray(theta, float) @ d
    sd = np.sqrt(np.maximum(np.einsum("in,ij,jn->n", d, np.asarray(cov, float), d), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(sd > 0, mean / sd, np.sign(mean) * np.inf)
    return ndtr(z)


def want_colours(theta, cov, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(RGB (n, 3) uint8, drawn (n,) bool) of the heat map: blue where the robot is sure it
    would rather have the cup there than elsewhere, red where it would rather not, the deeper
    the surer (:func:`want_probability`; without a covariance, ``cov`` None, by the sign and
    size of θ̂·(φ − φ̄)); ``drawn`` false where it cannot tell (within :data:`MAP_UNSURE` of
    0.5)."""
    import matplotlib

    if cov is None:
        mean = np.asarray(theta, float) @ (phi - np.mean(phi, axis=1, keepdims=True))
        shade = 0.5 + 0.5 * mean / (float(np.abs(mean).max()) or 1.0)
        drawn = mean != 0.0
    else:
        shade = want_probability(theta, cov, phi)
        drawn = np.abs(shade - 0.5) > MAP_UNSURE
    rgba = matplotlib.colormaps["RdBu"](np.clip(shade, 0.0, 1.0))
    return (255 * rgba[:, :3]).astype(np.uint8), drawn


def map_tiles(centres: np.ndarray, colours: np.ndarray):
    """A flat mesh of the heat map: a tile of :data:`MAP_TILE` of the grid's spacing around
    each of ``centres`` (n, 3), coloured ``colours`` (n, 3) uint8, so the table shows between
    them (squares that face the camera stood up from the table and hid what was on it)."""
    import trimesh  # (viser's own dependency, with the page's extra)

    hx, hy = g.TABLE_HALF_SIZE
    half = 0.5 * MAP_TILE * np.array([2 * hx / (MAP_GRID[0] - 1), 2 * hy / (MAP_GRID[1] - 1)])
    corners = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]) * [*half, 0]
    vertices = (np.asarray(centres, float)[:, None, :] + corners[None]).reshape(-1, 3)
    first = 4 * np.arange(len(centres))[:, None]
    faces = np.concatenate([first + [0, 1, 2], first + [0, 2, 3]])
    # A GLB's vertex colours are linear: the sRGB colours of the map, converted, so the
    # tiles show the colours of the scale (as given they came out washed pale).
    linear = np.round(255 * (np.asarray(colours, float) / 255) ** 2.2).astype(np.uint8)
    rgba = np.concatenate(
        [np.repeat(linear, 4, axis=0), np.full((4 * len(centres), 1), 255, np.uint8)], axis=1
    )
    return trimesh.Trimesh(vertices, faces, vertex_colors=rgba, process=False)


def off_laptop(points: np.ndarray, env) -> np.ndarray:
    """(n,) bool: the (x, y) of ``points`` (n, 3) lie off the laptop's keyboard and screen
    (their footprint on the table, :data:`LAPTOP_MARGIN` around it)."""
    x, y, yaw = env.laptop
    hx, hy, hz = g.LAPTOP_BASE_HALF_SIZE
    # The screen leans back from the keyboard's +y edge: its top reaches this far behind it.
    behind = 2 * g.LAPTOP_SCREEN_HALF_SIZE[2] * np.sin(g.LAPTOP_SCREEN_TILT)
    rot = g.laptop_rotation(yaw)[:2, :2]
    local = (np.asarray(points, float)[:, :2] - np.array([x, y])) @ rot
    m = LAPTOP_MARGIN
    inside = (np.abs(local[:, 0]) <= hx + m) & (local[:, 1] >= -hy - m)
    inside &= local[:, 1] <= hy + behind + m
    return ~inside


def shape_colours(values: np.ndarray) -> np.ndarray:
    """RGB (n, 3) uint8 of a feature's own ``values``: white at its lowest, purple at its
    highest (a shape, not a reward: another scale than :func:`want_colours`)."""
    import matplotlib

    values = np.asarray(values, float)
    span = float(np.ptp(values)) or 1.0
    rgba = matplotlib.colormaps["Purples"](0.05 + 0.9 * (values - values.min()) / span)
    return (255 * rgba[:, :3]).astype(np.uint8)


class Teaching:
    """The correction page's teaching mode and heat map (a part of
    :class:`~corrections_sim.pages.page.Page`, which owns the session, the client and the
    controls these methods reach)."""

    # --- teaching a feature ----------------------------------------------------------------

    def _teach_folder(self, gui) -> None:
        """The teaching controls, the heat map's controls and the person across the table:
        only where the learner may ask for traces."""
        s = self.session
        # Shown while the robot asks (it asks once): a folder of disabled buttons before and
        # after would only push the rest down.
        self.teach_folder = gui.add_folder("Teach the robot", visible=False)
        with self.teach_folder:
            self.start_trace = gui.add_button("Start a trace here", disabled=True)
            self.end_trace = gui.add_button("End the trace", disabled=True)
            self.cancel_trace = gui.add_button("Cancel this trace", disabled=True)
            self.learn_now = gui.add_button("Learn from the traces I gave", disabled=True)
            self.decline = gui.add_button("I cannot show it", disabled=True)
            self.set_aside = gui.add_button("Set my traces aside", disabled=True, visible=False)
        self.map_folder = gui.add_folder("Heat map on the table", visible=s.teaches)
        with self.map_folder:
            self.map_mode = gui.add_dropdown(
                "Show", options=(MAP_REWARD, MAP_SHAPE, MAP_OFF), initial_value=MAP_REWARD
            )
            self.map_height = gui.add_slider(
                "Cup height (m)", min=0.05, max=0.45, step=0.05, initial_value=MAP_HEIGHT
            )
            self.map_caption = gui.add_markdown("")
        self.start_trace.on_click(self._act(self.start_trace, self._start_trace))
        self.end_trace.on_click(self._act(self.end_trace, self._end_trace, "learning"))
        self.cancel_trace.on_click(self._act(self.cancel_trace, self._cancel_trace))
        self.learn_now.on_click(self._act(self.learn_now, self._learn_now, "learning"))
        self.decline.on_click(self._act(self.decline, self._decline, "planning"))
        self.set_aside.on_click(self._act(self.set_aside, self._set_aside, "planning"))
        self.map_mode.on_update(lambda _: self._redraw_map())
        self.map_height.on_update(lambda _: self._redraw_map())
        if s.teaches:
            self._add_person(self.client.scene)

    def _add_person(self, scene) -> None:
        """A figure where the person of the ``human`` feature sits, across the table."""
        x, y, z = HUMAN_POSITION
        scene.add_box(
            "/person/body",
            color=PERSON_RGB,
            dimensions=(0.16, 0.36, 0.5),
            position=(x + 0.08, y, z - 0.1),
            material=MESH_MATERIAL,
            opacity=0.55,
        )
        scene.add_icosphere(
            "/person/head",
            radius=0.085,
            color=PERSON_RGB,
            position=(x + 0.08, y, z + 0.24),
            material=MESH_MATERIAL,
            opacity=0.55,
        )

    def _start_teaching(self) -> None:
        """The learner asks for traces: the correction controls step aside, the heat map of
        what it wants now, the teaching handle where the cup last was (or where a trace a
        crash cut short began), the instructions. A reload while recording goes on
        recording (the trace so far is the page's)."""
        s = self.session
        self.proposal = None
        going_on = self.teaching and self.recording and s.open_trace is not None
        self.teaching = True
        if not going_on:
            self.recording, self.trace_points, self.drag_points = False, [], []
        self.confirming = False
        self.teach_refused = False
        if s.lost_trace is not None and s.lost_trace.get("q") is not None:
            self.teach_q = np.asarray(s.lost_trace["q"], float)
        elif self.teach_q is None and s.traces:
            self.teach_q = np.asarray(s.traces[-1][-1], float)  # where the last trace ended
        elif self.teach_q is None:
            rows = s.log.corrections(s.id)
            last = rows[-1]["xi_h"] if rows else s.envs[0].q_start[None, :]
            self.teach_q = np.asarray(last[len(last) // 2], float)
        self.teach_env = s.envs[int(s.last_env if s.last_env is not None else 0)]
        client = self.client
        if client is None:
            return
        if self.handle is not None:  # the correction's handle goes (an invisible one still
            self.handle.remove()  # takes the mouse)
            self.handle = None
        self._teaching_layout(True)
        self._hide_paths()
        self._make_teach_handle()
        self._draw_trace()
        self._teach_title()
        self._show_belief()
        self._redraw_map()
        self._refresh()
        if going_on:
            self._say("Still recording: drag the cup on, then press **End the trace**.")
        elif s.lost_trace is not None:
            self._say(
                f"**Trace {s.lost_trace['index'] + 1} was cut short** when the robot's server "
                "stopped, and was not kept. The cup is back where it began: press **Start a "
                "trace here** to give it again. The traces before it are all kept."
            )
        else:
            self._say("Put the cup where what you mind is strongest, then press Start a trace.")

    def _teaching_layout(self, teaching: bool) -> None:
        """While teaching, the correction's controls and the preference step aside, so the
        teaching buttons are on the first screen; back after."""
        for control in (
            self.waypoint,
            self.play,
            self.submit_button,
            self.reset_button,
            self.skip_button,
        ):
            control.visible = not teaching
        self.done_button.visible = not teaching and self._done_shown
        self.preference_folder.visible = not teaching
        self.where.visible = not teaching
        self.teach_folder.visible = teaching

    def _hide_paths(self) -> None:
        scene = self.client.scene
        for name in ("/plan/path", "/correction/path", "/deploy/plain", "/deploy/averse"):
            scene.add_spline_catmull_rom(name, np.zeros((2, 3)), visible=False)
        scene.add_point_cloud("/plan/waypoints", np.zeros((1, 3)), colors=(0, 0, 0), visible=False)

    def _teach_title(self) -> None:
        s = self.session
        given, left = len(s.traces), s.wanted - len(s.traces)
        fewest = s.fewest_traces
        stop = (
            f" You may stop after {fewest} (**Learn from the traces I gave**): fewer traces "
            "give me a rougher picture of what you mind."
            if fewest < s.wanted
            else ""
        )
        self.title.content = (
            "### Teach me what you mind\n"
            "Your corrections are not explained by what I know. You sit across the table from "
            "me (the grey figure). Show me what you mind with "
            f"**{s.wanted} {plural(s.wanted, 'trace')}** ({given} given, {left} to go): drag "
            "the cup to where what you mind is strongest, press **Start a trace here**, drag "
            "it to where it is weakest (as many drags as you like), press **End the trace**. "
            "Start each trace somewhere else, high and low." + stop
        )

    def _cup_handle(self, name: str, cup: np.ndarray):
        """Arrows at the cup ``cup`` (3,) that move it (no rotations, drawn over the scene)."""
        return self.client.scene.add_transform_controls(
            name, scale=HANDLE_SCALE, disable_rotations=True, depth_test=False, position=cup
        )

    def _make_teach_handle(self) -> None:
        self.teach_handle = self._cup_handle("/teach/handle", cup_pose(self.teach_q)[1])
        self.teach_handle.on_update(self._teach_moved)
        self._pose_arm(self.teach_q)

    def _teach_moved(self, event) -> None:
        """A teaching drag: while recording, the positions of a drag the arm can follow are
        the trace's; where a drag ends the arm follows (IK, the cup upright), or the cup goes
        back (and that drag's positions with it) if the arm cannot reach it."""
        with self._lock:
            if not self.teaching or self.client is None or self.teach_handle is None:
                return
            if event.target is not self.teach_handle:
                return  # a late event of a handle this page has replaced
            position = np.array(self.teach_handle.position, float)
            if self.recording:
                last = self.drag_points[-1] if self.drag_points else self.trace_points[-1]
                if np.linalg.norm(position - last) >= TRACE_STEP:
                    self.drag_points.append(position)
            if event.phase != "end":
                return
            q = cup_inverse_kinematics(position, cup_pose(self.teach_q)[0], self.teach_q)
            if q is None:
                self.teach_refused = True
                self.drag_points = []
                self._say(
                    "**Out of reach**: the arm cannot hold the cup there, so it went back. "
                    "Try somewhere nearer."
                )
                self._make_teach_handle()
            else:
                self.teach_refused = False
                self.teach_q = q
                self._pose_arm(q)
                if self.recording:
                    self.trace_points += self.drag_points
                    if np.linalg.norm(position - self.trace_points[-1]) > 1e-9:
                        self.trace_points.append(position)
                    self.drag_points = []
                    self._draw_trace()
                    self._say("Recording: drag on, or press **End the trace** when it is done.")
                else:
                    self._say("The cup is here. Press **Start a trace here**, or move it again.")
            self.teach_moves += 1
            self._refresh()

    def _draw_trace(self) -> None:
        """The trace recorded so far, as a line (hidden when there is none)."""
        points = np.array(self.trace_points) if self.recording else np.zeros((0, 3))
        shown = points.shape[0] >= 2
        self.client.scene.add_spline_catmull_rom(
            "/teach/trace",
            points if shown else np.zeros((2, 3)),
            thickness=4.0,
            thickness_units="screen",
            color=CORRECTION_RGB,
            visible=shown,
        )

    def _start_trace(self) -> None:
        """Start where the arm holds the cup, if that is where the page shows it."""
        s = self.session
        cup = cup_pose(self.teach_q)[1]
        shown = np.array(self.teach_handle.position, float)
        if self.teach_refused:
            self.starts_refused += 1
            self._say(
                "**Not started**: your last drag went where the arm cannot hold the cup, so the "
                "cup went back. Move it to where you want the trace to begin, then press Start."
            )
            return
        if np.linalg.norm(shown - cup) > START_TOLERANCE:
            self.starts_refused += 1
            self._say(
                "**Not started yet**: I am still checking that the arm can hold the cup where "
                "you put it. Press Start again in a moment."
            )
            return
        try:
            s.start_trace(
                {"cup": cup.tolist(), "shown": shown.tolist(), "q": self.teach_q.tolist()}
            )
        except Refused as exc:
            self._say(f"**Refused**: {exc}.")
            return
        self.recording = True
        self.trace_start_q = self.teach_q.copy()
        self.trace_points, self.drag_points = [cup], []
        self._draw_trace()
        self._say(
            "Recording: drag the cup to where what you mind is weakest. **End the trace** "
            "works once the cup has moved; **Cancel this trace** drops it."
        )

    def _cancel_trace(self) -> None:
        self.session.cancel_trace()
        self.recording, self.trace_points, self.drag_points = False, [], []
        self._draw_trace()
        self._say("Trace cancelled; nothing of it was kept. Start another when you are ready.")

    def _end_trace(self) -> None:
        s = self.session
        points = resample_path(np.array(self.trace_points), TRACE_STATES)
        configurations, q = [self.trace_start_q], self.trace_start_q
        rotation = cup_pose(self.trace_start_q)[0]
        for point in points[1:]:
            found = cup_inverse_kinematics(point, rotation, q)
            if found is not None:
                configurations.append(found)
                q = found
        try:
            left = s.add_trace(np.array(configurations), {"cup_path": points.tolist()})
        except Refused as exc:
            self._say(f"**Not kept**: {exc}. Move the cup farther, or cancel the trace.")
            return
        self.recording, self.trace_points, self.drag_points = False, [], []
        self._draw_trace()
        self.traces_taken += 1
        if left:
            self._teach_title()
            self._say(f"Trace {len(s.traces)} kept. {left} more, please, each from somewhere else.")
            return
        self._learn(stop=False)

    def _learn_now(self) -> None:
        self._learn(stop=True)

    def _learn(self, *, stop: bool) -> None:
        s = self.session
        given = len(s.traces)
        self._say(f"Learning what you mind from your {given} {plural(given, 'trace')}…")
        try:
            s.learn_feature(stop=stop)
        except Refused as exc:
            self._say(f"**Refused**: {exc}")
            return
        self._finish_teaching(
            f"Learnt from your {given} {plural(given, 'trace')}. The next plan takes it into "
            "account; your corrections now teach me how much to avoid it. To see what I "
            f"learnt, choose **{MAP_SHAPE}** under the heat map."
        )

    def _finish_teaching(self, said: str) -> None:
        self.teaching = self.recording = self.confirming = False
        self.trace_points, self.drag_points = [], []
        if self.teach_handle is not None:
            self.teach_handle.remove()
            self.teach_handle = None
        self._draw_trace()
        self.set_aside.visible = False
        self._teaching_layout(False)
        self._new_proposal()
        self._say(said)

    def _decline(self) -> None:
        """Nobody will teach: at once if no trace was given; else the page asks first."""
        s = self.session
        given = len(s.traces)
        if given == 0:
            s.decline_traces()
            self._finish_teaching("Understood: I will not ask again. Back to correcting.")
            return
        self.confirming = True
        self.set_aside.visible = True
        learn = (
            "**Learn from the traces I gave**"
            if given >= s.fewest_traces
            else f"give {s.fewest_traces - given} more and learn from them"
        )
        self._say(
            f"You gave {given} {plural(given, 'trace')}. Press **Set my traces aside** to stop "
            "teaching without them (they stay in the record; I do not learn from them and "
            f"will not ask again), or {learn}, or go on teaching."
        )

    def _set_aside(self) -> None:
        given = self.session.decline_traces()
        self._finish_teaching(
            f"Your {given} {plural(given, 'trace')} {'is' if given == 1 else 'are'} set aside "
            "(kept in the record, not learnt from). I will not ask again. Back to correcting."
        )

    # --- the heat map ----------------------------------------------------------------------

    def _map_env(self):
        return self.proposal.env if self.proposal is not None else self.teach_env

    def _redraw_map(self) -> None:
        """The heat map as its controls say, on the current environment's table (see the
        module): a reload, a resume, a new plan and a change of its controls redraw it."""
        with self._lock:
            if self.client is None or self.closed or not self.session.teaches:
                return
            env = self._map_env()
            if env is None:
                return
            mode = self.map_mode.value
            s = self.session
            scene = self.client.scene
            if mode == MAP_OFF or (mode == MAP_SHAPE and not s.belief.extra):
                scene.add_point_cloud(
                    "/teach/map", np.zeros((1, 3)), colors=(0, 0, 0), visible=False
                )
                self.map_caption.content = (
                    "Nothing is learnt from you yet: there is no shape to show."
                    if mode == MAP_SHAPE
                    else "No heat map."
                )
                return
            plan = None if self.proposal is None else self.proposal.plan.trajectory
            q = self.teach_q if self.teaching or plan is None else plan[0]
            if q is None:
                return
            rotation = cup_pose(q)[0]
            height = float(self.map_height.value)
            if mode == MAP_SHAPE:
                points, phi = map_features(env, s.belief.extra[-1:], rotation, height)
                colours = shape_colours(phi[0])
                drawn = np.ones(len(points), bool)
                caption = (
                    "**What you showed me**: purple where it is strongest (where your traces "
                    "began), white where it is weakest. This is its shape, not yet what I do "
                    "about it: how much I keep the cup from it, your next corrections teach me."
                )
            else:
                points, phi = map_features(env, s.features, rotation, height)
                cov = s.belief.cov if s.has_covariance else None
                colours, drawn = want_colours(s.belief.theta, cov, phi)
                caption = (
                    "**What I want now** on this table, with the cup at each point: blue where "
                    "I would rather have it than elsewhere on the table, red where I would "
                    "rather not."
                )
                unsure = 1.0 - drawn.mean()
                if cov is not None and unsure == 1.0:
                    caption += " I cannot tell yet where on this table: nothing is drawn."
                elif cov is not None:
                    caption += (
                        " The deeper the colour, the surer I am; where nothing is drawn "
                        f"({100 * unsure:.0f}% of the table) I cannot tell yet."
                    )
            drawn &= off_laptop(points, env)
            # Drawn on the table top, out of the hand's way: what it shows is the cup's.
            self.map_points = points[drawn] * [1, 1, 0] + [0, 0, g.TABLE_TOP_Z + 0.004]
            self.map_colours = colours[drawn]
            if drawn.any():
                scene.add_mesh_trimesh("/teach/map", map_tiles(self.map_points, self.map_colours))
            else:  # nothing to draw: an empty map, not a stale one
                scene.add_point_cloud(
                    "/teach/map", np.zeros((1, 3)), colors=(0, 0, 0), visible=False
                )
            self.map_caption.content = (
                caption + f" Computed with the cup {height:.2f} m above the table; it changes "
                "with height (the slider)."
            )
