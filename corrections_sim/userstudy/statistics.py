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

**What it refuses to say.** A model that is saturated (no residual degrees of freedom: as
many parameters as observations, as with two participants in two conditions) or singular (the
fit failed, a standard error is not finite, it did not converge, or the participant variance
sits on its boundary at 0, lme4's "singular fit") is marked ``reported: False`` with the reason;
a report then shows the paired comparison instead. An outcome on a bounded scale (a Likert
item 1…points, the TLX 0…100, seconds and errors ≥ 0) gets intervals computed on that scale:
the t interval on the logit of the mean's place within the bounds (or on its log, for a scale
bounded on one side), mapped back, so it never runs off the scale and needs no clipping.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from itertools import combinations

import numpy as np
from scipy import stats

from corrections_sim.calibration import wilson

#: A confidence level for every interval of the analysis.
LEVEL = 0.95
#: A participant standard deviation below this share of the residual one is on its boundary
#: (a singular fit, as lme4's ``isSingular`` judges one with its default tolerance).
SINGULAR = 1e-4


#: The bounds of a scale: (low, high), either may be None (unbounded on that side).
Bounds = tuple[float | None, float | None]
UNBOUNDED: Bounds = (None, None)


def mean_ci(values: Sequence[float], level: float = LEVEL, bounds: Bounds = UNBOUNDED) -> dict:
    """{n, mean, sd, lo, hi} of ``values`` (NaN dropped) by Student's t; on a bounded scale
    (``bounds``) the interval is computed on that scale (see the module), so it lies within
    it."""
    x = np.asarray([v for v in values if v is not None and np.isfinite(v)], float)
    n = len(x)
    if n == 0:
        return {"n": 0, "mean": math.nan, "sd": math.nan, "lo": math.nan, "hi": math.nan}
    mean = float(x.mean())
    if n < 2:
        return {"n": 1, "mean": mean, "sd": math.nan, "lo": math.nan, "hi": math.nan}
    sd = float(x.std(ddof=1))
    t = float(stats.t.ppf(0.5 + level / 2, n - 1))
    se = sd / math.sqrt(n)
    lo, hi = _bounded_interval(mean, se, t, bounds)
    return {"n": n, "mean": mean, "sd": sd, "lo": lo, "hi": hi}


def _bounded_interval(mean: float, se: float, t: float, bounds: Bounds) -> tuple[float, float]:
    """mean ± t·se on the scale ``bounds``: on the logit of the mean's place between two
    bounds, on the log of its distance from one, by the delta method; mapped back."""
    low, high = bounds
    if se == 0.0:
        return mean, mean
    if low is not None and high is not None:
        width = high - low
        p = (mean - low) / width
        if p <= 0.0 or p >= 1.0:  # every value at one end (se would be 0): no spread to say
            return mean, mean
        centre = math.log(p / (1 - p))
        half = t * (se / width) / (p * (1 - p))
        return tuple(low + width / (1 + math.exp(-(centre + s * half))) for s in (-1, 1))
    if low is not None or high is not None:
        edge, sign = (low, 1.0) if low is not None else (high, -1.0)
        distance = sign * (mean - edge)
        if distance <= 0.0:
            return mean, mean
        half = t * se / distance
        ends = [edge + sign * distance * math.exp(s * half) for s in (-1, 1)]
        return min(ends), max(ends)
    return mean - t * se, mean + t * se


def difference_bounds(bounds: Bounds) -> Bounds:
    """The bounds of a difference of two values on the scale ``bounds`` (± its range)."""
    low, high = bounds
    if low is None or high is None:
        return UNBOUNDED
    return (low - high, high - low)


def _complete(trials: list[dict], outcome: str) -> list[dict]:
    return [t for t in trials if t.get(outcome) is not None and np.isfinite(float(t[outcome]))]


def condition_summary(
    trials: list[dict], outcome: str, conditions: Sequence[str], bounds: Bounds = UNBOUNDED
) -> list[dict]:
    """Per condition: the mean over participants of their mean ``outcome``, with a t CI on
    the scale ``bounds``, and the range of the participants' means."""
    out = []
    for c in conditions:
        per = {}
        for t in _complete(trials, outcome):
            if t["condition"] == c:
                per.setdefault(t["participant"], []).append(float(t[outcome]))
        means = [float(np.mean(v)) for v in per.values()]
        spread = {"min": min(means, default=math.nan), "max": max(means, default=math.nan)}
        out.append({"condition": c, **mean_ci(means, bounds=bounds), **spread})
    return out


def paired(
    trials: list[dict], outcome: str, conditions: Sequence[str], bounds: Bounds = UNBOUNDED
) -> list[dict]:
    """Per pair (a, b) of conditions: each participant's mean(b) − mean(a), with a t CI (on
    the scale of a difference of values within ``bounds``) and Cohen's d_z; participants
    missing either condition are left out."""
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
        summary = mean_ci(diffs, bounds=difference_bounds(bounds))
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

    ``reported`` is False, with ``why``, for a saturated or singular model (see the module):
    its numbers (if any) are kept for the record, and are not a result.

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
    within = (len(conditions) - 1) + (len(periods) - 1)
    residual_df = len(frame) - len(people) - within
    base = {
        "outcome": outcome,
        "formula": formula + " + (1 | participant)",
        "observations": len(frame),
        "participants": len(people),
    }
    if residual_df < 1:
        # As many parameters as the data can carry: the fit would reproduce the data and
        # print intervals of width 0 and p-values of 0.
        return {
            **base,
            "reported": False,
            "why": f"saturated: {len(frame)} observations of {len(people)} participants leave "
            f"no residual degrees of freedom after {within} within-participant effects",
        }
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            model = smf.mixedlm(formula, frame, groups=frame["participant"])
            fit = model.fit(reml=True)
        except (np.linalg.LinAlgError, ValueError) as exc:
            return {**base, "reported": False, "why": f"the fit failed ({exc})"}
    converged = bool(getattr(fit, "converged", True))
    notes = sorted({str(w.message).splitlines()[0] for w in caught})
    df = max(residual_df, 1)
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
    residual_var = float(fit.scale)
    why = ""
    if not converged:
        why = "singular: the fit did not converge"
    elif not all(np.isfinite(e["se"]) and e["se"] > 0 for e in effects):
        why = "singular: a standard error is not finite"
    elif math.sqrt(max(group_var, 0.0)) < SINGULAR * math.sqrt(max(residual_var, 1e-300)):
        why = (
            "singular: the participant variance is at its boundary (0), so the model is a "
            "pooled regression whose interval ignores who gave which answer"
        )
    return {
        **base,
        "reported": not why,
        **({"why": why} if why else {}),
        "effects": effects,
        "participant_variance": group_var,
        "residual_variance": residual_var,
        "converged": converged,
        "warnings": notes,
    }


def sign_test(wins: int, losses: int) -> float:
    """The two-sided exact binomial p of ``wins`` against ``losses`` (ties left out)."""
    n = wins + losses
    if n == 0:
        return math.nan
    return float(stats.binomtest(wins, n, 0.5).pvalue)


def power_summary(significant: Sequence[bool], level: float = LEVEL) -> dict:
    """The share of studies that found the effect, with a Wilson interval."""
    n = len(significant)
    k = int(sum(bool(s) for s in significant))
    if n == 0:
        return {"studies": 0, "power": math.nan, "lo": math.nan, "hi": math.nan}
    z = float(stats.norm.ppf(0.5 + level / 2))
    lo, hi = wilson(k, n, z)
    return {"studies": n, "power": k / n, "lo": lo, "hi": hi}


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
