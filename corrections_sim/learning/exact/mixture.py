"""EX-M: the exact posterior over θ, the person's noise N *and how they correct*.

EX-C and EX-CL hold one correction model C (the paper's worst waypoint, moved all the way)
and are exact under it; a person who corrects otherwise (half way, several waypoints, a
smooth deformation, or by showing their own optimum with noise: fig. 6's people) is then
explained by a wrong θ. EX-M holds a set of models C₁…C_M with a prior π over them, the
person's model fixed across their corrections, and computes

    p(θ, m | z₁…zₜ) ∝ π_m p(θ) Πᵢ p(zᵢ | θ, C_m),

each p(θ | z, C_m) exactly as EX-CL does (N integrated out, or fixed with ``noise =
"fixed"``: EX-C), on the same atlas and its refined cells (each model's cells refined where
its own posterior lives). The posterior over models is their evidences,

    p(m | z₁…zₜ) ∝ π_m Z_m,   Z_m = ∫ p(θ) Πᵢ p(zᵢ | θ, C_m) dθ,

each Z_m the trapezoid rule's integral of that model's unnormalized posterior over its cells:
every model's density is written with the same constants (the prior's, N's or the
inverse-Wishart marginal's, which do not depend on C), so the Z_m compare as they are. The
belief's θ̂ and P are the mixture's moments; its columns add p(m | z) per model.

With one model, EX-M is EX-CL (EX-C) to the bit (tested).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from corrections_sim import components
from corrections_sim.belief import Belief, FamilyState, KalmanNoise, floored, symmetrize
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import Learner, LearnerContext, Likelihood, Step
from corrections_sim.learning.exact.learners import ExactCorrectionAware, ExactStep
from corrections_sim.learning.exact.state import ExactState
from corrections_sim.people.corrections import (
    CORRECTIONS,
    CorrectionModel,
    DeformCorrection,
    OptimalCorrection,
    WaypointCorrection,
)
from corrections_sim.planning.planner import Plan
from corrections_sim.scene.environments import Environment

#: EX-M's models by default: every registered way of correcting, whole and half way (the
#: worst waypoint; the three worst; a minimum-jerk deformation around the worst; the person's
#: own optimum, shown with noise).
DEFAULT_MODELS: tuple[CorrectionModel, ...] = (
    WaypointCorrection(),
    WaypointCorrection(step=0.5),
    WaypointCorrection(waypoints=3),
    DeformCorrection(),
    DeformCorrection(step=0.5),
    OptimalCorrection(),
)


def model_tag(model: CorrectionModel) -> str:
    """A short, column-safe name of a correction model with its parameters that differ from
    their defaults: ``waypoint``, ``waypoint_step0.5``, ``waypoint_waypoints3``."""
    name = components.name_of(CORRECTIONS, model)
    base = components.defaults(type(model))
    changed = [
        f"{key}{value:g}" if isinstance(value, float) else f"{key}{value}"
        for key, value in components.params(model).items()
        if value != base.get(key)
    ]
    return "_".join([name, *changed])


@dataclass(frozen=True, eq=False)
class MixtureState(FamilyState):
    """EX-M's own state: one exact belief per model (their :class:`ExactState`) and the
    posterior over the models.

    Attributes:
        tags: each model's :func:`model_tag` (M,), for the columns.
        parts: each model's belief, the posterior over θ given that model (M,).
        log_weights: log p(m | corrections so far) (M,), normalized.
    """

    tags: tuple[str, ...] = ()
    parts: tuple[Belief, ...] = ()
    log_weights: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        w = np.array(self.log_weights, dtype=float, copy=True)
        if not (len(self.tags) == len(self.parts) == w.shape[0]) or w.ndim != 1:
            raise ValueError(
                f"MixtureState: {len(self.tags)} tags, {len(self.parts)} parts and "
                f"{w.shape} log weights: expected one of each per model"
            )
        if w.size and not np.isclose(logsumexp(w), 0.0, atol=1e-9):
            raise ValueError("MixtureState.log_weights: not a normalized log distribution")
        w.setflags(write=False)
        object.__setattr__(self, "log_weights", w)

    def check(self, k: int) -> None:
        for part in self.parts:
            part.state.check(k)

    def weights(self) -> np.ndarray:
        """p(m | corrections so far) (M,)."""
        return np.exp(self.log_weights)

    def columns(self) -> dict[str, float]:
        out = self.parts[0].state.columns() if self.parts else {}
        return out | {
            f"model_{tag}": float(p) for tag, p in zip(self.tags, self.weights(), strict=True)
        }

    def noise_estimate(self) -> np.ndarray | None:
        return self.parts[0].state.noise_estimate() if self.parts else None

    def describe(self) -> str:
        if not self.parts:
            return ""
        best = int(np.argmax(self.log_weights))
        return (
            f"most likely you correct as '{self.tags[best]}' "
            f"(probability {self.weights()[best]:.2f})"
        )


@dataclass(frozen=True)
class ExactPersonModel(Learner):
    """The exact posterior over θ, N and the person's correction model (module docstring).

    Attributes:
        models: the correction models C₁…C_M it weighs (a list of names or tables), each
            with prior probability 1/M; :data:`DEFAULT_MODELS` by default.
        noise: "learnt" (N integrated out under KF-CL's prior, as EX-CL) or "fixed" (N the
            study's, as EX-C).
        noise_dof: that prior's degrees of freedom (None: k + 2, as KF-CL's).
        resolution, cut, max_level, axes: how every model's cells are refined, as EX-C's.
    """

    label = "Exact posterior over θ, N and how the person corrects (EX-M)"
    style = ("#d62728", "-")
    needs_atlas = True  # its grids are the study's plan atlas

    models: tuple[CorrectionModel, ...] = components.nested_many(CORRECTIONS, DEFAULT_MODELS)
    noise: str = "learnt"
    noise_dof: float | None = None
    resolution: float = 1.0
    cut: float = 9.2
    max_level: int = 4
    axes: str = "all"

    def __post_init__(self) -> None:
        if not isinstance(self.models, tuple) or not self.models:
            raise ParameterError("models", f"must be a non-empty list, got {self.models!r}")
        for i, model in enumerate(self.models):
            if not isinstance(model, CorrectionModel):
                raise ParameterError(f"models[{i}]", f"expected a correction model, got {model!r}")
        tags = [model_tag(m) for m in self.models]
        if len(set(tags)) != len(tags):
            raise ParameterError("models", f"lists a model twice: {', '.join(tags)}")
        self.parts()  # the shared settings checked where EX-C checks them

    def check(self, n_waypoints: int) -> None:
        for i, model in enumerate(self.models):
            try:
                model.check(n_waypoints)
            except ParameterError as exc:
                raise ParameterError(f"models[{i}].{exc.name}", exc.message) from None

    def parts(self) -> tuple[ExactCorrectionAware, ...]:
        """One exact learner per model (EX-CL's, or EX-C's with N fixed), with these
        settings."""
        shared = {
            "noise": self.noise,
            "noise_dof": self.noise_dof,
            "resolution": self.resolution,
            "cut": self.cut,
            "max_level": self.max_level,
            "axes": self.axes,
        }
        return tuple(ExactCorrectionAware(model=m, **shared) for m in self.models)

    def assumed_correction(self) -> CorrectionModel | None:
        """None: it holds several (:attr:`models`)."""
        return None

    def likelihood(self) -> Likelihood | None:
        """None: ``run reference`` has no mixture model; each part is EX-C's or EX-CL's and
        is checked as theirs are."""
        return None

    def initial(self, belief: Belief, noise: KalmanNoise) -> Belief:
        parts = tuple(part.initial(belief, noise) for part in self.parts())
        m = len(parts)
        state = MixtureState(
            tags=tuple(model_tag(x) for x in self.models),
            parts=parts,
            log_weights=np.full(m, -np.log(m)),
        )
        return Belief(theta=belief.theta, cov=belief.cov, state=state)

    def update(
        self, ctx: LearnerContext, belief: Belief, env: Environment, plan: Plan, phi_h: np.ndarray
    ) -> Step:
        state = belief.state
        if not isinstance(state, MixtureState):
            state = MixtureState.of(self.initial(belief, ctx.noise))
        before = state.weights()
        steps = [
            part.update(ctx, prior, env, plan, phi_h)
            for part, prior in zip(self.parts(), state.parts, strict=True)
        ]
        log_z = np.array([_log_evidence(step.belief) for step in steps])
        log_w = np.log(1.0 / len(steps)) + log_z
        log_w = log_w - logsumexp(log_w)
        weights = np.exp(log_w)
        mean, cov = _mixture(
            [s.belief.theta for s in steps], [s.belief.cov for s in steps], weights
        )
        predicted = _predictive(steps, before)
        kept = MixtureState(state.tags, tuple(s.belief for s in steps), log_w)
        new = Belief(theta=mean, cov=floored(cov), state=kept)
        return ExactStep(new, None, steps[0].innovation, predicted[1], expected=predicted[0])


def _log_evidence(belief: Belief) -> float:
    """log Z of an exact part's posterior: the trapezoid rule's integral of its unnormalized
    density over its cells (the constants every model shares left out)."""
    grid = ExactState.of(belief).grid
    log_post = ExactCorrectionAware._log_posterior(grid, ExactState.of(belief).noise)
    with np.errstate(divide="ignore"):
        return float(logsumexp(log_post + np.log(grid.cells.coefficients)))


def _mixture(means, covs, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the mixture Σ w_m N(μ_m, P_m)."""
    means = np.asarray(means, float)
    mean = weights @ means
    d = means - mean
    cov = np.einsum("m,mij->ij", weights, np.asarray(covs, float))
    return mean, symmetrize(cov + (weights[:, None] * d).T @ d)


def _predictive(steps: list[ExactStep], weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mean and covariance of the correction's features as the mixture predicted them
    before it (each part's, weighed by p(m) before the correction)."""
    means = np.array([s.expected for s in steps])
    return _mixture(means, [s.innovation_cov for s in steps], weights)
