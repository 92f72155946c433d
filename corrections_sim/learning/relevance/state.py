"""The relevance family's part of a belief: the belief over how one person corrects
(:class:`PersonBelief`), whether the robot has asked them for feature traces, and the
corrections it would read again over a learnt feature (:class:`RelevanceState`). Plain values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corrections_sim.belief import FamilyState, frozen
from corrections_sim.learning.history import HistoryEntry, checked


def _positive_finite(name: str, value) -> float:
    ok = isinstance(value, int | float | np.number) and not isinstance(value, bool)
    if not (ok and np.isfinite(value) and value > 0):
        raise ValueError(f"{name}: must be a finite number > 0, got {value!r}")
    return float(value)


#: Grid points of a :class:`PersonBelief`: the precision τ and the rate r.
PERSON_TAU_POINTS = 32
PERSON_RATE_POINTS = 21


@dataclass(frozen=True, eq=False)
class PersonBelief:
    """A belief over how one person corrects, shared by all of their corrections, on a grid:

    * r, the fraction of their corrections that are relevant (explained by the robot's
      features), at ``rates`` (midpoints of (0, 1));
    * τ = 1/σ², the precision of the unexplained fraction ρ of a relevant correction
      (ρ ~ half-normal(σ)), at ``taus`` (equal-probability nodes of its Gamma prior, so the
      prior weighs them equally).

    ``log_w`` (taus, rates) is the unnormalized log posterior. A correction updates it
    exactly (:meth:`update`) given its likelihood under each τ when relevant and when not;
    nothing about the person is approximated but the grid.

    Attributes:
        taus: τ nodes (n_τ,), > 0.
        rates: r nodes (n_r,), in (0, 1).
        log_w: log weights (n_τ, n_r), finite where not −inf.
    """

    taus: np.ndarray
    rates: np.ndarray
    log_w: np.ndarray

    def __post_init__(self) -> None:
        taus = np.asarray(self.taus, float)
        rates = np.asarray(self.rates, float)
        log_w = np.asarray(self.log_w, float)
        if taus.ndim != 1 or not np.all(np.isfinite(taus)) or np.any(taus <= 0):
            raise ValueError("PersonBelief.taus: expected finite precisions > 0")
        if rates.ndim != 1 or np.any(rates <= 0) or np.any(rates >= 1):
            raise ValueError("PersonBelief.rates: expected rates in (0, 1)")
        if log_w.shape != (taus.size, rates.size) or not np.any(np.isfinite(log_w)):
            raise ValueError(
                f"PersonBelief.log_w: expected shape {(taus.size, rates.size)} with a finite weight"
            )
        object.__setattr__(self, "taus", frozen(taus))
        object.__setattr__(self, "rates", frozen(rates))
        object.__setattr__(self, "log_w", frozen(log_w - np.max(log_w)))

    @classmethod
    def prior(
        cls,
        shape: float,
        rate: float,
        relevant: float,
        irrelevant: float,
        *,
        tau_points: int = PERSON_TAU_POINTS,
        rate_points: int = PERSON_RATE_POINTS,
    ) -> PersonBelief:
        """τ ~ Gamma(``shape``, ``rate``), r ~ Beta(``relevant``, ``irrelevant``), on the grid:
        τ in ``tau_points`` bins of equal prior probability, r in ``rate_points`` bins of equal
        width, each node the prior's mean within its bin and weighted by the bin's prior
        probability (so the prior's means are exact)."""
        from scipy.special import betainc, gammainc, gammaincinv

        for name, value in (
            ("shape", shape),
            ("rate", rate),
            ("relevant", relevant),
            ("irrelevant", irrelevant),
        ):
            _positive_finite(f"PersonBelief.{name}", value)
        edges = gammaincinv(shape, np.arange(tau_points + 1) / tau_points)  # in units of 1/rate
        upper = gammainc(shape + 1.0, edges)
        taus = shape / rate * tau_points * np.diff(upper)
        a, b = relevant, irrelevant
        cuts = np.linspace(0.0, 1.0, rate_points + 1)
        mass = np.diff(betainc(a, b, cuts))
        first = np.diff(betainc(a + 1.0, b, cuts))
        with np.errstate(divide="ignore", invalid="ignore"):
            rates = np.where(mass > 0, a / (a + b) * first / mass, 0.5 * (cuts[1:] + cuts[:-1]))
            log_r = np.log(mass)
        rates = np.clip(rates, 1e-12, 1.0 - 1e-12)
        return cls(taus, rates, np.zeros((tau_points, 1)) + log_r[None, :])

    def _weights(self) -> np.ndarray:
        w = np.exp(self.log_w)
        return w / w.sum()

    @property
    def rate_mean(self) -> float:
        """E[r], the probability that the next correction is relevant."""
        return float(self._weights().sum(axis=0) @ self.rates)

    @property
    def tau_weights(self) -> np.ndarray:
        """The posterior over the τ nodes (n_τ,), summing to 1."""
        return self._weights().sum(axis=1)

    @property
    def prior_precision(self) -> float:
        """E[τ] before any correction (the nodes' mean: the prior weighs them equally)."""
        return float(np.mean(self.taus))

    @property
    def precision(self) -> float:
        """E[τ]."""
        return float(self.tau_weights @ self.taus)

    @property
    def spread(self) -> float:
        """σ̂ = E[τ]^(−1/2)."""
        return float(self.precision**-0.5)

    def update(
        self, log_relevant: np.ndarray, log_irrelevant: np.ndarray
    ) -> tuple[float, PersonBelief]:
        """(β̂, the belief after) for a correction whose likelihood is ``log_relevant`` (n_τ,)
        if relevant at each τ node and ``log_irrelevant`` (n_τ,) if not: β̂ = P(relevant |
        everything so far and this correction), the posterior the mixture
        r L₁(τ) + (1 − r) L₀(τ) at every node."""
        log_on = np.asarray(log_relevant, float)[:, None] + np.log(self.rates)[None, :]
        log_off = np.asarray(log_irrelevant, float)[:, None] + np.log1p(-self.rates)[None, :]
        joint_on, joint_off = self.log_w + log_on, self.log_w + log_off
        top = max(np.max(joint_on), np.max(joint_off))
        on, off = np.exp(joint_on - top).sum(), np.exp(joint_off - top).sum()
        after = PersonBelief(self.taus, self.rates, np.logaddexp(joint_on, joint_off))
        return float(on / (on + off)), after


@dataclass(frozen=True, eq=False)
class RelevanceState(FamilyState):
    """KF-CRP's and KF-CRX's own state: the belief over the person (None once a feature is
    learnt: the person's corrections are then taken as relevant), whether it has asked for
    feature traces (it asks once), the prior with the corrections shown so far (what a
    learnt feature reads again), and, once a feature is learnt, the share of the study's
    observation noise its values are given (fitted from the corrections read again:
    :meth:`~corrections_sim.belief.KalmanNoise.grown`)."""

    person: PersonBelief | None = None
    asked: bool = False
    history: tuple[HistoryEntry, ...] = ()
    learnt_noise: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "history", checked(self.history, "RelevanceState.history"))
        _positive_finite("RelevanceState.learnt_noise", self.learnt_noise)

    def learnt_share(self) -> float:
        return self.learnt_noise

    def columns(self) -> dict[str, float]:
        """E[r] and σ̂ (``relevance_rate``, ``relevance_spread``) while it judges the person."""
        if self.person is None:
            return {}
        return {"relevance_rate": self.person.rate_mean, "relevance_spread": self.person.spread}

    def describe(self) -> str:
        if self.person is None:
            return ""
        return (
            f"The person's corrections so far: relevant at rate E[r] = "
            f"**{self.person.rate_mean:.2f}**; a relevant one scattered by σ̂ = "
            f"**{self.person.spread:.2f}** (feature units)."
        )
