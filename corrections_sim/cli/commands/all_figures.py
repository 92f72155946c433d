"""``all``: every figure of the paper, fig1 to fig6, one after the other, each with the options
that apply to it."""

from __future__ import annotations

import argparse
from pathlib import Path

from corrections_sim.cli.command import Command
from corrections_sim.cli.commands.figure import figures, run_figure


def all_options() -> tuple[str, ...]:
    """``all``'s options: every option of a figure it runs (each takes what applies to it)."""
    from corrections_sim.figures.registry import COMMON_OPTIONS

    options = [o for f in figures().values() if f.in_all for o in f.options]
    return tuple(dict.fromkeys((*COMMON_OPTIONS, *options)))


def run_all(args: argparse.Namespace) -> list[Path]:
    """Every figure of the paper, fig1 to fig6, one after the other (the scene render is
    ``run scene``); each takes the options that apply to it."""
    written = []
    for figure in figures().values():
        if figure.in_all:
            written += run_figure(args, figure)
    return written


def __getattr__(name: str):
    # COMMAND's options are those of the figures it runs, read from the figure registry when
    # the command line is built (not when this module is imported).
    if name == "COMMAND":
        return Command("all", run_all, "fig1 to fig6, one after the other", all_options())
    raise AttributeError(name)
