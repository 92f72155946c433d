"""A correction session: the robot plans, a person (or a simulated user) corrects, a learner
updates, and every confirmed correction is logged before anything else happens.

The same :class:`Session` serves the browser page (:mod:`corrections_sim.pages.page`), a
simulated user run headless (:func:`~corrections_sim.session.simulate.simulate`) and
``--resume``, so a logged human session and a simulated one compare line by line. Iteration t:

1. :meth:`Session.proposal` — the learner chooses Eᵗ (the seeded random draw, or its own choice,
   e.g. eq. (A1) for AL) and the robot plans ξᵗ = ξ*(θ̂ᵗ, Eᵗ). A draw whose plan fails is
   logged as a skip and the next draw is taken.
2. :meth:`Session.drag` — the person moves the cup at free waypoint i; the package's IK puts
   the hand there with the rotation it had (the cup does not tilt), and the session's
   correction model completes ξ_h from ξᵗ and that one moved waypoint (``waypoint``: only it;
   ``deform``: the minimum-jerk deformation of the whole path). A drag IK cannot reach, or
   whose ξ_h collides (MuJoCo's check, as for the planner's plans), is :class:`Refused` with
   the reason; nothing is logged but a ``refused`` event.
3. :meth:`Session.submit` — the learner updates on Φ(ξ_h, Eᵗ); the row is committed to the log;
   only then does the caller see the new belief.

A physical session (correction model ``physical``) replaces 2 and 3: the person pushes the cup
while the arm plays ξᵗ under impedance (:class:`~corrections_sim.people.physical.PushedMotion`,
driven by the page or by a simulated physical user); when the robot finds the push over,
:meth:`Session.submit_push` learns from the deformation ξ_H and logs it with the push (force
profile, executed path, sensed τ_h, where the arm was held), and :meth:`Session.replan` plans
anew, the arm joining the new plan where it is.

A learner that learns the feature it lacks (KF-CRX, :mod:`corrections_sim.learnt.training`)
may ask, after a correction, for feature traces (:attr:`Session.wanted`): the person moves
the cup from where the feature they mind is high to where it is low. A trace's start is logged
(``trace_start``, :meth:`Session.start_trace`), then the trace itself (``trace``,
:meth:`Session.add_trace`) or its cancellation (``trace_cancelled``). With all that were asked
for, or at least :data:`MIN_TRACES` when the person stops early (a ``traces`` event with
``enough``), :meth:`Session.learn_feature` trains the feature, logs it (a ``learnt`` event: its
name, network and weights) and the robot plans over it from then on.
:meth:`Session.decline_traces` tells the learner nobody will teach; traces already given stay
in the log, set aside (the event says how many).

No trace the person gave is lost to a crash. Training is a function of the logged traces and
the seed, so a session resumed with every trace logged but no ``learnt`` event (killed during
the training) learns the feature then, the same one; a trace started and never ended (killed
while recording) is logged as lost (``trace_lost``), and :attr:`Session.lost_trace` tells the
page where it began, to say so.

The environment draws are stateless functions of (seed, draw index), and the learners' own
generator of (seed, iteration), so a session resumed from its log (:meth:`Session.resume`)
continues exactly where it stopped: its corrections are replayed through the learner and
each θ̂ checked against the logged one.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from corrections_sim import components, provenance
from corrections_sim.calibration import nis
from corrections_sim.defaults import DEFAULTS
from corrections_sim.learning import correction
from corrections_sim.learning.base import LEARNERS, Learner, LearnerContext, make_learner
from corrections_sim.people.corrections import CORRECTIONS, CorrectionModel
from corrections_sim.people.physical import PushedMotion
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import Plan, Planner, PlanningError, shared_planner
from corrections_sim.planning.risk import plan_a4
from corrections_sim.plans.book import PlanBook
from corrections_sim.scene.environments import Environment
from corrections_sim.scene.robot import cup_inverse_kinematics, cup_pose
from corrections_sim.scene.world import CollisionChecker
from corrections_sim.session.log import ASK_KINDS, StudyLog, check_participant, now
from corrections_sim.session.refused import Refused
from corrections_sim.session.teaching import TEACH_EVENTS, Teaching
from corrections_sim.study import legacy
from corrections_sim.study.schema import parse_study
from corrections_sim.study.settings import FigureSettings

#: Consecutive draws whose plan fails before a session gives up.
MAX_FAILED_DRAWS = 20
#: How far a θ̂ recomputed from the log (``--resume``, and ``replay`` of a session planned
#: from cold starts) may lie from the logged one, max |Δ|. On the machine that logged it the
#: gap is 0: the same code repeats the same floating-point operations. On another processor
#: BLAS kernels, libm and so the solver's iterations round differently (the committed
#: physical session replayed elsewhere: 3.6e-15); a gap above this is other code or settings.
LOG_TOLERANCE = 1e-9


def make_asks(count: int, seed: int) -> list[str]:
    """``count`` kinds to ask for, half "toward" and half "nudge" (the odd one "toward"), in
    an order shuffled by ``seed``."""
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise ValueError(f"labelled corrections: expected a count >= 0, got {count!r}")
    kinds = ["toward"] * ((count + 1) // 2) + ["nudge"] * (count // 2)
    order = np.random.default_rng([int(seed), 38]).permutation(count)
    return [kinds[i] for i in order]


@dataclass(frozen=True, eq=False)
class Proposal:
    """What the person is shown at iteration t: ξᵗ = ξ*(θ̂ᵗ, Eᵗ).

    Attributes:
        iteration: t, corrections confirmed so far.
        draw: the index of the environment draw that led to it.
        env_index: Eᵗ's index in the study's environments.
        env: Eᵗ.
        plan: the robot's plan ξᵗ.
        shown_at: when it was proposed (UTC, ISO 8601), and ``monotonic``, for the seconds.
    """

    iteration: int
    draw: int
    env_index: int
    env: Environment
    plan: Plan
    shown_at: str
    monotonic: float = field(default_factory=time.monotonic)


@dataclass(frozen=True, eq=False)
class Deployment:
    """The end of a session in Eᵗ: the plain plan ξ*(θ̂) beside the risk-averse one of eq. (A4)."""

    env: Environment
    plain: Plan
    averse: Plan
    gamma: np.ndarray  # the γ ∈ Γ that (A4) deploys with


def environment_draw(seed: int, draw: int, n: int) -> int:
    """The ``draw``-th random environment index in [0, n) of a session with ``seed``."""
    return int(np.random.default_rng(np.random.SeedSequence([seed, 20, draw])).integers(n))


def learner_rng(seed: int, iteration: int) -> np.random.Generator:
    """The generator a learner gets at ``iteration`` (a pure function of the two)."""
    return np.random.default_rng(np.random.SeedSequence([seed, 21, iteration]))


def build_learner(settings: FigureSettings, name: str, params: Mapping | None = None) -> Learner:
    """Learner ``name``: the study's (with its parameters) if it has one, else a new one with
    ``params``; a PP-type learner needs a fixed rate in a live session."""
    if params is None and name in settings.study.learners:
        agent = settings.study.learners[name]
    else:
        agent = make_learner(name, params or {})
    agent.check(settings.planner_config().n_waypoints)
    return agent


def physical_learner(settings: FigureSettings, learner: str, *, model_set: bool = False):
    """A physical session's learner parameters: the study's, with the ``physical`` model of a
    push where the learner takes a model and none was set (``model_set``); None to take the
    study's (or the defaults) as they are."""
    if model_set or "model" not in components.defaults(LEARNERS[learner]):
        return None
    agent = settings.study.learners.get(learner)
    params = components.params(agent) if agent is not None else {}
    return params | {"model": "physical"}


