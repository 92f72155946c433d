"""Analysis that only reads records: curves per learner, final values and areas, calibration
(NEES band, coverage, NIS) and paired differences between learners on one random stream."""

from __future__ import annotations

import numpy as np

from corrections_sim import calibration
from corrections_sim.learning.base import LEARNERS
from corrections_sim.metrics import mean_sem
from corrections_sim.study.runner import FigureResult, _order
from corrections_sim.study.settings import FigureSettings

#: Curves averaged over runs, and the metrics compared between learners.
METRICS = ("estimate_error", "regret", "regret_paper")


def curves(settings: FigureSettings, records: list[dict]) -> dict[str, dict[str, np.ndarray]]:
    """learner -> metric -> values (runs, T + 1), for the metrics and "nees", "nis"."""
    out = {}
    for learner in sorted(settings.study.learners, key=_order):
        rows = [r for r in records if r["learner"] == learner]
        runs = sorted({r["run"] for r in rows})
        out[learner] = {
            key: np.array(
                [[_number(r[key]) for r in rows if r["run"] == run] for run in runs], dtype=float
            )
            for key in (*METRICS, "nees", "nis")
        }
    return out


def _number(value) -> float:
    """A record's value as a float; None and "" (no value) are NaN."""
    return float("nan") if value is None or value == "" else float(value)


def _mean_ci(values: np.ndarray) -> dict:
    """Mean, SEM and the 95% t-interval of the mean of ``values`` (n,)."""
    from scipy import stats

    n = values.size
    mean = float(np.mean(values))
    if n < 2:
        return {"mean": mean, "sem": None, "ci95": None, "n": n}
    sem = float(np.std(values, ddof=1) / np.sqrt(n))
    half = float(stats.t.ppf(0.975, n - 1) * sem)
    return {"mean": mean, "sem": sem, "ci95": [mean - half, mean + half], "n": n}


def paired_differences(settings: FigureSettings, data: dict) -> list[dict]:
    """Paired a − b of final value and area under the curve (Σ over iterations 0 … T) for
    every pair of learners that share their random stream and runs (common random numbers:
    run r of both saw the same environments), with the 95% t-interval of the mean."""
    names = list(data)
    out = []
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            if LEARNERS[a].stream != LEARNERS[b].stream:
                continue
            if data[a]["regret"].shape[0] != data[b]["regret"].shape[0]:
                continue
            if data[a]["regret"].shape[0] < 2:
                continue
            for key in METRICS:
                va, vb = data[a][key], data[b][key]
                out.append(
                    {
                        "a": a,
                        "b": b,
                        "metric": key,
                        "final": _mean_ci(va[:, -1] - vb[:, -1]),
                        "auc": _mean_ci(va.sum(axis=1) - vb.sum(axis=1)),
                    }
                )
    return out


def summarize(settings: FigureSettings, result: FigureResult) -> dict:
    """The figure's statistics, read from its records only: final mean ± SEM and AUC per
    learner and metric, calibration (NEES band, coverage, NIS) of every learner with a
    covariance, and paired differences."""
    s = settings.study
    data = curves(settings, result.records)
    final, calib = {}, {}
    for learner, values in data.items():
        stats = {}
        for key in METRICS:
            mean, sem = mean_sem(values[key][:, -1:])
            stats[key] = {
                "mean": float(mean[0]),
                "sem": float(sem[0]) if values[key].shape[0] > 1 else None,
                "auc_mean": float(np.mean(values[key].sum(axis=1))),
            }
        stats["runs"] = int(values["regret"].shape[0])
        final[learner] = stats
        if LEARNERS[learner].has_covariance:
            entry = calibration.summarize(values["nees"], s.k)
            nis = values["nis"][:, 1:]
            # None where no run has an innovation covariance (BP): valid JSON, not NaN.
            entry["mean_nis"] = [
                float(np.mean(col[np.isfinite(col)])) if np.isfinite(col).any() else None
                for col in nis.T
            ]
            entry["nis_band"] = list(calibration.mean_band(s.k, nis.shape[0]))
            noise = learnt_noise(result.records, learner, s.k)
            if noise:
                entry["mean_noise"] = noise
            calib[learner] = entry
    return {
        "final": final,
        "calibration": calib,
        "paired": paired_differences(settings, data),
    }


def learnt_noise(records: list[dict], learner: str, k: int) -> dict[str, list[float]]:
    """The mean over runs of a noise-learning learner's N̂ at every iteration, per entry
    ``noise_ij`` (i ≤ j); empty for a learner that assumes N."""
    rows = [r for r in records if r["learner"] == learner and "noise_00" in r]
    if not rows:
        return {}
    last = max(r["iteration"] for r in rows)
    out = {}
    for i in range(k):
        for j in range(i, k):
            key = f"noise_{i}{j}"
            out[key] = [
                float(np.mean([r[key] for r in rows if r["iteration"] == t]))
                for t in range(last + 1)
            ]
    return out
