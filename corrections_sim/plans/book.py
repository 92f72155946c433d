"""Memoized plans ξ*(θ, E) for one run, the user's side of every environment, and regret.

:class:`PlanBook` solves each (θ, E) once per run (failures included); :class:`Target` holds
θ* and its plans ξ*(θ*, E); :func:`evaluate` sums the regret of θ̂ over environments. Learners
reach the planner only
through a :class:`PlanBook`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from corrections_sim.metrics import regret_terms
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import Plan, Planner, PlanningError, smoothness_cost
from corrections_sim.scene.environments import Environment
from corrections_sim.scene.robot import N_ARM_JOINTS, joint_limits

if TYPE_CHECKING:
    from corrections_sim.plans.atlas import Atlas

PlanEntries = dict[tuple[bytes, bytes], "Plan | PlanningError"]
"""Memoized solves: (θ bytes, environment key) -> the plan or the failure."""


class PlanBook:
    """Memoized ξ*(θ, E) for one run: identical problems are solved once.

    Failures are memoized too (as the exception), so a failing problem costs one solve.
    ``known`` seeds the book with plans solved elsewhere (e.g. the shared prior's, see
    :meth:`entries`); they count as neither solves nor failures here.

    With an ``atlas``, every problem is answered by the atlas (warm from its cell's corner
    plans, cold outside its box), so a plan is a function of (θ, E) alone and ``warm_start``
    is ignored. Without, and with ``warm_start``, a new problem starts from the book's plan
    in the same environment whose θ is nearest (Euclidean; the first solved wins a tie), and
    falls back to the planner's cold starts if that fails. Along a run θ̂ moves in small
    steps, so this saves IPOPT iterations; the answer can then depend on what was solved
    before (the same local optimum up to the solver's tolerance when the landscape has one
    basin nearby: docs/speed.md).
    """

    def __init__(
        self,
        planner: Planner,
        known: PlanEntries | None = None,
        *,
        warm_start: bool = False,
        atlas: Atlas | None = None,
    ) -> None:
        if atlas is not None and atlas.planner.config != planner.config:
            raise ValueError("PlanBook: the atlas was built for another planner configuration")
        self.planner = planner
        self.warm_start = warm_start and atlas is None
        #: Where plans come from when set: ξ*(θ, E) from the atlas alone, whatever was
        #: solved before (:meth:`~corrections_sim.plans.atlas.Atlas.solve`).
        self.atlas = atlas
        self._plans: dict[tuple[bytes, bytes], Plan | PlanningError] = dict(known or {})
        # Per environment, the converged plans in the order they were solved.
        self._by_env: dict[bytes, _History] = {}
        for (theta, env_key), plan in self._plans.items():
            if isinstance(plan, Plan):
                self._by_env.setdefault(env_key, _History()).add(np.frombuffer(theta), plan)
        self.solves = 0
        self.failures = 0

    @staticmethod
    def _key(theta: np.ndarray, env: Environment) -> tuple[bytes, bytes]:
        return (np.asarray(theta, float).tobytes(), env.key())

    def entries(self) -> PlanEntries:
        """Everything solved so far (plans and failures), to seed other books with."""
        return dict(self._plans)

    def nearest(self, theta: np.ndarray, env: Environment) -> tuple[np.ndarray, Plan] | None:
        """The warm start of (θ, E): the solved (θ', plan) in E whose θ' is nearest θ
        (Euclidean; the first solved wins a tie), or None without warm starts or plans in E."""
        history = self._by_env.get(env.key()) if self.warm_start else None
        return None if history is None else history.nearest(np.asarray(theta, float))

    def _solve(self, theta: np.ndarray, env: Environment) -> Plan:
        if self.atlas is not None:
            return self.atlas.solve(theta, env)
        near = self.nearest(theta, env)
        if near is not None:
            try:
                return self.planner.solve(theta, env, inits=[near[1].trajectory])
            except PlanningError:
                self.solves += 1  # the warm start failed; the cold starts get their chance
        return self.planner.solve(theta, env)

    def plan(self, theta: np.ndarray, env: Environment) -> Plan:
        theta = np.asarray(theta, float)
        key = self._key(theta, env)
        hit = self._plans.get(key)
        if hit is None:
            self.solves += 1
            try:
                hit = self._solve(theta, env)
                self._by_env.setdefault(key[1], _History()).add(theta.copy(), hit)
            except PlanningError as exc:
                self.failures += 1
                hit = exc
            self._plans[key] = hit
        if isinstance(hit, PlanningError):
            raise hit
        return hit

    def observe(self, env: Environment) -> Callable[[np.ndarray], np.ndarray]:
        """h(θ) = Φ(ξ*(θ, E), E) as the learners' batch callable (n, k) -> (n, k)."""

        def h(thetas: np.ndarray) -> np.ndarray:
            return np.array([self.plan(t, env).features for t in np.atleast_2d(thetas)])

        return h


class TrailBook(PlanBook):
    """A :class:`PlanBook` that shares its solves with the other books of ``memo`` that asked
    the same problems in the same order before it.

    A book's answer to a new problem depends on the problem and on what the book solved before
    (its warm start is the nearest plan it holds), and on nothing else: so a book that has been
    asked the same sequence of new problems as another holds the same plans, and its next solve
    of the same problem is the other's to the bit. Each solve is kept in ``memo`` under a digest
    of that sequence and the problem, and taken from there by the next book along the same
    trail. Used where one past is read again under several hypotheses that ask the same problems
    until they differ (KF-CRX's expansion: the first correction's sigma points are the same
    under every noise share). ``solves`` counts as a PlanBook's does (every new problem);
    ``taken`` those of them it took from ``memo``."""

    def __init__(self, planner: Planner, memo: dict, **kwargs) -> None:
        super().__init__(planner, **kwargs)
        self._memo = memo
        self._trail = b""
        self.taken = 0

    def _solve(self, theta: np.ndarray, env: Environment) -> Plan:
        trail = hashlib.sha256(self._trail + self._key(theta, env)[0] + env.key()).digest()
        self._trail = trail
        found = self._memo.get(trail)
        if found is None:
            try:
                found = super()._solve(theta, env)
            except PlanningError as exc:
                found = exc
            self._memo[trail] = found
        else:
            self.taken += 1
        if isinstance(found, PlanningError):
            raise found
        return found


RESTART_BUMP_STD = 0.4  # rad, std of each sine coefficient of a random restart
RESTART_MODES = 3  # sine modes per joint in a random restart's perturbation


def random_starts(
    env: Environment, n_waypoints: int, count: int, rng: np.random.Generator
) -> list[np.ndarray]:
    """The straight joint-space line, then ``count - 1`` smooth random bends of it.

    A bend adds Σ_m a_m sin(mπs) per joint (s ∈ [0, 1] along the path, m = 1..RESTART_MODES,
    a_m ~ N(0, (RESTART_BUMP_STD/m)²)), so start and goal stay fixed; clipped to the limits.
    """
    s = np.linspace(0.0, 1.0, n_waypoints)[:, None]  # (T, 1)
    line = (1 - s) * env.q_start + s * env.q_goal  # (T, 7)
    lo, hi = joint_limits()
    modes = np.arange(1, RESTART_MODES + 1)
    out = [line]
    for _ in range(count - 1):
        coeffs = rng.normal(0.0, RESTART_BUMP_STD / modes[:, None], (RESTART_MODES, N_ARM_JOINTS))
        bend = np.sin(np.pi * s * modes) @ coeffs  # (T, 7)
        out.append(np.clip(line + bend, lo, hi))
    return out


def own_starts(env: Environment, n_waypoints: int, count: int) -> list[np.ndarray]:
    """:func:`random_starts` drawn from a generator seeded by the environment alone, so that
    the same environment gets the same starts in any run, order or process."""
    seed = int.from_bytes(hashlib.sha256(b"starts|" + env.key()).digest()[:8], "little")
    return random_starts(env, n_waypoints, count, np.random.default_rng(seed))


class _History:
    """One environment's converged plans in the order they were solved, their θ stacked for
    the nearest-θ search."""

    def __init__(self) -> None:
        self.thetas = np.empty((0, 0))
        self.plans: list[Plan] = []

    def add(self, theta: np.ndarray, plan: Plan) -> None:
        row = np.asarray(theta, float)[None, :]
        self.thetas = row if not self.plans else np.concatenate([self.thetas, row])
        self.plans.append(plan)

    def nearest(self, theta: np.ndarray) -> tuple[np.ndarray, Plan]:
        # Row by row the same sums as one θ at a time (k < 8 terms add in order), and argmin
        # takes the first of equals.
        i = int(np.argmin(np.sum((self.thetas - theta) ** 2, axis=1)))
        return self.thetas[i], self.plans[i]


@dataclass(frozen=True)
class Target:
    """The user's side of every environment: θ* and its optimal plans ξ*(θ*, E).

    Attributes:
        theta_star: the person's θ*, over ``features``.
        plans: ξ*(θ*, E) per environment, solved over the person's features.
        features: the features the person weighs, when they are not the robot's (a person
            who cares about what the robot does not know); None: the robot's own.
    """

    theta_star: np.ndarray
    plans: tuple[Plan, ...]
    features: tuple[str, ...] | None = None

    @classmethod
    def solve(
        cls,
        planner: Planner,
        theta_star,
        envs: Sequence[Environment],
        *,
        atlas: Atlas | None = None,
        restarts: int = 0,
        store=None,
    ) -> Target:
        """θ* and its plans with ``planner``, whose features are the person's; they are
        recorded when they differ from the robot's (see :func:`evaluate`).

        With ``restarts`` > 0 each plan is the best of the planner's cold starts, ``atlas``'s
        answer (when given; an atlas of the person's planner) and ``restarts`` random starts
        of the environment's own (:func:`own_starts`): the person's plans are what regret is
        measured against, so they get the search a figure's plans do not. ``store``: where
        such plans are kept once solved (:class:`~corrections_sim.plans.targets.TargetStore`;
        None: solved here)."""
        theta = np.asarray(theta_star, float)
        if atlas is not None and atlas.planner.config != planner.config:
            raise ValueError("Target.solve: the atlas was built for another planner")
        return cls(
            theta_star=theta,
            plans=_plans(planner, theta, envs, atlas, restarts, store),
            features=planner.config.features,
        )

    def person_features(self, plan: Plan, env: Environment, robot: tuple[str, ...]) -> np.ndarray:
        """Φ of a robot's ``plan`` over the person's features (the plan's own when the
        person weighs the robot's features ``robot``)."""
        if self.features is None or tuple(self.features) == tuple(robot):
            return plan.features
        return feature_counts(plan.trajectory, env, self.features)


def _plans(
    planner: Planner,
    theta: np.ndarray,
    envs: Sequence[Environment],
    atlas: Atlas | None,
    restarts: int,
    store,
) -> tuple[Plan, ...]:
    """:func:`_best_plan`'s in each of ``envs``, read from ``store`` where it holds them, kept
    there once solved."""
    if store is None:
        return tuple(_best_plan(planner, theta, e, atlas, restarts) for e in envs)
    out = []
    for env, key in zip(
        envs, store.keys(planner.config, envs, theta, restarts, atlas), strict=True
    ):
        found = store.load(key, planner.config.n_waypoints, planner.config.k)
        if found is None:
            found = _best_plan(planner, theta, env, atlas, restarts)
            store.save(key, found)
        out.append(found)
    return tuple(out)


def _best_plan(
    planner: Planner, theta: np.ndarray, env: Environment, atlas: Atlas | None, restarts: int
) -> Plan:
    """The best of the cold starts, the atlas's answer and ``restarts`` random starts."""
    if isinstance(restarts, bool) or not isinstance(restarts, int) or restarts < 0:
        raise ValueError(f"restarts = {restarts!r}: expected an integer >= 0")
    candidates, failures = [], []
    tries = [lambda: planner.solve(theta, env)]
    if atlas is not None:
        tries.append(lambda: atlas.solve(theta, env))
    if restarts:
        starts = own_starts(env, planner.config.n_waypoints, restarts)
        tries.append(lambda: planner.solve(theta, env, inits=starts))
    for attempt in tries:
        try:
            candidates.append(attempt())
        except PlanningError as exc:
            failures.append(exc)
    if not candidates:
        raise failures[0]
    return max(candidates, key=lambda plan: plan.reward)  # the first of equals


def evaluate(
    book: PlanBook, target: Target, envs: Sequence[Environment], theta_hat: np.ndarray
) -> tuple[float, float, int]:
    """(regret, paper regret, failed environments) of θ̂ summed over ``envs``.

    The regret is the person's: their full objective θ*·Φ − λS over their own features, which
    for a person who weighs features the robot lacks includes what the robot cannot see.

    An environment whose plan fails is left out of both sums and counted instead.
    """
    lam = book.planner.config.smoothness
    full = paper = 0.0
    failed = 0
    for env, star in zip(envs, target.plans, strict=True):
        try:
            plan = book.plan(theta_hat, env)
        except PlanningError:
            failed += 1
            continue
        f, p = regret_terms(
            target.theta_star,
            star.features,
            smoothness_cost(star.trajectory),
            target.person_features(plan, env, book.planner.config.features),
            smoothness_cost(plan.trajectory),
            lam,
        )
        full += f
        paper += p
    return full, paper, failed
