r"""Warm re-solves by Newton steps on the active set (``PlannerConfig.warm = "newton"``, the
default).

When θ moves a little, ξ*(θ, E) moves a little and keeps its active constraints. From the
previous plan x₀ (the free waypoints) this path guesses the active set 𝒜 (clearances with
c_j(x₀) < :data:`ACTIVE` and joints within :data:`AT_BOUND` of a limit, which stay fixed)
and takes Newton steps on the KKT system of

    min_x f(x) = −θ·Φ(x) + λ S(x)   subject to   c_𝒜(x) = 0:

    [ W   −J_𝒜ᵀ ] [ d ]   [ −∇f ]
    [ J_𝒜   0   ] [ μ ] = [ −c_𝒜 ],     W = ∇²(f − μᵀc),

on the free joints, until ‖∇f − J_𝒜ᵀμ‖∞ ≤ :data:`STATIONARITY` and ‖c_𝒜‖∞ ≤
:data:`FEASIBILITY`. A multiplier that turns negative leaves 𝒜 and a violated clearance joins
it (one change per step). The answer is accepted only as a strict local minimum of the
planner's NLP: every μ ≥ 0, every clearance ≥ 0, every joint inside its limits with a
multiplier of the right sign where it sits on one, and the Hessian reduced to the null space
of J_𝒜 positive definite. Anything else returns None and the caller solves as before (the
reference path); so does a step count above :data:`MAX_STEPS`.

f, ∇f, c, J (block diagonal: a clearance depends on its waypoint only) and the lower
triangle of W are one CasADi function, compiled once per machine and config into the
planner's cache (a content-addressed library, like the solver's) and called through ctypes
with preallocated buffers: a CasADi call from Python costs ≈ 0.1 ms plus ≈ 0.25 ms to
convert its outputs, more than the evaluation itself. A step factors W by LAPACK's banded
Cholesky (half-bandwidth 7 in the waypoint ordering) and solves the few active clearances'
Schur complement J W⁻¹ Jᵀ; where W is not positive definite (it need only be so on the null
space of J_𝒜), the step solves the KKT system by dense LU instead.

With the library compiled, the whole loop runs in one C call (``newton.c``, compiled into
the same library, LAPACK taken as function pointers from SciPy's ``cython_lapack``): the
same steps, tests and constants as :meth:`NewtonPath._solve_python`, which stays the loop of
an uncompiled planner (``jit = False``) and the one the compiled loop is tested against. Two
rare cases go back to Python: a KKT point where W is not positive definite (the reduced
Hessian is checked here) and a start whose multipliers need least squares (Python's loop).
The compiled loop alone adds the continuation for big steps (:data:`MAX_STAGES`): where the
attempt gives up, the start walks to the new θ through objectives tilted by its residual.
The compiled loop assembles f, ∇f, c, J and W by waypoint instead (``newton_waypoint``, and
the clearances' curvature ``newton_clearance`` only where a multiplier is nonzero: 85% of
the whole function's operations are that curvature).
"""

from __future__ import annotations

import ctypes
import hashlib
import inspect
import threading
from dataclasses import dataclass
from functools import partial
from importlib import resources
from pathlib import Path
from typing import NamedTuple

import casadi as ca
import numpy as np
from scipy.linalg import cython_lapack
from scipy.linalg.lapack import dpbtrf, dpbtrs, dposv

from corrections_sim.planning import compiled
from corrections_sim.planning.compiled import Compiled, build_once, compile_library
from corrections_sim.planning.features import slot_feature_function

