"""The reference beside a finished figure's runs (python -m corrections_sim.run reference):
the replayed corrections are the run's own, and the exact posterior on a coarse grid gives
finite NEES and KL for KF-C, for KF-CL (noise integrated out), for BP, for KF-CR (its
relevance integrated out) and for KF-CRP (θ, the person's rate and precision together)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from corrections_sim.cli import main as cli

STUDY = """\
theta_star = [1.0, -1.0]
runs = 1
iterations = 2
seed = 3
environments = ["s0-t0-l1", "s1-t1-l2"]
learners = ["KF-C", "KF-CL", "BP", "KF-CR", "KF-CRP"]
"""


@pytest.fixture(scope="module")
def figure(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ref")
    (folder / "tiny.toml").write_text(STUDY)
    argv = ["study", str(folder / "tiny.toml"), "--out", str(folder / "out"), "--workers", "1"]
    assert cli.main(argv) == 0
    return folder / "out" / "tiny"


@pytest.mark.parametrize("learner", ["KF-C", "KF-CL", "BP", "KF-CR", "KF-CRP"])
def test_the_reference_of_a_run(figure, learner, capsys):
    assert (
        cli.main(["reference", str(figure), "--learner", learner, "--runs", "1", "--points", "9"])
        == 0
    )
    with open(figure / f"reference-{learner}" / "records.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["iteration"]) for r in rows] == [1, 2]
    for r in rows:
        assert np.isfinite(float(r["ref_nees"])) and float(r["ref_kl"]) >= -1e-9
        assert float(r["ref_cov_00"]) > 0 and float(r["ref_cov_11"]) > 0
    summary = json.loads((figure / "summary.json").read_text())
    with open(figure / "curves.csv", newline="") as fh:
        curves = [c for c in csv.DictReader(fh) if c["learner"] == learner]
    assert [r["environment"] for r in rows] == [c["environment"] for c in curves[1:]]
    assert summary["settings"]["learners"][learner] is not None
    assert "ref NEES" in capsys.readouterr().out
    final = json.loads((figure / f"reference-{learner}" / "summary.json").read_text())
    assert final["learner"] == learner and final["iteration"] == 2 and final["runs"] == 1
    assert final["ratio"] > 0 and np.isfinite(final["ref_kl"])
    if learner == "KF-CRP":  # its exact β̂ beside the learner's, per correction
        for r in rows:
            assert 0.0 <= float(r["ref_relevance"]) <= 1.0 and float(r["relevance"]) > 0
            assert 0.0 < float(r["ref_relevance_rate"]) < 1.0
        assert "relevance_gap" in final


def test_a_reference_of_other_settings_replaces_an_earlier_one_only_with_force(figure, capsys):
    """``run reference`` writes ``<figure>/reference-<learner>/`` (its records, its summary
    with the settings): run again with the same settings it is replaced (its runs resumed
    from the cache), with other settings it is refused in one line and the earlier files
    stay as they were."""
    argv = ["reference", str(figure), "--learner", "KF-C", "--runs", "1", "--points", "9"]
    assert cli.main([*argv, "--force"]) == 0
    folder = figure / "reference-KF-C"
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert json.loads(before["summary.json"])["settings"]["points"] == 9
    assert cli.main(argv) == 0  # the same settings: replaced, the same records
    assert (folder / "records.csv").read_bytes() == before["records.csv"]
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    capsys.readouterr()
    assert cli.main([*argv[:-1], "11"]) == 2
    err = capsys.readouterr().err
    assert "made with other settings" in err and "--force" in err and err.count("\n") == 1
    assert (folder / "records.csv").read_bytes() == before["records.csv"]
    assert (folder / "summary.json").read_bytes() == before["summary.json"]


def test_a_kept_reference_run_is_not_reused_for_other_recorded_rows(figure, tmp_path):
    """The reference's runs are kept under ``<figure>/.runs/`` keyed by the figure's
    settings, the options, the code and the learner's recorded rows: a figure whose rows
    changed (here θ̂ after the first correction, as another version of a learner would
    record) gets its reference computed again, not the kept one."""
    import shutil

    copy = tmp_path / "tiny"
    shutil.copytree(figure, copy, ignore=shutil.ignore_patterns("reference-*", ".runs"))
    argv = ["reference", str(copy), "--learner", "KF-C", "--runs", "1", "--points", "9"]
    assert cli.main(argv) == 0
    first = (copy / "reference-KF-C" / "records.csv").read_text()
    with open(copy / "curves.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    moved = next(r for r in rows if r["learner"] == "KF-C" and r["iteration"] == "1")
    moved["theta_0"] = repr(float(moved["theta_0"]) + 0.5)  # the plan shown next moves
    with open(copy / "curves.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    assert cli.main(argv) == 0
    again = (copy / "reference-KF-C" / "records.csv").read_text()
    assert again != first  # recomputed from the new rows, not loaded
    keys = [d for d in (copy / ".runs" / "reference-KF-C").iterdir() if d.is_dir()]
    assert len(keys) == 2  # one kept set of runs for each set of recorded rows


def test_reference_plot_reads_a_figures_references_and_collected_ones(figure, tmp_path):
    """``reference-plot`` reads a figure's ``reference-<learner>/summary.json`` (the panel
    named by the figure its settings name) and collected ``<figure>-<learner>.json`` files."""
    from corrections_sim.figures.reference_plot import reference_panels

    argv = ["reference", str(figure), "--learner", "KF-C", "--runs", "1", "--points", "9"]
    assert cli.main([*argv, "--force"]) == 0
    summary = json.loads((figure / "reference-KF-C" / "summary.json").read_text())
    panels = reference_panels(figure)
    assert panels["tiny"]["KF-C"] == summary["by_iteration"]
    (tmp_path / "fig9-KF-C.json").write_text(json.dumps(summary))
    assert reference_panels(tmp_path) == {"fig9": {"KF-C": summary["by_iteration"]}}
    assert cli.main(["reference-plot", str(figure)]) == 0
    assert (figure / "calibration.png").stat().st_size > 10_000


def test_a_learner_the_figure_did_not_run_is_one_line(figure, capsys):
    assert cli.main(["reference", str(figure), "--learner", "KF"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --learner KF: not in this figure") and err.count("\n") == 1
    assert cli.main(["reference", str(figure), "--learner", "KF-C", "--axes", "narrow"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --axes narrow: cuts only a refined grid's cells") and (
        err.count("\n") == 1
    )


def test_one_filter_step_from_the_reference(figure, capsys):
    """``--one-step``: the learner's update from the reference before each correction. At the
    first correction it starts from the prior, as the learner itself did, so it is the
    learner's own first step (up to the grid's moments of the prior)."""
    argv = [str(figure), "--learner", "KF-CR", "--runs", "1", "--points", "41", "--one-step"]
    assert cli.main(["reference", *argv, "--restart", "0,1", "--force"]) == 0
    with open(figure / "reference-KF-CR" / "records.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    first = rows[0]
    assert float(first["one_step_nees"]) == pytest.approx(float(first["nees"]), rel=0.05)
    assert all(float(r["one_step_kl"]) >= -1e-9 for r in rows)
    # Run on from the reference after the first correction, the second step is one step.
    assert float(rows[1]["restart_1_nees"]) == pytest.approx(float(rows[1]["one_step_nees"]))
    # Run on from the prior, the filter is the learner replayed (plans solved cold here).
    assert float(rows[1]["restart_0_nees"]) == pytest.approx(float(rows[1]["nees"]), rel=0.1)
    assert "one filter step from the reference" in capsys.readouterr().out
    assert cli.main(["reference", str(figure), "--learner", "KF-CL", "--one-step"]) == 2
    assert "--one-step and --restart need a Kalman learner" in capsys.readouterr().err
    assert cli.main(["reference", str(figure), "--learner", "KF-C", "--restart", "x"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --restart x: expected iterations") and err.count("\n") == 1


THREE = """\
features = ["laptop", "table", "coffee"]
theta_star = [1.0, -1.0, -1.0]
theta0 = [0.0, 0.0, 0.0]
cov0 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
runs = 1
iterations = 2
seed = 3
environments = ["s0-t0-l1", "s1-t1-l2"]
warm_start = true

