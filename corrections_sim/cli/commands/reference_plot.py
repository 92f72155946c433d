"""``reference-plot``: the calibration figure of the exact references in a figure's folder
(its ``reference-<learner>/`` folders, written by ``reference``).

    python -m corrections_sim.run reference-plot results/fig4
"""

from __future__ import annotations

import argparse
from pathlib import Path

from corrections_sim.cli.command import Command, wrote_nothing
from corrections_sim.cli.errors import UsageError


def run_reference_plot(args: argparse.Namespace) -> list[Path]:
    """The calibration figure of the references in the folder FILE (a figure's
    ``reference-<learner>/`` folders, or collected ``<figure>-<learner>.json`` files)."""
    from corrections_sim.figures.reference_plot import calibration_figure

    if not args.study_file:
        raise UsageError("reference-plot: give the folder of the references, e.g. results/fig4")
    try:
        return [calibration_figure(Path(args.study_file))]
    except (OSError, ValueError, KeyError) as exc:
        raise UsageError(str(exc)) from None


COMMAND = Command(
    name="reference-plot",
    run=run_reference_plot,
    help="the calibration figure of the references in a figure's folder",
    options=("study_file",),
    file="DIR",
    option_help={
        "study_file": "a figure's folder with reference-<learner>/ in it, or one of "
        "collected <figure>-<learner>.json files (results/reference_posterior)"
    },
    nothing_kept=wrote_nothing,
)
