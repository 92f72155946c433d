"""``run interact`` and ``run replay`` on input that cannot work (issue 37): each is one line
and exit status 2, within seconds, and writes nothing: no database file, no session row."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_cli_input import _main, _one_line

from corrections_sim.session.log import StudyLog

STUDY_TOML = """environments = ["s0-t0-l1", "s0-t0-l2", "s1-t1-l0", "s2-t0-l1"]
theta_star = [1.0, -1.0]
learners = ["KF-C"]
seed = 3
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_busy_port_is_refused_in_one_line_and_nothing_is_written(tmp_path, capsys):
    db = tmp_path / "study.sqlite"
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        start = time.monotonic()
        assert _main(["interact", "--port", str(port), "--db", str(db)]) == 2
        assert time.monotonic() - start < 5.0
    _one_line(capsys.readouterr().err, f"--port {port}", "in use")
    assert not db.exists()  # no session row, not even an empty log


@pytest.mark.parametrize(
    ("host", "says"),
    [
        ("192.0.2.1", "cannot serve on 192.0.2.1"),  # TEST-NET-1: no machine's own address
        ("nonsense.invalid", "does not resolve"),  # .invalid never resolves (RFC 6761)
        ("", "does not resolve"),
    ],
)
def test_an_unusable_host_is_refused_in_one_line_within_seconds(tmp_path, capsys, host, says):
    db = tmp_path / "study.sqlite"
    start = time.monotonic()
    assert _main(["interact", "--host", host, "--port", str(_free_port()), "--db", str(db)]) == 2
    assert time.monotonic() - start < 5.0
    _one_line(capsys.readouterr().err, "--host", says)
    assert not db.exists()


def test_a_host_that_never_answers_is_given_up_on(monkeypatch):
    """A resolver that hangs (a machine with no name server) is waited for RESOLVE_TIMEOUT."""
    from corrections_sim.pages import server

    monkeypatch.setattr(server.socket, "getaddrinfo", lambda *a, **k: time.sleep(30))
    start = time.monotonic()
    with pytest.raises(server.AddressError, match="did not resolve within 1 s"):
        server.resolve("slow.example", timeout=1.0)
    assert time.monotonic() - start < 2.0


@pytest.mark.parametrize(
    ("argv", "names"),
    [
        (["--participant", "bad name"], ["--participant", "pseudonym"]),
        (["--resume", "1"], ["--db", "no such file"]),
        (["--runs", "3"], ["--runs: does not apply to interact", "FILE"]),
        (["--drag-model", "nonsense"], ["nonsense", "waypoint"]),
        (["--learner", "PP"], ["fixed_alpha"]),
        (["--mode", "physical", "--set", "learners.KF-C.model=bogus"], ["bogus"]),
    ],
)
def test_bad_session_options_write_nothing(tmp_path, capsys, argv, names):
    db = tmp_path / "study.sqlite"
    assert _main(["interact", *argv, "--db", str(db)]) == 2
    err = capsys.readouterr().err
    _one_line(err, *names)
    assert "--study-file" not in err  # there is no such option: the study file is FILE
    assert not db.exists()


def test_a_resume_refuses_what_the_session_already_has(tmp_path, capsys):
    db = tmp_path / "study.sqlite"
    study = tmp_path / "small.toml"
    study.write_text(STUDY_TOML)
    argv = ["interact", str(study), "--headless", "--iterations", "1", "--db", str(db)]
    assert _main(argv) == 0  # session 1, ended by the headless run
    capsys.readouterr()
    refused = {
        ("--learner", "KF"): "--learner",
        ("--mode", "physical"): "--mode",
        ("--participant", "p2"): "--participant",
        ("--set", "seed=4"): "--set",
    }
    for extra, name in refused.items():
        assert _main(["interact", "--resume", "1", "--db", str(db), *extra]) == 2
        _one_line(capsys.readouterr().err, "--resume", name)
    assert _main(["interact", "--resume", "1", "--db", str(db)]) == 2
    _one_line(capsys.readouterr().err, "--resume 1", "ended")
    assert _main(["interact", "--resume", "7", "--db", str(db)]) == 2
    _one_line(capsys.readouterr().err, "session 7: not in")
    with StudyLog(db) as log:
        assert log.session_ids() == [1]


def test_replay_help_speaks_of_the_database_and_of_learners(capsys):
    assert _main(["replay", "--help"]) == 0
    text = capsys.readouterr().out
    assert "SQLite database" in text and "study file (TOML)" not in text
    assert "learners.KF-C.model=physical" in text and "user.step" not in text


def _serve(argv: list[str]) -> tuple[subprocess.Popen, str]:
    """``run interact`` in its own process, once it prints its URL: (process, that line)."""
    command = [sys.executable, "-m", "corrections_sim.run", "interact", *argv]
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, cwd=Path.cwd())
    line = process.stderr.readline()
    while "open http" not in line:
        assert line, "the server ended before serving"
        line = process.stderr.readline()
    return process, line


def _stop(process: subprocess.Popen) -> str:
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=30)
    assert process.returncode == 130
    return err


def test_a_resumed_physical_session_keeps_its_speed_and_sigterm_names_the_session(tmp_path, capsys):
    study = tmp_path / "small.toml"
    study.write_text(STUDY_TOML)
    db = tmp_path / "study.sqlite"
    port = _free_port()
    argv = [str(study), "--mode", "physical", "--speed", "0.5", "--db", str(db)]
    process, line = _serve([*argv, "--port", str(port)])
    try:
        assert "physical at speed 0.5" in line and "--resume 1" in line
        # A second server on the same session would interleave two people's corrections.
        assert _main(["interact", "--resume", "1", "--db", str(db)]) == 2
        err = capsys.readouterr().err
        _one_line(err, "--resume 1", f"still served by process {process.pid}")
        err = _stop(process)
    finally:
        process.kill()
    assert f"--resume 1 --db {db}" in err and "SESSION" not in err
    # The port is free again at once, and the session plays at the speed it had.
    process, line = _serve(["--resume", "1", "--db", str(db), "--port", str(port)])
    try:
        assert "physical at speed 0.5" in line
        _stop(process)
    finally:
        process.kill()
    process, line = _serve(
        ["--resume", "1", "--db", str(db), "--speed", "0.25", "--port", str(port)]
    )
    try:
        assert "physical at speed 0.25" in line
        _stop(process)
    finally:
        process.kill()
    with StudyLog(db) as log:
        assert [e["detail"]["speed"] for e in log.events(1, "page")] == [0.5, 0.5, 0.25]
