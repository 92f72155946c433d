"""``quotes``: the numbers the README and the docs quote from committed ``results/``, checked
against their files or filled in from them (:mod:`corrections_sim.figures.quotes`).

    python -m corrections_sim.run quotes            # README.md and docs/*.md: which differ
    python -m corrections_sim.run quotes --fill     # rewrite them from results/
    python -m corrections_sim.run quotes docs/results.md --fill
"""

from __future__ import annotations

import argparse
from pathlib import Path

from corrections_sim.cli.command import Command
from corrections_sim.cli.errors import UsageError


def pages(root: Path) -> list[Path]:
    """The pages that quote results: the README and every docs page under ``root``, as paths
    relative to it."""
    found = [root / "README.md", *sorted((root / "docs").glob("*.md"))]
    return [p.relative_to(root) for p in found if p.is_file()]


def run_quotes(args: argparse.Namespace) -> list[Path]:
    """Check (or with ``--fill`` rewrite) the quotes of FILE, or of every page, against
    ``results/`` in the working directory; a page that differs is listed, exit status 1."""
    from corrections_sim.figures import quotes

    root = Path.cwd()
    if not (root / "results").is_dir():
        raise UsageError("results/: not in the working directory (run from the checkout's top)")
    chosen = [Path(args.study_file)] if args.study_file else pages(root)
    written, stale = [], 0
    for page in chosen:
        try:
            text = page.read_text()
            if args.fill:
                filled = quotes.fill(text, root)
                if filled != text:
                    page.write_text(filled)
                    written.append(page)
                continue
            for name, said, now in quotes.stale(text, root):
                stale += 1
                print(f"{page}: quote {name}: the page says {said!r}, results/ says {now!r}")
        except OSError as exc:
            raise UsageError(f"{page}: {exc.strerror or exc}") from None
        except quotes.QuoteError as exc:
            raise UsageError(f"{page}: {exc}") from None
    if stale:
        raise RuntimeError(f"{stale} quoted numbers differ from results/ (--fill writes them)")
    return written


COMMAND = Command(
    name="quotes",
    run=run_quotes,
    help="check the numbers README.md and docs/ quote from results/, or fill them in",
    options=("study_file", "fill"),
    file="PAGE",
    option_help={"study_file": "one page (default: README.md and docs/*.md)"},
    nothing_kept=lambda args: "quotes wrote nothing or whole pages; run it again",
)
