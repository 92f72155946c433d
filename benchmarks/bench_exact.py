"""What an exact learner's correction costs (``bench exact``): EX-C's and EX-CL's update, CPU
seconds a correction (median and 90th percentile), at fig. 4's paper settings (or a study
file's, ``--study``, with the learner's parameters as that file gives them) on its plan
atlas, in a fresh process whose store of plans between the atlas's nodes is

- **empty** (a machine's first time: every node of the refined cells solved, in every
  environment a correction was made in), then
- **full** (a second fresh process on what the first one left: every node read).

Each learner gets a store of its own (a temporary folder holding links to the machine's
compiled libraries and to the atlas's own nodes, built there first if the machine lacks them),
so neither is timed on the other's plans. Only the learner's update is timed; the run's regret
and the robot's plans, which every learner pays, are not.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CHILD = "--child"


def _overrides(runs: int, iterations: int | None, smaller: dict) -> dict:
    found: dict = {"runs": runs, **smaller}
    if iterations is not None:
        found["iterations"] = iterations
    return found


def _settings(figure: str, overrides: dict):
    """The paper-scale settings of ``figure``: a figure's name, or a study file's path."""
    from corrections_sim.figures.learning_study import load_settings
    from corrections_sim.study import schema

    if figure.endswith(".toml"):
        path = Path(figure)
        return schema.load_study(path, name=path.stem, quick=False, overrides=overrides)
    return load_settings(figure, quick=False, overrides=overrides)


def _measure(figure: str, learner: str, runs: int, iterations: int | None, smaller: dict) -> dict:
    """In this process: ``runs`` runs of ``learner`` with the parameters the study gives it,
    each update timed (CPU seconds)."""
    from corrections_sim.learning.exact.learners import ExactCorrectionAware
    from corrections_sim.study import runner

    times: list[float] = []
    update = ExactCorrectionAware.update

    def timed(self, *args, **kwargs):
        start = time.process_time()
        try:
            return update(self, *args, **kwargs)
        finally:
            times.append(time.process_time() - start)

    ExactCorrectionAware.update = timed  # EX-CL's is EX-C's: both are timed
    overrides = _overrides(runs, iterations, smaller)
    params = _settings(figure, overrides).study.learner_params().get(learner, {})
    settings = _settings(figure, {**overrides, "learners": {learner: params}})
    shared = runner.prepare(settings)
    for run in range(runs):
        runner.run_one(settings, shared, learner, run)
    return {"times": times}


def _store(root: Path) -> None:
    """``root``: links to the machine cache's compiled libraries and atlases (no plans
    between nodes, no interpolation cells)."""
    from corrections_sim.planning.planner import cache_dir

    machine = cache_dir()
    (root / "atlas").mkdir(parents=True)
    for path in machine.glob("*.so"):
        (root / path.name).symlink_to(path)
    for path in (machine / "atlas").glob("*"):
        if path.suffix in (".npy", ".json") and ".extra-" not in path.name:
            (root / "atlas" / path.name).symlink_to(path)


def _child(figure: str, learner: str, sizes: tuple, root: Path) -> list:
    env = dict(os.environ, CORRECTIONS_SIM_CACHE=str(root))
    runs, iterations, smaller = sizes
    args = [figure, learner, str(runs), str(iterations or 0), json.dumps(smaller)]
    done = subprocess.run(
        [sys.executable, "-m", "benchmarks.bench_exact", CHILD, *args],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"bench exact: the {learner} process failed: {tail}")
    return json.loads(done.stdout.strip().splitlines()[-1])["times"]


def run_bench(
    learners: tuple[str, ...] = ("EX-C", "EX-CL"),
    runs: int = 3,
    iterations: int | None = None,
    smaller: dict | None = None,
    figure: str = "fig4",
) -> list[str]:
    """The table of ``bench exact`` (module docstring); ``smaller``: overrides that shrink
    the figure's study (:mod:`benchmarks.sizes`); ``figure``: a figure's name or a study
    file's path."""
    from corrections_sim.plans import spread

    smaller = dict(smaller or {})
    settings = _settings(figure, _overrides(1, None, smaller))
    spec = settings.atlas_spec()
    if spec is None:
        return [f"{figure} has no plan atlas: no exact learner to time"]
    built = spread.prepare(spec, settings.envs())  # the machine's, before any timing
    lines = [
        f"{figure}, {runs} run(s) x {iterations or settings.study.iterations} corrections per "
        f"learner; the learner's update alone, CPU s a correction"
        + (f" ({built} atlas environments built first)" if built else ""),
        f"{'learner':8} {'store':6} {'median':>7} {'p90':>7} {'mean':>7} {'max':>7}",
    ]
    for learner in learners:
        with tempfile.TemporaryDirectory(prefix="bench-exact-") as scratch:
            root = Path(scratch)
            _store(root)
            for store in ("empty", "full"):
                sizes = (runs, iterations, smaller)
                t = np.array(_child(figure, learner, sizes, root))
                if not t.size:
                    lines.append(f"{learner:8} {store:6} no update was timed")
                    continue
                median, p90 = np.percentile(t, [50, 90])
                lines.append(
                    f"{learner:8} {store:6} {median:7.3f} {p90:7.3f} {t.mean():7.3f} {t.max():7.3f}"
                )
    return lines


if __name__ == "__main__" and len(sys.argv) == 7 and sys.argv[1] == CHILD:
    figure, learner = sys.argv[2], sys.argv[3]
    runs, iterations = int(sys.argv[4]), int(sys.argv[5])
    found = _measure(figure, learner, runs, iterations or None, json.loads(sys.argv[6]))
    print(json.dumps(found), flush=True)
