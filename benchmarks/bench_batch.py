"""Benchmark of a whole figure: ``python -m benchmarks.bench fig4``.

Runs the real command (``corrections_sim.run``, fresh output folder, nothing cached) and
prints, with the issue's targets beside them:

* the wall time of paper-scale fig. 4 (PP and KF 100 runs each, AL once, 12 corrections,
  regret over all 48 environments at every iteration) on the default process pool;
* planner solves per second over that run;
* the ratio of the IPOPT path's wall time to the default solver's on a slice of the same
  figure (``--slice-runs`` runs of PP and KF, same iterations), the two run one after the
  other on the same machine;
* the speed-up from 1 to 2 workers and Dask ``LocalCluster`` against the process pool, both
  on the same slice;
* the peak resident memory of a worker process.

It never asserts; a missed target is printed as MISS.
"""

from __future__ import annotations

import contextlib
import json
import logging
import resource
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from corrections_sim.cli import main as cli

#: Paper-scale fig. 4 on 2 workers (issue 30; the stretch is 120 s).
TARGET_WALL_S = 150.0
TARGET_SOLVER_RATIO = 2.5
TARGET_SPEEDUP = 1.8
TARGET_DASK_RATIO = 1.15
TARGET_WORKER_MIB = 1024.0


@dataclass(frozen=True)
class Measurement:
    """One command: wall time of the runs (s, from summary.json), the command's own wall
    time (s, planner loading and plotting included), planner solves, and how it executed."""

    label: str
    runs_wall: float
    command_wall: float
    solves: int
    executor: str

    @property
    def solves_per_second(self) -> float:
        return self.solves / self.runs_wall


