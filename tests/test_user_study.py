"""A user study from a protocol: the protocol file, counterbalancing, the participant's state
machine over the study log (resume, withdraw, answers once), the simulated cohort, and the
analysis across people."""

from __future__ import annotations

import itertools
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from corrections_sim.figures.presets import EXPERIMENTS_DIR
from corrections_sim.planning.planner import shared_planner, smoothness_cost
from corrections_sim.plans.book import PlanBook
from corrections_sim.session.log import StudyError, StudyLog
from corrections_sim.study import schema
from corrections_sim.userstudy import statistics
from corrections_sim.userstudy.cohort import open_run, power_table, simulate_cohort
from corrections_sim.userstudy.participant import StudyRun, experienced, simulate_participant
from corrections_sim.userstudy.protocol import (
    TLX_SCALES,
    balance,
    latin_square,
    load_protocol,
    parse_protocol,
)
from corrections_sim.userstudy.report import analyze, protocol_of, tidy

#: A short protocol: a practice of one correction, two conditions of two corrections each.
SHORT = """
description = "two robots, briefly"
study = "fig4-small.toml"
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


def write_study(folder: Path) -> Path:
    """Fig. 4's study file with its plan atlas at 3 points a weight, as ``fig4-small.toml`` in
    ``folder``: the protocol's mechanics are under test here, not the atlas (at the preset's
    31 points a new machine builds one per environment a participant meets, 10-20 s each: a
    cohort of five took five minutes of the suite)."""
    text = (EXPERIMENTS_DIR / "fig4.toml").read_text()
    assert "\natlas = true\n" in text, "fig4.toml no longer says atlas = true"
    path = folder / "fig4-small.toml"
    path.write_text(text.replace("\natlas = true\n", "\natlas = { points = 3 }\n", 1))
    return path


@pytest.fixture
def short(tmp_path):
    write_study(tmp_path)
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
        (
            {"conditions": [{"name": "A", "learner": "KF", "instructions": "**Robot 2.** Go."}]},
            "conditions[0].instructions: names a robot by number ('Robot 2')",
        ),
        ({"min_corrections": 3}, "min_corrections = 3"),
        ({"min_participants": 1}, "min_participants = 1"),
        (
            {"questionnaires": {"end": [{"id": "q", "text": "?", "compare": "yes"}]}},
            "questionnaires.end[0].compare = 'yes': expected true or false",
        ),
        (
            {"questionnaires": {"condition": [{"id": "q", "text": "?", "compare": True}]}},
            "questionnaires.condition[0].compare: an item after one condition cannot compare",
        ),
    ],
)
def test_a_bad_protocol_is_one_line_naming_the_key(change, message):
    with pytest.raises(ValueError) as caught:
        parse_protocol(values(**change))
    text = str(caught.value)
    assert message in text and "\n" not in text


def test_the_example_protocol_parses_and_its_study_keys_are_checked(tmp_path):
    protocol = load_protocol(EXPERIMENTS_DIR / "protocol.toml")
    assert protocol.names == ("C", "M") and protocol.simulation is not None
    write_study(tmp_path)
    bad = tmp_path / "bad.toml"
    bad.write_text(SHORT.replace('name = "CL"', 'name = "CL"\nset = { runz = 3 }'))
    with pytest.raises(ValueError, match=r"conditions\[1\]\.set: runz: unknown key"):
        open_run(bad, tmp_path / "bad.sqlite")


def test_a_conditions_text_names_the_robot_by_the_participants_own_order():
    protocol = parse_protocol(
        values(
            conditions=[
                {"name": "C", "learner": "KF-C", "instructions": "Robot {robot} of {robots}."},
                {"name": "CL", "learner": "KF-CL", "instructions": "Robot {robot} of {robots}."},
            ]
        )
    )
    for index in range(4):
        order = protocol.order_of(index)
        texts = {s.condition: s.text for s in protocol.steps(index) if s.kind == "instructions"}
        assert texts[order[0]] == "Robot 1 of 2." and texts[order[1]] == "Robot 2 of 2."


def test_the_prose_may_be_corrected_but_not_the_design(short, tmp_path):
    db = tmp_path / "study.sqlite"
    run = open_run(short, db)
    run.enroll("P01")
    run.log.close()
    reworded = tmp_path / "reworded.toml"
    reworded.write_text(
        SHORT.replace('welcome = "Hello."', 'welcome = "Hello, and thank you."').replace(
            '"The robot understood me."', '"The robot understood what I wanted."'
        )
    )
    run = open_run(reworded, db)  # the same design: adopted, the earlier wording kept
    assert "thank you" in json.loads(run.log.meta("protocol"))["welcome"]
    assert json.loads(run.log.meta("protocol_versions"))[0]["source"]["welcome"] == "Hello."
    assert run.participant("P01").index == 0
    run.log.close()
    changed = tmp_path / "changed.toml"
    changed.write_text(SHORT.replace("corrections = 2\n", "corrections = 3\n", 1))
    with pytest.raises(ValueError, match="belongs to another protocol") as caught:
        open_run(changed, db)
    assert "\n" not in str(caught.value)


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
    from corrections_sim.people.users import make_user
    from corrections_sim.session.simulate import simulate

    simulate(session, make_user("noisy", {"noise": 0.5}), [1.0, -1.0], 1)
    person.finish_trial("practice")
    order = run.protocol.order_of(0)
    step = person.current()
    if step.kind == "instructions":
        step = person.proceed(step.key)
    assert step.key == f"{order[0]}.trial1"
    session = person.session(step.key)
    simulate(session, make_user("noisy", {"noise": 0.5}), [1.0, -1.0], 1)
    with pytest.raises(StudyError, match="has 1 of the 2 corrections it needs"):
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


def test_a_trial_s_regret_is_the_planner_s_full_objective_never_below_zero(tmp_path):
    # A robot that shows the plan of 3 θ* buys more of θ*'s features than θ*'s own plan with a
    # less smooth path: θ*·Φ alone calls that negative regret (the committed pilot had a trial
    # at -0.49); under θ*·Φ − λS, what the planner maximizes for the person, it costs them.
    settings = schema.load_study(write_study(tmp_path), name="fig4-small", quick=False)
    book = PlanBook(shared_planner(settings.planner_config()), atlas=settings.atlas())
    lam = book.planner.config.smoothness
    theta = np.array([1.0, -1.0])
    env = settings.envs()[0]
    star, robot = book.plan(theta, env), book.plan(3 * theta, env)
    row = {"env_index": 0, "phi_robot": robot.features, "xi_robot": robot.trajectory}
    felt = experienced(settings, [{**row, "theta_after": theta}], theta)
    assert theta @ (star.features - robot.features) < -1.0  # θ*·Φ's regret
    full = star.reward - (theta @ robot.features - lam * smoothness_cost(robot.trajectory))
    assert felt["regret"] == pytest.approx(full, abs=1e-9) and full > 1.0
    assert felt["error"] == 0.0


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
        assert min(t["mean_regret"] for t in tidy(log)["trials"]) >= 0.0
        # An event of the features-only regret (a log or pool made before it was the full
        # objective) is not read: the analysis gives today's measure.
        first = tidy(log)["trials"][0]
        log.add_event(first["session"], 2, "experienced", {"regret": -99.0, "error": 0.0})
        assert tidy(log)["trials"][0]["mean_regret"] == first["mean_regret"] >= 0.0
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
    # Four participants, fewer than min_participants (6): descriptive only, said at the top,
    # no interval, test or model in the summary or the report.
    assert summary["descriptive_only"] and summary["min_participants"] == 6
    assert "Descriptive only" in report and "| p |" not in report and "95% CI" not in report
    entry = summary["outcomes"]["mean_regret"]
    assert not entry["mixed"]["reported"] and "p" not in entry["paired"][0]
    assert all("lo" not in row for row in entry["summary"])
    # The model itself, on the same rows: both orders twice, so the period is balanced and
    # its effect is the paired difference.
    with StudyLog(db) as log:
        rows = tidy(log)["trials"]
    mixed = statistics.mixed_model(rows, "mean_regret", ["C", "CL"])
    assert mixed["effects"][0]["estimate"] == pytest.approx(entry["paired"][0]["mean"], abs=1e-6)
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
        fit = statistics.mixed_model(synthetic(rng, 12, 0.4), "y", ["A", "B"])
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
    (pair,) = statistics.paired(rows, "y", ["A", "B"])
    assert pair["mean"] == pytest.approx(1.0) and pair["n"] == 3
    assert pair["d_z"] == pytest.approx(1.0 / np.std([1.0, 0.5, 1.5], ddof=1))


def test_simulated_participants_are_deterministic_functions_of_their_index(short, tmp_path):
    protocol = load_protocol(short)
    from corrections_sim.userstudy.participant import draw_simulated

    a = [draw_simulated(protocol, i, 2)["theta_star"] for i in range(3)]
    b = [draw_simulated(protocol, i, 2)["theta_star"] for i in range(3)]
    assert a == b and len({tuple(x) for x in a}) == 3
    assert list(itertools.chain(*a)) != [1.0, -1.0] * 3


def test_codes_are_read_without_regard_to_case(short, tmp_path):
    run = open_run(short, tmp_path / "study.sqlite")
    run.enroll("P01")
    with pytest.raises(StudyError, match="P01 is enrolled already"):
        run.enroll("p01")
    run.log.close()


def _to_questions(run, code: str, corrections: int | None = None):
    """``code`` enrolled and through the welcome, the practice and their first robot's trial
    (``corrections`` of it: all by default, then finished) by a simulated user."""
    from corrections_sim.people.users import make_user
    from corrections_sim.session.simulate import simulate

    user = make_user("noisy", {"noise": 0.5})
    person, _ = run.enroll(code)
    person.proceed("welcome")
    simulate(person.session("practice"), user, [1.0, -1.0], 1)
    person.finish_trial("practice")
    step = person.current()
    if step.kind == "instructions":
        step = person.proceed(step.key)
    session = person.session(step.key)
    simulate(session, user, [1.0, -1.0], corrections or person.corrections(step))
    return person, step


def test_a_trial_ends_when_it_has_its_minimum_or_the_participant_stops_it(short, tmp_path):
    db = tmp_path / "study.sqlite"
    run = open_run(short, db)
    person, step = _to_questions(run, "P01", corrections=1)
    with pytest.raises(StudyError, match="has 1 of the 2 corrections it needs"):
        person.finish_trial(step.key)
    after = person.stop_trial(step.key)  # "Stop this trial early", confirmed on the page
    assert after.kind == "questions"
    events = run.log.participant_events("P01", "stopped")
    assert events[0]["detail"] == {"step": step.key, "corrections": 1, "by": "participant"}
    person.leave()  # "Leave the study"
    assert run.log.participant("P01")["withdrawn"] is not None
    assert run.log.participant_events("P01", "withdrew")[0]["detail"] == {"by": "participant"}
    other, step = _to_questions(run, "P02", corrections=1)
    other.stop_trial(step.key)
    run.log.close()
    with StudyLog(db) as log:
        tables = tidy(log)
    assert tables["excluded"]["withdrew_themselves"] == ["P01"]
    assert tables["excluded"]["ended_early_trials"] == 1
    (trial,) = tables["trials"]
    assert trial["ended_early"] and trial["stopped_by_participant"] and trial["corrections"] == 1


def test_an_optional_item_left_blank_is_missing_and_every_answer_keeps_its_question(
    short, tmp_path
):
    db = tmp_path / "study.sqlite"
    run = open_run(short, db)
    person, step = _to_questions(run, "P01")
    step = person.finish_trial(step.key)
    tlx = {f"tlx.{s}": 5 * i for i, s in enumerate(TLX_SCALES)}
    person.answer({"understood": 3, **tlx}, step.key)
    asked = run.log.asked("P01")
    assert asked[("P01", step.key, "understood")]["text"] == "The robot understood me."
    assert asked[("P01", step.key, "tlx.performance")]["anchors"] == ["Perfect", "Failure"]
    # The end's free text is optional: left blank, it is missing (no row), never "".
    while person.current().kind != "questions" or person.current().key != "end.questions":
        current = person.current()
        if current.kind == "instructions":
            person.proceed(current.key)
        elif current.kind == "trial":
            from corrections_sim.people.users import make_user
            from corrections_sim.session.simulate import simulate

            session = person.session(current.key)
            simulate(session, make_user("noisy", {"noise": 0.5}), [1.0, -1.0], 2)
            person.finish_trial(current.key)
        else:
            person.answer({"understood": 4, **tlx}, current.key)
    person.answer({"comments": ""}, "end.questions")
    assert not [a for a in run.log.answers("P01") if a["item"] == "comments"]
    run.log.close()


def test_a_person_is_not_simulated(short, tmp_path):
    run = open_run(short, tmp_path / "study.sqlite")
    run.enroll("P01")
    with pytest.raises(StudyError, match="a person, not a simulated participant"):
        simulate_participant(run, "P01")
    run.log.close()


def test_an_aborted_trial_starts_over_and_its_session_leaves_the_analysis(short, tmp_path):
    from corrections_sim.people.users import make_user
    from corrections_sim.session.simulate import simulate

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
    write_study(tmp_path)
    path = tmp_path / "protocol.toml"
    path.write_text(
        'study = "fig4-small.toml"\nseed = 1\ncorrections = 1\n'
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


# --- what the report refuses to say ------------------------------------------------------------


def _tables(protocol, trials, answers=(), comparisons=()):
    people = sorted({t["participant"] for t in trials})
    excluded = {"withdrawn": [], "aborted_trials": 0, "unfinished_trials": 0}
    return {
        "protocol": protocol,
        "participants": people,
        "corrections": [],
        "trials": list(trials),
        "answers": list(answers),
        "comparisons": list(comparisons),
        "excluded": excluded,
        "simulated": False,
    }


def _trial(code, condition, period, regret, error=0.3):
    return {
        "participant": code,
        "condition": condition,
        "period": period,
        "mean_regret": regret,
        "final_error": error,
        "seconds": 5.0,
        "ended_early": False,
    }


def test_two_people_get_a_descriptive_report_with_the_end_preference_mapped_to_conditions():
    from corrections_sim.userstudy.report import analyse, compared, report, strict_json

    protocol = parse_protocol(
        values(
            questionnaires={
                "end": [
                    {"id": "prefer", "text": "Which?", "points": 5, "compare": True},
                    {"id": "comments", "kind": "text", "text": "Else?"},
                ]
            }
        )
    )
    # P1 met C then CL and answered 5 (the second); P2 met CL then C and answered 1 (the
    # first): both preferred CL.
    trials = [_trial("P1", "C", 1, 1.0), _trial("P1", "CL", 2, 4.0)]
    trials += [_trial("P2", "CL", 1, 2.0), _trial("P2", "C", 2, 1.5)]
    comparisons = [
        compared("P1", "prefer", 5, 5, ("C", "CL")),
        compared("P2", "prefer", 1, 5, ("CL", "C")),
    ]
    assert [c["preferred"] for c in comparisons] == ["CL", "CL"]
    assert [c["score"] for c in comparisons] == [2.0, 2.0]
    text = {"participant": "P2", "item": "comments", "kind": "text", "condition": ""}
    answers = [{**text, "value": "<script>x</script> **great** | 10/10\n# yes"}]
    tables = _tables(protocol, trials, answers, comparisons)
    result = analyse(tables)
    assert result["descriptive_only"]
    assert result["comparisons"]["prefer"]["preferred"] == {"C": 0, "CL": 2}
    for entry in result["outcomes"].values():
        assert not entry["mixed"]["reported"]
        assert all("p" not in row and "lo" not in row for row in entry["paired"])
    json.dumps(strict_json(result), allow_nan=False)  # strict JSON: no NaN token
    md = report(tables, result, Path("study.sqlite"))
    assert "Descriptive only" in md and "| p |" not in md and "95% CI" not in md
    assert "| prefer | C 0, CL 2 | 0 | CL |" in md
    line = next(x for x in md.splitlines() if x.startswith("- P2"))
    assert "<script>" not in line and "&lt;script&gt;" in line
    assert "\\*\\*great\\*\\*" in line and "\\|" in line and "\\#" in line


def test_a_saturated_model_is_no_result_and_the_report_says_why():
    from corrections_sim.userstudy.report import analyse, report

    protocol = parse_protocol(values(min_participants=2))
    trials = [_trial("P1", "C", 1, 1.0), _trial("P1", "CL", 2, 4.0)]
    trials += [_trial("P2", "CL", 1, 2.0), _trial("P2", "C", 2, 1.5)]
    fit = statistics.mixed_model(trials, "mean_regret", ["C", "CL"])
    assert not fit["reported"] and fit["why"].startswith("saturated")
    tables = _tables(protocol, trials)
    md = report(tables, analyse(tables), Path("study.sqlite"))
    assert "| mean_regret | not reported: saturated" in md
    assert "[-3.000, -3.000]" not in md and "0.000 |" not in md.split("## Paired")[0]


def test_a_singular_fit_is_no_result():
    # Every participant's mean is the same: no variance between them, the fit's boundary.
    rng = np.random.default_rng(3)
    rows = []
    for p in range(12):
        d = rng.normal()
        order = ("A", "B") if p % 2 else ("B", "A")
        for period, c in enumerate(order, 1):
            rows.append(
                {
                    "participant": f"p{p}",
                    "condition": c,
                    "period": period,
                    "y": d if c == "B" else -d,
                }
            )
    fit = statistics.mixed_model(rows, "y", ["A", "B"])
    assert not fit["reported"] and fit["why"].startswith("singular")


def test_an_interval_on_a_bounded_scale_stays_on_it():
    plain = statistics.mean_ci([7, 7, 6])
    bounded = statistics.mean_ci([7, 7, 6], bounds=(1.0, 7.0))
    assert plain["hi"] > 7 and 1 <= bounded["lo"] < bounded["mean"] < bounded["hi"] <= 7
    positive = statistics.mean_ci([0.1, 0.02, 3.0], bounds=(0.0, None))
    assert statistics.mean_ci([0.1, 0.02, 3.0])["lo"] < 0 < positive["lo"]
    difference = statistics.mean_ci([6, 6, -6], bounds=statistics.difference_bounds((1, 7)))
    assert -6 <= difference["lo"] and difference["hi"] <= 6
    assert statistics.mean_ci([7, 7, 7], bounds=(1.0, 7.0))["hi"] == 7


def test_analyze_makes_no_folder_for_a_log_it_cannot_read(tmp_path):
    db = tmp_path / "sessions.sqlite"
    StudyLog(db).close()  # a log of single sessions: no protocol
    out = tmp_path / "analysis"
    with pytest.raises(ValueError, match="not a protocol's study log"):
        analyze(db, out)
    assert not out.exists()


def test_a_log_made_before_answers_kept_their_questions_still_opens_and_analyses(short, tmp_path):
    """As the committed pilot's log was made: no asked or participant_events table, the
    protocol in its meta with a condition's text naming a robot by number."""
    import sqlite3

    db = tmp_path / "study.sqlite"
    run = open_run(short, db)
    simulate_cohort(run, range(2))
    run.log.close()
    with sqlite3.connect(db) as old:
        old.execute("DROP TABLE asked")
        old.execute("DROP TABLE participant_events")
        source = json.loads(
            old.execute("SELECT value FROM meta WHERE key = 'protocol'").fetchone()[0]
        )
        source["conditions"][0]["instructions"] = "**Robot 1.** Go."
        old.execute("UPDATE meta SET value = ? WHERE key = 'protocol'", (json.dumps(source),))
    paths = analyze(db, tmp_path / "analysis")
    assert (tmp_path / "analysis" / "report.md") in paths
    answers = (tmp_path / "analysis" / "answers.csv").read_text()
    assert "The robot understood me." in answers  # the question from the protocol kept
    run = open_run(short, db)  # served again: the same design, its prose corrected
    assert run.participant("sim00001").where().step.kind == "end"
    run.log.close()


