"""The clearance certificate against MuJoCo: its kinematics, every pair's bound against
``mj_geomDistance``, its pairs against the contacts MuJoCo finds, and never a certified
collision (random configurations, and trajectories made to collide between waypoints)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from corrections_sim.planning import clearance
from corrections_sim.planning.clearance import (
    MARGIN,
    CertificateError,
    CertifiedChecker,
    ClearanceCertificate,
)
from corrections_sim.planning.planner import Planner, PlannerConfig, cache_dir
from corrections_sim.scene.environments import paper_environments
from corrections_sim.scene.robot import joint_limits
from corrections_sim.scene.world import CollisionChecker


@pytest.fixture(scope="module")
def library():
    return cache_dir() / f"clearance-{clearance.library_key()}.so"


@pytest.fixture(scope="module")
def cert(library):
    return ClearanceCertificate(CollisionChecker(), library)


def _configurations(n, seed):
    lo, hi = joint_limits()
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, len(lo)))


def _mujoco(cert, q, env):
    """A MjData of the certificate's model at q in env, kinematics done."""
    cert.checker.set_environment(env)
    data = mujoco.MjData(cert.checker.model)
    data.qpos[:] = q
    mujoco.mj_kinematics(cert.checker.model, data)
    return data


def test_frames_match_mujoco(cert):
    model = cert.checker.model
    chain = sorted({int(w) for w in model.body_weldid if w})
    env = paper_environments()[0]
    for q in _configurations(20, 1):
        poses, _, _ = cert.details(q, env)
        data = _mujoco(cert, q, env)
        for frame, body in enumerate(chain):
            assert np.abs(poses[frame][:, :3] - data.xmat[body].reshape(3, 3)).max() < 1e-12
            assert np.abs(poses[frame][:, 3] - data.xpos[body]).max() < 1e-12


def test_every_bound_is_below_mujocos_distance(cert):
    """Each capsule bound and each frames' sphere bound is <= the distance of every geom
    pair it stands for; where MuJoCo finds penetration, the bound is <= 0 (never certifies)."""
    model = cert.checker.model
    pairs = set(cert.pairs)
    envs = paper_environments()
    checked = penetrating = 0
    for i, q in enumerate(_configurations(40, 2)):
        env = envs[(7 * i) % len(envs)]
        _, fine, coarse = cert.details(q, env)
        data = _mujoco(cert, q, env)
        for (kind, a, b), lower_fine, lower_coarse in zip(cert.entries, fine, coarse, strict=True):
            geoms_b = (b,) if kind == "static" else cert.capsules[b].geoms
            for g1 in cert.capsules[a].geoms:
                for g2 in geoms_b:
                    if (min(g1, g2), max(g1, g2)) not in pairs:
                        continue
                    true = mujoco.mj_geomDistance(model, data, g1, g2, 10.0, None)
                    checked += 1
                    if true >= 0:
                        assert lower_fine <= true + 1e-12 and lower_coarse <= true + 1e-12
                    else:
                        penetrating += 1
                        assert lower_fine <= 0 and lower_coarse <= 0
    # every pair MuJoCo tests stands for an entry (each checked 40 times)
    assert checked == 40 * len(pairs)
    assert penetrating > 0  # random configurations do collide, so both branches ran


def test_pairs_cover_every_contact_mujoco_finds(cert):
    model = cert.checker.model
    pairs = set(cert.pairs)
    seen = 0
    envs = paper_environments()
    for i, q in enumerate(_configurations(300, 3)):
        data = _mujoco(cert, q, envs[i % len(envs)])
        mujoco.mj_collision(model, data)
        for c in range(data.ncon):
            g1, g2 = (int(g) for g in data.contact.geom[c])
            assert (min(g1, g2), max(g1, g2)) in pairs
            seen += 1
    assert seen > 50


