"""Labelled corrections (issue 38): a session asks its person for corrections of a stated kind,
logs the label with each, and a replay scores the relevance-aware learners on them; the fitted
densities of ρ* and their file; the calibration metrics."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_cli_input import _main, _one_line

from corrections_sim.figures import relevance_fit
from corrections_sim.learning.base import make_learner
from corrections_sim.learning.relevance.judge import load_fit
from corrections_sim.metrics import expected_calibration_error, roc_auc, roc_auc_interval
from corrections_sim.pages.page import ask_text
from corrections_sim.people.physical import worst_cup_waypoint
from corrections_sim.scene.robot import cup_pose
from corrections_sim.session import relevance_scores
from corrections_sim.session.log import LogError, StudyLog
from corrections_sim.session.replay import replay
from corrections_sim.session.session import Session, make_asks
from corrections_sim.study.schema import parse_study

STUDY = {
    "environments": ["s0-t0-l1", "s0-t0-l2", "s1-t1-l0", "s2-t0-l1"],
    "theta_star": [1.0, -1.0],
    "learners": ["KF-C"],
    "seed": 7,
    "iterations": 4,
}


# ---- asking ---------------------------------------------------------------------------------


def test_asks_are_balanced_and_seeded():
    asks = make_asks(9, 3)
    assert asks.count("toward") == 5 and asks.count("nudge") == 4
    assert make_asks(9, 3) == asks and make_asks(9, 4) != asks
    assert make_asks(0, 3) == []
    with pytest.raises(ValueError, match="expected a count >= 0"):
        make_asks(-1, 3)


def test_the_page_says_what_is_asked():
    toward = ask_text({"kind": "toward", "preference": [1.0, -1.0]}, ("laptop", "table"))
    assert "laptop +1.0, table -1.0" in toward
    assert "for no reason" in ask_text({"kind": "nudge", "preference": None}, ("laptop",))
    pushed = ask_text({"kind": "toward", "preference": [1.0]}, ("laptop",), physical=True)
    assert "Push the cup toward where" in pushed


def _drag_toward(session: Session, kind: str, rng) -> None:
    """A correction of the asked ``kind``: the cup where the stated preference's plan has it,
    or moved as far in a random direction."""
    proposal = session.proposal()
    robot = proposal.plan.trajectory
    ideal = session.book.plan(session.preference, proposal.env).trajectory
    i, theirs = worst_cup_waypoint(robot, ideal)
    cup = cup_pose(robot[i])[1]
    move = theirs[i] - cup
    if kind == "nudge":
        direction = rng.normal(size=3)
        move = np.linalg.norm(move) * direction / np.linalg.norm(direction)
    session.submit(session.drag(i, cup + move), drag={"waypoint": i})


def test_a_labelled_session_logs_each_label_resumes_and_replays_the_scores(tmp_path):
    settings = parse_study(STUDY, name="t")
    rng = np.random.default_rng(5)
    with StudyLog(tmp_path / "s.sqlite") as log:
        session = Session.start(settings, log, learner="KF-C", asks=["toward", "nudge", "toward"])
        assert session.ask() == {"kind": "toward", "label": 1, "preference": [1.0, -1.0]}
        for _ in range(2):
            _drag_toward(session, session.ask()["kind"], rng)
        resumed = Session.resume(log, session.id)
        assert resumed.asks == ["toward", "nudge", "toward"]
        assert resumed.ask()["kind"] == "toward"
        _drag_toward(resumed, "toward", rng)
        assert resumed.ask() is None  # past the asked ones: unlabelled
        labels = log.labels(session.id)
        assert [labels[t]["label"] for t in range(3)] == [1, 0, 1]

        _, result, facts = replay(log, session.id, ["KF-C", "KF-CRP"], regret=False)
        mine = [r for r in result.records if r["learner"] == "KF-CRP"]
        assert [r.get("relevant") for r in mine] == [None, 1.0, 0.0, 1.0]
        scored = facts["labelled"]
        assert set(scored) == {"KF-CRP"}  # KF-C has no β̂ to score
        assert scored["KF-CRP"]["toward"] == 2 and scored["KF-CRP"]["nudges"] == 1
        assert 0.0 <= scored["KF-CRP"]["auc"] <= 1.0


def test_a_label_the_log_does_not_know_is_one_line(tmp_path):
    settings = parse_study(STUDY, name="t")
    with StudyLog(tmp_path / "s.sqlite") as log:
        session = Session.start(settings, log, learner="KF-C")
        log.add_event(session.id, 0, "label", {"kind": "sideways", "label": 1})
        with pytest.raises(LogError) as info:
            log.labels(session.id)
        assert "not one this log knows" in str(info.value) and "\n" not in str(info.value)
        with pytest.raises(ValueError, match="ask 'sideways'"):
            Session.start(settings, log, learner="KF-C", asks=["sideways"])
        with pytest.raises(ValueError, match="expected 2 finite weights"):
            Session.start(settings, log, learner="KF-C", asks=["toward"], preference=[1.0])


def test_the_command_line_refuses_labels_for_a_simulated_person(tmp_path, capsys):
    db = tmp_path / "s.sqlite"
    assert _main(["interact", "--headless", "--labelled", "4", "--db", str(db)]) == 2
    _one_line(capsys.readouterr().err, "--labelled", "drop --headless")
    assert not db.exists()
    argv = ["interact", "--labelled", "4", "--theta-star", "1,2,3", "--db", str(db)]
    assert _main(argv) == 2
    _one_line(capsys.readouterr().err, "--theta-star", "3 weights")
    assert not db.exists()


def test_the_committed_labelled_sessions_are_scored_held_out(tmp_path, capsys):
    """The committed log of corrections made through chromium: 40 or more, half of each kind,
    both modes; scoring it writes the table (its numbers are the docs')."""
    from pathlib import Path

    db = Path(__file__).resolve().parents[1] / "results" / "interact" / "labelled.sqlite"
    with StudyLog(db) as log:
        labels = [lab for s in log.session_ids() for lab in log.labels(s).values()]
        modes = {log.session(s).correction["name"] for s in log.session_ids()}
    assert len(labels) >= 40 and modes == {"waypoint", "physical"}
    assert sum(lab["label"] for lab in labels) == len(labels) // 2


# ---- the fit ----------------------------------------------------------------------------------


def test_the_shipped_fit_is_the_fit_of_the_committed_data():
    import csv
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    with open(root / "results" / "relevance_fit" / "data.csv", newline="") as fh:
        rows = [{**r, "relevant": int(r["relevant"])} for r in csv.DictReader(fh)]
        for r in rows:
            r |= {k: float(v) for k, v in r.items() if k.startswith(("rho_", "explained_"))}
    refit = relevance_fit.fit(rows)["spaces"]
    shipped = load_fit()
    committed = json.loads((root / "experiments" / "relevance_fit.json").read_text())["spaces"]
    for space, entry in refit.items():
        np.testing.assert_allclose(shipped[space].scatter, entry["scatter"], rtol=1e-6)
        np.testing.assert_allclose(shipped[space].precision, entry["precision"], rtol=1e-3)
        np.testing.assert_allclose(shipped[space].irrelevant, entry["irrelevant"], rtol=1e-3)
        assert committed[space]["relevant_count"] == entry["relevant_count"]


@pytest.mark.parametrize(
    "text, message",
    [
        (None, "cannot read it"),
        ("{", "not JSON"),
        ("[]", "expected an object with 'spaces'"),
        ('{"spaces": {"elbow": {}}}', "unknown space"),
        ('{"spaces": {"task": {"precision": [1, 1]}}}', "missing 'irrelevant'"),
        (
            '{"spaces": {"task": {"irrelevant": [-1, 2], "precision": [1, 1],'
            ' "scatter": [[1, 1]], "relevant_count": 1, "irrelevant_count": 1}}}',
            "Beta shapes must be finite and > 0",
        ),
        (
            '{"spaces": {"task": {"irrelevant": [1, 2], "precision": [1, 1],'
            ' "scatter": [[0.5, 1]], "relevant_count": 1, "irrelevant_count": 1}}}',
            "weights > 0 summing to 1",
        ),
        (
            '{"spaces": {"task": {"irrelevant": [1, 2], "precision": [0, 1],'
            ' "scatter": [[1, 1]], "relevant_count": 1, "irrelevant_count": 1}}}',
            "precision: Gamma shape and rate must be finite and > 0",
        ),
    ],
)
def test_a_bad_fit_file_is_one_line_naming_what_is_wrong(tmp_path, text, message):
    path = tmp_path / "fit.json"
    if text is not None:
        path.write_text(text)
    with pytest.raises(ValueError) as info:
        make_learner("KF-CRP", {"space": "task", "fit": str(path)})
    assert message in str(info.value) and "learners.KF-CRP.fit" in str(info.value)
    assert "\n" not in str(info.value)


def test_a_fit_without_the_learners_space_is_refused(tmp_path):
    path = tmp_path / "fit.json"
    entry = {
        "irrelevant": [1, 2],
        "precision": [2.0, 0.02],
        "scatter": [[0.7, 1.0], [0.3, 4.0]],
        "relevant_count": 1,
        "irrelevant_count": 1,
    }
    path.write_text(json.dumps({"spaces": {"joint": entry}}))
    with pytest.raises(ValueError, match="has no densities for space 'task'"):
        make_learner("KF-CRP", {"space": "task", "fit": str(path)})
    learner = make_learner("KF-CRP", {"fit": str(path)})
    assert learner.densities() == ((1.0, 2.0), (2.0, 0.02), ((0.7, 1.0), (0.3, 4.0)))
    assert learner.person().precision == pytest.approx(100.0)


def test_the_fit_is_maximum_likelihood():
    rng = np.random.default_rng(0)
    places = {f"explained_{s}_{j}": 0.0 for s in ("joint", "task") for j in range(2)}
    rows = [
        {"mode": "drag", "relevant": 1, "rho_task": abs(v), "rho_joint": 0.0} | places
        for v in rng.normal(0.0, 0.1, 4000)
    ] + [
        {"mode": "drag", "relevant": 0, "rho_task": float(np.sqrt(v)), "rho_joint": 0.0}
        | places
        | {"explained_task_0": e0, "explained_task_1": e1}
        for v, e0, e1 in zip(
            rng.beta(2.0, 0.8, 4000),
            rng.normal(0, 2.0, 4000),
            rng.normal(0, 2.0, 4000),
            strict=True,
        )
    ]
    entry = relevance_fit.fit(rows)["spaces"]["task"]
    shape, rate = entry["precision"]  # one precision for everyone: the Gamma has no tail
    assert np.sqrt(rate / shape) == pytest.approx(0.1, rel=0.03)
    (w1, s1), (w2, s2) = entry["scatter"]  # one scale: the parts agree, or one vanishes
    assert w1 * s1**2 + w2 * s2**2 == pytest.approx(4.0, rel=0.06)
    np.testing.assert_allclose(entry["irrelevant"], [2.0, 0.8], rtol=0.08)


# ---- calibration metrics ----------------------------------------------------------------------


def test_expected_calibration_error_and_its_bins():
    p = np.array([0.05, 0.05, 0.95, 0.95, 0.55, 0.55])
    y = np.array([0, 0, 1, 1, 1, 0])
    ece, bins = expected_calibration_error(p, y, bins=10)
    assert ece == pytest.approx((2 * 0.05 + 2 * 0.05 + 2 * 0.05) / 6)
    assert [b["count"] for b in bins] == [2, 0, 0, 0, 0, 2, 0, 0, 0, 2]
    assert bins[5]["fraction"] == 0.5


def test_the_auc_interval_brackets_the_auc_and_is_seeded():
    rng = np.random.default_rng(1)
    scores = np.r_[rng.normal(1.0, 1.0, 40), rng.normal(0.0, 1.0, 40)]
    labels = np.r_[np.ones(40), np.zeros(40)]
    low, high = roc_auc_interval(scores, labels)
    assert low < roc_auc(scores, labels) < high and high - low < 0.3
    assert roc_auc_interval(scores, labels) == (low, high)
    assert roc_auc_interval(scores, np.ones(80)) is None


def test_scores_are_per_mode_and_together():
    rows = [
        {"mode": mode, "learner": "KF-CR", "relevant": lab, "relevance": b}
        for mode in ("drag", "physical")
        for lab, b in ((1, 0.9), (1, 0.8), (0, 0.1), (0, 0.85))
    ]
    table = relevance_scores.scores(rows)
    assert set(table) == {"drag", "physical", "both"}
    assert table["drag"]["KF-CR"]["auc"] == pytest.approx(0.75)
    assert table["both"]["KF-CR"]["toward"] == 4
