"""``run coverage``: the credible regions judged for people the robot's model does not hold
(issue 67, item 2). The machinery at CI's size; the statistic is the committed study's."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from corrections_sim.cli import main as cli
from corrections_sim.figures import coverage
from corrections_sim.study import runner
from corrections_sim.study import sbc as core


def test_coverage_counts_levels_at_or_below_each_region_with_a_wilson_interval():
    rows = [{"level": v, "nees": 1.0, "estimate_error": 0.1} for v in (0.1, 0.5, 0.6, 0.95)]
    found = core.coverage_of(rows)
    assert found["runs"] == 4
    assert found["coverage_50"]["share"] == 0.5 and found["coverage_90"]["share"] == 0.75
    lo, hi = found["coverage_50"]["ci95"]
    assert lo < 0.5 < hi and lo > 0.0 and hi < 1.0
    assert found["mean_level"] == pytest.approx(np.mean([0.1, 0.5, 0.6, 0.95]))
    assert core.coverage_of([])["coverage_90"]["share"] is None


def test_a_judged_run_is_the_matrix_s_own_run():
    """The run judged is the study's: the same draws, so the same error as the run the
    matrix itself makes (its records), and a level in [0, 1]."""
    settings = coverage.load_settings(quick=True, overrides={})
    person = settings.people[1]
    shared = runner.prepare(person.settings)
    own = runner.run_one(person.settings, shared, "EX-M", 0)
    row = core.judged_run(person.settings, shared, "EX-M", 0)
    last = person.settings.study.iterations
    assert row["iteration"] == last
    assert row["estimate_error"] == own.records[last]["estimate_error"]
    assert row["nees"] == own.records[last]["nees"]
    assert 0.0 <= row["level"] <= 1.0


def test_the_command_writes_its_files_and_resumes(tmp_path):
    argv = ["coverage", "--quick", "--out", str(tmp_path), "--workers", "1"]
    assert cli.main(argv) == 0
    folder = tmp_path / "coverage"
    with open(folder / "runs.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    settings = coverage.load_settings(quick=True, overrides={})
    assert len(rows) == len(settings.people) * len(settings.learners) * settings.runs
    assert {r["learner"] for r in rows} == set(settings.learners)
    assert all(0.0 <= float(r["level"]) <= 1.0 for r in rows)
    summary = json.loads((folder / "summary.json").read_text())
    for person in settings.people:
        for learner in settings.learners:
            entry = summary["coverage"][person.key][learner]
            assert entry["runs"] == settings.runs
            assert entry["coverage_90"]["share"] in (0.0, 1.0)  # one run each
    assert (folder / "coverage.png").stat().st_size > 10_000
    before = (folder / "runs.csv").read_bytes()
    assert cli.main([*argv, "--force"]) == 0
    again = json.loads((folder / "summary.json").read_text())
    assert again["resumed_runs"] == len(rows)
    assert (folder / "runs.csv").read_bytes() == before


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--learners", "KF,PP"], "learners: PP has no posterior to judge"),
        (["--learners", "NOPE"], "NOPE"),
    ],
)
def test_bad_input_is_one_line(tmp_path, capsys, argv, message):
    assert cli.main(["coverage", "--quick", "--out", str(tmp_path), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert not (tmp_path / "coverage").exists()