[learners.PP]
fixed_alpha = 0.2

[learners."KF-C"]
"""


def test_the_particle_reference_at_k_3_and_against_the_grid_at_k_2(figure, tmp_path, capsys):
    """Beyond k = 2 the particles are the reference (no grid there: asked without them, one
    line); at k = 2 they are judged against the grid; a learner without a covariance and a
    particle count < 2 are refused in one line; every iteration's summary has its CIs."""
    (tmp_path / "three.toml").write_text(THREE)
    argv = ["study", str(tmp_path / "three.toml"), "--out", str(tmp_path / "out"), "--workers", "1"]
    assert cli.main(argv) == 0
    three = tmp_path / "out" / "three"
    capsys.readouterr()
    assert cli.main(["reference", str(three), "--learner", "PP"]) == 2
    err = capsys.readouterr().err
    assert err == "error: learner PP: has no covariance to judge against a reference\n"
    assert cli.main(["reference", str(three), "--learner", "KF-C"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: k = 3: no grid beyond k = 2") and err.count("\n") == 1
    assert cli.main(["reference", str(three), "--learner", "KF-C", "--check-grid"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --check-grid: only at k = 2, not 3") and err.count("\n") == 1
    assert cli.main(["reference", str(three), "--learner", "KF-C", "--particles", "1"]) == 2
    assert "--particles 1: expected an integer >= 2" in capsys.readouterr().err
    assert cli.main(["reference", str(three), "--learner", "KF-C", "--particles", "40"]) == 0
    final = json.loads((three / "reference-KF-C" / "summary.json").read_text())
    assert [s["iteration"] for s in final["by_iteration"]] == [1, 2]
    assert "ref_kl" not in final and final["ref_kl_gaussian"] >= 0.0
    assert final["ratio"] > 0 and len(final["ratio_ci95"]) == 2
    with open(three / "reference-KF-C" / "records.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert all(float(r["ref_cov_22"]) > 0 for r in rows)
    # At k = 2, 300 particles against the grid on the same corrections.
    argv = [str(figure), "--learner", "KF-C", "--runs", "1", "--points", "31", "--particles", "300"]
    assert cli.main(["reference", *argv, "--force"]) == 0  # KF-C's reference was on 9 points
    final = json.loads((figure / "reference-KF-C" / "summary.json").read_text())
    assert final["particle_mean_gap"] < 0.3 and final["particle_var_gap"] < 0.3
    assert 0.0 <= final["particle_kl"] < 0.3
    assert "particles against the grid" in capsys.readouterr().out


def test_with_a_plan_atlas_the_reference_has_a_grid_at_k_3():
    """The three-feature study plans from an atlas: its reference's grid is the atlas's box
    at k = 3 (refined as its exact learners refine theirs); without the atlas, no grid."""
    from corrections_sim.figures import reference
    from corrections_sim.study import schema

    path = Path(__file__).resolve().parents[1] / "experiments" / "three_features.toml"
    settings = schema.load_study(path, name="three_features", quick=False)
    grid = reference.reference_grid(settings, None)
    box = settings.atlas_spec().grid
    assert grid is not None and grid.thetas().shape == (11**3, 3)
    assert (grid.low, grid.high, grid.points) == (tuple(box.lows), tuple(box.highs), 11)
    no_atlas = {"atlas": False, "learners": ["KF", "KF-C"]}
    without = schema.load_study(path, name="three_features", quick=False, overrides=no_atlas)
    assert reference.reference_grid(without, None) is None
