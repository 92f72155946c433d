"""The commands of ``python -m corrections_sim.run``, registered here once each.

A command is one module of this package that defines ``COMMAND``
(a :class:`~corrections_sim.cli.command.Command`: its name, its ``run``, its help, the options
it takes and what its FILE is); the registered figures are commands too
(:func:`~corrections_sim.cli.commands.figure.figure_commands`). Adding a command is a new module
here and its name in :data:`TOOLS`.
"""

from __future__ import annotations

from corrections_sim.cli.command import Command
from corrections_sim.cli.commands import (
    all_figures,
    analyze,
    cache,
    figure,
    interact,
    models,
    pilot,
    power,
    quotes,
    reference_plot,
    relevance_fit,
    relevance_scores,
    replay,
    report,
    scene,
    serve_study,
    study_status,
    video,
)

#: The commands that are not figures, in ``--help``'s order.
TOOLS = (
    scene,
    all_figures,
    video,
    interact,
    replay,
    serve_study,
    study_status,
    analyze,
    pilot,
    power,
    reference_plot,
    relevance_fit,
    relevance_scores,
    report,
    quotes,
    models,
    cache,
)


def commands() -> dict[str, Command]:
    """Every command by name, in ``--help``'s order: the registered figures, then the tools."""
    return {**figure.figure_commands(), **{t.COMMAND.name: t.COMMAND for t in TOOLS}}


def tool(name: str | None) -> Command | None:
    """The tool called ``name``, looked up without importing anything beyond this package's
    modules (a figure's, and ``all``'s, command is built from the figure registry: None here).
    Safe while an interrupt is being handled, when a half-imported package must not be
    imported again."""
    for module in TOOLS:
        command = vars(module).get("COMMAND")
        if command is not None and command.name == name:
            return command
    return None