def test_never_certifies_a_collision(cert):
    """Colliding configurations alone, as a waypoint between free ones, and as the middle
    sample of a segment whose two waypoints are elsewhere: never certified."""
    checker = cert.checker
    envs = paper_environments()
    colliding = free = 0
    qs = _configurations(400, 4)
    for i, q in enumerate(qs):
        env = envs[i % len(envs)]
        hit = not checker.check_configuration(q, env).collision_free
        certified = cert.certifies(q[None], env)
        assert not (hit and certified)
        if not hit:
            free += 1
            continue
        colliding += 1
        other = qs[i - 1]
        traj = np.array([other, q, other])
        assert not checker.check_trajectory(traj, env).collision_free
        assert not cert.certifies(traj, env)
        step = 0.05 * (qs[i - 2] - q)
        made = np.array([q - step, q + step])  # the sample between them is q
        if not checker.check_trajectory(made, env, substeps=2).collision_free:
            assert not cert.certifies(made, env, substeps=2)
    assert colliding > 30 and free > 30


def test_certified_trajectories_are_collision_free(cert):
    """Random short trajectories: a certified one has no contact in MuJoCo's check, and the
    full bound above MARGIN always certifies (the pruning only skips what it has proved)."""
    envs = paper_environments()
    rng = np.random.default_rng(5)
    lo, hi = joint_limits()
    certified = 0
    for i in range(150):
        centre = rng.uniform(lo, hi)
        traj = np.clip(centre + rng.normal(0, 0.15, size=(4, 7)), lo, hi)
        env = envs[i % len(envs)]
        full = cert.bound(traj, env)
        ok = cert.certifies(traj, env)
        if full > MARGIN:
            assert ok
        if ok:
            certified += 1
            assert cert.checker.check_trajectory(traj, env).collision_free
    assert certified > 20


def test_planner_plans_are_certified_and_unchanged(library):
    """The planner with and without the certificate gives the same plans, and certifies
    them (the checks it skipped would have found nothing)."""
    envs = paper_environments()
    on = Planner(PlannerConfig(n_starts=1))
    off = Planner(PlannerConfig(n_starts=1, certificate=False))
    assert isinstance(on._checker, CertifiedChecker) and isinstance(off._checker, CollisionChecker)
    for env, theta in ((envs[0], [1.0, 0.5]), (envs[17], [-0.5, 1.0]), (envs[40], [0.3, -0.8])):
        a, b = on.solve(theta, env), off.solve(theta, env)
        assert np.array_equal(a.trajectory, b.trajectory) and a.reward == b.reward
    assert on._checker.certified > 0


def test_bad_input_and_unsupported_models(cert):
    env = paper_environments()[0]
    with pytest.raises(ValueError, match="waypoints: expected shape"):
        cert.bound(np.zeros((3, 6)), env)
    with pytest.raises(ValueError, match="finite"):
        cert.bound(np.full((2, 7), np.nan), env)
    with pytest.raises(ValueError, match="substeps"):
        cert.bound(np.zeros((2, 7)), env, substeps=0)
    with pytest.raises(ValueError, match="certificate"):
        PlannerConfig(certificate="yes")
    free = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><geom type='plane' size='1 1 1'/>"
        "<body><freejoint/><geom type='box' size='.1 .1 .1'/></body></worldbody></mujoco>"
    )
    with pytest.raises(CertificateError, match="joint"):
        ClearanceCertificate(CollisionChecker(model=free), cache_dir() / "unused.so")


def test_a_study_can_turn_it_off_and_the_run_key_ignores_it():
    from corrections_sim.figures import learning_study
    from corrections_sim.study.runner import run_key

    on = learning_study.load_settings("fig4", quick=True)
    off = learning_study.load_settings(
        "fig4", quick=True, overrides={"set": ["planner.certificate=false"]}
    )
    assert on.planner_config().certificate and not off.planner_config().certificate
    assert run_key(on) == run_key(off)  # it changes no number, so cached runs are reused
    with pytest.raises(ValueError, match="planner.certificate"):
        learning_study.load_settings(
            "fig4", quick=True, overrides={"set": ["planner.certificate=2"]}
        )
