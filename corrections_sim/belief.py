"""The robot's belief over the human's preferences θ, and the Kalman filter's noise model.

Both are frozen values validated where they are made: a covariance that is not symmetric
positive definite, a NaN or a wrong shape is refused here, with the field named, instead of
surfacing as a failed Cholesky factorization several iterations later.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

# Relative tolerance on ‖C − Cᵀ‖_max / max(1, ‖C‖_max) accepted as "symmetric"; the
# asymmetry that is accepted is rounding, and it is removed on construction.
SYMMETRY_RTOL = 1e-8


def symmetrize(matrix: np.ndarray) -> np.ndarray:
    """Return (C + Cᵀ) / 2, the nearest symmetric matrix in the Frobenius norm.

    Args:
        matrix: square array, shape (k, k).

    Returns:
        A new symmetric array, shape (k, k).
    """
    matrix = np.asarray(matrix, dtype=float)
    return 0.5 * (matrix + matrix.T)


def _as_vector(name: str, value, k: int | None = None) -> np.ndarray:
    arr = np.array(value, dtype=float, copy=True)
    if arr.ndim != 1 or arr.shape[0] == 0:
        raise ValueError(f"{name}: expected a non-empty vector of shape (k,), got {arr.shape}")
    if k is not None and arr.shape[0] != k:
        raise ValueError(f"{name}: expected shape ({k},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: all values must be finite, got {arr.tolist()}")
    return arr


def _as_symmetric(name: str, value, k: int | None = None) -> np.ndarray:
    """Copy, check square / finite / symmetric within tolerance, and symmetrize exactly."""
    arr = np.array(value, dtype=float, copy=True)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or arr.shape[0] == 0:
        raise ValueError(f"{name}: expected a square matrix of shape (k, k), got {arr.shape}")
    if k is not None and arr.shape[0] != k:
        raise ValueError(f"{name}: expected shape ({k}, {k}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: all values must be finite, got {arr.tolist()}")
    scale = max(1.0, float(np.max(np.abs(arr))))
    asym = float(np.max(np.abs(arr - arr.T)))
    if asym > SYMMETRY_RTOL * scale:
        raise ValueError(
            f"{name}: must be symmetric (|C - C^T| <= {SYMMETRY_RTOL:g} * max(1, |C|)), "
            f"largest asymmetry is {asym:.3g}"
        )
    return symmetrize(arr)


def _check_positive_definite(name: str, matrix: np.ndarray) -> None:
    try:
        np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError:
        lowest = float(np.linalg.eigvalsh(matrix)[0])
        raise ValueError(
            f"{name}: must be positive definite (Cholesky failed; smallest eigenvalue "
            f"{lowest:.3g}, allowed > 0)"
        ) from None


def _check_positive_semidefinite(name: str, matrix: np.ndarray) -> None:
    eigenvalues = np.linalg.eigvalsh(matrix)
    # Eigenvalues of an exactly PSD matrix can come out at −(rounding) × its scale.
    tolerance = 1e-12 * max(1.0, float(np.max(np.abs(eigenvalues))))
    if eigenvalues[0] < -tolerance:
        raise ValueError(
            f"{name}: must be positive semidefinite (smallest eigenvalue "
            f"{eigenvalues[0]:.3g}, allowed >= 0)"
        )


def floored(cov: np.ndarray) -> np.ndarray:
    """A weighted sample's covariance kept positive definite, as a filter's posterior is:
    symmetrized, its eigenvalues at least 1e-9 of the largest (a sample whose mass sits on
    one point or one line has none there)."""
    cov = symmetrize(cov)
    eigenvalues, vectors = np.linalg.eigh(cov)
    floor = 1e-9 * max(float(eigenvalues[-1]), 1e-12)
    if eigenvalues[0] < floor:
        cov = symmetrize((vectors * np.maximum(eigenvalues, floor)) @ vectors.T)
    return cov


def _freeze(arr: np.ndarray) -> np.ndarray:
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Particles:
    """A weighted sample of θ: the particle learner's belief, whose mean and covariance are
    the :class:`Belief`'s θ̂ and P.

    Attributes:
        thetas: the particles, shape (n, k).
        log_weights: their normalized log weights (n,) (Σ exp = 1).
        log_likelihood: each particle's log-likelihood of every correction so far (n,), up
            to one constant (what a Metropolis move compares against).
    """

    thetas: np.ndarray
    log_weights: np.ndarray
    log_likelihood: np.ndarray

    def __post_init__(self) -> None:
        thetas = np.array(self.thetas, dtype=float, copy=True)
        if thetas.ndim != 2 or thetas.shape[0] < 2 or not np.all(np.isfinite(thetas)):
            raise ValueError(f"Particles.thetas: expected finite (n >= 2, k), got {thetas.shape}")
        n = thetas.shape[0]
        log_w = np.array(self.log_weights, dtype=float, copy=True)
        log_l = np.array(self.log_likelihood, dtype=float, copy=True)
        for name, arr in (("log_weights", log_w), ("log_likelihood", log_l)):
            if arr.shape != (n,) or np.any(np.isnan(arr)):
                raise ValueError(f"Particles.{name}: expected ({n},) without NaN, got {arr.shape}")
        top = float(np.max(log_w))
        if not np.isfinite(top):
            raise ValueError("Particles.log_weights: every particle has weight zero")
        log_w = log_w - (top + np.log(np.exp(log_w - top).sum()))
        object.__setattr__(self, "thetas", _freeze(thetas))
        object.__setattr__(self, "log_weights", _freeze(log_w))
        object.__setattr__(self, "log_likelihood", _freeze(log_l))

    @property
    def count(self) -> int:
        return int(self.thetas.shape[0])

    def weights(self) -> np.ndarray:
        return np.exp(self.log_weights)

    def effective_size(self) -> float:
        """Kish's effective sample size 1 / Σ w²."""
        return float(1.0 / np.sum(self.weights() ** 2))

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """The weighted mean (k,) and covariance (k, k), the covariance kept positive
        definite (eigenvalues at least 1e-9 of the largest, as a filter's posterior)."""
        w = self.weights()
        mean = w @ self.thetas
        d = self.thetas - mean
        return mean, floored((w[:, None] * d).T @ d)


