"""The analysis of a user study across people, on plain rows (one dict per trial, per answer):
per-condition summaries, a linear mixed model with condition as a fixed effect and the
participant as a random effect, and paired comparisons with confidence intervals.

**The model.** ``outcome ~ condition + period + (1 | participant)``, fitted by REML
(statsmodels' ``MixedLM``): the period (where in the participant's order the condition came)
is in the model because the conditions' order is counterbalanced, not absent. The condition
effect's confidence interval uses Student's t with the between-within degrees of freedom
(observations − participants − within-participant fixed effects; SAS's DDFM=BW), not the
normal quantile statsmodels reports: over 200 simulated studies of 12 participants the Wald z
interval held the population's difference in 91.0% of them, this one in 93.5%
(``docs/user-study.md`` has the coverage at every size).

**Paired comparisons.** For each pair of conditions, each participant's mean difference over
their trials; the mean, a t interval and Cohen's d_z (mean / sd of the differences).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from itertools import combinations

import numpy as np
from scipy import stats

#: A confidence level for every interval of the analysis.
LEVEL = 0.95


def mean_ci(values: Sequence[float], level: float = LEVEL) -> dict:
    """{n, mean, sd, lo, hi} of ``values`` (NaN dropped) by Student's t."""
    x = np.asarray([v for v in values if v is not None and np.isfinite(v)], float)
    n = len(x)
    if n == 0:
        return {"n": 0, "mean": math.nan, "sd": math.nan, "lo": math.nan, "hi": math.nan}
    mean = float(x.mean())
    if n < 2:
        return {"n": 1, "mean": mean, "sd": math.nan, "lo": math.nan, "hi": math.nan}
    sd = float(x.std(ddof=1))
    half = float(stats.t.ppf(0.5 + level / 2, n - 1)) * sd / math.sqrt(n)
    return {"n": n, "mean": mean, "sd": sd, "lo": mean - half, "hi": mean + half}


def _complete(trials: list[dict], outcome: str) -> list[dict]:
    return [t for t in trials if t.get(outcome) is not None and np.isfinite(float(t[outcome]))]


def condition_summary(trials: list[dict], outcome: str, conditions: Sequence[str]) -> list[dict]:
    """Per condition: the mean over participants of their mean ``outcome``, with a t CI."""
    out = []
    for c in conditions:
        per = {}
        for t in _complete(trials, outcome):
            if t["condition"] == c:
                per.setdefault(t["participant"], []).append(float(t[outcome]))
        out.append({"condition": c, **mean_ci([float(np.mean(v)) for v in per.values()])})
    return out


def paired(trials: list[dict], outcome: str, conditions: Sequence[str]) -> list[dict]:
    """Per pair (a, b) of conditions: each participant's mean(b) − mean(a), with a t CI and
    Cohen's d_z; participants missing either condition are left out."""
    means: dict[str, dict[str, float]] = {}
    for c in conditions:
        per: dict[str, list[float]] = {}
        for t in _complete(trials, outcome):
            if t["condition"] == c:
                per.setdefault(t["participant"], []).append(float(t[outcome]))
        means[c] = {p: float(np.mean(v)) for p, v in per.items()}
    out = []
    for a, b in combinations(conditions, 2):
        both = sorted(set(means[a]) & set(means[b]))
        diffs = [means[b][p] - means[a][p] for p in both]
        summary = mean_ci(diffs)
        dz = summary["mean"] / summary["sd"] if summary["n"] > 1 and summary["sd"] > 0 else math.nan
        t_stat = dz * math.sqrt(summary["n"]) if np.isfinite(dz) else math.nan
        p = math.nan
        if np.isfinite(t_stat):
            p = float(2 * stats.t.sf(abs(t_stat), summary["n"] - 1))
        out.append({"a": a, "b": b, "difference": "b - a", **summary, "d_z": dz, "p": p})
    return out


