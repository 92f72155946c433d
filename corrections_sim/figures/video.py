"""Animations of a learning run: the robot's plan, the user's correction, the learned plan.

For each chosen iteration t of one run (learner, run index) of fig. 4 or 5, read from the
figure's ``curves.csv`` (θ̂ after every correction, the environment Eᵗ) and ``summary.json``
(θ*, the user, the planner's starts), three trajectories are planned again and played in turn:

* the robot's plan ξᵗ = ξ*(θ̂ᵗ⁻¹, Eᵗ) (blue),
* the user's correction ξ_h, as the run's user makes it from ξᵗ (the paper's biased user moves
  its worst waypoint onto ξ*(θ*, Eᵗ); orange; the user's own plan ξ*(θ*, Eᵗ) is the faint grey
  path),
* the learned plan ξ*(θ̂ᵗ, Eᵗ) in the same environment (green).

Re-planning is cold (the figures warm-start), so a plan can differ from the run's at the
solver's tolerance. Frames are rendered offscreen by MuJoCo from ``models/scene.xml`` and
encoded as MP4 (H.264, the ffmpeg binary of the ``imageio-ffmpeg`` wheel) or GIF (Pillow).
"""

from __future__ import annotations

import csv
import json
import os
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from corrections_sim.defaults import DEFAULTS
from corrections_sim.people.users import Situation
from corrections_sim.planning.planner import Planner, PlannerConfig
from corrections_sim.scene.environments import Environment, paper_environments

FIGURES = ("fig4", "fig5")
FORMATS = (".mp4", ".gif")
#: Stage names, in playing order, with their path colours (rgba).
STAGES = ("robot", "correction", "learned")
COLORS = {
    "robot": (0.15, 0.45, 0.95, 1.0),
    "correction": (1.0, 0.55, 0.05, 1.0),
    "learned": (0.1, 0.7, 0.25, 1.0),
    "intended": (0.35, 0.35, 0.35, 0.35),
}


class VideoInputError(ValueError):
    """Bad input for the video command; the message is one line naming the option."""


@dataclass(frozen=True)
class Episode:
    """One correction of a run, as trajectories (T, 7) in its environment.

    Attributes:
        iteration: t, the correction's number (1-based).
        env: Eᵗ.
        theta_before: θ̂ᵗ⁻¹ (k,), the estimate the robot planned with.
        theta_after: θ̂ᵗ (k,), the estimate after the correction.
        robot: ξ*(θ̂ᵗ⁻¹, Eᵗ).
        intended: ξ*(θ*, Eᵗ), the user's own plan.
        correction: ξ_h, the user's corrected trajectory.
        learned: ξ*(θ̂ᵗ, Eᵗ).
    """

    iteration: int
    env: Environment
    theta_before: np.ndarray
    theta_after: np.ndarray
    robot: np.ndarray
    intended: np.ndarray
    correction: np.ndarray
    learned: np.ndarray

    def trajectory(self, stage: str) -> np.ndarray:
        return {"robot": self.robot, "correction": self.correction, "learned": self.learned}[stage]


@dataclass(frozen=True)
class RunRecord:
    """What a figure recorded of one run: its settings and θ̂ and Eᵗ per iteration.

    Attributes:
        figure: "fig4" or "fig5".
        learner: the learner's name.
        run: the run's index.
        settings: the figure's resolved settings (``summary.json``'s ``settings``).
        thetas: θ̂ᵗ for t = 0 … T, shape (T + 1, k).
        environments: the name of Eᵗ for t = 1 … T (index 0 is t = 1).
    """

    figure: str
    learner: str
    run: int
    settings: dict
    thetas: np.ndarray
    environments: tuple[str, ...]

    @property
    def iterations(self) -> int:
        return len(self.environments)


