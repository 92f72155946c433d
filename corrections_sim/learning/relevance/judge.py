"""Is a correction explained by the robot's features at all? A relevance β̂ per correction.

In the manner of Bobu, Bajcsy, Fisac & Dragan (CoRL 2018, "Learning under misspecified
objective spaces"): before learning from a correction the robot asks how well the best θ in its
own feature space explains it, and learns in proportion to the answer.

The statistic is the correction-aware model's joint-space residual. With ξ the robot's
trajectory, ξ_h the person's correction and C the robot's correction model (KF-C's, the paper's
one-waypoint correction by default), a person with preference θ would have made
ĉ(θ) = C(ξ, ξ*(θ, E)). On the waypoints the person moved (rows of ξ_h − ξ that are not zero;
a model that picks which waypoints move answers for those, :meth:`CorrectionModel.at`),

    ρ = min_θ ‖ξ_h − ĉ(θ)‖ / ‖ξ_h − ξ‖ ,

the fraction of the move that no θ explains (0: some θ explains it exactly; 1: the best θ
is no better than not moving). The minimum is found by a trust-region Gauss–Newton over θ
whose Jacobian is a secant fit to every ĉ(θ) solved so far (:func:`explain`), starting from
θ̂ and the unscented sigma points of the current belief, whose plans a correction-aware
filter solves anyway: about six extra planner solves a correction.

Two models of ρ turn it into a probability (:meth:`Relevance.probability`):

* a relevant correction is explained up to the model's error: ρ ~ half-normal(``spread``);
* an irrelevant one (a nudge that carries no preference, or one made for a feature the robot
  does not have) moves the waypoint in a direction unrelated to the robot's features. For a
  uniformly random direction in the n = 7 joint dimensions and a k-dimensional family of
  plans through ξ (ξ = ξ*(θ̂, E) is one of them), the unexplained fraction obeys
  ρ² ~ Beta((n − k)/2, k/2) exactly when the family is flat; that density is used.

β̂ = P(relevant | ρ) = p f₁(ρ) / (p f₁(ρ) + (1 − p) f₀(ρ)) with the prior p (``prior``, a
study setting). How the learners use it
(:mod:`corrections_sim.learning.relevance.learners`): a Kalman
filter inflates its observation noise to N / β̂ (β̂ → 0: no update; β̂ = 1: the filter
itself); the perceptron scales its rate, α β̂. The Boltzmann posterior (BP) integrates the
rationality β out and has a lapse ε, the chance that a correction carries no information; its
1 − ε is a prior relevance that never changes with the correction, whereas β̂ here is a
posterior per correction from the joint-space evidence that BP never sees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from corrections_sim.components import ParameterError
from corrections_sim.learning.params import require_fraction
from corrections_sim.learning.relevance.state import PersonBelief
from corrections_sim.people.corrections import MOVED, CorrectionModel
from corrections_sim.planning.planner import PlanningError
from corrections_sim.plans.book import PlanBook
from corrections_sim.scene.environments import Environment
from corrections_sim.scene.robot import cup_pose

#: Joint-space directions a nudge can take at one waypoint (the arm's joints).
NUDGE_DIMENSIONS = 7
#: Smallest β̂ handed to a learner: N / β̂ stays finite.
MIN_RELEVANCE = 1e-6
#: Where a correction's residual is measured: the arm's joints (what a simulated person moves)
#: or the cup's path (what a person at the page drags or pushes).
SPACES = ("joint", "task")


def embed(space: str, configs: np.ndarray) -> np.ndarray:
    """The waypoints ``configs`` (m, 7) as the vector the residual is taken in: the joints
    themselves (m·7,) or the cup's centre at each (m·3,), m."""
    configs = np.atleast_2d(np.asarray(configs, float))
    if space == "joint":
        return configs.ravel()
    if space == "task":
        return np.concatenate([cup_pose(q)[1] for q in configs]) if len(configs) else np.zeros(0)
    raise ValueError(f"space {space!r}: expected one of {', '.join(SPACES)}")


