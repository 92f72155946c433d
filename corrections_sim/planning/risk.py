r"""Risk-sensitive deployment with the belief's uncertainty, paper §5, eqs. (A2)–(A4).

After learning, the robot holds a belief N(θ̂, P). Instead of planning with θ̂ alone it plans
with a set of 2k + 1 preferences one standard deviation around θ̂, eq. (A2):

    Γ₀ = θ̂,   Γ_i = θ̂ + s_i,   Γ_{k+i} = θ̂ − s_i   (i = 1 … k),   S = √P = [s_1 … s_k]

where √P is the symmetric (principal) square root, S = Sᵀ, S S = P. "One standard deviation"
means: every s_i lies on the 1-σ ellipsoid of the belief, s_iᵀ P⁻¹ s_i = 1 (Mahalanobis
length 1), and the 2k offsets ±s_i reproduce the covariance, ½ Σ_i (s_i s_iᵀ + s_i s_iᵀ) =
S Sᵀ = P. For a diagonal P, s_i = √P_ii e_i: the marginal standard deviation of weight i.

With R_γ(ξ) = γ·Φ(ξ, E) − λ·S(ξ) (the planner's objective; S is the smoothness cost):

* (A3) risk-averse, exact: ξ = argmax_ξ min_{γ ∈ Γ} R_γ(ξ) — :class:`WorstCasePlanner`, one
  NLP in epigraph form: maximize t − λ·S(ξ) subject to t ≤ γ_j·Φ(ξ, E) for every j and the
  planner's clearance constraints. (S does not depend on γ, so it leaves the min.)
* (A4) the paper's simplification, the order of optimization reversed: with
  V(γ) = max_ξ R_γ(ξ), a risk-averse robot deploys ξ*(argmin_γ V(γ)), a risk-seeking one
  ξ*(argmax_γ V(γ)), a risk-neutral one ξ*(θ̂) — :func:`plan_a4`.

The risk-seeking analogue of (A3), max_ξ max_γ R_γ(ξ), *is* (A4)'s risk-seeking rule: two
maxima commute, so the best of the 2k + 1 plans ξ*(γ_j) solves it exactly (up to the local
optima of each ξ*(γ_j)). Only the risk-averse rule needs its own NLP.

Because Φ ≥ 0 (every feature is a sum of values in [0, 1]), V is non-decreasing in each
weight, so (A4)'s averse choice is always some θ̂ − s_i and its seeking choice some θ̂ + s_i:
the risk-averse robot lowers the weight of the feature whose uncertainty costs most, and so
collects fewer of that feature; the risk-seeking robot collects more.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

from corrections_sim.belief import Belief
from corrections_sim.planning.features import feature_counts, waypoint_features
from corrections_sim.planning.planner import (
    Plan,
    Planner,
    PlannerConfig,
    PlanningError,
    best_start,
    check_inits,
    initial_guesses,
    smoothness_cost,
    solver_options,
    trajectory_terms,
)
from corrections_sim.scene.environments import Environment
from corrections_sim.scene.robot import N_ARM_JOINTS, joint_limits
from corrections_sim.scene.world import CollisionChecker

#: Deployment attitudes of eq. (A4), in the order figures list them.
ATTITUDES = ("averse", "neutral", "seeking")


#: IPOPT statuses accepted as a converged solve (as in :mod:`corrections_sim.planning.planner`).
def matrix_sqrt(cov) -> np.ndarray:
    """Symmetric square root S of a symmetric positive definite P: S = Sᵀ, S S = P.

    Computed from the eigendecomposition P = V diag(λ) Vᵀ as V diag(√λ) Vᵀ.

    Args:
        cov: P, shape (k, k), symmetric positive definite.

    Returns:
        S, shape (k, k).

    Raises:
        ValueError: if P is not a finite, symmetric, positive definite square matrix (the
            message names ``cov``).
    """
    arr = np.asarray(cov, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or arr.shape[0] == 0:
        raise ValueError(f"cov: expected a square matrix of shape (k, k), got {arr.shape}")
    belief = _belief(np.zeros(arr.shape[0]), arr)
    eigenvalues, vectors = np.linalg.eigh(belief.cov)
    root = (vectors * np.sqrt(eigenvalues)) @ vectors.T
    return 0.5 * (root + root.T)


def preference_set(belief: Belief) -> np.ndarray:
    """Γ of eq. (A2): θ̂ and θ̂ ± each column of √P.

    Args:
        belief: N(θ̂, P) with k weights.

    Returns:
        Γ, shape (2k + 1, k): row 0 is θ̂, rows 1 … k are θ̂ + s_i, rows k + 1 … 2k are
        θ̂ − s_i, with s_i the i-th column of :func:`matrix_sqrt` (P).
    """
    root = matrix_sqrt(belief.cov)
    return np.vstack([belief.theta, belief.theta + root.T, belief.theta - root.T])


def worst_case_reward(gammas, features, smoothness: float, smoothness_weight: float) -> float:
    """min_j γ_j·Φ − λ·S: the objective of eq. (A3) for one trajectory.

    Args:
        gammas: Γ, shape (m, k).
        features: Φ(ξ, E), shape (k,).
        smoothness: S(ξ).
        smoothness_weight: λ.
    """
    gammas = np.asarray(gammas, float)
    return float(np.min(gammas @ np.asarray(features, float)) - smoothness_weight * smoothness)


def a4_index(values, attitude: str) -> int:
    """Which γ of Γ eq. (A4) deploys with.

    Args:
        values: V(γ_j) = max_ξ R_{γ_j}(ξ) for each row of Γ, shape (2k + 1,); row 0 is θ̂.
        attitude: "averse" (argmin V), "neutral" (θ̂, index 0) or "seeking" (argmax V).

    Returns:
        The row of Γ; ties go to the lowest index.
    """
    values = np.asarray(values, float)
    if values.ndim != 1 or values.size == 0 or not np.all(np.isfinite(values)):
        raise ValueError(f"values: expected a finite vector (2k + 1,), got {values.tolist()}")
    if attitude == "averse":
        return int(np.argmin(values))
    if attitude == "seeking":
        return int(np.argmax(values))
    if attitude == "neutral":
        return 0
    raise ValueError(f"attitude {attitude!r}: choose one of {', '.join(ATTITUDES)}")


@dataclass(frozen=True, eq=False)
class A4Plans:
    """ξ*(γ, E) for every γ of Γ, and the choices of eq. (A4).

    Attributes:
        gammas: Γ, shape (2k + 1, k).
        plans: ξ*(γ_j, E) for each row of Γ.
    """

    gammas: np.ndarray
    plans: tuple[Plan, ...]

    @property
    def values(self) -> np.ndarray:
        """V(γ_j) = γ_j·Φ(ξ*(γ_j)) − λ·S(ξ*(γ_j)), shape (2k + 1,)."""
        return np.array([p.reward for p in self.plans])

    def index(self, attitude: str) -> int:
        """The row of Γ that ``attitude`` deploys with (see :func:`a4_index`)."""
        return a4_index(self.values, attitude)

    def plan(self, attitude: str) -> Plan:
        """The deployed trajectory ξ*(γ_attitude, E)."""
        return self.plans[self.index(attitude)]


def plan_a4(planner: Planner, belief: Belief, env: Environment) -> A4Plans:
    """Solve ξ*(γ, E) for every γ ∈ Γ(belief), eq. (A4).

    Raises:
        PlanningError: if any of the 2k + 1 problems fails (V of that γ is then unknown,
            and so is the choice).
    """
    gammas = preference_set(belief)
    return A4Plans(gammas=gammas, plans=tuple(planner.solve(g, env) for g in gammas))


def refine_a4(
    planner: Planner, a4: A4Plans, env: Environment, trajectories: Sequence[np.ndarray]
) -> A4Plans:
    """(A4) with every ξ*(γ_j, E) re-solved from ``trajectories`` too; the better plan is kept.

    The values V(γ_j) of :func:`plan_a4` are local optima of the planner. Starting each
    γ_j also from the other preferences' plans (and, e.g., the (A3) trajectory) can only
    raise them, so the choice of (A4) is then about the rule, not about the local optimizer.
    With the (A3) trajectory among the starts, min_j V(γ_j) ≥ its worst case (weak duality
    made to hold for the computed values). A γ whose re-solve fails keeps its plan.
    """
    plans = []
    for gamma, plan in zip(a4.gammas, a4.plans, strict=True):
        try:
            again = planner.solve(gamma, env, inits=list(trajectories))
        except PlanningError:
            again = plan
        plans.append(again if again.reward > plan.reward else plan)
    return A4Plans(gammas=a4.gammas, plans=tuple(plans))


@dataclass(frozen=True, eq=False)
class WorstCasePlan:
    """A converged solve of eq. (A3).

    Attributes:
        trajectory: waypoints (T, 7), start and goal included.
        features: Φ(ξ, E), shape (k,).
        worst_reward: min_j γ_j·Φ(ξ, E) − λ·S(ξ), the maximized objective.
        binding: the rows j of Γ whose γ_j·Φ lies within 1e-6 of the minimum (the
            preferences the trajectory is hedged against).
        status: IPOPT's return status of the kept start.
        iterations: IPOPT iterations of the kept start.
        solve_time: wall time of the whole call (all starts), seconds.
        starts: how many initial guesses were tried.
    """

    trajectory: np.ndarray
    features: np.ndarray
    worst_reward: float
    binding: tuple[int, ...]
    status: str
    iterations: int
    solve_time: float
    starts: int


class WorstCasePlanner:
    """The exact risk-averse trajectory of eq. (A3), in epigraph form.

    Decision (x, t) with x the free waypoints; parameters Γ (2k + 1, k), the environment,
    the end points, and c = φ(q_start) + φ(q_goal) (the fixed waypoints' features, which
    shift each γ_j·Φ differently and so matter to the min):

        maximize    t − λ·S(ξ)
        subject to  t ≤ γ_j·(Φ_free(ξ) + c)   for j = 0 … 2k
                    the planner's table and laptop clearances at every free waypoint.

    The constraint set is the planner's (:func:`corrections_sim.planning.planner.trajectory_terms`),
    and like :meth:`Planner.solve` a start is kept only if MuJoCo finds the interpolated
    trajectory collision-free. The NLP is evaluated by CasADi's virtual machine (no gcc): it
    is solved a handful of times per figure.
    """

    def __init__(self, config: PlannerConfig | None = None) -> None:
        self.config = config or PlannerConfig()
        cfg = self.config
        self.n_gammas = 2 * cfg.k + 1
        self._n_free = cfg.n_waypoints - 2
        terms = trajectory_terms(cfg)
        t = ca.SX.sym("t")
        gammas = ca.SX.sym("gammas", self.n_gammas, cfg.k)
        fixed = ca.SX.sym("fixed_features", cfg.k)
        margins = gammas @ (terms.features + fixed) - t  # (2k + 1,), all >= 0
        nlp = {
            "x": ca.vertcat(terms.x, t),
            "p": ca.vertcat(ca.vec(gammas), terms.env, terms.q_start, terms.q_goal, fixed),
            "f": -t + cfg.smoothness * terms.smoothness,
            "g": ca.vertcat(terms.constraints, margins),
        }
        self._solver = ca.nlpsol("worst_case", "ipopt", nlp, solver_options(cfg))
        lo, hi = joint_limits()
        self._lbx = np.concatenate([np.tile(lo, self._n_free), [-np.inf]])
        self._ubx = np.concatenate([np.tile(hi, self._n_free), [np.inf]])
        self._n_clearance = 2 * self._n_free
        self._checker = CollisionChecker()

    def _check_gammas(self, gammas) -> np.ndarray:
        arr = np.asarray(gammas, dtype=float)
        shape = (self.n_gammas, self.config.k)
        if arr.shape != shape:
            raise ValueError(f"gammas: expected shape {shape}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError("gammas: all weights must be finite")
        return arr

    def _trajectory(self, x: np.ndarray, env: Environment) -> np.ndarray:
        inner = np.asarray(x, float)[:-1].reshape(self._n_free, N_ARM_JOINTS)
        return np.vstack([env.q_start, inner, env.q_goal])

    def solve(
        self,
        gammas,
        env: Environment,
        inits: Sequence[np.ndarray] | None = None,
    ) -> WorstCasePlan:
        """Solve eq. (A3) for Γ in ``env``; keep the best converged, collision-free start.

        Args:
            gammas: Γ, shape (2k + 1, k) (see :func:`preference_set`).
            env: the environment.
            inits: initial trajectories (T, 7); by default the planner's first
                ``config.n_starts`` deterministic guesses. Good starts are the (A4) plans
                ξ*(γ_j, E): from them the worst case can only improve (up to IPOPT's
                tolerance), which is how (A3) ≥ (A4) is guaranteed in practice.

        Raises:
            PlanningError: no start converged to a collision-free trajectory.
        """
        gammas = self._check_gammas(gammas)
        cfg = self.config
        T = cfg.n_waypoints
        inits = check_inits(initial_guesses(env, T, cfg.n_starts) if inits is None else inits, T)
        ends = np.vstack([env.q_start, env.q_goal])
        fixed = waypoint_features(ends, env.params(), cfg.features).sum(axis=0)
        p = np.concatenate([gammas.ravel(order="F"), env.params(), env.q_start, env.q_goal, fixed])
        lbg = np.zeros(self._n_clearance + self.n_gammas)
        # Each start's epigraph variable t begins at its trajectory's worst case over Γ.
        starts = [
            np.concatenate(
                [
                    init[1:-1].ravel(),
                    [np.min(gammas @ feature_counts(init, env.params(), cfg.features))],
                ]
            )
            for init in inits
        ]
        t0 = time.perf_counter()
        arguments = {"p": p, "lbx": self._lbx, "ubx": self._ubx, "lbg": lbg, "ubg": np.inf}
        best, statuses = best_start(
            self._solver,
            starts,
            arguments,
            lambda x: self._trajectory(x, env),
            self._checker,
            env,
        )
        elapsed = time.perf_counter() - t0
        if best is None:
            raise PlanningError(
                f"worst case: no start converged in environment {env.name or '<unnamed>'}: "
                f"IPOPT statuses {statuses}"
            )
        _, x, status, iters = best
        traj = self._trajectory(x, env)
        phi = feature_counts(traj, env.params(), cfg.features)
        rewards = gammas @ phi
        return WorstCasePlan(
            trajectory=traj,
            features=phi,
            worst_reward=worst_case_reward(gammas, phi, smoothness_cost(traj), cfg.smoothness),
            binding=tuple(int(j) for j in np.flatnonzero(rewards <= rewards.min() + 1e-6)),
            status=status,
            iterations=int(iters),
            solve_time=elapsed,
            starts=len(statuses),
        )


def _belief(theta, cov) -> Belief:
    """Belief(θ̂, P) with Belief's field names replaced by ``theta`` and ``cov``."""
    try:
        return Belief(theta=np.asarray(theta, float), cov=np.asarray(cov, float))
    except ValueError as exc:
        message = str(exc).replace("Belief.theta", "theta").replace("Belief.cov", "cov")
        raise ValueError(message) from None
