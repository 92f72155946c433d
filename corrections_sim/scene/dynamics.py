"""The Panda with dynamics: torque control under joint impedance, a timed trajectory, and the
interaction torque as the robot senses it.

The collision scene of :mod:`corrections_sim.scene.world` gains what a torque-controlled arm
needs (all in :func:`dynamics_spec`):

* one torque actuator per joint, limited to the Panda's rated torques
  (:data:`TORQUE_LIMITS`: 87 N·m for joints 1–4, 12 N·m for 5–7, Franka's datasheet);
* joint armature 0.1 kg·m² and viscous damping 1 N·m·s/rad on every joint, MuJoCo Menagerie's
  values for its ``franka_emika_panda`` (which also uses ``implicitfast``);
* the ``implicitfast`` integrator at a 1 ms step (the model's 2 ms explicit Euler step
  diverges under a joint PD loop within 34 ms; measured, ``DESIGN.md``);
* gravity compensation of every arm body and the cup at the *measured* state, routed through
  the actuators (``actgravcomp``), so it counts against the torque limits;
* sensors a real Panda has: joint positions and velocities and the actuators' torques, and the
  cup's position (what a person watching sees; the robot never reads it).

The controller is a joint impedance around the timed plan q_d(t) (:class:`TimedTrajectory`):

    τ = g(q) + M(q_d) q̈_d + c(q_d, q̇_d) + K (q_d − q) + D (q̇_d − q̇),

clamped to the torque limits. The stiffness and damping act inside MuJoCo's step (an affine
actuator: force = ctrl − K q − D q̇, ``ctrl = τ_ff + K q_d + D q̇_d``) and the feedforward
τ_ff = M(q_d) q̈_d + c(q_d, q̇_d) is the inverse dynamics of the plan, so one control sequence
per step is computed ahead and the loop runs in C (:func:`mujoco.rollout.rollout`), 1 kHz.

Sensing (:func:`sensed_torque`) uses only the robot's own model and measurements: the joint
torque needed for the measured motion, inverse dynamics of the robot alone (no props, no
contacts) at the measured q, q̇ and the finite-difference q̈, minus the torque its motors
gave: τ_h = ID(q, q̇, q̈) − τ_motor. Whatever pushed (a person, the table) is in τ_h; the force
MuJoCo was given is never read. Optional sensor noise (σ per joint, N·m) and a first-order
low-pass filter follow.
"""

from __future__ import annotations

import copy
import functools
import threading
from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout
from scipy.interpolate import CubicSpline

from corrections_sim.scene import world
from corrections_sim.scene.environments import Environment
from corrections_sim.scene.robot import N_ARM_JOINTS

#: Rated joint torques of the Panda, N·m (Franka Emika's datasheet).
TORQUE_LIMITS = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0])
#: Joint armature, kg·m², and viscous damping, N·m·s/rad: MuJoCo Menagerie's Panda.
ARMATURE = 0.1
JOINT_DAMPING = 1.0
#: Physics step, s (implicitfast).
TIMESTEP = 1e-3

_ARM_BODIES = tuple(f"panda_link{i}" for i in range(1, 8)) + (
    "panda_link8",
    "panda_hand",
    "panda_hand_tcp",
    "panda_leftfinger",
    "panda_rightfinger",
    world.CUP_BODY,
)