def load_run(folder: Path, figure: str, learner: str, run: int) -> RunRecord:
    """Read one run from ``folder/<figure>/curves.csv`` and ``summary.json``.

    Raises:
        VideoInputError: a missing or malformed file, an unknown learner or run.
    """
    curves, summary = folder / figure / "curves.csv", folder / figure / "summary.json"
    for path in (curves, summary):
        if not path.is_file():
            raise VideoInputError(
                f"--out {folder}: no {figure}/{path.name}; run "
                f"`python -m corrections_sim.run {figure} --out {folder}` first"
            )
    try:
        settings = json.loads(summary.read_text())["settings"]
        with open(curves, newline="") as fh:
            rows = list(csv.DictReader(fh))
        k = len(settings["theta_star"])
        by_run = {}
        for row in rows:
            if row["learner"] == learner:
                by_run.setdefault(int(row["run"]), []).append(row)
    except (KeyError, ValueError, TypeError) as exc:
        raise VideoInputError(f"{curves}: malformed ({type(exc).__name__}: {exc})") from None
    learners = sorted({row["learner"] for row in rows})
    if learner not in learners:
        raise VideoInputError(f"--learner {learner}: not in {curves}; it has {', '.join(learners)}")
    if run not in by_run:
        runs = sorted(by_run)
        raise VideoInputError(
            f"--run {run}: {learner} has runs {runs[0]}-{runs[-1]} in {curves}"
            if len(runs) > 1
            else f"--run {run}: {learner} has only run {runs[0]} in {curves}"
        )
    rows = sorted(by_run[run], key=lambda r: int(r["iteration"]))
    try:
        thetas = np.array([[float(r[f"theta_{i}"]) for i in range(k)] for r in rows])
    except (KeyError, ValueError) as exc:
        raise VideoInputError(f"{curves}: malformed θ̂ columns ({exc})") from None
    if [int(r["iteration"]) for r in rows] != list(range(len(rows))):
        raise VideoInputError(f"{curves}: {learner} run {run} has gaps in its iterations")
    return RunRecord(
        figure=figure,
        learner=learner,
        run=run,
        settings=settings,
        thetas=thetas,
        environments=tuple(r["environment"] for r in rows[1:]),
    )


def check_iterations(record: RunRecord, iterations: Sequence[int]) -> tuple[int, ...]:
    """The chosen iterations, each in 1 … T.

    Raises:
        VideoInputError: an iteration outside the run.
    """
    for t in iterations:
        if not 1 <= t <= record.iterations:
            raise VideoInputError(
                f"--corrections {t}: {record.learner} run {record.run} has corrections "
                f"1-{record.iterations}"
            )
    return tuple(iterations)


def figure_settings(record: RunRecord):
    """The figure's settings as the run had them: its preset, overridden by ``summary.json``.

    Raises:
        VideoInputError: the recorded settings are not valid settings of the figure.
    """
    from corrections_sim.study import schema

    try:
        return schema.parse_study(record.settings, name=record.figure)
    except (ValueError, TypeError) as exc:
        raise VideoInputError(f"{record.figure}/summary.json: {exc}") from None


def planner_config(record: RunRecord) -> PlannerConfig:
    """The figure's planner as the run had it (features, multi-start count, solver)."""
    return figure_settings(record).planner_config()


def plan_episodes(record: RunRecord, iterations: Sequence[int], planner: Planner) -> list[Episode]:
    """Plan the three trajectories of each chosen iteration (3 solves each).

    Raises:
        VideoInputError: the run's user does not edit trajectories (the noisy user shows
            features), or the run names an environment that is not one of the 48.
    """
    figure = figure_settings(record)
    study = figure.study
    user = study.user
    if user.stochastic:
        raise VideoInputError(
            f"{record.figure}: the {study.user_name} user draws random numbers, so its "
            "corrections cannot be replayed; only runs of a deterministic user can be animated"
        )
    envs = {e.name: e for e in paper_environments()}
    study_features = planner.config.features
    episodes = []
    for t in iterations:
        name = record.environments[t - 1]
        if name not in envs:
            raise VideoInputError(f"{record.figure}: unknown environment {name!r} at t = {t}")
        env = envs[name]
        before, after = record.thetas[t - 1], record.thetas[t]
        robot = planner.solve(before, env).trajectory
        person = figure.person_target([env])
        intended = person.plans[0].trajectory
        episodes.append(
            Episode(
                iteration=t,
                env=env,
                theta_before=before,
                theta_after=after,
                robot=robot,
                intended=intended,
                correction=user.correct(
                    Situation(robot, intended, env, study_features, person.theta_star),
                    np.random.default_rng(0),
                ),
                learned=planner.solve(after, env).trajectory,
            )
        )
    return episodes


@dataclass(frozen=True)
class Timing:
    """How an episode is played: ``substeps`` frames per waypoint segment, then ``hold``
    frames at rest, for each of the three stages."""

    substeps: int = 3
    hold: int = 8
    fps: int = 20

    def frames_per_stage(self, n_waypoints: int) -> int:
        return (n_waypoints - 1) * self.substeps + 1 + self.hold

    def n_frames(self, episodes: Sequence[Episode]) -> int:
        return sum(len(STAGES) * self.frames_per_stage(len(e.robot)) for e in episodes)


