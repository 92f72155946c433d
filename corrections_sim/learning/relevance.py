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
study setting). How the learners use it (:mod:`corrections_sim.learning.paper`): a Kalman
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
from corrections_sim.people.corrections import CorrectionModel
from corrections_sim.planning.planner import PlanningError
from corrections_sim.planning.plans import PlanBook
from corrections_sim.scene.environments import Environment

#: Joint-space directions a nudge can take at one waypoint (the arm's joints).
NUDGE_DIMENSIONS = 7
#: Smallest β̂ handed to a learner: N / β̂ stays finite.
MIN_RELEVANCE = 1e-6
#: A waypoint counts as moved when it moved more than this (rad).
MOVED = 1e-9


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
) -> Explanation:
    """ρ and the θ of the best explanation of ``corrected`` (T, 7) of ``robot`` (T, 7).

    Args:
        book: the run's plans (ξ*(θ, E) memoized; the starts' plans are usually there).
        model: C, the correction model the explanation assumes.
        starts: θ's to start from (m, k), the belief's mean and sigma points; the best one
            starts the search.
        iterations: trust-region Gauss–Newton steps after the starts (one solve each).
        radius: initial trust radius in θ units.
    """
    robot = np.asarray(robot, float)
    corrected = np.asarray(corrected, float)
    move = corrected - robot
    rows = np.linalg.norm(move, axis=1) > MOVED
    size = float(np.linalg.norm(move[rows]))
    starts = np.atleast_2d(np.asarray(starts, float))
    if size == 0.0:
        return Explanation(rho=0.0, theta=starts[0].copy(), solves=0)
    target = corrected[rows].ravel()

    thetas: list[np.ndarray] = []
    predictions: list[np.ndarray] = []
    costs: list[float] = []

    def visit(theta: np.ndarray) -> float:
        try:
            plan = book.plan(theta, env)
        except PlanningError:
            return math.inf
        predicted = model.at(robot, plan.trajectory, rows).ravel()
        thetas.append(np.array(theta, float))
        predictions.append(predicted)
        costs.append(float(np.linalg.norm(target - predicted)))
        return costs[-1]

    for theta in starts:
        visit(theta)
    evaluated = len(starts)
    if not costs:
        return Explanation(rho=1.0, theta=starts[0].copy(), solves=evaluated)
    for _ in range(iterations):
        best = int(np.argmin(costs))
        step = _secant_step(thetas, predictions, best, target, radius)
        if step is None:
            break
        before = costs[best]
        evaluated += 1
        if visit(thetas[best] + step) < before:
            radius *= 2.0
        else:
            radius *= 0.5
    best = int(np.argmin(costs))
    return Explanation(rho=min(costs[best] / size, 1.0), theta=thetas[best], solves=evaluated)


def _secant_step(thetas, predictions, best, target, radius) -> np.ndarray | None:
    """A Gauss–Newton step from ``thetas[best]`` with a Jacobian fitted to every point seen
    (weighted toward the best), bounded by ``radius``; None when no step is left."""
    points = np.array(thetas)
    values = np.array(predictions)
    k = points.shape[1]
    if points.shape[0] < k + 1:
        return None
    offsets = points - points[best]
    scale = max(radius, 1e-3)
    weights = np.exp(-0.5 * np.sum(offsets**2, axis=1) / (2.0 * scale) ** 2)
    design = np.hstack([np.ones((points.shape[0], 1)), offsets]) * weights[:, None]
    fit, *_ = np.linalg.lstsq(design, values * weights[:, None], rcond=None)
    jac = fit[1:].T  # (m, k)
    residual = target - values[best]
    step, *_ = np.linalg.lstsq(jac, residual, rcond=None)
    norm = float(np.linalg.norm(step))
    if not np.all(np.isfinite(step)) or norm < 1e-6:
        return None
    return step * min(1.0, radius / norm)


def _check_fraction(name: str, value) -> float:
    number = isinstance(value, int | float) and not isinstance(value, bool)
    if not (number and math.isfinite(value) and 0.0 < value < 1.0):
        raise ParameterError(name, f"must lie in (0, 1), got {value!r}")
    return float(value)


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
        _check_fraction("relevance_prior", self.prior)
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
        a = 0.5 * max(self.dimensions - self.k, 1)
        b = 0.5 * max(self.k, 1)
        x = min(max(rho * rho, 1e-300), 1.0 - 1e-12)
        log_beta = math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b)
        log_pdf = (a - 1.0) * math.log(x) + (b - 1.0) * math.log1p(-x) - log_beta
        return 2.0 * max(rho, 1e-300) * math.exp(log_pdf)

    def probability(self, rho: float) -> float:
        """β̂ = p f₁ / (p f₁ + (1 − p) f₀), at least :data:`MIN_RELEVANCE`."""
        relevant = self.prior * self.relevant_density(rho)
        other = (1.0 - self.prior) * self.irrelevant_density(rho)
        total = relevant + other
        beta = relevant / total if total > 0 else self.prior
        return max(beta, MIN_RELEVANCE)
