"""What every command's edge shares: the output folder (``--out``, a folder made by other
settings refused without ``--force``), a notice on stderr, a staging folder whose files replace
the final ones only on success, and the progress of a batch."""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from corrections_sim.cli import output_folder
from corrections_sim.cli.errors import UsageError
from corrections_sim.cli.executors import check_interrupted, uninterrupted


def out_dir(args: argparse.Namespace) -> Path:
    """The output folder: --out, or the preset's default (see :mod:`output_folder`)."""
    if args.out is None:
        return output_folder.default_out(args.quick)
    if not args.out.strip():
        raise UsageError("--out '': give a folder name (default: results, or results/quick)")
    return Path(args.out)


def check_replace(
    args: argparse.Namespace,
    final: Path,
    figure: str,
    settings: dict,
    upgrade=None,
    *,
    preset: str | None = None,
) -> str:
    """Refuse (exit 2) to replace a figure folder made by other settings without --force;
    otherwise the line to print, once the command is sure to start, saying what it replaces.
    ``preset``: the folder's (default: ``--quick``'s)."""
    preset = preset or ("quick" if args.quick else "paper")
    try:
        return output_folder.check_replace(final, figure, preset, settings, args.force, upgrade)
    except output_folder.FolderTaken as exc:
        raise UsageError(f"--out {final.parent}: {exc}") from None


def say(notice: str) -> None:
    if notice:
        print(notice, file=sys.stderr)


def writable_dir(path: Path) -> Path:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--out {path}: cannot create the folder ({exc.strerror})") from None
    if not os.access(path, os.W_OK):
        raise UsageError(f"--out {path}: the folder is not writable")
    return path


@contextlib.contextmanager
def staged(final: Path) -> Iterator[Path]:
    """A scratch folder beside ``final``; its files replace ``final``'s only if the body
    succeeds, so a failed command leaves earlier results as they were."""
    final.parent.mkdir(parents=True, exist_ok=True)  # a figure's folder may be nested
    staging = Path(tempfile.mkdtemp(prefix=f".{final.name}-", dir=final.parent))
    try:
        yield staging
        final.mkdir(parents=True, exist_ok=True)
        with uninterrupted():
            for item in sorted(staging.iterdir()):
                os.replace(item, final / item.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


class Progress:
    """Progress of a batch: a tqdm bar with rate and ETA on a terminal, otherwise a plain
    line at most every ``every`` seconds (and at the end), for CI logs."""

    def __init__(self, label: str, *, unit: str = "run", every: float = 15.0, stream=None) -> None:
        self.label = label
        self.unit = unit
        self.every = every
        self.stream = stream or sys.stderr
        self._bar = None
        self._start = time.perf_counter()
        self._last = -np.inf

    def phase(self, label: str, unit: str) -> Progress:
        """The progress of a step before the batch (e.g. building a plan atlas), on the same
        stream, labelled ``<label> <label of this step>``."""
        return Progress(f"{self.label} {label}", unit=unit, every=self.every, stream=self.stream)

    def __call__(self, done: int, total: int) -> None:
        check_interrupted()  # one that a library's import swallowed (see there)
        if self.stream.isatty():
            if self._bar is None:
                from tqdm import tqdm

                self._bar = tqdm(
                    total=total, initial=done, desc=self.label, unit=self.unit, file=self.stream
                )
            self._bar.update(done - self._bar.n)
            if done == total:
                self._bar.close()
            return
        now = time.perf_counter()
        if done < total and now - self._last < self.every:
            return
        self._last = now
        elapsed = now - self._start
        rate = done / elapsed if elapsed > 0 else 0.0
        eta = f"{(total - done) / rate:.0f} s" if 0 < rate and done < total else "-"
        print(
            f"{self.label}: {done}/{total} {self.unit}s, {elapsed:.0f} s elapsed, ETA {eta}",
            file=self.stream,
            flush=True,
        )
