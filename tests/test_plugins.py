"""Plug-ins: learners, users, correction models, features and environment parameters by name.

Every registered learner and user is checked through the same tests (a new one never edits
them); unknown names and parameters are refused in one line naming their key path; a plug-in's
own defaults are never overridden; the examples in ``examples/`` run end to end in a fresh
interpreter (their registrations stay out of this one).
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from corrections_sim import components
from corrections_sim.components import ParameterError
from corrections_sim.learning.base import LEARNERS, Learner, Step, make_learner, register_learner
from corrections_sim.people.corrections import (
    CORRECTIONS,
    CorrectionModel,
    register_correction,
    waypoint_correction,
)
from corrections_sim.people.users import (
    USERS,
    Situation,
    User,
    make_user,
    register_user,
    user_parameters,
)
from corrections_sim.planning.features import FEATURES, feature_counts, register_feature
from corrections_sim.registry import Registry, UnknownName
from corrections_sim.scene.environments import (
    ENV_PARAMETERS,
    env_index,
    paper_environments,
    register_env_parameter,
)
from corrections_sim.study import schema
from corrections_sim.study.settings import StudySettings

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
BUILT_IN = ("PP", "KF", "AL", "PP-C", "KF-C", "AL-C", "KF-A", "BP")


def settings(**overrides) -> StudySettings:
    """Study settings as a study file gives them (through the one schema)."""
    values = dict(
        theta_star=[1.0, -1.0],
        theta0=[0.0, 0.0],
        cov0=[[1.0, 0.0], [0.0, 1.0]],
        iterations=2,
        runs=2,
        learners=list(BUILT_IN),
    )
    values.update(overrides)
    return schema.parse_study(values).study


# --------------------------------------------------------------------------- the registry


def test_an_unknown_name_is_refused_in_one_line_listing_the_known_ones():
    reg: Registry[int] = Registry("widget")
    reg.register("a", 1)
    reg.register("b-2", 2)
    with pytest.raises(UnknownName) as info:
        reg["c"]
    assert str(info.value) == "unknown widget 'c': known are a, b-2"
    assert isinstance(info.value, KeyError) and isinstance(info.value, ValueError)
    assert reg.get("c") is None and "c" not in reg
    assert list(reg) == ["a", "b-2"]


def test_a_retired_name_is_refused_with_why_it_left_and_may_be_registered_again():
    reg: Registry[int] = Registry("widget")
    reg.register("a", 1)
    reg.retire("old", "it measured nothing")
    with pytest.raises(UnknownName) as info:
        reg["old"]
    assert str(info.value) == "widget 'old' left the registry: it measured nothing; known are a"
    assert "old" not in reg and list(reg) == ["a"]
    with pytest.raises(ValueError, match="is registered"):
        reg.retire("a", "no")
    assert reg.retired("old") == "it measured nothing" and reg.retired("a") is None
    reg.register("old", 2)  # a plug-in may take the name again
    assert reg["old"] == 2 and reg.retired("old") is None


def test_a_study_naming_a_learner_that_left_says_why_in_one_line():
    """The EKF left the registry (issue 66): a study file, a recorded summary or
    ``--learners`` that names it is refused with the reason and where it is recorded."""
    from corrections_sim.learning.roster import RETIRED

    assert {"EKF", "KF-CB"} <= set(RETIRED) and not set(RETIRED) & set(LEARNERS)
    with pytest.raises(ValueError) as info:
        settings(learners=["KF", "EKF"])
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith("learners[1] = 'EKF': the paper's EKF answered its question")
    assert "docs/decision.md#learners-that-left" in message
    # As a table too, and wherever a learner is made by name (a recorded summary, a log).
    with pytest.raises(ValueError, match="learner 'EKF' left the registry: the paper's EKF"):
        settings(learners={"EKF": {"step": 0.05}})


@pytest.mark.parametrize("name", ["", "-a", "a b", "a/b", 3])
def test_a_malformed_name_is_refused(name):
    with pytest.raises(ValueError, match="name"):
        Registry("widget").register(name, 1)


def test_a_name_is_registered_once_unless_replaced():
    reg: Registry[int] = Registry("widget")
    reg.register("a", 1)
    with pytest.raises(ValueError, match="already registered"):
        reg.register("a", 2)
    reg.register("a", 3, replace=True)
    assert reg["a"] == 3
    reg.unregister("a")
    assert "a" not in reg


# --------------------------------------------------------------------------- learners


def test_the_papers_learners_are_registered_in_the_figures_order():
    assert list(LEARNERS)[:8] == ["PP", "KF", "AL", "PP-C", "KF-C", "AL-C", "KF-A", "BP"]


def test_no_two_registered_learners_are_drawn_alike():
    """A figure tells its learners apart by colour and line style: no two share both (EX-M
    was drawn as AL was, red and solid)."""
    drawn: dict[tuple, str] = {}
    for name, cls in LEARNERS.items():
        if cls.style is None:  # a plug-in without one (a test's): the next free colour
            continue
        assert cls.style not in drawn, f"{name} is drawn as {drawn.get(cls.style)} is"
        drawn[cls.style] = name


@pytest.mark.parametrize("name", list(LEARNERS))
def test_every_learner_describes_itself_and_owns_its_parameters(name):
    cls = LEARNERS[name]
    assert issubclass(cls, Learner) and dataclasses.is_dataclass(cls)
    assert cls.label and cls.style is not None
    assert cls.rate_from is None or cls.rate_from in LEARNERS
    if cls.__module__.startswith("corrections_sim."):  # its own question, not its parent's
        assert "question" in vars(cls) and cls.question.endswith("?"), name
    learner = make_learner(name)
    assert isinstance(learner, cls)
    # Its parameters as data build the same learner again (what summary.json records).
    params = components.params(learner)
    assert set(params) == set(components.defaults(cls))
    assert make_learner(name, params) == learner


def test_unknown_learners_and_parameters_are_refused_by_their_key_path():
    with pytest.raises(ValueError, match=r"learners\[1\] = 'UKF': unknown learner"):
        settings(learners=["KF", "UKF"])
    with pytest.raises(ValueError, match="learners.KF.gain: the KF learner has no such param"):
        settings(learners={"KF": {"gain": 1.0}})
    with pytest.raises(ValueError, match="learners.KF-A.attenuation_min: must be > 0, got -1"):
        settings(learners={"KF-A": {"attenuation_min": -1.0}})
    with pytest.raises(ValueError, match="learner_params: 'BP' is not one of the learners"):
        settings(learners=["KF"], learner_params={"BP": {}})


def test_a_registered_learner_takes_its_parameters_by_name():
    @register_learner("TEST-FIXED")
    @dataclasses.dataclass(frozen=True)
    class Fixed(Learner):
        has_covariance = False
        shift: float = 0.0

        def __post_init__(self) -> None:
            if not np.isfinite(self.shift):
                raise ParameterError("shift", f"must be finite, got {self.shift}")

        def update(self, ctx, belief, env, plan, phi_h):
            return Step(belief, None, phi_h - plan.features)

    try:
        s = settings(learners={"TEST-FIXED": {"shift": 2.0}})
        assert s.learners["TEST-FIXED"].shift == 2.0
        assert make_learner("TEST-FIXED").shift == 0.0
        with pytest.raises(ValueError, match="learners.TEST-FIXED.shift: must be finite, got inf"):
            settings(learners={"TEST-FIXED": {"shift": np.inf}})
        with pytest.raises(ValueError, match=r"learners.TEST-FIXED.scale: .* \(it takes: shift\)"):
            make_learner("TEST-FIXED", {"scale": 1.0})
        with pytest.raises(TypeError, match="not a Learner subclass"):
            register_learner("TEST-BAD")(object)
    finally:
        LEARNERS.unregister("TEST-FIXED")


def test_plot_styles_and_labels_come_from_the_learners():
    from corrections_sim.figures.style import learner_label, learner_style

    assert learner_style("KF-C") == ("#1f77b4", "--")
    assert learner_label("KF") == "Kalman filter (KF)"
    assert learner_label("not-registered") == "not-registered"


# --------------------------------------------------------------------------- users


def test_the_papers_users_are_registered_with_their_parameters():
    assert list(USERS)[:4] == ["biased", "deform", "noisy", "model"]
    assert user_parameters("biased") == {"step": 1.0, "waypoints": 1}
    assert user_parameters("deform") == {"step": 1.0}
    assert user_parameters("noisy") == {"noise": 0.5}


@pytest.mark.parametrize(
    ("name", "params", "message"),
    [
        ("psychic", {}, "user: unknown user 'psychic': known are biased, deform, noisy, model"),
        (
            "biased",
            {"stp": 0.5},
            r"user.stp: the biased user has no such parameter \(it takes: step, waypoints",
        ),
        ("biased", {"step": 0.0}, r"user.step: must lie in \(0, 1\], got 0.0"),
        ("biased", {"waypoints": 1.5}, "user.waypoints: must be an integer, got 1.5"),
        ("noisy", {"noise": -1.0}, "user.noise: must be finite and >= 0, got -1.0"),
        ("model", {"correction": "psychic"}, "user.correction: unknown correction model"),
    ],
)
def test_bad_users_and_parameters_are_refused_in_one_line(name, params, message):
    with pytest.raises(ValueError, match=message) as info:
        make_user(name, params)
    assert "\n" not in str(info.value)


def test_a_user_table_sets_its_parameters_and_the_old_keys_still_work():
    assert settings(user={"name": "biased", "step": 0.5}).user == make_user("biased", {"step": 0.5})
    assert settings(user_step=0.5).user == make_user("biased", {"step": 0.5})
    assert settings(user_params={"step": 0.25}, user_step=0.5).user.step == 0.25
    assert settings(user="noisy", observation_noise=0.04).user.noise == pytest.approx(0.2)
    assert settings(user="noisy").user.noise == 0.5  # its own default, √ of the default N
    with pytest.raises(ValueError, match=r"user.step: must lie in \(0, 1\], got 2.0"):
        settings(user_step=2.0)
    with pytest.raises(ValueError, match="user.waypoints: the deform user has no such"):
        settings(user="deform", user_params={"waypoints": 2})


@pytest.fixture()
def slow_user():
    """A plug-in user whose own default step (0.6) is no built-in default."""

    @register_user("TEST-SLOW")
    @dataclasses.dataclass(frozen=True)
    class Slow(User):
        step: float = 0.6
        waypoints: int = 2
        noise: float = 0.05

        def correct(self, situation, rng):
            return waypoint_correction(situation.robot, situation.intended, self.step)

    yield Slow
    USERS.unregister("TEST-SLOW")


def test_nothing_overrides_a_plugin_users_own_defaults(slow_user):
    base = {"theta_star": [1.0, -1.0]}
    user = schema.parse_study({**base, "user": "TEST-SLOW"}).study.user
    assert (user.step, user.waypoints, user.noise) == (0.6, 2, 0.05)
    # Through the command line's options too: --user takes a plug-in's name, and the filters'
    # N (once √N became the noisy user's σ) reaches no user.
    values = schema.apply_overrides(
        base, {"user": "TEST-SLOW", "set": ["filter.observation_noise=0.04"]}
    )
    user = schema.parse_study(values).study.user
    assert (user.step, user.waypoints, user.noise) == (0.6, 2, 0.05)
    # An option that sets a parameter is never ignored, even over the file's table.
    values = schema.apply_overrides(
        {**base, "user": {"name": "TEST-SLOW", "step": 0.3}}, {"user_step": 0.5}
    )
    assert schema.parse_study(values).study.user.step == 0.5


def test_a_plugin_correction_model_serves_kf_c_and_a_user():
    @register_correction("TEST-HALF")
    @dataclasses.dataclass(frozen=True)
    class Half(CorrectionModel):
        share: float = 0.5

        def apply(self, robot, intended):
            return robot + self.share * (np.asarray(intended) - robot)

    try:
        s = settings(
            learners={"KF-C": {"model": {"name": "TEST-HALF", "share": 0.25}}},
            user={"name": "model", "correction": "TEST-HALF"},
        )
        assert s.learners["KF-C"].model == Half(0.25) and s.user.correction == Half(0.5)
        assert s.as_dict()["learners"]["KF-C"]["model"] == {"name": "TEST-HALF", "share": 0.25}
        values = schema.apply_overrides(
            {"theta_star": [1, -1], "learners": ["KF-C"]},
            {"set": ["learners.KF-C.model=TEST-HALF"]},
        )
        assert schema.parse_study(values).study.learners["KF-C"].model == Half()
        with pytest.raises(ValueError, match="learners.KF-C.model.shares: the TEST-HALF"):
            settings(learners={"KF-C": {"model": {"name": "TEST-HALF", "shares": 1}}})
    finally:
        CORRECTIONS.unregister("TEST-HALF")


@pytest.mark.parametrize("name", list(USERS))
def test_every_user_corrects_deterministically_given_its_generator(name):
    env = paper_environments()[0]
    robot = np.linspace(env.q_start, env.q_goal, 12)
    intended = robot.copy()
    intended[4:7, 1] += np.array([0.1, 0.3, 0.1])
    features = ("laptop", "table")
    seen = Situation(robot, intended, env, features, np.array([1.0, -1.0]))
    user = make_user(name)
    assert isinstance(user, User)
    a = user.correction_features(seen, np.random.default_rng(3))
    b = user.correction_features(seen, np.random.default_rng(3))
    assert a.shape == (2,) and np.all(np.isfinite(a))
    np.testing.assert_array_equal(a, b)
    corrected = user.correct(seen, np.random.default_rng(3))
    assert corrected.shape == robot.shape
    np.testing.assert_array_equal(corrected[[0, -1]], robot[[0, -1]])  # start, goal fixed


# --------------------------------------------------------------------------- features


def test_environment_parameters_have_names():
    env = paper_environments()[5]
    names = ["laptop_x", "laptop_y", "laptop_yaw", "table_x", "table_y"]
    assert list(ENV_PARAMETERS)[:5] == names
    assert [env.param(n) for n in names] == [*env.laptop, *env.table]
    assert env_index("table_x") == 3
    with pytest.raises(ValueError, match="unknown environment parameter 'laptop_z'"):
        env.param("laptop_z")


def test_a_new_feature_is_one_function_and_one_environment_field():
    register_env_parameter("test_spot_x", default=0.5)
    try:

        @register_feature("test-spot")
        def spot(w):
            return (w.cup[0] - w.param("test_spot_x")) ** 2

        try:
            env = paper_environments()[0]
            moved = dataclasses.replace(env, extra={"test_spot_x": 0.0})
            assert env.param("test_spot_x") == 0.5 and moved.param("test_spot_x") == 0.0
            assert moved != env and len(env.params()) == 6
            trajectory = np.linspace(env.q_start, env.q_goal, 5)
            a = feature_counts(trajectory, env, ("test-spot", "laptop"))
            b = feature_counts(trajectory, moved, ("test-spot", "laptop"))
            assert a[1] == b[1] and a[0] != b[0]
            from corrections_sim.scene.environments import configuration_at

            q = configuration_at((0.5, 0.2, 0.3))
            assert feature_counts(np.array([q]), env, ("test-spot",))[0] == pytest.approx(
                0.0, abs=1e-6
            )
        finally:
            FEATURES.unregister("test-spot")
    finally:
        ENV_PARAMETERS.unregister("test_spot_x")
    with pytest.raises(ValueError, match="unknown environment parameter"):
        dataclasses.replace(paper_environments()[0], extra={"test_spot_x": 0.0})


# --------------------------------------------------------------------------- examples


def _run_example(name: str, *args: str) -> dict:
    call = f"m['main']({', '.join(args)})"
    code = f"import json, runpy; m = runpy.run_path({str(EXAMPLES / name)!r}); "
    code += f"print(json.dumps({call}))"
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_example_custom_learner_learns():
    out = _run_example("custom_learner.py", "iterations=4", "runs=2")
    errors = out["mean_estimate_error"]
    assert len(errors) == 5 and errors[0] == pytest.approx(2.0)
    assert errors[-1] < errors[0] - 0.3  # steps of 0.3 toward θ*


def test_example_custom_user_skips_and_corrects():
    never = _run_example("custom_user.py", "iterations=3", "skip=1.0")
    assert "LazyUser(skip=1.0" in never["user"]
    # A correction that shows nothing moves no estimate.
    assert all(theta == [0.0, 0.0] for theta in never["theta"])
    always = _run_example("custom_user.py", "iterations=3", "skip=0.0")
    assert always["estimate_error"][-1] < always["estimate_error"][0]


def test_example_custom_feature_plans_with_it():
    out = _run_example("custom_feature.py")
    assert out["env_params"]["person_x"] == 0.45
    assert out["seek"] > out["ignore"] + 0.5 > out["avoid"] + 0.5


def test_a_plugin_learner_runs_through_the_figures_pipeline():
    """learning_study.run (executor, PP-type ordering, learning rates) takes a registered learner
    without a covariance that needs no rates; plotting gives it a colour and its label."""
    code = f"""
