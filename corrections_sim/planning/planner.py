r"""The trajectory optimizer ξ*(θ, E) = argmax_ξ θ·Φ(ξ, E) − λ·S(ξ).

A trajectory is T joint-space waypoints (T, 7): the first is the environment's start, the last
its goal configuration; the T − 2 between them are the decision variables. S(ξ) =
Σ_i ‖q^{i+1} − q^i‖² is the smoothness cost (λ > 0 keeps the problem well conditioned).
Constraints: joint limits; every sphere of ``robot.ARM_SPHERES`` stays ``CLEARANCE`` above
the table top and outside the laptop's keep-out ellipsoid inflated by its radius.

The NLP is built once per :class:`Planner` with θ, the environment and the end points as
*parameters*, so one solver instance serves every (θ, E). A solve tries a small deterministic
set of initial guesses (or the caller's warm start) and keeps the best converged one whose
joint-space interpolation MuJoCo finds collision-free; the result carries the solver's status,
and a failure raises :class:`PlanningError` instead of returning a trajectory.

Two solvers (``PlannerConfig.solver``): ``"fatrop"`` (default) solves the same problem written
in stage form, q^{i+1} = q^i + u^i, with fatrop's Riccati-based interior-point method; when
no start of it converges collision-free, IPOPT gets the same starts (the fallback).
``"ipopt"`` solves the waypoint form with IPOPT only (the original path). Both stop after
``max_iter`` iterations; no limit depends on wall time, so a result never depends on how
loaded the machine is.

A warm start (one initial trajectory, e.g. the run's plan at a nearby θ) is first re-solved
by Newton steps on its active set (``PlannerConfig.warm = "newton"``, the default;
:mod:`~corrections_sim.planning.newton`): about three steps in one compiled call, and for a
big θ step a continuation in stages, accepted only as a certified strict local minimum that
MuJoCo (or the clearance certificate) finds collision-free, otherwise the solver runs as
above from the same start (``warm = "solver"`` always does: the reference path).
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import functools
import hashlib
import inspect
import json
import os
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from corrections_sim.planning import compiled
from corrections_sim.planning.cache import cache_dir
from corrections_sim.planning.clearance import CertifiedChecker
from corrections_sim.planning.clearance import library_key as clearance_library_key
from corrections_sim.planning.compiled import BuildError, build_once, build_shared_library
from corrections_sim.planning.features import (
    canonical,
    check_feature_names,
    feature_counts,
    learnt_values,
    n_learnt,
    symbolic_features,
)
from corrections_sim.planning.newton import NewtonPath
from corrections_sim.planning.newton import library_key as newton_library_key
from corrections_sim.scene import geometry as g
from corrections_sim.scene.environments import Environment, env_index, n_env_params
from corrections_sim.scene.robot import (
    ARM_SPHERES,
    N_ARM_JOINTS,
    joint_limits,
    sphere_centers_symbolic,
    symbolic_fk,
)
from corrections_sim.scene.world import CollisionChecker

#: IPOPT statuses accepted as a converged solve.
_CONVERGED = {"Solve_Succeeded", "Solved_To_Acceptable_Level"}

#: The solvers a :class:`PlannerConfig` may name (see the module docstring).
SOLVERS = ("fatrop", "ipopt")

#: How a warm start is re-solved (``PlannerConfig.warm``): ``"newton"`` takes Newton steps on
#: the warm start's active set (:mod:`~corrections_sim.planning.newton`) and calls the solver
#: only when they cannot certify a strict local minimum; ``"solver"`` calls the solver from
#: the warm start (the reference path).
WARM_MODES = ("newton", "solver")


#: Sharpness (1/m) of the log-sum-exp soft minimum over the arm's spheres. The soft minimum
#: never exceeds the true minimum, so the constraint is conservative by at most
#: log(n_spheres)/SOFT_MIN_SHARPNESS (≈ 5 mm when a single sphere is close).
SOFT_MIN_SHARPNESS = 50.0


def _soft_min(values: list[ca.SX]) -> ca.SX:
    """Smooth lower bound of min(values): -log Σ exp(-ρ v) / ρ (one constraint, not n)."""
    v = ca.vertcat(*values)
    return -ca.log(ca.sum1(ca.exp(-SOFT_MIN_SHARPNESS * v))) / SOFT_MIN_SHARPNESS


def _gaps(poses: dict, env: ca.SX) -> tuple[list[ca.SX], list[ca.SX]]:
    """Per-sphere clearances: height above the table top + CLEARANCE (m), and the laptop
    keep-out ellipsoid's level set minus 1 (dimensionless); both must stay >= 0."""
    laptop_x, laptop_y, yaw = (env[env_index(n)] for n in ("laptop_x", "laptop_y", "laptop_yaw"))
    cyaw, syaw = ca.cos(yaw), ca.sin(yaw)
    semi = np.array(g.LAPTOP_KEEPOUT_SEMI_AXES)
    table_gaps, laptop_gaps = [], []
    for sphere, c in zip(ARM_SPHERES, sphere_centers_symbolic(poses), strict=True):
        table_gaps.append(c[2] - sphere.radius - (g.TABLE_TOP_Z + g.CLEARANCE))
        dx = c[0] - laptop_x
        dy = c[1] - laptop_y
        dz = c[2] - (g.TABLE_TOP_Z + g.LAPTOP_KEEPOUT_CENTER_Z)
        lx = cyaw * dx + syaw * dy
        ly = -syaw * dx + cyaw * dy
        a = semi + sphere.radius + g.CLEARANCE
        laptop_gaps.append((lx / a[0]) ** 2 + (ly / a[1]) ** 2 + (dz / a[2]) ** 2 - 1)
    return table_gaps, laptop_gaps


