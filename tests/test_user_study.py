"""A user study from a protocol: the protocol file, counterbalancing, the participant's state
machine over the study log (resume, withdraw, answers once), the simulated cohort, and the
analysis across people."""

from __future__ import annotations

import itertools
import json
import math
import tomllib

import numpy as np
import pytest

from corrections_sim.interact.cohort import open_run, power_table, simulate_cohort
from corrections_sim.interact.log import StudyError, StudyLog
from corrections_sim.interact.participant import StudyRun, simulate_participant
from corrections_sim.interact.study_report import analyze, protocol_of, tidy
from corrections_sim.study import user_study
from corrections_sim.study.protocol import balance, latin_square, load_protocol, parse_protocol

#: A short protocol: a practice of one correction, two conditions of two corrections each.
SHORT = """
description = "two robots, briefly"
study = "fig4"
seed = 3
corrections = 2
primary = "mean_regret"
welcome = "Hello."
[practice]
learner = "KF"
corrections = 1
[[conditions]]
name = "C"
learner = "KF-C"
instructions = "Robot one."
[[conditions]]
name = "CL"
learner = "KF-CL"
[[questionnaires.condition]]
id = "understood"
text = "The robot understood me."
points = 5
[[questionnaires.condition]]
kind = "tlx"
[[questionnaires.end]]
id = "comments"
kind = "text"
text = "Anything else?"
[simulation]
mean = [1.0, -1.0]
sd = [0.3, 0.3]
user = { name = "noisy", noise = 0.5 }
[simulation.responses.default]
intercept = 4.0
slope = -0.5
"""


@pytest.fixture
def short(tmp_path):
    path = tmp_path / "protocol.toml"
    path.write_text(SHORT)
    return path


def values(**changes):
    out = tomllib.loads(SHORT)
    out.update(changes)
    return out


# --- counterbalancing ---------------------------------------------------------------------


@pytest.mark.parametrize("n", range(1, 9))
def test_the_square_puts_every_condition_at_every_position_and_after_every_other_equally(n):
    rows = latin_square(n)
    assert len(rows) == (n if n % 2 == 0 or n == 1 else 2 * n)
    for row in rows:
        assert sorted(row) == list(range(n))
    positions, carry = balance([tuple(map(str, r)) for r in rows])
    assert np.all(positions == positions[0, 0])
    off = carry[~np.eye(n, dtype=bool)]
    assert np.all(off == off.max(initial=0)) and np.all(np.diag(carry) == 0)


@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_participants_over_any_multiple_of_the_square_are_balanced(n):
    conditions = [{"name": f"c{i}", "learner": "KF"} for i in range(n)]
    protocol = parse_protocol(values(conditions=conditions))
    size = len(protocol.square())
    for multiple in (1, 2, 3):
        orders = [protocol.order_of(i) for i in range(multiple * size)]
        positions, carry = balance(orders)
        assert np.all(positions == multiple * size // n)
        off = carry[~np.eye(n, dtype=bool)]
        assert np.all(off == off[0])
    # Reproducible from the index and the seed; another seed shuffles the rows.
    again = parse_protocol(values(conditions=conditions))
    assert [again.order_of(i) for i in range(size)] == [protocol.order_of(i) for i in range(size)]
    if n > 2:
        other = parse_protocol(values(conditions=conditions, seed=4))
        assert [other.order_of(i) for i in range(size)] != [
            protocol.order_of(i) for i in range(size)
        ]


def test_a_fixed_order_is_the_same_for_everyone():
    protocol = parse_protocol(values(order="fixed"))
    assert {protocol.order_of(i) for i in range(5)} == {("C", "CL")}


# --- the protocol file's errors -------------------------------------------------------------


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            {"conditions": [{"name": "A", "learner": "KF-X"}]},
            "conditions[0].learner: unknown learner 'KF-X'",
        ),
        (
            {"questionnaires": {"condition": [{"id": "q", "text": "?", "points": 12}]}},
            "questionnaires.condition[0].points = 12: a Likert scale has 2 to 11 points",
        ),
        (
            {"questionnaires": {"condition": [{"id": "q", "text": "?", "points": 1}]}},
            "a Likert scale has 2 to 11 points",
        ),
        (
            {"conditions": [{"name": "A", "learner": "KF"}, {"name": "A", "learner": "KF-C"}]},
            "conditions: the name 'A' is used twice",
        ),
        ({"order": "random"}, "order = 'random': expected one of williams, fixed"),
        ({"colour": "red"}, "colour: unknown key"),
        (
            {"conditions": [{"name": "A", "learner": "KF", "mode": "fly"}]},
            "conditions[0].mode = 'fly'",
        ),
        ({"primary": "joy"}, "primary = 'joy'"),
    ],
)
def test_a_bad_protocol_is_one_line_naming_the_key(change, message):
    with pytest.raises(ValueError) as caught:
        parse_protocol(values(**change))
    text = str(caught.value)
    assert message in text and "\n" not in text