@dataclass(frozen=True, eq=False)
class GridPosterior:
    """An exact learner's posterior over θ on the nodes of a grid (its plan atlas's): the
    :class:`Belief`'s θ̂ and P are its moments.

    Attributes:
        thetas: the nodes (n, k).
        log_density: the unnormalized log posterior at each node (n,), −inf where it is
            impossible; with N learnt, the log prior only (the corrections are in
            ``scatter``).
        scatter: with N learnt, Σᵢ rᵢ rᵢᵀ at each node (n, k, k), rᵢ = zᵢ − hᵢ(θ); else None.
        count: corrections taken in.
        cells: the nodes as cells (:class:`~corrections_sim.learning.exact.cells.Cells`;
            their trapezoid weights integrate the density), or None: every node weighs the
            same.
    """

    thetas: np.ndarray
    log_density: np.ndarray
    scatter: np.ndarray | None = None
    count: int = 0
    cells: Any = None  # the exact family's Cells (learning.exact.cells; not imported here)

    def __post_init__(self) -> None:
        thetas = np.array(self.thetas, dtype=float, copy=True)
        log_d = np.array(self.log_density, dtype=float, copy=True)
        if thetas.ndim != 2 or log_d.shape != (thetas.shape[0],) or np.any(np.isnan(log_d)):
            raise ValueError(
                f"GridPosterior: expected nodes (n, k) and n log densities without NaN, got "
                f"{thetas.shape} and {log_d.shape}"
            )
        if not np.any(np.isfinite(log_d)):
            raise ValueError("GridPosterior.log_density: every node is impossible")
        object.__setattr__(self, "thetas", _freeze(thetas))
        object.__setattr__(self, "log_density", _freeze(log_d))
        if self.scatter is not None:
            scatter = np.array(self.scatter, dtype=float, copy=True)
            k = thetas.shape[1]
            if scatter.shape != (thetas.shape[0], k, k):
                raise ValueError(f"GridPosterior.scatter: expected (n, k, k), got {scatter.shape}")
            object.__setattr__(self, "scatter", _freeze(scatter))
        if self.cells is not None and len(self.cells.coords) != thetas.shape[0]:
            raise ValueError(
                f"GridPosterior.cells: {len(self.cells.coords)} nodes for {thetas.shape[0]} θ"
            )


