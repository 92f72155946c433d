"""The figure registry: every figure and study has one shape, the command line runs whatever is
registered (a new figure is one module and one registration), and each figure's options are
the only ones it accepts."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pytest

from corrections_sim.cli import main as cli
from corrections_sim.cli.options import catalogue
from corrections_sim.figures import registry

PAPER = ("fig1", "fig2", "fig3", "fig4", "fig5", "fig6")


def test_every_figure_of_the_paper_and_the_study_file_is_registered():
    figures = registry.figures()
    assert set(PAPER) | {"study"} <= set(figures)
    assert [n for n, f in figures.items() if f.in_all] == list(PAPER)


@pytest.mark.parametrize("name", [*PAPER, "study"])
def test_every_figure_has_the_protocol(name):
    figure = registry.figures()[name]
    for method in ("load", "folder", "cache_keys", "recorded", "run", "write"):
        assert callable(getattr(figure, method)), method
    assert figure.name == name and figure.help and figure.unit in ("run", "task")
    assert set(figure.options) <= {a.dest for a in catalogue()._actions}
    if name != "study":
        settings = figure.load(quick=True, overrides={})
        assert figure.folder(settings) == name
        json.dumps(figure.recorded(settings, quick=True))  # plain data
        assert all(isinstance(k, dict) for k in figure.cache_keys(settings).values())


def test_a_registered_name_cannot_be_taken_twice():
    with pytest.raises(ValueError, match="fig4"):
        registry.register(Toy(name="fig4"))


@dataclass(frozen=True)
class Toy:
    """A figure written against the protocol alone: squares of 1 … n, on the executor."""

    name: str = "toy"
    help: str = "squares"
    options: tuple[str, ...] = ("runs",)
    unit: str = "task"
    in_all: bool = False

    def load(self, *, quick, overrides):
        n = overrides.get("runs", 2 if quick else 5)
        if n > 10:
            raise ValueError(f"runs = {n}: at most 10")
        return {"n": n}

    def folder(self, settings):
        return self.name

    def cache_keys(self, settings):
        return {}

    def recorded(self, settings, *, quick):
        return dict(settings)

    def run(self, settings, executor, progress, cache):
        squares = list(executor.map(pow, range(1, settings["n"] + 1), [2] * settings["n"]))
        progress(settings["n"], settings["n"])
        return squares

    def write(self, settings, result, folder: Path):
        (folder / "squares.txt").write_text(" ".join(map(str, result)) + "\n")
        return {"total": sum(result)}


def test_a_new_figure_is_one_registration_and_runs_through_the_command_line(
    tmp_path, monkeypatch, capsys
):
    monkeypatch.setattr(registry, "_FIGURES", dict(registry._FIGURES))
    registry.register(Toy())
    assert cli.main(["toy", "--runs", "3", "--workers", "1", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "toy" / "squares.txt").read_text() == "1 4 9\n"
    summary = json.loads((tmp_path / "toy" / "summary.json").read_text())
    assert summary["figure"] == "toy" and summary["settings"] == {"n": 3}
    assert summary["total"] == 14 and summary["command"].endswith(f"--out {tmp_path}")
    capsys.readouterr()
    # Its own options only, and its own checks: one line, exit 2.
    assert cli.main(["toy", "--runs", "11", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err == "error: runs = 11: at most 10\n"
    assert cli.main(["toy", "--iterations", "2", "--out", str(tmp_path)]) == 2
    assert "--iterations: does not apply to toy" in capsys.readouterr().err


def test_run_all_makes_the_paper_figures_in_order_without_touching_the_arguments(
    tmp_path, monkeypatch
):
    made = []

    def fake(args, figure):
        made.append((figure.name, args.runs, args.figure))
        return []

    from corrections_sim.cli.commands import all_figures

    monkeypatch.setattr(all_figures, "run_figure", fake)
    assert cli.main(["all", "--quick", "--runs", "2", "--out", str(tmp_path)]) == 0
    assert made == [(name, 2, "all") for name in PAPER]