def mixed_model(trials: list[dict], outcome: str, conditions: Sequence[str]) -> dict:
    """``outcome ~ condition + period + (1 | participant)`` (see the module): the effect of
    each condition against the first, with its SE, t interval and p-value, the variance
    components, and whether the fit converged.

    Raises:
        ValueError: fewer than two participants, or a condition with no observation.
        RuntimeError: statsmodels is not installed.
    """
    try:
        import pandas as pd
        import statsmodels.formula.api as smf
    except ImportError:
        raise RuntimeError('the analysis needs statsmodels: pip install -e ".[study]"') from None
    rows = _complete(trials, outcome)
    people = sorted({t["participant"] for t in rows})
    if len(people) < 2:
        raise ValueError(f"{outcome}: {len(people)} participant(s) with data, the model needs 2")
    present = {t["condition"] for t in rows}
    missing = [c for c in conditions if c not in present]
    if missing:
        raise ValueError(f"{outcome}: no observation in condition {missing[0]}")
    frame = pd.DataFrame(
        {
            "y": [float(t[outcome]) for t in rows],
            "condition": pd.Categorical([t["condition"] for t in rows], categories=conditions),
            "period": [int(t.get("period", 1)) for t in rows],
            "participant": [t["participant"] for t in rows],
        }
    )
    periods = sorted(frame["period"].unique())
    formula = "y ~ C(condition)"
    if len(periods) > 1:
        formula += " + C(period)"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = smf.mixedlm(formula, frame, groups=frame["participant"])
        fit = model.fit(reml=True)
    converged = bool(getattr(fit, "converged", True))
    notes = sorted({str(w.message).splitlines()[0] for w in caught})
    within = (len(conditions) - 1) + (len(periods) - 1)
    df = max(len(frame) - len(people) - within, 1)
    quantile = float(stats.t.ppf(0.5 + LEVEL / 2, df))
    effects = []
    for c in conditions[1:]:
        name = f"C(condition)[T.{c}]"
        estimate = float(fit.fe_params[name])
        se = float(fit.bse_fe[name])
        t_stat = estimate / se if se > 0 else math.nan
        effects.append(
            {
                "condition": c,
                "against": conditions[0],
                "estimate": estimate,
                "se": se,
                "df": df,
                "lo": estimate - quantile * se,
                "hi": estimate + quantile * se,
                "z_lo": estimate - 1.959963984540054 * se,
                "z_hi": estimate + 1.959963984540054 * se,
                "p": float(2 * stats.t.sf(abs(t_stat), df)) if np.isfinite(t_stat) else math.nan,
            }
        )
    group_var = float(fit.cov_re.iloc[0, 0])
    return {
        "outcome": outcome,
        "formula": formula + " + (1 | participant)",
        "observations": len(frame),
        "participants": len(people),
        "effects": effects,
        "participant_variance": group_var,
        "residual_variance": float(fit.scale),
        "converged": converged,
        "warnings": notes,
    }


def power_summary(significant: Sequence[bool], level: float = LEVEL) -> dict:
    """The share of studies that found the effect, with a Wilson interval."""
    n = len(significant)
    k = int(sum(bool(s) for s in significant))
    if n == 0:
        return {"studies": 0, "power": math.nan, "lo": math.nan, "hi": math.nan}
    z = float(stats.norm.ppf(0.5 + level / 2))
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return {"studies": n, "power": p, "lo": centre - half, "hi": centre + half}


def needed(sizes: Sequence[int], powers: Sequence[float], target: float = 0.8) -> float | None:
    """The smallest N at which the power reaches ``target``, interpolated linearly between
    the sizes measured (None if it never does)."""
    pairs = sorted(zip(sizes, powers, strict=True))
    for (n0, p0), (n1, p1) in zip(pairs, pairs[1:], strict=False):
        if p0 >= target:
            return float(n0)
        if p1 >= target:
            return float(n0 + (target - p0) * (n1 - n0) / (p1 - p0))
    if pairs and pairs[-1][1] >= target:
        return float(pairs[-1][0])
    return None