def beta_rho_density(rho: float, a: float, b: float) -> float:
    """The density of ρ when ρ² ~ Beta(a, b): 2ρ · Beta(ρ²; a, b)."""
    x = min(max(rho * rho, 1e-300), 1.0 - 1e-12)
    log_beta = math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b)
    log_pdf = (a - 1.0) * math.log(x) + (b - 1.0) * math.log1p(-x) - log_beta
    return 2.0 * max(rho, 1e-300) * math.exp(log_pdf)


def random_direction_shape(dimensions: int, k: int) -> tuple[float, float]:
    """(a, b) of ρ² ~ Beta(a, b) for a uniformly random direction in ``dimensions`` against a
    flat k-dimensional family: ((n − k)/2, k/2)."""
    return 0.5 * max(dimensions - k, 1), 0.5 * max(k, 1)


@dataclass(frozen=True)
class Explanation:
    """The best explanation of one correction in the robot's feature space.

    Attributes:
        rho: ρ, the unexplained fraction of the move, ≥ 0 (1 when no θ beats not moving).
        theta: the θ that explains it best (k,).
        solves: the ĉ(θ) evaluated (planner solves asked of the book, memoized ones included).
    """

    rho: float
    theta: np.ndarray
    solves: int


class _Search:
    """The explanations of one correction tried so far: θ's, their predicted corrections on
    the moved waypoints, and the distance of each from the person's; the secant Jacobian is
    fitted to all of them, so a second search (under the belief) reuses the first's plans."""

    def __init__(self, book, env, robot, corrected, model, space: str = "joint") -> None:
        self.book, self.env, self.model, self.space = book, env, model, space
        self.robot = np.asarray(robot, float)
        corrected = np.asarray(corrected, float)
        move = corrected - self.robot
        self.rows = np.linalg.norm(move, axis=1) > MOVED
        self.target = embed(space, corrected[self.rows])
        start = embed(space, self.robot[self.rows])
        self.size = float(np.linalg.norm(self.target - start))
        self.thetas: list[np.ndarray] = []
        self.predictions: list[np.ndarray] = []
        self.costs: list[float] = []
        self.solves = 0

    def visit(self, theta: np.ndarray) -> float:
        """‖ξ_h − ĉ(θ)‖ on the moved waypoints (inf when the planner finds no plan)."""
        self.solves += 1
        try:
            plan = self.book.plan(theta, self.env)
        except PlanningError:
            return math.inf
        predicted = embed(self.space, self.model.at(self.robot, plan.trajectory, self.rows))
        self.thetas.append(np.array(theta, float))
        self.predictions.append(predicted)
        self.costs.append(float(np.linalg.norm(self.target - predicted)))
        return self.costs[-1]

    def jacobian(self, best: int, radius: float) -> np.ndarray | None:
        """∂ĉ/∂θ at ``thetas[best]`` (m, k): a linear fit to every point seen, weighted
        toward the best; None until k + 1 points are known."""
        points = np.array(self.thetas)
        k = points.shape[1]
        if points.shape[0] < k + 1:
            return None
        offsets = points - points[best]
        scale = max(radius, 1e-3)
        weights = np.exp(-0.5 * np.sum(offsets**2, axis=1) / (2.0 * scale) ** 2)
        design = np.hstack([np.ones((points.shape[0], 1)), offsets]) * weights[:, None]
        values = np.array(self.predictions)
        fit, *_ = np.linalg.lstsq(design, values * weights[:, None], rcond=None)
        return fit[1:].T

    def minimize(self, objective, iterations: int, radius: float, prior=None) -> int:
        """Trust-region Gauss–Newton on ``objective`` (index -> value) over the points seen,
        one planner solve a step; ``prior`` = (mean, inverse root L⁻¹, precision τ) adds
        the belief's term to the least squares. Returns the best index."""
        for _ in range(iterations):
            best = min(range(len(self.thetas)), key=objective)
            jac = self.jacobian(best, radius)
            if jac is None:
                break
            residual = self.target - self.predictions[best]
            if prior is not None:
                mean, root_inv, tau = prior
                scale = math.sqrt(tau) / self.size
                jac = np.vstack([scale * jac, root_inv])
                residual = np.concatenate(
                    [scale * residual, -root_inv @ (self.thetas[best] - mean)]
                )
            step, *_ = np.linalg.lstsq(jac, residual, rcond=None)
            norm = float(np.linalg.norm(step))
            if not np.all(np.isfinite(step)) or norm < 1e-6:
                break
            before = objective(best)
            if self.visit(self.thetas[best] + step * min(1.0, radius / norm)) < math.inf and (
                objective(len(self.thetas) - 1) < before
            ):
                radius *= 2.0
            else:
                radius *= 0.5
        return min(range(len(self.thetas)), key=objective)