def _fmt(theta: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:+.2f}" for v in theta) + ")"


def frames(
    record: RunRecord,
    episodes: Sequence[Episode],
    model,
    *,
    timing: Timing = Timing(),
    width: int = 640,
    height: int = 480,
) -> Iterator[np.ndarray]:
    """RGB frames (height, width, 3) uint8: each episode's three stages, captioned."""
    from corrections_sim.scene import render
    from corrections_sim.scene import world as scene

    caption = _Captions(width)
    for episode in episodes:
        paths = {s: render.cup_path(episode.trajectory(s), 4) for s in STAGES}
        intended = (render.cup_path(episode.intended, 4), COLORS["intended"], 0.006)
        header = (
            f"{record.figure}, {record.learner} run {record.run}: correction {episode.iteration}"
            f" of {record.iterations}, environment {episode.env.name}"
        )
        texts = {
            "robot": f"robot plans with θ = {_fmt(episode.theta_before)}",
            "correction": "the user corrects its worst waypoint",
            "learned": f"robot re-plans with the learned θ = {_fmt(episode.theta_after)}",
        }
        for k, stage in enumerate(STAGES):
            # Earlier stages thin, the playing one last and thick: it is never hidden.
            shown = [intended] + [(paths[s], COLORS[s], 0.006) for s in STAGES[:k]]
            shown.append((paths[stage], COLORS[stage], 0.011))
            samples = scene.interpolate(episode.trajectory(stage), timing.substeps)
            samples = np.vstack([samples, np.repeat(samples[-1:], timing.hold, axis=0)])
            for q in samples:
                image = render.render_scene(
                    episode.env,
                    shown,
                    q=q,
                    width=width,
                    height=height,
                    camera=render.VIDEO_CAMERA,
                    show_goal=True,
                    model=model,
                )
                yield caption(image, header, texts[stage], stage)


