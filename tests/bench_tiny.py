"""Running a benchmark at its tiny size (``bench <what> --tiny``) for the tests of
``test_bench.py`` and ``test_bench_browser.py``."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: The benchmarks that open chromium (run with the browser tests).
IN_A_BROWSER = ("interact", "questionnaire", "catch")


def run_tiny(what: str, tmp_path: Path) -> str:
    """``bench <what> --tiny`` in a fresh process, from a scratch folder (a benchmark that
    writes into the working folder writes there), its output; failing with its last lines."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    done = subprocess.run(
        [sys.executable, "-m", "benchmarks.bench", what, "--tiny"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    out = done.stdout + done.stderr
    assert done.returncode == 0, f"bench {what} --tiny failed:\n" + "\n".join(
        out.splitlines()[-25:]
    )
    assert "Traceback" not in out, out
    assert done.stdout.strip(), f"bench {what} --tiny printed nothing"
    return done.stdout