@dataclass(frozen=True, eq=False)
class PriorEntry:
    """The first entry of a belief's history: the prior N(θ̂⁰, P⁰) the past is read from."""

    theta: np.ndarray
    cov: np.ndarray


@dataclass(frozen=True, eq=False)
class CorrectionEntry:
    """A correction as an iterated or particle learner reads it again: its environment Eᵗ,
    the robot's trajectory ξᵗ (T, 7), the features Φ_h (k,) and the observation noise N
    (k, k) it was seen under."""

    env: Any
    robot: np.ndarray
    phi_h: np.ndarray
    noise: np.ndarray


@dataclass(frozen=True, eq=False)
class ShownEntry:
    """A correction kept for feature expansion: its environment Eᵗ, the robot's trajectory
    ξᵗ and the person's ξ_h (both (T, 7)), to be read again over a learnt feature."""

    env: Any
    robot: np.ndarray
    corrected: np.ndarray


#: What a belief's history holds: a :class:`PriorEntry` first, then corrections.
HistoryEntry = PriorEntry | CorrectionEntry | ShownEntry


@dataclass(frozen=True, eq=False)
class Belief:
    """Gaussian belief θ ~ N(θ̂, P) over the human's preference weights.

    The arrays are copied, symmetrized (cov) and made read-only, so a Belief can be shared
    between records without defensive copies.

    Attributes:
        theta: mean estimate θ̂, shape (k,).
        cov: covariance P, shape (k, k), symmetric positive definite. The Preference
            Perceptron has no covariance; it carries its initial one unchanged.
        noise: the belief over the person's observation noise N, for a learner that learns
            it (:class:`NoisePosterior`); None for one that assumes N.
        person: the belief over how this person corrects (how often relevantly, how
            precisely), for a learner that judges relevance across a person's corrections
            (:class:`PersonBelief`); None otherwise.
        extra: the names of features the learner learnt beyond the study's (feature
            expansion: θ̂ and P then have ``len(extra)`` more entries, after the study's).
        asked: whether the learner has asked the person for feature traces (it asks once).
        history: what a learner that reads the past again keeps: a :class:`PriorEntry`
            first, then each correction, a :class:`ShownEntry` for feature expansion or a
            :class:`CorrectionEntry` for an iterated or particle learner.
        particles: the particle learner's weighted sample (θ̂ and P are its moments), or
            None.
        grid: the exact learner's posterior on its grid (θ̂ and P are its moments), or None.

    Raises:
        ValueError: on wrong shapes, non-finite values, or a cov that is not symmetric
            positive definite; the message names the field.
    """

    theta: np.ndarray
    cov: np.ndarray
    noise: NoisePosterior | None = None
    person: PersonBelief | None = None
    extra: tuple[str, ...] = ()
    asked: bool = False
    history: tuple[HistoryEntry, ...] = ()
    particles: Particles | None = None
    grid: GridPosterior | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "extra", tuple(self.extra))
        theta = _as_vector("Belief.theta", self.theta)
        if len(self.extra) >= theta.shape[0]:
            raise ValueError(
                f"Belief.extra: {len(self.extra)} learnt features of {theta.shape[0]} weights"
            )
        cov = _as_symmetric("Belief.cov", self.cov, theta.shape[0])
        _check_positive_definite("Belief.cov", cov)
        object.__setattr__(self, "theta", _freeze(theta))
        object.__setattr__(self, "cov", _freeze(cov))
        if self.noise is not None and self.noise.dim != theta.shape[0]:
            raise ValueError(
                f"Belief.noise: a posterior over {self.noise.dim} x {self.noise.dim} noise, "
                f"expected {theta.shape[0]} x {theta.shape[0]}"
            )
        history = tuple(self.history)
        if history and not isinstance(history[0], PriorEntry):
            raise ValueError("Belief.history: its first entry must be the PriorEntry")
        if any(not isinstance(e, CorrectionEntry | ShownEntry) for e in history[1:]):
            raise ValueError("Belief.history: after the prior, CorrectionEntry or ShownEntry only")
        object.__setattr__(self, "history", history)
        if self.particles is not None and self.particles.thetas.shape[1] != theta.shape[0]:
            raise ValueError(
                f"Belief.particles: particles over {self.particles.thetas.shape[1]} weights, "
                f"expected {theta.shape[0]}"
            )

    @property
    def dim(self) -> int:
        """Number of features k."""
        return int(self.theta.shape[0])


