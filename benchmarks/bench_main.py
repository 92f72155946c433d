"""The main job as a newcomer meets it (``python -m benchmarks.bench main``): the README's
``run fig4`` in a fresh process with an empty cache (``CORRECTIONS_SIM_CACHE``: the gcc builds
and the plan atlas made first), then again with everything cached but the runs (the runs'
cache deleted: every run recomputed, only compiled code, atlas nodes and plans kept).

For each: wall time, CPU seconds (the command and its workers), the largest resident set of
any one process so far (the kernel keeps one maximum over every finished child, so the
second row cannot show less than the first), and the wall time split by what the command's
progress lines say: until the first run starts (compile, atlas and the shared plans), the
runs, and the rest (summaries, figure, files). Then whether the two runs' ``curves.csv``
are byte-identical. Where a learner's time goes inside the runs: ``bench split``.

It prints figures and never asserts.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: A progress line of the runs (``fig4: 12/402 runs, 20 s elapsed, ...``).
RUNS = re.compile(r"^(?P<name>\S+): (?P<done>\d+)/(?P<total>\d+) runs, (?P<s>\d+) s elapsed")


def _run(command: list[str], cache: Path, cwd: Path) -> dict:
    """``command`` in a fresh process with ``cache``; wall, CPU and peak memory, and when its
    first and last progress line of the runs came (seconds from its start)."""
    import os
    import resource

    env = dict(os.environ, CORRECTIONS_SIM_CACHE=str(cache))
    env.setdefault("MUJOCO_GL", "egl")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        command, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    first = last = None
    lines = []
    for line in proc.stdout or ():
        now = time.perf_counter() - t0
        lines.append(line.rstrip())
        match = RUNS.match(line.strip())
        if match:
            # The first line comes as the runs begin (the atlas has lines of its own).
            first = now if first is None else first
            last = now
    proc.wait()
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        tail = "\n".join(lines[-15:])
        raise RuntimeError(f"{' '.join(command)} failed (exit {proc.returncode}):\n{tail}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {
        "wall": wall,
        "cpu": cpu,
        # The largest resident set of any process waited for so far (Linux: KiB): the
        # command's or one of its workers'.
        "rss_gb": after.ru_maxrss / 1024**2,
        "before_runs": first,
        "runs": None if first is None or last is None else last - first,
        "after_runs": None if last is None else wall - last,
    }


def run(
    figure: str = "fig4", extra: list[str] | None = None, workers: int = 2, compiled: bool = False
) -> dict:
    """Both runs of ``run <figure>`` (with ``extra`` options) in a scratch folder;
    ``compiled``: the empty cache starts with this machine's compiled solvers (``*.so``)."""
    from corrections_sim.planning.cache import cache_dir

    root = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        out, cache = scratch / "out", scratch / "cache"
        cache.mkdir()
        if compiled:
            for library in cache_dir().glob("*.so"):
                shutil.copy2(library, cache / library.name)
        command = [
            sys.executable,
            "-m",
            "corrections_sim.run",
            figure,
            "--out",
            str(out),
            "--workers",
            str(workers),
            *(extra or []),
        ]
        empty = _run(command, cache, root)
        first = (out / figure / "curves.csv").read_bytes()
        shutil.rmtree(out / ".runs")
        cached = _run([*command, "--force"], cache, root)
        again = (out / figure / "curves.csv").read_bytes()
    return {
        "empty": empty,
        "cached": cached,
        "identical": first == again,
        "figure": figure,
        "command": " ".join(command[3:]),
        "compiled": compiled,
    }


def _s(value: float | None) -> str:
    return "—" if value is None else f"{value:.0f} s"


def report(result: dict) -> list[str]:
    empty = "compiled solvers kept" if result["compiled"] else "gcc, atlas built"
    lines = [
        f"main job: run {result['command']} in a fresh process",
        f"{'cache':<34}{'wall':>9}{'CPU':>9}{'max RSS':>10}"
        f"{'to 1st run':>12}{'runs':>9}{'after':>9}",
    ]
    for key, name in ((("empty", f"empty ({empty})")), ("cached", "all cached but the runs")):
        r = result[key]
        lines.append(
            f"{name:<34}{r['wall']:>7.0f} s{r['cpu']:>7.0f} s{r['rss_gb']:>7.2f} GB"
            f"{_s(r['before_runs']):>12}{_s(r['runs']):>9}{_s(r['after_runs']):>9}"
        )
    same = "byte-identical" if result["identical"] else "DIFFERENT"
    lines.append(f"the two runs' curves.csv: {same}")
    return lines
