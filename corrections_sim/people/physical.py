"""Physical corrections: a person pushes the cup while the arm moves under impedance control.

The paper's person corrects "using physical human-robot interaction or a virtual interface"
(§1). Here the physical one (Bajcsy et al., CoRL 2017; Losey & O'Malley, T-RO 2018; Losey et
al., IJRR 2022), on the dynamics of :mod:`corrections_sim.scene.dynamics`:

1. The robot plays its plan ξ_R, timed over ``duration`` seconds, under joint impedance.
2. :class:`PhysicalUser` ("physical") watches: where the cup of ξ_R is farthest from where its
   own plan ξ*(θ*, E) would have it (waypoint i, in metres), it pushes the cup toward its own
   plan's cup, ``hold`` seconds centred on t_i (no earlier than ``reaction_delay``), through a
   hand spring of ``stiffness`` N/m whose force is capped at ``force_cap`` N, ramped in and
   out over ``ramp`` s, with optional force noise; then it lets go. Its effort, ∫‖F‖ dt, and
   the time in contact are recorded.
3. The robot senses the interaction torque τ_h from its own model (never the force it was
   given), finds the push where ‖τ_h‖ exceeds ``detect`` N·m, turns it into where it was held,
   Ũ_j = K⁻¹ τ̄_h,j at each waypoint j the push overlapped (τ̄ the mean over the push's samples
   nearest t_j; K⁻¹τ is how far the impedance yields to τ), and deforms its trajectory,
   ξ_H = ξ_R + μ A⁻¹ Ũ (:func:`~corrections_sim.people.corrections.held_deformation`).
   Learners see Φ(ξ_H).
4. Online (the IJRR 2022 setting), when the robot finds the push over it hands ξ_H to a
   ``replan`` callback (the study loop: the learner updates and the planner plans ξ*(θ̂, E)
   anew) and follows the new plan for the rest of the motion, joining it from where the arm is
   meant to be at the same point of its timing; the motion it would have made on the old plan is
   simulated too, from the same state, so the two are compared paired.

:class:`PhysicalCorrection` ("physical", a correction model) is the robot's model of what such
a push does, for the correction-aware learners: the same hand spring against the same
impedance, at equilibrium (quasi-static), at the worst waypoint and the ``span`` waypoints on
each side, deformed the same way.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from corrections_sim.components import ParameterError
from corrections_sim.people.corrections import (
    CorrectionModel,
    held_deformation,
    register_correction,
)
from corrections_sim.people.users import Situation, TaskOutcome, User, register_user
from corrections_sim.planning.features import feature_counts
from corrections_sim.scene import dynamics
from corrections_sim.scene.environments import Environment

#: The person looks and pushes at this rate (their force is held between looks), Hz.
PERSON_RATE = 100
#: After the sensed torque falls below the threshold, the robot waits this long before it
#: takes the push as over, s.
RELEASE_WAIT = 0.05

#: replan(ξ_H (T, 7), q_now (7,), t_now) -> the new plan of the whole task (T, 7), which the
#: arm joins from where it is, or None (the old plan goes on).
Replan = Callable[[np.ndarray, np.ndarray, float], "np.ndarray | None"]


def _positive(name: str, value, *, zero: bool = False) -> float:
    number = isinstance(value, int | float | np.number) and not isinstance(value, bool)
    if not (number and np.isfinite(value) and (value >= 0 if zero else value > 0)):
        raise ParameterError(name, f"must be finite and {'>= 0' if zero else '> 0'}, got {value!r}")
    return float(value)


def worst_cup_waypoint(robot: np.ndarray, intended: np.ndarray) -> tuple[int, np.ndarray]:
    """The free waypoint where the cups of ``robot`` and ``intended`` (T, 7) are farthest apart
    (ties to the lower index), and the intended cup path (T, 3)."""
    mine, _ = dynamics.cup_kinematics(robot)
    theirs, _ = dynamics.cup_kinematics(intended)
    gaps = np.linalg.norm(theirs - mine, axis=1)
    gaps[[0, -1]] = -np.inf
    return int(np.argmax(gaps)), theirs


def spring_force(cup: np.ndarray, target: np.ndarray, stiffness: float, cap: float) -> np.ndarray:
    """The hand spring's force (3,), N: stiffness · (target − cup), its norm capped at ``cap``."""
    force = stiffness * (np.asarray(target, float) - np.asarray(cup, float))
    return cap_force(force, cap)


