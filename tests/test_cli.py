"""The command line of figs. 4/5: bad input, determinism across executors, resuming.

Every run here is a tiny variant of the quick preset (2 runs, 2 corrections) so the whole
module costs well under a minute on two cores.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from corrections_sim.cli import main as cli
from corrections_sim.cli.commands import figure as figure_command
from corrections_sim.figures import learning_study
from corrections_sim.study import runner
from corrections_sim.study.store import RunStore

#: Fig. 4 in small, with one learner of each family (perceptron, filter, active, particles):
#: what these tests check (the same bytes on any executor, after a kill, after a dead worker)
#: is the runner's, and the other learners would only triple its time. PF-C (a random
#: stream of its own) at 50 particles: its 200 were a quarter of each command's time.
TINY = [
    *["fig4", "--quick", "--runs", "2", "--iterations", "2"],
    *["--learners", "PP,KF,AL,KF-C,PF-C", "--set", "learners.PF-C.particles=50"],
]
SENTINEL = "results made earlier, which a failed command must not touch\n"


def _main(argv: list[str]) -> int:
    try:
        return cli.main(argv)
    except SystemExit as exc:  # argparse's own errors
        return int(exc.code)


@pytest.fixture
def earlier(tmp_path: Path) -> Path:
    """An output folder that already holds a fig. 4."""
    folder = tmp_path / "fig4"
    folder.mkdir()
    (folder / "curves.csv").write_text(SENTINEL)
    return tmp_path


@pytest.mark.parametrize(
    ("argv", "names"),
    [
        (["fig9"], "fig9"),
        (["fig4", "--runs", "0"], "--runs"),
        (["fig4", "--iterations", "-3"], "--iterations"),
        (["fig4", "--workers", "0"], "--workers"),
        (["fig4", "--theta-star", "1,-1,0.5"], "theta_star"),
        (["fig4", "--theta0", "0,0,0"], "theta0"),
        (["fig4", "--theta0", "zero,0"], "--theta0"),
        (["fig4", "--cov0", "1,2;2,1"], "cov0"),
        (["fig4", "--cov0", "1,-1"], "cov0"),
        (["fig4", "--cov0", "1,0;0"], "--cov0"),
        (["fig4", "--learners", "PP,XX"], "learners"),
        (["fig4", "--user", "lazy"], "user = 'lazy': unknown user"),
        (["fig4", "--runs", "99999999999999999999999"], "runs"),
        (["fig4", "--iterations", "20000"], "iterations"),
        (["fig4", "--runs", "90000"], "records"),
        (["fig4", "--user-step", "0"], "user.step: must lie in (0, 1]"),
        (["fig4", "--user-step", "1.5"], "user.step"),
        (["fig4", "--user-waypoints", "11"], "user.waypoints: 11 must lie in"),
        (["fig4", "--user", "noisy", "--user-waypoints", "2"], "user.waypoints: the noisy user"),
        (["fig4", "--correction-model", "psychic"], "learners.KF-C.model: unknown correction"),
        (["fig4", "--correction-step", "-0.5"], "learners.KF-C.model.step"),
        (["fig4", "--correction-waypoints", "11"], "learners.KF-C.model.waypoints"),
        (["fig4", "--set", "learners.KF-A.attenuation_min=-1"], "learners.KF-A.attenuation_min"),
        (["fig4", "--set", "learners.XX.step=1"], "XX is not one of the study's learners"),
        (["fig4", "--set", "user.stp=0.5"], "user.stp: the biased user has no such"),
        (["fig4", "--set", "runs"], "--set runs: expected KEY.PATH=VALUE"),
        (["fig4", "--learners", "PP-C"], "KF-C"),
        (["fig4", "--fixed-alpha", "0"], "fixed_alpha"),
        (["fig6", "--user", "noisy"], "user"),
        (["fig2", "--user-step", "0.5"], "--user-step"),
        (["fig4", "--scheduler", "tcp://127.0.0.1:1", "--workers", "2"], "--workers"),
        (["fig1", "--runs", "3"], "--runs"),
        (["fig3", "--theta-star", "1,-1"], "--theta-star"),
        (["fig2", "--workers", "0"], "--workers"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_leaves_results_alone(earlier, capsys, argv, names):
    status = _main([*argv, "--out", str(earlier)])
    err = capsys.readouterr().err
    assert status == 2
    assert err.count("\n") == 1 and err.startswith("error: ") and names in err, err
    assert "Traceback" not in err
    assert (earlier / "fig4" / "curves.csv").read_text() == SENTINEL


def test_an_unwritable_output_folder_is_named(tmp_path, capsys):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    assert _main([*TINY, "--out", str(blocker / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--out" in err and "cannot create" in err


def test_an_unreachable_scheduler_fails_within_seconds(tmp_path, capsys):
    start = time.perf_counter()
    status = _main([*TINY, "--out", str(tmp_path), "--scheduler", "tcp://127.0.0.1:9"])
    assert status == 2
    assert time.perf_counter() - start < figure_command.SCHEDULER_TIMEOUT_S + 5
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--scheduler tcp://127.0.0.1:9: cannot connect" in err


def test_a_second_command_on_the_same_folder_is_refused(earlier, capsys):
    settings = learning_study.load_settings("fig4", quick=True)
    store = RunStore(earlier / ".runs" / "fig4", {"other": settings.as_dict()})
    with store.lock():
        status = _main([*TINY, "--out", str(earlier), "--force"])
    err = capsys.readouterr().err
    assert status == 2 and "another run" in err and err.count("\n") == 1
    assert (earlier / "fig4" / "curves.csv").read_text() == SENTINEL


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> bytes:
    """curves.csv of the tiny run, one worker, nothing cached."""
    out = tmp_path_factory.mktemp("uninterrupted")
    assert cli.main([*TINY, "--workers", "1", "--out", str(out)]) == 0
    return (out / "fig4" / "curves.csv").read_bytes()


def test_same_bytes_with_two_workers_and_on_a_dask_cluster(uninterrupted, tmp_path):
    from distributed import LocalCluster

    assert cli.main([*TINY, "--workers", "2", "--out", str(tmp_path / "two")]) == 0
    assert (tmp_path / "two" / "fig4" / "curves.csv").read_bytes() == uninterrupted
    with LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
    ) as cluster:
        argv = [*TINY, "--scheduler", cluster.scheduler_address, "--out", str(tmp_path / "dask")]
        assert cli.main(argv) == 0
    assert (tmp_path / "dask" / "fig4" / "curves.csv").read_bytes() == uninterrupted
    summary = json.loads((tmp_path / "dask" / "fig4" / "summary.json").read_text())
    assert summary["executor"].startswith("dask tcp://127.0.0.1")


def test_sigkill_part_way_then_resume_gives_the_same_bytes(uninterrupted, tmp_path):
    out = tmp_path / "killed"
    command = [sys.executable, "-m", "corrections_sim.run", *TINY, "--workers", "1"]
    proc = subprocess.Popen(
        [*command, "--out", str(out)],
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    runs = out / ".runs" / "fig4"
    deadline = time.monotonic() + 120
    try:
        while len(list(runs.glob("*/*-*.json"))) < 2:
            assert proc.poll() is None, "the command ended before it could be killed"
            assert time.monotonic() < deadline, "no run finished within 120 s"
            time.sleep(0.05)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    finished = {p.name for p in runs.glob("*/*-*.json")}
    assert 2 <= len(finished) < 9  # 2 PP, KF, KF-C and PF-C runs, 1 AL run in all
    assert not (out / "fig4").exists()  # no half-written figure

    assert cli.main([*TINY, "--workers", "1", "--out", str(out)]) == 0
    assert (out / "fig4" / "curves.csv").read_bytes() == uninterrupted
    summary = json.loads((out / "fig4" / "summary.json").read_text())
    assert summary["resumed_runs"] == len(finished)


def _die(*args, **kwargs):
    os._exit(1)


def test_a_worker_that_dies_is_replaced_and_its_run_redone(uninterrupted, tmp_path, monkeypatch):
    pools = []

    class KillsOnce(ProcessPoolExecutor):
        def submit(self, fn, *args, **kwargs):
            if fn is runner.run_one and len(pools) == 1 and not self.killed:
                self.killed = True
                fn = _die
            return super().submit(fn, *args, **kwargs)

    @contextlib.contextmanager
    def executor(args):
        pool = KillsOnce(max_workers=1)
        pool.killed = False
        pools.append(pool)
        with pool:
            yield pool, "test pool"

    monkeypatch.setattr(figure_command, "open_executor", executor)
    assert cli.main([*TINY, "--out", str(tmp_path)]) == 0
    assert len(pools) == 2
    assert (tmp_path / "fig4" / "curves.csv").read_bytes() == uninterrupted


def test_a_vector_that_starts_with_a_minus_sign_is_a_value():
    args = cli.parser().parse_args(
        ["fig4", "--theta-star", "-1,1", "--cov0", "-.5,1;1,2", "--theta0", "-1e-3,0"]
    )
    assert args.theta_star == (-1.0, 1.0)
    assert args.cov0 == ((-0.5, 1.0), (1.0, 2.0))
    assert args.theta0 == (-0.001, 0.0)
    assert cli.parser().parse_args(["fig4", "--seed", "-3"]).seed == -3
    # An option is still an option: "--theta-star --runs 3" lacks the vector.
    with pytest.raises(SystemExit):
        cli.parser().parse_args(["fig4", "--theta-star", "--runs", "3"])


def test_a_negative_first_weight_reaches_the_settings(earlier, capsys):
    # Typed as a person would, the vector is the value; a wrong length is then the error.
    assert _main(["fig4", "--theta-star", "-1,1,0", "--out", str(earlier)]) == 2
    err = capsys.readouterr().err
    assert "theta_star: expected 2 weights" in err and err.count("\n") == 1, err
