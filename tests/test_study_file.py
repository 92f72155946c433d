"""Study files (``run study FILE``): the examples in experiments/ run on quick settings and show
what they claim; bad input is one line naming the key and the file, exit 2, and nothing
already computed is lost.
"""

from __future__ import annotations

import contextlib
import csv
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from corrections_sim.cli import main as cli
from corrections_sim.cli.commands import figure as figure_command
from corrections_sim.figures import learning_plot, learning_study
from corrections_sim.study import runner
from corrections_sim.study import schema as study_file

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"
SENTINEL = "results made earlier, which a failed command must not touch\n"
GOOD = """\
features = ["laptop", "table"]
theta_star = [1.0, -1.0]
runs = 1
iterations = 1
learners = ["KF"]
"""
MINE = (
    '{ name = "mine", start = [0.45, 0.50, 0.28], laptop = [0.55, 0.05, 0.2], table = [0.55, 0.0] }'
)


def _main(argv: list[str]) -> int:
    try:
        return cli.main(argv)
    except SystemExit as exc:
        return int(exc.code)


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _mean(rows: list[dict], learner: str, key: str, t: int) -> float:
    return float(
        np.mean(
            [float(r[key]) for r in rows if r["learner"] == learner and int(r["iteration"]) == t]
        )
    )


# --- the examples ------------------------------------------------------------------------------


def test_three_features_every_weight_moves_towards_the_truth(tmp_path):
    argv = ["study", str(EXPERIMENTS / "three_features.toml"), "--quick", "--workers", "2"]
    assert _main([*argv, "--out", str(tmp_path)]) == 0
    folder = tmp_path / "three_features"
    assert {p.name for p in folder.iterdir()} >= {
        "curves.csv",
        "mean_estimate.csv",
        "summary.json",
        "three_features.png",
        "three_features.pdf",
    }
    rows = _rows(folder / "curves.csv")
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["figure"] == "three_features" and summary["preset"] == "quick"
    assert summary["planner"]["features"] == ["laptop", "table", "coffee"]
    theta_star = summary["settings"]["theta_star"]
    last = summary["settings"]["iterations"]
    assert not any(r["update_skipped"] for r in rows)
    # KF and KF-C: each weight, laptop and table and coffee, ends nearer θ* than it started;
    # the coffee weight (θ* = −1) is learned from the tilted environments (upright ones alone
    # leave it at 0: docs/three-features.md).
    for learner in ("KF", "KF-C"):
        for i, star in enumerate(theta_star):
            start = _mean(rows, learner, f"theta_{i}", 0)
            end = _mean(rows, learner, f"theta_{i}", last)
            assert abs(end - star) < abs(start - star), (learner, i, start, end)
        assert _mean(rows, learner, "theta_2", last) < -0.15
        assert _mean(rows, learner, "regret", last) < 0.5 * _mean(rows, learner, "regret", 0)
    tilted = [e for e in summary["settings"]["environments"] if isinstance(e, dict)]
    assert len(tilted) == 12 and all(e["tilt"] == 0.9 for e in tilted)
    # The exact posterior at k = 3 (on the quick preset's 3-point atlas, its cells cut along
    # the narrow axes) learns every weight, and more than KF-C's filter of the same model.
    for i, star in enumerate(theta_star):
        assert abs(_mean(rows, "EX-C", f"theta_{i}", last) - star) < abs(star), i
    errors = {n: _mean(rows, n, "estimate_error", last) for n in ("EX-C", "KF-C")}
    assert errors["EX-C"] < errors["KF-C"], errors