@functools.cache
def _gap_function(n_params: int) -> ca.Function:
    q = ca.SX.sym("q", N_ARM_JOINTS)
    e = ca.SX.sym("e", n_params)
    frames = tuple(dict.fromkeys(s.frame for s in ARM_SPHERES))
    table_gaps, laptop_gaps = _gaps(symbolic_fk(q, frames), e)
    return ca.Function(
        "gaps", [q, e], [ca.mmin(ca.vertcat(*table_gaps)), ca.mmin(ca.vertcat(*laptop_gaps))]
    )


def clearance(q: np.ndarray, env: Environment) -> tuple[float, float]:
    """The planner's constraints at one configuration (7,): (smallest table gap in m,
    smallest laptop keep-out level minus 1). Both >= 0 means the configuration is allowed."""
    params = env.params()
    table_gap, laptop_gap = _gap_function(len(params))(np.asarray(q, float), params)
    return float(table_gap), float(laptop_gap)


class PlanningError(RuntimeError):
    """The optimizer found no acceptable trajectory; the message names status and environment."""


@dataclass(frozen=True)
class PlannerConfig:
    """Settings that shape the NLP (everything here is part of the build).

    Attributes:
        features: names of the features θ weighs, in order (see ``features.FEATURES``).
        n_waypoints: T, waypoints including the fixed start and goal.
        smoothness: λ > 0, weight of Σ‖Δq‖².
        n_starts: how many of the deterministic initial guesses a cold solve tries (1 … 10;
            10 for θ in every sign quadrant, see the guesses' comment).
        max_iter: iteration limit per start (of each solver; the only limit on the work).
        tol: convergence tolerance.
        jit: compile the NLP's functions with gcc (≈ 8× faster evaluations, ≈ 30 s once per
            machine and setting; the library is cached on disk, see :func:`cache_dir`).
        solver: ``"fatrop"`` (stage form, IPOPT as fallback) or ``"ipopt"`` (see the module
            docstring).
        warm: how a warm start (one initial trajectory) is re-solved, one of
            :data:`WARM_MODES`; not part of the build.
        certificate: skip MuJoCo's collision check of a plan where the compiled clearance
            certificate proves it would find no contact (:mod:`.clearance`; never changes an
            answer; needs ``jit``); not part of the build.
    """

    features: tuple[str, ...] = ("laptop", "table")
    n_waypoints: int = 12
    smoothness: float = 20.0
    n_starts: int = 3
    max_iter: int = 300
    tol: float = 1e-6
    jit: bool = True
    solver: str = "fatrop"
    warm: str = "newton"
    certificate: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "features", check_feature_names(self.features))
        for name in ("n_waypoints", "n_starts", "max_iter"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer):
                raise ValueError(f"{name} = {value!r} must be an integer")
        if not 3 <= self.n_waypoints <= 200:
            raise ValueError(f"n_waypoints = {self.n_waypoints} must lie in [3, 200]")
        if not (np.isfinite(self.smoothness) and self.smoothness > 0):
            raise ValueError(f"smoothness = {self.smoothness} must be finite and > 0")
        if not 1 <= self.n_starts <= len(_GUESS_BUMPS):
            raise ValueError(f"n_starts = {self.n_starts} must lie in [1, {len(_GUESS_BUMPS)}]")
        if self.max_iter < 1 or not self.tol > 0:
            raise ValueError("max_iter and tol must be positive")
        if self.solver not in SOLVERS:
            raise ValueError(f"solver = {self.solver!r} must be one of {', '.join(SOLVERS)}")
        if not isinstance(self.certificate, bool | np.bool_):
            raise ValueError(f"certificate = {self.certificate!r} must be true or false")
        if self.warm not in WARM_MODES:
            raise ValueError(f"warm = {self.warm!r} must be one of {', '.join(WARM_MODES)}")
        if self.solver == "fatrop" and self.n_waypoints < 4:
            raise ValueError(
                f"n_waypoints = {self.n_waypoints}: solver 'fatrop' needs >= 4 (two free "
                "waypoints, one stage); use solver 'ipopt'"
            )

    @property
    def k(self) -> int:
        return len(self.features)


