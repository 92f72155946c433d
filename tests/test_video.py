"""The video of a run: the frames it promises, none blank, and bad input refused up front."""

from __future__ import annotations

import json

import numpy as np
import pytest

from corrections_sim.cli import main as run
from corrections_sim.defaults import RECOMMENDED
from corrections_sim.figures import video
from corrections_sim.scene.environments import paper_environments

TIMING = video.Timing(substeps=1, hold=1, fps=10)
SIZE = {"width": 160, "height": 120}


@pytest.fixture()
def recorded(tmp_path):
    """A finished fig4 folder with one run of the recommended robot (the video's default) of
    two corrections (as the figure writes it)."""
    folder = tmp_path / "fig4"
    folder.mkdir()
    envs = paper_environments()
    settings = {"theta_star": [1.0, -1.0], "user": "biased", "user_step": 1.0, "n_starts": 1}
    (folder / "summary.json").write_text(json.dumps({"settings": settings}))
    rows = [
        "learner,run,iteration,environment,theta_0,theta_1",
        f"{RECOMMENDED},0,0,,0.0,0.0",
        f"{RECOMMENDED},0,1,{envs[1].name},0.4,-0.3",
        f"{RECOMMENDED},0,2,{envs[21].name},0.8,-0.6",
    ]
    (folder / "curves.csv").write_text("\n".join(rows) + "\n")
    return tmp_path


def _read_mp4(path) -> list[np.ndarray]:
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    width, height = meta["size"]
    return [np.frombuffer(f, np.uint8).reshape(height, width, 3) for f in reader]


def _read_gif(path) -> list[np.ndarray]:
    """The GIF's frames, each repeated for its duration: Pillow stores a held (identical)
    frame once with the summed duration."""
    from PIL import Image, ImageSequence

    frames = []
    with Image.open(path) as gif:
        for frame in ImageSequence.Iterator(gif):
            repeats = round(frame.info["duration"] / (1000 / TIMING.fps))
            frames += [np.asarray(frame.convert("RGB"))] * repeats
    return frames


@pytest.mark.parametrize(
    ("suffix", "corrections"), [(".mp4", "1,2"), (".gif", "2")]
)  # the GIF one correction: the frames are drawn in software, 0.25 s each
def test_video_has_every_frame_and_none_is_blank(recorded, suffix, corrections):
    target = recorded / f"clip{suffix}"
    result = video.make_video(
        recorded, "fig4", corrections=corrections, video_file=target, timing=TIMING, **SIZE
    )
    # corrections x 3 stages x (11 segments x 1 substep + 1 + 1 held) frames.
    count = len(corrections.split(","))
    expected = count * 3 * (11 * TIMING.substeps + 1 + TIMING.hold)
    assert result.frames == expected and result.seconds == pytest.approx(expected / TIMING.fps)
    frames = (_read_mp4 if suffix == ".mp4" else _read_gif)(target)
    assert len(frames) == expected
    assert frames[0].shape == (SIZE["height"], SIZE["width"], 3)
    for frame in frames:
        assert frame.std() > 20  # not one flat colour
        assert len(np.unique(frame.reshape(-1, 3) // 32, axis=0)) > 8
    # The arm moves: the first and last frames of a stage differ.
    stage = 11 * TIMING.substeps + 1 + TIMING.hold
    assert np.abs(frames[0].astype(int) - frames[stage - 1].astype(int)).mean() > 1.0


def test_episode_is_the_robot_plan_corrected_at_its_worst_waypoint(recorded):
    from corrections_sim.planning.planner import shared_planner

    record = video.load_run(recorded, "fig4", RECOMMENDED, 0)
    (episode,) = video.plan_episodes(record, (2,), shared_planner(video.planner_config(record)))
    assert episode.env.name == paper_environments()[21].name
    np.testing.assert_array_equal(episode.theta_before, [0.4, -0.3])
    moved = np.flatnonzero(np.any(episode.correction != episode.robot, axis=1))
    assert len(moved) == 1
    # robot + 1.0 (intended - robot): equal up to rounding
    np.testing.assert_allclose(
        episode.correction[moved[0]], episode.intended[moved[0]], rtol=0, atol=1e-12
    )


def _cli(capsys, *argv) -> tuple[int, str]:
    code = run.main(["video", *argv])
    return code, capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--run", "3"], f"--run 3: {RECOMMENDED} has only run 0"),
        (["--corrections", "0,2"], f"--corrections 0: {RECOMMENDED} run 0 has corrections 1-2"),
        (["--corrections", "13"], "--corrections 13"),
        (["--corrections", "a"], "--corrections 'a': expected comma-separated integers"),
        (["--learner", "AL"], "--learner AL: not in"),
        (["--from", "fig5"], "no fig5/curves.csv"),
        (["--video-file", "clip.avi"], "must end in .mp4 or .gif"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_keeps_earlier_output(recorded, capsys, argv, message):
    earlier = recorded / "video" / f"fig4-{RECOMMENDED}-run0.mp4"
    earlier.parent.mkdir()
    earlier.write_bytes(b"an earlier video")
    code, err = _cli(capsys, "--out", str(recorded), *argv)
    assert code == 2 and message in err and err.count("\n") == 1, err
    assert earlier.read_bytes() == b"an earlier video"


@pytest.mark.parametrize(
    ("content", "message"),
    [(None, "no such file"), ("<mujoco><worldbody>", "not a loadable MJCF")],
)
def test_missing_or_malformed_model_file(recorded, capsys, content, message):
    model = recorded / "scene.xml"
    if content is not None:
        model.write_text(content)
    code, err = _cli(capsys, "--out", str(recorded), "--model", str(model))
    assert code == 2 and err.startswith(f"error: --model {model}") and message in err
    assert err.count("\n") == 1


def test_unwritable_output_is_refused_before_planning(recorded, capsys):
    blocker = recorded / "a-file"
    blocker.write_text("")
    code, err = _cli(capsys, "--out", str(recorded), "--video-file", str(blocker / "v.mp4"))
    assert code == 2 and "--video-file" in err and "cannot write" in err
    code, err = _cli(capsys, "--out", str(recorded), "--video-file", str(recorded))
    assert code == 2 and "must end in" in err