class _Captions:
    """Draws the header, the stage's sentence and a colour legend onto a frame (Pillow)."""

    def __init__(self, width: int) -> None:
        from matplotlib import font_manager
        from PIL import ImageFont

        path = font_manager.findfont(font_manager.FontProperties(family="DejaVu Sans"))
        self.font = ImageFont.truetype(path, max(12, width // 42))
        self.small = ImageFont.truetype(path, max(10, width // 52))

    def __call__(self, image: np.ndarray, header: str, text: str, stage: str) -> np.ndarray:
        from PIL import Image, ImageDraw

        canvas = Image.fromarray(image)
        draw = ImageDraw.Draw(canvas, "RGBA")
        w, h = canvas.size
        line = self.font.size + 6
        draw.rectangle([0, 0, w, 2 * line + 6], fill=(255, 255, 255, 200))
        draw.text((8, 4), header, fill=(20, 20, 20), font=self.font)
        color = tuple(int(255 * c) for c in COLORS[stage][:3])
        draw.text((8, 4 + line), text, fill=color, font=self.font)
        legend = [
            ("robot's plan", "robot"),
            ("user's correction", "correction"),
            ("learned plan", "learned"),
            ("user's own plan", "intended"),
        ]
        x, y = 8, h - self.small.size - 10
        draw.rectangle([0, y - 6, w, h], fill=(255, 255, 255, 200))
        for label, key in legend:
            rgb = tuple(int(255 * c) for c in COLORS[key][:3])
            draw.rectangle([x, y + 2, x + 14, y + self.small.size], fill=rgb)
            draw.text((x + 18, y), label, fill=(20, 20, 20), font=self.small)
            x += 26 + int(draw.textlength(label, font=self.small))
        return np.asarray(canvas)


def check_output(path: Path) -> Path:
    """Refuse an output the encoder cannot write, before anything is computed.

    Raises:
        VideoInputError: an unknown suffix, a folder, or a folder that cannot be written.
    """
    if path.suffix.lower() not in FORMATS:
        raise VideoInputError(f"--video-file {path}: the name must end in {' or '.join(FORMATS)}")
    if path.is_dir():
        raise VideoInputError(f"--video-file {path}: is a folder")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.name}-"):
            pass
    except OSError as exc:
        raise VideoInputError(
            f"--video-file {path}: cannot write in {path.parent} ({exc.strerror})"
        ) from None
    return path


def write_animation(path: Path, images: Iterator[np.ndarray], *, fps: int) -> int:
    """Encode ``images`` into ``path`` (.mp4 or .gif) via a temporary file in the same folder,
    renamed only when the encoder finished: an existing file is never left half-written.

    Returns:
        The number of frames written.
    """
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}-", suffix=path.suffix)
    os.close(fd)
    temporary = Path(name)
    try:
        count = (_write_mp4 if path.suffix.lower() == ".mp4" else _write_gif)(
            temporary, images, fps
        )
        umask = os.umask(0)
        os.umask(umask)
        temporary.chmod(0o666 & ~umask)  # mkstemp's 0600 is not what a user expects
        os.replace(temporary, path)
        return count
    finally:
        temporary.unlink(missing_ok=True)


def _write_mp4(path: Path, images: Iterator[np.ndarray], fps: int) -> int:
    import imageio_ffmpeg

    first = next(images)
    height, width = first.shape[:2]
    writer = imageio_ffmpeg.write_frames(
        str(path),
        (width, height),
        fps=fps,
        codec="libx264",
        pix_fmt_out="yuv420p",
        output_params=["-crf", "28", "-preset", "slow", "-movflags", "+faststart"],
        macro_block_size=2,  # yuv420p needs even sizes; 640 x 480 and the like pass as they are
    )
    writer.send(None)
    count = 0
    try:
        for image in _chain(first, images):
            writer.send(np.ascontiguousarray(image))
            count += 1
    finally:
        writer.close()
    return count


def _write_gif(path: Path, images: Iterator[np.ndarray], fps: int) -> int:
    from PIL import Image

    pictures = [Image.fromarray(image).quantize(colors=128) for image in images]
    pictures[0].save(
        path,
        save_all=True,
        append_images=pictures[1:],
        duration=round(1000 / fps),
        loop=0,
        optimize=True,
    )
    return len(pictures)


def _chain(first: np.ndarray, rest: Iterator[np.ndarray]) -> Iterator[np.ndarray]:
    yield first
    yield from rest


def parse_iterations(text: str | None, total: int) -> tuple[int, ...]:
    """'1,6,12' -> (1, 6, 12); None -> first, middle and last correction."""
    if text is None:
        return tuple(sorted({1, (total + 1) // 2, total}))
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise VideoInputError(
            f"--corrections {text!r}: expected comma-separated integers"
        ) from None
    return values


@dataclass(frozen=True)
class VideoResult:
    """What :func:`make_video` wrote: the file, its frames and its length in seconds."""

    path: Path
    frames: int
    seconds: float


def make_video(
    out: Path,
    figure: str,
    *,
    learner: str = DEFAULTS["video"][0],
    run: int = 0,
    corrections: str | None = None,
    model_path: Path | None = None,
    video_file: Path | None = None,
    timing: Timing = Timing(),
    width: int = 640,
    height: int = 480,
) -> VideoResult:
    """Animate corrections of one recorded run (see the module's docstring).

    Every input is checked before anything is planned or rendered.

    Args:
        out: the folder the figure was written to (``out/<figure>/curves.csv``).
        figure: "fig4" or "fig5".
        learner: whose run.
        run: the run's index.
        corrections: iterations to show, '1,6,12'; default first, middle and last.
        model_path: the MJCF to render; default ``models/scene.xml``.
        video_file: .mp4 or .gif; default ``out/video/<figure>-<learner>-run<run>.mp4``.

    Raises:
        VideoInputError: bad input (the message names the option).
        corrections_sim.scene.models.ModelFileError: a missing or malformed model file.
    """
    from corrections_sim.planning.planner import shared_planner
    from corrections_sim.scene import models

    if figure not in FIGURES:
        raise VideoInputError(f"--from {figure}: choose one of {', '.join(FIGURES)}")
    model = models.load_model(
        models.MODELS_DIR / models.SCENE_FILE if model_path is None else model_path
    )
    record = load_run(out, figure, learner, run)
    iterations = check_iterations(record, parse_iterations(corrections, record.iterations))
    default_file = out / "video" / f"{figure}-{learner}-run{run}.mp4"
    path = check_output(default_file if video_file is None else video_file)
    episodes = plan_episodes(record, iterations, shared_planner(planner_config(record)))
    images = frames(record, episodes, model, timing=timing, width=width, height=height)
    count = write_animation(path, images, fps=timing.fps)
    return VideoResult(path=path, frames=count, seconds=count / timing.fps)
