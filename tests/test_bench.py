"""Every benchmark runs (``python -m benchmarks.bench <what> --tiny``), so that none rots
unnoticed: a benchmark that measures something the code no longer does (``bench warm`` once
watched a method fig. 4 had stopped calling, and crashed) fails here, not on the day someone
needs its numbers. Tiny sizes only: the numbers printed mean nothing, and no timing is asserted.
The ones that drive chromium are in ``test_bench_browser.py``."""

from __future__ import annotations

import re

import pytest
from bench_tiny import IN_A_BROWSER, run_tiny

from benchmarks import bench


def test_every_benchmark_has_a_tiny_size_and_a_test():
    """A new benchmark without a tiny size (or without a test here) fails at once."""
    assert set(bench.TINY) == set(bench.SUBCOMMANDS)
    tested = set(SPLIT[0]) | set(SPLIT[1]) | set(IN_A_BROWSER) | {"exact", "split", "main"}
    assert tested == set(bench.SUBCOMMANDS)


#: The benchmarks run here, in two classes (each goes to a worker of its own; ``exact`` and
#: ``split`` have tests of their own below).
SPLIT = (
    ("planner", "fig4", "warm", "learnt", "atlas"),
    ("physical", "relevance", "confidence", "study", "particles"),
)


class TestBenchmarksA:
    @pytest.mark.parametrize("what", SPLIT[0])
    def test_it_runs_at_its_tiny_size(self, what, tmp_path):
        lines = run_tiny(what, tmp_path).splitlines()
        assert len(lines) >= 2


class TestBenchmarksB:
    @pytest.mark.parametrize("what", SPLIT[1])
    def test_it_runs_at_its_tiny_size(self, what, tmp_path):
        lines = run_tiny(what, tmp_path).splitlines()
        assert len(lines) >= 2


def test_exact_reports_an_empty_and_a_full_store_per_learner(tmp_path):
    """``bench exact``'s table (EX-C alone at the tiny size): a row per store, with numbers."""
    out = run_tiny("exact", tmp_path)
    rows = [line.split() for line in out.splitlines() if line.startswith("EX-")]
    assert [(r[0], r[1]) for r in rows] == [("EX-C", "empty"), ("EX-C", "full")]
    for r in rows:
        assert all(float(v) >= 0 for v in r[2:6])


def test_split_gives_each_learner_a_row_whose_parts_add_up(tmp_path):
    """``bench split``'s table (KF and EX-C at the tiny size): a row per learner whose regret
    metric and update are parts of its run (not counted twice: the rest is not negative), and
    a total over the study's runs."""
    out = run_tiny("split", tmp_path)
    rows = {
        cells[0]: cells[1:]
        for cells in (
            [c.strip() for c in line.strip("|").split("|")]
            for line in out.splitlines()
            if line.startswith("| ")
        )
    }
    assert {"KF", "EX-C", "all"} <= set(rows)
    for name in ("KF", "EX-C"):
        runs, each, regret, update, other, solves, study = (float(v) for v in rows[name][:7])
        assert runs == 1 and each > 0 and solves > 0 and study == 100
        assert (
            regret >= 0 and update > 0 and each == pytest.approx(regret + update + other, abs=0.02)
        )


def test_a_bad_tiny_request_is_one_line():
    with pytest.raises(SystemExit):
        bench.main(["nonsense", "--tiny"])


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["exact", "--study", "missing.toml"], "--study missing.toml: not a study file"),
        (["warm", "--study", "experiments/three_features.toml"], "only exact and atlas take"),
        (
            ["atlas", "--study", "experiments/three_features.toml", "--coarse", "2"],
            "--coarse 2: a coarse grid needs >= 3 points",
        ),
        (
            ["exact", "--study", "experiments/three_features.toml", "--study-envs", "2"],
            "a study file has its own",
        ),
        (["atlas", "--cluster"], "only exact runs on a cluster"),
        (["warm", "--pool"], "only exact compares a pool's sharing"),
        (["exact", "--pool", "--cluster"], "one at a time"),
    ],
)
def test_a_study_the_benchmark_cannot_take_is_one_line(argv, message, capsys):
    """``--study`` names a study file for ``exact`` and ``atlas`` alone, with its own
    environments, and ``--cluster`` is ``exact``'s alone: anything else is refused in one line
    before anything is built."""
    with pytest.raises(SystemExit):
        bench.main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in err if line.startswith("python -m benchmarks.bench: error:")]
    assert len(errors) == 1 and message in errors[0] and err[-1] == errors[0]


def test_atlas_compares_a_studys_levels_on_its_own_box(tmp_path, capsys):
    """``bench atlas --study``: the study's atlas, a coarse level and a lazily solved finer
    one, each within 1% of the best answer on some share of the problems, and the finer
    level's nodes counted (a one-environment study at 3 points a weight: a check that it
    runs, not a measurement)."""
    study = tmp_path / "tiny.toml"
    study.write_text(
        'theta_star = [1.0, -1.0]\nruns = 1\niterations = 1\nenvironments = ["s0-t0-l1"]\n'
        "atlas = { points = 3 }\n"
    )
    argv = ["atlas", "--study", str(study), "--coarse", "3", "--problems", "2"]
    bench.main([*argv, "--restarts", "1"])
    out = capsys.readouterr().out
    shares = re.findall(r"within 1% on ([0-9.]+)% of 2,", out)
    assert len(shares) == 5 and all(0.0 <= float(v) <= 100.0 for v in shares), out
    asked = re.findall(r"(\d+) nodes asked for", out)
    assert len(asked) == 2 and all(int(n) > 0 for n in asked), out


def test_main_times_the_main_job_from_an_empty_cache_and_again(tmp_path):
    """``bench main`` at the quick preset: both rows (an empty cache, then all cached but the
    runs) with a wall time and the runs found in the progress lines, and the verdict on the
    two curves (the same code and cache: identical)."""
    out = run_tiny("main", tmp_path)
    rows = [line.split() for line in out.splitlines() if line.startswith(("empty", "all cached"))]
    assert len(rows) == 2
    assert "the two runs' curves.csv: byte-identical" in out
