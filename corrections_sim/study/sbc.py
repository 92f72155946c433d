"""Simulation-based calibration (Talts et al. 2018): people drawn from the recommended
robot's own prior, each learner's posterior judged by the rank of the truth among its draws.
The computation; the command, its files and its figure are :mod:`corrections_sim.figures.sbc`.

Each draw d is one person, drawn from the generator of ``SeedSequence([seed, d])`` from the
prior of the study's EX-M (:func:`draw_person`): θ* from N(θ̂⁰, P⁰) within the atlas's box
(where EX-M's grid truncates its prior), one of EX-M's correction models (uniform), one of its
noise scales c (uniform) and N from IW(ν₀, c V₀), the inverse-Wishart EX-M mixes; every
correction relevant (EX-M's default judges none). The person (:class:`PriorPerson`) corrects
exactly as that model says, toward their plans from the study's atlas (the plans the robot's
model reads), and shows the features of their correction plus noise drawn from N. Every
learner of the study meets the same person, environments and noise (common random numbers).

After t = :data:`AT` corrections, :data:`SAMPLES` draws are taken from each learner's
posterior (:func:`~corrections_sim.learning.exact.draws.mixture_draws`: an exact learner's
within its refined cells, a Gaussian's from N(θ̂, P)) and the rank of each true weight among
them is recorded: for the Bayes posterior of the person's generative process the ranks are
uniform over 0 … :data:`SAMPLES`. Also the posterior mass denser than θ* (``level``: θ* lies
in the α highest-density region iff level ≤ α; an exact learner's from
:data:`LEVEL_SAMPLES` draws, a Gaussian's χ²ₖ's CDF at its NEES).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import stats

from corrections_sim.belief import Belief
from corrections_sim.calibration import wilson
from corrections_sim.learning.base import LEARNERS
from corrections_sim.learning.exact.draws import mixture_density, mixture_draws, posterior_parts
from corrections_sim.learning.exact.mixture import ExactPersonModel, model_tag
from corrections_sim.people.corrections import CorrectionModel
from corrections_sim.people.users import CorrectingUser, Situation
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import shared_planner
from corrections_sim.plans import spread
from corrections_sim.plans.book import Target
from corrections_sim.study import loop, runner
from corrections_sim.study.settings import FigureSettings

#: The corrections after which the posterior is judged.
AT: tuple[int, ...] = (4, 12)
#: Posterior draws a rank is taken among (ranks 0 … SAMPLES).
SAMPLES = 99
#: Bins of the ranks' histogram (SAMPLES + 1 ranks, 10 a bin).
BINS = 10
#: Posterior draws an exact learner's highest-density level of θ* is estimated from.
LEVEL_SAMPLES = 999
#: The highest-density regions whose coverage is reported.
COVERAGE = (0.5, 0.9)
#: The learner whose prior the people are drawn from.
ROBOT = "EX-M"
#: Off-node plans of an environment a draw leaves unsaved before they go to the store.
SAVE_AT_LEAST = 200


@dataclass(frozen=True)
class DrawnPerson:
    """One person drawn from EX-M's prior (:func:`draw_person`).

    Attributes:
        theta: θ* (k,).
        model: the index of their correction model among EX-M's.
        scale: the noise scale c of their inverse-Wishart (1 with N fixed).
        noise: N (k, k), the covariance of the noise on the features they show.
    """

    theta: np.ndarray
    model: int
    scale: float
    noise: np.ndarray


def robot(base: FigureSettings) -> ExactPersonModel:
    """The learner whose prior the people come from: the study's EX-M, else its defaults."""
    found = base.study.learners.get(ROBOT)
    return found if isinstance(found, ExactPersonModel) else ExactPersonModel()