def explain(
    book: PlanBook,
    env: Environment,
    robot: np.ndarray,
    corrected: np.ndarray,
    model: CorrectionModel,
    starts: np.ndarray,
    *,
    iterations: int = 12,
    radius: float = 0.5,
    space: str = "joint",
) -> Explanation:
    """ρ and the θ of the best explanation of ``corrected`` (T, 7) of ``robot`` (T, 7).

    Args:
        book: the run's plans (ξ*(θ, E) memoized; the starts' plans are usually there).
        model: C, the correction model the explanation assumes.
        starts: θ's to start from (m, k), the belief's mean and sigma points; the best one
            starts the search.
        iterations: trust-region Gauss–Newton steps after the starts (one solve each).
        radius: initial trust radius in θ units.
        space: where the residual is measured (:data:`SPACES`).
    """
    found, _ = _explain(book, env, robot, corrected, model, starts, iterations, radius, space)
    return found


def _explain(book, env, robot, corrected, model, starts, iterations, radius, space="joint"):
    starts = np.atleast_2d(np.asarray(starts, float))
    search = _Search(book, env, robot, corrected, model, space)
    if search.size == 0.0:
        return Explanation(rho=0.0, theta=starts[0].copy(), solves=0), search
    for theta in starts:
        search.visit(theta)
    if not search.costs:
        return Explanation(rho=1.0, theta=starts[0].copy(), solves=search.solves), search
    best = search.minimize(lambda i: search.costs[i], iterations, radius)
    rho = min(search.costs[best] / search.size, 1.0)
    return Explanation(rho=rho, theta=search.thetas[best], solves=search.solves), search


@dataclass(frozen=True)
class Judgement:
    """One correction judged against the belief and the person's record.

    Attributes:
        relevance: β̂, the posterior probability that the correction is relevant.
        rho: ρ*, the unexplained fraction of the best explanation by any θ.
        rho_belief: ρ at θ_b, the best explanation under the belief (below).
        theta: θ_b, the maximum of the belief's density times the relevant likelihood.
        log_relevant: log L₁, the relevant model's evidence (averaged over τ).
        log_irrelevant: log L₀, the irrelevant model's.
        solves: planner solves asked of the book (memoized ones included).
        person: the belief over the person after this correction.
    """

    relevance: float
    rho: float
    rho_belief: float
    theta: np.ndarray
    log_relevant: float
    log_irrelevant: float
    solves: int
    person: PersonBelief


def widening(jac: np.ndarray, spread: np.ndarray, size: float) -> np.ndarray:
    """σᵢ² (k,), the squared singular values of J L / s (Q = ``spread`` = L Lᵀ, s = ``size``),
    so that log det(I + t Q JᵀJ / s²) = Σ log(1 + t σᵢ²): each term >= 0 and finite however
    large J is. (The determinant of I + t Q JᵀJ / s² itself cancels to 0 for a near rank-one
    J of norm 1e10 — a secant across a jump of the planner — giving a log of −inf and a NaN
    belief: measured on run 75 of the FERL study's third column, under OpenBLAS's SkylakeX
    kernel.)"""
    sv = np.linalg.svd(jac @ np.linalg.cholesky(spread), compute_uv=False) / size
    return np.concatenate([sv**2, np.zeros(spread.shape[0] - sv.shape[0])])