def test_the_example_protocol_parses_and_its_study_keys_are_checked(tmp_path):
    from corrections_sim.figures.presets import EXPERIMENTS_DIR

    protocol = load_protocol(EXPERIMENTS_DIR / "protocol.toml")
    assert protocol.names == ("C", "CL") and protocol.simulation is not None
    bad = tmp_path / "bad.toml"
    bad.write_text(SHORT.replace('name = "CL"', 'name = "CL"\nset = { runz = 3 }'))
    with pytest.raises(ValueError, match=r"conditions\[1\]\.set: runz: unknown key"):
        open_run(bad, tmp_path / "bad.sqlite")


# --- the participant's state machine over the log ---------------------------------------------


def test_a_used_code_is_refused_and_an_answer_posted_twice_keeps_the_first(short, tmp_path):
    db = tmp_path / "study.sqlite"
    run = open_run(short, db)
    person, token = run.enroll("P01")
    assert run.by_token(token).code == "P01"
    assert run.by_token(token[:-1] + ("A" if token[-1] != "A" else "B")) is None
    with pytest.raises(StudyError, match="participant P01: the code is already used"):
        run.enroll("P01")
    assert run.log.meta("protocol_sha256") and token not in db.read_bytes().decode("latin-1")
    with pytest.raises(StudyError, match="at step welcome"):
        person.answer({"understood": 3})
    assert person.proceed("welcome").key == "practice"
    with pytest.raises(StudyError, match="at step practice"):
        person.proceed("welcome")  # a stale click of the welcome's button


def test_a_simulated_participant_goes_through_and_a_crash_resumes_at_the_same_step(short, tmp_path):
    db = tmp_path / "study.sqlite"
    run = open_run(short, db)
    person, _ = run.enroll("P01")
    person.proceed("welcome")
    session = person.session("practice")
    from corrections_sim.interact.session import simulate
    from corrections_sim.people.users import make_user

    simulate(session, make_user("noisy", {"noise": 0.5}), [1.0, -1.0], 1)
    person.finish_trial("practice")
    order = run.protocol.order_of(0)
    step = person.current()
    if step.kind == "instructions":
        step = person.proceed(step.key)
    assert step.key == f"{order[0]}.trial1"
    session = person.session(step.key)
    simulate(session, make_user("noisy", {"noise": 0.5}), [1.0, -1.0], 1)
    with pytest.raises(StudyError, match="has 1 of 2 corrections"):
        person.finish_trial(step.key)
    first_theta = session.belief.theta.copy()
    run.log.close()
    # The server dies here; a new one opens the log and finds the participant mid-trial.
    run = open_run(short, db)
    person = run.participant("P01")
    assert person.current().key == step.key
    resumed = person.session(step.key)
    assert resumed.id == session.id and resumed.iteration == 1
    np.testing.assert_array_equal(resumed.belief.theta, first_theta)
    simulate(resumed, make_user("noisy", {"noise": 0.5}), [1.0, -1.0], 1)
    step = person.finish_trial(step.key)
    assert step.key == f"{order[0]}.questions"
    answers = {
        "understood": 4,
        **{
            f"tlx.{s}": 50
            for s in ("mental", "physical", "temporal", "performance", "effort", "frustration")
        },
    }
    with pytest.raises(ValueError, match="understood: expected a whole number 1-5"):
        person.answer({**answers, "understood": 6})
    with pytest.raises(ValueError, match=r"tlx\.mental: not answered"):
        person.answer({k: v for k, v in answers.items() if k != "tlx.mental"})
    assert person.answer(answers, step.key).key != step.key
    with pytest.raises(StudyError, match="posted twice"):
        run.log.finish_step("P01", person.steps.index(step), step.key, {"understood": 1})
    assert [a["value"] for a in run.log.answers("P01") if a["item"] == "understood"] == [4]
    run.log.close()


