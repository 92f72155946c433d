"""The benchmarks that drive chromium, at their tiny size (see ``test_bench.py``)."""

from __future__ import annotations

import pytest
from bench_tiny import IN_A_BROWSER, run_tiny

pytestmark = pytest.mark.browser


@pytest.mark.parametrize("what", IN_A_BROWSER)
def test_it_runs_at_its_tiny_size(what, tmp_path):
    assert len(run_tiny(what, tmp_path).splitlines()) >= 2
    # A check, not a measurement: its session log is a scratch file, not results/interact/.
    assert not (tmp_path / "results").exists()
