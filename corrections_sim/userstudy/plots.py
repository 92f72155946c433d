"""The plots of ``run analyze`` (:mod:`corrections_sim.userstudy.report`): each participant's
outcomes by condition, the conditions side by side, the questionnaires' answers."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from corrections_sim.userstudy.protocol import OUTCOMES


def plot(tables: dict, result: dict, out: Path, answer_rows: list[dict]) -> list[Path]:
    """participants.png, conditions.png, questionnaires.png (see the module);
    ``answer_rows``: the questionnaires' answers as outcomes (``report.answer_outcomes``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    conditions = result["conditions"]
    names = list(result["outcomes"])
    from matplotlib.ticker import MaxNLocator

    complete = [t for t in tables["trials"] if not t.get("ended_early")]
    descriptive = result["descriptive_only"]
    simulated = " (simulated participants)" if result["simulated"] else ""
    paths = []
    cols = min(3, len(names))
    rows = math.ceil(len(names) / cols)
    for kind in ("participants", "conditions"):
        fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
        for ax, name in zip(axes.flat, names, strict=False):
            source = complete if name in OUTCOMES else answer_rows
            x = np.arange(len(conditions))
            if kind == "participants":
                per: dict[str, dict[str, list[float]]] = {}
                for t in source:
                    if name in t and np.isfinite(float(t[name])):
                        per.setdefault(t["participant"], {}).setdefault(t["condition"], []).append(
                            float(t[name])
                        )
                for values in per.values():
                    y = [np.mean(values[c]) if c in values else np.nan for c in conditions]
                    ax.plot(x, y, "-o", color="0.45", alpha=0.55, lw=1, ms=3)
            entry = result["outcomes"][name]
            spread = kind == "conditions"  # (the participants' figure draws each of them)
            draw_summary(ax, x, entry["summary"], entry["bounds"], descriptive, spread=spread)
            ax.set_xticks(x, conditions)
            ax.set_xlim(-0.5, len(conditions) - 0.5)
            ax.set_title(name.replace("_", " "))
            ax.grid(alpha=0.3)
        for ax in list(axes.flat)[len(names) :]:
            ax.axis("off")
        what = (
            "each participant (grey) and "
            if kind == "participants"
            else "the range of the participants' means (grey), "
        )
        shown = "the mean with its 95% CI"
        if descriptive:
            shown = "the mean (descriptive only: too few participants)"
        fig.suptitle(f"By condition: {what}{shown}{simulated}")
        fig.tight_layout()
        path = out / f"{kind}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    likert = [a for a in tables["answers"] if a["kind"] == "likert"]
    items = list(dict.fromkeys(a["item"] for a in likert))
    if items:
        fig, axes = plt.subplots(1, len(items), figsize=(3.6 * len(items), 3.2), squeeze=False)
        compared_items = {c["item"] for c in tables["comparisons"]}
        for ax, item in zip(axes.flat, items, strict=True):
            mine = [a for a in likert if a["item"] == item]
            points = int(mine[0]["points"])
            if item in compared_items:  # mapped to the conditions, not the raw positions
                rows = [c for c in tables["comparisons"] if c["item"] == item]
                plot_comparison(ax, rows, points)
                continue
            present = {a["condition"] or "end" for a in mine}
            groups = [g for g in (*conditions, "end") if g in present]
            width = 0.8 / len(groups)
            for g, group in enumerate(groups):
                values = [a["value"] for a in mine if (a["condition"] or "end") == group]
                counts = np.bincount(values, minlength=points + 1)[1:]
                ax.bar(
                    np.arange(1, points + 1) + (g - (len(groups) - 1) / 2) * width,
                    counts,
                    width,
                    label=group,
                )
            ax.set_xticks(range(1, points + 1))
            ax.set_title(item)
            ax.set_xlabel("answer")
            ax.legend(fontsize=8)
        axes.flat[0].set_ylabel("participants")
        for ax in axes.flat:
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        fig.suptitle(f"Questionnaire answers{simulated}")
        fig.tight_layout()
        path = out / "questionnaires.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


def draw_summary(
    ax, x: np.ndarray, summary: list[dict], bounds, descriptive: bool, *, spread: bool = True
) -> None:
    """One outcome's panel: per condition the range of the participants' means (a grey bar,
    with ``spread``), the mean, and its 95% CI unless ``descriptive``; the y-axis
    spans the outcome's scale where it has one, and zero where it has none (the errors 0.999
    and 1.024 of two participants were drawn from the bottom of the panel to its top)."""
    means = np.array([row["mean"] for row in summary], float)
    lowest = np.array([row.get("min", np.nan) for row in summary], float)
    highest = np.array([row.get("max", np.nan) for row in summary], float)
    if spread:
        ax.vlines(
            x - 0.12,
            lowest,
            highest,
            color="0.55",
            lw=6,
            alpha=0.6,
            label="range of the participants' means",
        )
    seen = [means, lowest, highest]
    if descriptive:  # no interval to draw: the mean alone
        ax.plot(x, means, "s", color="C3", ms=7, zorder=3, label="mean")
    else:
        lo = np.array([row["lo"] for row in summary], float)
        hi = np.array([row["hi"] for row in summary], float)
        seen += [lo, hi]
        ax.errorbar(
            x,
            means,
            yerr=[means - lo, hi - means],
            fmt="s",
            color="C3",
            capsize=5,
            lw=2,
            ms=7,
            zorder=3,
            label="mean, 95% CI",
        )
    values = np.concatenate(seen)
    values = values[np.isfinite(values)]
    low, high = bounds
    bottom = low if low is not None else min(0.0, *values) if values.size else 0.0
    top = high if high is not None else max(values.max(), bottom + 1e-9) if values.size else 1.0
    pad = 0.05 * (top - bottom)
    ax.set_ylim(bottom - pad, top + pad)


def plot_comparison(ax, rows: list[dict], points: int) -> None:
    """An item that compares the robots: how many leant how far toward each condition."""
    reach = (points - 1) / 2
    scores = np.arange(-reach, reach + 1)
    counts = [sum(r["score"] == s for r in rows) for s in scores]
    names = sorted({rows[0]["first"], rows[0]["second"]})
    ax.bar(scores, counts, 0.7, color="C2")
    ax.set_xticks(scores)
    ax.set_title(f"{rows[0]['item']} (mapped to the conditions)")
    ax.set_xlabel(f"← {names[0]}     neither     {names[1]} →")
