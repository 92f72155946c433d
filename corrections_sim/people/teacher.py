"""A simulated person who teaches a feature they know by feature traces (FERL's protocol).

Asked for N traces, the teacher (as FERL's participants did) puts the arm where the feature is
high, then moves it to where it is low. Where it is "high" is their judgement: of a few
reachable configurations they look at (``candidates``), they start at the one that seems
highest and end at the one that seems lowest. They judge "high" relatively, as a place's
standing among the arm's reachable places (its quantile over the workspace), with noise
(``label_noise``, an sd in quantile: at 0.05 a place at the 90th percentile seems anywhere from
the 80th to the 100th): the labels a trace implies are wrong by about that much. (In the
feature's own units an error would mean different things for different features: `human` is
below 0.001 on half the workspace.) The path between is the one a person pushing an arm
takes: the straight joint-space line, bent by a smooth random detour (``path_noise``, rad at
mid-path) and jittered state by state (a tenth of it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.learnt.training import reachable, workspace
from corrections_sim.planning.features import FEATURES, waypoint_features
from corrections_sim.scene.environments import Environment
from corrections_sim.scene.robot import joint_limits


@dataclass(frozen=True)
class Teacher:
    """How a simulated person gives feature traces.

    Attributes:
        states: configurations per trace (>= 2).
        candidates: configurations they look at to choose a start, and again an end (>= 1).
        path_noise: sd of the path's smooth detour at mid-path (rad, >= 0).
        label_noise: sd of their misjudgement of a place's quantile (>= 0).
    """

    states: int = 12
    candidates: int = 20
    path_noise: float = 0.1
    label_noise: float = 0.05

    def __post_init__(self) -> None:
        for name, low in (("states", 2), ("candidates", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
                raise ValueError(f"teacher.{name} = {value!r} must be an integer >= {low}")
        for name in ("path_noise", "label_noise"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"teacher.{name} = {value} must be finite and >= 0")

    def traces(
        self, feature: str, n: int, env: Environment, rng: np.random.Generator
    ) -> list[np.ndarray]:
        """``n`` traces (states, 7) of the registered ``feature`` in ``env``, high to low."""
        if feature not in FEATURES:
            raise ValueError(f"teacher: unknown feature {feature!r}")
        if n < 1:
            raise ValueError(f"teacher: asked for {n} traces; at least 1")
        lo, hi = joint_limits()
        ranked = np.sort(waypoint_features(workspace(env), env, (feature,))[:, 0])
        s = np.linspace(0.0, 1.0, self.states)[:, None]
        out = []
        for _ in range(n):
            ends = []
            for sign in (1.0, -1.0):  # the start: seems highest; the end: seems lowest
                q = reachable(env, self.candidates, rng)
                value = waypoint_features(q, env, (feature,))[:, 0]
                quantile = np.searchsorted(ranked, value, side="right") / ranked.size
                seen = quantile + self.label_noise * rng.standard_normal(value.shape)
                ends.append(q[int(np.argmax(sign * seen))])
            detour = self.path_noise * rng.standard_normal(7)
            jitter = 0.1 * self.path_noise * rng.standard_normal((self.states, 7))
            jitter[[0, -1]] = 0.0
            path = (1 - s) * ends[0] + s * ends[1] + np.sin(np.pi * s) * detour + jitter
            out.append(np.clip(path, lo, hi))
        return out
