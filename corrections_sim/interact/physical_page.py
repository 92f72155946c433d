"""The page of a physical session: the person pushes the cup while the arm moves.

"Play" runs the plan under joint impedance on the server
(:class:`~corrections_sim.people.physical.PushedMotion`: 1 kHz physics, a look every 10 ms of
simulated time, paced to ``speed`` × real time) and sends the arm's pose to the page at
:data:`FRAME_RATE`. The person grabs the handle on the cup and drags it: the handle pulls the
cup through a spring of ``stiffness`` N/m whose force is capped at ``force_cap`` N and drawn
as a red line from the cup; the arm yields under impedance. When the robot finds the push
over, the session learns from the deformation and logs the push before the page changes
(:meth:`~corrections_sim.interact.session.Session.submit_push`), the rest of the motion is
replanned from where the arm is and played, and the page shows the deformed path (orange) and
the new one (green). When the motion ends the next plan is shown.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from corrections_sim.interact.page import (
    CORRECTION_RGB,
    HANDLE_SCALE,
    PLAN_RGB,
    Page,
    cup_path,
    relevance_note,
)
from corrections_sim.interact.session import Refused, Session
from corrections_sim.people.physical import spring_force
from corrections_sim.scene.robot import cup_pose

#: Arm poses sent to the page per second of real time during a motion (a little over 30, so
#: that at least 30 arrive whatever the rounding of the looks).
FRAME_RATE = 32.0
REST_RGB = (30, 160, 80)
FORCE_RGB = (220, 30, 30)
#: The handle jumps back onto the cup when it is this far from it (m) and nobody holds it.
HANDLE_FOLLOW = 0.03
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
        on_done=None,
    ) -> None:
        self.speed = float(speed)
        self.stiffness = float(stiffness)
        self.force_cap = float(force_cap)
        self.duration = float(duration)
        self.grab: np.ndarray | None = None  # where the person holds the handle, or None
        self.motion = None
        self.pushes = 0  # pushes learnt through this page (tests wait on it)
        self.frames = 0  # arm poses sent during motions
        self.last_push = (float("nan"), float("nan"))  # release found, new path on the page
        self.max_force = 0.0
        self._runner: threading.Thread | None = None
        self._force_shown = False
        self._force_line = None
        super().__init__(server, session, on_done=on_done)

    def _build(self, client) -> None:
        self.client = client
        scene, gui = client.scene, client.gui
        self._add_meshes(scene)
        self.title = gui.add_markdown("")
        self.status = gui.add_markdown("")
        self.where = gui.add_markdown("")
        self.play = gui.add_button("Play: push the cup while it moves")
        self.skip_button = gui.add_button("Skip this environment")
        self.done_button = gui.add_button("Done: deploy")
        self.submit_button = gui.add_button("Submit correction", visible=False, disabled=True)
        self._add_belief_panel(gui)
        self.play.on_click(lambda _: self._start())
        self.skip_button.on_click(lambda _: self._skip_physical())
        self.done_button.on_click(lambda _: self._done())
        self._new_proposal()

    def _new_proposal(self) -> None:
        s = self.session
        self.proposal = s.proposal()
        plan = self.proposal.plan.trajectory
        scene = self.client.scene
        scene.add_spline_catmull_rom(
            "/plan/path", cup_path(plan), thickness=3.0, thickness_units="screen", color=PLAN_RGB
        )
        for name in ("/correction/path", "/rest/path", "/deploy/plain", "/deploy/averse"):
            scene.add_spline_catmull_rom(name, np.zeros((2, 3)), visible=False)
        cup = cup_pose(plan[0])[1]
        self.handle = scene.add_transform_controls(
            "/handle", scale=HANDLE_SCALE, disable_rotations=True, depth_test=False, position=cup
        )
        self.handle.on_update(self._grabbed)
        self.grab = None
        self._pose_arm(plan[0])
        self.play.disabled = False
        self.skip_button.disabled = False
        self.title.content = (
            f"### Push {s.iteration + 1}: environment {self.proposal.env.name}\n"
            f"Learner **{s.learner}**. Press Play; while the arm moves, drag the arrows on the "
            f"cup to push it (a spring, at most {self.force_cap:.0f} N); let go and the robot "
            "learns and replans."
        )
        self._show_belief()
        self._say("The robot's plan is the blue path.")

    # --- the person's hand -----------------------------------------------------------------

    async def _grabbed(self, event) -> None:
        """The handle: held while dragged (its position is where the hand is), let go at the
        drag's end. A non-finite position is no hold. Async, so that viser runs the phases in
        order (threadpool callbacks may run an update after the end: a hand that never lets
        go)."""
        position = np.asarray(event.target.position, dtype=float)
        with self._lock:
            if event.phase == "end" or position.shape != (3,) or not np.all(np.isfinite(position)):
                self.grab = None
            else:
                self.grab = position

    def hand_force(self, cup: np.ndarray) -> np.ndarray | None:
        """The handle's spring force on the cup (3,), N, capped; None when nobody holds it."""
        with self._lock:
            grab = self.grab
        if grab is None:
            return None
        return spring_force(cup, grab, self.stiffness, self.force_cap)

    # --- the motion ------------------------------------------------------------------------

    def _start(self) -> None:
        with self._lock:
            if self._runner is not None and self._runner.is_alive():
                return
            self.play.disabled = True
            self.skip_button.disabled = True
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
            self.play.disabled = False
            self.skip_button.disabled = False

    def _play_motion(self) -> None:
        s = self.session
        # A look every 1/(2 FRAME_RATE) s of real time at most, so a slow motion is shown
        # smoothly (10 steps at real time, fewer when slower).
        steps = max(1, min(10, int(1000 * self.speed / (2 * FRAME_RATE))))
        motion = s.motion(self.duration, look_steps=steps)
        self.motion = motion
        start = time.perf_counter()
        next_frame = start
        learnt = None
        self._say("Playing. Push the cup by dragging the arrows on it.")
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
        self._show_motion(motion, None)
        if learnt is None:
            self._say("No push was felt. Play again, or skip this environment.")
            return
        self._new_proposal()
        self._say(
            f"Push {learnt['iteration'] + 1} learnt (peak {learnt['drag']['peak_force']:.1f} N, "
            f"{learnt['drag']['push_time']:.2f} s). The next plan is blue."
        )

    def _learn(self, motion) -> dict:
        """The push is over: learn and log it, replan the rest, show both paths."""
        s = self.session
        with self._lock:
            self.grab = None
        row = s.submit_push(motion, speed=self.speed)
        plan = s.replan(motion.q(), motion.time, row["iteration"])
        if plan is not None:
            motion.switch(plan, keep=False)
        scene = self.client.scene
        scene.add_spline_catmull_rom(
            "/correction/path",
            cup_path(row["xi_h"]),
            thickness=3.0,
            thickness_units="screen",
            color=CORRECTION_RGB,
        )
        if plan is not None:
            scene.add_spline_catmull_rom(
                "/rest/path",
                cup_path(motion.reference.waypoints),
                thickness=3.0,
                thickness_units="screen",
                color=REST_RGB,
            )
        self.pushes += 1
        self._show_belief()
        replanned = "the rest replanned (green)" if plan is not None else "no new plan found"
        note = relevance_note(row)
        self._say(f"Push felt and learnt{note}: the deformed path is orange, {replanned}.")
        return row

    def _show_motion(self, motion, force) -> None:
        """The arm's pose now; the force line while pushed (removed once, when let go); the
        handle back on the cup when it has fallen behind; the time and force in words."""
        cup = motion.cup()
        self._pose_arm(motion.q(), moving_only=True)
        self.frames += 1
        scene = self.client.scene
        if force is None:
            if self._force_shown:
                self._force_line.remove()
                self._force_shown = False
            with self._lock:
                # The handle follows the cup in steps, not every frame: a gizmo moved under
                # the mouse while it is being grabbed loses the grab.
                far = np.linalg.norm(np.asarray(self.handle.position) - cup) > HANDLE_FOLLOW
                if self.grab is None and far:
                    self.handle.position = cup
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
        if self.frames % 5 == 0 or force is not None:
            self.where.content = (
                f"t = {motion.time:.2f} s · cup ({cup[0]:.2f}, {cup[1]:.2f}, {cup[2]:.2f}) m"
                + (f" · force {np.linalg.norm(force):.1f} N" if force is not None else "")
            )

    def _skip_physical(self) -> None:
        with self._lock:
            if self._runner is not None and self._runner.is_alive():
                return
            self.session.skip()
            self._new_proposal()