@dataclass(frozen=True)
class Plan:
    """A converged solve of ξ*(θ, E).

    Attributes:
        trajectory: waypoints (T, 7), start and goal included.
        features: Φ(ξ, E), shape (k,).
        reward: θ·Φ(ξ, E) − λ·S(ξ), the maximized objective.
        status: the solver's return status of the kept start.
        iterations: iterations of the kept start.
        solve_time: wall time of the whole call (all starts), seconds.
        starts: how many initial guesses were tried (by each solver that ran).
        solver: which solver found the kept start: ``"fatrop"`` or ``"ipopt"`` (the fallback
            of a fatrop planner, or an IPOPT planner).
    """

    trajectory: np.ndarray
    features: np.ndarray
    reward: float
    status: str
    iterations: int
    solve_time: float
    starts: int
    solver: str = "ipopt"


# Deterministic initial guesses: the straight joint-space line, then the line bent by a
# half-sine bump (rad at mid-path, per joint): the base turned one way with the shoulder lifted,
# the other way, then elbow and wrist folded. Chosen by measurement over 400 off-grid problems
# at figs. 4-5's settings against 30 random restarts (docs/speed.md): within 1% of the
# restarts' best, the line alone 96.0%, all four 99.5% (the old three, lifting or lowering the
# hand, 96.6%).
# The line stays first so that single-start figures (1, 2, 6) keep their start.
# Then the three bumps 2.2 times as deep, and 1.6 times, for θ in every sign quadrant, where
# the misses are θ_laptop < 0 < θ_table. Within 1% of 30 random restarts with θ ∈ [-2, 2]^k
# (k = 2 / 3), on three problem sets (40 and 50 problems per quadrant and k, the first used
# to choose the scales, and `bench planner --theta-range 2 --seed 1`, 200 problems per k):
#   4 starts: 95.6-95.0-95.5% / 95.0-96.0-98.5%;  7: 98.8-99.0-97.5% / 98.1-98.0-99.5%;
#   10: 98.8-99.0-98.5% / 99.4-98.5-99.5% (docs/speed.md). Appended, so that n_starts <= 4
# solves as before.
_BUMPS = (
    (0.3, 0.25, 0.2, 0.0, 0.0, 0.1, 0.0),
    (-0.3, 0.15, -0.2, 0.0, 0.0, 0.1, 0.0),
    (0.0, 0.0, 0.0, -0.45, 0.0, -0.4, 0.0),
)
_DEEPER = (2.2, 1.6)
_GUESS_BUMPS: tuple[tuple[float, ...], ...] = (
    (0.0,) * 7,
    *_BUMPS,
    *(tuple(scale * v for v in bump) for scale in _DEEPER for bump in _BUMPS),
)


def initial_guesses(env: Environment, n_waypoints: int, count: int) -> list[np.ndarray]:
    """The first ``count`` deterministic initial trajectories (T, 7) for ``env``."""
    s = np.linspace(0.0, 1.0, n_waypoints)[:, None]
    line = (1 - s) * env.q_start + s * env.q_goal
    lo, hi = joint_limits()
    return [np.clip(line + np.sin(np.pi * s) * np.array(b), lo, hi) for b in _GUESS_BUMPS[:count]]


def smoothness_cost(trajectory: np.ndarray) -> float:
    """S(ξ) = Σ_i ‖q^{i+1} − q^i‖²."""
    return float(np.sum(np.diff(np.asarray(trajectory, float), axis=0) ** 2))