def _children_peak_mib() -> float:
    """Largest resident set of any finished child process so far (Linux: ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0


def measure(label: str, argv: Sequence[str]) -> Measurement:
    """Run ``python -m corrections_sim.run <argv>`` in a fresh folder; read its summary."""
    with tempfile.TemporaryDirectory(prefix="bench-") as out:
        t0 = time.perf_counter()
        status = cli.main([*argv, "--out", out])
        wall = time.perf_counter() - t0
        if status != 0:
            raise RuntimeError(f"{label}: the command failed with exit status {status}")
        figure = argv[0]
        summary = json.loads((Path(out) / figure / "summary.json").read_text())
    return Measurement(
        label=label,
        runs_wall=float(summary["wall_time_s"]),
        command_wall=wall,
        solves=int(summary["planner_solves"]),
        executor=summary["executor"],
    )


#: Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536 (to hand memory back to the
#: OS). Any explicit trim threshold switches off glibc's dynamic mmap threshold, and IPOPT's
#: allocations then go through mmap/munmap: a run is slower (measured: docs/getting-started.md).
#: None unsets it, as on a cluster started per docs/getting-started.md.
DASK_WORKER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}


@contextlib.contextmanager
def local_cluster(n_workers: int) -> Iterator[tuple[str, object]]:
    """A Dask LocalCluster on loopback (one thread per worker process) and a client to it,
    its workers configured as docs/getting-started.md recommends for a cluster."""
    import dask
    from distributed import Client, LocalCluster

    with (
        dask.config.set(DASK_WORKER_CONFIG),
        LocalCluster(
            n_workers=n_workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
            # Only its critical logs: at teardown a worker's heartbeat in flight to the closing
            # scheduler is logged at ERROR with a traceback (a CI run's tiny benchmark failed
            # on it), and so is a nanny's cancelled close; a run's own failure still reaches
            # the command through the client.
            silence_logs=logging.CRITICAL,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield cluster.scheduler_address, client


def _worker_peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _verdict(ok: bool) -> str:
    return "PASS" if ok else "MISS"


def run_bench(
    *,
    full: bool,
    slice_runs: int,
    iterations: int | None,
    solver: str = "fatrop",
    warm: str = "newton",
    smaller: Sequence[str] = (),
) -> list[str]:
    """Measure and return the report's lines (printed as they come, too); ``solver`` is the
    planner's solver of every run but the slice's IPOPT comparison, ``warm`` its warm mode
    (with ``"newton"`` the slice also runs with ``"solver"``, side by side); ``smaller``: ``run``
    options that shrink fig. 4's study (:func:`benchmarks.sizes.set_options`)."""

    def say(line: str) -> None:
        print(line, flush=True)

    lines: list[str] = []
    rows: list[tuple[str, str, str]] = []
    common = ["--iterations", str(iterations)] if iterations else []
    common += list(smaller)
    extra = [*common, "--solver", solver, "--set", f"planner.warm={warm}"]

    def report(m: Measurement, label: str) -> None:
        lines.append(
            f"slice, {label}: {m.runs_wall:.1f} s, {m.solves} solves, "
            f"{m.solves_per_second:.0f} solves/s"
        )
        say(lines[-1])

    if full:
        say(
            f"paper-scale fig. 4 ({solver}, warm {warm}) on the default process pool (this "
            "takes minutes) ..."
        )
        m = m_full = measure("paper fig4", ["fig4", *extra])
        lines.append(
            f"paper-scale fig4: {m.runs_wall:.1f} s for the runs ({m.command_wall:.1f} s "
            f"the whole command), {m.solves} planner solves, {m.solves_per_second:.0f} "
            f"solves/s, {m.executor}"
        )
        rows.append(
            (
                f"paper fig4 <= {TARGET_WALL_S:.0f} s",
                f"{m.runs_wall:.0f} s",
                _verdict(m.runs_wall <= TARGET_WALL_S),
            )
        )
        say(lines[-1])
    slice_base = ["fig4", "--runs", str(slice_runs), "--learners", "PP,KF", *common]
    slice_argv = [*slice_base, "--solver", solver, "--set", f"planner.warm={warm}"]
    say(f"slice: {slice_runs} runs each of PP and KF: {solver} and ipopt on 2 workers ...")
    two = measure("2 workers", [*slice_argv, "--workers", "2"])
    if warm != "solver":
        reference = measure(
            "warm solver",
            [*slice_base, "--solver", solver, "--set", "planner.warm=solver", "--workers", "2"],
        )
        report(reference, f"{solver}, warm solver (the reference path)")
        warm_ratio = reference.runs_wall / two.runs_wall
        rows.append((f"warm {warm} faster than warm solver", f"{warm_ratio:.2f}x", "-"))
    # IPOPT's path: IPOPT for every solve, warm starts included (the paper's original path).
    ipopt_argv = [*slice_base, "--solver", "ipopt", "--set", "planner.warm=solver"]
    ipopt = measure("ipopt", [*ipopt_argv, "--workers", "2"])
    solver_ratio = ipopt.runs_wall / two.runs_wall
    for m, label in ((two, solver), (ipopt, "ipopt")):
        report(m, f"{label} ({m.executor})")
    rows.append(
        (
            f"{solver} >= {TARGET_SOLVER_RATIO}x faster than ipopt",
            f"{solver_ratio:.2f}x",
            _verdict(solver_ratio >= TARGET_SOLVER_RATIO),
        )
    )
    if full:
        lines.append(
            f"paper-scale fig4 with ipopt, estimated from the slice's ratio: "
            f"{m_full.runs_wall * solver_ratio:.0f} s"
        )
        say(lines[-1])
    say("slice on 1 worker, then Dask ...")
    one = measure("1 worker", [*slice_argv, "--workers", "1"])
    peak_pool = _children_peak_mib()
    with local_cluster(2) as (address, client):
        dask = measure("dask", [*slice_argv, "--scheduler", address])
        peak_dask = max(client.run(_worker_peak_mib).values())
    speedup = one.runs_wall / two.runs_wall
    ratio = dask.runs_wall / two.runs_wall
    for m in (one, dask):
        report(m, m.executor)
    lines.append(f"peak RSS per worker: process pool {peak_pool:.0f} MiB, Dask {peak_dask:.0f} MiB")
    rows += [
        (
            f"speed-up 1 -> 2 workers >= {TARGET_SPEEDUP}x",
            f"{speedup:.2f}x",
            _verdict(speedup >= TARGET_SPEEDUP),
        ),
        (
            f"Dask within {100 * (TARGET_DASK_RATIO - 1):.0f}% of the pool",
            f"{100 * (ratio - 1):+.1f}%",
            _verdict(ratio <= TARGET_DASK_RATIO),
        ),
        (
            f"<= {TARGET_WORKER_MIB:.0f} MiB per worker",
            f"{max(peak_pool, peak_dask):.0f} MiB",
            _verdict(max(peak_pool, peak_dask) <= TARGET_WORKER_MIB),
        ),
    ]
    lines.append("")
    lines.append(f"{'target':<40}{'measured':>12}  verdict")
    lines += [f"{name:<40}{value:>12}  {verdict}" for name, value, verdict in rows]
    return lines
