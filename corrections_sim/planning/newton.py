r"""Warm re-solves by Newton steps on the active set (``PlannerConfig.warm = "newton"``).

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
"""

from __future__ import annotations

import hashlib
import inspect
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import NamedTuple

import casadi as ca
import numpy as np
from scipy.linalg.lapack import dpbtrf, dpbtrs, dposv

from corrections_sim.planning import compiled
from corrections_sim.planning.compiled import Compiled, compile_library
from corrections_sim.planning.features import waypoint_feature_function

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
    steps, and Φ(ξ, E) of the whole trajectory (start and goal included), shape (k,)."""

    x: np.ndarray
    objective: float
    steps: int
    features: np.ndarray


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
        p = ca.vertcat(theta, terms.env, terms.q_start, terms.q_goal)
        f = -ca.dot(theta, terms.features) + smoothness * terms.smoothness
        jac = ca.jacobian(terms.constraints, terms.x)
        hess = ca.tril(ca.hessian(f - ca.dot(mu, terms.constraints), terms.x)[0])
        grad = ca.gradient(f, terms.x)
        first = ca.Function("newton_first", [terms.x, p], [grad, terms.constraints, jac])
        fn = ca.Function("newton_terms", [terms.x, p, mu], [f, grad, terms.constraints, jac, hess])
        ends = waypoint_feature_function(names)
        phi = terms.features + ends(terms.q_start, terms.env) + ends(terms.q_goal, terms.env)
        features = ca.Function("newton_features", [terms.x, p], [phi])
        if library is not None and not library.is_file():
            compile_library([first, fn, features], library)
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
        x, on_lower, held, free, active, mu, residual = self._start(x0, p)
        all_free = free.size == self.n
        if residual > GATE:
            return None  # θ moved too far for a few Newton steps (measured: 7% would pass)
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
                return None  # not converging quadratically: a step too far from the start
            found = _kkt_step(
                self._band(hess_nz, free), partial(self.hessian, hess_nz, free), ja, g, c[active]
            )
            if found is None:
                return None
            d, mu_active = found
            if all_free:
                x += d
            else:
                x[free] += d
            mu[:] = 0.0
            mu[active] = mu_active
            since_change += 1
            f, grad, c, jac, hess_nz = self.terms(x, p, mu)
        return None

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
            return None
        # Multipliers of the joints held on a limit: ∂L/∂x ≥ 0 on a lower one, ≤ 0 on an upper.
        if held.any():
            bound = (grad - jac[active].T @ mu[active])[held]
            if np.any(np.where(on_lower[held], bound, -bound) < -STATIONARITY):
                return None
        if _band_cholesky(self._band(hess_nz, free)) is None:
            # W itself is not positive definite; it need only be so on the null space of J_𝒜.
            ja = jac[np.ix_(active, free)]
            if not ja.shape[0]:
                return None
            q, _ = np.linalg.qr(ja.T, mode="complete")
            z = q[:, ja.shape[0] :]
            try:
                np.linalg.cholesky(z.T @ self.hessian(hess_nz, free) @ z)
            except np.linalg.LinAlgError:
                return None
        return NewtonSolution(x=x, objective=f, steps=steps, features=self._features(x, p)[0])


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
    for module in (inspect.getmodule(NewtonPath), compiled):
        h.update(inspect.getsource(module).encode())
    return h.hexdigest()[:20]
