"""The command line on plausible input (issue 13): options that do not apply, an empty --out,
a malformed scheduler, PP alone; where figures go and when they may replace a folder; what
every summary.json records.

Runs are tiny (1-2 runs, 1-2 corrections, one worker) so the module costs about half a minute.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from corrections_sim.cli import main as cli

#: Fig. 4's quick preset at its smallest, PP and KF alone (what these tests check is the
#: command's, not the learners': its twelve learners took twice as long).
TINY = [
    *["fig4", "--quick", "--runs", "1", "--iterations", "1"],
    *["--learners", "PP,KF", "--workers", "1"],
]


def _main(argv: list[str]) -> int:
    try:
        return cli.main(argv)
    except SystemExit as exc:
        return int(exc.code)


def _one_line(err: str, *names: str) -> None:
    assert err.count("\n") == 1 and err.startswith("error: "), err
    assert "Traceback" not in err
    for name in names:
        assert name in err, err


@pytest.mark.parametrize(
    ("argv", "names"),
    [
        (["scene", "--runs", "5"], ["--runs", "scene"]),
        (["scene", "--quick"], ["--quick"]),
        (["scene", "--workers", "2"], ["--workers"]),
        (["fig4", "--env", "s0-t0-l0"], ["--env", "fig4"]),
        (["fig1", "--fixed-alpha", "0.1"], ["--fixed-alpha"]),
        (["fig2", "--env", "s0-t0-l0"], ["--env"]),
        (["fig4", "--learners", "PP"], ["learners", "--fixed-alpha"]),
        (["fig4", "--learners", "PP", "--fixed-alpha", "0"], ["--fixed-alpha"]),
        (["fig4", "--learners", "PP", "--fixed-alpha", "nan"], ["--fixed-alpha"]),
        (["fig4", "--out", ""], ["--out"]),
        (["fig1", "--out", " "], ["--out"]),
        (["fig4", "--scheduler", "foo"], ["--scheduler foo"]),
        (["fig3", "--scheduler", "tcp://host-without-port"], ["--scheduler"]),
    ],
)
def test_bad_input_is_refused_before_anything_is_created(
    tmp_path, monkeypatch, capsys, argv, names
):
    monkeypatch.chdir(tmp_path)  # an empty --out would write here
    status = _main(argv if "--out" in argv else [*argv, "--out", str(tmp_path / "out")])
    _one_line(capsys.readouterr().err, *names)
    assert status == 2
    assert list(tmp_path.iterdir()) == []


def test_a_malformed_scheduler_fails_at_once_without_a_traceback(tmp_path):
    start = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "corrections_sim.run", *TINY[:-2], "--scheduler", "foo"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    _one_line(proc.stderr, "--scheduler foo")
    # "At once": no wait for a scheduler to answer (Dask's connect timeout is 30 s and more);
    # not a speed bound (a loaded 2-core machine took 6.3 s to start Python and refuse).
    assert time.perf_counter() - start < 25
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("gcc", ["refuses", "missing"])
def test_a_machine_whose_gcc_cannot_build_the_planner_gets_one_line(tmp_path, refusing_gcc, gcc):
    """gcc refusing the planner's C (or absent) on a machine with an empty cache: one line
    naming the planner's features, the library and gcc's error (or that gcc is missing), exit
    status 1, and no figure; not a traceback from a worker."""
    folder, says = refusing_gcc
    empty = tmp_path / "no-gcc"
    empty.mkdir()
    path = f"{folder}:{os.environ['PATH']}" if gcc == "refuses" else str(empty)
    env = dict(os.environ, PATH=path, CORRECTIONS_SIM_CACHE=str(tmp_path / "cache"))
    proc = subprocess.run(
        [sys.executable, "-m", "corrections_sim.run", *TINY, "--out", str(tmp_path / "out")],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert proc.returncode == 1, proc.stderr
    err = proc.stderr.splitlines()[-1] + "\n"
    said = says if gcc == "refuses" else "no gcc on the PATH"
    _one_line(err, "error: the planner over laptop, table: ", ".so: ", said)
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "out" / "fig4").exists()  # no figure (only the run cache's settings)


def test_pp_alone_runs_with_a_fixed_rate_and_a_quick_preset_goes_to_scratch(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = [*TINY[:6], "--learners", "PP", "--fixed-alpha", "0.05", "--workers", "1"]
    assert _main(argv) == 0
    assert not (tmp_path / "results" / "fig4").exists()
    summary = json.loads((tmp_path / "results" / "quick" / "fig4" / "summary.json").read_text())
    assert summary["learning_rates"] == {"PP": [0.05]}
    assert summary["runs_per_learner"] == {"PP": 1}


def _fake_figure(folder: Path, **settings) -> None:
    folder.mkdir(parents=True)
    (folder / "curves.csv").write_text("made by a paper-scale run\n")
    summary = {"figure": "fig4", "preset": "paper", "settings": settings}
    (folder / "summary.json").write_text(json.dumps(summary))


def test_a_folder_made_with_other_settings_is_replaced_only_with_force(tmp_path, capsys):
    _fake_figure(tmp_path / "fig4", runs=100, iterations=12, seed=2018)
    before = {p.name: p.read_bytes() for p in (tmp_path / "fig4").iterdir()}

    assert _main([*TINY, "--out", str(tmp_path)]) == 2
    _one_line(capsys.readouterr().err, "--force", "runs 100 (now 1)", "iterations 12 (now 1)")
    assert {p.name: p.read_bytes() for p in (tmp_path / "fig4").iterdir()} == before
    assert not (tmp_path / ".runs").exists()

    assert _main([*TINY, "--out", str(tmp_path), "--force"]) == 0
    err = capsys.readouterr().err
    assert "replacing" in err and "--force" in err and "runs 100" in err
    summary = json.loads((tmp_path / "fig4" / "summary.json").read_text())
    assert summary["settings"]["runs"] == 1

    # Provenance: enough to trace the folder back to a command, a commit and the numbers.
    assert summary["command"].startswith("python -m corrections_sim.run fig4 --quick")
    assert summary["timestamp"].endswith("+00:00")
    assert summary["versions"]["corrections_sim"]
    assert summary["planner"]["features"] == ["laptop", "table"]
    assert set(summary["runs_per_learner"].values()) == {1}
    for learner in summary["runs_per_learner"]:
        assert len(summary["curves"][learner]["regret"]["mean"]) == 2  # iterations 0 and 1
    if (Path(cli.__file__).parents[1] / ".git").exists():
        assert len(summary["git"]["commit"]) == 40

    # The same settings again: replaced, and said so.
    assert _main([*TINY, "--out", str(tmp_path)]) == 0
    assert "same settings" in capsys.readouterr().err


def test_files_no_figure_wrote_are_not_replaced(tmp_path, capsys):
    (tmp_path / "fig1").mkdir()
    (tmp_path / "fig1" / "notes.txt").write_text("mine\n")
    assert _main(["fig1", "--quick", "--out", str(tmp_path)]) == 2
    _one_line(capsys.readouterr().err, "--out", "--force", "summary.json")
    assert (tmp_path / "fig1" / "notes.txt").read_text() == "mine\n"


def test_figs_1_to_3_record_their_provenance_and_what_they_show(tmp_path, monkeypatch):
    from types import SimpleNamespace

    from corrections_sim.figures import selection

    shown = ({"map": "laptop", "best_x": 0.5, "best_frobenius": float("nan")},)

    def fake_run(settings, executor, progress):  # the figure's computation is tested elsewhere
        return SimpleNamespace(maps=shown)

    def fake_write(settings, result, folder):
        (folder / "maps.csv").write_text("map\nlaptop\n")

    monkeypatch.setattr(selection, "run", fake_run)
    monkeypatch.setattr(selection, "write", fake_write)
    assert _main(["fig1", "--quick", "--workers", "1", "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "fig1" / "summary.json").read_text())
    assert (
        summary["command"]
        == f"python -m corrections_sim.run fig1 --quick --workers 1 --out {tmp_path}"
    )
    assert summary["settings"]["features"] == ["laptop"]  # the resolved preset
    assert summary["planner"]["features"] == ["laptop"]
    assert summary["results"] == {
        "maps": [{"map": "laptop", "best_x": 0.5, "best_frobenius": None}]
    }
    assert summary["timestamp"] and summary["versions"]["casadi"]
    assert "git" in summary


def test_a_port_outside_the_range_is_one_line_and_exit_2(capsys):
    assert _main(["interact", "--port", "99999"]) == 2
    _one_line(capsys.readouterr().err, "--port", "99999", "65535")


def test_a_command_help_lists_its_own_options_only(capsys):
    assert _main(["interact", "--help"]) == 0
    text = capsys.readouterr().out
    assert "--port" in text and "--resume" in text
    for other in ("--video-file", "--force", "--runs", "--scheduler"):
        assert other not in text
    assert _main(["fig4", "--help"]) == 0
    text = capsys.readouterr().out
    assert "--runs" in text and "--online" in text and "--port" not in text


def test_an_interrupted_session_speaks_of_the_session():
    """An interrupt's message gives the command that resumes the very session."""
    args = cli.parser().parse_args(["interact", "--db", "x.sqlite"])
    assert "before a session was started" in cli._nothing_kept(args)
    args.interact_session = 4
    assert "--resume 4 --db x.sqlite" in cli._nothing_kept(args)
    assert "fig4 stopped before any run" in cli._nothing_kept(cli.parser().parse_args(["fig4"]))