def cap_force(force: np.ndarray, cap: float) -> np.ndarray:
    """``force`` (3,) scaled down to norm ``cap`` if it is larger; a non-finite force is none."""
    force = np.asarray(force, dtype=float)
    if not np.all(np.isfinite(force)):
        return np.zeros(3)
    norm = float(np.linalg.norm(force))
    return force * (cap / norm) if norm > cap else force


def quasi_static_hold(
    q: np.ndarray, target: np.ndarray, stiffness: float, cap: float, joint_stiffness: np.ndarray
) -> np.ndarray:
    """Where a hand spring toward ``target`` (3,) holds an arm at ``q`` (7,) under joint
    stiffness K (7,): Δq (7,) with K Δq = Jᵀ F and F = stiffness · (target − x − J Δq),
    |F| ≤ cap (linearized at q; the cap scales F down and Δq with it)."""
    (x,), (jac,) = dynamics.cup_kinematics(q[None])
    compliance = jac / joint_stiffness[None, :]  # J K⁻¹ (3, 7)
    gap = np.asarray(target, float) - x
    # (I + s J K⁻¹ Jᵀ) F = s · gap
    force = np.linalg.solve(np.eye(3) + stiffness * compliance @ jac.T, stiffness * gap)
    force = cap_force(force, cap)
    return (jac.T @ force) / joint_stiffness


@register_correction("physical")
@dataclass(frozen=True)
class PhysicalCorrection(CorrectionModel):
    """A push at the cup toward ξ*'s cup where the two cups are farthest apart (waypoint i), held
    at waypoints i − span … i + span, the arm yielding under joint impedance; the trajectory
    deformed by :func:`~corrections_sim.people.corrections.held_deformation`.

    Attributes:
        stiffness: the person's hand spring, N/m.
        force_cap: the largest force the person uses, N.
        span: waypoints held on each side of the worst one (a push lasts about
            (2 span + 1) waypoint intervals).
    """

    stiffness: float = 300.0
    force_cap: float = 30.0
    span: int = 1

    def __post_init__(self) -> None:
        _positive("stiffness", self.stiffness)
        _positive("force_cap", self.force_cap)
        if isinstance(self.span, bool) or not isinstance(self.span, int | np.integer):
            raise ParameterError("span", f"must be an integer, got {self.span!r}")
        if self.span < 0:
            raise ParameterError("span", f"must be >= 0, got {self.span}")

    def apply(self, robot: np.ndarray, intended: np.ndarray) -> np.ndarray:
        robot = np.asarray(robot, dtype=float)
        i, theirs = worst_cup_waypoint(robot, intended)
        held = np.zeros_like(robot)
        stiff = dynamics.Impedance().stiffness
        for j in range(max(1, i - self.span), min(robot.shape[0] - 1, i + self.span + 1)):
            held[j] = quasi_static_hold(robot[j], theirs[j], self.stiffness, self.force_cap, stiff)
        return held_deformation(robot, held)


@dataclass(frozen=True, eq=False)
class PushTrace:
    """A physical task sampled at the person's rate (one row per look).

    Attributes:
        times: (n,) s. cup: (n, 3) m. force: the person's force (n, 3), N.
        tau_sensed: the robot's sensed τ_h (n, 7), N·m (NaN once the push is found over: no one
            learns from what it senses later). tau_applied: Jᵀ F (n, 7), N·m (the truth).
        q: measured joint positions (n, 7).
    """

    times: np.ndarray
    cup: np.ndarray
    force: np.ndarray
    tau_sensed: np.ndarray
    tau_applied: np.ndarray
    q: np.ndarray


@dataclass(frozen=True, eq=False)
class PhysicalOutcome(TaskOutcome):
    """:class:`~corrections_sim.people.users.TaskOutcome` of a push, with what it was made of.

    Attributes:
        held: Ũ (T, 7), where the robot found itself held. deformed: ξ_H (T, 7).
        trace: the task's trace at the person's rate.
    """

    held: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))
    deformed: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))
    trace: PushTrace | None = None


