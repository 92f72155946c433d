"""``reference``: the exact posterior beside a learner's Gaussian, for the runs of a finished
learning figure (:mod:`corrections_sim.figures.reference`).

    python -m corrections_sim.run reference results/quick/fig4 --learner KF-C --runs 2
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from corrections_sim.cli.command import Command, wrote_nothing
from corrections_sim.cli.errors import UsageError
from corrections_sim.defaults import DEFAULTS


def run_reference(args: argparse.Namespace) -> list[Path]:
    """The reference of ``--runs`` runs of ``--learner`` in the figure folder FILE: its CSV and
    JSON beside the figure's files, and the table of its means over runs printed."""
    from corrections_sim.figures.reference import judge_figure, report_lines, write_judged

    if not args.study_file:
        raise UsageError("reference: give a finished figure's folder, e.g. results/quick/fig4")
    folder = Path(args.study_file)
    restart = args.restart or ""
    try:
        restarts = tuple(sorted({int(v) for v in restart.split(",") if v.strip()}))
    except ValueError:
        raise UsageError(f"--restart {restart}: expected iterations like 0,1,4") from None
    try:
        judged = judge_figure(
            folder,
            args.learner or DEFAULTS["reference"][0],
            runs=2 if args.runs is None else args.runs,
            points=args.points,
            restarts=restarts,
            particles=args.particles or 0,
            seed=args.seed or 0,
            one_step=args.one_step,
            resolution=args.resolution,
            check_grid=args.check_grid,
            progress=lambda run: print(f"run {run}: done", file=sys.stderr, flush=True),
        )
        written = write_judged(folder, judged)
    except (OSError, KeyError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    for line in report_lines(judged, args.particles or 0):
        print(line)
    return written[:1]


COMMAND = Command(
    name="reference",
    run=run_reference,
    help="the exact posterior beside a learner's Gaussian, for a finished figure's runs",
    options=(
        "study_file",
        "learner",
        "runs",
        "points",
        "resolution",
        "one_step",
        "restart",
        "particles",
        "seed",
        "check_grid",
    ),
    file="DIR",
    option_help={
        "study_file": "a finished learning figure's folder (curves.csv, summary.json)",
        "learner": f"whose runs to judge (default {DEFAULTS['reference'][0]})",
        "runs": "how many runs (the first N; default 2)",
        "seed": "the particle reference's seed (default 0; run r uses seed + r)",
    },
    nothing_kept=wrote_nothing,
)
