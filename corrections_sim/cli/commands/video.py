"""``video``: an MP4 or GIF of a recorded fig. 4/5 run."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from corrections_sim.cli.command import Command, wrote_nothing
from corrections_sim.cli.common import out_dir
from corrections_sim.cli.errors import UsageError
from corrections_sim.defaults import DEFAULTS


def run_video(args: argparse.Namespace) -> list[Path]:
    """An MP4/GIF of a recorded fig. 4/5 run: plan, correction, learned plan (see video.py)."""
    from corrections_sim.figures import video
    from corrections_sim.scene.models import ModelFileError

    try:
        result = video.make_video(
            out_dir(args),
            args.source or "fig4",
            learner=args.learner or DEFAULTS["video"][0],
            run=0 if args.run is None else args.run,
            corrections=args.corrections,
            model_path=None if args.model is None else Path(args.model),
            video_file=None if args.video_file is None else Path(args.video_file),
        )
    except ModelFileError as exc:
        raise UsageError(f"--model {exc}") from None
    except video.VideoInputError as exc:
        raise UsageError(str(exc)) from None
    print(f"{result.frames} frames, {result.seconds:.1f} s", file=sys.stderr)
    return [result.path]


COMMAND = Command(
    name="video",
    run=run_video,
    help="animate corrections of a recorded fig4/fig5 run (MP4 or GIF)",
    options=("out", "source", "learner", "run", "corrections", "model", "video_file"),
    option_help={"learner": f"whose run to show (default {DEFAULTS['video'][0]})"},
    nothing_kept=wrote_nothing,
)