def check_theta(theta, k: int) -> np.ndarray:
    """θ as a float array (k,), refused if the length is wrong or a value is not finite."""
    arr = np.asarray(theta, dtype=float)
    if arr.shape != (k,):
        raise ValueError(f"theta: expected {k} weights, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"theta: all weights must be finite, got {arr.tolist()}")
    return arr


#: The settings that shape the compiled functions (the others are solver options, given when
#: the library is loaded, so changing them never recompiles).
_BUILD_FIELDS = ("features", "n_waypoints", "smoothness", "solver")


def build_key(config: PlannerConfig) -> str:
    """Hash of everything that shapes the compiled library: the NLP's settings and solver
    (waypoint or stage form), the code, the CasADi version."""
    import sys

    from corrections_sim.planning import features
    from corrections_sim.scene import geometry, robot

    h = hashlib.sha256()
    shaping = {name: value for name, value in asdict(config).items() if name in _BUILD_FIELDS}
    h.update(json.dumps(shaping, sort_keys=True).encode())
    h.update(ca.__version__.encode())
    for module in (geometry, robot, features, compiled, sys.modules[__name__]):
        h.update(inspect.getsource(module).encode())
    h.update(features.fingerprint(config.features).encode())  # plug-in features, env params
    return h.hexdigest()[:20]


#: IPOPT options beyond the config's. The adaptive barrier update halves the iterations of
#: warm-started solves (measured: 4-7 instead of 8-9).
_IPOPT_OPTIONS = {
    "print_level": 0,
    "sb": "yes",
    "linear_solver": "mumps",
    "hessian_approximation": "exact",
    "mu_strategy": "adaptive",
}


def _compile_library(solver: ca.Function, library: Path) -> None:
    """C code of the solver's NLP functions, compiled by gcc into ``library`` (atomically)."""
    library.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=library.parent) as scratch:
        source = Path(scratch) / "trajopt_nlp.c"
        cwd = os.getcwd()
        os.chdir(scratch)  # generate_dependencies writes into the working directory
        try:
            solver.generate_dependencies(source.name)
        finally:
            os.chdir(cwd)
        build_shared_library(source, library)


@dataclass(frozen=True, eq=False)
class TrajectoryTerms:
    """The symbolic pieces of a trajectory NLP over the free waypoints of one config.

    :class:`Planner` maximizes θ·Φ − λ·S subject to ``constraints >= 0``; other planners
    (e.g. the risk-averse one of :mod:`corrections_sim.planning.risk`) reuse the same terms with
    their
    own objective, so every planner keeps the arm out of the table and laptop alike.

    Attributes:
        x: decision variables, the free waypoints q¹ … q^{T−2} stacked, SX (7 (T − 2),).
        env: environment parameters (laptop x, y, yaw, table x, y), SX (5,).
        q_start: fixed first waypoint, SX (7,).
        q_goal: fixed last waypoint, SX (7,).
        features: Φ(ξ, E) summed over the free waypoints, SX (k,).
        smoothness: S(ξ) = Σ_i ‖q^{i+1} − q^i‖² over the whole path, SX scalar.
        constraints: per free waypoint the soft-min table gap and laptop keep-out level,
            SX (2 (T − 2),); all must be >= 0.
        waypoint: one waypoint's share, (q (7,), env, learnt) -> (its features (k,), its two
            constraints (2,)), the same expressions; features and constraints are their sums
            and concatenation over the free waypoints (the Newton loop evaluates by waypoint).
        learnt: the weights of the learnt-feature slots among the features (see
            :func:`~corrections_sim.planning.features.canonical`), SX (0,) when there are
            none; the NLPs take them as their last parameters.
    """

    x: ca.SX
    env: ca.SX
    q_start: ca.SX
    q_goal: ca.SX
    features: ca.SX
    smoothness: ca.SX
    constraints: ca.SX
    waypoint: ca.Function
    learnt: ca.SX

    def params(self, theta: ca.SX) -> ca.SX:
        """The planner NLPs' parameter vector p = (θ, e, q_start, q_goal, learnt)."""
        return ca.vertcat(theta, self.env, self.q_start, self.q_goal, self.learnt)


def _waypoint_terms(
    q: ca.SX, env: ca.SX, features: tuple[str, ...], learnt: ca.SX
) -> tuple[ca.SX, ...]:
    """One waypoint's features, soft-min table gap and laptop keep-out level."""
    poses = symbolic_fk(q, tuple(dict.fromkeys(s.frame for s in ARM_SPHERES)))
    rot_h, pos_h = poses["panda_hand"]
    phi = symbolic_features(rot_h, pos_h, env, features, learnt)
    table_gaps, laptop_gaps = _gaps(poses, env)
    return phi, _soft_min(table_gaps), _soft_min(laptop_gaps)


