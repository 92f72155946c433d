"""EX-M's relevance: the exact posterior over θ with each correction either about what the
robot can represent (relevant) or not, judged across the person's corrections.

Each correction is relevant with probability r, the person's rate, independently given r,
and r ~ Beta(a, b) is shared by all of their corrections. A correction is seen twice: its
features zᵢ, and the direction uᵢ of the person's move on the waypoints they moved (a unit
vector in 7 dimensions a waypoint; its size is taken as given).

* relevant: zᵢ ~ N(hᵢ(θ), N_s), hᵢ(θ) = Φ(C(ξⁱ, ξ*(θ, Eⁱ))) as in EX-C, the person's noise
  N_s = s N̄ one of the point masses s of ``noise_scales`` (N̄ the centre of KF-CL's prior
  over N, V₀ / (ν₀ − k − 1)); and uᵢ ~ von Mises–Fisher about the direction C(ξⁱ, ξ*(θ, Eⁱ))
  − ξⁱ predicts there, with the person's concentration κ one of ``concentrations``;
  a uniform prior over the (s, κ) pairs;
* irrelevant: uᵢ uniform on the sphere (a nudge in a random direction, or a move made for a
  feature the robot lacks, whose direction no θ predicts), and zᵢ ~ qᵢ, the features of a
  nudge as large as the person's move in a random direction (a Gaussian moment-matched to 64
  such nudges, 32 directions and their opposites, the same for every correction and run),
  its spread widened by N̄ / 16.

The direction is what tells a nudge from a correction: the features alone cannot once the
robot's plan is nearly the person's, when both move them by a few thousandths (measured,
docs/person-models.md), whereas the angle between two directions does not shrink with the
move. The sum over which corrections were relevant is exact: given θ, s and κ the corrections
are independent, so with j of t relevant

    p(data | θ, s, κ) = Σⱼ B(a + j, b + t − j) / B(a, b) · eⱼ(θ, s, κ),

eⱼ the sum over the subsets R of j corrections of Π_{i∈R} (relevant density) Π_{i∉R} qᵢ(zᵢ)
(each density over the uniform one of uᵢ), found by a recursion over the corrections (O(t²) a
node and pair). A person's noise is learnt among point masses, not under KF-CL's
inverse-Wishart as in EX-CL: with N integrated out under the latter the corrections are not
independent given θ, and the sum over subsets would take 2ᵗ terms. Where ``ctx.corrected`` is
not given (no joint-space correction to judge), the correction is taken as relevant and its
direction is not read; where the person moved nothing (their plan is the robot's), it is taken
in as relevant but reported unjudged (β̂ None: there is no move to call a nudge, and a study
scores relevance over the corrections that moved something).

Every correction is weighed at every node at once (no lazy weighing: at k = 2 it saves
little, and the relevance sum has no cheap bound).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.special import betaln, gammaln, ive, logsumexp

from corrections_sim.belief import Belief, symmetrize
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import LearnerContext, Step
from corrections_sim.learning.exact import bayes as ref
from corrections_sim.learning.exact.cells import Cells
from corrections_sim.learning.exact.learners import ExactCorrectionAware, ExactStep
from corrections_sim.learning.exact.state import ExactState, GridPosterior
from corrections_sim.learning.history import CorrectionEntry
from corrections_sim.learning.params import require_fraction, require_positive
from corrections_sim.people.corrections import MOVED, CorrectionModel, WaypointCorrection
from corrections_sim.planning.features import waypoint_features
from corrections_sim.planning.planner import Plan, PlanningError
from corrections_sim.scene.environments import Environment

#: Random nudge directions the irrelevant density is moment-matched to (and their opposites).
NUDGE_DIRECTIONS = 32
#: The seed of those directions (the same for every correction, run and machine).
NUDGE_SEED = 6602
#: The irrelevant density's spread is widened by N̄ times this (a nudge that barely moves
#: the features is not a point mass).
NUDGE_FLOOR = 1.0 / 16.0
#: The concentrations κ of a relevant move's direction about the predicted one (von
#: Mises–Fisher), a uniform prior over them: from nearly any direction (1) to within about
#: 0.3 rad of it (64) for a one-waypoint move. Up to 1024, a person whose plan is another
#: local optimum than the atlas's in one environment was judged irrelevant there and the
#: posterior collapsed off θ* (mean NEES in the millions; docs/person-models.md).
DEFAULT_CONCENTRATIONS: tuple[float, ...] = (1.0, 4.0, 16.0, 64.0)


@functools.cache
def _directions(dims: int) -> np.ndarray:
    """Unit directions in ``dims`` joint dimensions, and their opposites (2·NUDGE_DIRECTIONS,
    dims)."""
    u = np.random.default_rng([NUDGE_SEED, dims]).normal(size=(NUDGE_DIRECTIONS, dims))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    out = np.concatenate([u, -u])
    out.setflags(write=False)
    return out


def moved(robot: np.ndarray, corrected: np.ndarray):
    """(the waypoints the person moved (T,) bool, the move there (7·m,)), or (None, None)
    when nothing moved."""
    move = np.asarray(corrected, float) - np.asarray(robot, float)
    rows = np.linalg.norm(move, axis=1) > MOVED
    return (rows, move[rows].ravel()) if rows.any() else (None, None)


def nudge_density(
    robot: np.ndarray, rows: np.ndarray, size: float, env: Environment, names, floor: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The irrelevant density's mean (k,) and covariance (k, k) of Φ after a nudge of ``size``
    on the waypoints ``rows`` (a mask (T,)) of ``robot`` (T, 7), in a random direction."""
    robot = np.asarray(robot, float)
    rows = np.flatnonzero(rows)
    u = _directions(7 * rows.size) * size  # (m, 7·rows)
    params = env.params()
    nudged = robot[rows][None] + u.reshape(len(u), rows.size, 7)
    after = waypoint_features(nudged.reshape(-1, 7), params, names).reshape(len(u), rows.size, -1)
    before = waypoint_features(robot, params, names)
    phi = before.sum(axis=0) + (after - before[rows][None]).sum(axis=1)  # (m, k)
    mean = phi.mean(axis=0)
    d = phi - mean
    return mean, symmetrize(d.T @ d / len(d) + floor)