def test_the_condition_plot_shows_the_spread_on_the_outcomes_scale(tmp_path, monkeypatch):
    """Two participants' final errors 0.999 and 1.024 (descriptive only): conditions.png
    drew the means from the panel's bottom to its top with nothing of the spread. Now the
    axis starts at the scale's zero and each condition shows its participants' range."""
    import matplotlib.figure

    from corrections_sim.userstudy.plots import plot

    trials = [
        {"participant": p, "condition": c, "final_error": e}
        for p, c, e in (
            ("P1", "C", 0.98),
            ("P2", "C", 1.018),
            ("P1", "CL", 1.02),
            ("P2", "CL", 1.028),
        )
    ]
    summary = [
        {
            "condition": "C",
            "n": 2,
            "mean": 0.999,
            "sd": 0.027,
            "lo": np.nan,
            "hi": np.nan,
            "min": 0.98,
            "max": 1.018,
        },
        {
            "condition": "CL",
            "n": 2,
            "mean": 1.024,
            "sd": 0.006,
            "lo": np.nan,
            "hi": np.nan,
            "min": 1.02,
            "max": 1.028,
        },
    ]
    result = {
        "conditions": ["C", "CL"],
        "outcomes": {"final_error": {"summary": summary, "bounds": [0.0, None]}},
        "descriptive_only": True,
        "simulated": False,
    }
    tables = {"trials": trials, "answers": [], "comparisons": []}
    drawn = {}

    def keep(fig, path, **kw):
        ax = fig.axes[0]
        spans = [
            seg[:, 1].tolist()
            for coll in ax.collections
            for seg in getattr(coll, "get_segments", list)()
        ]
        drawn[Path(path).stem] = (ax.get_ylim(), spans)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", keep)
    plot(tables, result, tmp_path, [])
    (bottom, top), spans = drawn["conditions"]
    assert bottom <= 0.0 < 1.028 < top < 1.2, (bottom, top)
    assert sorted(spans) == [[0.98, 1.018], [1.02, 1.028]], spans
    assert drawn["participants"][0][0] <= 0.0


