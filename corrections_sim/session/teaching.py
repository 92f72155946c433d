"""Teaching a feature in a session: the learner asks for feature traces after a correction
(KF-CRX, :meth:`Learner.wants_traces <corrections_sim.learning.base.Learner.wants_traces>`),
the person gives them (each logged as it starts and ends, so a crash mid-trace is known), and
the feature is learnt from them and planned over from then on; a resume retrains it from the
logged traces and checks the weights. :class:`Teaching` is the part of
:class:`~corrections_sim.session.session.Session` that does it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np

from corrections_sim.planning.compiled import BuildError
from corrections_sim.planning.planner import shared_planner
from corrections_sim.plans.book import PlanBook
from corrections_sim.session.refused import Refused

#: The fewest feature traces a person may stop teaching after (fewer than the learner asks
#: for give a rougher feature; one trace ranks only the states along one path).
MIN_TRACES = 3

#: The kinds of event a resume reads to replay the teaching of a feature (in the log's order).
TEACH_EVENTS = ("trace_start", "trace_cancelled", "trace_lost", "trace", "traces", "learnt")


def teach_rng(seed: int, iteration: int) -> np.random.Generator:
    """The generator a feature learnt after ``iteration`` corrections is trained with."""
    return np.random.default_rng(np.random.SeedSequence([seed, 39, iteration]))


class Teaching:
    """A session's feature teaching (a part of
    :class:`~corrections_sim.session.session.Session`, which owns the log, the learner and
    the belief these methods read and change)."""

    @property
    def learnt_before_stop(self) -> int | None:
        """How many traces the feature was learnt from when a resumed session's last step
        was that learning (the server stopped after the person's last trace, in the training
        or just after it): the page tells the person, until their next correction. Else
        None."""
        note = self._learnt_before
        return None if note is None or note["iteration"] != self.iteration else note["traces"]

    def _replay_teaching(self, events: list[dict]) -> None:
        """The traces given after a correction, and the feature learnt from them (retrained:
        the same traces, the same seed give the logged weights, checked). Traces all logged
        without a ``learnt`` event (a kill during the training): the feature is learnt now."""
        learnt = False
        for event in events:
            kind, detail = event["kind"], event["detail"]
            if kind == "trace_start":
                self.open_trace = detail
            elif kind in ("trace_cancelled", "trace_lost"):
                self.open_trace = None
            elif kind == "trace":
                self.open_trace = None
                self.traces.append(np.asarray(detail["states"], float))
            elif kind == "traces" and detail.get("declined"):
                self.belief = self.agent.declined(self.belief)
                self.wanted, self.traces, self.open_trace = 0, [], None
            elif kind == "traces" and "enough" in detail:
                self.wanted = int(detail["enough"])  # the person stopped there
            elif kind == "learnt":
                belief, facts = self.agent.grow(
                    self.belief,
                    self.envs[int(detail["env_index"])],
                    self.traces,
                    teach_rng(self.seed, self.iteration),
                    self._context(),
                )
                if facts["feature"] != detail["feature"]:
                    raise ValueError(
                        f"session {self.id}: retraining the feature learnt after correction "
                        f"{self.iteration - 1} gives {facts['feature']}, the log has "
                        f"{detail['feature']} (other code or settings?)"
                    )
                self._grown(belief)
                self._learnt_before = {"traces": len(self.traces), "iteration": self.iteration}
                self.wanted, self.traces = 0, []
                learnt = True
        if not learnt and self.wanted and len(self.traces) >= self.wanted:
            self._grow(self.traces)  # logged now: the kill came before it was
            self._learnt_before = {"traces": len(self.traces), "iteration": self.iteration}
            self.wanted, self.traces = 0, []

    def _ask_traces(self) -> None:
        """Whether the learner now asks for feature traces (after each correction)."""
        self.wanted = int(self.agent.wants_traces(self.belief, self.iteration))
        self.traces, self.open_trace = [], None

    def start_trace(self, detail: Mapping) -> None:
        """The person starts a trace (``detail``: where, e.g. the cup and the arm's q), logged
        as a ``trace_start`` event before anything is recorded, so a crash mid-trace is known.

        Raises:
            Refused: none is asked for, or a trace is already being recorded.
        """
        with self._lock:
            self._check_open()
            if self.wanted <= len(self.traces):
                raise Refused("trace: the robot asks for no (more) traces now")
            if self.open_trace is not None:
                raise Refused("trace: one is being recorded; end or cancel it first")
            self.open_trace = {"index": len(self.traces), **dict(detail)}
            self.lost_trace = None
            self.log.add_event(self.id, self.iteration, "trace_start", self.open_trace)

    def cancel_trace(self) -> None:
        """The trace being recorded is dropped (logged as ``trace_cancelled``).

        Raises:
            Refused: no trace is being recorded.
        """
        with self._lock:
            self._check_open()
            if self.open_trace is None:
                raise Refused("cancel: no trace is being recorded")
            self.log.add_event(
                self.id, self.iteration, "trace_cancelled", {"index": len(self.traces)}
            )
            self.open_trace = None

    def add_trace(self, configurations, detail: Mapping | None = None) -> int:
        """One feature trace, arm configurations (n, 7) from high to low, logged as a
        ``trace`` event (it ends the trace :meth:`start_trace` began, if one did); returns
        how many are still wanted.

        Raises:
            Refused: none is asked for, or the trace is malformed (fewer than two states,
                a value not finite: the message says which).
        """
        from corrections_sim.learnt.training import check_traces

        with self._lock:
            self._check_open()
            if self.wanted <= len(self.traces):
                raise Refused("trace: the robot asks for no (more) traces now")
            try:
                (trace,) = check_traces([np.asarray(configurations, float)])
            except ValueError as exc:
                raise Refused(str(exc)) from None
            self.log.add_event(
                self.id,
                self.iteration,
                "trace",
                {"index": len(self.traces), "states": trace.tolist(), **dict(detail or {})},
            )
            self.traces.append(trace)
            self.open_trace = None
            return self.wanted - len(self.traces)

    @property
    def fewest_traces(self) -> int:
        """How many traces the person must give before they may stop and have the robot learn
        from those (:data:`MIN_TRACES`, or all asked for if fewer)."""
        return min(MIN_TRACES, self.wanted)

    def learn_feature(self, *, stop: bool = False) -> str:
        """Learn the feature from the traces given, log it as a ``learnt`` event and plan
        over it from now on; returns its name. ``stop``: the person stops before giving all
        that were asked for (at least :attr:`fewest_traces`), logged first as a ``traces``
        event with ``enough``.

        Raises:
            Refused: fewer traces than asked for (or with ``stop``, than the fewest), a trace
                being recorded, traces that rank nothing, or a planner over the learnt
                feature that gcc could not build (one line each; the traces stay given).
        """
        with self._lock:
            self._check_open()
            given = len(self.traces)
            if self.open_trace is not None:
                raise Refused("learn: a trace is being recorded; end or cancel it first")
            if not self.wanted or given < (self.fewest_traces if stop else self.wanted):
                need = "at least " + str(self.fewest_traces) if stop else "them all"
                raise Refused(f"learn: {given} of {self.wanted} traces given; give {need}")
            if given < self.wanted:
                self.log.add_event(
                    self.id, self.iteration, "traces", {"enough": given, "asked": self.wanted}
                )
                self.wanted = given
            try:
                name = self._grow(self.traces)
            except (ValueError, BuildError) as exc:
                raise Refused(str(exc).splitlines()[0]) from None
            self.wanted, self.traces = 0, []
            return name

    def decline_traces(self) -> int:
        """Nobody will teach: the learner is told so (it does not ask again); logged, with how
        many traces were given and are set aside (they stay in the log, not learnt from).
        Returns that number."""
        with self._lock:
            self._check_open()
            if not self.wanted:
                raise Refused("decline: the robot asks for no traces now")
            given = len(self.traces)
            if self.open_trace is not None:
                self.cancel_trace()
            self.log.add_event(
                self.id, self.iteration, "traces", {"declined": True, "set_aside": given}
            )
            self.belief = self.agent.declined(self.belief)
            self.wanted, self.traces = 0, []
            return given

    def _grow(self, traces: list[np.ndarray]) -> str:
        env = self.envs[int(self.last_env)]
        rng = teach_rng(self.seed, self.iteration)
        belief, facts = self.agent.grow(self.belief, env, traces, rng, self._context())
        name = facts["feature"]
        from corrections_sim.planning.features import FEATURES

        f = FEATURES[name]
        self.log.add_event(
            self.id,
            self.iteration,
            "learnt",
            {
                "feature": name,
                "env_index": int(self.last_env),
                "traces": len(traces),
                "inputs": list(f.network.inputs),
                "hidden": list(f.network.hidden),
                "weights": np.asarray(f.weights).tolist(),
                "loss": facts["loss"],
                "variance": facts["variance"],
                "noise": facts["noise"],
                "candidates": facts["candidates"],
                "evidence": facts["evidence"],
            },
        )
        self._grown(belief)
        return name

    def _grown(self, belief) -> None:
        """The belief after learning a feature, and the planner over the features it has."""
        self.belief = belief
        self.features = self.settings.features + tuple(belief.extra)
        config = dataclasses.replace(self.settings.planner_config(), features=self.features)
        self.planner = shared_planner(config)
        self.book = PlanBook(self.planner, warm_start=self.settings.study.warm_start)