def test_a_study_with_its_own_plug_ins_runs_them_in_every_worker(tmp_path):
    # A fresh interpreter: the plug-ins register "NPP" and "lazy" for good, which must not
    # leak into this process's other tests.
    study = Path(__file__).resolve().parents[1] / "examples" / "plugin_study.toml"
    command = [sys.executable, "-m", "corrections_sim.run", "study", str(study), "--quick"]
    done = subprocess.run(
        [*command, "--workers", "2", "--out", str(tmp_path)], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    folder = tmp_path / "plugin_study"
    summary = json.loads((folder / "summary.json").read_text())
    plugins = summary["settings"]["plugins"]
    assert [Path(p["path"]).name for p in plugins] == ["custom_learner.py", "custom_user.py"]
    assert all(len(p["sha256"]) == 64 for p in plugins)
    rows = _rows(folder / "curves.csv")
    assert {r["learner"] for r in rows} == {"KF", "NPP"}
    last = summary["settings"]["iterations"]
    for learner in ("KF", "NPP"):
        first = _mean(rows, learner, "estimate_error", 0)
        assert _mean(rows, learner, "estimate_error", last) < first
    # NPP moves θ̂ by exactly its step (0.3) at a correction, or not at all when the lazy
    # user skips one (its correction is then the robot's own trajectory).
    npp = {}
    for r in rows:
        if r["learner"] == "NPP":
            theta = [float(r["theta_0"]), float(r["theta_1"])]
            npp[(r["run"], int(r["iteration"]))] = np.array(theta)
    moves = [
        np.linalg.norm(npp[(run, t + 1)] - npp[(run, t)]) for run, t in npp if (run, t + 1) in npp
    ]
    assert all(abs(m - 0.3) < 1e-9 or m < 1e-12 for m in moves), moves
    assert any(abs(m - 0.3) < 1e-9 for m in moves)
    # One worker gives the same bytes.
    again = subprocess.run(
        [*command, "--workers", "1", "--out", str(tmp_path / "one")], capture_output=True, text=True
    )
    assert again.returncode == 0, again.stderr
    assert (tmp_path / "one" / "plugin_study" / "curves.csv").read_bytes() == (
        folder / "curves.csv"
    ).read_bytes()


def test_own_environments_are_the_ones_the_study_runs_in(tmp_path):
    argv = ["study", str(EXPERIMENTS / "own_environments.toml"), "--quick", "--workers", "1"]
    assert _main([*argv, "--out", str(tmp_path)]) == 0
    folder = tmp_path / "own_environments"
    summary = json.loads((folder / "summary.json").read_text())
    listed = summary["settings"]["environments"]
    names = [e if isinstance(e, str) else e["name"] for e in listed]
    assert len(names) == 6 and "left-near" in names and "s0-t0-l1" in names
    rows = _rows(folder / "curves.csv")
    assert {r["environment"] for r in rows if r["iteration"] != "0"} <= set(names)
    assert all(r["regret_failures"] == "0" for r in rows)
    for learner in ("PP", "KF", "AL"):
        assert _mean(rows, learner, "estimate_error", 3) < _mean(rows, learner, "estimate_error", 0)
    # The same file again resumes every run and gives the same bytes.
    before = (folder / "curves.csv").read_bytes()
    assert _main([*argv, "--out", str(tmp_path)]) == 0
    assert (folder / "curves.csv").read_bytes() == before
    again = json.loads((folder / "summary.json").read_text())
    assert again["resumed_runs"] == sum(again["runs_per_learner"].values())


def test_figs_4_and_5_are_study_files_with_the_same_settings():
    for figure in learning_study.FIGURES:
        via_figure = learning_study.load_settings(figure, quick=True)
        path = EXPERIMENTS / f"{figure}.toml"
        via_file = study_file.load_study(path, name=figure, quick=True)
        assert via_figure == via_file
        assert via_file.environments == study_file.PAPER and len(via_file.envs()) == 48


# --- bad input ---------------------------------------------------------------------------------


@pytest.fixture
def earlier(tmp_path: Path) -> Path:
    """An output folder that already holds the study's results."""
    (tmp_path / "out" / "bad").mkdir(parents=True)
    (tmp_path / "out" / "bad" / "curves.csv").write_text(SENTINEL)
    return tmp_path


def _replace(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new)


@pytest.mark.parametrize(
    ("content", "names"),
    [
        (GOOD + "colour = 3\n", ["colour", "unknown key"]),
        (GOOD + "[quick]\nrunz = 3\n", ["quick.runz"]),
        (_replace(GOOD, '"table"]', '"table", "sofa"]'), ["features[2]", "sofa"]),
        (_replace(GOOD, '["laptop", "table"]', "[]"), ["features"]),
        (_replace(GOOD, "[1.0, -1.0]", "[1.0, -1.0, 0.5]"), ["theta_star", "2 weights"]),
        (GOOD + "theta0 = [0.0]\n", ["theta0"]),
        (GOOD + "cov0 = [[1.0, 2.0], [2.0, 1.0]]\n", ["cov0", "positive definite"]),
        (GOOD + "cov0 = [[1.0, 0.0]]\n", ["cov0", "2 x 2"]),
        (GOOD + 'user = "nobody"\n', ["user", "nobody", "unknown user"]),
        (GOOD + 'plugins = ["nowhere.py"]\n', ["plugins[0]", "nowhere.py", "cannot read"]),
        (GOOD + 'plugins = ["raises.py"]\n', ["plugins[0]", "raises.py", "ZeroDivisionError"]),
        (
            GOOD + 'environments = [{ name = "t", like = "s0-t0-l0", tilt = 5.0 }]\n',
            ["environments[0].tilt", "joint 6"],
        ),
        (
            GOOD + 'environments = [{ name = "t", like = "s7-t0-l0" }]\n',
            ["environments[0].like", "s7-t0-l0"],
        ),
        (_replace(GOOD, '["KF"]', '["KF", "XX"]'), ["learners[1]", "XX", "unknown learner"]),
        (GOOD + "user_step = 1.5\n", ["user.step", "(0, 1]"]),
        (GOOD + "[user]\nname = 'biased'\nstep = 1.5\n", ["user.step", "(0, 1]"]),
        (
            _replace(GOOD, 'learners = ["KF"]\n', "") + "[learners.KF]\ngain = 2\n",
            ["learners.KF.gain", "no such parameter"],
        ),
        (GOOD + "[filter]\nobservation_noise = -1\n", ["filter.observation_noise"]),
        (GOOD + "lapse = 0.5\n", ["lapse", "BP", "does not run"]),
        (GOOD + 'environments = ["s9-t9-l9"]\n', ["environments[0]", "s9-t9-l9"]),
        (
            GOOD + "environments = [" + MINE.replace("0.45, 0.50, 0.28", "1.5, 0.5, 0.3") + "]\n",
            ["environments[0].start", "unreachable"],
        ),
        (
            GOOD + "environments = [" + MINE.replace("0.45, 0.50, 0.28", "0.55, 0.3, 0.04") + "]\n",
            ["environments[0].start", "collides"],
        ),
        (
            GOOD + "environments = [" + MINE.replace("0.55, 0.05, 0.2", "0.95, 0.05, 0.2") + "]\n",
            ["environments[0].laptop", "off the table"],
        ),
        (
            GOOD
            + "environments = ["
            + MINE.replace("table = [0.55, 0.0]", "table = [0.9, 0.0]")
            + "]\n",
            ["environments[0]", "table"],
        ),
        (GOOD + "environments = [" + MINE + ", " + MINE + "]\n", ["environments[1].name"]),
        (GOOD + "environments = 48\n", ["environments"]),
        ("runs = 1\nruns = 2\n", ["invalid TOML", "line 2"]),
        ('features = ["laptop"]\nruns = = 3\n', ["invalid TOML", "line 2"]),
        (GOOD.replace("runs = 1", "runs = 99999999999999999"), ["runs", "100,000"]),
        (GOOD.replace("runs = 1", "runs = 0"), ["runs"]),
        (GOOD.replace("runs = 1", "runs = 2.5"), ["runs", "integer"]),
        (GOOD.replace("iterations = 1", "iterations = 10001"), ["iterations", "10,000"]),
        (GOOD + "seed = -1\n", ["seed"]),
        (GOOD + "n_starts = 7000\n", ["n_starts"]),
        (GOOD + "attenuation_points = 10000000000\n", ["attenuation_points"]),
        (
            GOOD.replace("runs = 1", "runs = 90000").replace("iterations = 1", "iterations = 30"),
            ["records"],
        ),
        (
            GOOD.replace("runs = 1", "runs = 20000").replace("iterations = 1", "iterations = 99"),
            ["planner solves", "environments"],
        ),
        (GOOD.replace("theta_star = [1.0, -1.0]\n", ""), ["theta_star", "missing"]),
        (GOOD + "person_restarts = -1\n", ["person_restarts", "integer"]),
        (GOOD + "person_restarts = 5000\n", ["person_restarts", "1,000"]),
        (GOOD + "person_restarts = 2.5\n", ["person_restarts", "integer"]),
        (GOOD + "person_restarts = true\n", ["person_restarts", "integer"]),
    ],
)
def test_bad_study_files_are_one_line_naming_the_key_and_file(earlier, capsys, content, names):
    path = earlier / "bad.toml"
    path.write_text(content)
    (earlier / "raises.py").write_text("1 / 0\n")
    status = _main(["study", str(path), "--out", str(earlier / "out")])
    err = capsys.readouterr().err
    assert status == 2, err
    assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err, err
    assert str(path) in err, err
    for name in names:
        assert name in err, err
    assert (earlier / "out" / "bad" / "curves.csv").read_text() == SENTINEL
    assert not (earlier / "out" / ".runs").exists()


def test_a_missing_file_and_a_missing_argument_are_named(tmp_path, capsys):
    assert _main(["study", str(tmp_path / "nowhere.toml"), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "nowhere.toml" in err and "cannot read" in err and err.count("\n") == 1
    assert _main(["study", "--out", str(tmp_path)]) == 2
    assert "study file" in capsys.readouterr().err
    assert _main(["fig4", str(tmp_path / "x.toml"), "--out", str(tmp_path)]) == 2
    assert "FILE: does not apply to fig4" in capsys.readouterr().err


def _fails_on_the_second_run(settings, shared, learner, run, alphas=None):
    if run == 1:
        raise ValueError("my learner cannot handle this environment")
    return learning_run_one(settings, shared, learner, run, alphas)


learning_run_one = runner.run_one


def test_a_plug_in_that_raises_is_one_line_and_finished_runs_are_kept(
    tmp_path, capsys, monkeypatch
):
    path = tmp_path / "mine.toml"
    path.write_text(GOOD.replace("runs = 1", "runs = 2"))

    @contextlib.contextmanager
    def threads(args):
        with ThreadPoolExecutor(max_workers=1) as pool:
            yield pool, "test threads"

    monkeypatch.setattr(figure_command, "open_executor", threads)
    monkeypatch.setattr(runner, "run_one", _fails_on_the_second_run)
    argv = ["study", str(path), "--out", str(tmp_path / "out")]
    assert _main(argv) == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if not line.startswith("mine: ")]  # progress
    assert len(errors) == 1 and errors[0].startswith("error: mine: a run failed"), err
    assert "ValueError: my learner cannot handle" in err and "Traceback" not in err, err
    assert "1 finished run kept" in err, err
    assert not (tmp_path / "out" / "mine").exists()

    monkeypatch.setattr(runner, "run_one", learning_run_one)
    assert _main(argv) == 0
    summary = json.loads((tmp_path / "out" / "mine" / "summary.json").read_text())
    assert summary["resumed_runs"] == 1


def test_sizes_are_refused_before_anything_is_built(monkeypatch):
    def no_environments(*args):
        raise AssertionError("environments were built for a study that cannot fit")

    monkeypatch.setattr(study_file, "parse_environments", no_environments)
    values = {"theta_star": [1.0, -1.0], "runs": 10**40, "iterations": 12}
    with pytest.raises(ValueError, match="runs"):
        study_file.parse_study(values)


def test_an_environment_sets_a_plug_in_features_parameter():
    """A study-file environment gives a registered extra parameter its own value (``extra``);
    one nobody registered is refused by its key path."""
    from corrections_sim.scene.environments import ENV_PARAMETERS, register_env_parameter

    register_env_parameter("test_person_x", default=0.5)
    try:
        values = {
            "theta_star": [1.0, -1.0],
            "environments": [
                {"name": "a", "like": "s0-t0-l0", "extra": {"test_person_x": 0.3}},
                {"name": "b", "like": "s0-t0-l0"},
            ],
        }
        settings = study_file.parse_study(values)
        a, b = settings.envs()
        assert a.param("test_person_x") == 0.3 and b.param("test_person_x") == 0.5
        assert settings.as_dict()["environments"][0]["extra"] == {"test_person_x": 0.3}
        values["environments"][0]["extra"] = {"test_persn_x": 0.3}
        with pytest.raises(ValueError, match=r"environments\[0\].extra.test_persn_x: not a"):
            study_file.parse_study(values)
    finally:
        ENV_PARAMETERS.unregister("test_person_x")


def test_the_learners_legend_covers_no_panel(tmp_path, monkeypatch):
    """Thirteen learners (fig. 4's) named inside a panel covered the curves they name: the
    legend sits under the panels, and every learner is in it once."""
    from corrections_sim.figures import style
    from corrections_sim.learning.base import LEARNERS

    names = [n for n in LEARNERS if n != "BP"][:13]
    rng = np.random.default_rng(0)
    curves = {
        n: {key: rng.random((3, 5)) + 0.1 for key in ("estimate_error", "regret", "regret_paper")}
        | {"nees": rng.random((3, 5)) + 0.1}
        for n in names
    }
    drawn = {}

    def keep(fig, paths, dpi):
        fig.tight_layout()
        drawn["fig"] = fig

    monkeypatch.setattr(style, "save_and_close", keep)
    learning_plot.plot_learning_curves(
        curves, "title", [tmp_path / "x.png"], bands={n: (0.5, 3.0) for n in names[:4]}
    )
    fig = drawn["fig"]
    renderer = fig.canvas.get_renderer()
    panels = [ax for ax in fig.axes if ax.get_visible() and ax.axison]
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    (learners,) = legends  # the learners and the calibration panel's bands, under the panels
    box = learners.get_window_extent(renderer)
    assert len(panels) == 4
    for ax in panels:
        assert not box.overlaps(ax.get_tightbbox(renderer)), ax.get_title()
    texts = [t.get_text() for t in learners.get_texts()]
    assert sorted(t.rsplit(", N = ")[0] for t in texts if ", N = " in t) == sorted(
        style.learner_label(n) for n in names
    )
    assert [t for t in texts if ", N = " not in t] == ["95% band of a calibrated mean of 3 runs"]
    style.plt.close(fig)


def test_figs_4_and_5_show_six_learners_each_its_own_and_the_recommended_robot_on_top(
    tmp_path, monkeypatch
):
    """Issue 68: the paper's three, the correction-aware two, and EX-M; no two drawn alike,
    EX-M thickest, on top and named the robot we recommend; the calibration panel says in
    words what the band means."""
    from corrections_sim.defaults import RECOMMENDED
    from corrections_sim.figures import style

    (names,) = {
        tuple(learning_study.load_settings(f, quick=q).study.learners)
        for f in learning_study.FIGURES
        for q in (False, True)
    }
    assert len(names) <= 6 and RECOMMENDED in names and {"PP", "KF", "AL"} <= set(names)
    rng = np.random.default_rng(0)
    curves = {
        n: {
            k: rng.random((3, 5)) + 0.1
            for k in ("estimate_error", "regret", "regret_paper", "nees")
        }
        for n in names
    }
    drawn = {}
    monkeypatch.setattr(style, "save_and_close", lambda fig, paths, dpi: drawn.update(fig=fig))
    learning_plot.plot_learning_curves(
        curves, "t", [tmp_path / "x.png"], bands={n: (0.5, 3.0) for n in names if n != "PP"}
    )
    fig = drawn["fig"]
    error = fig.axes[0]
    lines = {line.get_label(): line for line in error.get_lines()}
    assert len({(line.get_color(), line.get_linestyle()) for line in lines.values()}) == len(names)
    (ours,) = [label for label in lines if "the robot we recommend" in label]
    assert ours.startswith(style.learner_label(RECOMMENDED))
    assert lines[ours].get_linewidth() > max(
        line.get_linewidth() for label, line in lines.items() if label != ours
    )
    assert lines[ours].get_zorder() > max(
        line.get_zorder() for label, line in lines.items() if label != ours
    )
    calibration = fig.axes[3].get_title()
    assert "calibrated" in calibration and "over-confident" in calibration
    assert "PP: no covariance" in calibration
    style.plt.close(fig)


def test_a_flat_key_is_read_with_a_one_line_note_of_its_nested_spelling(tmp_path, capsys):
    """A study file written before components owned their parameters still loads, as the same
    study as its nested spelling, and says once per flat key how to write it now; the command
    line prints that as one ``note:`` line."""
    import warnings

    from corrections_sim.cli.main import _note
    from corrections_sim.study.legacy import OlderSpelling

    old, new = tmp_path / "old.toml", tmp_path / "new.toml"
    old.write_text(GOOD.replace('"KF"', '"KF-C"') + 'n_starts = 3\ncorrection_model = "deform"\n')
    new.write_text(
        GOOD.replace('learners = ["KF"]\n', "")
        + '[planner]\nn_starts = 3\n[learners.KF-C]\nmodel = "deform"\n'
    )
    with pytest.warns(OlderSpelling) as caught:
        before = study_file.load_study(old, name="s", quick=False)
    said = [str(w.message) for w in caught]
    assert said == [
        f"{old}: n_starts = 3 is an older spelling; write [planner] n_starts = 3 "
        "(docs/study-files.md)",
        f'{old}: correction_model = "deform" is an older spelling; write [learners.KF-C] '
        'model = "deform" (docs/study-files.md)',
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        after = study_file.load_study(new, name="s", quick=False)
    assert before.as_dict() == after.as_dict()
    _note(caught[0].message, OlderSpelling, "x.py", 1)
    assert capsys.readouterr().err == f"note: {said[0]}\n"


@pytest.mark.parametrize("name", ["fig4", "fig5", "three_features", "physical", "ferl"])
def test_the_shipped_study_files_are_in_the_nested_spelling(name):
    """The flagship study files are read without a note (the legacy reader is for files a
    user wrote before)."""
    import warnings

    from corrections_sim.study import files
    from corrections_sim.study.legacy import OlderSpelling, note_older_spellings

    path = Path(__file__).resolve().parents[1] / "experiments" / f"{name}.toml"
    values = files.read(path, quick=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", OlderSpelling)
        note_older_spellings(values, str(path))


def test_the_persons_restarts_default_with_the_atlas_and_enter_the_key_only_when_set(
    monkeypatch, tmp_path
):
    """``person_restarts``: 30 with an atlas, none without, unless set; the settings (and so a
    run's key) name it only where it differs from that default, so studies that do not set
    it keep their keys; set without an atlas, the person's plans get those restarts."""
    from corrections_sim.study.settings import PERSON_RESTARTS

    base = {"theta_star": [1.0, -1.0], "runs": 1, "iterations": 1, "learners": ["KF"]}
    books = study_file.parse_study(dict(base))
    atlas = study_file.parse_study({**base, "atlas": True})
    assert books.study.restarts() == 0 and atlas.study.restarts() == PERSON_RESTARTS
    assert "person_restarts" not in books.as_dict() and "person_restarts" not in atlas.as_dict()
    same = study_file.parse_study({**base, "atlas": True, "person_restarts": PERSON_RESTARTS})
    assert same.as_dict() == atlas.as_dict()
    assert study_file.parse_study({**base, "person_restarts": 0}).as_dict() == books.as_dict()
    mine = study_file.parse_study({**base, "person_restarts": 2})
    assert mine.study.restarts() == 2 and mine.as_dict()["person_restarts"] == 2
    from corrections_sim.plans import book, targets

    monkeypatch.setattr(targets, "store_root", lambda: tmp_path)  # solved here, not read
    asked = []
    own = book.own_starts
    monkeypatch.setattr(book, "own_starts", lambda *a: asked.append(a[-1]) or own(*a))
    envs = mine.envs()[:1]
    cold = books.person_target(envs)
    assert asked == []
    searched = mine.person_target(envs)
    assert asked == [2]
    assert searched.plans[0].reward >= cold.plans[0].reward - 1e-12


def test_a_process_solves_a_persons_plans_once_and_they_are_target_solves_own(
    monkeypatch, tmp_path
):
    """The person's plans (:meth:`FigureSettings.person_target`) are kept by the process: a
    second study of the same person (other learners, runs and seed: the FERL study's robots
    that know the person's feature, the relevance study's nudger) takes them without a solve,
    and they are Target.solve's to the bit; another θ*, other restarts or other environments
    are solved again."""
    from corrections_sim.planning.planner import shared_planner
    from corrections_sim.plans import book, targets

    monkeypatch.setattr(targets, "store_root", lambda: tmp_path)
    base = {"theta_star": [1.0, -1.0], "runs": 1, "iterations": 1, "person_restarts": 1}
    first = study_file.parse_study({**base, "learners": ["KF"]})
    other = study_file.parse_study({**base, "learners": ["KF-C"], "runs": 3, "seed": 7})
    envs = first.envs()[:2]
    made = first.person_target(envs)
    assert other.person_target(envs) is made
    planner = shared_planner(first.planner_config())  # with the study's atlas, as the person
    alone = book.Target.solve(planner, [1.0, -1.0], envs, atlas=first.atlas(), restarts=1)
    for kept, fresh in zip(made.plans, alone.plans, strict=True):
        assert np.array_equal(kept.trajectory, fresh.trajectory)
        assert np.array_equal(kept.features, fresh.features) and kept.reward == fresh.reward
    moved = study_file.parse_study({**base, "theta_star": [1.0, -0.5], "learners": ["KF"]})
    assert moved.person_target(envs) is not made
    assert first.person_target(envs[:1]) is not made
    more = study_file.parse_study({**base, "person_restarts": 2, "learners": ["KF"]})
    assert more.person_target(envs) is not made
