"""The command line as subcommands, and a user study's commands: every invocation the README
and the docs show parses, each command's help speaks of that command alone, bad input to the
study's commands is one line, and the committed pilot analyses to its committed numbers."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from corrections_sim.cli import main as cli

ROOT = Path(__file__).resolve().parents[1]


def _invocations() -> list[tuple[str, list[str]]]:
    """(where, argv) of every ``python -m corrections_sim.run ...`` in a code block of the
    README and the docs (continuation lines joined, comments dropped)."""
    found = []
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("**/*.md"))]:
        text = path.read_text()
        for block in re.findall(r"```[a-z]*\n(.*?)```", text, flags=re.S):
            for line in block.replace("\\\n", " ").splitlines():
                if "python -m corrections_sim.run " not in line:
                    continue  # (the module named in prose, "corrections_sim.run: ...")
                rest = line.split("python -m corrections_sim.run ", 1)[1]
                rest = re.split(r"\s#", rest)[0].replace("[--quick]", "--quick")
                rest = rest.split("&&")[0].split("|")[0]
                argv = shlex.split(rest)
                if argv:
                    found.append((f"{path.name}: {line.strip()}", argv))
    return found


INVOCATIONS = _invocations()


def test_the_docs_show_invocations_of_every_kind():
    commands = {argv[0] for _, argv in INVOCATIONS}
    assert {"fig4", "interact", "replay", "study", "serve-study", "analyze", "pilot", "power"} <= (
        commands
    )


@pytest.mark.parametrize(("where", "argv"), INVOCATIONS, ids=[w for w, _ in INVOCATIONS])
def test_every_invocation_in_the_readme_and_docs_parses(where, argv):
    args = cli._parse(argv)
    assert args.figure == argv[0]


def test_a_command_help_speaks_of_that_command_alone(capsys):
    assert cli.main(["interact", "--help"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("usage: python -m corrections_sim.run interact")
    for other in ("fig4", "fig5", "fig6", "video", "{interact}", "for 'study'", "--runs"):
        assert other not in text, other
    assert cli.main(["power", "--help"]) == 0
    text = capsys.readouterr().out
    assert "PROTOCOL" in text and "--pool" in text and "--port" not in text
    text = cli.parser().format_help()
    assert "serve-study" in text and "analyze" in text and "COMMAND --help" in text


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["interact", "--runs", "3"], ["--runs: does not apply to interact"]),
        (["fig4", "my.toml"], ["FILE: does not apply to fig4"]),
        (["analyze", "--pool", "3"], ["--pool: does not apply to analyze"]),
        (["power", "--sizes", "0,4"], ["--sizes", "whole numbers >= 1"]),
        (["fig4", "--learner", "KF"], ["--learner: does not apply to fig4"]),
    ],
)
def test_an_option_of_another_command_is_one_line(argv, words, capsys):
    assert _main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and all(w in err for w in words), err


def test_the_study_commands_refuse_bad_input_in_one_line_and_write_nothing(tmp_path, capsys):
    from corrections_sim.userstudy.cohort import open_run

    protocol = tmp_path / "protocol.toml"
    protocol.write_text('study = "fig4"\n[[conditions]]\nname = "A"\nlearner = "KF-X"\n')
    db = tmp_path / "study.sqlite"
    assert cli.main(["serve-study", str(protocol), "--db", str(db)]) == 2
    err = capsys.readouterr().err
    assert "conditions[0].learner: unknown learner 'KF-X'" in err and err.count("\n") == 1
    protocol.write_text('study = "fig4"\n[[conditions]]\nname = "A"\nlearner = "KF"\n')
    run = open_run(protocol, db)
    run.enroll("P01")
    run.log.close()
    before = db.read_bytes()
    argv = ["serve-study", str(protocol), "--db", str(db), "--enroll", "P02,P01", "--port", "1"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "--enroll P01: already used" in err and err.count("\n") == 1
    with cli_log(db) as log:
        assert [p["code"] for p in log.participants()] == ["P01"]
    assert db.read_bytes()[:100] == before[:100]
    assert cli.main(["analyze", str(tmp_path / "none.sqlite")]) == 2
    assert "no such study log" in capsys.readouterr().err
    assert cli.main(["analyze", str(db)]) == 2
    assert "no finished trial" in capsys.readouterr().err
    assert cli.main(["pilot", str(protocol), "--out", str(tmp_path / "p")]) == 2
    assert "no [simulation] table" in capsys.readouterr().err


def _main(argv) -> int:
    """``cli.main``, with argparse's own refusals (a bad value) as their exit status."""
    try:
        return cli.main(argv)
    except SystemExit as exc:
        return int(exc.code)