@register_user("physical")
@dataclass(frozen=True)
class PhysicalUser(User):
    """Pushes the cup toward its own plan while the arm moves (see the module docstring).

    Attributes:
        force_cap: the largest force it uses, N (a larger request is clamped to it).
        stiffness: its hand spring toward its plan's cup, N/m.
        reaction_delay: it pushes no earlier than this after the motion starts, s.
        hold: how long it pushes, s (ramps included).
        ramp: the force ramps in and out over this long (raised cosine), s.
        force_noise: σ of Gaussian noise on each force component, N, drawn per look.
        duration: how long the robot's plan takes, s.
        torque_noise: σ of the robot's joint-torque sensing noise, N·m.
        detect: the robot takes ‖τ_h‖ above this as a push, N·m.
    """

    force_cap: float = 30.0
    stiffness: float = 300.0
    reaction_delay: float = 0.3
    hold: float = 1.2
    ramp: float = 0.15
    force_noise: float = 0.0
    duration: float = 5.0
    torque_noise: float = 0.0
    detect: float = 1.0
    during_motion: ClassVar[bool] = True

    def __post_init__(self) -> None:
        for name in ("force_cap", "stiffness", "hold", "duration", "detect"):
            _positive(name, getattr(self, name))
        for name in ("reaction_delay", "ramp", "force_noise", "torque_noise"):
            _positive(name, getattr(self, name), zero=True)
        if 2 * self.ramp > self.hold:
            raise ParameterError(
                "ramp", f"{self.ramp} s: two ramps must fit in hold = {self.hold} s"
            )
        if self.reaction_delay + self.hold >= self.duration:
            raise ParameterError(
                "hold",
                f"reaction_delay + hold = {self.reaction_delay + self.hold} s must be shorter "
                f"than the motion (duration = {self.duration} s)",
            )

    @property
    def stochastic(self) -> bool:  # type: ignore[override]
        return self.force_noise > 0 or self.torque_noise > 0

    def model(self) -> PhysicalCorrection:
        """The correction model that describes this person to a learner (quasi-static)."""
        return PhysicalCorrection(self.stiffness, self.force_cap)

    def correct(self, situation: Situation, rng: np.random.Generator) -> np.ndarray:
        """ξ_H, (T, 7): the robot's deformation of its plan after the push."""
        return self.perform(situation, rng).deformed

    def correction_features(self, situation: Situation, rng: np.random.Generator) -> np.ndarray:
        return self.perform(situation, rng).phi_h

    def window(self, t_worst: float) -> tuple[float, float]:
        """The push's start and end, s, for the worst waypoint at ``t_worst``."""
        start = max(t_worst - self.hold / 2, self.reaction_delay)
        start = min(start, self.duration - self.hold)
        return start, start + self.hold

    def envelope(self, t: float, start: float, end: float) -> float:
        """The force's ramp in [0, 1] at time ``t``."""
        if t < start or t >= end:
            return 0.0
        if self.ramp == 0:
            return 1.0
        edge = min(t - start, end - t) / self.ramp
        return 1.0 if edge >= 1 else 0.5 - 0.5 * np.cos(np.pi * edge)

    def perform(
        self,
        situation: Situation,
        rng: np.random.Generator,
        replan: Replan | None = None,
        *,
        keep: bool = True,
    ) -> PhysicalOutcome:
        """Play the robot's plan, push, let go; see the module docstring. With ``replan``
        and ``keep``, the motion on the old plan is played too (``executed_kept``)."""
        return _perform(self, situation, rng, replan, keep)


#: Each thread's arms, one per sensing noise (see :func:`_simulation`).
_ARMS = threading.local()


def _simulation(torque_noise: float) -> dynamics.ArmSimulation:
    """This thread's arm (one per sensing noise), moved to each task's environment. One per
    thread, not per process: an ArmSimulation is not thread-safe, and a page's motion thread
    that outlives its tab (or a second participant's motion on a study server) stepped the
    arm another motion was using — a push felt where nobody pushed, and MuJoCo asking for a
    19 GB arena (seen in a full suite run). Each task resets the arm, so a thread's first arm
    and its reused one give the same motion."""
    from corrections_sim.scene.environments import paper_environments

    arms = vars(_ARMS).setdefault("arms", {})
    if torque_noise not in arms:
        arms[torque_noise] = dynamics.ArmSimulation(
            paper_environments()[0], torque_noise=torque_noise
        )
    return arms[torque_noise]