def check(base: FigureSettings) -> None:
    """Refuse, in one line, a study SBC cannot judge."""
    if base.atlas_spec() is None:
        raise ValueError("atlas: SBC draws people from EX-M's prior, which needs the plan atlas")
    if base.study.iterations < max(AT):
        raise ValueError(
            f"iterations: SBC judges the posterior at t = {', '.join(map(str, AT))}: needs at "
            f"least {max(AT)}, got {base.study.iterations}"
        )
    if robot(base).relevance:
        raise ValueError(
            f"learners.{ROBOT}.relevance: SBC's people make every correction relevant; judge "
            "the robot without relevance"
        )
    for name, learner in base.study.learners.items():
        if LEARNERS[name].needs_rates() or not learner.has_covariance:
            raise ValueError(f"learners: {name} has no posterior to draw from")


def draw_person(base: FigureSettings, rng: np.random.Generator) -> DrawnPerson:
    """A person from EX-M's prior (module docstring): θ* by rejection within the atlas's box,
    then the model, the scale and N, in that order from ``rng``."""
    s = base.study
    prior = s.prior()
    grid = base.atlas_spec().grid
    lows, highs = np.array(grid.lows), np.array(grid.highs)
    while True:
        theta = rng.multivariate_normal(prior.theta, prior.cov)
        if np.all((theta >= lows) & (theta <= highs)):
            break
    parts = robot(base).parts()
    which = int(rng.integers(len(parts)))
    noise_prior = parts[which].noise_prior(prior, s.noise())
    if noise_prior is None:  # N fixed (noise = "fixed"): the study's
        return DrawnPerson(theta, which, 1.0, np.array(s.noise().observation, float))
    scales = getattr(parts[which], "noise_scales", (1.0,))
    scale = float(scales[int(rng.integers(len(scales)))])
    found = stats.invwishart(df=noise_prior.dof, scale=scale * noise_prior.scale)
    return DrawnPerson(theta, which, scale, np.atleast_2d(found.rvs(random_state=rng)))


@dataclass(frozen=True, eq=False)
class PriorPerson(CorrectingUser):
    """A person as EX-M's model says: corrects with ``correction`` toward their plans and
    shows the features of the correction plus noise N(0, ``noise``) (only those: the
    corrected trajectory is not read)."""

    correction: CorrectionModel
    noise: np.ndarray
    stochastic: ClassVar[bool] = True

    def model(self) -> CorrectionModel:
        return self.correction

    def observe(self, corrected: np.ndarray, situation: Situation, rng: np.random.Generator):
        phi = feature_counts(corrected, situation.env, situation.features)
        return phi + rng.multivariate_normal(np.zeros(len(phi)), self.noise)

    def shows_trajectory(self) -> bool:
        return False


def judge(learner, belief: Belief, theta_star: np.ndarray, rng: np.random.Generator) -> dict:
    """The rank of each true weight among :data:`SAMPLES` posterior draws (``rank_i``) and
    the posterior mass denser than θ* (``level``): an exact learner's from
    :data:`LEVEL_SAMPLES` more draws within its cells, a Gaussian's χ²ₖ's CDF at its NEES."""
    k = len(theta_star)
    parts = posterior_parts(learner, belief)
    if parts:
        draws = mixture_draws(parts, SAMPLES, rng)
        found = mixture_density(
            parts, np.vstack([mixture_draws(parts, LEVEL_SAMPLES, rng), theta_star])
        )
        level = float(np.mean(found[:-1] > found[-1]))
    else:
        draws = rng.multivariate_normal(belief.theta, belief.cov, size=SAMPLES)
        e = belief.theta[:k] - theta_star
        nees = float(e @ np.linalg.solve(belief.cov[:k, :k], e))
        level = float(stats.chi2.cdf(nees, k))
    ranks = (draws[:, :k] < theta_star[None, :]).sum(axis=0)
    return {**{f"rank_{i}": int(ranks[i]) for i in range(k)}, "level": level}


