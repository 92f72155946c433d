"""``run learners SETTING`` (issue 68): every registered learner on fig. 4's or fig. 5's
settings, or a study file's, in ``<out>/learners/<name>/``; the curves themselves are guarded
by ``test_regression.py`` (``TestEveryLearnerFig4``, ``TestEveryLearnerFig5``)."""

from __future__ import annotations

import pytest

from corrections_sim.cli import main as cli
from corrections_sim.figures import every_learner, learning_plot, learning_study
from corrections_sim.learning.base import LEARNERS


def _main(argv: list[str]) -> int:
    try:
        return cli.main(argv)
    except SystemExit as exc:
        return int(exc.code)


@pytest.mark.parametrize("figure", learning_study.FIGURES)
def test_it_runs_every_registered_learner_on_a_figures_settings(figure):
    settings = every_learner.EveryLearner("learners", "").load(
        quick=True, overrides={"study_file": figure}
    )
    assert list(settings.study.learners) == list(LEARNERS)
    shown = learning_study.load_settings(figure, quick=True)
    # The figure's own settings but the learners: the same runs (the run cache's key).
    assert settings.study.seed == shown.study.seed and settings.study.atlas == shown.study.atlas
    assert every_learner.EveryLearner("learners", "").folder(settings) == f"learners/{figure}"


def test_a_study_without_an_atlas_leaves_out_the_learners_that_need_one(tmp_path):
    study = tmp_path / "mine.toml"
    study.write_text('theta_star = [1.0, -1.0]\nruns = 2\nlearners = ["KF"]\natlas = false\n')
    settings = every_learner.EveryLearner("learners", "").load(
        quick=False, overrides={"study_file": str(study)}
    )
    kept, left_out = every_learner.every_learner(atlas=False)
    assert list(settings.study.learners) == kept
    assert set(left_out) == {n for n, cls in LEARNERS.items() if cls.needs_atlas} != set()


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["learners"], "learners: name the settings, e.g. run learners fig4"),
        (["learners", "fig9"], "learners fig9: neither fig4 nor fig5 nor a study file"),
        (["learners", "fig4", "--learners", "PP"], "--learners"),
    ],
)
def test_a_wrong_setting_is_one_line_and_writes_nothing(argv, says, tmp_path, capsys):
    assert _main([*argv, "--quick", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert says in err and len(err.strip().splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []


def test_every_built_in_learner_has_a_family_panel():
    from corrections_sim.learning.roster import RETIRED

    built_in = [n for n, c in LEARNERS.items() if c.__module__.startswith("corrections_sim.")]
    # The 21 built-in learners at least, none of those that left (decision.md).
    assert len(built_in) >= 21 and not set(built_in) & set(RETIRED)
    for name in built_in:
        assert learning_plot.family(name) in learning_plot.FAMILY_ORDER[:-1], name
