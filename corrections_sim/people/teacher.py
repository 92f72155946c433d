"""A simulated person who teaches a feature they know by feature traces (FERL's protocol).

Asked for N traces, the teacher (as FERL's participants did) puts the arm where the feature is
highest, then moves it to where it is low. Where it is "high" is their judgement: of a few
reachable configurations they look at (``candidates``), they take the one that seems highest
and search from there, moving the arm a little at a time toward where it seems higher still
(``search`` rounds of ``SEARCH_TRIES`` small moves each), and start the trace where that
search ends; they end it at the one of ``candidates`` more places that seems lowest. They
judge "high" relatively, as a place's standing among the arm's reachable places (its
quantile over the workspace), with noise (``label_noise``, an sd in quantile: at 0.05 a place
at the 90th percentile seems anywhere from the 80th to the 100th): the labels a trace implies
are wrong by about that much; where two places stand alike (the workspace's top), the one
where the feature is higher seems higher. (In the
feature's own units an error would mean different things for different features: `human` is
below 0.001 on half the workspace.) The path between is the one a person pushing an arm
takes: the straight joint-space line, bent by a smooth random detour (``path_noise``, rad at
mid-path) and jittered state by state (a tenth of it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.learnt.training import reachable, reachable_mask, workspace
from corrections_sim.planning.features import FEATURES, waypoint_features
from corrections_sim.scene.environments import Environment
from corrections_sim.scene.robot import joint_limits

#: The teacher's search for a start: small moves tried a round (rad, sd per joint).
SEARCH_TRIES, SEARCH_STEP = 8, 0.1


@dataclass(frozen=True)
class Teacher:
    """How a simulated person gives feature traces.

    Attributes:
        states: configurations per trace (>= 2).
        candidates: configurations they look at to choose a start, and again an end (>= 1).
        path_noise: sd of the path's smooth detour at mid-path (rad, >= 0).
        label_noise: sd of their misjudgement of a place's quantile (>= 0).
        search: rounds of their search for the start, from the best-seeming candidate toward
            where the feature seems higher (>= 0; 0: start at that candidate).
    """

    states: int = 12
    candidates: int = 20
    path_noise: float = 0.1
    label_noise: float = 0.05
    search: int = 30

    def __post_init__(self) -> None:
        for name, low in (("states", 2), ("candidates", 1), ("search", 0)):
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

        def seen(q: np.ndarray) -> np.ndarray:
            """How high places seem: their quantile misjudged, then (ties of the quantile,
            at the workspace's top) the feature itself."""
            value = waypoint_features(q, env, (feature,))[:, 0]
            quantile = np.searchsorted(ranked, value, side="right") / ranked.size
            noisy = quantile + self.label_noise * rng.standard_normal(value.shape)
            return np.stack([noisy, value], axis=1)

        def best(judged: np.ndarray, sign: float) -> int:
            order = np.lexsort((sign * judged[:, 1], sign * judged[:, 0]))
            return int(order[-1])

        s = np.linspace(0.0, 1.0, self.states)[:, None]
        out = []
        for _ in range(n):
            ends = []
            for sign in (1.0, -1.0):  # the start: seems highest; the end: seems lowest
                q = reachable(env, self.candidates, rng)
                judged = seen(q)
                i = best(judged, sign)
                here, how = q[i], judged[i]
                for _ in range(self.search if sign > 0 else 0):
                    tries = np.clip(
                        here + SEARCH_STEP * rng.standard_normal((SEARCH_TRIES, 7)), lo, hi
                    )
                    tries = tries[reachable_mask(tries, env)]
                    if not tries.shape[0]:
                        continue
                    them = seen(tries)
                    j = best(them, 1.0)
                    if (them[j, 0], them[j, 1]) > (how[0], how[1]):
                        here, how = tries[j], them[j]
                ends.append(here)
            detour = self.path_noise * rng.standard_normal(7)
            jitter = 0.1 * self.path_noise * rng.standard_normal((self.states, 7))
            jitter[[0, -1]] = 0.0
            path = (1 - s) * ends[0] + s * ends[1] + np.sin(np.pi * s) * detour + jitter
            out.append(np.clip(path, lo, hi))
        return out