def test_a_log_of_one_protocol_refuses_another(short, tmp_path):
    db = tmp_path / "study.sqlite"
    open_run(short, db).log.close()
    other = tmp_path / "other.toml"
    other.write_text(SHORT.replace("seed = 3", "seed = 5"))
    with pytest.raises(ValueError, match="belongs to another protocol"):
        open_run(other, db)


def test_a_cohort_analysed_says_it_is_simulated_and_leaves_out_the_withdrawn(short, tmp_path):
    db = tmp_path / "study.sqlite"
    run = open_run(short, db)
    assert simulate_cohort(run, range(5)) == 5
    run.withdraw("sim00004")
    run.log.close()
    # The same participant in another log (another worker's shard) is the same numbers.
    other = open_run(short, tmp_path / "shard.sqlite")
    simulate_cohort(other, [1])
    with StudyLog(db) as log, StudyLog(tmp_path / "shard.sqlite") as shard:
        mine = [t for t in tidy(log)["trials"] if t["participant"] == "sim00001"]
        theirs = tidy(shard)["trials"]
        assert [t["final_error"] for t in mine] == [t["final_error"] for t in theirs]
        assert [t["mean_regret"] for t in mine] == [t["mean_regret"] for t in theirs]
    other.log.close()
    out = tmp_path / "analysis"
    paths = analyze(db, out)
    assert {p.name for p in paths} >= {
        "trials.csv",
        "answers.csv",
        "corrections.csv",
        "summary.json",
        "report.md",
        "participants.png",
    }
    summary = json.loads((out / "summary.json").read_text())
    assert summary["simulated"] and summary["participants"] == 4
    assert summary["excluded"]["withdrawn"] == ["sim00004"]
    report = (out / "report.md").read_text()
    assert "Simulated participants" in report
    trials = (out / "trials.csv").read_text().splitlines()
    assert len(trials) == 1 + 4 * 2  # four participants, two conditions, the practice out
    # Four participants, both orders twice: the period is balanced, and the model's effect
    # is the paired difference.
    mixed = summary["outcomes"]["mean_regret"]["mixed"]
    paired = summary["outcomes"]["mean_regret"]["paired"][0]
    assert mixed["effects"][0]["estimate"] == pytest.approx(paired["mean"], abs=1e-6)
    # Deleted on request: nothing of theirs is left but the emptied code.
    with StudyLog(db) as log:
        run = StudyRun(protocol_of(log), log, open_run(short, tmp_path / "x.sqlite").settings_of)
        run.withdraw("sim00002", delete=True)
        assert log.answers("sim00002") == [] and log.steps("sim00002") == []
        assert all(log.session(s).participant != "sim00002" for s in log.session_ids())
        with pytest.raises(StudyError, match="already used"):
            run.enroll("sim00002")


# --- the analysis -------------------------------------------------------------------------------


def synthetic(rng, n, effect, between=1.0, within=0.5):
    rows = []
    for p in range(n):
        u = between * rng.standard_normal()
        order = ("A", "B") if p % 2 == 0 else ("B", "A")
        for period, c in enumerate(order, 1):
            y = u + (effect if c == "B" else 0.0) + within * rng.standard_normal()
            rows.append(
                {"participant": f"p{p}", "index": p, "condition": c, "period": period, "y": y}
            )
    return rows


def test_the_mixed_model_t_interval_covers_a_known_effect_at_its_level():
    rng = np.random.default_rng(7)
    covered = []
    for _ in range(300):
        fit = user_study.mixed_model(synthetic(rng, 12, 0.4), "y", ["A", "B"])
        effect = fit["effects"][0]
        assert effect["df"] == 12 * 2 - 12 - 2
        covered.append(effect["lo"] <= 0.4 <= effect["hi"])
    # 300 studies: a true 95% gives 0.925-0.975 with probability 0.99.
    assert 0.925 <= np.mean(covered) <= 0.975