#: A clearance below this at the warm start is guessed active (fatrop stops with active
#: clearances at 1e-9 … 1e-6 and inactive ones above 1e-3).
ACTIVE = 1e-5
#: A joint this close to a limit at the warm start stays on it (rad).
AT_BOUND = 1e-7
#: Acceptance: stationarity of the Lagrangian (objective units per rad) and feasibility of
#: the active clearances, both far inside the reference solver's tolerance 1e-6.
STATIONARITY = 1e-7
FEASIBILITY = 1e-9
#: Newton steps (each may change the active set by one) before giving up, and the residual
#: above which a solve that has taken SLOW_AFTER steps is given up early.
MAX_STEPS = 6
#: Newton steps on one active set before giving up: from a start in its basin, Newton reaches
#: STATIONARITY in 2–3 (473 accepted warm problems: 358 in 2–3, 45 in 4); needing 5 means
#: the start was outside that basin, and the one such answer of 600 problems was another,
#: worse local minimum (1.6e-3 below the solver's from the same start).
STEPS_PER_SET = 4
SLOW_AFTER, SLOW = 3, 1e-1
#: The gate: above this stationarity residual at the warm start, Newton is not tried. On
#: 600 warm problems from fig. 4, 7% of those above it were accepted (35 problems, median
#: |Δθ| 0.7), 99% of those below 0.1.
GATE = 1.0
#: The continuation where the attempt fails (the compiled loop only): the start walks to the
#: new θ through objectives tilted by its residual r₀, f − (1 − s) r₀ᵀx, in ⌈‖r₀‖∞ /
#: STAGE_RESIDUAL⌉ stages (at most MAX_STAGES; 0 turns it off), each solved to
#: STAGE_TOLERANCE and the last to the full tolerances.
STAGE_RESIDUAL = 0.1
STAGE_TOLERANCE = 1e-3
MAX_STAGES = 16

#: The compiled loop's C source, built into the Newton library beside the CasADi functions.
_SOURCE = "newton.c"
#: The compiled loop's outcomes (``newton.c``'s enum), by name; :meth:`NewtonPath.attempt`
#: reports them, and the Python loop the same names.
OUTCOMES = {
    0: "certified",
    1: "reduced",  # a KKT point whose W is not positive definite: checked here
    2: "lstsq",  # the start's multipliers need least squares: Python's loop
    -1: "gate",
    -2: "stalled",
    -3: "singular",
    -4: "infeasible",
    -5: "evaluation",
    -6: "indefinite",
}


class _Problem(ctypes.Structure):
    """``newton.c``'s ``NewtonProblem``: sizes, sparsity, limits, constants, LAPACK."""

    _fields_ = [
        *((name, ctypes.c_int) for name in ("n", "n_c", "k", "nnz_j", "nnz_h")),
        *((name, ctypes.c_void_p) for name in ("j_row", "j_col", "h_row", "h_col")),
        ("n_env", ctypes.c_int),
        ("smoothness", ctypes.c_double),
        *((name, ctypes.c_void_p) for name in ("lower", "upper")),
        *(
            (name, ctypes.c_double)
            for name in ("active", "at_bound", "stationarity", "feasibility", "gate", "slow")
        ),
        *((name, ctypes.c_int) for name in ("max_steps", "steps_per_set", "slow_after")),
        ("stage_residual", ctypes.c_double),
        ("stage_tolerance", ctypes.c_double),
        ("max_stages", ctypes.c_int),
        *((name, ctypes.c_void_p) for name in ("dpbtrf", "dpbtrs", "dposv", "dgesv")),
    ]


class _Report(ctypes.Structure):
    """``newton.c``'s ``NewtonReport``."""

    _fields_ = [
        ("steps", ctypes.c_int),
        ("stages", ctypes.c_int),
        ("objective", ctypes.c_double),
        ("residual", ctypes.c_double),
    ]


def _layout(n_waypoints: int) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """(row, column) of the Jacobian's and of W's lower-triangle nonzeros in the order
    ``newton.c`` assembles them (its comment on BLOCK): per free waypoint i, J's 2 × 7 block
    column by column; W's 7 × 7 block's lower triangle column by column, then the 7 entries
    coupling it with waypoint i + 1."""
    j, h = [], []
    for i in range(n_waypoints):
        at = 7 * i
        j += [(2 * i + r, at + a) for a in range(7) for r in range(2)]
        h += [(at + b, at + a) for a in range(7) for b in range(a, 7)]
        if i + 1 < n_waypoints:
            h += [(at + 7 + a, at + a) for a in range(7)]
    return tuple(tuple(np.array(v, dtype=np.intc) for v in zip(*t, strict=True)) for t in (j, h))