@dataclass(frozen=True, eq=False)
class JudgedEntry(CorrectionEntry):
    """A correction with the irrelevant density of its features, log qᵢ(zᵢ) (−inf: it is
    relevant for certain, e.g. no joint-space correction was given), the waypoints the person
    moved (a mask (T,)) and the direction of their move there (a unit vector, 7 a waypoint),
    or None."""

    log_irrelevant: float = -np.inf
    rows: np.ndarray | None = None
    direction: np.ndarray | None = None


def predicted_cosines(
    model: CorrectionModel, robot: np.ndarray, plans: np.ndarray, rows, direction
) -> np.ndarray:
    """cos of the angle between the person's move and the move C(ξ, ξ*(θ)) − ξ predicts, on
    the waypoints they moved, at each of ``plans`` (n, T, 7) (0 where none is predicted, NaN
    where a plan is NaN)."""
    robot = np.asarray(robot, float)
    plans = np.asarray(plans, float)
    if isinstance(model, WaypointCorrection):  # its answer for the observed waypoints
        moved = robot[rows][None] + model.step * (plans[:, rows] - robot[rows][None])
    else:
        moved = np.full((len(plans), int(rows.sum()), robot.shape[1]), np.nan)
        finite = np.all(np.isfinite(plans), axis=(1, 2))
        if finite.any():
            moved[finite] = model.apply_many(robot, plans[finite])[:, rows]
    pred = (moved - robot[rows][None]).reshape(len(plans), -1)
    norm = np.linalg.norm(pred, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = (pred @ direction) / norm
    return np.where(norm > 0, np.clip(cos, -1.0, 1.0), np.where(np.isnan(norm), np.nan, 0.0))


def log_vmf_ratio(kappas: np.ndarray, dims: int, cos: np.ndarray) -> np.ndarray:
    """log of the von Mises–Fisher density on the sphere in ``dims`` dimensions with
    concentration κ at cos, over the uniform density there: (…, K) for cos (…,); 0 at κ = 0
    (the uniform density: the direction not read)."""
    kappas = np.asarray(kappas, float)
    nu = 0.5 * dims - 1.0
    some = np.where(kappas > 0, kappas, 1.0)
    log_c = nu * np.log(some) - 0.5 * dims * np.log(2 * np.pi) - (np.log(ive(nu, some)) + some)
    log_area = np.log(2.0) + 0.5 * dims * np.log(np.pi) - gammaln(0.5 * dims)
    out = log_c + log_area + some * np.asarray(cos, float)[..., None]
    return np.where(kappas > 0, out, 0.0)


@dataclass(frozen=True)
class RelevantExact(ExactCorrectionAware):
    """One correction model's exact posterior over θ, the person's noise scale and which of
    their corrections were relevant (module docstring). EX-M's part when it judges relevance.

    Attributes:
        noise_scales: the point masses s of N = s N̄ (> 0, distinct), uniform a priori.
        concentrations: the concentrations κ ≥ 0 of a relevant move's direction (0: the
            direction not read), uniform a priori, each pair (s, κ) alike.
        relevance_prior: E[r] before any correction, in (0, 1).
        relevance_count: how many corrections' worth the prior on r holds (> 0):
            r ~ Beta(prior · count, (1 − prior) · count).
    """

    noise: str = "learnt"
    noise_scales: tuple[float, ...] = (1.0,)
    concentrations: tuple[float, ...] = DEFAULT_CONCENTRATIONS
    relevance_prior: float = 0.9
    relevance_count: float = 2.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.noise != "learnt":
            raise ParameterError("noise", 'judging relevance needs noise = "learnt"')
        require_fraction("relevance_prior", self.relevance_prior)
        require_positive("relevance_count", self.relevance_count)

    # -- the model ---------------------------------------------------------------------------

    def _beta(self) -> tuple[float, float]:
        a = self.relevance_prior * self.relevance_count
        return a, self.relevance_count - a

    def _centre(self, prior) -> np.ndarray:
        k = prior.scale.shape[0]
        return prior.scale / (prior.dof - k - 1)

    def _scale_terms(self, left: np.ndarray, prior, history) -> np.ndarray:
        """log of a relevant correction's density (over the irrelevant direction's) at every
        node, (noise scale, concentration) and correction (n, S·K, t): N(rᵢ; 0, s N̄) times
        the von Mises–Fisher density of its direction over the uniform one."""
        count = left.shape[1]
        res = left[:, :, :-1]  # (n, t, k): the residuals rᵢ = zᵢ − hᵢ(θ)
        cos = left[:, :, -1]  # (n, t): the moves' cosines
        centre = self._centre(prior)
        k = centre.shape[0]
        inv = np.linalg.inv(centre)
        _, logdet = np.linalg.slogdet(2.0 * np.pi * centre)
        quad = np.einsum("nti,ij,ntj->nt", res, inv, res)
        s = np.asarray(self.noise_scales, float)
        norm = 0.5 * (logdet + k * np.log(s))
        gauss = -0.5 * quad[:, None, :] / s[None, :, None] - norm[None, :, None]  # (n, S, t)
        kappas = np.asarray(self.concentrations, float)
        vmf = np.zeros((len(res), len(kappas), count))
        for i, seen in enumerate(history[1 : count + 1]):
            if seen.direction is not None:
                vmf[:, :, i] = log_vmf_ratio(kappas, seen.direction.size, cos[:, i])
        combos = len(s) * len(kappas)
        out = (gauss[:, :, None, :] + vmf[:, None, :, :]).reshape(len(res), combos, count)
        return np.where(np.isfinite(out), out, -np.inf)

    def _elementary(self, left: np.ndarray, prior, history, log_q: np.ndarray, upto: int):
        """log eⱼ over the first ``upto`` corrections (n, S, upto + 1) and the scale terms,
        from what the corrections ``left`` at the nodes (:attr:`GridPosterior.left`)."""
        terms = self._scale_terms(left, prior, history)
        n, S, _ = terms.shape
        e = np.full((n, S, upto + 1), -np.inf)
        e[:, :, 0] = 0.0
        for i in range(upto):
            rel = e[:, :, :-1] + terms[:, :, i : i + 1]
            irr = e + log_q[i]
            e = irr.copy()
            e[:, :, 1:] = np.logaddexp(irr[:, :, 1:], rel)
        return e, terms

    def _count_weights(self, t: int) -> np.ndarray:
        """log B(a + j, b + t − j) / B(a, b) for j = 0…t."""
        a, b = self._beta()
        j = np.arange(t + 1)
        return betaln(a + j, b + t - j) - betaln(a, b)

    def _joint(self, left: np.ndarray, prior, history) -> np.ndarray:
        """log π p(z₁…zₜ | θ, s, κ) at each node and (scale, concentration) (n, S·K), from
        what the corrections ``left`` there (n, t, k + 1)."""
        t = left.shape[1]
        e, _ = self._elementary(left, prior, history, self._log_q(history), t)
        out = logsumexp(e + self._count_weights(t)[None, None, :], axis=2)
        return out - np.log(len(self.noise_scales) * len(self.concentrations))

    # -- the grid -----------------------------------------------------------------------------

    def _log_q(self, history) -> np.ndarray:
        return np.array([h.log_irrelevant for h in history[1:]], float)

    def state_log_posterior(self, state: ExactState) -> np.ndarray:
        return self._posterior(state.grid, state.noise, state.history)

    def _posterior(self, grid: GridPosterior, prior, history) -> np.ndarray:
        """The log posterior at every node (n,)."""
        return grid.log_density + logsumexp(self._joint(grid.left, prior, history), axis=1)

    def _residuals(self, history, ctx: LearnerContext, thetas: np.ndarray):
        """(log prior, what each correction left at each node (n, t, k + 1): its residual and
        its move's cosine) at ``thetas``: every correction of ``history``."""
        first = history[0]
        log_d = ref.gaussian_log_prior(thetas, Belief(theta=first.theta, cov=first.cov))
        k = thetas.shape[1]
        res = np.zeros((len(thetas), len(history) - 1, k + 1))
        for i, seen in enumerate(history[1:]):
            plans = ctx.book.atlas.plans(thetas, seen.env)
            res[:, i], bad = self._left(plans, seen, ctx.features)
            log_d = np.where(bad, -np.inf, log_d)
        return log_d, res

    def _left(self, plans: np.ndarray, seen: JudgedEntry, names):
        """(residual and cosine at each of ``plans`` (n, k + 1), where no plan is (n,))."""
        h = self.observation().at_plans(plans, seen.robot, seen.env, names)
        out = np.zeros((len(plans), h.shape[1] + 1))
        out[:, :-1] = np.asarray(seen.phi_h, float)[None, :] - h
        if seen.direction is not None:
            out[:, -1] = predicted_cosines(self.model, seen.robot, plans, seen.rows, seen.direction)
        bad = ~np.all(np.isfinite(out), axis=1)
        out[bad] = 0.0
        return out, bad

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        atlas, state, history = self._opened(ctx, belief)
        prior = state.noise
        before = state.grid
        if before is None:
            g = atlas.grid
            cells = Cells.base(g.lows, g.highs, g.counts, self.max_level)
            log_d, res = self._residuals(history[:1], ctx, cells.thetas())
            before = GridPosterior(cells.thetas(), log_d, None, 0, cells, left=res)
        joint = self._joint(before.left, prior, history)
        log_before = before.log_density + logsumexp(joint, axis=1)
        weights = ref.posterior(log_before, before.cells.coefficients)
        z = np.asarray(phi_h, float)
        k = z.size
        at = np.flatnonzero(np.isfinite(before.log_density))
        plans = atlas.plans(before.thetas[at], env)
        h = self.observation().at_plans(plans, plan.trajectory, env, ctx.features)
        seen = np.all(np.isfinite(h), axis=1) & (weights[at] > 0)
        if not seen.any():
            raise PlanningError(
                f"{env.name}: the atlas has no plan where the posterior lives; update skipped"
            )
        centre = self._centre(prior)
        rows, move, log_q = None, None, -np.inf
        if ctx.corrected is not None:
            rows, move = moved(plan.trajectory, ctx.corrected)
        if rows is not None:
            size = float(np.linalg.norm(move))
            q = nudge_density(plan.trajectory, rows, size, env, ctx.features, NUDGE_FLOOR * centre)
            log_q, move = ref.gaussian_log_density(z, *q), move / size
        entry = JudgedEntry(env, plan.trajectory, z, ctx.noise.observation, log_q, rows, move)
        # What it expected before the correction (a relevant correction's predictive).
        w = weights[at][seen] / weights[at][seen].sum()
        expected = w @ h[seen]
        spread = (w[:, None] * (h[seen] - expected)).T @ (h[seen] - expected)
        noise_mean = self._noise_mean(joint, prior, weights)
        # Take it in: its residual and cosine at every node.
        r = np.zeros((len(before.thetas), k + 1))
        log_d = np.array(before.log_density)
        r[at], bad = self._left(plans, entry, ctx.features)
        log_d[at[bad]] = -np.inf
        res = np.concatenate([before.left, r[:, None, :]], axis=1)
        history = (*history, entry)
        after = GridPosterior(before.thetas, log_d, None, before.count + 1, before.cells, left=res)
        after, log_post = self._refine(ctx, after, history, prior)
        mean, cov = self.moments(after, log_post)
        kept = ExactState(noise=prior, grid=after, history=history)
        new = Belief(theta=mean, cov=cov, state=kept)
        # A correction that moved nothing (the robot's plan was already the person's) is
        # judged by nobody: no move, no nudge to tell from a correction (None, not 1).
        nothing = ctx.corrected is not None and rows is None
        beta = None if nothing else self._relevance(after, prior, history)
        return ExactStep(
            new,
            None,
            z - plan.features,
            symmetrize(spread + noise_mean),
            relevance=beta,
            expected=expected,
        )

    def _refine(self, ctx, grid: GridPosterior, history, prior):
        """``grid`` with its cells cut finer while the posterior needs it (as EX-C's), and
        its log posterior (the sum over relevant subsets made once a node)."""
        refine = ref.Refinement(self.resolution, self.cut, self.axes)
        mass = logsumexp(self._joint(grid.left, prior, history), axis=1)
        while (cells := refine.finer(grid.cells, grid.log_density + mass)) is not None:
            new = cells.thetas()[len(grid.thetas) :]
            log_d, res = self._residuals(history, ctx, new)
            mass = np.concatenate([mass, logsumexp(self._joint(res, prior, history), axis=1)])
            log_d = np.concatenate([grid.log_density, log_d])
            res = np.concatenate([grid.left, res])
            grid = GridPosterior(cells.thetas(), log_d, None, grid.count, cells, left=res)
        return grid, grid.log_density + mass

    def _noise_mean(self, joint: np.ndarray, prior, weights: np.ndarray) -> np.ndarray:
        """E[N | corrections] = Σ_s p(s | corrections) s N̄, from the joint (n, S·K) of
        :meth:`_joint` and the nodes' weights."""
        joint = logsumexp(joint.reshape(len(joint), len(self.noise_scales), -1), axis=2)
        with np.errstate(divide="ignore"):
            log_s = logsumexp(joint + np.log(weights)[:, None], axis=0)
        p = np.exp(log_s - logsumexp(log_s))
        return float(p @ np.asarray(self.noise_scales, float)) * self._centre(prior)

    def _relevance(self, grid: GridPosterior, prior, history) -> float:
        """P(the latest correction is relevant | every correction so far)."""
        log_q = self._log_q(history)
        t = grid.count
        if not np.isfinite(log_q[-1]):
            return 1.0
        e, terms = self._elementary(grid.left, prior, history, log_q, t - 1)  # (n, S·K, t)
        w = self._count_weights(t)
        on = logsumexp(e + w[None, None, 1:], axis=2) + terms[:, :, t - 1]
        off = logsumexp(e + w[None, None, :-1], axis=2) + log_q[-1]
        with np.errstate(divide="ignore"):
            log_c = np.log(grid.cells.coefficients)[:, None] + grid.log_density[:, None]
        on, off = logsumexp(on + log_c), logsumexp(off + log_c)
        return float(np.exp(on - np.logaddexp(on, off)))