def cli_log(db):
    from corrections_sim.session.log import StudyLog

    return StudyLog(db)


def _numbers(value, path=""):
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _numbers(v, f"{path}.{k}")
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _numbers(v, f"{path}[{i}]")
    elif isinstance(value, int | float) and not isinstance(value, bool):
        yield path, float(value)


def test_the_committed_pilot_analyses_to_its_committed_numbers(tmp_path):
    from corrections_sim.userstudy.report import analyze

    committed = ROOT / "results" / "pilot"
    analyze(committed / "study.sqlite", tmp_path)
    old = dict(_numbers(json.loads((committed / "analysis" / "summary.json").read_text())))
    new = dict(_numbers(json.loads((tmp_path / "summary.json").read_text())))
    assert old.keys() == new.keys()
    for key, value in old.items():
        # The analysis reads the log's numbers; only the model's optimizer rounds per CPU.
        assert np.isclose(new[key], value, rtol=1e-4, atol=1e-6, equal_nan=True), key
    report = (tmp_path / "report.md").read_text()
    assert "Simulated participants" in report
    # No p-value from a singular fit (a participant variance at 0), and the end question
    # mapped to the conditions by each participant's order.
    summary = json.loads((committed / "analysis" / "summary.json").read_text())
    singular = [n for n, o in summary["outcomes"].items() if not o["mixed"]["reported"]]
    assert singular, "no singular fit in the committed pilot: this check would check nothing"
    for name in singular:
        assert f"| {name} | not reported: singular" in report
    assert "## Which robot they would rather work with" in report
    comparisons = (committed / "analysis" / "comparisons.csv").read_text().splitlines()
    assert len(comparisons) == 13


def test_study_status_prints_where_everyone_is(capsys):
    db = ROOT / "results" / "pilot" / "study.sqlite"
    assert cli.main(["study-status", "--db", str(db)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 12
    assert all(re.fullmatch(r"sim\d{5} simulated: step 10/10 end", line) for line in lines)


SMALL_STUDY = (
    'environments = ["s0-t0-l1", "s1-t1-l0"]\ntheta_star = [1.0, -1.0]\nlearners = ["KF-C"]\n'
)
SMALL_PROTOCOL = (
    'description = "a small study"\nstudy = "small.toml"\nseed = 3\ncorrections = 1\n'
    '[[conditions]]\nname = "C"\nlearner = "KF-C"\n'
)


def _small_protocol(folder: Path) -> Path:
    (folder / "small.toml").write_text(SMALL_STUDY)
    protocol = folder / "protocol.toml"
    protocol.write_text(SMALL_PROTOCOL)
    return protocol


def test_serve_study_on_a_busy_port_is_one_line_and_makes_no_log(tmp_path, capsys):
    """A busy port is refused before the log is touched: no file is left (it left an empty
    73 KB study log, tables and no rows)."""
    import socket

    protocol = _small_protocol(tmp_path)
    db = tmp_path / "x.sqlite"
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        argv = ["serve-study", str(protocol), "--db", str(db), "--port", str(port)]
        assert cli.main([*argv, "--enroll", "P01"]) == 2
    err = capsys.readouterr().err
    assert f"--port {port}: in use" in err and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["protocol.toml", "small.toml"]


def test_serve_study_prints_the_links_on_stdout_and_its_interrupt_names_it(tmp_path):
    """The links, a line each, on the standard output (a lab pipes them to a file); what the
    server does on stderr; Ctrl-C says that the study's server stopped and where every step
    is, not a figure's message."""
    import signal
    import socket
    import subprocess
    import sys

    protocol = _small_protocol(tmp_path)
    db = tmp_path / "study.sqlite"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    argv = ["serve-study", str(protocol), "--db", str(db), "--port", str(port)]
    server = subprocess.Popen(
        [sys.executable, "-m", "corrections_sim.run", *argv, "--enroll", "P01,P02"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        lines = [server.stdout.readline() for _ in range(3)]
        assert [line.split(": ")[0] for line in lines] == [
            "participant P01",
            "participant P02",
            "experimenter",
        ], lines
        assert all(
            re.fullmatch(r"[^:]+: http://127\.0\.0\.1:\d+/\?websocket=\S+\n", x) for x in lines
        )
        server.send_signal(signal.SIGINT)
        out, err = server.communicate(timeout=60)
    finally:
        if server.poll() is None:
            server.kill()
    assert server.returncode == 130, err
    assert "http://" not in err and out == "", (out, err)
    last = err.strip().splitlines()[-1]
    assert last.startswith("interrupted: serve-study stopped serving"), last
    assert str(db) in last and "figs." not in last and "runs" not in last, last
