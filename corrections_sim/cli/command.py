"""A command of ``python -m corrections_sim.run``: everything the command line knows of it, in
one value its own module defines (``COMMAND``), registered once in
:mod:`corrections_sim.cli.commands`."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path


def nothing_kept_by_default(args: argparse.Namespace | None) -> str:
    """What an interrupted figure leaves when no run had finished (a figure's command, and
    ``all``, say nothing else; a run that had finished is said by the interrupt itself)."""
    name = getattr(args, "figure", None)
    if name is None:
        return "stopped before a command had started; nothing was written"
    return f"{name} stopped before any run had finished; nothing was written (run it again)"


@dataclass(frozen=True)
class Command:
    """One command.

    Attributes:
        name: as typed after ``python -m corrections_sim.run``.
        run: the command itself: the parsed options in, the files it wrote out.
        help: one line for ``--help``'s list of commands.
        options: the options it takes, by destination, from
            :func:`~corrections_sim.cli.options.catalogue`; any other is refused.
        file: what its positional ``FILE`` is, as its usage line shows it.
        option_help: an option's help where this command reads it otherwise than the
            catalogue says.
        nothing_kept: what an interrupted run of it leaves, naming the command (default
            :func:`nothing_kept_by_default`).
    """

    name: str
    run: Callable[[argparse.Namespace], list[Path]]
    help: str
    options: tuple[str, ...]
    file: str = "FILE"
    option_help: Mapping[str, str] = field(default_factory=dict)
    nothing_kept: Callable[[argparse.Namespace], str] = nothing_kept_by_default


def wrote_nothing(args: argparse.Namespace) -> str:
    """``nothing_kept`` of a command that writes its files only at its end."""
    return f"{args.figure} wrote nothing; run it again"