def judge(
    book: PlanBook,
    env: Environment,
    robot: np.ndarray,
    corrected: np.ndarray,
    model: CorrectionModel,
    belief_mean: np.ndarray,
    belief_cov: np.ndarray,
    starts: np.ndarray,
    *,
    person: PersonBelief,
    scatter: list[tuple[float, np.ndarray]],
    scatter_center: np.ndarray,
    irrelevant: tuple[float, float] | None = None,
    space: str = "joint",
    iterations: int = 12,
    belief_iterations: int = 6,
    radius: float = 0.5,
) -> Judgement:
    """β̂ of a correction under the belief N(``belief_mean``, ``belief_cov``) over θ and the
    belief over the ``person`` (their rate r of relevant corrections and the precision τ of
    those, :class:`~corrections_sim.learning.relevance.state.PersonBelief`), and that belief
    after it.

    What a correction shows: ρ*, the least unexplained fraction of the move over θ (ρ(θ) =
    ‖ξ_h − ĉ(θ)‖ / ‖ξ_h − ξ‖ in ``space``), and *where* it is explained. Both hypotheses give
    a density to both:

    * relevant: ρ* ~ half-normal with precision τ (f₁), and the explanation lies where the
      belief over θ says the person's θ is;
    * irrelevant: ρ* ~ f₀ (the random direction's Beta((7 − k)/2, k/2), or a fitted Beta(a, b)
      of ρ*², ``irrelevant``), and the explanation lies where explanations of irrelevant
      corrections scatter around ``scatter_center`` (the robot's θ̂, whose plan the correction
      moves): a mixture Σ w_c N(θ̂, W_c), ``scatter`` = [(w_c, W_c), …] (fitted: a core about as
      wide as people's preferences and a far tail).

    Where: for a centre c and covariance Q, Λ(Q) = E_{θ ~ N(c, Q)}[exp(−τ₀ (ρ(θ)² − ρ*²) / 2)],
    by Laplace's method around θ_Q = argmin τ₀ ρ(θ)² + (θ − c)ᵀ Q⁻¹ (θ − c) with the secant
    Jacobian J of ĉ: exp(−(τ₀ (ρ(θ_Q)² − ρ*²) + |θ_Q − c|²_Q) / 2) / √det(I + τ₀ Q JᵀJ / ‖ξ_h −
    ξ‖²), at the prior mean precision τ₀ (in directions J does not see, the factors of the
    two hypotheses share it and it cancels). So L₁(τ) = f₁(ρ*; τ) Λ(P) and L₀ = f₀(ρ*) Σ w_c
    Λ(W_c): a correction explained only by θ's the belief rules out (and the scatter of
    irrelevant explanations does not) is doubted however small ρ* is, and one explained where
    the belief expects counts. The person's belief over (τ, r) is updated exactly with L₁(τ)
    at each of its τ nodes and L₀: β̂ = E[r L₁(τ)] / E[r L₁(τ) + (1 − r) L₀]; a nudge is
    explained by the irrelevant branch and leaves a precise person's precision alone.

    The first search (``iterations`` steps, as :func:`explain`) finds ρ*; the search under the
    belief (``belief_iterations`` more) and under each W_c (half as many) continue from every
    plan solved.
    """
    mean = np.asarray(belief_mean, float)
    cov = np.asarray(belief_cov, float)
    k = mean.shape[0]
    found, search = _explain(book, env, robot, corrected, model, starts, iterations, radius, space)
    a, b = irrelevant or random_direction_shape(NUDGE_DIMENSIONS, k)
    if search.size == 0.0 or not search.costs:  # nothing moved: no evidence either way
        log_f0 = math.log(max(beta_rho_density(found.rho, a, b), 1e-300))
        return Judgement(
            person.rate_mean,
            found.rho,
            found.rho,
            found.theta,
            math.nan,
            log_f0,
            search.solves,
            person,
        )
    taus = person.taus
    tau = person.prior_precision
    places = []
    center_w = np.asarray(scatter_center, float)
    steps = [belief_iterations] + [belief_iterations // 2] * len(scatter)
    regions = [(mean, cov)] + [(center_w, np.asarray(w, float)) for _, w in scatter]
    for (center, spread), count in zip(regions, steps, strict=True):
        root_inv = np.linalg.inv(np.linalg.cholesky(spread))

        def objective(i: int, center=center, root_inv=root_inv) -> float:
            d = root_inv @ (search.thetas[i] - center)
            return tau * (search.costs[i] / search.size) ** 2 + float(d @ d)

        best = search.minimize(objective, count, radius, prior=(center, root_inv, tau))
        jac = search.jacobian(best, radius)
        if jac is None:
            jac = np.zeros((search.target.shape[0], k))
        d = root_inv @ (search.thetas[best] - center)
        sv2 = widening(jac, spread, search.size)
        places.append((best, search.costs[best] / search.size, float(d @ d), sv2))
    rho_star = min(min(search.costs) / search.size, 1.0)

    def log_place(t: float, place) -> float:
        _, rho_q, d2, sv2 = place
        return -0.5 * (t * (rho_q**2 - rho_star**2) + d2) - 0.5 * float(np.sum(np.log1p(t * sv2)))

    def log_mean(values, weights=None) -> float:
        """log of the (weighted) mean of exp(values)."""
        values = np.array(values)
        top = float(np.max(values))
        return top + math.log(float(np.average(np.exp(values - top), weights=weights)))

    weights = np.array([w for w, _ in scatter], float)
    log_relevant = (
        0.5 * np.log(2.0 * taus / math.pi) - 0.5 * taus * rho_star**2 + log_place(tau, places[0])
    )
    log_irrelevant = np.full(
        taus.shape,
        math.log(max(beta_rho_density(rho_star, a, b), 1e-300))
        + log_mean([log_place(tau, place) for place in places[1:]], weights),
    )
    beta, after = person.update(log_relevant, log_irrelevant)
    beta = max(beta, MIN_RELEVANCE)
    tau_w = person.tau_weights
    best, rho_b = places[0][0], places[0][1]
    return Judgement(
        relevance=beta,
        rho=rho_star,
        rho_belief=min(rho_b, 1.0),
        theta=search.thetas[best],
        log_relevant=log_mean(log_relevant, tau_w),
        log_irrelevant=log_mean(log_irrelevant, tau_w),
        solves=search.solves,
        person=after,
    )


@dataclass(frozen=True)
class Relevance:
    """From ρ to β̂ = P(relevant | ρ).

    Attributes:
        prior: p, the prior probability that a correction is relevant, in (0, 1).
        spread: σ of the half-normal ρ of a relevant correction (> 0): how much of a relevant
            correction the robot's model may leave unexplained.
        k: the dimension of θ (of the family of plans).
        dimensions: n, joint-space directions of an irrelevant move (the arm's 7).
    """

    prior: float = 0.5
    spread: float = 0.05
    k: int = 2
    dimensions: int = NUDGE_DIMENSIONS

    def __post_init__(self) -> None:
        require_fraction("relevance_prior", self.prior)
        ok = isinstance(self.spread, int | float) and not isinstance(self.spread, bool)
        if not (ok and math.isfinite(self.spread) and self.spread > 0):
            raise ParameterError("relevance_spread", f"must be finite and > 0, got {self.spread!r}")

    def relevant_density(self, rho: float) -> float:
        """f₁(ρ): half-normal with scale ``spread``."""
        s = self.spread
        return math.sqrt(2.0 / math.pi) / s * math.exp(-0.5 * (rho / s) ** 2)

    def irrelevant_density(self, rho: float) -> float:
        """f₀(ρ) = 2ρ · Beta(ρ²; (n − k)/2, k/2): the unexplained fraction of a random
        direction in n dimensions against a flat k-dimensional family."""
        return beta_rho_density(rho, *random_direction_shape(self.dimensions, self.k))

    def probability(self, rho: float) -> float:
        """β̂ = p f₁ / (p f₁ + (1 − p) f₀), at least :data:`MIN_RELEVANCE`."""
        relevant = self.prior * self.relevant_density(rho)
        other = (1.0 - self.prior) * self.irrelevant_density(rho)
        total = relevant + other
        beta = relevant / total if total > 0 else self.prior
        return max(beta, MIN_RELEVANCE)


#: The fit the learners use when a study names none: fitted by
#: ``python -m corrections_sim.run relevance-fit`` to labelled corrections, shipped with
#: the presets.
DEFAULT_FIT = "relevance_fit.json"


@dataclass(frozen=True)
class SpaceFit:
    """The fitted densities of ρ* in one space.

    Attributes:
        irrelevant: (a, b) with ρ*² ~ Beta(a, b) for an irrelevant correction.
        precision: (shape, rate) of the Gamma over people's precision τ of a relevant ρ*
            (each person's ρ* half-normal with their own τ).
        scatter: where the best explanations θ_e of irrelevant corrections lie around the
            robot's θ̂: a mixture of isotropic Gaussians, ((weight, standard deviation per
            feature weight), …), weights summing to 1.
        relevant_count, irrelevant_count: how many labelled corrections each was fitted to.
    """

    irrelevant: tuple[float, float]
    precision: tuple[float, float]
    scatter: tuple[tuple[float, float], ...]
    relevant_count: int
    irrelevant_count: int

    @property
    def spread(self) -> float:
        """σ̂ = E[τ]^(−1/2) under the prior on the precision."""
        shape, rate = self.precision
        return math.sqrt(rate / shape)


def load_fit(path: str | None = None) -> dict[str, SpaceFit]:
    """The fit in the JSON file ``path`` (None or "": the shipped :data:`DEFAULT_FIT`), per
    space.

    Raises:
        ValueError: a missing or unreadable file, malformed JSON, an unknown space, or a
            value out of range, in one line naming the file and the key.
    """
    import json
    from importlib import resources
    from pathlib import Path

    if path:
        where = str(path)
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise ValueError(f"fit {where}: cannot read it ({exc.strerror or exc})") from None
    else:
        where = f"corrections_sim.experiments/{DEFAULT_FIT}"
        try:
            text = resources.files("corrections_sim.experiments").joinpath(DEFAULT_FIT).read_text()
        except OSError as exc:
            raise ValueError(f"fit {where}: cannot read it ({exc.strerror or exc})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"fit {where}: not JSON ({exc.msg}, line {exc.lineno})") from None
    spaces = data.get("spaces") if isinstance(data, dict) else None
    if not isinstance(spaces, dict) or not spaces:
        raise ValueError(f"fit {where}: expected an object with 'spaces'")
    out = {}
    for space, entry in spaces.items():
        key = f"fit {where}: spaces.{space}"
        if space not in SPACES:
            raise ValueError(f"{key}: unknown space (known: {', '.join(SPACES)})")
        if not isinstance(entry, dict):
            raise ValueError(f"{key}: expected an object")
        try:
            a, b = (float(v) for v in entry["irrelevant"])
            shape, rate = (float(v) for v in entry["precision"])
            scatter = tuple((float(w), float(sd)) for w, sd in entry["scatter"])
            counts = int(entry["relevant_count"]), int(entry["irrelevant_count"])
        except KeyError as exc:
            raise ValueError(f"{key}: missing {exc.args[0]!r}") from None
        except (TypeError, ValueError):
            raise ValueError(
                f"{key}: expected irrelevant = [a, b], precision = [shape, rate], "
                "scatter = [[weight, sd], …] and counts as numbers"
            ) from None
        if not (math.isfinite(a) and math.isfinite(b) and a > 0 and b > 0):
            raise ValueError(f"{key}.irrelevant: Beta shapes must be finite and > 0, got {a}, {b}")
        if not (math.isfinite(shape) and math.isfinite(rate) and shape > 0 and rate > 0):
            raise ValueError(
                f"{key}.precision: Gamma shape and rate must be finite and > 0, got {shape}, {rate}"
            )
        ok = scatter and all(
            math.isfinite(w) and math.isfinite(sd) and w > 0 and sd > 0 for w, sd in scatter
        )
        if not ok or abs(sum(w for w, _ in scatter) - 1.0) > 1e-6:
            raise ValueError(
                f"{key}.scatter: expected [[weight, sd], …] with weights > 0 summing to 1 and "
                f"sd > 0, got {entry['scatter']}"
            )
        out[space] = SpaceFit((a, b), (shape, rate), scatter, *counts)
    return out