def _check_vector(name: str, value, *, positive: bool) -> np.ndarray:
    arr = np.array(value, dtype=float).reshape(-1)
    if arr.size == 1:
        arr = np.full(N_ARM_JOINTS, float(arr[0]))
    if arr.shape != (N_ARM_JOINTS,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: expected one value or 7 finite values, got {value!r}")
    if positive and not np.all(arr > 0):
        raise ValueError(f"{name}: every value must be > 0, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Impedance:
    """Joint impedance gains.

    Attributes:
        stiffness: K per joint, N·m/rad (7,). The default, 120 for joints 1–4 and 40 for 5–7,
            lets a 20 N push at the cup move it by several centimetres (a push a person can
            see; stiff gains of 600 … 50 deflect it by millimetres) while the plan is tracked
            within millimetres without a push (the feedforward carries the motion).
        damping_ratio: ζ of the joint damping D = 2ζ √(K m), m the joint's diagonal inertia
            at the start configuration (critically damped by default).
    """

    stiffness: np.ndarray = (120.0, 120.0, 120.0, 120.0, 40.0, 40.0, 40.0)  # type: ignore[assignment]
    damping_ratio: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "stiffness", _check_vector("stiffness", self.stiffness, positive=True)
        )
        ratio = self.damping_ratio
        if isinstance(ratio, bool) or not (isinstance(ratio, int | float) and 0 < ratio <= 10):
            raise ValueError(f"damping_ratio: must lie in (0, 10], got {ratio!r}")

    def damping(self, inertia: np.ndarray) -> np.ndarray:
        """D (7,) from the joints' diagonal inertia (7,), kg·m²."""
        return 2.0 * self.damping_ratio * np.sqrt(self.stiffness * inertia)


def dynamics_spec() -> mujoco.MjSpec:
    """The collision scene with actuators, armature, damping, gravity compensation, sensors and
    the ``implicitfast`` integrator at :data:`TIMESTEP` (see the module docstring)."""
    spec = world.build_spec(visual=False)
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.timestep = TIMESTEP
    joints = [spec.joint(f"panda_joint{i}") for i in range(1, 8)]
    for joint, limit in zip(joints, TORQUE_LIMITS, strict=True):
        joint.armature = ARMATURE
        joint.damping = [JOINT_DAMPING, 0.0, 0.0]
        joint.actgravcomp = True
        act = spec.add_actuator(name=f"tau_{joint.name}", target=joint.name)
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.gainprm[0] = 1.0
        act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        act.ctrllimited = False
        # The limit holds for the joint's whole actuation, gravity compensation included.
        joint.actfrclimited = True
        joint.actfrcrange = [-limit, limit]
    for name in _ARM_BODIES:
        spec.body(name).gravcomp = 1.0
    for joint in joints:
        spec.add_sensor(
            name=f"torque_{joint.name}",
            type=mujoco.mjtSensor.mjSENS_JOINTACTFRC,
            objtype=mujoco.mjtObj.mjOBJ_JOINT,
            objname=joint.name,
        )
    spec.add_sensor(
        name="cup_position",
        type=mujoco.mjtSensor.mjSENS_FRAMEPOS,
        objtype=mujoco.mjtObj.mjOBJ_XBODY,
        objname=world.CUP_BODY,
    )
    return spec


@functools.cache
def _compiled() -> mujoco.MjModel:
    return dynamics_spec().compile()


def dynamics_model() -> mujoco.MjModel:
    """A private copy of the compiled dynamics scene (compiled once per process)."""
    return copy.copy(_compiled())


def robot_model(model: mujoco.MjModel) -> mujoco.MjModel:
    """The robot's own model of itself: ``model`` without contacts and gravity compensation
    (its inverse dynamics then gives the full joint torque a motion needs)."""
    own = copy.copy(model)
    own.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    own.body_gravcomp[:] = 0.0
    return own


class TimedTrajectory:
    """Waypoints (T, 7) at times t_0 < … < t_{T−1} (by default spaced uniformly over
    ``duration`` s from ``t0``), joined by a C² cubic spline with a given velocity at the start
    (rest by default) and rest at the end.

    The spline passes through every waypoint at its time; its velocity and acceleration are
    continuous, so the feedforward torque is too.
    """

    def __init__(
        self,
        waypoints: np.ndarray,
        duration: float,
        *,
        start_velocity: np.ndarray | None = None,
        t0: float = 0.0,
        times: np.ndarray | None = None,
    ) -> None:
        waypoints = np.asarray(waypoints, dtype=float)
        if waypoints.ndim != 2 or waypoints.shape[0] < 2 or waypoints.shape[1] != N_ARM_JOINTS:
            raise ValueError(f"waypoints: expected shape (T, 7) with T >= 2, got {waypoints.shape}")
        if not np.all(np.isfinite(waypoints)):
            raise ValueError("waypoints: all values must be finite")
        if not (np.isfinite(duration) and duration > 0):
            raise ValueError(f"duration: must be finite and > 0, got {duration!r}")
        if times is None:
            times = t0 + np.linspace(0.0, duration, waypoints.shape[0])
        times = np.asarray(times, dtype=float)
        if times.shape != (waypoints.shape[0],) or not np.all(np.diff(times) > 0):
            raise ValueError(f"times: expected {waypoints.shape[0]} increasing times")
        v0 = np.zeros(N_ARM_JOINTS) if start_velocity is None else np.asarray(start_velocity, float)
        self.waypoints = waypoints
        self.times = times
        self.t0 = float(times[0])
        self.duration = float(times[-1] - times[0])
        self._spline = CubicSpline(
            self.times, waypoints, axis=0, bc_type=((1, v0), (1, np.zeros(N_ARM_JOINTS)))
        )

    def join(
        self, plan: np.ndarray, t: float, q: np.ndarray, *, gap: float = 0.1
    ) -> TimedTrajectory:
        """Another plan (T, 7), timed like this one, joined at time ``t`` from configuration
        ``q`` (7,): the new plan's waypoints after ``t`` (those closer than ``gap`` s to ``t``
        left out), reached from ``q`` with this trajectory's velocity at ``t``."""
        plan = np.asarray(plan, dtype=float)
        if plan.shape != self.waypoints.shape:
            raise ValueError(f"plan: expected shape {self.waypoints.shape}, got {plan.shape}")
        later = np.flatnonzero(self.times > t + gap)
        later = later if later.size else np.array([self.times.size - 1])
        if self.times[later[0]] <= t:
            raise ValueError(f"t = {t}: past the end of the motion ({self.times[-1]} s)")
        _, velocity, _ = self.at(np.array([t]))
        # The joined trajectory keeps this one's timing: its waypoints come at this one's times.
        return TimedTrajectory(
            np.vstack([q, plan[later]]),
            self.times[-1] - t,
            start_velocity=velocity[0],
            times=np.concatenate([[t], self.times[later]]),
        )

    @property
    def t_end(self) -> float:
        return self.t0 + self.duration

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q_d, q̇_d, q̈_d at times ``t`` (n,), each (n, 7); held at the ends outside
        [t_0, t_end) (at t_0 itself the spline's own velocity and acceleration: a joined
        trajectory starts moving)."""
        t = np.asarray(t, dtype=float)
        inside = (t >= self.t0) & (t < self.t_end)
        t = np.clip(t, self.t0, self.t_end)
        q = self._spline(t)
        qd = self._spline(t, 1) * inside[:, None]
        qdd = self._spline(t, 2) * inside[:, None]
        return q, qd, qdd


class ArmSimulation:
    """One Panda under joint impedance in one environment: step it in chunks, read what the
    robot senses. Not thread-safe (one MjData).

    Args:
        env: where the table and laptop are.
        impedance: the controller's gains.
        torque_noise: σ of the joint-torque sensing noise, N·m (0: none).
        filter_hz: cut-off of the first-order low-pass filter on the sensed τ_h (0: none).
        model: the dynamics scene (default :func:`dynamics_model`; a private copy is taken).
    """

    def __init__(
        self,
        env: Environment,
        impedance: Impedance | None = None,
        *,
        torque_noise: float = 0.0,
        filter_hz: float = 30.0,
        model: mujoco.MjModel | None = None,
    ) -> None:
        if not (np.isfinite(torque_noise) and torque_noise >= 0):
            raise ValueError(f"torque_noise: must be finite and >= 0, got {torque_noise!r}")
        if not (np.isfinite(filter_hz) and filter_hz >= 0):
            raise ValueError(f"filter_hz: must be finite and >= 0, got {filter_hz!r}")
        self.model = dynamics_model() if model is None else copy.copy(model)
        world.place_environment(self.model, env)
        self.impedance = impedance or Impedance()
        self.torque_noise = float(torque_noise)
        self.filter_hz = float(filter_hz)
        self.data = mujoco.MjData(self.model)
        self._scratch = mujoco.MjData(self.model)
        self.own = robot_model(self.model)
        self._own_data = mujoco.MjData(self.own)
        self.dt = float(self.model.opt.timestep)
        self._cup = self.model.body(world.CUP_BODY).id
        self._state_spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self._control_spec = mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_XFRC_APPLIED
        self._nstate = mujoco.mj_stateSize(self.model, self._state_spec)
        # One rollout object for every look, on the calling thread: the module function makes
        # one per call and checks, tiles and allocates the arrays each time; advance() hands
        # it arrays already in the shapes it takes (a physical task ~3% faster end to end).
        self._rollout = mj_rollout.Rollout(nthread=0)
        self._qpos = slice(1, 1 + self.model.nq)
        self._qvel = slice(1 + self.model.nq, 1 + self.model.nq + self.model.nv)
        self._tau_filtered = np.zeros(N_ARM_JOINTS)
        self.time = 0.0

    def reset(self, q: np.ndarray, qvel: np.ndarray | None = None, time: float = 0.0) -> None:
        """Put the arm at rest (or moving at ``qvel``) at ``q`` (7,), at ``time``."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = q
        self.data.qvel[:] = 0.0 if qvel is None else qvel
        mujoco.mj_forward(self.model, self.data)
        self._damping = self.impedance.damping(np.diag(self._mass_matrix(self.data.qpos)))
        self.model.actuator_biasprm[:, 1] = -self.impedance.stiffness
        self.model.actuator_biasprm[:, 2] = -self._damping
        self._tau_filtered = np.zeros(N_ARM_JOINTS)
        self.time = float(time)

    def move_to(self, env: Environment) -> None:
        """Move the table and laptop to ``env`` (call :meth:`reset` next)."""
        world.place_environment(self.model, env)

    def q(self) -> np.ndarray:
        """The measured joint positions now (7,)."""
        return np.array(self.data.qpos)

    def cup_position(self) -> np.ndarray:
        """Where the cup's centre of mass is now (3,), m (what a person sees)."""
        return np.array(self.data.xipos[self._cup])

    def snapshot(self) -> tuple:
        """Remember the arm's state (with the contact solver's warm start), its sensing filter
        and the clock, and return them (see :meth:`restore`)."""
        state = np.empty(self._nstate)
        mujoco.mj_getState(self.model, self.data, state, self._state_spec)
        self._saved = (
            state,
            self.data.qacc_warmstart.copy(),
            self._tau_filtered.copy(),
            self.time,
        )
        return self._saved

    def restore(self, saved: tuple | None = None) -> None:
        """Go back to ``saved`` (default: the last :meth:`snapshot`)."""
        state, warmstart, filtered, time = self._saved if saved is None else saved
        mujoco.mj_setState(self.model, self.data, state, self._state_spec)
        mujoco.mj_forward(self.model, self.data)
        self.data.qacc_warmstart[:] = warmstart
        self._tau_filtered = filtered.copy()
        self.time = time

    def _mass_matrix(self, q: np.ndarray) -> np.ndarray:
        d = self._own_data
        d.qpos[:] = q
        mujoco.mj_kinematics(self.own, d)
        mujoco.mj_comPos(self.own, d)
        mujoco.mj_crb(self.own, d)
        full = np.zeros((self.own.nv, self.own.nv))
        mujoco.mj_fullM(self.own, d, full)
        return full

    def feedforward(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """τ_ff = M(q_d) q̈_d + c(q_d, q̇_d) per row (n, 7): the plan's inverse dynamics
        without gravity (compensated at the measured state) and without passive damping."""
        own = self.own
        gravity = own.opt.gravity.copy()
        own.opt.gravity[:] = 0.0
        try:
            return self._inverse_rows(q, qd, qdd, passive=True)
        finally:
            own.opt.gravity[:] = gravity

    def _inverse_rows(self, q, qvel, qacc, *, passive: bool) -> np.ndarray:
        """The robot's own inverse dynamics at each row (n, 7) of (q, q̇, q̈), plus its passive
        forces if ``passive``. One MuJoCo call a row: the views of the data are taken once."""
        own, d = self.own, self._own_data
        qpos, qvel_d, qacc_d = d.qpos, d.qvel, d.qacc
        tau, passive_force = d.qfrc_inverse, d.qfrc_passive
        inverse = mujoco.mj_inverse
        out = np.empty_like(q)
        for i in range(q.shape[0]):
            qpos[:] = q[i]
            qvel_d[:] = qvel[i]
            qacc_d[:] = qacc[i]
            inverse(own, d)
            if passive:
                np.add(tau, passive_force, out=out[i])
            else:
                out[i] = tau
        return out

    def controls(self, reference: TimedTrajectory, times: np.ndarray) -> np.ndarray:
        """The actuators' ctrl per step (n, 7): τ_ff + K q_d + D q̇_d."""
        q, qd, qdd = reference.at(times)
        return self.feedforward(q, qd, qdd) + self.impedance.stiffness * q + self._damping * qd

    def advance(
        self,
        reference: TimedTrajectory,
        n_steps: int,
        force: np.ndarray | None = None,
        rng: np.random.Generator | None = None,
        *,
        sense: bool = True,
    ) -> Chunk:
        """Run ``n_steps`` physics steps tracking ``reference``, with ``force`` (3,), newtons,
        applied at the cup's centre of mass throughout (None: no push). Without ``sense`` the
        robot's τ_h is not computed (NaN; its filter is left as it was): for motions nobody
        learns from."""
        return self.advance_looks(reference, n_steps, 1, force, rng, sense=sense)[0]

    def advance_looks(
        self,
        reference: TimedTrajectory,
        look_steps: int,
        looks: int,
        force: np.ndarray | None = None,
        rng: np.random.Generator | None = None,
        *,
        sense: bool = True,
    ) -> list[Chunk]:
        """``looks`` calls of :meth:`advance` with ``look_steps`` steps each, in one rollout:
        the same chunks to the last bit (the same clock, controls, physics, sensing, noise
        draws and contacts at each look's end), without the Python between looks."""
        dt = self.dt
        blocks, t = [], self.time
        for _ in range(looks):
            blocks.append(t + dt * np.arange(look_steps))
            t = look_after(t, dt, look_steps)
        times = np.concatenate(blocks)
        n_steps = times.shape[0]
        ctrl = self.controls(reference, times)
        control = np.zeros((n_steps, self.model.nu + self.model.nbody * 6))
        control[:, : self.model.nu] = ctrl
        if force is not None:
            at = self.model.nu + 6 * self._cup
            control[:, at : at + 3] = force
        state0 = np.empty(self._nstate)
        mujoco.mj_getState(self.model, self.data, state0, self._state_spec)
        states = np.empty((1, n_steps, self._nstate))
        sensors = np.empty((1, n_steps, self.model.nsensordata))
        self._rollout.rollout(
            [self.model],
            [self.data],
            state0[None],
            control[None],
            control_spec=int(self._control_spec),
            skip_checks=True,
            nstep=n_steps,
            initial_warmstart=self.data.qacc_warmstart[None],
            state=states,
            sensordata=sensors,
        )
        states, sensors = states[0], sensors[0]
        mujoco.mj_setState(self.model, self.data, states[-1], self._state_spec)
        mujoco.mj_forward(self.model, self.data)
        # Row i is step i: the state it started from, the torque and force during it (MuJoCo
        # computes sensors before integrating), and the velocity change it made.
        q = np.vstack([state0[self._qpos], states[:-1, self._qpos]])
        qvel_after = states[:, self._qvel]
        qvel = np.vstack([state0[self._qvel], qvel_after[:-1]])
        qacc = (qvel_after - qvel) / dt
        tau_motor = sensors[:, :N_ARM_JOINTS]
        cup = sensors[:, N_ARM_JOINTS : N_ARM_JOINTS + 3]
        if sense:
            sensed = self._sense(q, qvel, qacc, tau_motor, rng)
        else:
            sensed = np.full_like(q, np.nan)
        applied = self._applied_torque(q, force)
        pushed = np.broadcast_to(np.zeros(3) if force is None else force, (n_steps, 3)).copy()
        self.time = t
        # Contacts at each look's end: the state the next look starts from, as advance() finds
        # them after setting it (the last look's are the live data's).
        contacts = [self._contacts(states[(k + 1) * look_steps - 1]) for k in range(looks - 1)]
        contacts.append(int(self.data.ncon))
        return [
            Chunk(
                times=times[rows],
                q=q[rows],
                qvel=qvel[rows],
                cup=cup[rows],
                tau_sensed=sensed[rows],
                tau_applied=applied[rows],
                force=pushed[rows],
                contacts=contacts[k],
            )
            for k, rows in enumerate(
                slice(k * look_steps, (k + 1) * look_steps) for k in range(looks)
            )
        ]

    def _contacts(self, state: np.ndarray) -> int:
        """How many contacts the scene has at ``state`` (a scratch copy of the data)."""
        scratch = self._scratch
        mujoco.mj_setState(self.model, scratch, state, self._state_spec)
        mujoco.mj_kinematics(self.model, scratch)
        mujoco.mj_collision(self.model, scratch)
        return int(scratch.ncon)

    def _sense(self, q, qvel, qacc, tau_motor, rng) -> np.ndarray:
        """τ_h per step (n, 7): the robot's inverse dynamics of the measured motion minus the
        torque its motors gave, plus sensor noise, low-pass filtered."""
        raw = self._inverse_rows(q, qvel, qacc, passive=False)
        raw -= tau_motor
        if self.torque_noise > 0:
            if rng is None:
                raise ValueError("torque_noise > 0 needs a generator")
            raw += rng.normal(0.0, self.torque_noise, size=raw.shape)
        if self.filter_hz <= 0:
            return raw
        alpha = 1.0 - np.exp(-2.0 * np.pi * self.filter_hz * self.dt)
        out = np.empty_like(raw)
        y = self._tau_filtered
        for i, x in enumerate(raw):
            y = y + alpha * (x - y)
            out[i] = y
        self._tau_filtered = y
        return out

    def _applied_torque(self, q: np.ndarray, force: np.ndarray | None) -> np.ndarray:
        """Jᵀ F per step (n, 7) of the applied force at the cup's centre of mass: the truth
        the sensing is checked against (tests and benchmarks only; the robot never reads it)."""
        if force is None:
            return np.zeros_like(q)
        _, jacobians = cup_kinematics(q)  # (n, 3, 7)
        return np.array([jac.T @ force for jac in jacobians])


def look_after(t: float, dt: float, steps: int) -> float:
    """The clock after a look of ``steps`` physics steps of ``dt`` s from ``t``, float for
    float as :meth:`ArmSimulation.advance` keeps it (so that looks can be counted ahead)."""
    return t + dt * (steps - 1) + dt


@dataclass(frozen=True, eq=False)
class Chunk:
    """What ``n`` physics steps produced, one row per step: the state it started from and the
    torques and force during it.

    Attributes:
        times: (n,) seconds.
        q, qvel: measured joint positions and velocities (n, 7).
        cup: the cup's position (n, 3), metres (what a person sees).
        tau_sensed: the interaction torque the robot senses, τ_h (n, 7), N·m (NaN where
            sensing was off).
        tau_applied: Jᵀ F of the applied force (n, 7), N·m (the truth, for checks only).
        force: the applied force (n, 3), N.
        contacts: contacts at the chunk's last step.
    """

    times: np.ndarray
    q: np.ndarray
    qvel: np.ndarray
    cup: np.ndarray
    tau_sensed: np.ndarray
    tau_applied: np.ndarray
    force: np.ndarray
    contacts: int


#: Each thread's kinematic model and data (an MjData is not thread-safe).
_KINEMATICS = threading.local()


def _kinematics() -> tuple[mujoco.MjModel, mujoco.MjData]:
    mine = getattr(_KINEMATICS, "pair", None)
    if mine is None:
        model = robot_model(dynamics_model())
        mine = _KINEMATICS.pair = (model, mujoco.MjData(model))
    return mine


def cup_kinematics(qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cup's centre of mass (n, 3) and its position Jacobian (n, 3, 7) at configurations
    ``qs`` (n, 7): where a push at the cup acts, and how a force there maps to joint torques
    (Jᵀ F). One kinematic model per thread."""
    model, data = _kinematics()
    qs = np.atleast_2d(np.asarray(qs, dtype=float))
    cup = model.body(world.CUP_BODY).id
    positions = np.empty((qs.shape[0], 3))
    jacobians = np.empty((qs.shape[0], 3, model.nv))
    for i, q in enumerate(qs):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        positions[i] = data.xipos[cup]
        mujoco.mj_jac(model, data, jacobians[i], None, data.xipos[cup], cup)
    return positions, jacobians