def sbc_draw(base: FigureSettings, d: int, handed: spread.Carried | None = None) -> list[dict]:
    """Draw ``d``'s person, every learner's run with them, and the judged posteriors at
    :data:`AT`: one row a learner and t. Safe in a worker process; ``handed``: the study's
    atlases, to a worker that may not share the caller's files."""
    if handed is not None:
        spread.receive(base.atlas_spec(), handed)
    s = base.study
    person = draw_person(base, np.random.default_rng(np.random.SeedSequence([s.seed, d])))
    models = robot(base).models
    atlas = base.atlas()
    planner = shared_planner(base.planner_config())
    envs = base.envs()
    # The person's plans are the atlas's at θ*: the plans the robot's model reads.
    target = Target(
        theta_star=person.theta,
        plans=tuple(atlas.solve(person.theta, env) for env in envs),
        features=planner.config.features,
    )
    study = dataclasses.replace(s, theta_star=tuple(float(v) for v in person.theta))
    user = PriorPerson(correction=models[person.model], noise=person.noise)
    tag = model_tag(models[person.model])
    rows = []
    for learner in s.learners:
        kept: dict[int, Belief] = {}

        def watch(t: int, belief: Belief, kept=kept) -> None:
            if t in AT:
                kept[t] = belief

        rng = np.random.default_rng(np.random.SeedSequence([s.seed, d, 1]))
        result = loop.run_learner(
            learner, d, study, planner, envs, target, user, rng, atlas=atlas, watch=watch
        )
        stream = LEARNERS[learner].stream
        for t in AT:
            belief = kept[t]
            seed = np.random.SeedSequence([s.seed, d, 2, stream, t])
            judged = judge(s.learners[learner], belief, person.theta, np.random.default_rng(seed))
            record = result.records[t]
            row = {
                "draw": d,
                "learner": learner,
                "iteration": t,
                "model": tag,
                "noise_scale": person.scale,
                **{f"theta_star_{i}": float(v) for i, v in enumerate(person.theta)},
                **{f"noise_{i}{j}": float(person.noise[i, j]) for i, j in ((0, 0), (0, 1), (1, 1))},
                **judged,
                "nees": record["nees"],
                "estimate_error": record["estimate_error"],
                "skipped": sum(bool(r["update_skipped"]) for r in result.records[: t + 1]),
            }
            p_model = belief.state.columns().get(f"model_{tag}")
            if p_model is not None:  # EX-M's posterior probability of the person's own model
                row["p_model"] = float(p_model)
            rows.append(row)
    atlas.save(at_least=SAVE_AT_LEAST)
    return rows


