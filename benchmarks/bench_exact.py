"""What an exact learner's correction costs (``bench exact``): EX-C's, EX-CL's (and, with
``--learners``, EX-M's) update, CPU
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
    from corrections_sim.learning.exact.mixture import ExactPersonModel
    from corrections_sim.learning.relevance.asking import AskingPersonModel
    from corrections_sim.study import runner

    times: list[float] = []
    depth = [0]  # EX-M's update calls its models' EX-CL updates: only the outermost counts

    def timing(update):
        def timed(self, *args, **kwargs):
            start = time.process_time()
            depth[0] += 1
            try:
                return update(self, *args, **kwargs)
            finally:
                depth[0] -= 1
                if depth[0] == 0:
                    times.append(time.process_time() - start)

        return timed

    # EX-CL's update is EX-C's; EX-M's calls it once for each of its models, and EX-M as
    # registered (AskingPersonModel) calls the posterior's, then judges whether to ask.
    for cls in (ExactCorrectionAware, ExactPersonModel, AskingPersonModel):
        cls.update = timing(cls.__dict__["update"])
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


def _in_child(args: list[str], root: Path, what: str) -> dict:
    """``python -m benchmarks.bench_exact <args>`` in a fresh process whose store is
    ``root``: the JSON of its last line; failing with its last error line, ``what`` said."""
    env = dict(os.environ, CORRECTIONS_SIM_CACHE=str(root))
    done = subprocess.run(
        [sys.executable, "-m", "benchmarks.bench_exact", *args],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"bench exact: {what} failed: {tail}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _child(figure: str, learner: str, sizes: tuple, root: Path) -> list:
    runs, iterations, smaller = sizes
    args = [CHILD, figure, learner, str(runs), str(iterations or 0), json.dumps(smaller)]
    return _in_child(args, root, f"the {learner} process")["times"]


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


def _with_learners(
    figure: str, learners: tuple[str, ...], runs: int, iterations: int | None, smaller
) -> dict:
    """The overrides of ``runs`` runs of ``learners`` alone, each with the parameters the
    study gives it."""
    overrides = _overrides(runs, iterations, dict(smaller or {}))
    params = _settings(figure, overrides).study.learner_params()
    return {**overrides, "learners": {name: params.get(name, {}) for name in learners}}


def run_cluster(
    learners: tuple[str, ...] = ("EX-C", "EX-CL"),
    runs: int = 3,
    iterations: int | None = None,
    smaller: dict | None = None,
    figure: str = "fig4",
) -> list[str]:
    """``bench exact --cluster``: the study's runs of ``learners`` on a Dask cluster of two
    workers whose caches are folders of their own (the compiled code linked, no atlas, no plan
    between nodes: machines that share no files), once without the plan exchange and once
    with it, each on a fresh cluster: the plans between the atlas's nodes the workers solved,
    against the distinct plans the runs needed, the wall time, and whether the records agree."""
    from distributed import Client, Nanny, Scheduler, SpecCluster

    from corrections_sim.cli.executors import dask_executor
    from corrections_sim.planning.planner import cache_dir
    from corrections_sim.plans import spread
    from corrections_sim.study import runner

    settings = _settings(figure, _with_learners(figure, learners, runs, iterations, smaller))
    spec = settings.atlas_spec()
    if spec is None:
        return [f"{figure} has no plan atlas: no exact learner to share plans for"]
    spread.prepare(spec, settings.envs())  # this process hands the atlases to the workers

    def solved() -> int:
        return settings.atlas().solved_between

    def once(exchange: bool, root: Path) -> tuple[int, int, float, tuple]:
        workers = {}
        for name in ("a", "b"):
            cache = root / name
            cache.mkdir(parents=True)
            for path in cache_dir().glob("*.so"):
                (cache / path.name).symlink_to(path)
            env = {"CORRECTIONS_SIM_CACHE": str(cache)}
            workers[name] = {"cls": Nanny, "options": {"nthreads": 1, "env": env}}
        scheduler = {"cls": Scheduler, "options": {"host": "127.0.0.1", "dashboard_address": None}}
        made: list = []
        with SpecCluster(workers=workers, scheduler=scheduler, asynchronous=False) as cluster:
            with dask_executor(cluster.scheduler_address, 30.0) as (executor, _):
                if exchange:
                    make = executor.exchange
                    executor.exchange = lambda: made.append(make()) or made[-1]
                else:
                    del executor.exchange
                start = time.perf_counter()
                result = runner.run(settings, executor, mean_estimate=False)
                wall = time.perf_counter() - start
                distinct = 0
                if made:
                    items, _ = made[0].since(0).result()
                    distinct = len({(e.key(), t.tobytes()) for e, _, th, _ in items for t in th})
            with Client(cluster) as client:
                total = sum(client.run(solved).values())
        return total, distinct, wall, tuple(map(tuple, (r.items() for r in result.records)))

    lines = [
        f"{figure}, {', '.join(learners)}: {runs} run(s) each on a Dask cluster of 2 workers, "
        "a cache folder each (no shared files), plans between the atlas's nodes solved:",
        f"{'exchange':10} {'solved':>8} {'distinct':>9} {'per plan':>9} {'wall s':>7}",
    ]
    with tempfile.TemporaryDirectory(prefix="bench-cluster-") as scratch:
        without = once(False, Path(scratch) / "without")
        within = once(True, Path(scratch) / "with")
    distinct = within[1]
    for name, (total, _, wall, _) in (("without", without), ("with", within)):
        per = f"{total / distinct:9.2f}" if distinct else f"{'-':>9}"
        lines.append(f"{name:10} {total:8d} {distinct:9d} {per} {wall:7.1f}")
    same = "the same" if without[3] == within[3] else "DIFFERENT"
    lines.append(f"records with and without the exchange: {same}")
    return lines


POOL_CHILD = "--pool-child"


def _pool_pass(figure: str, overrides: dict, exchange: bool) -> dict:
    """In this process (a store of its own): the study's runs on a pool of 2 workers, with
    the command's pool (its plan exchange) or a plain one; wall seconds and the plans between
    nodes its workers saved (all, and distinct)."""
    from concurrent.futures import ProcessPoolExecutor

    from corrections_sim.cli.executors import process_pool
    from corrections_sim.planning.planner import cache_dir
    from corrections_sim.study import runner

    settings = _settings(figure, overrides)
    start = time.perf_counter()
    if exchange:
        with process_pool(2) as pool:
            runner.run(settings, pool, mean_estimate=False)
    else:
        with ProcessPoolExecutor(2) as pool:
            runner.run(settings, pool, mean_estimate=False)
    wall = time.perf_counter() - start
    saved, distinct = 0, set()
    for path in (cache_dir() / "atlas").glob("*.extra-*.npz"):
        with np.load(path) as data:
            saved += len(data["thetas"])
            distinct |= {(path.name.split(".extra")[0], t.tobytes()) for t in data["thetas"]}
    return {"wall": wall, "saved": saved, "distinct": len(distinct)}


def run_pool(
    learners: tuple[str, ...] = ("EX-C", "EX-CL"),
    runs: int = 3,
    iterations: int | None = None,
    smaller: dict | None = None,
    figure: str = "fig4",
) -> list[str]:
    """``bench exact --pool``: the study's runs of ``learners`` on a process pool of two
    workers sharing one store that holds the atlas and no plan between its nodes, each pass
    in a fresh process with a store of its own: without the plan exchange (each worker reads
    the store's plans of an environment when it first asks about it) and with it. The plans
    saved count every solve but those a worker solved and had not saved at the end."""
    overrides = _with_learners(figure, learners, runs, iterations, smaller)
    settings = _settings(figure, overrides)
    if settings.atlas_spec() is None:
        return [f"{figure} has no plan atlas: no exact learner to share plans for"]
    from corrections_sim.plans import spread

    spread.prepare(settings.atlas_spec(), settings.envs())
    lines = [
        f"{figure}, {', '.join(learners)}: {runs} run(s) each on a process pool of 2 workers, "
        "one store with the atlas and no plan between its nodes:",
        f"{'exchange':10} {'saved':>8} {'distinct':>9} {'per plan':>9} {'wall s':>7}",
    ]
    for exchange in (False, True):
        with tempfile.TemporaryDirectory(prefix="bench-pool-") as scratch:
            root = Path(scratch)
            _store(root)
            args = [POOL_CHILD, figure, json.dumps(overrides), str(int(exchange))]
            found = _in_child(args, root, "the pool's pass")
        per = found["saved"] / found["distinct"] if found["distinct"] else float("nan")
        name = "with" if exchange else "without"
        lines.append(
            f"{name:10} {found['saved']:8d} {found['distinct']:9d} {per:9.2f} {found['wall']:7.1f}"
        )
    return lines


if __name__ == "__main__" and len(sys.argv) == 5 and sys.argv[1] == POOL_CHILD:
    print(json.dumps(_pool_pass(sys.argv[2], json.loads(sys.argv[3]), sys.argv[4] == "1")))

if __name__ == "__main__" and len(sys.argv) == 7 and sys.argv[1] == CHILD:
    figure, learner = sys.argv[2], sys.argv[3]
    runs, iterations = int(sys.argv[4]), int(sys.argv[5])
    found = _measure(figure, learner, runs, iterations or None, json.loads(sys.argv[6]))
    print(json.dumps(found), flush=True)