def trajectory_terms(cfg: PlannerConfig) -> TrajectoryTerms:
    """Build the symbols and expressions every trajectory NLP of ``cfg`` shares."""
    n_free = cfg.n_waypoints - 2
    x = ca.SX.sym("x", n_free * N_ARM_JOINTS)
    env = ca.SX.sym("env", n_env_params())
    q_start = ca.SX.sym("q_start", N_ARM_JOINTS)
    q_goal = ca.SX.sym("q_goal", N_ARM_JOINTS)
    learnt = ca.SX.sym("learnt", n_learnt(cfg.features))
    qs = ca.reshape(x, N_ARM_JOINTS, n_free)

    phi_sum = ca.SX.zeros(cfg.k)
    constraints = []
    for i in range(n_free):
        phi, table, laptop = _waypoint_terms(qs[:, i], env, cfg.features, learnt)
        phi_sum += phi
        constraints += [table, laptop]
    path = ca.horzcat(q_start, qs, q_goal)
    q = ca.SX.sym("q", N_ARM_JOINTS)
    phi, table, laptop = _waypoint_terms(q, env, cfg.features, learnt)
    waypoint = ca.Function("waypoint_terms", [q, env, learnt], [phi, ca.vertcat(table, laptop)])
    return TrajectoryTerms(
        x=x,
        env=env,
        q_start=q_start,
        q_goal=q_goal,
        features=phi_sum,
        smoothness=ca.sumsqr(path[:, 1:] - path[:, :-1]),
        constraints=ca.vertcat(*constraints),
        waypoint=waypoint,
        learnt=learnt,
    )


def solver_options(cfg: PlannerConfig) -> dict:
    """``nlpsol`` options for IPOPT with the config's limits (errors reported in stats)."""
    return {
        "print_time": False,
        "error_on_fail": False,
        "ipopt": {
            **_IPOPT_OPTIONS,
            "max_iter": cfg.max_iter,
            "tol": cfg.tol,
        },
    }


def check_inits(inits: Sequence[np.ndarray], n_waypoints: int) -> list[np.ndarray]:
    """Initial trajectories as float arrays (T, 7), refused if empty or of the wrong shape."""
    if len(inits) == 0:
        raise ValueError("inits: give at least one initial trajectory, or None")
    out = [np.asarray(init, float) for init in inits]
    for init in out:
        if init.shape != (n_waypoints, N_ARM_JOINTS):
            raise ValueError(
                f"inits: expected shape ({n_waypoints}, {N_ARM_JOINTS}), got {init.shape}"
            )
    return out


def best_start(
    solver: ca.Function,
    starts: Sequence[np.ndarray],
    arguments: dict,
    trajectory: Callable[[np.ndarray], np.ndarray],
    checker: CollisionChecker | CertifiedChecker,
    env: Environment,
) -> tuple[tuple[float, np.ndarray, str, int] | None, list[str]]:
    """Solve from each start ``x0``; keep the lowest objective that converged and that
    MuJoCo finds collision-free along the interpolated ``trajectory(x)``.

    Returns:
        ((f, x, IPOPT status, iterations) of the kept start, or None), and one status per
        start (a collision replaces the start's IPOPT status).
    """
    best, statuses = None, []
    for x0 in starts:
        sol = solver(x0=x0, **arguments)
        stats = solver.stats()
        status = stats["return_status"]
        statuses.append(status)
        if status not in _CONVERGED:
            continue
        f = float(sol["f"])
        if best is not None and f >= best[0]:
            continue
        x = np.array(sol["x"]).ravel()
        # The NLP keeps spheres clear at the waypoints; MuJoCo checks the full geometry
        # along the joint-space interpolation between them.
        report = checker.check_trajectory(trajectory(x), env)
        if not report.collision_free:
            c = max(report.contacts, key=lambda c: c.depth)
            statuses[-1] = f"Collision({c.body_a}-{c.body_b} at waypoint {c.time:.2f})"
            continue
        best = (f, x, status, stats["iter_count"])
    return best, statuses


def _fatrop_options(cfg: PlannerConfig, n_free: int) -> dict:
    """``nlpsol`` options for fatrop on :func:`stage_nlp`'s layout (structure given, not
    detected: fatrop's automatic detection has known bugs)."""
    J = N_ARM_JOINTS
    return {
        "print_time": False,
        "error_on_fail": False,
        "structure_detection": "manual",
        "N": n_free - 1,
        "nx": [J] * n_free,
        "nu": [J] * (n_free - 1) + [0],
        "ng": [2] * n_free,
        "equality": ([True] * J + [False, False]) * (n_free - 1) + [False, False],
        "fatrop": {"print_level": 0, "max_iter": cfg.max_iter, "tol": cfg.tol},
    }


