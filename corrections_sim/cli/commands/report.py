"""``report``: a learning figure's tables (final error and regret, calibration, paired
differences) from its ``summary.json``, as the docs show them
(:mod:`corrections_sim.figures.report`).

    python -m corrections_sim.run report results/fig4
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from corrections_sim.cli.command import Command
from corrections_sim.cli.errors import UsageError


def run_report(args: argparse.Namespace) -> list[Path]:
    """Print the tables of the figure folder FILE; writes nothing."""
    from corrections_sim.figures.report import report

    if not args.study_file:
        raise UsageError("report: give a finished figure's folder, e.g. results/fig4")
    folder = Path(args.study_file)
    try:
        print(report(folder))
    except FileNotFoundError:
        raise UsageError(f"{folder}: no summary.json (run the figure first)") from None
    except (KeyError, json.JSONDecodeError) as exc:
        raise UsageError(
            f"{folder}/summary.json: not a learning figure's summary ({exc})"
        ) from None
    return []


COMMAND = Command(
    name="report",
    run=run_report,
    help="print a learning figure's tables (final values, calibration, paired differences)",
    options=("study_file",),
    file="DIR",
    option_help={"study_file": "a finished learning figure's folder (its summary.json)"},
    nothing_kept=lambda args: "report stopped; it only reads (run it again)",
)
