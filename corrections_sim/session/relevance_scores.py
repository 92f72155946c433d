"""Relevance scored on corrections made through the page (issue 38): every labelled
correction of a log replayed through the relevance-aware learners.

    python -m corrections_sim.run relevance-scores results/interact/labelled.sqlite

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
