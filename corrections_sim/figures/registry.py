"""One shape for every figure and study: settings, a run, files; registered by name.

A figure is an object with a name, the command-line options it takes, and three steps (the
bsuite shape: settings as data, a run, an analysis that only reads records):

* ``load(quick=..., overrides=...)`` — its settings, checked where they enter (a
  ``ValueError`` naming the field);
* ``run(settings, executor, progress, cache)`` — the computation, on any
  ``concurrent.futures`` executor; resumable figures load and keep finished runs in the
  caches their ``cache_keys(settings)`` asked for;
* ``write(settings, result, folder)`` — its files in ``folder``, and the fields it adds to
  ``summary.json`` (what it shows, where its numbers came from).

The command line (:mod:`corrections_sim.run`) parses options, picks the executor and the
output folder, and calls these; it knows no figure. A new figure is one module that calls
:func:`register` and one line in :data:`BUILT_IN`.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from concurrent.futures import Executor
from pathlib import Path
from typing import Any, Protocol

from corrections_sim.study.runner import RunCache

#: Modules whose import registers the package's figures (figs. 1–6 and ``study``).
BUILT_IN = (
    "corrections_sim.figures.selection",
    "corrections_sim.figures.deployment",
    "corrections_sim.figures.learning_study",
    "corrections_sim.figures.every_learner",
    "corrections_sim.figures.robustness",
    "corrections_sim.figures.physical",
    "corrections_sim.figures.relevance",
    "corrections_sim.figures.ferl",
    "corrections_sim.figures.reference_figure",
    "corrections_sim.figures.sbc",
    "corrections_sim.figures.coverage",
)

#: Options every figure takes (the command line's own: where, how big, which executor).
COMMON_OPTIONS = ("out", "quick", "force", "workers", "scheduler")

Progress = Callable[[int, int], None]


#: The run caches a figure receives: part ("" for the whole figure, "column-0", …) -> cache.
Caches = Mapping[str, RunCache]


class Figure(Protocol):
    """A figure or study: what the command line runs by name.

    Attributes:
        name: the command (``fig4``) and the output sub-folder.
        help: one line for ``--help``.
        options: command-line options it takes beyond :data:`COMMON_OPTIONS` (their
            ``argparse`` destinations); they reach :meth:`load` as ``overrides``.
        unit: what progress counts ("run", "task").
        in_all: whether ``run all`` makes it.
    """

    name: str
    help: str
    options: tuple[str, ...]
    unit: str
    in_all: bool

    def load(self, *, quick: bool, overrides: Mapping[str, Any]) -> Any:
        """The settings (raises ValueError naming the field)."""
        ...

    def folder(self, settings: Any) -> str:
        """The output sub-folder and the name in ``summary.json`` (usually :attr:`name`)."""
        ...

    def cache_keys(self, settings: Any) -> dict[str, dict]:
        """The run caches :meth:`run` uses, part -> the settings their runs depend on; empty
        when the figure is not resumable. The command line opens and locks each (adding the
        code's fingerprint to the key) before anything runs, and passes them to :meth:`run`."""
        ...

    def recorded(self, settings: Any, *, quick: bool) -> dict:
        """The settings as plain data, for ``summary.json`` and to compare an output folder's
        earlier settings with (see :mod:`corrections_sim.cli.output_folder`)."""
        ...

    # Optional: ``upgrade_recorded(old) -> dict``, settings recorded by an older version in
    # today's form (the command line compares them with :meth:`recorded`'s);
    # ``default_out(settings) -> Path``, where its folder goes without ``--out`` (inside the
    # figure a reference judges); ``lines(settings, result) -> list[str]``, what it prints
    # once its files are written; ``file`` and ``option_help``, its FILE and its options'
    # help where they differ from the catalogue's; a ``preset`` field on its settings, the
    # preset its summary records (default: ``--quick``'s).

    def run(
        self, settings: Any, executor: Executor, progress: Progress, cache: Caches | None
    ) -> Any: ...

    def write(self, settings: Any, result: Any, folder: Path) -> dict:
        """Write the figure's files into ``folder``; return its ``summary.json`` fields."""
        ...


_FIGURES: dict[str, Figure] = {}


def register(figure: Figure) -> Figure:
    """Add ``figure`` under its name; a name registered twice is a mistake, not an update."""
    if figure.name in _FIGURES and _FIGURES[figure.name] is not figure:
        raise ValueError(f"figure {figure.name!r} is registered already")
    _FIGURES[figure.name] = figure
    return figure


def figures() -> dict[str, Figure]:
    """Every registered figure, in name order (``run all`` makes fig1 … fig6 in that order,
    whichever module was imported first)."""
    for module in BUILT_IN:
        importlib.import_module(module)
    return dict(sorted(_FIGURES.items()))