#: CPython's capsule accessors, with their own prototypes (ctypes.pythonapi's are left alone).
_CAPSULE_NAME = ctypes.PYFUNCTYPE(ctypes.c_char_p, ctypes.py_object)(
    ("PyCapsule_GetName", ctypes.pythonapi)
)
_CAPSULE_POINTER = ctypes.PYFUNCTYPE(ctypes.c_void_p, ctypes.py_object, ctypes.c_char_p)(
    ("PyCapsule_GetPointer", ctypes.pythonapi)
)


def _lapack(name: str) -> int:
    """The address of SciPy's ``cython_lapack`` routine ``name`` (its LP64 Fortran ABI)."""
    capsule = cython_lapack.__pyx_capi__[name]
    return _CAPSULE_POINTER(capsule, _CAPSULE_NAME(capsule))


class _Start(NamedTuple):
    """:meth:`NewtonPath._start`: x with held joints on their limits, which joints sit on a
    lower limit and which on any, the free ones, the guessed active set, its multipliers and
    the stationarity residual."""

    x: np.ndarray
    on_lower: np.ndarray
    held: np.ndarray
    free: np.ndarray
    active: np.ndarray
    mu: np.ndarray
    residual: float


@dataclass(frozen=True)
class NewtonSolution:
    """An accepted Newton re-solve: free waypoints x (7 (T − 2),), objective f, Newton
    steps, Φ(ξ, E) of the whole trajectory (start and goal included), shape (k,), and the
    continuation's stages it took (0: answered by the plain attempt)."""

    x: np.ndarray
    objective: float
    steps: int
    features: np.ndarray
    stages: int = 0