def test_power_grows_with_the_study_size_and_reports_the_n_for_80_percent():
    rng = np.random.default_rng(8)
    pool = synthetic(rng, 480, 0.5)
    table = power_table(pool, ["A", "B"], [4, 8, 16, 24, 40], outcome="y")
    powers = [s["power"] for s in table["sizes"]]
    assert powers[0] < powers[-1] and powers[-1] > 0.8
    assert table["n_for_80"] is not None and 4 < table["n_for_80"] <= 40
    assert table["difference"] == pytest.approx(0.5, abs=0.1)
    assert math.isfinite(table["d_z"])


def test_the_paired_comparison_is_each_participants_difference():
    rows = [
        {"participant": p, "condition": c, "y": y}
        for p, (a, b) in enumerate([(1.0, 2.0), (2.0, 2.5), (0.0, 1.5)])
        for c, y in (("A", a), ("B", b))
    ]
    (pair,) = user_study.paired(rows, "y", ["A", "B"])
    assert pair["mean"] == pytest.approx(1.0) and pair["n"] == 3
    assert pair["d_z"] == pytest.approx(1.0 / np.std([1.0, 0.5, 1.5], ddof=1))


def test_simulated_participants_are_deterministic_functions_of_their_index(short, tmp_path):
    protocol = load_protocol(short)
    from corrections_sim.interact.participant import draw_simulated

    a = [draw_simulated(protocol, i, 2)["theta_star"] for i in range(3)]
    b = [draw_simulated(protocol, i, 2)["theta_star"] for i in range(3)]
    assert a == b and len({tuple(x) for x in a}) == 3
    assert list(itertools.chain(*a)) != [1.0, -1.0] * 3


def test_a_person_is_not_simulated(short, tmp_path):
    run = open_run(short, tmp_path / "study.sqlite")
    run.enroll("P01")
    with pytest.raises(StudyError, match="a person, not a simulated participant"):
        simulate_participant(run, "P01")
    run.log.close()


def test_an_aborted_trial_starts_over_and_its_session_leaves_the_analysis(short, tmp_path):
    from corrections_sim.interact.session import simulate
    from corrections_sim.people.users import make_user

    db = tmp_path / "study.sqlite"
    run = open_run(short, db)
    person, _ = run.enroll("P01")
    person.proceed("welcome")
    user = make_user("noisy", {"noise": 0.5})
    first = person.session("practice")
    simulate(first, user, [1.0, -1.0], 1)
    aborted = person.abort_trial()
    assert aborted == first.id and run.log.session(first.id).ended is not None
    assert run.log.events(first.id, "aborted")
    again = person.session("practice")
    assert again.id != first.id and again.iteration == 0
    simulate(again, user, [1.0, -1.0], 1)
    person.finish_trial("practice")
    assert run.log.steps("P01")[1]["aborted"] == [first.id]
    with pytest.raises(StudyError, match="at step"):
        person.abort_trial()  # not at a trial now
    run.log.close()
    with StudyLog(db) as log:
        assert tidy(log)["excluded"]["aborted_trials"] == 1


def test_a_simulated_participant_pushes_in_a_physical_condition_and_drags_in_the_other(
    tmp_path,
):
    path = tmp_path / "protocol.toml"
    path.write_text(
        'study = "fig4"\nseed = 1\ncorrections = 1\n'
        '[[conditions]]\nname = "P"\nlearner = "KF-C"\nmode = "physical"\n'
        '[[conditions]]\nname = "D"\nlearner = "KF-C"\n'
        "[simulation]\nmean = [1.0, -1.0]\n"
    )
    run = open_run(path, tmp_path / "study.sqlite")
    simulate_cohort(run, [0])
    person = run.participant("sim00000")
    assert person.where().step.kind == "end"
    by_condition = {step.condition: sid for step, sid in person.trial_sessions()}
    physical = run.log.corrections(by_condition["P"])[0]["drag"]
    dragged = run.log.corrections(by_condition["D"])[0]["drag"]
    assert physical["simulated"] and "released_at" in physical  # a push, let go of
    assert dragged == {"simulated": True}
    assert run.log.session(by_condition["P"]).correction["name"] == "physical"
    run.log.close()
