"""Relevance (beyond the paper): people who correct for what the robot cannot represent, and
learners that notice (Bobu, Bajcsy, Fisac & Dragan, CoRL 2018).

The columns of ``experiments/relevance.toml`` are people, as in fig. 6 (the same machinery,
:mod:`corrections_sim.figures.robustness`; a column may set ``user_features`` and
``theta_star``, what the person weighs): the paper's biased user; a person who also minds a
feature the robot does not have; the biased user whose corrections are nudges without a
preference 30% of the time; a person who minds only the unknown feature. Rows are learners:
the paper's, the correction-aware ones, BP, one feature at a time (PP-MAX) and the
relevance-aware PP-R and KF-CR, which estimate per correction the probability β̂ that it is
explained by their features (:mod:`corrections_sim.learning.relevance.judge`).

Files: ``matrix.csv`` (fig. 6's cells — final error on the known features, regret of the
person's whole objective, calibration — plus the drift ‖θ̂¹² − θ̂⁰‖₁, and for a learner with
β̂ its ROC AUC against the ``relevant`` labels and its mean over relevant and irrelevant
corrections), ``curves.csv`` (every record, with ``relevant``, ``relevance`` and
``relevance_residual`` per correction), ``paired.csv`` (paired 95% intervals of each
relevance-aware learner and PP-MAX against its twin: final error, regret and drift, per
person), the matrix plot and ``relevance-beta.png`` (ρ of relevant and irrelevant
corrections, and the drift).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from corrections_sim.figures import robustness
from corrections_sim.figures.registry import register
from corrections_sim.metrics import expected_calibration_error, mean_sem, roc_auc
from corrections_sim.study import analysis
from corrections_sim.study.runner import FigureResult

FIGURE = "relevance"
#: Each learner compared with its twin in ``paired.csv``: the same learner without relevance
#: (and PP-MAX with the perceptron it restricts).
TWINS = {"KF-CR": "KF-C", "KF-CRP": "KF-C", "PP-R": "PP", "PP-MAX": "PP"}


def _final(records: Sequence[dict], learner: str) -> list[dict]:
    last = max(r["iteration"] for r in records)
    return [r for r in records if r["learner"] == learner and r["iteration"] == last]


def drift(records: Sequence[dict], learner: str, k: int) -> np.ndarray:
    """‖θ̂ᵀ − θ̂⁰‖₁ per run (runs,), in run order."""
    first = {r["run"]: r for r in records if r["learner"] == learner and r["iteration"] == 0}
    out = []
    for r in sorted(_final(records, learner), key=lambda r: r["run"]):
        start = first[r["run"]]
        out.append(sum(abs(float(r[f"theta_{i}"]) - float(start[f"theta_{i}"])) for i in range(k)))
    return np.array(out, dtype=float)


def judged(records: Sequence[dict], learner: str) -> dict[str, np.ndarray]:
    """β̂, ρ and the label of every correction ``learner`` judged (``relevant`` 1 where the
    study records no label: every correction of such a person is relevant)."""
    rows = [
        r
        for r in records
        if r["learner"] == learner
        and r["iteration"] > 0
        and np.isfinite(analysis._number(r.get("relevance")))
    ]
    label = [analysis._number(r.get("relevant", 1.0)) for r in rows]
    return {
        "beta": np.array([analysis._number(r["relevance"]) for r in rows], dtype=float),
        "rho": np.array([analysis._number(r.get("relevance_residual")) for r in rows], float),
        "relevant": np.nan_to_num(np.array(label, dtype=float), nan=1.0),
    }


def matrix(settings, results: Sequence[FigureResult]) -> list[dict]:
    """Fig. 6's rows with, per learner and person: the drift of θ̂ (mean, SEM), and for a
    learner that estimates relevance its ROC AUC and mean β̂ over relevant and irrelevant
    corrections, and the share of irrelevant corrections."""
    rows = robustness.matrix(settings, results)
    by_user = {c.label: (c, r) for c, r in zip(settings.columns, results, strict=True)}
    for row in rows:
        column, result = by_user[row["user"]]
        moved = drift(result.records, row["learner"], column.settings.study.k)
        mean, sem = mean_sem(moved[:, None])
        row["drift_mean"], row["drift_sem"] = float(mean[0]), float(sem[0])
        seen = judged(result.records, row["learner"])
        has = seen["beta"].size > 0
        relevant = seen["relevant"] == 1
        row["relevance_auc"] = roc_auc(seen["beta"], seen["relevant"]) if has else None
        row["relevance_relevant_mean"] = (
            float(seen["beta"][relevant].mean()) if has and relevant.any() else None
        )
        row["relevance_irrelevant_mean"] = (
            float(seen["beta"][~relevant].mean()) if has and (~relevant).any() else None
        )
        row["irrelevant_share"] = float(np.mean(~relevant)) if has else None
    return rows


def paired(settings, results: Sequence[FigureResult]) -> list[dict]:
    """Paired 95% t-intervals of each learner in :data:`TWINS` minus its twin, per person:
    final estimate error, final regret and drift (the learners share their runs' draws)."""
    out = []
    for column, result in zip(settings.columns, results, strict=True):
        learners = column.settings.study.learners
        data = analysis.curves(column.settings, result.records)
        k = column.settings.study.k
        for a, b in TWINS.items():
            if a not in learners or b not in learners:
                continue
            pairs = robustness.final_pairs(column.label, data, a, b)
            if not pairs:
                continue
            out += pairs
            diff = drift(result.records, a, k) - drift(result.records, b, k)
            out.append(
                {"user": column.label, "a": a, "b": b, "metric": "drift"} | analysis._mean_ci(diff)
            )
    return out


def boundary(settings) -> float | None:
    """The ρ at which KF-CR's β̂ is one half (bisection), if the study runs KF-CR."""
    learner = settings.columns[0].settings.study.learners.get("KF-CR")
    if learner is None:
        return None
    model = learner.relevance(settings.columns[0].settings.study.k)
    low, high = 1e-9, 1.0 - 1e-9
    for _ in range(60):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if model.probability(mid) > 0.5 else (low, mid)
    return 0.5 * (low + high)


def write(settings, results: Sequence[FigureResult], folder: Path) -> dict:
    """matrix.csv, curves.csv, paired.csv and the plots in ``folder``; the summary's fields."""
    from corrections_sim.figures.output import write_csv
    from corrections_sim.figures.robustness import plot_robustness_matrix

    rows = matrix(settings, results)
    pairs = paired(settings, results)
    summary = robustness.write_matrix(settings, results, rows, folder, pairs)
    title = robustness.title(settings, "relevance")
    paths = [folder / f"{FIGURE}.png", folder / f"{FIGURE}.pdf"]
    environments = len(settings.columns[0].settings.envs())
    plot_robustness_matrix(rows, title, paths, environments=environments)
    seen = {
        c.label: {
            learner: judged(r.records, learner)
            for learner in c.settings.study.learners
            if learner in TWINS and learner != "PP-MAX"
        }
        for c, r in zip(settings.columns, results, strict=True)
    }
    plot_relevance(rows, seen, title, [folder / f"{FIGURE}-beta.png"], boundary(settings))
    diagrams = reliability(settings, results)
    write_csv(
        folder / "reliability.csv",
        [{"learner": name} | b for name, d in diagrams.items() for b in d["bins"]],
    )
    plot_reliability(diagrams, title, [folder / f"{FIGURE}-reliability.png"])
    return summary | {
        "pooled_auc": pooled_auc(settings, results),
        "ece": {name: d["ece"] for name, d in diagrams.items()},
    }


def reliability(settings, results: Sequence[FigureResult], bins: int = 10) -> dict:
    """Per learner with β̂, the reliability diagram of β̂ over every person's corrections
    (a person without labels counts as relevant) in ``bins`` bins, and its expected
    calibration error."""
    out = {}
    for learner in settings.columns[0].settings.study.learners:
        parts = [judged(r.records, learner) for r in results]
        beta = np.concatenate([p["beta"] for p in parts])
        if beta.size:
            label = np.concatenate([p["relevant"] for p in parts])
            ece, rows = expected_calibration_error(beta, label, bins)
            out[learner] = {"ece": ece, "bins": rows}
    return out


def pooled_auc(settings, results: Sequence[FigureResult]) -> dict[str, float | None]:
    """Per learner with β̂, its ROC AUC over every person's corrections together (a person
    without labels counts as relevant): whether β̂ ranks the partly explainable corrections
    of a person who also minds something else above the unexplainable ones."""
    out = {}
    for learner in settings.columns[0].settings.study.learners:
        parts = [judged(r.records, learner) for r in results]
        beta = np.concatenate([p["beta"] for p in parts])
        if beta.size:
            out[learner] = roc_auc(beta, np.concatenate([p["relevant"] for p in parts]))
    return out


@dataclass(frozen=True)
class RelevanceFigure(robustness.RobustnessFigure):
    """The relevance study as a registered figure: fig. 6's columns (people) and caches, its
    own file, files and plots."""

    name: str = FIGURE
    help: str = "beyond the paper: corrections the robot cannot explain; relevance-aware learners"
    in_all: bool = False

    def load(self, *, quick: bool, overrides: Mapping[str, Any]):
        return robustness.load_settings(quick=quick, overrides=dict(overrides), figure=FIGURE)

    def write(self, settings, result: list[FigureResult], folder: Path) -> dict:
        return write(settings, result, folder)


register(RelevanceFigure())


def plot_relevance(
    rows: Sequence[dict], seen: dict, title: str, paths, boundary: float | None = None
) -> None:
    """The relevance figure's second plot: (a) the distribution of ρ, the unexplained fraction
    of each correction KF-CR judged, relevant and irrelevant apart, per person; (b) how
    far θ̂ drifted from θ̂⁰ over the run, per learner and person (mean ± SEM).

    Args:
        rows: ``relevance.matrix`` rows (learner, user, drift_mean, drift_sem, …).
        seen: person -> learner -> {"rho", "beta", "relevant"} arrays per correction.
        paths: files to write.
        boundary: the ρ where β̂ = 1/2, drawn as a line.
    """
    from corrections_sim.figures.style import plt, save_and_close

    users = list(dict.fromkeys(r["user"] for r in rows))
    learners = list(dict.fromkeys(r["learner"] for r in rows))
    cell = {(r["learner"], r["user"]): r for r in rows}
    fig, (left, right) = plt.subplots(1, 2, figsize=(15, 5.2))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for j, user in enumerate(users):
        data = seen.get(user, {}).get("KF-CR")
        if data is None or data["rho"].size == 0:
            continue
        for label, mask, style in (
            ("relevant", data["relevant"] == 1, "-"),
            ("irrelevant", data["relevant"] == 0, "--"),
        ):
            values = np.sort(data["rho"][mask & np.isfinite(data["rho"])])
            if values.size:
                left.step(
                    values,
                    np.arange(1, values.size + 1) / values.size,
                    where="post",
                    linestyle=style,
                    color=colours[j % len(colours)],
                    label=f"{user}: {label} ({values.size})",
                )
    if boundary is not None:
        left.axvline(boundary, color="0.4", lw=0.8, ls=":")
        left.text(boundary, 0.02, f" β̂ = 0.5 at ρ = {boundary:.2f}", fontsize=8, color="0.3")
    left.set_xlim(0.0, 1.0)
    left.set_ylim(0.0, 1.02)
    left.set_xlabel("ρ, the unexplained fraction of a correction (KF-CR's best θ)")
    left.set_ylabel("fraction of corrections with a smaller ρ")
    left.set_title("(a) what the robot's features cannot explain", fontsize=10)
    left.legend(fontsize=7)
    width = 0.8 / max(len(users), 1)
    x = np.arange(len(learners))
    for j, user in enumerate(users):
        means = [cell[(n, user)]["drift_mean"] for n in learners]
        sems = [cell[(n, user)]["drift_sem"] for n in learners]
        right.bar(x + (j - (len(users) - 1) / 2) * width, means, width, yerr=sems, label=user)
    right.set_xticks(x, learners, rotation=20, fontsize=9)
    right.set_ylabel("‖θ̂ᵀ − θ̂⁰‖₁")
    right.set_title("(b) how far θ̂ moved over the run", fontsize=10)
    right.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_and_close(fig, paths, dpi=130)


def plot_reliability(diagrams: dict, title: str, paths) -> None:
    """Reliability diagrams of β̂: per learner, the fraction of relevant corrections in each
    β̂ bin against the bin's mean β̂ (marker area ∝ the bin's corrections), the diagonal
    being perfect calibration; the expected calibration error in the legend.

    Args:
        diagrams: learner -> {"ece": float, "bins": [{count, probability, fraction}, …]}.
        paths: files to write.
    """
    from corrections_sim.figures.style import learner_style, plt, save_and_close

    fig, ax = plt.subplots(figsize=(6.2, 5.6))
    ax.plot([0, 1], [0, 1], color="0.6", lw=0.8, ls=":")
    total = max(sum(b["count"] for b in d["bins"]) for d in diagrams.values())
    for name, diagram in diagrams.items():
        bins = [b for b in diagram["bins"] if b["count"]]
        colour, style = learner_style(name)
        x = [b["probability"] for b in bins]
        y = [b["fraction"] for b in bins]
        ax.plot(x, y, color=colour, ls=style, lw=1.2, label=f"{name}: ECE {diagram['ece']:.3f}")
        ax.scatter(x, y, s=[8 + 600 * b["count"] / total for b in bins], color=colour, alpha=0.6)
    ax.set_xlim(-0.02, 1.02)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("β̂ (mean within the bin)")
    ax.set_ylabel("fraction of the bin's corrections that are relevant")
    ax.set_title("Is β̂ calibrated? (every person's corrections; area ∝ count)", fontsize=10)
    ax.legend(fontsize=8, loc="upper left")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    save_and_close(fig, paths, dpi=130)
