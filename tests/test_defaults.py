"""Every command meets the recommended robot when no learner is named (issue 67): each
command's default is read where the command reads it, not from the table alone."""

from __future__ import annotations

import inspect

from corrections_sim.cli import main as cli
from corrections_sim.defaults import DEFAULTS, RECOMMENDED
from corrections_sim.learning.base import LEARNERS, make_learner


def test_the_recommended_robot_is_a_registered_exact_learner_with_a_posterior():
    robot = make_learner(RECOMMENDED)
    assert RECOMMENDED in LEARNERS and robot.needs_atlas and robot.has_covariance


def test_a_study_without_learners_runs_the_recommended_robot_on_the_atlas_it_needs():
    from corrections_sim.study import schema

    settings = schema.parse_study({"theta_star": [1.0, -1.0]}, name="own")
    assert list(settings.study.learners) == list(DEFAULTS["study"])
    assert list(settings.study.learners)[0] == RECOMMENDED
    assert settings.study.atlas is not None  # not asked for: the robot needs it
    # Learners that need no atlas get none unless asked, as before; one asked away is
    # refused in one line naming the key.
    named = schema.parse_study({"theta_star": [1.0, -1.0], "learners": ["KF"]}, name="own")
    assert named.study.atlas is None
    try:
        schema.parse_study({"theta_star": [1.0, -1.0], "atlas": False}, name="own")
    except ValueError as exc:
        assert str(exc).startswith(f"learners.{RECOMMENDED}: its grid is the study's plan atlas")
    else:
        raise AssertionError("atlas = false with the recommended robot was accepted")


def test_interact_and_physical_sessions_default_to_the_recommended_robot():
    from corrections_sim.cli.commands import interact
    from corrections_sim.session.session import Session

    for argv in (["interact"], ["interact", "--mode", "physical"]):
        args = cli.parser().parse_args(argv)
        settings = interact._interact_settings(args)
        assert (args.learner or interact.DEFAULT_LEARNER) == RECOMMENDED
        assert RECOMMENDED in settings.study.learners and settings.study.atlas is not None
    start = inspect.signature(Session.start).parameters["learner"].default
    assert start == RECOMMENDED


def test_video_and_replay_default_to_the_recommended_robot_and_say_so():
    from corrections_sim.cli.commands import commands
    from corrections_sim.figures.video import make_video
    from corrections_sim.session.replay import DEFAULT_LEARNERS

    assert inspect.signature(make_video).parameters["learner"].default == RECOMMENDED
    assert f"(default {RECOMMENDED})" in commands()["video"].option_help["learner"]
    assert DEFAULT_LEARNERS[0] == RECOMMENDED
    assert ",".join(DEFAULT_LEARNERS) in commands()["replay"].option_help["learners"]


def test_reference_judges_an_approximation_and_sbc_judges_the_recommended_robot():
    """``reference`` asks how far an approximation is from the exact posterior of its own
    model; the recommended robot is such a posterior, so its check is ``run sbc``."""
    from corrections_sim.figures.presets import EXPERIMENTS_DIR
    from corrections_sim.study import schema

    judged = make_learner(DEFAULTS["reference"][0])
    assert not judged.needs_atlas and judged.likelihood() is not None
    sbc = schema.load_study(EXPERIMENTS_DIR / "sbc.toml", name="sbc", quick=False)
    assert RECOMMENDED in sbc.study.learners


def test_the_example_protocol_compares_the_recommended_robot_with_kf_c():
    from corrections_sim.figures.presets import EXPERIMENTS_DIR
    from corrections_sim.userstudy.protocol import load_protocol

    protocol = load_protocol(EXPERIMENTS_DIR / "protocol.toml")
    learners = {c.learner for c in protocol.conditions}
    assert learners == {RECOMMENDED, "KF-C"}