import json, runpy
from concurrent.futures import ThreadPoolExecutor
runpy.run_path({str(EXAMPLES / "custom_learner.py")!r})
from corrections_sim.figures import learning_study
from corrections_sim.study import runner
from corrections_sim.figures.style import learner_label, learner_style
from corrections_sim.study import schema
s = schema.parse_study(dict(
    theta_star=[1.0, -1.0], theta0=[0.0, 0.0], cov0=[[1.0, 0.0], [0.0, 1.0]], runs=1,
    iterations=1, seed=3, learners={{"KF": {{}}, "PP": {{}}, "NPP": {{"step": 0.5}}}}))
with ThreadPoolExecutor(1) as pool:
    result = runner.run(s, pool, mean_estimate=False)
rows = [r for r in result.records if r["learner"] == "NPP"]
print(json.dumps({{"order": [r["learner"] for r in result.records][::2],
                  "npp": [r["estimate_error"] for r in rows], "alphas": sorted(result.alphas),
                  "label": learner_label("NPP"), "style": learner_style("NPP")}}))
"""
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["order"] == ["PP", "KF", "NPP"]
    assert out["alphas"] == ["PP"]
    assert out["npp"][0] == pytest.approx(2.0) and out["npp"][1] < 2.0
    assert out["label"] == "Normalized perceptron (NPP)"
    assert out["style"] == ["#9467bd", "-"]


@pytest.fixture(scope="module")
def small_study():
    from corrections_sim.planning.planner import Planner, PlannerConfig
    from corrections_sim.plans.book import Target

    planner = Planner(PlannerConfig(features=("laptop", "table"), n_starts=1))
    envs = paper_environments()[::16]  # 3 environments
    return planner, envs, Target.solve(planner, np.array([1.0, -1.0]), envs)


@pytest.mark.parametrize("name", list(LEARNERS))
def test_every_learner_runs_reproducibly_and_moves_toward_theta_star(name, small_study):
    """The loop's contract for any registered learner: same seed, same records; a belief
    after each correction; the estimate error falls from the prior's over 3 corrections."""
    from corrections_sim.study.loop import run_learner

    planner, envs, target = small_study
    names = [name, *filter(None, [LEARNERS[name].rate_from])]
    # The contract does not need a paper-scale particle count (200: about 27 s a learner here).
    few = {"particles": 40} if "particles" in components.defaults(LEARNERS[name]) else {}
    # An exact learner's grid is the study's plan atlas: a small one.
    more = {"atlas": {"points": 9}} if LEARNERS[name].needs_atlas else {}
    s = settings(iterations=3, learners={n: (few if n == name else {}) for n in names}, **more)
    alphas = np.full(3, 0.2) if LEARNERS[name].needs_rates() else None
    atlas = None
    if s.atlas is not None:
        from corrections_sim.plans.spread import AtlasSpec

        grid = s.atlas.grid(s.theta0, s.cov0)
        atlas = AtlasSpec(planner.config, grid, s.atlas.cold_stride).atlas()

    def once():
        rng = np.random.default_rng(7)
        return run_learner(name, 0, s, planner, envs, target, s.user, rng, alphas, atlas=atlas)

    a, b = once(), once()
    assert a.records == b.records
    assert [r["iteration"] for r in a.records] == [0, 1, 2, 3]
    assert all(r["learner"] == name and not r["update_skipped"] for r in a.records)
    assert a.records[-1]["estimate_error"] < a.records[0]["estimate_error"]
    assert (a.records[-1]["nees"] is None) == (not LEARNERS[name].has_covariance)