@pytest.mark.parametrize("n", [25, 37, 200, 600])
def test_a_power_of_zero_or_one_keeps_its_interval_around_it(n):
    """At p = 1 the Wilson bound came out 1 − 1e-16 for 25 studies: a negative error bar
    that stopped the power plot after the whole pool was simulated."""
    from corrections_sim.userstudy import statistics as st

    for hits in (0, n):
        found = st.power_summary([True] * hits + [False] * (n - hits))
        assert found["lo"] <= found["power"] <= found["hi"]
        assert 0.0 <= found["lo"] and found["hi"] <= 1.0
    inside = st.power_summary([True] * (n // 2) + [False] * (n - n // 2))
    assert inside["lo"] < inside["power"] < inside["hi"]


def test_a_run_reads_its_atlases_and_stored_plans_before_participants_come(short, tmp_path):
    """``read_plans`` (what serve-study does before it serves): every condition's atlas held by
    this process for every environment, and the stored plans between its nodes counted, so
    the first submits do not wait for them; no condition is left without its atlas."""
    run = open_run(short, tmp_path / "study.sqlite")
    atlases = [(s.atlas(), s.envs()) for s in run.settings_of.values()]
    assert any(atlas is not None for atlas, _ in atlases)  # the test would check nothing
    held = run.read_plans()
    assert isinstance(held, int) and held >= 0
    for atlas, envs in atlases:
        assert atlas is None or all(atlas.holds(env) for env in envs)
    run.log.close()