@pytest.mark.parametrize(
    ("argv", "names"),
    [
        (["interact", "--mode", "physical", "--drag-model", "deform"], ["--drag-model"]),
        (["interact", "--speed", "0.5"], ["--speed", "--mode physical"]),
        (["interact", "--mode", "physical", "--speed", "2"], ["--speed", "(0, 1]"]),
        (["interact", "--mode", "pushy"], ["--mode", "pushy"]),
    ],
)
def test_physical_session_options_are_checked(argv, names, tmp_path, capsys):
    assert _main([*argv, "--db", str(tmp_path / "s.sqlite")]) == 2
    _one_line(capsys.readouterr().err, *names)


def test_a_replay_sets_learners_parameters_only(tmp_path, capsys):
    import shutil

    db = tmp_path / "p.sqlite"
    shutil.copy(Path(__file__).parents[1] / "results/interact/physical.sqlite", db)
    assert _main(["replay", str(db), "--set", "user.step=0.5", "--out", str(tmp_path)]) == 2
    _one_line(capsys.readouterr().err, "--set user.step=0.5", "learners")
    argv = ["replay", str(db), "--learners", "KF-C", "--set", "learners.KF-C.model=physical"]
    assert _main([*argv, "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "replay-1" / "summary.json").read_text())
    assert summary["settings"]["learners"]["KF-C"]["model"]["name"] == "physical"


def test_the_architecture_pages_new_command_is_one_module_and_its_registration(
    tmp_path, monkeypatch, capsys
):
    """docs/architecture.md's example command, as written there: registered by its module in
    TOOLS alone, it runs, lists in --help, and refuses an option it does not name."""
    import re
    import types

    from corrections_sim.cli import commands
    from corrections_sim.session.log import StudyLog

    page = (Path(__file__).parents[1] / "docs" / "architecture.md").read_text()
    source = re.search(
        r"```python\n# corrections_sim/cli/commands/sessions.py\n(.*?)```", page, re.S
    )
    assert source, "docs/architecture.md lost its example command"
    module = types.ModuleType("corrections_sim.cli.commands.sessions")
    exec(compile(source[1], "sessions.py", "exec"), module.__dict__)
    monkeypatch.setattr(commands, "TOOLS", (*commands.TOOLS, module))
    db = tmp_path / "log.sqlite"
    StudyLog(db).close()
    assert _main(["sessions", str(db)]) == 0
    assert _main(["--help"]) == 0
    assert "the sessions of a study log" in capsys.readouterr().out
    assert _main(["sessions", str(db), "--runs", "3"]) == 2
    _one_line(capsys.readouterr().err, "--runs", "sessions", "FILE")


@pytest.mark.parametrize(
    ("argv", "names"),
    [
        (["relevance-scores", "{tmp}/none.sqlite"], ["none.sqlite", "no such file"]),
        (["relevance-scores"], ["relevance-scores", "give the log"]),
        (["relevance-fit", "--per-kind", "1"], ["--per-kind 1", "at least 2"]),
        (["reference"], ["reference", "folder"]),
        (["reference", "{tmp}"], ["summary.json"]),
        (["reference-plot", "{tmp}"], ["no reference summaries"]),
        (["report", "{tmp}"], ["no summary.json"]),
        (["models", "--runs", "2"], ["--runs", "does not apply to models"]),
    ],
)
def test_the_former_side_doors_are_commands_with_one_line_errors(argv, names, tmp_path, capsys):
    """reference, reference-plot, relevance-fit, relevance-scores, report and models are
    commands of ``python -m corrections_sim.run``: bad input is one line and exit status 2,
    before anything is written."""
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert _main(argv) == 2
    _one_line(capsys.readouterr().err, *names)
    assert list(tmp_path.iterdir()) == []


def test_models_check_lists_what_drifted_and_exits_1(tmp_path, capsys):
    assert _main(["models", "--check", "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert "differs from the code" in err and "scene.xml" in err
    assert _main(["models", "--out", str(tmp_path)]) == 0
    assert _main(["models", "--check", "--out", str(tmp_path)]) == 0


def test_what_an_interrupt_leaves_is_said_without_importing_anything():
    """An interrupt can land inside an import (scipy's, the figure registry's); saying what it
    left must not import again what is half-imported (a traceback and exit 1, seen once)."""
    code = (
        "import argparse, sys\n"
        "from corrections_sim.cli import main\n"
        "import corrections_sim.cli.commands  # as main() has by the time it parsed\n"
        "before = set(sys.modules)\n"
        "args = argparse.Namespace(figure='interact', interact_session=3, db='x.sqlite')\n"
        "said = [main._nothing_kept(None), main._nothing_kept(args),\n"
        "        main._nothing_kept(argparse.Namespace(figure='replay')),\n"
        "        main._nothing_kept(argparse.Namespace(figure='fig4'))]\n"
        "print(sorted(set(sys.modules) - before))\n"
        "print(said)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.splitlines()
    assert out[0] == "[]", out[0]
    assert "--resume 3 --db x.sqlite" in out[1] and "replay wrote nothing" in out[1]
    assert "fig4 stopped before any run had finished" in out[1]
    assert "before a command had started" in out[1]


def test_every_interrupt_message_names_its_command():
    """What an interrupt leaves is said in the command's own words, naming it: serve-study
    said a figure run's "no finished runs to keep (figs. 4-6 resume, figs. 1-3 start over)"."""
    import argparse

    from corrections_sim.cli.commands import commands

    for name, command in commands().items():
        said = command.nothing_kept(argparse.Namespace(figure=name, db=None, out=None))
        assert name in said, (name, said)
        assert "figs. 4-6" not in said, (name, said)


def test_the_command_line_module_imports_nothing_heavy():
    """``python -m corrections_sim.run`` imports cli.main before main() puts its interrupt
    handlers in place: a Ctrl-C then (seen at 0.7 s on a loaded machine, while the commands
    imported numpy) killed the process by SIGINT instead of ending it with status 130. The
    module imports neither numpy nor the commands; main() does."""
    code = (
        "import sys\n"
        "import corrections_sim.cli.main\n"
        "print(sorted(m for m in ('numpy', 'corrections_sim.cli.commands') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