def rank_counts(ranks: Sequence[int]) -> np.ndarray:
    """The ranks' histogram over :data:`BINS` equal bins of 0 … :data:`SAMPLES`."""
    width = (SAMPLES + 1) // BINS
    return np.bincount(np.asarray(ranks, int) // width, minlength=BINS)


def chi2_p(ranks: Sequence[int]) -> float:
    """The χ² test's p-value of the ranks' histogram against uniform."""
    return float(stats.chisquare(rank_counts(ranks)).pvalue)


def wilson_or_none(hits: int, n: int) -> list[float | None]:
    """:func:`~corrections_sim.calibration.wilson`'s 95% interval, [None, None] of no runs."""
    return list(wilson(hits, n)) if n else [None, None]


def summarize(learners: Sequence[str], k: int, rows: Sequence[dict]) -> dict:
    """Per learner and t: each weight's ranks' χ² p-value (``chi2_p``) and histogram, the
    coverage of the 50% and 90% highest-density regions with their 95% (Wilson) intervals,
    the mean NEES, for EX-M the mean posterior probability of the person's own model, and per
    correction model of the people (its tag's dots written as underscores) each weight's χ²
    p-value and EX-M's mean probability of that model (a diagnostic: a sixth of the people
    each)."""
    out: dict = {}
    for learner in learners:
        mine = [r for r in rows if r["learner"] == learner]
        by_t: dict = {}
        for t in AT:
            at = [r for r in mine if r["iteration"] == t]
            entry: dict = {"draws": len(at)}
            for i in range(k):
                ranks = [r[f"rank_{i}"] for r in at]
                entry[f"weight_{i}"] = {
                    "chi2_p": chi2_p(ranks),
                    "counts": rank_counts(ranks).tolist(),
                }
            for alpha in COVERAGE:
                hits = int(sum(r["level"] <= alpha for r in at))
                entry[f"coverage_{round(100 * alpha)}"] = {
                    "share": hits / len(at) if at else None,
                    "ci95": wilson_or_none(hits, len(at)),
                }
            nees = [r["nees"] for r in at if r["nees"] is not None]
            entry["mean_nees"] = float(np.mean(nees)) if nees else None
            entry["mean_error"] = float(np.mean([r["estimate_error"] for r in at])) if at else None
            if at and "p_model" in at[0]:
                entry["mean_p_model"] = float(np.mean([r["p_model"] for r in at]))
            models: dict = {}
            for tag in sorted({r["model"] for r in at}):
                group = [r for r in at if r["model"] == tag]
                ranks = {i: [r[f"rank_{i}"] for r in group] for i in range(k)}
                found = {"draws": len(group)} | {f"chi2_p_{i}": chi2_p(ranks[i]) for i in range(k)}
                if "p_model" in group[0]:  # how often the robot holds these people's model
                    found["mean_p_model"] = float(np.mean([r["p_model"] for r in group]))
                # A tag's dots as underscores (waypoint_step0_5): a key a dotted path names.
                models[tag.replace(".", "_")] = found
            entry["by_model"] = models
            by_t[str(t)] = entry
        out[learner] = by_t
    return out


def judged_run(
    settings: FigureSettings,
    shared: runner.Shared,
    learner: str,
    run: int,
    handed: spread.Carried | None = None,
) -> dict:
    """Run ``run`` of ``learner`` in ``settings``'s study exactly as the study runs it (the
    same draws, so its records are the study's own), its posterior after the last correction
    judged against the study's θ* (:func:`judge`): the highest-density level of θ*
    (``level``: θ* lies in the posterior's a-region for every a ≥ level) and each weight's
    rank. For people the robot's model does not hold (a matrix's columns): the coverage of
    its credible regions where SBC's people, drawn from its prior, cannot tell. Safe in a
    worker process; ``handed``: the study's atlases."""
    s = settings.study
    last = s.iterations
    kept: dict[int, Belief] = {}

    def watch(t: int, belief: Belief) -> None:
        if t == last:
            kept[t] = belief

    result = runner.run_one(settings, shared, learner, run, handed=handed, watch=watch)
    stream = LEARNERS[learner].stream
    rng = np.random.default_rng(np.random.SeedSequence([s.seed, stream, run, 3]))
    theta_star = np.asarray(s.theta_star, float)
    judged = judge(s.learners[learner], kept[last], theta_star, rng)
    record = result.records[last]
    return {
        "learner": learner,
        "run": run,
        "iteration": last,
        **judged,
        "nees": record["nees"],
        "estimate_error": record["estimate_error"],
        "regret": record.get("regret"),
    }


def coverage_of(rows: Sequence[dict]) -> dict:
    """Of judged runs' rows: how many, the share whose θ* lies in the 50% and 90%
    highest-density regions with 95% (Wilson) intervals, and the mean level, NEES and error."""
    out: dict = {"runs": len(rows)}
    for alpha in COVERAGE:
        hits = int(sum(r["level"] <= alpha for r in rows))
        out[f"coverage_{round(100 * alpha)}"] = {
            "share": hits / len(rows) if rows else None,
            "ci95": wilson_or_none(hits, len(rows)),
        }
    for name in ("level", "nees", "estimate_error"):
        found = [r[name] for r in rows if r.get(name) is not None]
        out[f"mean_{name}"] = float(np.mean(found)) if found else None
    return out
