"""``relevance-scores``: every labelled correction of a log replayed through the
relevance-aware learners and scored (:mod:`corrections_sim.session.relevance_scores`).

    python -m corrections_sim.run relevance-scores results/interact/labelled.sqlite
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from corrections_sim.cli.command import Command, wrote_nothing
from corrections_sim.cli.errors import UsageError


def run_relevance_scores(args: argparse.Namespace) -> list[Path]:
    """``corrections.csv`` and ``scores.json`` in OUT/relevance_page/, and the table printed."""
    from corrections_sim.figures.output import write_csv
    from corrections_sim.session.log import LogError, StudyLog
    from corrections_sim.session.relevance_scores import judged, scores

    if not args.study_file:
        raise UsageError("relevance-scores: give the log, e.g. results/interact/labelled.sqlite")
    db = Path(args.study_file)
    if not db.is_file():
        raise UsageError(f"{db}: no such file")
    rows: list[dict] = []
    try:
        with StudyLog(db) as log:
            for session_id in log.session_ids():
                if log.labels(session_id):
                    rows += judged(log, session_id)
    except (LogError, ValueError) as exc:
        raise UsageError(f"{db}: {str(exc).splitlines()[0]}") from None
    if not rows:
        raise UsageError(f"{db}: no labelled corrections")
    folder = (Path("results") if args.out is None else Path(args.out)) / "relevance_page"
    folder.mkdir(parents=True, exist_ok=True)
    written = [write_csv(folder / "corrections.csv", rows)]
    table = scores(rows)
    (folder / "scores.json").write_text(json.dumps(table, indent=1) + "\n")
    written.append(folder / "scores.json")
    print(f"{'mode':9} {'learner':15} {'AUC [95%]':>20} {'β̂ toward':>9} {'β̂ nudge':>9} {'ECE':>6}")
    for mode, learners in table.items():
        for name, s in learners.items():
            if s["auc"] is None:  # one kind only so far
                print(f"{mode:9} {name:15} {'—':>20}  ({s['toward']} + {s['nudges']})")
                continue
            low, high = s["auc_ci95"]
            print(
                f"{mode:9} {name:15} {s['auc']:.3f} [{low:.3f}, {high:.3f}] "
                f"{s['median_toward']:9.3f} {s['median_nudge']:9.3g} {s['ece']:6.3f}"
                f"  ({s['toward']} + {s['nudges']})"
            )
    return written


COMMAND = Command(
    name="relevance-scores",
    run=run_relevance_scores,
    help="score a log's labelled corrections through the relevance-aware learners",
    options=("study_file", "out"),
    file="LOG",
    option_help={
        "study_file": "a study log with labelled sessions (run interact --labelled N)",
        "out": "output folder (default results: OUT/relevance_page/)",
    },
    nothing_kept=wrote_nothing,
)
