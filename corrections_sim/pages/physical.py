"""The page of a physical session: the person pushes the cup while the arm moves.

"Play" runs the plan under joint impedance on the server
(:class:`~corrections_sim.people.physical.PushedMotion`: 1 kHz physics, a look every 10 ms of
simulated time, paced to ``speed`` × real time) and sends the arm's pose to the page at
:data:`FRAME_RATE`. The person grabs the cup's handle and drags it: the hand holds the cup
where the cup was at the grab and moves that hold as the handle moves (a clutch, as MuJoCo's
viewer perturbs a body), pulling the cup through a spring of ``stiffness`` N/m whose force is
capped at ``force_cap`` N and drawn as a red line from the cup; the arm yields under
impedance. When the robot finds the push over, the session learns from the deformation and
logs the push before the page changes
(:meth:`~corrections_sim.session.session.Session.submit_push`), the rest of the motion is
replanned from where the arm is and played, and the page shows the deformed path (orange) and
the new one (green). A person still holding on when the motion ends has pushed: the end is the
release. When the motion ends the next plan is shown.

The handle waits where the motion started, on the cup, and does not chase it (a thin grey
line shows what it holds): a gizmo that moves is missed by a hand that reaches for where it
was drawn (18 of 18 grabs made with a pointer during a motion, when it trailed the cup), and
moving it under a pointer that holds it loses the grab. With the clutch, where the handle is
grabbed does not change the push.

During a motion only the handle works: Play, Skip and Done are disabled (the page says so)
and refused if a click crosses that; they come back when the motion ends.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from corrections_sim.pages.drawing import CORRECTION_RGB, HANDLE_SCALE, PLAN_RGB, draw_path
from corrections_sim.pages.page import SKIP, SKIP_BLIND, Page, relevance_note
from corrections_sim.people.physical import spring_force
from corrections_sim.scene.robot import cup_pose
from corrections_sim.session.session import Refused, Session

#: Arm poses sent to the page per second of real time during a motion (a little over 30, so
#: that at least 30 arrive whatever the rounding of the looks).
FRAME_RATE = 32.0
REST_RGB = (30, 160, 80)
FORCE_RGB = (220, 30, 30)
#: The line from the waiting handle to the cup it holds, redrawn every this many frames (each
#: redraw is a new line on the page, which chromium's software WebGL pays for).
TETHER_RGB = (120, 120, 120)
TETHER_EVERY = 4
#: Metres of the drawn force line per newton.
FORCE_SCALE = 0.006


class PhysicalPage(Page):
    """A physical session's page (see the module).

    Args:
        speed: simulated seconds per real second, in (0, 1].
        stiffness: the handle's spring, N/m.
        force_cap: the largest force the handle applies, N.
        duration: how long a plan takes, s (simulated).
    """

    def __init__(
        self,
        server,
        session: Session,
        *,
        speed: float = 1.0,
        stiffness: float = 300.0,
        force_cap: float = 30.0,
        duration: float = 5.0,
        **options,
    ) -> None:
        self.speed = float(speed)
        self.stiffness = float(stiffness)
        self.force_cap = float(force_cap)
        self.duration = float(duration)
        self.grab: np.ndarray | None = None  # where the person holds the handle, or None
        self._grabbed_at: np.ndarray | None = None  # the handle where the grab began
        self._rest_cup = np.zeros(3)  # where the handle sits when the arm is at rest
        self._hold: np.ndarray | None = None  # the cup where the grab began
        self.grabs = 0  # grabs of the handle that reached the server (tests count them)
        self.motion = None
        self.pushes = 0  # pushes learnt through this page (tests wait on it)
        self.frames = 0  # arm poses sent during motions
        self.last_push = (float("nan"), float("nan"))  # release found, new path on the page
        self.max_force = 0.0
        self._runner: threading.Thread | None = None
        self._hand = threading.Lock()  # the grab's state, shared with viser's event loop
        self._in_motion = False
        self._force_shown = False
        self._force_line = None
        super().__init__(server, session, **options)

    def settle(self, timeout: float | None = None) -> bool:
        """Wait until the motion running on the server has ended (a push it had is learnt
        and logged), at most ``timeout`` seconds (default: the motion's length and a minute to
        learn); whether it has. Call it before closing the session's log."""
        runner = self._runner
        if runner is None:
            return True
        runner.join(timeout=self.duration / self.speed + 60.0 if timeout is None else timeout)
        return not runner.is_alive()

    def _connect(self, client) -> None:
        runner = self._runner
        if runner is not None and runner.is_alive() and self.owner is None:
            # A tab (re)connected during a motion whose page was closed: the motion plays out
            # on the server (a push it had is learnt and logged); this page starts after it.
            self.settle()
        super()._connect(client)

    def _build(self, client) -> None:
        self.client = client
        scene, gui = client.scene, client.gui
        self._add_meshes(scene)
        self._add_texts(gui)
        self.sliders = []  # the stated preference only where a study asks for it
        if self.require_stated:
            self._add_preference(gui)
        self.play = gui.add_button("Play: push the cup while it moves", disabled=True)
        self.skip_button = gui.add_button(SKIP_BLIND if self.blind else SKIP, disabled=True)
        self.done_button = self._add_done(gui)
        self.submit_button = gui.add_button("Submit correction", visible=False, disabled=True)
        self._add_belief_panel(gui)
        self.play.on_click(self._act(self.play, self._start))
        self.skip_button.on_click(self._act(self.skip_button, self._skip, "planning"))
        self.done_button.on_click(self._act(self.done_button, self._done, "deploying"))
        self._first_view()

    def _controls(self) -> list[tuple]:
        s = self.session
        ready = self.proposal is not None and not s.ended and not self._busy
        ready = ready and not self._in_motion
        stated = self.stated is not None or not self.require_stated
        enough = s.iteration >= self.minimum or self.limit is None
        first = ready and s.iteration == 0
        preference = []
        if self.sliders:  # a study's page, which asks for the stated preference
            preference = [(self.state_button, first), *((x, first) for x in self.sliders)]
        return [
            *preference,
            (self.play, ready and stated),
            (self.skip_button, ready),
            (self.done_button, ready and enough),
        ]

    def _new_proposal(self) -> None:
        s = self.session
        self.proposal = s.proposal()
        plan = self.proposal.plan.trajectory
        client = self.client
        if client is None:
            return  # the tab closed: the next one draws it
        scene = client.scene
        draw_path(scene, "/plan/path", plan, PLAN_RGB)
        for name in ("/correction/path", "/rest/path", "/deploy/plain", "/deploy/averse"):
            scene.add_spline_catmull_rom(name, np.zeros((2, 3)), visible=False)
        self._clear_lines()
        cup = cup_pose(plan[0])[1]
        self._rest_cup = cup
        self.handle = scene.add_transform_controls(
            "/handle", scale=HANDLE_SCALE, disable_rotations=True, depth_test=False, position=cup
        )
        self.handle.on_update(self._grabbed)
        self._let_go()
        self._pose_arm(plan[0])
        self.where.content = ""  # the last push's time and force belong to the last plan
        if self.blind:
            of = "" if self.limit is None else f" of {self.limit}"
            head = f"### Push {s.iteration + 1}{of}\n{self._first_line()}"
        else:
            head = (
                f"### Push {s.iteration + 1}: environment {self.proposal.env.name}\n"
                f"Learner **{s.learner}**. "
            )
        self.title.content = (
            head + "Press Play; while the arm moves, drag the arrows of the "
            f"cup's handle to push the cup (a spring, at most {self.force_cap:.0f} N); let go "
            "and the robot learns and replans." + self._ask_line()
        )
        self._show_belief()
        self._refresh()
        self._say("The robot's plan is the blue path.")

    # --- the person's hand -----------------------------------------------------------------

    async def _grabbed(self, event) -> None:
        """The handle: grabbed at the drag's start (the hold begins where the cup is then),
        held while dragged, let go at the drag's end. A non-finite position is no hold.
        Async, so that viser runs the phases in order (threadpool callbacks may run an update
        after the end: a hand that never lets go)."""
        position = np.asarray(event.target.position, dtype=float)
        finite = position.shape == (3,) and bool(np.all(np.isfinite(position)))
        with self._hand:
            if event.phase == "end" or not finite:
                self.grab = self._grabbed_at = self._hold = None
                if not self._in_motion and self.client is not None:
                    # At rest nothing moves the cup: the handle goes back on it.
                    self.handle.position = self._rest_cup
                return
            motion = self.motion if self._in_motion else None
            if event.phase == "start" or self._grabbed_at is None:
                self.grabs += 1
                self._grabbed_at = position
                self._hold = None if motion is None else motion.cup()
            if self._hold is None:  # at rest nothing moves the cup: the handle is let go
                self.grab = None
                return
            self.grab = position

    def hand_force(self, cup: np.ndarray) -> np.ndarray | None:
        """The handle's spring force on the cup (3,), N, capped; None when nobody holds it.
        The hand holds the cup where it was at the grab, moved as far as the handle since."""
        with self._hand:
            if self.grab is None or self._hold is None:
                return None
            target = self._hold + (self.grab - self._grabbed_at)
        return spring_force(cup, target, self.stiffness, self.force_cap)

    def _let_go(self) -> None:
        with self._hand:
            self.grab = self._grabbed_at = self._hold = None

    # --- the motion ------------------------------------------------------------------------

    def _start(self) -> None:
        if self._runner is not None and self._runner.is_alive():
            return
        self._in_motion = True
        self.motion = None  # the new motion's, once it is made
        self._refresh()
        self._runner = threading.Thread(target=self._run, name="physics", daemon=True)
        self._runner.start()

    def _run(self) -> None:
        try:
            self._play_motion()
        except Refused as exc:
            self._say(f"**Refused**: {exc}")
        except Exception as exc:  # the page says what broke; the log keeps what was confirmed
            self._say(f"**Error**: {type(exc).__name__}: {str(exc).splitlines()[0]}")
            raise
        finally:
            with self._lock:
                self._in_motion = False
                self._let_go()
                self._refresh()

    def _play_motion(self) -> None:
        s = self.session
        # A look every 1/(2 FRAME_RATE) s of real time at most, so a slow motion is shown
        # smoothly (10 steps at real time, fewer when slower).
        steps = max(1, min(10, int(1000 * self.speed / (2 * FRAME_RATE))))
        motion = s.motion(self.duration, look_steps=steps)
        with self._lock:
            self.motion = motion
        start = time.perf_counter()
        next_frame = start
        learnt = None
        self._say(
            "Playing. Push the cup by dragging the arrows of its handle. Skip and Done come "
            "back when the motion ends."
        )
        while not motion.done:
            force = self.hand_force(motion.cup())
            if force is not None:
                self.max_force = max(self.max_force, float(np.linalg.norm(force)))
            if motion.look(force):
                found = time.perf_counter()
                learnt = self._learn(motion)
                self.last_push = (found, time.perf_counter())
            now = time.perf_counter()
            if now >= next_frame:
                self._show_motion(motion, force)
                # On a schedule, not "a frame period after this one": frames go out with
                # looks, so that would round every period up to a whole number of looks.
                next_frame = max(next_frame + 1.0 / FRAME_RATE, now - 1.0 / FRAME_RATE)
            # Pace: simulated time over speed is the real time it should have taken.
            ahead = start + motion.time / self.speed - time.perf_counter()
            if ahead > 0:
                time.sleep(ahead)
        if learnt is None and motion.hold_to_the_end():
            # Still held when the motion ended: the person pushed, and the end is the release.
            found = time.perf_counter()
            learnt = self._learn(motion)
            self.last_push = (found, time.perf_counter())
        self._show_motion(motion, None)
        if self.client is None:
            return  # the tab closed: a new one shows the next plan
        if learnt is None:
            self._put_handle(motion.cup())
            self.where.content = ""
            self._say("No push was felt. Play again, or skip this environment.")
            return
        if self.limit is not None and self.session.iteration >= self.limit:
            self._done()  # a study's trial has its pushes
            return
        self._new_proposal()
        self._say(
            f"Push {learnt['iteration'] + 1} learnt (peak {learnt['drag']['peak_force']:.1f} N, "
            f"{learnt['drag']['push_time']:.2f} s). The next plan is blue."
        )

    def _learn(self, motion) -> dict:
        """The push is over: learn and log it, replan the rest (if the motion goes on), show
        both paths."""
        s = self.session
        self._let_go()
        row = s.submit_push(motion, speed=self.speed)
        plan = None
        if not motion.done:
            plan = s.replan(motion.q(), motion.time, row["iteration"])
            if plan is not None:
                motion.switch(plan, keep=False)
        self.pushes += 1
        client = self.client
        if client is None:
            return row
        scene = client.scene
        draw_path(scene, "/correction/path", row["xi_h"], CORRECTION_RGB)
        if plan is not None:
            draw_path(scene, "/rest/path", motion.reference.waypoints, REST_RGB)
        self._show_belief()
        if motion.done:
            replanned = "held to the end of the motion"
        else:
            replanned = "the rest replanned (green)" if plan is not None else "no new plan found"
        note = relevance_note(row)
        self._say(f"Push felt and learnt{note}: the deformed path is orange, {replanned}.")
        return row

    def _put_handle(self, cup: np.ndarray) -> None:
        with self._hand:
            self._rest_cup = np.asarray(cup, float)
            if self.grab is None and self.client is not None:
                self.handle.position = cup

    def _clear_lines(self) -> None:
        if self._force_shown:
            self._force_line.remove()
            self._force_shown = False
        client = self.client
        if client is not None:
            client.scene.add_line_segments(
                "/tether", np.zeros((1, 2, 3)), colors=TETHER_RGB, visible=False
            )

    def _show_motion(self, motion, force) -> None:
        """The arm's pose now; the force line while pushed (removed once, when let go), else
        the tether from the waiting handle to the cup; the time and force in words."""
        client = self.client
        if client is None:
            return
        cup = motion.cup()
        self._pose_arm(motion.q(), moving_only=True)
        self.frames += 1
        scene = client.scene
        if force is None:
            if self._force_shown:
                self._force_line.remove()
                self._force_shown = False
            if self.frames % TETHER_EVERY == 1:
                handle = np.asarray(self.handle.position, float)
                scene.add_line_segments(
                    "/tether",
                    np.array([[handle, cup]]),
                    colors=TETHER_RGB,
                    thickness=1.5,
                    thickness_units="screen",
                )
        else:
            tip = cup + FORCE_SCALE * force
            self._force_line = scene.add_line_segments(
                "/force",
                np.array([[cup, tip]]),
                colors=FORCE_RGB,
                thickness=6.0,
                thickness_units="screen",
            )
            self._force_shown = True
        if motion.done:
            self._clear_lines()
        if self.frames % 5 == 0 or force is not None:
            self.where.content = (
                f"t = {motion.time:.2f} s · cup ({cup[0]:.2f}, {cup[1]:.2f}, {cup[2]:.2f}) m"
                + (f" · force {np.linalg.norm(force):.1f} N" if force is not None else "")
            )