def _arm(env: Environment, torque_noise: float) -> dynamics.ArmSimulation:
    sim = _simulation(torque_noise)
    sim.move_to(env)
    return sim


class PushedMotion:
    """One task of a physical correction, a look (10 ms, 10 physics steps) at a time: the
    robot plays ``robot`` (T, 7) over ``duration`` s in ``env``; whoever pushes gives the force
    at the cup for each look; the robot finds the push in what it senses and, once the push is
    over (:attr:`released`), knows where it was held (:meth:`deformation`); a replanned rest of
    the motion is played with :meth:`switch`. The simulated person (:func:`PhysicalUser.perform`)
    and the page's person (:mod:`corrections_sim.pages`) drive the same object.

    Args:
        robot: the plan ξ_R (T, 7).
        env: the environment.
        duration: how long the plan takes, s.
        rng: the generator of the sensing noise.
        torque_noise: σ of the joint-torque sensing noise, N·m.
        detect: ‖τ_h‖ above this is a push, N·m.
        look_steps: physics steps a look advances (default: the person's 100 Hz, 10 steps; a
            page played slower than real time looks more often, to show the arm smoothly).
    """

    def __init__(
        self,
        robot: np.ndarray,
        env: Environment,
        duration: float,
        rng: np.random.Generator,
        *,
        torque_noise: float = 0.0,
        detect: float = 1.0,
        look_steps: int | None = None,
    ) -> None:
        self.robot = np.asarray(robot, dtype=float)
        self.env = env
        self.duration = float(duration)
        self.rng = rng
        self.detect = float(detect)
        self.plan_timing = dynamics.TimedTrajectory(self.robot, self.duration)
        self.reference = self.plan_timing
        self.sim = _arm(env, torque_noise)
        self.sim.reset(self.robot[0])
        person = int(round(1.0 / (PERSON_RATE * self.sim.dt)))
        self.steps = person if look_steps is None else int(look_steps)
        if not 1 <= self.steps <= person:
            raise ValueError(f"look_steps: must lie in [1, {person}], got {look_steps!r}")
        self.look_time = self.steps * self.sim.dt
        self.chunks: list[dynamics.Chunk] = []
        self.pushed: list[dynamics.Chunk] = []
        self.effort = 0.0
        self.push_time = 0.0
        self.released: float | None = None
        self.kept: tuple | None = None
        self.switched = False
        self._quiet_since: float | None = None

    @property
    def time(self) -> float:
        return self.sim.time

    @property
    def done(self) -> bool:
        return self.sim.time >= self.duration - 1e-9

    def cup(self) -> np.ndarray:
        """Where the cup is now (3,), m."""
        return self.sim.cup_position()

    def q(self) -> np.ndarray:
        """The arm's joint positions now (7,)."""
        return self.sim.q()

    def look(self, force: np.ndarray | None) -> bool:
        """Advance one look with ``force`` (3,), N, at the cup (None: nobody pushes); True when
        the robot has just found the push over (then :meth:`deformation` is what it learns).
        Once it has, the robot's sensing is no longer computed (one push a task: what it
        senses later is learnt from by nobody); the trace's τ_h is NaN from there."""
        sense = self.released is None
        out = self.sim.advance(self.reference, self.steps, force, self.rng, sense=sense)
        self.chunks.append(out)
        if force is not None:
            self.effort += float(np.linalg.norm(force)) * self.look_time
            self.push_time += self.look_time
        return sense and self._found_release(out)

    def _found_release(self, out: dynamics.Chunk) -> bool:
        """The robot's reading of one look before the release: a push goes on while ‖τ_h‖
        is above ``detect`` at the look's end, and is over after :data:`RELEASE_WAIT` below."""
        if float(np.linalg.norm(out.tau_sensed[-1])) > self.detect:
            self.pushed.append(out)
            self._quiet_since = None
        elif self.pushed:
            if self._quiet_since is None:
                self._quiet_since = self.sim.time
            if self.sim.time - self._quiet_since >= RELEASE_WAIT:
                self.released = self.sim.time
                return True
        return False

    def hold_to_the_end(self) -> bool:
        """The motion is over and the push is not (the person still holds the cup): the end is
        its release. True when that gives a push to learn from (one was felt and not yet
        found over); call it once :attr:`done`."""
        if self.released is not None or not self.pushed:
            return False
        self.released = self.sim.time
        return True

    def look_starts(self):
        """The times the looks still to come start at, s, to the end of the motion (the
        simulation's own clock arithmetic, so that a caller can count the looks before a
        given moment exactly)."""
        t = self.sim.time
        while t < self.duration - 1e-9:
            yield t
            t = dynamics.look_after(t, self.sim.dt, self.steps)

    def coast(self, looks: int) -> bool:
        """``looks`` looks with nobody pushing, as many :meth:`look` (None) calls would give
        them to the last bit, but in one rollout where nothing can happen between them: True
        when the robot found the push over (after that look; the rest are not run). Before a
        push the looks are checked afterwards; if the robot felt anything (a contact, a
        push) they are run again one by one from a snapshot, noise draws included."""
        if looks <= 0:
            return False
        if looks == 1 or (self.pushed and self.released is None):
            return self._one_by_one(looks)
        sense = self.released is None
        if sense:
            saved, drawn = self.sim.snapshot(), self.rng.bit_generator.state
        out = self.sim.advance_looks(self.reference, self.steps, looks, None, self.rng, sense=sense)
        if sense and any(float(np.linalg.norm(c.tau_sensed[-1])) > self.detect for c in out):
            self.sim.restore(saved)
            self.rng.bit_generator.state = drawn
            return self._one_by_one(looks)
        self.chunks.extend(out)
        return False

    def _one_by_one(self, looks: int) -> bool:
        for _ in range(looks):
            if self.look(None):
                return True
        return False

    def deformation(self) -> tuple[np.ndarray, np.ndarray]:
        """(Ũ, ξ_H), each (T, 7): where the robot was held, and its plan deformed."""
        held = _held(self.pushed, self.plan_timing.times, self.sim.impedance.stiffness)
        return held, held_deformation(self.robot, held)

    def switch(self, plan: np.ndarray, *, keep: bool = True) -> None:
        """Follow ``plan`` (T, 7), the robot's new plan of the whole task, for the rest of the
        motion: joined from where the arm is meant to be now, at the same point of its timing
        (:meth:`~corrections_sim.scene.dynamics.TimedTrajectory.join`). With ``keep``, first
        play the current plan to its end from a snapshot (the motion had the robot not
        replanned), then come back."""
        if keep:
            self.sim.snapshot()
            self.kept = _finish(self.sim, self.reference, self.rng, self.steps)
            self.sim.restore()
        # Joined from where the arm is meant to be now (the reference's own state, so the
        # setpoint does not jump); the impedance brings the arm there as it would have.
        t = self.sim.time
        (here,), _, _ = self.reference.at(np.array([t]))
        self.reference = self.reference.join(plan, t, here)
        self.switched = True

    def sense_error(self) -> float:
        """RMS of the sensed τ_h minus the applied Jᵀ F over RMS of Jᵀ F, over the push's
        samples (NaN before a push)."""
        return _relative_rms(self.pushed)

    def trace(self) -> PushTrace:
        """The task so far at the person's rate."""
        chunks = self.chunks
        return PushTrace(
            times=np.array([c.times[0] for c in chunks]),
            cup=np.vstack([c.cup[0] for c in chunks]),
            force=np.vstack([c.force[0] for c in chunks]),
            tau_sensed=np.vstack([c.tau_sensed[0] for c in chunks]),
            tau_applied=np.vstack([c.tau_applied[0] for c in chunks]),
            q=np.vstack([c.q[0] for c in chunks]),
        )

    def outcome(self, features: tuple[str, ...]) -> PhysicalOutcome:
        """What the finished task gave (see :class:`PhysicalOutcome`)."""
        final = (self.sim.time, self.sim.q())
        held, deformed = self.deformation()
        trace = self.trace()
        at = self.plan_timing.times
        extras = {
            "effort": self.effort,
            "push_time": self.push_time,
            "sense_error": self.sense_error(),
            "replanned": float(self.switched),
            "contact": float(any(c.contacts for c in self.chunks)),
        }
        kept = None if self.kept is None else _sample(*_after(trace, self.kept), at)
        return PhysicalOutcome(
            phi_h=feature_counts(deformed, self.env, features),
            executed=_sample(trace.times, trace.q, final, at),
            executed_kept=kept,
            extras=extras,
            corrected=deformed,
            held=held,
            deformed=deformed,
            trace=trace,
        )