@dataclass(frozen=True, eq=False)
class KalmanNoise:
    """Noise covariances of the filter's dynamical system, eqs. (K1)–(K2).

    θᵗ = θᵗ⁻¹ + m,  m ~ N(0, M)         (preferences are noisily constant)
    Φ_h = Φ(ξ*(θᵗ, E), E) + n,  n ~ N(0, N)

    Attributes:
        process: M, shape (k, k), symmetric positive semidefinite (zero is allowed: the
            preferences are then exactly constant).
        observation: N, shape (k, k), symmetric positive definite (it keeps the innovation
            covariance invertible).

    Raises:
        ValueError: on wrong or mismatched shapes, non-finite values, an M that is not PSD or
            an N that is not PD; the message names the field.
    """

    process: np.ndarray
    observation: np.ndarray

    def __post_init__(self) -> None:
        process = _as_symmetric("KalmanNoise.process", self.process)
        observation = _as_symmetric("KalmanNoise.observation", self.observation, process.shape[0])
        _check_positive_semidefinite("KalmanNoise.process", process)
        _check_positive_definite("KalmanNoise.observation", observation)
        object.__setattr__(self, "process", _freeze(process))
        object.__setattr__(self, "observation", _freeze(observation))

    @classmethod
    def isotropic(cls, k: int, process: float, observation: float) -> KalmanNoise:
        """M = process · I and N = observation · I, both (k, k)."""
        eye = np.eye(k)
        return cls(process=process * eye, observation=observation * eye)

    @property
    def dim(self) -> int:
        """Number of features k."""
        return int(self.process.shape[0])

    def grown(self, dim: int) -> KalmanNoise:
        """The noise over ``dim`` >= k features: a learnt feature's share (past the k) its
        mean diagonal entry, uncorrelated (the studies' M and N are m·I and n·I)."""
        k = self.dim
        if dim == k:
            return self

        def grow(a: np.ndarray) -> np.ndarray:
            out = np.eye(dim) * float(np.mean(np.diag(a)))
            out[:k, :k] = a
            return out

        return KalmanNoise(process=grow(self.process), observation=grow(self.observation))


@dataclass(frozen=True, eq=False)
class NoisePosterior:
    """A belief over the observation noise N: inverse-Wishart IW(ν, V), density
    ∝ |N|^(−(ν + k + 1)/2) exp(−tr(V N⁻¹)/2).

    Under it E[N⁻¹] = ν V⁻¹, so the noise a variational-Bayes filter plugs into its update
    is N̂ = E[N⁻¹]⁻¹ = V / ν (:meth:`estimate`).

    Attributes:
        dof: ν > k − 1, the degrees of freedom: how many corrections' worth of evidence.
        scale: V, shape (k, k), symmetric positive definite.
    """

    dof: float
    scale: np.ndarray

    def __post_init__(self) -> None:
        scale = _as_symmetric("NoisePosterior.scale", self.scale)
        _check_positive_definite("NoisePosterior.scale", scale)
        k = scale.shape[0]
        if not (np.isfinite(self.dof) and self.dof > k - 1):
            raise ValueError(f"NoisePosterior.dof: must be finite and > {k - 1}, got {self.dof}")
        object.__setattr__(self, "dof", float(self.dof))
        object.__setattr__(self, "scale", _freeze(scale))

    @classmethod
    def around(cls, noise: np.ndarray, dof: float) -> NoisePosterior:
        """A prior whose estimate is ``noise`` (k, k), held with ``dof`` degrees of freedom."""
        return cls(dof=dof, scale=dof * np.asarray(noise, dtype=float))

    @property
    def dim(self) -> int:
        return int(self.scale.shape[0])

    def estimate(self) -> np.ndarray:
        """N̂ = V / ν, shape (k, k)."""
        return self.scale / self.dof


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
        object.__setattr__(self, "taus", _freeze(taus))
        object.__setattr__(self, "rates", _freeze(rates))
        object.__setattr__(self, "log_w", _freeze(log_w - np.max(log_w)))

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