def stage_nlp(cfg: PlannerConfig) -> dict:
    """The planner's NLP in stage form, for fatrop (same parameters p as :class:`Planner`).

    Decision variables w = (q¹, u¹, q², u², …, q^{T−2}), free waypoints q^i (7,) and steps
    u^i (7,); constraints per stage i: q^{i+1} − q^i − u^i = 0, then the waypoint's two
    clearances >= 0 (the same expressions as :func:`trajectory_terms`). The objective
    −θ·Φ + λ(‖q¹ − q_start‖² + Σ‖u^i‖² + ‖q_goal − q^{T−2}‖²) equals the waypoint form's on
    the feasible set, and its Hessian is block diagonal per stage, as fatrop requires.
    """
    terms = trajectory_terms(cfg)
    n, J = cfg.n_waypoints - 2, N_ARM_JOINTS
    theta = ca.SX.sym("theta", cfg.k)
    pieces = ca.Function(
        "pieces", [terms.x, terms.env, terms.learnt], [terms.features, terms.constraints]
    )
    qs = [ca.SX.sym(f"q{i}", J) for i in range(n)]
    us = [ca.SX.sym(f"u{i}", J) for i in range(n - 1)]
    phi, clear = pieces(ca.vertcat(*qs), terms.env, terms.learnt)
    steps = ca.sumsqr(qs[0] - terms.q_start) + ca.sumsqr(terms.q_goal - qs[-1])
    w, g = [], []
    for i in range(n - 1):
        w += [qs[i], us[i]]
        g += [qs[i + 1] - qs[i] - us[i], clear[2 * i : 2 * i + 2]]
        steps += ca.sumsqr(us[i])
    w.append(qs[-1])
    g.append(clear[2 * n - 2 :])
    return {
        "x": ca.vertcat(*w),
        "p": terms.params(theta),
        "f": -ca.dot(theta, phi) + cfg.smoothness * steps,
        "g": ca.vertcat(*g),
    }


def _load_solver(name: str, plugin: str, nlp: dict, opts: dict, cfg: PlannerConfig) -> ca.Function:
    """``nlpsol`` over the NLP, its functions compiled into the cached library of ``cfg``."""
    if not cfg.jit:
        return ca.nlpsol(name, plugin, nlp, opts)
    library = cache_dir() / f"trajopt-{build_key(cfg)}.so"
    build_once(library, lambda path: _compile_library(ca.nlpsol(name, plugin, nlp, opts), path))
    # The solver evaluates the NLP through the compiled library; every process dlopens the
    # same finished file, which nobody rewrites (a fresh build goes to a new name).
    return ca.nlpsol(name, plugin, str(library), opts)


