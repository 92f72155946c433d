"""Every option of every command, defined once (:func:`catalogue`), the types that parse their
values, and the parser class whose errors are one line. A command takes the options it names
(:attr:`~corrections_sim.cli.command.Command.options`) from the catalogue; any other is
refused (:mod:`corrections_sim.cli.main`).
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Callable

import numpy as np

from corrections_sim.defaults import DEFAULTS


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value}: must be a positive integer")
    return value


def port(text: str) -> int:
    """A TCP port to listen on, 1 … 65535 (viser's server thread would die on a larger one and
    leave the command waiting for ever)."""
    value = positive_int(text)
    if value > 65535:
        raise argparse.ArgumentTypeError(f"{value}: a port lies in [1, 65535]")
    return value


def speed(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a number") from None
    if not (np.isfinite(value) and 0 < value <= 1):
        raise argparse.ArgumentTypeError(f"{value}: must lie in (0, 1]")
    return value


def positive_float(option: str) -> Callable[[str], float]:
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: expected a number") from None
        if not (np.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"{option} must be a finite number > 0, got {text}")
        return value

    return parse


def floats(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected comma-separated numbers") from None
    if not all(np.isfinite(values)):
        raise argparse.ArgumentTypeError(f"{text!r}: every value must be finite")
    return values


def matrix(text: str) -> tuple[tuple[float, ...], ...]:
    """'a,b' is diag(a, b); 'a,b;c,d' is a full matrix, rows separated by ';'."""
    rows = [floats(row) for row in text.split(";")]
    if len(rows) == 1:
        return tuple(
            tuple(v if i == j else 0.0 for j in range(len(rows[0]))) for i, v in enumerate(rows[0])
        )
    if any(len(r) != len(rows) for r in rows):
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected a square matrix, rows separated by ';'"
        )
    return tuple(rows)


def counts(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected whole numbers like 4,8,12, got {text!r}"
        ) from None
    if not values or any(v < 1 for v in values):
        raise argparse.ArgumentTypeError(f"expected whole numbers >= 1, got {text!r}")
    return values


def names(text: str) -> tuple[str, ...]:
    return tuple(n.strip() for n in text.split(","))


def label(dest: str) -> str:
    """How the command line spells an option (the positional FILE has no dashes)."""
    return "FILE" if dest == "study_file" else "--" + dest.replace("_", "-")


#: A value that starts with a minus sign but is a number or a list of numbers ("-1,1",
#: "-.5,1;0,2", "-1e-3"): a value, never an option.
NUMBERS = re.compile(r"-\.?\d[\d.eE+\-]*([,;]\s*[-+]?\.?\d[\d.eE+\-]*)*")


class Parser(argparse.ArgumentParser):
    """argparse, but a bad option is one line on stderr (no usage block), exit status 2."""

    def error(self, message: str):
        self.exit(2, f"error: {message} (see --help)\n")

    def _parse_optional(self, arg_string: str):
        # argparse reads any token that starts with a minus sign and is not a plain number
        # as an option, so "--theta-star -1,1" would lack its value; a list of numbers is a
        # value wherever it stands.
        if NUMBERS.fullmatch(arg_string):
            return None
        return super()._parse_optional(arg_string)


def catalogue() -> argparse.ArgumentParser:
    """Every option of every command, once (each command's parser takes its own from here,
    :func:`parser`)."""
    # Imported here, not at the top: they load the planner's stack (CasADi, MuJoCo, pinocchio),
    # and main() has its interrupt handlers in place by the time this runs.
    from corrections_sim.learning.base import LEARNERS
    from corrections_sim.people.corrections import CORRECTIONS
    from corrections_sim.people.users import USERS

    p = Parser(prog="python -m corrections_sim.run", allow_abbrev=False)
    p.add_argument(
        "study_file",
        nargs="?",
        metavar="FILE",
        help="the study file (TOML; see docs/study-files.md, and experiments/ for examples)",
    )
    p.add_argument(
        "--out",
        help="output folder (default: results; with --quick the scratch folder results/quick)",
    )
    p.add_argument("--env", help="environment name for 'scene' (default: s0-t0-l1)")
    p.add_argument("--quick", action="store_true", help="the figure's quick preset (CI size)")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace a figure folder made with other settings or another preset (without "
        "it, such a folder is left alone and the command refuses)",
    )
    g = p.add_argument_group(
        "learning studies (fig4, fig5, fig6, study); defaults come from the study file"
    )
    g.add_argument(
        "--runs",
        type=positive_int,
        help="runs per learner (an active learner runs once: it chooses its environments)",
    )
    g.add_argument("--iterations", type=positive_int, help="corrections per run")
    g.add_argument("--seed", type=int, help="root seed of every random draw")
    g.add_argument(
        "--theta-star", type=floats, metavar="W,W", help="the user's true weights θ*, e.g. -1,1"
    )
    g.add_argument(
        "--theta0", type=floats, metavar="W,W", help="the robot's initial estimate θ̂⁰, e.g. 0,0"
    )
    g.add_argument(
        "--cov0",
        type=matrix,
        metavar="P",
        help="initial covariance P⁰: 'a,b' for diag(a, b) or 'a,b;c,d' row by row "
        "(symmetric positive definite)",
    )
    g.add_argument(
        "--learners",
        type=names,
        metavar="L,L",
        help="which learners, from "
        + ", ".join(LEARNERS)
        + " or a plug-in's (e.g. PP,KF,AL,KF-C); "
        "their parameters stay as the study file gives them",
    )
    g.add_argument(
        "--user",
        help="the simulated user, from " + ", ".join(USERS) + " or a plug-in's (biased: "
        "moves its worst waypoint(s), the paper's; deform: the path deforms smoothly; noisy: "
        "Φ(ξ*) + Gaussian noise; model: any correction model); replaces the file's user",
    )
    g.add_argument(
        "--set",
        action="append",
        metavar="KEY.PATH=VALUE",
        help="set any key of the study, e.g. user.step=0.5, learners.KF-C.model=deform, "
        "filter.observation_noise=0.1 (repeatable; a value is read as TOML, else as text); "
        "replay sets its learners' keys only (learners.NAME.KEY)",
    )
    g.add_argument("--user-step", type=float, help="= --set user.step=S")
    g.add_argument("--user-waypoints", type=int, help="= --set user.waypoints=N")
    g.add_argument(
        "--correction-model",
        help="KF-C's and AL-C's model of a correction, from " + ", ".join(CORRECTIONS) + " or a "
        "plug-in's (= --set learners.KF-C.model=NAME)",
    )
    g.add_argument("--correction-step", type=float, help="how far KF-C's model moves, (0, 1]")
    g.add_argument("--correction-waypoints", type=int, help="how many waypoints KF-C's model moves")
    g.add_argument(
        "--fixed-alpha",
        type=positive_float("fixed_alpha"),
        help="a fixed learning rate for PP and PP-C (default: from KF's / KF-C's gains)",
    )
    g.add_argument(
        "--solver",
        help="the planner's solver (default fatrop; ipopt is the original path)",
    )
    g.add_argument(
        "--warm-start",
        action="store_true",
        default=None,
        help="start each solve from the run's nearest solved θ (faster; results move at the "
        "solver's tolerance, see docs/choices.md)",
    )
    g.add_argument(
        "--online",
        action="store_true",
        default=None,
        help="learn during the motion: a physical user's push updates the learner and the robot "
        "replans the rest of the motion (= --set online=true)",
    )
    p.add_argument(
        "--fill",
        action="store_true",
        help="rewrite each quoted number from its file in results/ (without it: only check)",
    )
    v = p.add_argument_group("video (reads OUT/<figure>/curves.csv of a finished fig4/fig5)")
    v.add_argument("--from", dest="source", metavar="FIG", help="fig4 or fig5 (default fig4)")
    v.add_argument(
        "--learner",
        help=f"video: whose run to show (default {DEFAULTS['video'][0]}); interact: who learns "
        f"(default {DEFAULTS['session'][0]})",
    )
    v.add_argument("--run", type=int, help="the run's index (default 0)")
    v.add_argument(
        "--corrections",
        metavar="T,T",
        help="iterations to show, e.g. 1,6,12 (default: first, middle, last)",
    )
    v.add_argument("--model", help="the MJCF to render (default models/scene.xml)")
    v.add_argument(
        "--video-file", help="an .mp4 or .gif (default OUT/video/<figure>-<learner>-run<N>.mp4)"
    )
    i = p.add_argument_group(
        "interact (FILE: a study file, default fig. 4's) and replay (FILE: the database)"
    )
    i.add_argument("--db", help="the study's SQLite log (default results/interact/study.sqlite)")
    i.add_argument("--participant", help="the participant's pseudonym (never a name)")
    i.add_argument("--host", help="address to serve the page on (default 127.0.0.1)")
    i.add_argument("--port", type=port, help="port of the page, 1-65535 (default 8080)")
    i.add_argument("--resume", type=int, metavar="SESSION", help="continue a logged session")
    i.add_argument(
        "--mode",
        choices=["drag", "physical"],
        help="drag (default): drag the cup at a waypoint of the plan; physical: push the cup "
        "while the arm moves under impedance, the robot learns and replans when you let go",
    )
    i.add_argument(
        "--speed",
        type=speed,
        help="physical: simulated seconds per real second, in (0, 1] (default 1)",
    )
    i.add_argument(
        "--drag-model",
        help="how a dragged waypoint becomes the corrected path: waypoint (default: only "
        "that waypoint, as the learners' default model of a correction), deform (the "
        "minimum-jerk deformation of the path), or a plug-in's",
    )
    i.add_argument(
        "--headless",
        action="store_true",
        help="no page: the study's simulated user (--user) corrects, --iterations times",
    )
    i.add_argument(
        "--labelled",
        type=positive_int,
        metavar="N",
        help="interact: ask the person for N labelled corrections, half toward a stated "
        "preference (--theta-star, default the study's θ*), half nudges for no reason, in a "
        "seeded order; the page says which, the log keeps the label",
    )
    i.add_argument("--session", type=int, help="for replay: which session (default the last)")
    u = p.add_argument_group("a user study from a protocol")
    u.add_argument(
        "--enroll",
        metavar="CODE,CODE",
        help="enroll these participant codes (pseudonyms) and print each one's link",
    )
    u.add_argument("--participants", type=positive_int, help="simulated participants (default 12)")
    u.add_argument(
        "--pool",
        type=positive_int,
        help="simulated participants to cut into studies (default 2400: 200 studies of 12)",
    )
    u.add_argument(
        "--sizes",
        type=counts,
        metavar="N,N",
        help="study sizes to measure the power at (default 4,8,12,16,24,32,48)",
    )
    u.add_argument(
        "--outcome",
        help="the outcome to power for: final_error, mean_regret, seconds (default: the "
        "protocol's primary)",
    )
    r = p.add_argument_group(
        "exact references, fits and the scene's files (reference, relevance-fit, models)"
    )
    r.add_argument(
        "--points",
        type=positive_int,
        help="grid points per axis over [-3, 3]^k (default 61; with a plan atlas, over its "
        "box, default its own)",
    )
    r.add_argument(
        "--resolution",
        type=float,
        metavar="R",
        help="on a study with a plan atlas: refine the reference's grid where its posterior "
        "has fewer than R nodes in its narrowest sd (default 2, twice the exact learners'; "
        "0: never)",
    )
    r.add_argument(
        "--axes",
        choices=("all", "narrow"),
        help="on a refined reference: how its cells are cut, 'all' (in 2^k) or 'narrow' (along "
        "the posterior's narrow axes, as the exact learners of the three-feature study cut "
        "theirs); default: as the learner cuts its own, 'all' for a filter",
    )
    r.add_argument(
        "--one-step",
        action="store_true",
        help="also the learner's update from the reference before each correction (a Kalman "
        "learner with N fixed): the error of one filter step, apart from accumulation",
    )
    r.add_argument(
        "--restart",
        metavar="S,S",
        help="also the learner's filter run on from the reference at these iterations (0: the "
        "prior): NEES / reference NEES at the end for each",
    )
    r.add_argument(
        "--particles",
        type=int,
        metavar="N",
        help="also run PF-C's particle machinery with N particles on the same corrections: "
        "judged against the grid at k = 2, the reference itself at k > 2 (no grid there)",
    )
    r.add_argument(
        "--check-grid",
        action="store_true",
        help="also on the halved grid (first run): how much mean and covariance move",
    )
    r.add_argument(
        "--per-kind",
        type=int,
        help="simulated relevant (and irrelevant) corrections per mode (default 60; 12 with "
        "--quick)",
    )
    r.add_argument(
        "--check",
        action="store_true",
        help="only list the files that differ from what the code writes; exit status 1 if any",
    )
    c = p.add_argument_group("the machine's cache (cache)")
    c.add_argument(
        "--prune",
        type=positive_float("--prune"),
        metavar="DAYS",
        help="remove what no run has used for DAYS days (compiled libraries, atlases, plans "
        "between their nodes, reference grids, what dead writers left); it is rebuilt if needed",
    )
    x = p.add_argument_group("where the runs execute")
    x.add_argument(
        "--workers",
        type=positive_int,
        help="local worker processes (default: the cores this process may use)",
    )
    x.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="run on an existing Dask cluster instead of local processes",
    )
    return p
