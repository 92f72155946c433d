"""Metrics of a learner's estimate: estimate error and regret (paper §6).

Regret compares, in each environment E, the user's optimal trajectory ξ* = ξ*(θ*, E) with the
robot's ξ = ξ*(θ̂, E), and is summed over all environments:

* ``regret`` (headline): the planner's full objective under θ*,
  R*(ξ) = θ*·Φ(ξ, E) − λ·S(ξ), so regret = R*(ξ*) − R*(ξ) ≥ 0 up to local optima;
* ``regret_paper``: the paper's θ*·Φ(ξ*, E) − θ*·Φ(ξ, E), which can go negative because the
  planner also pays for smoothness.
"""

from __future__ import annotations

import numpy as np


def estimate_error(theta_hat: np.ndarray, theta_star: np.ndarray) -> float:
    """‖θ̂ − θ*‖₁."""
    return float(np.sum(np.abs(np.asarray(theta_hat) - np.asarray(theta_star))))


def regret_terms(
    theta_star: np.ndarray,
    phi_star: np.ndarray,
    smooth_star: float,
    phi: np.ndarray,
    smooth: float,
    smoothness_weight: float,
) -> tuple[float, float]:
    """(full-objective regret, paper's θ*·Φ regret) of one environment.

    Args:
        theta_star: the user's θ* (k,).
        phi_star: Φ of the user's optimal trajectory ξ*(θ*, E) (k,).
        smooth_star: S, its smoothness cost.
        phi: Φ of the robot's trajectory ξ*(θ̂, E) (k,).
        smooth: S, its smoothness cost.
        smoothness_weight: λ of the planner.
    """
    paper = float(theta_star @ (np.asarray(phi_star) - np.asarray(phi)))
    full = paper - smoothness_weight * (smooth_star - smooth)
    return full, paper


def mean_sem(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error over axis 0 (runs), ignoring NaN; SEM is 0 for a single run."""
    values = np.asarray(values, dtype=float)
    mean = np.nanmean(values, axis=0)
    if values.shape[0] < 2:
        return mean, np.zeros_like(mean)
    n = np.sum(np.isfinite(values), axis=0)
    return mean, np.nanstd(values, axis=0, ddof=1) / np.sqrt(np.maximum(n, 1))


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float | None:
    """ROC AUC of ``scores`` for the binary ``labels`` (1 positive): the probability that a
    random positive scores above a random negative, ties counting one half (Mann–Whitney U
    from mid-ranks). None when either class is empty or a score is not finite."""
    scores = np.asarray(scores, dtype=float)
    labels = np.asarray(labels, dtype=float)
    if scores.shape != labels.shape or not np.all(np.isfinite(scores)):
        return None
    positive = labels == 1
    n_pos, n_neg = int(positive.sum()), int((~positive).sum())
    if n_pos == 0 or n_neg == 0:
        return None
    from scipy.stats import rankdata

    ranks = rankdata(scores)  # mid-ranks of ties
    u = ranks[positive].sum() - n_pos * (n_pos + 1) / 2.0
    return float(u / (n_pos * n_neg))


def roc_auc_interval(
    scores: np.ndarray, labels: np.ndarray, *, resamples: int = 2000, seed: int = 0
) -> tuple[float, float] | None:
    """A 95% bootstrap interval of :func:`roc_auc`, resampling positives and negatives apart
    (each class keeps its size; seeded, so the same data give the same interval). None when
    the AUC is."""
    scores = np.asarray(scores, dtype=float)
    labels = np.asarray(labels, dtype=float)
    if roc_auc(scores, labels) is None:
        return None
    pos, neg = scores[labels == 1], scores[labels != 1]
    rng = np.random.default_rng(seed)
    values = []
    for _ in range(resamples):
        a = pos[rng.integers(len(pos), size=len(pos))]
        b = neg[rng.integers(len(neg), size=len(neg))]
        values.append(roc_auc(np.concatenate([a, b]), np.r_[np.ones(len(a)), np.zeros(len(b))]))
    return float(np.quantile(values, 0.025)), float(np.quantile(values, 0.975))


def expected_calibration_error(
    probabilities: np.ndarray, labels: np.ndarray, bins: int = 10
) -> tuple[float, list[dict]]:
    """ECE of probabilities against binary labels over ``bins`` equal-width bins of [0, 1]
    (Σ_b n_b/n · |mean label − mean probability|), and the reliability diagram's bins
    (low, high, count, mean probability, fraction positive; None for an empty bin)."""
    p = np.asarray(probabilities, dtype=float)
    y = np.asarray(labels, dtype=float)
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.clip(np.digitize(p, edges[1:-1]), 0, bins - 1)
    rows, total = [], 0.0
    for b in range(bins):
        mask = which == b
        n = int(mask.sum())
        row = {"low": float(edges[b]), "high": float(edges[b + 1]), "count": n}
        row |= {"probability": None, "fraction": None}
        if n:
            row["probability"] = float(p[mask].mean())
            row["fraction"] = float(y[mask].mean())
            total += n / len(p) * abs(row["fraction"] - row["probability"])
        rows.append(row)
    return float(total), rows


def label_scores(probabilities: np.ndarray, labels: np.ndarray) -> dict:
    """How probabilities of relevance score binary labels (1 a correction toward a preference,
    0 a nudge): ROC AUC with its 95% bootstrap interval, the median of each label, the expected
    calibration error and the counts (None where a label is missing)."""
    p = np.asarray(probabilities, dtype=float)
    y = np.asarray(labels, dtype=float)
    interval = roc_auc_interval(p, y)
    return {
        "auc": roc_auc(p, y),
        "auc_ci95": None if interval is None else list(interval),
        "median_toward": float(np.median(p[y == 1])) if (y == 1).any() else None,
        "median_nudge": float(np.median(p[y == 0])) if (y == 0).any() else None,
        "ece": expected_calibration_error(p, y)[0] if p.size else None,
        "toward": int((y == 1).sum()),
        "nudges": int((y == 0).sum()),
    }
