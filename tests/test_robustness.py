"""Fig. 6, the robustness matrix (learners × simulated users), on its quick preset through
the command line: every cell is filled, the random user gets every learner N runs, the files
are written, and the correction-aware filter is calibrated for the user it models."""

from __future__ import annotations

import csv
import json

import pytest

from corrections_sim.cli import main as cli
from corrections_sim.figures import robustness
from corrections_sim.learning.base import LEARNERS


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("fig6")
    assert cli.main(["fig6", "--quick", "--workers", "2", "--out", str(out)]) == 0
    return robustness.load_settings(quick=True), out / "fig6"


def test_every_cell_is_filled_and_the_files_are_written(quick):
    settings, folder = quick
    assert {p.name for p in folder.iterdir()} == {
        "curves.csv",
        "matrix.csv",
        "summary.json",
        "fig6.png",
        "fig6.pdf",
    }
    with open(folder / "matrix.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    users = [c.label for c in settings.columns]
    assert [(r["learner"], r["user"]) for r in rows] == [
        (learner, user) for user in users for learner in settings.learners
    ]
    runs = settings.columns[0].settings.study.runs
    for r in rows:
        random_user = r["user"] == "noisy-optimal"
        active = LEARNERS[r["learner"]].active  # AL, AL-C, AL-CL: one run, deterministic
        assert int(r["runs"]) == (1 if active and not random_user else runs), r
        assert float(r["estimate_error_mean"]) >= 0.0 and float(r["regret_mean"]) >= 0.0
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["planner_solves"] > 0 and len(summary["matrix"]) == len(rows)
    # The summary's runs are the matrix's: per column where the columns differ (an active
    # learner runs once for a deterministic person and N times for the random one).
    for learner, given in summary["runs_per_learner"].items():
        cells = {r["user"]: int(r["runs"]) for r in rows if r["learner"] == learner}
        expected = cells if len(set(cells.values())) > 1 else cells[users[0]]
        assert given == expected, learner
    assert isinstance(summary["runs_per_learner"]["AL"], dict)


def test_kf_c_is_calibrated_for_the_user_it_models_and_kf_is_not(quick):
    _, folder = quick
    with open(folder / "matrix.csv", newline="") as fh:
        cells = {(r["learner"], r["user"]): r for r in csv.DictReader(fh)}

    def inside(learner: str) -> bool:
        r = cells[(learner, "biased (paper)")]
        return float(r["nees_band_low"]) <= float(r["nees_final"]) <= float(r["nees_band_high"])

    assert inside("KF-C") and not inside("KF")
    assert cells[("PP", "biased (paper)")]["nees_final"] == ""  # no covariance: an empty cell


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        ({"user": "noisy"}, "user"),
        ({"user_step": 0.5}, "user_step"),
        ({"learners": ("PP", "XX")}, "learners"),
        ({"runs": 0}, "runs"),
    ],
)
def test_bad_overrides_are_refused_by_name(overrides, match):
    with pytest.raises(ValueError, match=match):
        robustness.load_settings(quick=True, overrides=overrides)


def test_a_column_is_set_by_index_or_label_and_a_study_theta_never_skips_one_silently():
    def load(*items, **options):
        return robustness.load_settings(
            quick=True, overrides={**options, "set": list(items)}, figure="relevance"
        )

    moved = load(
        "columns.1.theta_star=[2.0, -2.0, -3.0]",
        "columns.minds only the person.theta_star=[0.0, 0.0, -4.0]",
        theta_star=(2.0, -2.0),
    )
    persons = {c.label: c.settings.study.user_theta for c in moved.columns}
    assert persons["also minds the person"] == pytest.approx([2.0, -2.0, -3.0])
    assert persons["minds only the person"] == pytest.approx([0.0, 0.0, -4.0])
    assert moved.columns[0].settings.study.theta_star == (2.0, -2.0)  # the study-wide θ*
    assert moved.columns[2].settings.study.theta_star == (2.0, -2.0)
    # Without the two columns' own θ*, the study-wide one would leave them at the file's.
    with pytest.raises(ValueError, match=r"theta_star: column 1 \(also minds the person\)"):
        load(theta_star=(2.0, -2.0))
    with pytest.raises(ValueError, match=r"theta_star: column 3 "):
        load("columns.1.theta_star=[2.0, -2.0, -2.0]", "theta_star=[2.0, -2.0]")
    with pytest.raises(ValueError, match=r"--set columns\.9\.theta_star=\[1\]: expected"):
        load("columns.9.theta_star=[1]")
    with pytest.raises(ValueError, match=r"columns\[1\] \(also minds the person\): theta_star"):
        load("columns.1.theta_star=[1.0, 2.0]")


def test_the_summary_is_strict_json(quick):
    _, folder = quick

    def refuse(constant):
        raise ValueError(f"{constant} is not JSON")

    json.loads((folder / "summary.json").read_text(), parse_constant=refuse)


def test_each_column_reports_the_atlas_build_as_its_own_phase(monkeypatch):
    """A matrix's columns get the command's progress with its ``phase``, so building a plan
    atlas (minutes, in the first column) is shown as fig. 4's and fig. 5's is."""
    from corrections_sim.figures import robustness
    from corrections_sim.study import runner

    seen = []
    monkeypatch.setattr(runner, "run", lambda s, e, report, **kw: seen.append(report))
    monkeypatch.setattr(runner, "tasks", lambda s: [0, 1])

    class Progress:
        def __call__(self, done: int, total: int) -> None:
            self.last = (done, total)

        def phase(self, label: str, unit: str):
            return (label, unit)

    settings = robustness.load_settings(quick=True)
    progress = Progress()
    robustness.run(settings, executor=None, progress=progress)
    assert len(seen) == len(settings.columns) == 5
    assert all(r.phase("atlas", "environment") == ("atlas", "environment") for r in seen)
    seen[-1](2, 2)  # the last column's runs done: all of the matrix's
    assert progress.last == (10, 10)