class NewtonPath:
    """The Newton re-solve of one planner config (see the module docstring).

    Args:
        terms: the planner's :class:`~.planner.TrajectoryTerms`.
        smoothness: λ.
        names: the features θ weighs.
        lower: lower joint limits of the free waypoints, (7 (T − 2),).
        upper: upper joint limits of the free waypoints, (7 (T − 2),).
        library: where the compiled function lives (None: do not compile).
    """

    def __init__(
        self, terms, smoothness: float, names: tuple[str, ...], lower, upper, library: Path | None
    ) -> None:
        theta = ca.SX.sym("theta", len(names))
        n_c = terms.constraints.shape[0]
        mu = ca.SX.sym("mu", n_c)
        p = terms.params(theta)
        f = -ca.dot(theta, terms.features) + smoothness * terms.smoothness
        jac = ca.jacobian(terms.constraints, terms.x)
        hess = ca.tril(ca.hessian(f - ca.dot(mu, terms.constraints), terms.x)[0])
        grad = ca.gradient(f, terms.x)
        first = ca.Function("newton_first", [terms.x, p], [grad, terms.constraints, jac])
        fn = ca.Function("newton_terms", [terms.x, p, mu], [f, grad, terms.constraints, jac, hess])
        ends = slot_feature_function(names)
        phi = (
            terms.features
            + ends(terms.q_start, terms.env, terms.learnt)
            + ends(terms.q_goal, terms.env, terms.learnt)
        )
        features = ca.Function("newton_features", [terms.x, p], [phi])
        # By waypoint, for the compiled loop (newton.c): its features, clearances, their
        # Jacobian and θ·φ's gradient and Hessian; the clearances' Hessian apart.
        q, mu_i = ca.SX.sym("q", 7), ca.SX.sym("mu_i", 2)
        phi_i, c_i = terms.waypoint(q, terms.env, terms.learnt)
        reward_i = ca.dot(theta, phi_i)
        waypoint = ca.Function(
            "newton_waypoint",
            [q, p],
            [
                ca.densify(e)
                for e in (
                    phi_i,
                    c_i,
                    ca.jacobian(c_i, q),
                    ca.gradient(reward_i, q),
                    ca.hessian(reward_i, q)[0],
                )
            ],
        )
        clearance = ca.Function(
            "newton_clearance", [q, p, mu_i], [ca.densify(ca.hessian(ca.dot(mu_i, c_i), q)[0])]
        )
        if library is not None:
            source = resources.files(__package__).joinpath(_SOURCE).read_bytes()
            functions = [first, fn, features, waypoint, clearance]
            build_once(library, lambda path: compile_library(functions, path, (_SOURCE, source)))
        self._first = Compiled(first, library)
        self._eval = Compiled(fn, library)
        self._features = Compiled(features, library)
        self.n, self.n_c = terms.x.shape[0], n_c
        rows, cols = fn.sparsity_out(3).get_triplet()
        self._jac_at = np.ravel_multi_index((rows, cols), (n_c, self.n))
        rows, cols = (np.array(a) for a in fn.sparsity_out(4).get_triplet())
        self._hess_at = np.ravel_multi_index((rows, cols), (self.n, self.n))
        self._hess_mirror = np.ravel_multi_index((cols, rows), (self.n, self.n))
        if np.any(rows - cols > BANDWIDTH):
            raise ValueError(f"the Hessian's half-bandwidth exceeds {BANDWIDTH}")
        self._band_at = np.ravel_multi_index((rows - cols, cols), (BANDWIDTH + 1, self.n))
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.k = len(names)
        self._native = None
        if library is not None:
            n_env = terms.env.shape[0]
            self._native = self._load_native(library, n_env, smoothness)

    def _load_native(self, library: Path, n_env: int, smoothness: float):
        """``newton.c``'s solve from ``library``, its problem filled in (arrays kept alive)."""
        lib = ctypes.CDLL(str(library))
        solve = lib.newton_solve
        solve.restype = ctypes.c_int
        solve.argtypes = [ctypes.c_void_p] * 10
        (j_row, j_col), (h_row, h_col) = _layout(self.n // 7)
        self._keep = (j_row, j_col, h_row, h_col, self.lower, self.upper)
        problem = _Problem(
            n=self.n, n_c=self.n_c, k=self.k, nnz_j=j_row.size, nnz_h=h_row.size,
            j_row=j_row.ctypes.data, j_col=j_col.ctypes.data,
            h_row=h_row.ctypes.data, h_col=h_col.ctypes.data,
            n_env=n_env, smoothness=smoothness,
            lower=self.lower.ctypes.data, upper=self.upper.ctypes.data,
            active=ACTIVE, at_bound=AT_BOUND, stationarity=STATIONARITY,
            feasibility=FEASIBILITY, gate=GATE, slow=SLOW,
            max_steps=MAX_STEPS, steps_per_set=STEPS_PER_SET, slow_after=SLOW_AFTER,
            stage_residual=STAGE_RESIDUAL, stage_tolerance=STAGE_TOLERANCE,
            max_stages=MAX_STAGES,
            dpbtrf=_lapack("dpbtrf"), dpbtrs=_lapack("dpbtrs"),
            dposv=_lapack("dposv"), dgesv=_lapack("dgesv"),
        )  # fmt: skip
        n_double, n_int = ctypes.c_longlong(), ctypes.c_longlong()
        if lib.newton_workspace(ctypes.byref(problem), ctypes.byref(n_double), ctypes.byref(n_int)):
            raise RuntimeError(f"{library}: the compiled Newton loop refused its workspace")
        self._problem, self._sizes = problem, (n_double.value, n_int.value)
        self._plain = _Problem.from_buffer_copy(problem)
        self._plain.max_stages = 0  # the attempt alone, no continuation
        self._local = threading.local()
        return solve

    def _workspace(self):
        """This thread's buffers for the compiled loop."""
        b = getattr(self._local, "buffers", None)
        if b is None:
            n_double, n_int = self._sizes
            b = self._local.buffers = (
                np.zeros(n_double),
                np.zeros(n_int, dtype=np.int64),
                np.zeros(self.n),
                np.zeros(self.n_c),
                np.zeros(self.n_c, dtype=np.intc),
                np.zeros(self.k),
                _Report(),
                np.zeros(self.n),
            )
        return b

    def _jacobian(self, nonzeros: np.ndarray) -> np.ndarray:
        jac = np.zeros(self.n_c * self.n)
        jac[self._jac_at] = nonzeros
        return jac.reshape(self.n_c, self.n)

    def terms(self, x: np.ndarray, p: np.ndarray, mu: np.ndarray):
        """(f, ∇f, c, J (n_c, n) dense, W's lower-triangle nonzeros) at (x, p, μ)."""
        f, grad, c, jac_nz, hess_nz = self._eval(x, p, mu)
        return float(f[0]), grad, c, self._jacobian(jac_nz), hess_nz

    def hessian(self, hess_nz: np.ndarray, free: np.ndarray | None = None) -> np.ndarray:
        """W dense and symmetric, (n, n), or its rows and columns ``free``."""
        hess = np.zeros(self.n * self.n)
        hess[self._hess_at] = hess_nz
        hess[self._hess_mirror] = hess_nz
        hess = hess.reshape(self.n, self.n)
        return hess if free is None else hess[np.ix_(free, free)]

    def _band(self, hess_nz: np.ndarray, free: np.ndarray) -> np.ndarray:
        """W's rows and columns ``free`` in LAPACK's lower band storage (8, n_free)."""
        if free.size == self.n:
            band = np.zeros((BANDWIDTH + 1) * self.n)
            band[self._band_at] = hess_nz
            return band.reshape(BANDWIDTH + 1, self.n)
        w = self.hessian(hess_nz, free)
        band = np.zeros((BANDWIDTH + 1, free.size))
        for d in range(min(BANDWIDTH, free.size - 1) + 1):
            band[d, : free.size - d] = np.diagonal(w, -d)
        return band

    def _start(self, x0: np.ndarray, p: np.ndarray) -> _Start:
        """The start of a re-solve: joints on a limit held there, the guessed active set, its
        multipliers for the new θ (least squares) and the stationarity residual they leave."""
        x = np.array(x0, dtype=float)
        lower, upper = self.lower, self.upper
        on_lower = x - lower < AT_BOUND
        on_upper = upper - x < AT_BOUND
        held = on_lower | on_upper
        x[on_lower], x[on_upper] = lower[on_lower], upper[on_upper]
        free = np.flatnonzero(~held)
        mu = np.zeros(self.n_c)
        grad, c, jac_nz = self._first(x, p)
        active = np.flatnonzero(c < ACTIVE)
        jac = self._jacobian(jac_nz)
        ja = jac[active] if free.size == self.n else jac[np.ix_(active, free)]
        g = grad if free.size == self.n else grad[free]
        if active.size == 1:  # multipliers at x0 for the new θ (least squares)
            row = ja[0]
            mu[active] = row @ g / (row @ row) if row @ row > 0 else 0.0
        elif active.size:  # normal equations (a few rows), least squares if singular
            _, solved, info = dposv(ja @ ja.T, ja @ g)
            mu[active] = solved if info == 0 else np.linalg.lstsq(ja.T, g, rcond=None)[0]
        residual = _inf_norm(g - ja.T @ mu[active])
        return _Start(x, on_lower, held, free, active, mu, residual)

    def residual(self, x0: np.ndarray, p: np.ndarray) -> float:
        """How far the start ``x0`` is from stationary for parameters ``p``: the gate's
        ‖∇f − J_𝒜ᵀμ‖∞ with the least-squares multipliers of its guessed active set (near 0 at
        the plan of the same θ; above :data:`GATE`, Newton is not tried)."""
        return self._start(x0, p).residual

    def solve(self, x0: np.ndarray, p: np.ndarray) -> NewtonSolution | None:
        """Newton from the free waypoints ``x0`` for parameters ``p`` = (θ, e, q_start,
        q_goal); None when the answer cannot be certified as a strict local minimum."""
        return self.attempt(x0, p)[1]

    def attempt(
        self, x0: np.ndarray, p: np.ndarray, continuation: bool = True
    ) -> tuple[str, NewtonSolution | None]:
        """:meth:`solve` with its outcome's name (:data:`OUTCOMES`: "certified", or why not);
        ``continuation = False``: the plain attempt alone, as the Python loop does it."""
        if self._native is None:
            return self._solve_python(x0, p)
        work, iwork, x, mu, active, phi, report, start = self._workspace()
        start[:] = x0
        p = np.ascontiguousarray(p, dtype=float)
        problem = self._problem if continuation else self._plain
        code = self._native(
            ctypes.byref(problem), start.ctypes.data, p.ctypes.data, work.ctypes.data,
            iwork.ctypes.data, x.ctypes.data, mu.ctypes.data, active.ctypes.data,
            phi.ctypes.data, ctypes.byref(report),
        )  # fmt: skip
        outcome = OUTCOMES[code]
        if outcome == "certified":
            answer = NewtonSolution(
                x.copy(), report.objective, report.steps, phi.copy(), report.stages
            )
            return outcome, answer
        if outcome == "lstsq":
            return self._solve_python(x0, p)
        if outcome == "reduced":  # W indefinite at a KKT point: its reduced Hessian decides
            held = (start - self.lower < AT_BOUND) | (self.upper - start < AT_BOUND)
            free, on = np.flatnonzero(~held), np.flatnonzero(active)
            _, _, _, jac, hess_nz = self.terms(x, p, mu)
            if not _reduced_positive(self.hessian(hess_nz, free), jac[np.ix_(on, free)]):
                return "indefinite", None
            phi = self._features(x, p)[0]
            answer = NewtonSolution(x.copy(), report.objective, report.steps, phi, report.stages)
            return "certified", answer
        return outcome, None

    def _solve_python(self, x0: np.ndarray, p: np.ndarray) -> tuple[str, NewtonSolution | None]:
        """The loop in Python (an uncompiled planner's; the compiled one's oracle)."""
        x, on_lower, held, free, active, mu, residual = self._start(x0, p)
        all_free = free.size == self.n
        if residual > GATE:
            return "gate", None  # θ moved too far for a few Newton steps (7% would pass)
        f, grad, c, jac, hess_nz = self.terms(x, p, mu)
        since_change = 0
        for step in range(MAX_STEPS + 1):
            ja = jac[active] if all_free else jac[np.ix_(active, free)]
            g = grad if all_free else grad[free]
            residual = _inf_norm(g - ja.T @ mu[active])
            infeasible = _inf_norm(c[active])
            if residual <= STATIONARITY and infeasible <= FEASIBILITY:
                change = self._change(active, mu, c)
                if change is None:
                    return self._certify(
                        x, p, f, grad, jac, hess_nz, active, mu, free, held, on_lower, step
                    )
                active = np.setxor1d(active, [change])
                mu[change] = 0.0
                ja = jac[active] if all_free else jac[np.ix_(active, free)]
                since_change = 0
            elif (
                step == MAX_STEPS
                or since_change == STEPS_PER_SET
                or (step >= SLOW_AFTER and max(residual, infeasible) > SLOW)
            ):
                return "stalled", None  # not quadratic: a step too far from the start
            found = _kkt_step(
                self._band(hess_nz, free), partial(self.hessian, hess_nz, free), ja, g, c[active]
            )
            if found is None:
                return "singular", None
            d, mu_active = found
            if all_free:
                x += d
            else:
                x[free] += d
            mu[:] = 0.0
            mu[active] = mu_active
            since_change += 1
            f, grad, c, jac, hess_nz = self.terms(x, p, mu)
        return "stalled", None

    @staticmethod
    def _change(active: np.ndarray, mu: np.ndarray, c: np.ndarray) -> int | None:
        """The one active-set change a converged step still needs: the most negative
        multiplier leaves, else the most violated inactive clearance joins; None if none."""
        if active.size and mu[active].min() < 0:
            return int(active[np.argmin(mu[active])])
        inactive = np.ones(c.size, dtype=bool)
        inactive[active] = False
        if np.any(c[inactive] < 0):
            return int(np.argmin(np.where(inactive, c, np.inf)))
        return None

    def _certify(self, x, p, f, grad, jac, hess_nz, active, mu, free, held, on_lower, steps):
        """The KKT point as a solution if it is a strict local minimum (second order)."""
        if np.any(x < self.lower) or np.any(x > self.upper):
            return "infeasible", None
        # Multipliers of the joints held on a limit: ∂L/∂x ≥ 0 on a lower one, ≤ 0 on an upper.
        if held.any():
            bound = (grad - jac[active].T @ mu[active])[held]
            if np.any(np.where(on_lower[held], bound, -bound) < -STATIONARITY):
                return "infeasible", None
        if _band_cholesky(self._band(hess_nz, free)) is None and not _reduced_positive(
            self.hessian(hess_nz, free), jac[np.ix_(active, free)]
        ):
            return "indefinite", None
        answer = NewtonSolution(x=x, objective=f, steps=steps, features=self._features(x, p)[0])
        return "certified", answer


def _reduced_positive(w: np.ndarray, ja: np.ndarray) -> bool:
    """Whether W (free rows and columns) is positive definite on the null space of the
    active clearances' Jacobian ``ja`` (never with no active clearance: W itself was not)."""
    if not ja.shape[0]:
        return False
    q, _ = np.linalg.qr(ja.T, mode="complete")
    z = q[:, ja.shape[0] :]
    try:
        np.linalg.cholesky(z.T @ w @ z)
    except np.linalg.LinAlgError:
        return False
    return True


def _inf_norm(v: np.ndarray) -> float:
    """max |v_i| (0 for an empty v), without NumPy's slower reduction keywords."""
    return float(np.abs(v).max()) if v.size else 0.0


#: Half-bandwidth of W in the waypoint ordering: a waypoint's 7 joints couple among
#: themselves (features, clearances) and with the same joint of the next waypoint (S).
BANDWIDTH = 7


def _band_cholesky(band: np.ndarray) -> np.ndarray | None:
    """LAPACK's banded Cholesky (dpbtrf) of W in lower band storage, or None when W is not
    positive definite."""
    factor, info = dpbtrf(band, lower=1)
    return factor if info == 0 else None


def _kkt_step(band, dense, ja, grad, c_active):
    """(d, μ_𝒜) of the KKT system: by the banded Cholesky of W (``band``) and the Schur
    complement J W⁻¹ Jᵀ of the few active clearances when W is positive definite, else by
    dense LU of the whole system (``dense()`` gives W)."""
    m = ja.shape[0]
    factor = _band_cholesky(band)
    if factor is not None:
        rhs = np.empty((grad.size, m + 1))
        rhs[:, :m] = ja.T
        rhs[:, m] = grad
        solved, info = dpbtrs(factor, rhs, lower=1)
        if info != 0:
            return None
        y, wg = solved[:, :m], solved[:, m]
        if m == 1:  # the usual case: one active clearance, a scalar Schur complement
            schur = float(ja[0] @ y[:, 0])
            if not schur > 0:
                return None
            mu = np.array([(ja[0] @ wg - c_active[0]) / schur])
            d = y[:, 0] * mu[0] - wg
        elif m == 2:  # two: Cramer's rule on the 2 × 2 Schur complement (positive definite)
            (a, b), (c, e) = ja @ y
            r = ja @ wg - c_active
            det = a * e - b * c
            if not (a > 0 and det > 0):
                return None
            mu = np.array([e * r[0] - b * r[1], a * r[1] - c * r[0]]) / det
            d = y @ mu - wg
        elif m:  # the Schur complement is positive definite: LAPACK's Cholesky solve
            _, mu, info = dposv(ja @ y, ja @ wg - c_active)
            if info != 0:
                return None
            d = y @ mu - wg
        else:
            mu, d = np.zeros(0), -wg
    else:
        nf = grad.size
        kkt = np.zeros((nf + m, nf + m))
        kkt[:nf, :nf] = dense()
        kkt[:nf, nf:] = -ja.T
        kkt[nf:, :nf] = ja
        try:
            sol = np.linalg.solve(kkt, np.concatenate([-grad, -c_active]))
        except np.linalg.LinAlgError:
            return None
        d, mu = sol[:nf], sol[nf:]
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(mu))):
        return None
    return d, mu


def library_key(build_key: str) -> str:
    """The compiled Newton functions' file name key: the solver's build key, this module and
    how it is compiled (:mod:`~corrections_sim.planning.compiled`)."""
    h = hashlib.sha256(build_key.encode())
    h.update(resources.files(__package__).joinpath(_SOURCE).read_bytes())
    for module in (inspect.getmodule(NewtonPath), compiled):
        h.update(inspect.getsource(module).encode())
    return h.hexdigest()[:20]
