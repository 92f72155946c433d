"""EX-M that asks for feature traces (issues 66 and 69): off by default; when on, KF-CRP's
judgement across the person's corrections, fed EX-M's own belief, decides when to ask, and
the posterior is EX-M's to the bit until the person teaches; a person with nothing to teach
declines and it goes on exactly; a person who minds what it lacks teaches, and it goes on over
k + 1 features (KF-CRX's filter after expansion); its options are checked in one line."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from corrections_sim import components
from corrections_sim.cli import main as cli
from corrections_sim.learning.base import make_learner

STUDY = """\
features = ["laptop", "table"]
theta_star = {theta_star}
{user_features}
runs = 1
iterations = 3
seed = 3
environments = ["s0-t0-l1", "s1-t1-l2"]
atlas = {{ points = 9 }}
user = "biased"
teacher = {{ states = 6, candidates = 8, search = 2 }}
[learners.EX-M]
{asking}
"""


def _study(folder, name, theta_star="[1.0, -1.0]", user_features="", asking="") -> list[dict]:
    path = folder / f"{name}.toml"
    path.write_text(STUDY.format(theta_star=theta_star, user_features=user_features, asking=asking))
    argv = ["study", str(path), "--out", str(folder / "out"), "--workers", "1"]
    assert cli.main(argv) == 0
    with open(folder / "out" / name / "curves.csv", newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def studies(tmp_path_factory):
    folder = tmp_path_factory.mktemp("asking")
    minds_human = 'user_features = ["laptop", "table", "human"]'
    return {
        "plain": _study(folder, "plain"),
        # Asked at the first correction (a rate of relevant corrections below 0.99): the
        # paper's person has nothing to teach and declines.
        "declined": _study(
            folder, "declined", asking="expand_traces = 3\nexpand_below = 0.99\nexpand_after = 1"
        ),  # fmt: skip
        "taught": _study(
            folder,
            "taught",
            "[0.0, 0.0, -5.0]",
            minds_human,
            "expand_traces = 3\nexpand_after = 2\nexpand_variances = [1.0]\nexpand_noises = [1.0]",
        ),  # fmt: skip
    }


BELIEF = ("theta_0", "theta_1", "cov_00", "cov_01", "cov_11", "nees", "nis", "regret")


def test_it_never_asks_by_default():
    ex_m = make_learner("EX-M")
    assert ex_m.expand_traces == 0 and not ex_m.learns_features()
    assert make_learner("EX-M", {"expand_traces": 10}).learns_features()


def test_a_person_who_declines_leaves_the_exact_posterior_as_it_was(studies):
    plain, declined = studies["plain"], studies["declined"]
    assert len(plain) == len(declined) == 4
    for a, b in zip(plain, declined, strict=True):
        assert {k: a[k] for k in BELIEF} == {k: b[k] for k in BELIEF}
    # It judged every correction and asked once, at the first; it never expanded.
    assert [r["asked"] for r in declined] == ["", "1.0", "1.0", "1.0"]
    assert {r["expanded"] for r in declined[1:]} == {"0.0"}
    assert all(0.0 <= float(r["relevance"]) <= 1.0 for r in declined[1:])
    assert "relevance" not in plain[0]


def test_a_person_who_minds_what_it_lacks_teaches_and_it_goes_on_over_k_plus_1(studies):
    taught = studies["taught"]
    first, asked, after = taught[1], taught[2], taught[3]
    # Their first correction is judged unexplained: the believed rate falls below 0.35, but
    # it asks no sooner than after the second (expand_after = 2), and learns the feature then.
    assert float(first["relevance"]) < 0.5 and float(first["relevance_rate"]) < 0.35
    assert first["asked"] == "" and first["theta_2"] == ""
    for row in (asked, after):
        assert row["asked"] == row["expanded"] == "1.0" and row["expanded_at"] == "2"
        assert row["theta_2"] != "" and float(row["cov_22"]) > 0
        assert row["learnt_variance"] == "1.0" and row["learnt_noise"] == "1.0"
    assert -1.0 <= float(asked["learnt_spearman"]) <= 1.0
    # Over k + 1 features it updates as KF-CRX does after teaching: every correction relevant.
    assert after["relevance"] == "1.0" and after["theta_2"] != asked["theta_2"]


@pytest.mark.parametrize(
    "params, key",
    [
        ({"expand_traces": -1}, "expand_traces"),
        ({"expand_below": 1.5}, "expand_below"),
        ({"expand_after": 0}, "expand_after"),
        ({"expand_variances": []}, "expand_variances"),
        ({"expand_noises": [0.0]}, "expand_noises"),
        ({"expand_inputs": ["elbow"]}, "expand_inputs"),
    ],
)
def test_its_asking_options_are_checked_in_one_line(params, key):
    with pytest.raises(ValueError, match=f"learners.EX-M.{key}") as info:
        make_learner("EX-M", params)
    assert "\n" not in str(info.value)


ASKING = Path(__file__).resolve().parents[1] / "experiments" / "asking"


PEOPLE = [("only", "minds only the person"), ("also", "minds the person"), ("paper", "biased")]


@pytest.mark.parametrize("who, label", PEOPLE)
def test_the_asking_study_files_are_the_ferl_studys_people(who, label):
    """experiments/asking/<who>.toml is the FERL study's column (the same person, seed,
    teacher, planner and atlas), so its run r meets the environments of that study's run r
    and the docs pair them by run; its robot is EX-M asking for 10 traces, else the default."""
    from corrections_sim.figures import ferl as ferl_figure
    from corrections_sim.figures import robustness
    from corrections_sim.study.schema import load_study

    mine = load_study(ASKING / f"{who}.toml", name=who, quick=False)
    ferl = robustness.load_settings(quick=False, figure="ferl", column_keys=ferl_figure.COLUMN_KEYS)
    column = next(c.settings for c in ferl.columns if c.label.endswith(label))
    for key in ("iterations", "seed", "user_theta", "theta_star", "theta0", "cov0", "teacher",
                "person_restarts", "warm_start"):  # fmt: skip
        assert getattr(mine.study, key) == getattr(column.study, key), key
    assert mine.features == column.features and mine.user_features == column.user_features
    assert mine.planner == column.planner and mine.atlas_spec() == column.atlas_spec()
    assert mine.study.user_params() == column.study.user_params()
    assert mine.study.learner_params() == {
        "EX-M": components.params(make_learner("EX-M", {"expand_traces": 10}))
    }


def test_at_a_session_it_asks_learns_resumes_and_replays(tmp_path):
    """EX-M that asks, at a session (the page's path): after the first correction it asks
    (``expand_below`` 0.99), the person's traces are learnt from, it plans over k + 1
    features; resumed from the log it is the same robot; replayed, it learns the same."""
    import numpy as np

    from corrections_sim.people.teacher import Teacher
    from corrections_sim.people.users import make_user
    from corrections_sim.session.log import StudyLog
    from corrections_sim.session.replay import replay
    from corrections_sim.session.session import Session
    from corrections_sim.session.simulate import simulate
    from corrections_sim.study.schema import parse_study

    settings = parse_study(
        {
            "environments": ["s0-t0-l1", "s1-t1-l2"],
            "theta_star": [1.0, -1.0],
            "learners": ["EX-M"],
            "atlas": {"points": 9},
            "seed": 5,
            "iterations": 3,
        },
        name="ask",
    )
    params = {"expand_traces": 3, "expand_after": 1, "expand_below": 0.99}
    with StudyLog(tmp_path / "t.sqlite") as log:
        session = Session.start(settings, log, learner="EX-M", params=params)
        simulate(session, make_user("biased"), (1.0, -1.0), 1)
        assert session.wanted == 3
        env = session.envs[session.last_env]
        for trace in Teacher().traces("human", 3, env, np.random.default_rng(0)):
            session.add_trace(trace)
        name = session.learn_feature()
        assert session.features == ("laptop", "table", name) and session.belief.dim == 3
        simulate(session, make_user("biased"), (1.0, -1.0), 1)
        assert session.belief.dim == 3 and session.wanted == 0

        resumed = Session.resume(log, session.id)
        np.testing.assert_array_equal(resumed.belief.theta, session.belief.theta)
        _, result, facts = replay(log, session.id, ["EX-M"], regret=False)
        assert facts["max_gap_to_log"] == 0.0
        assert "theta_2" in [r for r in result.records if r["iteration"] == 2][0]


def test_a_summary_recorded_before_ex_m_could_ask_compares_equal():
    """Every committed EX-M study recorded EX-M's parameters without the ``expand_*`` keys:
    read today, they are EX-M's with asking off, so a resumed or re-run folder compares
    equal."""
    from corrections_sim.study.legacy import normalize_recorded

    today = components.params(make_learner("EX-M"))
    older = {k: v for k, v in today.items() if not k.startswith("expand_")}
    assert older != today
    assert normalize_recorded({"learners": {"EX-M": older}})["learners"]["EX-M"] == today