def build_correction(spec: str | Mapping) -> CorrectionModel:
    """A correction model from a name or a table ``{name = ..., params...}``."""
    if isinstance(spec, str):
        spec = {"name": spec}
    spec = dict(spec)
    name = spec.pop("name", None)
    if not isinstance(name, str):
        raise ValueError(f"correction: expected a model name, got {name!r}")
    return components.build(CORRECTIONS, name, spec, where="correction")


def correction_spec(model: CorrectionModel) -> dict:
    """The table that :func:`build_correction` takes back."""
    return {"name": components.name_of(CORRECTIONS, model), **components.params(model)}


class Session(Teaching):
    """One session of corrections (see the module). Thread-safe: one lock around every step.

    Make one with :meth:`start` or :meth:`resume`.
    """

    def __init__(
        self,
        settings: FigureSettings,
        learner: str,
        agent: Learner,
        correction: CorrectionModel,
        log: StudyLog,
        session_id: int,
        seed: int,
        *,
        planner: Planner | None = None,
        lock: threading.RLock | None = None,
    ) -> None:
        cls = LEARNERS[learner]
        self.settings = settings
        self.learner = learner
        self.agent = agent
        self.has_covariance = cls.has_covariance
        self.correction = correction
        self.log = log
        self.id = session_id
        self.seed = int(seed)
        self.planner = planner or shared_planner(settings.planner_config())
        self.envs = settings.envs()
        self.features = settings.features
        self.n_waypoints = self.planner.config.n_waypoints
        correction.check(self.n_waypoints)
        s = settings.study
        self._noise, self._sigma = s.noise(), s.sigma()
        self.belief = agent.initial(s.prior(), self._noise)
        # With the study's warm_start, each plan starts from the nearest solved θ in its
        # environment (eq. (A1)'s 48 × (2k + 1) predictions for AL in well under a second);
        # --resume then repeats the very same solves in the same order.
        # With the study's plan atlas, every plan is the atlas's answer (a function of (θ, E)
        # alone, so --resume and replay give the same plans in any order).
        atlas = settings.atlas() if self.planner.config == settings.planner_config() else None
        self.book = PlanBook(self.planner, warm_start=s.warm_start, atlas=atlas)
        if agent.learns_features() and self.planner.config.jit:
            # A learner that may learn a feature: its shape's planner is built now, not while
            # the person waits for the plan over it (a first build takes about two minutes).
            from corrections_sim.learnt.training import prepare_slot

            prepare_slot(self.planner.config, agent.network())
        self.checker = CollisionChecker()
        self.iteration = 0
        #: β̂ and ρ of the last correction, for a relevance-aware learner (else None).
        self.last_relevance: dict | None = None
        self.draws = 0
        #: environments skipped since the last correction (a choosing learner leaves them out)
        self.declined: set[int] = set()
        self.ended = False
        #: the kinds of correction asked for, one per iteration from the first (labelled
        #: corrections), and the preference a "toward" correction is asked toward
        self.asks: list[str] = []
        self.preference: np.ndarray | None = None
        self._pending: Proposal | None = None
        #: feature traces the learner asks for now (0: none), and those given so far
        self.wanted = 0
        self.traces: list[np.ndarray] = []
        #: the trace being recorded (its ``trace_start`` event's detail), else None; and
        #: the one a crash cut short, found when the session resumed (the page says so)
        self.open_trace: dict | None = None
        self.lost_trace: dict | None = None
        #: a feature learnt from traces the person gave before the server stopped, with no
        #: correction since (found when the session resumed; the page says so)
        self._learnt_before: dict | None = None
        #: the environment of the last correction (where traces are given)
        self.last_env: int | None = None
        # Sessions served side by side in one process (a study's participants) share one:
        # the planner, its collision checker and CasADi's function building are not safe
        # to use from two threads at once (a segfault, measured).
        self._lock = lock or threading.RLock()

    # --- making one ------------------------------------------------------------------------

    @classmethod
    def start(
        cls,
        settings: FigureSettings,
        log: StudyLog,
        *,
        learner: str = DEFAULTS["session"][0],
        params: Mapping | None = None,
        correction: str | Mapping = "waypoint",
        participant: str = "anonymous",
        corrector: Any = "person",
        seed: int | None = None,
        planner: Planner | None = None,
        asks: list[str] | None = None,
        preference=None,
        lock: threading.RLock | None = None,
    ) -> Session:
        """A new session, logged in ``log`` (its row is written first). ``asks``: the kinds
        of correction (:data:`ASK_KINDS`) to ask the person for, one per correction from the
        first; a "toward" one is toward ``preference`` (default the study's θ*)."""
        check_participant(participant)
        agent, model = cls.prepare(settings, learner, params, correction)
        asks = list(asks or [])
        for kind in asks:
            if kind not in ASK_KINDS:
                raise ValueError(f"ask {kind!r}: expected one of {', '.join(ASK_KINDS)}")
        if preference is None:
            preference = settings.study.theta_star
        preference = np.asarray(preference, float)
        if preference.shape != (settings.study.k,) or not np.all(np.isfinite(preference)):
            raise ValueError(
                f"preference {preference.tolist()}: expected {settings.study.k} finite weights"
            )
        seed = settings.study.seed if seed is None else int(seed)
        session_id = log.new_session(
            participant=participant,
            settings=settings.as_dict(),
            learner=learner,
            learner_params=components.params(agent),
            correction=correction_spec(model),
            seed=seed,
            corrector=corrector,
        )
        log.add_event(session_id, -1, "machine", provenance.machine())
        spec = settings.atlas_spec()
        if spec is not None:  # what the plans depend on besides (θ, E): planner build, grid
            log.add_event(session_id, -1, "atlas", {"identity": spec.key(None)})
        asked = {"kinds": asks, "preference": preference.tolist()} if asks else None
        if asked:
            log.add_event(session_id, -1, "asks", asked)
        session = cls(
            settings, learner, agent, model, log, session_id, seed, planner=planner, lock=lock
        )
        session._set_asks(asked)
        return session

    def _set_asks(self, detail: Mapping | None) -> None:
        if detail:
            self.asks = list(detail["kinds"])
            self.preference = np.asarray(detail["preference"], float)

    def ask(self) -> dict | None:
        """The correction asked for now: {kind, label, preference}, or None (none asked)."""
        if self.iteration >= len(self.asks):
            return None
        kind = self.asks[self.iteration]
        preference = None if kind == "nudge" else self.preference.tolist()
        return {"kind": kind, "label": ASK_KINDS[kind], "preference": preference}

    @staticmethod
    def prepare(
        settings: FigureSettings,
        learner: str,
        params: Mapping | None = None,
        correction: str | Mapping = "waypoint",
    ) -> tuple[Learner, CorrectionModel]:
        """The learner and the correction model a session of ``settings`` would run, checked
        as :meth:`start` checks them, with nothing written.

        Raises:
            ValueError: an unknown learner or model, bad parameters, or a PP-type learner
                without a fixed rate.
        """
        agent = build_learner(settings, learner, params)
        model = build_correction(correction)
        if LEARNERS[learner].needs_rates() and agent.fixed_rate() is None:
            raise ValueError(
                f"learner {learner}: its rate comes from {agent.rate_source()}'s gains over "
                f"many runs; give it one for a session (--set learners.{learner}.fixed_alpha=0.1)"
            )
        model.check(settings.planner_config().n_waypoints)
        return agent, model

    @classmethod
    def resume(
        cls,
        log: StudyLog,
        session_id: int,
        *,
        planner: Planner | None = None,
        lock: threading.RLock | None = None,
    ) -> Session:
        """Session ``session_id`` of ``log``, continued after its last confirmed correction.

        Raises:
            LogError: no such session.
            ValueError: the session has ended, or its corrections replayed give another θ̂
                than the one logged (other code or settings).
        """
        row = log.session(session_id)
        if row.ended is not None:
            raise ValueError(f"session {session_id}: ended at {row.ended}; start a new one")
        settings = settings_from_log(row.settings)
        agent = build_learner(settings, row.learner, row.learner_params)
        model = build_correction(row.correction)
        session = cls(
            settings,
            row.learner,
            agent,
            model,
            log,
            session_id,
            row.seed,
            planner=planner,
            lock=lock,
        )
        asked = log.events(session_id, "asks")
        session._set_asks(asked[0]["detail"] if asked else None)
        teach = [e for e in log.events(session_id) if e["kind"] in TEACH_EVENTS]
        session._replay(log.corrections(session_id), log.events(session_id, "skip"), teach)
        if session.open_trace is not None:  # killed while a trace was being recorded
            session.lost_trace, session.open_trace = session.open_trace, None
            log.add_event(session_id, session.iteration, "trace_lost", session.lost_trace)
        # Where the session goes on (a resume on another processor is exact to LOG_TOLERANCE).
        log.add_event(session_id, session.iteration, "machine", provenance.machine())
        return session

    def _replay(self, rows: list[dict], skips: list[dict], teach: list[dict] = ()) -> None:
        """Repeat the session's steps (each draw's choice and plan, each update) as they were
        made, so the plans solved, and with warm starts their history, are the same."""
        by_draw = {int(r["draw"]): r for r in rows}
        skipped = {int(e["detail"]["draw"]) for e in skips}
        teaching: dict[int, list[dict]] = {}
        for event in teach:
            teaching.setdefault(int(event["iteration"]) - 1, []).append(event)
        last = max([*by_draw, *skipped], default=-1)
        for draw in range(last + 1):
            random_index = environment_draw(self.seed, draw, len(self.envs))
            index = int(self.agent.choose(self._context(), self.belief, random_index))
            try:
                plan = self.book.plan(self.belief.theta, self.envs[index])
            except PlanningError:
                self.declined.add(index)
                continue  # logged as a skip when it happened
            row = by_draw.get(draw)
            if row is None:
                if draw not in skipped:
                    raise ValueError(
                        f"session {self.id}: draw {draw} is neither a correction "
                        "nor a skip in the log"
                    )
                self.declined.add(index)
                continue
            if index != int(row["env_index"]):
                raise ValueError(
                    f"session {self.id}: correction {row['iteration']} was in environment "
                    f"{row['env_index']}, the learner now chooses {index} (other code or settings?)"
                )
            try:
                step = self._update(index, plan, np.asarray(row["phi_h"]), row["xi_h"])
            except PlanningError:
                step = None  # the update was skipped then too (update_skipped)
            theta = self.belief.theta if step is None else step.belief.theta
            gap = float(np.max(np.abs(theta - row["theta_after"])))
            if gap > LOG_TOLERANCE:
                raise ValueError(
                    f"session {self.id}: replaying correction {row['iteration']} gives θ̂ "
                    f"{np.round(theta, 6).tolist()}, the log has "
                    f"{np.round(row['theta_after'], 6).tolist()} (other code or settings?)"
                )
            if step is not None:
                self.belief = step.belief
            self.iteration += 1
            self.declined.clear()
            self.last_env = index
            self._ask_traces()
            self._replay_teaching(teaching.get(self.iteration - 1, []))
        self.draws = last + 1

    @property
    def correction_name(self) -> str:
        """The registered name of the model that completes a drag into ξ_h."""
        return components.name_of(CORRECTIONS, self.correction)

    @property
    def physical(self) -> bool:
        """Whether the person pushes the moving arm (correction model ``physical``) rather
        than drags a waypoint."""
        return self.correction_name == "physical"

    @property
    def teaches(self) -> bool:
        """Whether the learner may ask its person for feature traces (a page shows the
        teaching controls only then)."""
        return self.agent.learns_features() and not self.physical

    def motion(self, duration: float = 5.0, *, look_steps: int | None = None) -> PushedMotion:
        """The current proposal played under impedance, for a person to push (no sensing
        noise: the robot senses what the simulation gives it); ``look_steps`` physics steps a
        look (see :class:`~corrections_sim.people.physical.PushedMotion`)."""
        pending = self.proposal()
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 28, pending.draw]))
        return PushedMotion(
            pending.plan.trajectory, pending.env, duration, rng, look_steps=look_steps
        )

    def submit_push(self, motion: PushedMotion, **extra) -> dict:
        """Learn from ``motion``'s push (its deformation ξ_H), log it with the push and return
        the row (see :func:`push_record`; ``extra`` is logged with it)."""
        _, deformed = motion.deformation()
        return self.submit(deformed, drag=push_record(motion) | extra)

    def replan(self, q_now, t_now: float, iteration: int) -> np.ndarray | None:
        """The new plan (T, 7) with the current θ̂ in the environment of correction
        ``iteration``, which the arm (at ``q_now`` (7,), ``t_now`` s into the motion) joins;
        None if the planner finds none. Logged as a ``replan`` event either way."""
        with self._lock:
            row = self.log.corrections(self.id)[-1]
            env = self.envs[int(row["env_index"])]
            detail: dict = {"t": float(t_now), "q": np.asarray(q_now, float).tolist()}
            try:
                plan = self.book.plan(self.belief.theta, env).trajectory
            except PlanningError as exc:
                detail["failed"] = str(exc).splitlines()[0]
                self.log.add_event(self.id, iteration, "replan", detail)
                return None
            detail["trajectory"] = plan.tolist()
            self.log.add_event(self.id, iteration, "replan", detail)
            return plan

    # --- the steps -------------------------------------------------------------------------

    def _context(self) -> LearnerContext:
        fixed = self.agent.fixed_rate()
        return correction.context(
            self.belief,
            self._noise,
            book=self.book,
            envs=self.envs,
            features=self.features,
            n_waypoints=self.n_waypoints,
            alphas=None if fixed is None else np.full(self.iteration + 1, fixed),
            rng=learner_rng(self.seed, self.iteration),
            sigma=self._sigma,
            iteration=self.iteration,
            declined=frozenset(self.declined),
        )

    def _check_open(self) -> None:
        if self.ended:
            raise Refused(f"session {self.id} has ended")

    def proposal(self) -> Proposal:
        """ξᵗ in Eᵗ, the plan the person is to correct (the same one until it is submitted or
        skipped)."""
        with self._lock:
            self._check_open()
            if self._pending is not None:
                return self._pending
            for _ in range(MAX_FAILED_DRAWS):
                draw = self.draws
                random_index = environment_draw(self.seed, draw, len(self.envs))
                index = int(self.agent.choose(self._context(), self.belief, random_index))
                if not 0 <= index < len(self.envs):
                    raise ValueError(f"learner {self.learner}: chose environment {index}")
                try:
                    plan = self.book.plan(self.belief.theta, self.envs[index])
                except PlanningError as exc:
                    self._skip(f"planner: {str(exc).splitlines()[0]}", index)
                    continue
                self._pending = Proposal(self.iteration, draw, index, self.envs[index], plan, now())
                return self._pending
            raise RuntimeError(
                f"session {self.id}: {MAX_FAILED_DRAWS} draws in a row failed to plan"
            )

    def _skip(self, reason: str, env_index: int) -> None:
        self.log.add_event(
            self.id,
            self.iteration,
            "skip",
            {"draw": self.draws, "env_index": env_index, "reason": reason},
        )
        self.draws += 1
        self.declined.add(env_index)
        self._pending = None

    def skip(self, reason: str = "skipped by the person") -> None:
        """Leave Eᵗ uncorrected; the next proposal is the next draw."""
        with self._lock:
            pending = self.proposal()
            self._skip(reason, pending.env_index)

    def undo(self) -> None:
        """The person put the handle back (logged; the proposal stays)."""
        with self._lock:
            self.log.add_event(self.id, self.iteration, "undo", {})

    def waypoint_cup(self, waypoint: int) -> np.ndarray:
        """Cup centre (3,) at waypoint ``waypoint`` of the current plan: where its handle goes."""
        return cup_pose(self.proposal().plan.trajectory[waypoint])[1]

    def drag(self, waypoint: int, cup_position) -> np.ndarray:
        """ξ_h (T, 7) for the cup at free ``waypoint`` moved to ``cup_position`` (3,), m.

        Raises:
            Refused: a fixed or unknown waypoint, a position IK cannot reach with the hand's
                rotation, or a ξ_h that collides; the message says which (and the refusal is
                logged as an event).
        """
        with self._lock:
            pending = self.proposal()
            try:
                return self._drag(pending, waypoint, cup_position)
            except Refused as exc:
                detail = {"waypoint": waypoint, "cup": np.asarray(cup_position, float).tolist()}
                self.log.add_event(
                    self.id, self.iteration, "refused", {**detail, "reason": str(exc)}
                )
                raise

    def _drag(self, pending: Proposal, waypoint, cup_position) -> np.ndarray:
        robot = pending.plan.trajectory
        n = robot.shape[0]
        if isinstance(waypoint, bool) or not isinstance(waypoint, int | np.integer):
            raise Refused(f"waypoint {waypoint!r}: not a waypoint index")
        if not 0 < waypoint < n - 1:
            raise Refused(
                f"waypoint {waypoint}: only waypoints 1 to {n - 2} move (start and goal are fixed)"
            )
        cup = np.asarray(cup_position, dtype=float)
        if cup.shape != (3,) or not np.all(np.isfinite(cup)):
            raise Refused(f"cup position {cup_position!r}: expected 3 finite numbers")
        rotation, _ = cup_pose(robot[waypoint])
        q = cup_inverse_kinematics(cup, rotation, robot[waypoint])
        if q is None:
            raise Refused(
                f"unreachable: the arm cannot hold the cup level at ({cup[0]:.2f}, {cup[1]:.2f}, "
                f"{cup[2]:.2f}) m"
            )
        intended = robot.copy()
        intended[waypoint] = q
        corrected = np.asarray(self.correction.apply(robot, intended), dtype=float)
        report = self.checker.check_trajectory(corrected, pending.env)
        if not report.collision_free:
            pairs = ", ".join(f"{a}-{b}" for a, b in sorted(report.body_pairs()))
            raise Refused(f"collides: {pairs} (depth {report.max_depth * 100:.1f} cm)")
        return corrected

    def submit(
        self,
        corrected: np.ndarray,
        *,
        drag: Mapping | None = None,
        phi_h: np.ndarray | None = None,
    ) -> dict:
        """Update on the correction ξ_h (T, 7) of the current proposal; log it; return the row.

        Args:
            corrected: ξ_h, same start and goal as ξᵗ.
            drag: what the page reported (waypoint, handle position, ...), logged as is.
            phi_h: the features the learner sees (default Φ(ξ_h, Eᵗ); a simulated user with
                feature noise gives its own).
        """
        with self._lock:
            pending = self.proposal()
            robot = pending.plan.trajectory
            corrected = np.asarray(corrected, dtype=float)
            if corrected.shape != robot.shape or not np.all(np.isfinite(corrected)):
                raise Refused(
                    f"correction: expected finite shape {robot.shape}, got {corrected.shape}"
                )
            if not (np.allclose(corrected[0], robot[0]) and np.allclose(corrected[-1], robot[-1])):
                raise Refused("correction: the start and the goal must stay where they are")
            if phi_h is None:
                phi_h = feature_counts(corrected, pending.env, self.features)
            phi_h = np.asarray(phi_h, dtype=float)
            before = self.belief
            skipped = ""
            try:
                step = self._update(pending.env_index, pending.plan, phi_h, corrected)
            except PlanningError as exc:
                step, skipped = None, str(exc).splitlines()[0]
            after = before if step is None else step.belief
            row = {
                "iteration": self.iteration,
                "draw": pending.draw,
                "env_index": pending.env_index,
                "env_name": pending.env.name,
                "xi_robot": robot,
                "xi_h": corrected,
                "phi_robot": pending.plan.features,
                "phi_h": phi_h,
                "theta_before": before.theta,
                "cov_before": before.cov,
                "theta_after": after.theta,
                "cov_after": after.cov,
                "noise_after": after.state.noise_estimate(),
                "nis": (
                    nis(step.innovation, step.innovation_cov)
                    if step is not None and step.innovation_cov is not None
                    else None
                ),
                "drag": dict(drag or {}),
                "shown_at": pending.shown_at,
                "submitted_at": now(),
                "seconds": time.monotonic() - pending.monotonic,
                "update_skipped": skipped,
            }
            asked = self.ask()
            if asked is not None:
                # What the person was asked for, the correction's label: written first, so no
                # correction is ever without it (a label whose correction a kill lost is
                # written again when the session resumes and the person makes it).
                row["label"] = asked
                self.log.add_event(self.id, self.iteration, "label", asked)
            self.log.add_correction(self.id, row)  # committed before anyone sees the update
            if self.book.atlas is not None:
                # The plans the update solved between the atlas's nodes (an exact learner's
                # refined cells), kept for every later session and study on this machine: a
                # plan is a function of (θ, E) alone, so this changes no number, only the time
                # the next participant whose posterior goes there waits.
                self.book.atlas.save()
            if step is not None and step.relevance is not None:
                # A relevance-aware learner's β̂ and ρ: an event beside the row (the
                # corrections table keeps its schema; a replay recomputes both).
                row["relevance"] = {"beta": float(step.relevance), "rho": step.residual}
                self.log.add_event(self.id, self.iteration, "relevance", row["relevance"])
            self.last_relevance = row.get("relevance")
            self.belief = after
            self.iteration += 1
            self.draws = pending.draw + 1
            self.declined.clear()
            self._pending = None
            self.last_env = pending.env_index
            self._ask_traces()
            return row

    def _update(self, env_index: int, plan: Plan, phi_h: np.ndarray, corrected=None):
        """The learner's step for a correction with features ``phi_h`` and, where the person
        showed it, the corrected trajectory ``corrected`` (a relevance-aware learner judges it)."""
        seen = None if corrected is None else np.asarray(corrected, float)
        env = self.envs[env_index]
        return correction.step(self.agent, self._context(), self.belief, env, plan, phi_h, seen)

    def state(self, theta) -> np.ndarray:
        """Log the person's stated preference θ (k,) as the session's reference."""
        theta = np.asarray(theta, dtype=float)
        k = len(self.settings.features)  # over the study's features (not any learnt)
        if theta.shape != (k,) or not np.all(np.isfinite(theta)):
            raise Refused(f"stated θ: expected {k} finite numbers")
        with self._lock:
            self.log.state_theta(self.id, theta)
        return theta

    def finish(self) -> Deployment | None:
        """End the session: the plain and the risk-averse (A4) plan in the last Eᵗ shown
        (None if no plan could be made), logged as a ``done`` event."""
        with self._lock:
            pending = self._pending
            if pending is None and not self.ended:
                try:
                    pending = self.proposal()
                except RuntimeError:
                    pending = None
            deployment = None
            detail: dict = {"iteration": self.iteration}
            if pending is not None and self.has_covariance:
                try:
                    a4 = plan_a4(self.planner, self.belief, pending.env)
                    index = a4.index("averse")
                    deployment = Deployment(
                        pending.env, pending.plan, a4.plans[index], a4.gammas[index]
                    )
                    detail |= {"env_index": pending.env_index, "gamma": a4.gammas[index].tolist()}
                except PlanningError as exc:
                    detail["a4_failed"] = str(exc).splitlines()[0]
            self.log.add_event(self.id, self.iteration, "done", detail)
            self.log.end_session(self.id)
            self.ended = True
            return deployment