def _perform(
    person: PhysicalUser,
    situation: Situation,
    rng: np.random.Generator,
    replan: Replan | None,
    keep: bool,
) -> PhysicalOutcome:
    robot, intended = situation.robot, situation.intended
    motion = PushedMotion(
        robot,
        situation.env,
        person.duration,
        rng,
        torque_noise=person.torque_noise,
        detect=person.detect,
    )
    theirs = dynamics.TimedTrajectory(intended, person.duration)
    worst, _ = worst_cup_waypoint(robot, intended)
    start, end = person.window(motion.plan_timing.times[worst])

    def person_force(t: float, cup: np.ndarray) -> np.ndarray | None:
        gain = person.envelope(t, start, end)
        if gain == 0.0:
            return None
        (target,), _ = dynamics.cup_kinematics(theirs.at(np.array([t]))[0])
        force = gain * spring_force(cup, target, person.stiffness, person.force_cap)
        if person.force_noise > 0:
            force = force + rng.normal(0.0, person.force_noise, size=3)
        return cap_force(force, person.force_cap)

    while not motion.done:
        # Looks the person sits out (before the push, after it) run in one rollout.
        quiet = 0
        for t in motion.look_starts():
            if person.envelope(t, start, end) != 0.0:
                break
            quiet += 1
        if quiet:
            released = motion.coast(quiet)
        else:
            released = motion.look(person_force(motion.time, motion.cup()))
        if released and replan is not None:
            _, deformed = motion.deformation()
            rest = replan(deformed, motion.q(), motion.time)
            if rest is not None:
                motion.switch(rest, keep=keep)
    return motion.outcome(situation.features)


