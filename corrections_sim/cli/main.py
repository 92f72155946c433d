"""Command line: reproduce a figure of the paper headless.

    python -m corrections_sim.run fig4             # results/fig4/ (CSV, summary, PNG, PDF)
    python -m corrections_sim.run fig5 --quick     # results/quick/fig5/ (what CI runs)
    python -m corrections_sim.run study my.toml    # results/my/ (docs/study-files.md)
    python -m corrections_sim.run scene            # results/scene.png

Bad input ends with a one-line message on stderr and exit status 2; nothing already in the
output folder is overwritten by a run that failed, and a figure folder made with other
settings only with --force (:mod:`corrections_sim.cli.output_folder`). SIGINT and SIGTERM end
the command within seconds at any moment with one line and exit status 130, keeping the
finished runs (:mod:`corrections_sim.cli.executors`).
"""

from __future__ import annotations

import argparse
import copy
import sys
import warnings
from collections.abc import Sequence

from corrections_sim.cli.command import nothing_kept_by_default
from corrections_sim.cli.errors import UsageError
from corrections_sim.cli.executors import Interrupted, interruption, interrupts, taken

# Nothing heavier at import: ``python -m corrections_sim.run`` imports this module before
# main() puts its interrupt handlers in place, so the commands (and numpy, with the options'
# types) are imported inside main(), where a Ctrl-C during an import is an interrupt like any
# other.


def commands() -> dict:
    """Every command by name (:func:`corrections_sim.cli.commands.commands`)."""
    from corrections_sim.cli.commands import commands

    return commands()


def applies(command: str) -> tuple[str, ...]:
    """The options ``command`` takes; any other option given is refused, not ignored."""
    return commands()[command].options


def command_help(command: str) -> str:
    """``COMMAND --help``: the command's own options only."""
    p = parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[command].format_help()


def _asks_command_help(given: Sequence[str]) -> str | None:
    """The command of ``COMMAND ... --help`` (None for a bare ``--help``)."""
    if not any(a in ("-h", "--help") for a in given):
        return None
    known = set(commands())
    for token in given:
        if token in known:
            return token
        if not token.startswith("-"):
            return None
    return None


def parser() -> argparse.ArgumentParser:
    """The command line: one subcommand per figure and tool, each with its own options
    (from :func:`~corrections_sim.cli.options.catalogue`), help and errors."""
    from corrections_sim.cli.options import Parser, catalogue

    flat = catalogue()
    p = Parser(
        prog="python -m corrections_sim.run",
        allow_abbrev=False,
        description="Reproduce a figure of Losey & O'Malley (CoRL 2018) headless, or run a "
        "user study. Figures 4-6 and study files are resumable: finished runs are kept in "
        "OUT/.runs/<figure>/ (keyed by a hash of the settings and the code) and an "
        "interrupted command, run again, only computes what is missing. Ctrl-C or SIGTERM "
        "stops the command within seconds (exit status 130). A figure folder made with other "
        "settings or another preset is replaced only with --force. "
        "COMMAND --help lists the command's own options.",
    )
    sub = p.add_subparsers(
        dest="figure", metavar="COMMAND", title="commands", parser_class=Parser, required=True
    )
    every = [a for a in flat._actions if a.dest != "help"]
    for name, command in commands().items():
        allowed = set(command.options)
        sp = sub.add_parser(
            name,
            help=command.help,
            description=f"{name}: {command.help}.",
            prog=f"python -m corrections_sim.run {name}",
            allow_abbrev=False,
        )
        groups: dict[str, argparse._ArgumentGroup] = {}
        for group in flat._action_groups:
            for action in group._group_actions:
                if action.dest not in allowed:
                    continue
                mine = copy.copy(action)
                mine.help = command.option_help.get(action.dest, action.help)
                if action.dest == "study_file":
                    mine.metavar = command.file
                    sp._add_action(mine)
                    continue
                title = group.title if group.title == "where the runs execute" else "options"
                if title not in groups:
                    groups[title] = (
                        sp._optionals if title == "options" else sp.add_argument_group(title)
                    )
                groups[title]._add_action(mine)
        # Options of other commands read as unset, as the code that reads them expects.
        sp.set_defaults(**{a.dest: a.default for a in every if a.dest not in allowed})
    return p


def _parse(given: Sequence[str]) -> argparse.Namespace:
    """``given`` parsed by its command's parser; an option of another command is refused in
    one line that says which options the command takes."""
    from corrections_sim.cli.options import catalogue, label

    p = parser()
    args, extra = p.parse_known_args(given)
    if extra:
        token = extra[0]
        allowed = applies(args.figure)
        takes = ", ".join(label(n) for n in allowed)
        if token.startswith("-"):
            option = token.split("=")[0]
            known = {o for a in catalogue()._actions for o in a.option_strings}
            if option in known:
                raise UsageError(f"{option}: does not apply to {args.figure} (it takes {takes})")
            raise UsageError(f"{option}: no such option of {args.figure} (it takes {takes})")
        if "study_file" not in allowed:
            raise UsageError(f"FILE: does not apply to {args.figure} (it takes {takes})")
        raise UsageError(f"{token}: an argument {args.figure} does not take (it takes {takes})")
    return args


def _nothing_kept(args: argparse.Namespace | None) -> str:
    """What an interrupted command leaves, said for that command."""
    # No import here: the interrupt may have landed inside one, and a half-imported module
    # must not be imported again. The tools' modules are there if the command got that far.
    loaded = sys.modules.get("corrections_sim.cli.commands")
    tool = getattr(loaded, "tool", None)
    command = None if tool is None else tool(getattr(args, "figure", None))
    return nothing_kept_by_default(args) if command is None else command.nothing_kept(args)


def _note(message, category, filename, lineno, file=None, line=None) -> None:
    """A study file's older spelling as one line (``note: …``); any other warning as Python
    shows it."""
    if category.__name__ == "OlderSpelling":
        print(f"note: {message}", file=sys.stderr)
    else:
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; 0 on success, 1 on a failure, 2 on bad input, 130 on SIGINT/SIGTERM."""
    with interrupts(), warnings.catch_warnings():  # from the start: heavy imports inside
        warnings.showwarning = _note
        try:
            given = list(sys.argv[1:] if argv is None else argv)
            command = _asks_command_help(given)
            if command is not None:
                print(command_help(command), end="")
                return 0
            args = _parse(given)
            args.argv = given
            written = commands()[args.figure].run(args)
        except UsageError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except (KeyboardInterrupt, Exception) as exc:
            cause = interruption(exc)
            if cause is not None:
                taken()
            if cause is None and isinstance(exc, RuntimeError):
                # A missing GL backend, a planner failure: one line, no trace.
                print(f"error: {str(exc).splitlines()[0]}", file=sys.stderr)
                return 1
            if cause is None:
                raise
            kept = getattr(cause, "kept", None)
            named = getattr(locals().get("args"), "figure", None)
            message = (
                f"{named}: {kept}; run it again to resume"
                if kept
                else _nothing_kept(locals().get("args"))
            )
            by = f" ({cause})" if isinstance(cause, Interrupted) else ""
            print(f"interrupted: {message}{by}", file=sys.stderr)
            return 130
    for path in written:
        print(f"wrote {path}")
    return 0
