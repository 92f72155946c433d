"""EX-M: the exact posterior over θ, the person's noise N *and how they correct*.

EX-C and EX-CL hold one correction model C (the paper's worst waypoint, moved all the way)
and are exact under it; a person who corrects otherwise (half way, several waypoints, a
smooth deformation, or by showing their own optimum with noise: fig. 6's people) is then
explained by a wrong θ. EX-M holds a set of models C₁…C_M with a prior π over them, the
person's model fixed across their corrections, and computes

    p(θ, m | z₁…zₜ) ∝ π_m p(θ) Πᵢ p(zᵢ | θ, C_m),

each p(θ | z, C_m) exactly as EX-CL does (N integrated out, or fixed with ``noise =
"fixed"``: EX-C), on the same atlas and its refined cells (each model's cells refined where
its own posterior lives). How noisy the person is, is theirs too: N's prior is a mixture of
KF-CL's inverse-Wishart at several scales (:class:`ScaledNoiseExact`), so a person who
corrects without noise is not held to the study's N. The posterior over models is their
evidences,

    p(m | z₁…zₜ) ∝ π_m Z_m,   Z_m = ∫ p(θ) Πᵢ p(zᵢ | θ, C_m) dθ,

each Z_m the trapezoid rule's integral of that model's unnormalized posterior over its cells:
every model's density is written with the same constants (the prior's, N's or the
inverse-Wishart marginal's, which do not depend on C), so the Z_m compare as they are. The
belief's θ̂ and P are the mixture's moments; its columns add p(m | z) per model.

With one model, EX-M is EX-CL (EX-C) to the bit (tested). With ``relevance = true`` each part
also judges, exactly, which of the person's corrections were about what the robot can
represent (:mod:`.relevance`; N then among point masses); an option, not the default.
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
from corrections_sim.learning.exact.learners import (
    ExactCorrectionAware,
    ExactStep,
    iw_log_term,
    scatter_logdets,
)
from corrections_sim.learning.exact.relevance import DEFAULT_CONCENTRATIONS, RelevantExact
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


#: The scales c of N's prior EX-M mixes by default (``noise_scales``): IW(ν₀, c V₀), its
#: estimate c N from 1/16 to 4 times the study's N (factors of 4, each 1/4 of the prior).
#: Chosen on fig. 6's people at θ* drawn from the prior (docs/person-models.md): against
#: KF-CL's prior alone (c = 1) it learns a noiseless person several times better; reaching
#: down to 1/256 learns them better still but leaves the posterior narrower than the atlas's
#: finest cells resolve (mean NEES in the tens to thousands).
DEFAULT_NOISE_SCALES: tuple[float, ...] = tuple(4.0**j for j in range(-2, 2))
#: With relevance judged (:mod:`.relevance`), N is one of these point masses s N̄ instead:
#: 1/1024 to 4 at factors of 4 (a point mass at 1/16 cannot fit a noiseless person, as the
#: inverse-Wishart at that scale can: measured, docs/person-models.md).
DEFAULT_POINT_SCALES: tuple[float, ...] = tuple(4.0**j for j in range(-5, 2))


@dataclass(frozen=True)
class ScaledNoiseExact(ExactCorrectionAware):
    """EX-CL with N integrated out under a mixture of inverse-Wisharts that differ in scale,
    p(N) = Σ_c π_c IW(N; ν₀, c V₀), π uniform over ``noise_scales``: how noisy the person is
    left to their corrections, from near noiseless (a deterministic person, whose
    corrections EX-CL's one prior, centred on the study's N, cannot tell apart below that
    noise) to four times the study's. Exact at every node, with no plan or kinematics beyond
    EX-CL's: the marginal over c needs only the scatter Σ r rᵀ each node keeps,

        p(r₁…rₜ | θ) ∝ Σ_c π_c c^(kν₀/2) |c V₀ + Σ r rᵀ|^(−(ν₀+t)/2)

    (the IW marginal's other constants are the same for every c). EX-M's part.

    Attributes:
        noise_scales: the scales c (> 0, distinct).
    """

    noise_scales: tuple[float, ...] = (1.0,)

    def _log_marginals(self, grid, prior) -> np.ndarray:
        """log π_c p(r₁…rₜ | θ, c) at every node and scale (n, C), up to the shared constants;
        kept with the grid (:meth:`GridPosterior.memo`)."""
        scales = self.noise_scales

        def make() -> np.ndarray:
            logdets = scatter_logdets(grid, prior, scales)
            terms = [iw_log_term(grid, prior, c, logdets[:, j]) for j, c in enumerate(scales)]
            return np.stack(terms, axis=1) - np.log(len(scales))

        return grid.memo(("log_marginals", scales, prior.scale.tobytes(), prior.dof), make)

    def _noise_log_marginal(self, grid, prior) -> np.ndarray:
        key = ("noise_log_marginal", self.noise_scales, prior.scale.tobytes(), prior.dof)
        return grid.memo(key, lambda: logsumexp(self._log_marginals(grid, prior), axis=1))

    def _noise_means(self, grid, prior) -> np.ndarray:
        """E[N | θ, corrections] = Σ_c p(c | θ, corrections) (c V₀ + Σ r rᵀ) / (ν₀ + t − k − 1)."""
        k = grid.thetas.shape[1]
        log_m = self._log_marginals(grid, prior)
        p = np.exp(log_m - logsumexp(log_m, axis=1, keepdims=True))
        scales = np.asarray(self.noise_scales, float)
        spread = np.einsum("nc,c->n", p, scales)[:, None, None] * prior.scale[None] + grid.scatter
        return spread / (prior.dof + grid.count - k - 1)


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
        noise_scales: with N learnt, the scales c of that prior it mixes
            (:class:`ScaledNoiseExact`; None: :data:`DEFAULT_NOISE_SCALES`; ``[1]``: KF-CL's
            prior alone, EX-CL's numbers to the bit); with ``relevance``, the point masses
            s of N = s N̄ (None: :data:`DEFAULT_POINT_SCALES`).
        relevance: judge whether each correction is about what the robot can represent,
            across the person's corrections, exactly
            (:class:`~corrections_sim.learning.exact.relevance.RelevantExact`).
        concentrations: with ``relevance``, the concentrations κ of a relevant move's
            direction about the predicted one (None:
            :data:`~corrections_sim.learning.exact.relevance.DEFAULT_CONCENTRATIONS`;
            ``[0]``: the direction not read, relevance judged from the features alone).
        relevance_prior, relevance_count: with ``relevance``, the prior over the person's
            rate r of relevant corrections: Beta(prior · count, (1 − prior) · count).
        resolution, cut, max_level, axes: how every model's cells are refined, as EX-C's.
        spread: what every model's P is, as EX-C's ("nodes" or "cells"); the mixture's P
            is theirs mixed.
    """

    label = "Exact posterior over θ, N and how the person corrects (EX-M)"
    # Its question is EX-M's (:class:`~corrections_sim.learning.relevance.asking.AskingPersonModel`,
    # registered as EX-M: this posterior that may also ask for feature traces).
    style = ("#000000", "-")  # black and solid, as no other learner (it was drawn as AL)
    needs_atlas = True  # its grids are the study's plan atlas

    models: tuple[CorrectionModel, ...] = components.nested_many(CORRECTIONS, DEFAULT_MODELS)
    noise: str = "learnt"
    noise_dof: float | None = None
    noise_scales: tuple[float, ...] | None = None
    relevance: bool = False
    concentrations: tuple[float, ...] | None = None
    relevance_prior: float = 0.9
    relevance_count: float = 2.0
    resolution: float = 1.0
    cut: float = 9.2
    max_level: int = 4
    axes: str = "all"
    spread: str = "nodes"

    def __post_init__(self) -> None:
        if not isinstance(self.models, tuple) or not self.models:
            raise ParameterError("models", f"must be a non-empty list, got {self.models!r}")
        for i, model in enumerate(self.models):
            if not isinstance(model, CorrectionModel):
                raise ParameterError(f"models[{i}]", f"expected a correction model, got {model!r}")
        tags = [model_tag(m) for m in self.models]
        if len(set(tags)) != len(tags):
            raise ParameterError("models", f"lists a model twice: {', '.join(tags)}")
        if self.noise_scales is not None:
            if self.noise != "learnt":
                raise ParameterError("noise_scales", 'only with noise = "learnt"')
            object.__setattr__(self, "noise_scales", _numbers("noise_scales", self.noise_scales))
        if not isinstance(self.relevance, bool):
            raise ParameterError("relevance", f"must be true or false, got {self.relevance!r}")
        if self.concentrations is not None:
            kappas = _numbers("concentrations", self.concentrations, zero=True)
            object.__setattr__(self, "concentrations", kappas)
        base = components.defaults(type(self))
        for name in ("concentrations", "relevance_prior", "relevance_count"):
            if not self.relevance and getattr(self, name) != base[name]:
                raise ParameterError(name, "only with relevance = true")
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
            "spread": self.spread,
        }
        if self.relevance:
            scales = DEFAULT_POINT_SCALES if self.noise_scales is None else self.noise_scales
            kappas = DEFAULT_CONCENTRATIONS if self.concentrations is None else self.concentrations
            judged = {
                "noise_scales": scales,
                "concentrations": kappas,
                "relevance_prior": self.relevance_prior,
                "relevance_count": self.relevance_count,
            }
            return tuple(RelevantExact(model=m, **judged, **shared) for m in self.models)
        if self.noise != "learnt":
            return tuple(ExactCorrectionAware(model=m, **shared) for m in self.models)
        scales = DEFAULT_NOISE_SCALES if self.noise_scales is None else self.noise_scales
        return tuple(ScaledNoiseExact(model=m, noise_scales=scales, **shared) for m in self.models)

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
        parts = self.parts()
        steps = [
            part.update(ctx, prior, env, plan, phi_h)
            for part, prior in zip(parts, state.parts, strict=True)
        ]
        log_z = np.array([_log_evidence(p, s.belief) for p, s in zip(parts, steps, strict=True)])
        log_w = np.log(1.0 / len(steps)) + log_z
        log_w = log_w - logsumexp(log_w)
        weights = np.exp(log_w)
        mean, cov = _mixture(
            [s.belief.theta for s in steps], [s.belief.cov for s in steps], weights
        )
        predicted = _predictive(steps, before)
        kept = MixtureState(state.tags, tuple(s.belief for s in steps), log_w)
        new = Belief(theta=mean, cov=floored(cov), state=kept)
        judged = [s.relevance for s in steps]
        relevance = None if None in judged else float(weights @ np.array(judged))
        return ExactStep(
            new,
            None,
            steps[0].innovation,
            predicted[1],
            relevance=relevance,
            expected=predicted[0],
        )


def _numbers(name: str, values, *, zero: bool = False) -> tuple[float, ...]:
    """A non-empty list of distinct finite numbers > 0 (≥ 0 with ``zero``), as floats;
    anything else refused in one line naming ``name`` (and the item)."""
    if isinstance(values, str) or not isinstance(values, list | tuple) or not values:
        raise ParameterError(name, f"expected a non-empty list, got {values!r}")
    for i, c in enumerate(values):
        number = isinstance(c, int | float) and not isinstance(c, bool)
        if not (number and (c >= 0 if zero else c > 0) and c < np.inf):
            bound = ">= 0" if zero else "> 0"
            raise ParameterError(f"{name}[{i}]", f"must be a number {bound}, got {c!r}")
    if len(set(values)) != len(values):
        raise ParameterError(name, f"lists a value twice: {list(values)}")
    return tuple(float(c) for c in values)


def _log_evidence(part: ExactCorrectionAware, belief: Belief) -> float:
    """log Z of an exact part's posterior: the trapezoid rule's integral of its unnormalized
    density over its cells (the constants every model shares left out)."""
    state = ExactState.of(belief)
    grid = state.grid
    log_post = part.state_log_posterior(state)
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
