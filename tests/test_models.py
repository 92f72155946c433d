"""models/: the committed MJCF is what the code writes, and it is the planner's scene."""

from __future__ import annotations

import shutil

import mujoco
import numpy as np
import pytest

from corrections_sim.scene import models, render, robot
from corrections_sim.scene import world as scene
from corrections_sim.scene.environments import paper_environments

SCENE_XML = models.MODELS_DIR / models.SCENE_FILE


@pytest.fixture(scope="module")
def from_file() -> mujoco.MjModel:
    return models.load_model(SCENE_XML)


def test_committed_models_match_the_code():
    stale = models.drift()
    assert not stale, f"models/ drifted: {stale}; run `python -m corrections_sim.run models`"


def test_opens_anywhere_as_the_viewer_loads_it(tmp_path):
    # A copy elsewhere proves the mesh paths are relative to the file, not to this checkout.
    shutil.copytree(models.MODELS_DIR, tmp_path / "models")
    model = mujoco.MjModel.from_xml_path(str(tmp_path / "models" / models.SCENE_FILE))
    assert model.nq == robot.N_ARM_JOINTS
    assert model.nmesh == 10 and model.ncam == len(render.CAMERAS)
    assert {model.camera(i).name for i in range(model.ncam)} == set(render.CAMERAS)


def test_fk_and_collision_verdicts_equal_the_planners_checker(from_file, rng):
    """The same colliding body pairs at the same samples, and every body's world pose, in the
    model loaded from models/scene.xml and in the one the planner verifies against.

    MJCF stores 6 significant digits (the hand's quaternion, the laptop screen's tilt), so
    poses and depths agree to ~1e-6, not bitwise (measured over 4,800 configurations in the
    48 environments: 849 colliding, the same pairs everywhere; positions 5e-8 m, rotations
    1.2e-6, depths 6e-7 m)."""
    ours, theirs = scene.CollisionChecker(), scene.CollisionChecker(model=from_file)
    names = [ours.model.body(i).name for i in range(ours.model.nbody)]
    assert names == [theirs.model.body(i).name for i in range(theirs.model.nbody)]
    lo, hi = robot.joint_limits()
    envs = paper_environments()
    n_colliding = 0
    for env in (envs[0], envs[17], envs[46]):
        qs = np.vstack([rng.uniform(lo, hi, size=(150, 7)), env.q_start, env.q_goal])
        a, b = ours.check_configurations(qs, env), theirs.check_configurations(qs, env)
        assert [(c.sample, c.body_a, c.body_b) for c in a.contacts] == [
            (c.sample, c.body_a, c.body_b) for c in b.contacts
        ]
        np.testing.assert_allclose(
            [c.depth for c in a.contacts], [c.depth for c in b.contacts], atol=1e-5
        )
        n_colliding += len(a.colliding_samples())
        for q in qs[:20]:
            for body in names[1:]:
                rot_a, pos_a = ours.body_pose(q, body)
                rot_b, pos_b = theirs.body_pose(q, body)
                np.testing.assert_allclose(pos_a, pos_b, rtol=0, atol=1e-5)
                np.testing.assert_allclose(rot_a, rot_b, rtol=0, atol=1e-5)
    assert n_colliding > 50  # the comparison saw many contacts, not only free space


def test_is_well_formed_xml():
    """Strict XML (MuJoCo's own parser is lenient, lxml and dm_control.mjcf are not)."""
    import xml.etree.ElementTree as ET

    root = ET.parse(SCENE_XML).getroot()
    assert root.tag == "mujoco" and root.find("worldbody") is not None


def test_keyframes_and_props_are_the_named_environment(from_file):
    env = {e.name: e for e in paper_environments()}[models.SCENE_ENV]
    np.testing.assert_allclose(from_file.key("start").qpos, env.q_start, atol=1e-5)
    np.testing.assert_allclose(from_file.key("goal").qpos, env.q_goal, atol=1e-5)
    np.testing.assert_allclose(from_file.body(scene.TABLE_BODY).pos[:2], env.table, atol=1e-9)
    np.testing.assert_allclose(from_file.body(scene.LAPTOP_BODY).pos[:2], env.laptop[:2])


@pytest.mark.parametrize("name", sorted(render.CAMERAS))
def test_fixed_cameras_show_the_figures_views(from_file, name):
    """The file's fixed camera sits where the renders' free camera does and looks the same way."""
    data = mujoco.MjData(from_file)
    mujoco.mj_forward(from_file, data)
    option = mujoco.MjvOption()
    views = []
    for fixed in (True, False):
        cam = mujoco.MjvCamera()
        if fixed:
            cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
            cam.fixedcamid = from_file.camera(name).id
        else:
            free = render.CAMERAS[name]
            cam.type = mujoco.mjtCamera.mjCAMERA_FREE
            cam.lookat[:] = free.lookat
            cam.distance, cam.azimuth, cam.elevation = free.distance, free.azimuth, free.elevation
        scn = mujoco.MjvScene(from_file, maxgeom=1000)
        mujoco.mjv_updateScene(from_file, data, option, None, cam, mujoco.mjtCatBit.mjCAT_ALL, scn)
        views.append(np.concatenate([scn.camera[0].pos, scn.camera[0].forward, scn.camera[0].up]))
    np.testing.assert_allclose(views[0], views[1], atol=1e-5)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "no such file"),
        ("<mujoco><worldbody><body", "not a loadable MJCF"),
        ('<mujoco><asset><mesh file="nowhere.stl"/></asset></mujoco>', "not a loadable MJCF"),
        ("<mujoco/>", "no body 'cup'"),
    ],
)
def test_bad_model_file_is_one_line_naming_it(tmp_path, content, message):
    path = tmp_path / "scene.xml"
    if content is not None:
        path.write_text(content)
    with pytest.raises(models.ModelFileError, match=message) as info:
        models.load_model(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
