"""``relevance-fit``: the densities of a relevant and an irrelevant correction, fitted on
simulated labelled corrections (:mod:`corrections_sim.figures.relevance_fit`).

    python -m corrections_sim.run relevance-fit
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from corrections_sim.cli.command import Command, wrote_nothing
from corrections_sim.cli.errors import UsageError


def run_relevance_fit(args: argparse.Namespace) -> list[Path]:
    """Simulated labelled corrections, the fit, its densities plotted; the fit printed."""
    from corrections_sim.figures.output import write_csv
    from corrections_sim.figures.relevance_fit import SEED, fit, labelled_corrections, plot

    per_kind = 12 if args.quick else (60 if args.per_kind is None else args.per_kind)
    if per_kind < 2:
        raise UsageError(f"--per-kind {per_kind}: at least 2")
    seed = SEED if args.seed is None else args.seed
    out = Path("results") if args.out is None else Path(args.out)
    folder = out / ("quick" if args.quick else "") / "relevance_fit"
    rows = labelled_corrections(per_kind, seed)
    fitted = fit(rows)
    fitted["source"] = f"relevance_fit --per-kind {per_kind} --seed {seed}"
    folder.mkdir(parents=True, exist_ok=True)
    written = [write_csv(folder / "data.csv", rows)]
    (folder / "fit.json").write_text(json.dumps(fitted, indent=1) + "\n")
    written += [folder / "fit.json", plot(rows, fitted, folder / "densities.png")]
    for space, entry in fitted["spaces"].items():
        a, b = entry["irrelevant"]
        shape, rate = entry["precision"]
        print(
            f"{space}: relevant τ ~ Gamma({shape:.3g}, {rate:.3g}) (σ̂ {np.sqrt(rate / shape):.4f});"
            f" irrelevant ρ² ~ Beta({a:.3f}, {b:.3f}); explanations' scatter {entry['scatter']};"
            f" {entry['relevant_count']} + {entry['irrelevant_count']} corrections"
        )
    return written


COMMAND = Command(
    name="relevance-fit",
    run=run_relevance_fit,
    help="fit the densities of relevant and irrelevant corrections on simulated ones",
    options=("out", "per_kind", "quick", "seed"),
    option_help={
        "out": "output folder (default results: OUT/relevance_fit, with --quick "
        "OUT/quick/relevance_fit)",
        "quick": "12 corrections per kind, into OUT/quick/",
        "seed": "the simulated corrections' seed (default: the shipped fit's)",
    },
    nothing_kept=wrote_nothing,
)
