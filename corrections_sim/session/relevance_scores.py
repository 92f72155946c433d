"""Relevance scored on corrections made through the page (issue 38): every labelled
correction of a log replayed through the relevance-aware learners.

    python -m corrections_sim.session.relevance_scores results/interact/labelled.sqlite

A labelled session (``python -m scripted_people.labelled``, or ``run interact
--labelled N`` with a person) asked its person, correction by correction, for a correction
toward a stated preference (label 1) or a nudge for no reason (label 0). Each such session of
the log is replayed (:func:`~corrections_sim.session.replay.replay`) through KF-CR and PP-R
(their per-correction β̂, ρ in joint space), KF-CRP in joint space and KF-CRP in task space
(``space = "task"``, the cup's path, with the shipped fit); a physical session's learners are
told that people push (``model = "physical"``). None of these corrections is in the data the
fit was made from (:mod:`~corrections_sim.figures.relevance_fit` fits simulated corrections),
so every score is held out.

Writes ``corrections.csv`` (per correction and learner: β̂, ρ, the label) and
``scores.json`` (per mode and learner: ROC AUC with its 95% bootstrap interval, median β̂ of
each label, the expected calibration error) in ``OUT/relevance_page/``, and prints the table.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from corrections_sim.figures.output import write_csv
from corrections_sim.metrics import label_scores

#: (row name, registered learner, its parameters) of each learner scored.
VARIANTS = (
    ("KF-CR", "KF-CR", {}),
    ("PP-R", "PP-R", {"fixed_alpha": 0.05}),
    ("KF-CRP (joint)", "KF-CRP", {}),
    ("KF-CRP (task)", "KF-CRP", {"space": "task"}),
)


def judged(log, session_id: int) -> list[dict]:
    """Every labelled correction of one session, judged by each variant (rows)."""
    from corrections_sim.session.replay import replay

    row = log.session(session_id)
    physical = row.correction.get("name") == "physical"
    mode = "physical" if physical else "drag"
    out = []
    for name, learner, params in VARIANTS:
        given = dict(params) | ({"model": "physical"} if physical else {})
        _, result, _ = replay(log, session_id, [learner], regret=False, params={learner: given})
        for r in result.records:
            if r["learner"] != learner or "relevant" not in r or r.get("relevance") is None:
                continue
            out.append(
                {
                    "session": session_id,
                    "mode": mode,
                    "learner": name,
                    "iteration": r["iteration"],
                    "relevant": int(r["relevant"]),
                    "relevance": float(r["relevance"]),
                    "residual": r.get("relevance_residual"),
                }
            )
    return out


def scores(rows: list[dict]) -> dict:
    """Per mode (and both together) and learner: :func:`~corrections_sim.metrics.label_scores`
    (AUC and its interval, medians, ECE, counts)."""
    out: dict = {}
    for mode in ("drag", "physical", "both"):
        for name, _, _ in VARIANTS:
            mine = [
                r for r in rows if r["learner"] == name and (mode == "both" or r["mode"] == mode)
            ]
            if mine:
                out.setdefault(mode, {})[name] = label_scores(
                    [r["relevance"] for r in mine], [r["relevant"] for r in mine]
                )
    return out


def main(argv: list[str] | None = None) -> int:
    from corrections_sim.session.log import LogError, StudyLog

    p = argparse.ArgumentParser(
        prog="python -m corrections_sim.session.relevance_scores",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("db", type=Path, help="a log with labelled sessions")
    p.add_argument("--out", type=Path, default=Path("results"))
    args = p.parse_args(argv)
    if not args.db.is_file():
        print(f"error: {args.db}: no such file", file=sys.stderr)
        return 2
    rows: list[dict] = []
    try:
        with StudyLog(args.db) as log:
            for session_id in log.session_ids():
                if log.labels(session_id):
                    rows += judged(log, session_id)
    except (LogError, ValueError) as exc:
        print(f"error: {args.db}: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    if not rows:
        print(f"error: {args.db}: no labelled corrections", file=sys.stderr)
        return 2
    folder = args.out / "relevance_page"
    folder.mkdir(parents=True, exist_ok=True)
    print(f"wrote {write_csv(folder / 'corrections.csv', rows)}")
    table = scores(rows)
    (folder / "scores.json").write_text(json.dumps(table, indent=1) + "\n")
    print(f"wrote {folder / 'scores.json'}")
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