def push_record(motion: PushedMotion) -> dict:
    """What the log keeps of a push (the ``drag`` column): the force profile, the executed
    cup path and the sensed τ_h at the person's rate, where the robot found itself held (Ũ),
    when it let go, the effort and the sensing's error against the applied Jᵀ F."""
    trace = motion.trace()
    held, _ = motion.deformation()
    return {
        "mode": "physical",
        "times": np.round(trace.times, 4).tolist(),
        "force": np.round(trace.force, 4).tolist(),
        "cup": np.round(trace.cup, 5).tolist(),
        "tau_sensed": np.round(trace.tau_sensed, 4).tolist(),
        "held": held.tolist(),
        "released_at": motion.released,
        "effort": motion.effort,
        "push_time": motion.push_time,
        "peak_force": float(np.linalg.norm(trace.force, axis=1).max(initial=0.0)),
        "sense_error": None if np.isnan(error := motion.sense_error()) else error,
    }


def settings_from_log(recorded: Mapping) -> FigureSettings:
    """A study's settings from the dictionary a session logged (``FigureSettings.as_dict``)."""
    values = dict(recorded)
    values.pop("plugins", None)  # plug-ins are loaded by their files (see the session's study)
    if isinstance(values.get("learners"), dict):  # a retired parameter as what replaced it
        values["learners"] = {
            name: legacy.current_learner_params(name, params)
            for name, params in values["learners"].items()
        }
    return parse_study(values, name="interact")
