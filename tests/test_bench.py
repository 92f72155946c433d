"""Every benchmark runs (``python -m benchmarks.bench <what> --tiny``), so that none rots
unnoticed: a benchmark that measures something the code no longer does (``bench warm`` once
watched a method fig. 4 had stopped calling, and crashed) fails here, not on the day someone
needs its numbers. Tiny sizes only: the numbers printed mean nothing, and no timing is asserted.
The ones that drive chromium are in ``test_bench_browser.py``."""

from __future__ import annotations

import pytest
from bench_tiny import IN_A_BROWSER, run_tiny

from benchmarks import bench


def test_every_benchmark_has_a_tiny_size_and_a_test():
    """A new benchmark without a tiny size (or without a test here) fails at once."""
    assert set(bench.TINY) == set(bench.SUBCOMMANDS)
    tested = set(SPLIT[0]) | set(SPLIT[1]) | set(IN_A_BROWSER) | {"exact"}
    assert tested == set(bench.SUBCOMMANDS)


#: The benchmarks run here, in two classes (each goes to a worker of its own; ``exact`` has
#: a test of its own below).
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


def test_a_bad_tiny_request_is_one_line():
    with pytest.raises(SystemExit):
        bench.main(["nonsense", "--tiny"])


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["exact", "--study", "missing.toml"], "--study missing.toml: not a study file"),
        (["atlas", "--study", "experiments/three_features.toml"], "only exact takes a study"),
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
    """``--study`` names a study file for ``exact`` alone, with its own environments, and
    ``--cluster`` is ``exact``'s alone: anything else is refused in one line before anything
    is built."""
    with pytest.raises(SystemExit):
        bench.main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in err if line.startswith("python -m benchmarks.bench: error:")]
    assert len(errors) == 1 and message in errors[0] and err[-1] == errors[0]