class Planner:
    """ξ*(θ, E) for one :class:`PlannerConfig`; build once per process, solve many times.

    A learnt feature (:mod:`corrections_sim.learnt.training`) among the config's features is
    planned with through its shape's slot: the NLP is built (and compiled) for the shape, its
    weights are the NLP's last parameters, so a newly learnt feature costs no build
    (:meth:`bind`, :func:`shared_planner`)."""

    def __init__(self, config: PlannerConfig | None = None) -> None:
        self.config = config or PlannerConfig()
        #: What the NLP is built for: the config with learnt features as their slots.
        self._build = dataclasses.replace(self.config, features=canonical(self.config.features))
        self._learnt = learnt_values(self.config.features)
        self._base = self
        n = self._n_free = self.config.n_waypoints - 2
        lo, hi = joint_limits()
        self._lbx = np.tile(lo, n)
        self._ubx = np.tile(hi, n)
        self._checker = CollisionChecker()
        if self.config.certificate and self.config.jit:
            library = cache_dir() / f"clearance-{clearance_library_key()}.so"
            with self._building():
                self._checker = CertifiedChecker(self._checker, library)
        self._ipopt: ca.Function | None = None
        self._newton: NewtonPath | None = None
        if self.config.solver == "ipopt":
            self._ipopt_solver()
            return
        cfg = self._build
        with self._building():
            self._fatrop = _load_solver(
                "trajopt_stages", "fatrop", stage_nlp(cfg), _fatrop_options(cfg, n), cfg
            )
        J, free = N_ARM_JOINTS, np.full(N_ARM_JOINTS, np.inf)
        self._stage_bounds = {
            "lbx": np.concatenate([*[np.r_[lo, -free]] * (n - 1), lo]),
            "ubx": np.concatenate([*[np.r_[hi, free]] * (n - 1), hi]),
            "lbg": np.concatenate([*[np.zeros(J + 2)] * (n - 1), np.zeros(2)]),
            "ubg": np.concatenate([*[np.r_[np.zeros(J), np.inf, np.inf]] * (n - 1), [np.inf] * 2]),
        }

    def bind(self, config: PlannerConfig) -> Planner:
        """This planner for ``config``, which differs from its own only in which learnt
        features of the same shapes it plans with: the solvers are shared, nothing is built."""
        mine = dataclasses.replace(config, features=canonical(config.features))
        if mine != self._build:
            raise ValueError(
                f"bind: {list(config.features)} do not share this planner's build "
                f"{list(self._build.features)}"
            )
        view = copy.copy(self)
        view.config, view._learnt, view._base = config, learnt_values(config.features), self._base
        return view

    def _ipopt_solver(self) -> ca.Function:
        """IPOPT on the waypoint form; a fatrop planner builds (or loads) it at its first
        fallback, sharing the library of the same config with ``solver = "ipopt"``."""
        if self._base is not self:
            return self._base._ipopt_solver()
        if self._ipopt is None:
            cfg = dataclasses.replace(self._build, solver="ipopt")
            nlp, opts = self._nlp(cfg)
            with self._building():
                self._ipopt = _load_solver("trajopt", "ipopt", nlp, opts, cfg)
        return self._ipopt

    def _newton_path(self) -> NewtonPath:
        """The Newton re-solve, built (or its compiled library loaded) at the first warm start;
        it is the waypoint form's, so every solver of a config shares one library."""
        if self._base is not self:
            return self._base._newton_path()
        if self._newton is None:
            cfg = self._build
            library = None
            if cfg.jit:
                key = newton_library_key(build_key(dataclasses.replace(cfg, solver="ipopt")))
                library = cache_dir() / f"newton-{key}.so"
            with self._building():
                self._newton = NewtonPath(
                    trajectory_terms(cfg),
                    cfg.smoothness,
                    cfg.features,
                    self._lbx,
                    self._ubx,
                    library,
                )
        return self._newton

    @contextlib.contextmanager
    def _building(self):
        """gcc's failure to build a library of this planner, named by the features it plans
        over (a learnt feature's name says which was being learnt): one line."""
        try:
            yield
        except BuildError as exc:
            raise BuildError(f"the planner over {', '.join(self.config.features)}: {exc}") from None

    def _newton_solve(self, theta: np.ndarray, env: Environment, start: np.ndarray, p, t0):
        """The warm start re-solved by :class:`NewtonPath`, checked by MuJoCo like every
        plan; None when Newton cannot certify a minimum or the path collides."""
        found = self._newton_path().solve(start, p)
        if found is None:
            return None
        traj = self._trajectory(found.x, env)
        if not self._checker.check_trajectory(traj, env).collision_free:
            return None
        phi = found.features
        return Plan(
            trajectory=traj,
            features=phi,
            reward=float(theta @ phi - self.config.smoothness * smoothness_cost(traj)),
            status="Newton_Converged",
            iterations=found.steps,
            solve_time=time.perf_counter() - t0,
            starts=1,
            solver="newton",
        )

    @staticmethod
    def _nlp(cfg: PlannerConfig) -> tuple[dict, dict]:
        """The NLP (parameters p = (θ, e, q_start, q_goal)) and the solver options."""
        terms = trajectory_terms(cfg)
        theta = ca.SX.sym("theta", cfg.k)
        objective = -ca.dot(theta, terms.features) + cfg.smoothness * terms.smoothness
        nlp = {"x": terms.x, "p": terms.params(theta), "f": objective, "g": terms.constraints}
        return nlp, solver_options(cfg)

    def _params(self, theta: np.ndarray, env: Environment) -> np.ndarray:
        return np.concatenate([theta, env.params(), env.q_start, env.q_goal, self._learnt])

    def _trajectory(self, x: np.ndarray, env: Environment) -> np.ndarray:
        inner = np.asarray(x, float).reshape(self._n_free, N_ARM_JOINTS)
        return np.vstack([env.q_start, inner, env.q_goal])

    def _to_stages(self, x: np.ndarray) -> np.ndarray:
        """Free waypoints (7 (T − 2),) -> the stage form's w = (q¹, u¹, …, q^{T−2})."""
        q = x.reshape(self._n_free, N_ARM_JOINTS)
        return np.concatenate([np.hstack([q[:-1], np.diff(q, axis=0)]).ravel(), q[-1]])

    def _from_stages(self, w: np.ndarray) -> np.ndarray:
        """The stage form's w -> the free waypoints (7 (T − 2),)."""
        J, n = N_ARM_JOINTS, self._n_free
        head = w[: 2 * J * (n - 1)].reshape(n - 1, 2 * J)[:, :J]
        return np.concatenate([head.ravel(), w[2 * J * (n - 1) :]])

    def _fatrop_starts(
        self, starts: Sequence[np.ndarray], p: np.ndarray, env: Environment
    ) -> tuple[tuple[float, np.ndarray, str, int] | None, list[str]]:
        """:func:`best_start` for fatrop on the stage form (statuses ``fatrop:<flag>``)."""
        best, statuses = None, []
        for x0 in starts:
            sol = self._fatrop(x0=self._to_stages(x0), p=p, **self._stage_bounds)
            stats = self._fatrop.stats()
            if not stats["success"]:
                statuses.append(f"fatrop:{stats['return_status']}")
                continue
            statuses.append("Solve_Succeeded")
            f = float(sol["f"])
            if best is not None and f >= best[0]:
                continue
            x = self._from_stages(np.array(sol["x"]).ravel())
            report = self._checker.check_trajectory(self._trajectory(x, env), env)
            if not report.collision_free:
                c = max(report.contacts, key=lambda c: c.depth)
                statuses[-1] = f"Collision({c.body_a}-{c.body_b} at waypoint {c.time:.2f})"
                continue
            best = (f, x, "Solve_Succeeded", stats["iter_count"])
        return best, statuses

    def reward(self, theta, trajectory: np.ndarray, env: Environment) -> float:
        """θ·Φ(ξ, E) − λ·S(ξ) for any trajectory (T, 7)."""
        theta = check_theta(theta, self.config.k)
        phi = feature_counts(trajectory, env.params(), self.config.features)
        return float(theta @ phi - self.config.smoothness * smoothness_cost(trajectory))

    def solve(
        self,
        theta,
        env: Environment,
        inits: Sequence[np.ndarray] | None = None,
    ) -> Plan:
        """Solve ξ*(θ, E); keep the best converged start.

        Args:
            theta: feature weights (k,).
            env: the environment.
            inits: initial trajectories (T, 7) to start from; by default the first
                ``config.n_starts`` deterministic guesses. One trajectory is a warm start:
                with ``config.warm = "newton"`` Newton steps re-solve it first.

        Raises:
            PlanningError: no start converged; the message names the statuses.
        """
        theta = check_theta(theta, self.config.k)
        T = self.config.n_waypoints
        warm = inits is not None and len(inits) == 1 and self.config.warm == "newton"
        inits = initial_guesses(env, T, self.config.n_starts) if inits is None else inits
        starts = [init[1:-1].ravel() for init in check_inits(inits, T)]
        p = self._params(theta, env)
        t0 = time.perf_counter()
        if warm:  # a warm start (one given trajectory), never the cold guesses
            plan = self._newton_solve(theta, env, starts[0], p, t0)
            if plan is not None:
                return plan
        best, statuses, solver = None, [], self.config.solver
        if solver == "fatrop":
            best, statuses = self._fatrop_starts(starts, p, env)
        if best is None:
            solver = "ipopt"
            arguments = {"p": p, "lbx": self._lbx, "ubx": self._ubx, "lbg": 0.0, "ubg": np.inf}
            best, more = best_start(
                self._ipopt_solver(),
                starts,
                arguments,
                lambda x: self._trajectory(x, env),
                self._checker,
                env,
            )
            statuses += more
        elapsed = time.perf_counter() - t0
        if best is None:
            raise PlanningError(
                f"no start converged for theta={theta.tolist()} in environment "
                f"{env.name or '<unnamed>'}: statuses {statuses}"
            )
        _, x, status, iters = best
        traj = self._trajectory(x, env)
        phi = feature_counts(traj, env.params(), self.config.features)
        return Plan(
            trajectory=traj,
            features=phi,
            reward=float(theta @ phi - self.config.smoothness * smoothness_cost(traj)),
            status=status,
            iterations=int(iters),
            solve_time=elapsed,
            starts=len(starts),
            solver=solver,
        )


def shared_planner(config: PlannerConfig) -> Planner:
    """This process's planner for ``config``, built (or its compiled solver loaded) once and
    shared by every figure's worker tasks; a config with learnt features gets a view
    (:meth:`Planner.bind`) of the one planner of their shapes."""
    build = dataclasses.replace(config, features=canonical(config.features))
    if build == config:
        return _shared(config)
    return _shared(build).bind(config)


@functools.cache
def _shared(config: PlannerConfig) -> Planner:
    return Planner(config)
