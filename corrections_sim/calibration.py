"""Is the robot's uncertainty right? Calibration statistics of a Gaussian belief N(θ̂, P).

* NEES (normalized estimation error squared) = (θ̂ − θ*)ᵀ P⁻¹ (θ̂ − θ*). If P is the
  covariance of the error, NEES ~ χ²_k: its mean over runs should be k.
* NIS (normalized innovation squared) = νᵀ S⁻¹ ν, ν the innovation and S the covariance the
  filter predicted for it; also χ²_k if the observation model is right. It needs no θ*, so a
  deployed robot could check it.
* Coverage: the fraction of runs whose θ* lies inside the belief's credible ellipse of
  probability p, i.e. NEES ≤ χ²_k⁻¹(p); calibrated means coverage ≈ p. The "1σ" and "2σ"
  ellipses are those of probability 68.27% and 95.45% (for k = 1 they are ±1σ and ±2σ).
* The band for a mean NEES over N independent runs: N·mean ~ χ²_{Nk}, so the mean lies in
  [χ²_{Nk}(0.025)/N, χ²_{Nk}(0.975)/N] with probability 95% when P is calibrated.

Pure numpy/scipy; plain values in and out.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

#: Probabilities of the "1σ" and "2σ" credible ellipses (those of a normal's ±1σ, ±2σ).
ONE_SIGMA = float(stats.norm.cdf(1.0) - stats.norm.cdf(-1.0))
TWO_SIGMA = float(stats.norm.cdf(2.0) - stats.norm.cdf(-2.0))


def normalized_squared(error: np.ndarray, cov: np.ndarray) -> float:
    """eᵀ C⁻¹ e for an error e (k,) and a symmetric positive definite C (k, k)."""
    error = np.asarray(error, dtype=float)
    cov = np.asarray(cov, dtype=float)
    if cov.shape != (error.size, error.size):
        raise ValueError(f"cov: expected shape ({error.size}, {error.size}), got {cov.shape}")
    factor = np.linalg.cholesky(cov)
    z = np.linalg.solve(factor, error)
    return float(z @ z)


def nees(theta_hat: np.ndarray, cov: np.ndarray, theta_star: np.ndarray) -> float:
    """(θ̂ − θ*)ᵀ P⁻¹ (θ̂ − θ*)."""
    return normalized_squared(np.asarray(theta_hat, float) - np.asarray(theta_star, float), cov)


def nis(innovation: np.ndarray, innovation_cov: np.ndarray) -> float:
    """νᵀ S⁻¹ ν."""
    return normalized_squared(innovation, innovation_cov)


def credible_radius(k: int, probability: float) -> float:
    """χ²_k⁻¹(p): the NEES below which θ* lies in the belief's credible ellipse of prob. p."""
    return float(stats.chi2.ppf(probability, k))


def mean_band(k: int, runs: int, confidence: float = 0.95) -> tuple[float, float]:
    """Two-sided ``confidence`` interval of the mean of ``runs`` independent χ²_k values."""
    if runs < 1 or k < 1:
        raise ValueError(f"runs = {runs} and k = {k} must be >= 1")
    tail = (1.0 - confidence) / 2.0
    dof = runs * k
    return (
        float(stats.chi2.ppf(tail, dof) / runs),
        float(stats.chi2.ppf(1.0 - tail, dof) / runs),
    )


def wilson(hits: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson interval of a share ``hits`` / ``n`` (n ≥ 1; z = 1.96: 95%): the coverage of
    a credible region over runs, a power over studies. It holds the share and stays in
    [0, 1] (at a share of 0 or 1 rounding put an end a hair past either: 1 − 1e-16 at 1)."""
    p = hits / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return float(min(max(centre - half, 0.0), p)), float(max(min(centre + half, 1.0), p))


def summarize(values: np.ndarray, k: int) -> dict:
    """Calibration of one learner from its NEES, shape (runs, iterations + 1).

    Iteration 0 is the prior (given, not learned), so the fraction inside the band and the
    coverage averages are over iterations 1 … T. NaN entries (no belief) are ignored.

    Returns:
        ``mean_nees`` per iteration, the 95% ``band`` for that many runs, ``inside_band``
        (fraction of iterations 1 … T whose mean lies in the band), ``coverage_1sigma`` and
        ``coverage_2sigma`` per iteration and their averages over iterations 1 … T.
    """
    values = np.asarray(values, dtype=float)
    if values.ndim != 2 or values.shape[1] < 2:
        raise ValueError(f"values: expected NEES of shape (runs, T + 1), got {values.shape}")
    finite = np.isfinite(values)
    runs = int(finite[:, 0].sum())
    if runs == 0:
        raise ValueError("values: no finite NEES")
    mean = np.nanmean(values, axis=0)
    low, high = mean_band(k, runs)
    inside = (mean[1:] >= low) & (mean[1:] <= high)
    cover = {}
    for name, p in (("coverage_1sigma", ONE_SIGMA), ("coverage_2sigma", TWO_SIGMA)):
        hit = np.where(finite, values <= credible_radius(k, p), np.nan)
        per_t = np.nanmean(hit, axis=0)
        cover[name] = [float(v) for v in per_t]
        cover[name + "_mean"] = float(np.mean(per_t[1:]))
    return {
        "runs": runs,
        "mean_nees": [float(v) for v in mean],
        "band": [low, high],
        "inside_band": float(np.mean(inside)),
        **cover,
        "expected_coverage": [ONE_SIGMA, TWO_SIGMA],
    }
