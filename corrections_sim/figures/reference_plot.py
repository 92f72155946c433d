"""The calibration figure of the exact references in a folder (``run reference-plot``): every
learner's NEES / reference NEES and the Gaussian part of ``ref_kl`` against t, one column per
figure (:mod:`corrections_sim.figures.reference` writes the summaries it reads)."""

from __future__ import annotations

import json
from pathlib import Path


def calibration_figure(folder: Path) -> Path:
    """The calibration figure from the reference summaries in ``folder``: a finished figure's
    ``reference-<learner>/summary.json`` (``run reference``'s), or collected ones,
    ``<figure>-<learner>.json`` as in ``results/reference_posterior``, each with its
    ``by_iteration``: per figure, every learner's NEES / reference NEES and the Gaussian part
    of ``ref_kl`` against t. Writes ``calibration.png`` there."""

    panels = reference_panels(folder)
    if not panels:
        raise ValueError(f"{folder}: no reference summaries with by_iteration in it")
    runs = sorted({rows[-1]["runs"] for learners in panels.values() for rows in learners.values()})
    out = folder / "calibration.png"
    title = "Each learner against exact Bayes under its own model (95% intervals over "
    plot_reference_calibration(panels, f"{title}{'/'.join(map(str, runs))} runs)", [out])
    return out


def reference_panels(folder: Path) -> dict[str, dict[str, list[dict]]]:
    """figure -> learner -> its reference's summaries by iteration, from ``folder``'s
    ``reference-<learner>/summary.json`` (the figure named in their settings) and collected
    ``<figure>-<learner>.json`` files."""
    panels: dict[str, dict] = {}
    for path in sorted([*folder.glob("*.json"), *folder.glob("reference-*/summary.json")]):
        data = json.loads(path.read_text())
        if "by_iteration" not in data:
            continue
        if path.name == "summary.json":  # a reference's folder: its settings name the figure
            figure = data["settings"]["figure"]
        else:
            figure = path.stem.removesuffix(f"-{data['learner']}")
        panels.setdefault(figure, {})[data["learner"]] = data["by_iteration"]
    return panels


def plot_reference_calibration(panels: dict, title: str, paths) -> None:
    """Each learner against its exact reference over t, one column per figure (``panels``:
    figure label -> {learner: by-iteration summaries of ``figures.reference``}): NEES /
    reference NEES with its 95% interval (1 is exact Bayes' confidence; the band
    [0.8, 1.25] shaded) and the Gaussian part of ``ref_kl`` (nats; 0 is the reference's own
    moments) with its interval."""
    from corrections_sim.figures.style import learner_style, plt, save_and_close

    columns = list(panels)
    fig, axes = plt.subplots(
        2, len(columns), figsize=(4.2 * len(columns), 6.4), squeeze=False, sharex="col"
    )
    for c, figure in enumerate(columns):
        top, bottom = axes[0, c], axes[1, c]
        top.axhspan(0.8, 1.25, color="0.9")
        top.axhline(1.0, color="0.5", lw=0.8)
        for learner, rows in panels[figure].items():
            colour, style = learner_style(learner)
            t = [r["iteration"] for r in rows]
            ratio = [r["ratio"] for r in rows]
            low, high = zip(*(r["ratio_ci95"] for r in rows), strict=True)
            top.plot(t, ratio, color=colour, ls=style, marker="o", ms=3, label=learner)
            top.fill_between(t, low, high, color=colour, alpha=0.15)
            gauss = [r["ref_kl_gaussian"] for r in rows]
            low, high = zip(*(r["ref_kl_gaussian_ci95"] for r in rows), strict=True)
            bottom.plot(t, gauss, color=colour, ls=style, marker="o", ms=3, label=learner)
            bottom.fill_between(t, low, high, color=colour, alpha=0.15)
        top.set_yscale("log")
        top.set_title(figure, fontsize=9)
        top.set_ylabel("NEES / reference NEES")
        bottom.axhline(0.02, color="0.6", lw=0.8, ls=":")
        bottom.set_ylabel("ref_kl, Gaussian part (nats)")
        bottom.set_xlabel("corrections t")
        for ax in (top, bottom):
            ax.grid(alpha=0.3)
        top.legend(fontsize=7)
    import textwrap

    # One column is narrower than the title: it wraps rather than runs off the page.
    fig.suptitle(textwrap.fill(title, 60 * len(columns)), fontsize=9)
    fig.tight_layout()
    save_and_close(fig, paths, dpi=130)