def _held(pushed: list[dynamics.Chunk], waypoint_times: np.ndarray, stiffness) -> np.ndarray:
    """Ũ (T, 7): K⁻¹ times the mean sensed τ_h of the push's samples nearest each waypoint."""
    T = waypoint_times.shape[0]
    held = np.zeros((T, stiffness.shape[0]))
    if not pushed:
        return held
    times = np.concatenate([c.times for c in pushed])
    tau = np.vstack([c.tau_sensed for c in pushed])
    spacing = waypoint_times[1] - waypoint_times[0]
    nearest = np.clip(np.round((times - waypoint_times[0]) / spacing).astype(int), 0, T - 1)
    for j in range(1, T - 1):
        mask = nearest == j
        if np.any(mask):
            held[j] = tau[mask].mean(axis=0) / stiffness
    return held


def _relative_rms(pushed: list[dynamics.Chunk]) -> float:
    """RMS of (sensed − applied) over RMS of applied, over the push's samples."""
    if not pushed:
        return float("nan")
    sensed = np.vstack([c.tau_sensed for c in pushed])
    applied = np.vstack([c.tau_applied for c in pushed])
    scale = float(np.sqrt(np.mean(applied**2)))
    return float(np.sqrt(np.mean((sensed - applied) ** 2)) / scale) if scale > 0 else float("nan")


def _finish(sim, reference, rng, chunk) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Play ``reference`` to its end, no push, nothing sensed (nobody learns from it), in one
    rollout: the looks' times and q, and the final state."""
    looks, t = 0, sim.time
    while t < reference.t_end - 1e-9:
        looks += 1
        t = dynamics.look_after(t, sim.dt, chunk)
    out = sim.advance_looks(reference, chunk, looks, None, rng, sense=False) if looks else []
    times = np.array([c.times[0] for c in out])
    qs = np.vstack([c.q[0] for c in out]) if out else np.empty((0, sim.model.nq))
    return times, qs, (sim.time, sim.q())


def _after(trace: PushTrace, kept: tuple) -> tuple[np.ndarray, np.ndarray, tuple]:
    """The kept branch's looks after the motion's looks up to where it branched off."""
    times, qs, final = kept
    before = trace.times < times[0] - 1e-9
    return np.append(trace.times[before], times), np.vstack([trace.q[before], qs]), final


def _sample(times: np.ndarray, qs: np.ndarray, final: tuple, at: np.ndarray) -> np.ndarray:
    """The executed motion at times ``at`` (T,), linear between looks and the final state."""
    times = np.append(times, final[0])
    qs = np.vstack([qs, final[1]])
    return np.column_stack([np.interp(at, times, qs[:, j]) for j in range(qs.shape[1])])
