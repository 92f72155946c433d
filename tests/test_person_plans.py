"""The person's plans kept on disk (:mod:`corrections_sim.plans.targets`): read back to the
bit, solved again where the file cannot be trusted, and keyed by all an answer depends on."""

from __future__ import annotations

import numpy as np
import pytest

from corrections_sim.planning.planner import shared_planner
from corrections_sim.plans import book, targets
from corrections_sim.study import schema as study_file
from corrections_sim.study.settings import _TARGETS

BASE = {"theta_star": [1.0, -1.0], "runs": 1, "iterations": 1, "person_restarts": 2}


@pytest.fixture
def counted(monkeypatch, tmp_path):
    """The store in ``tmp_path``; the list of environments whose restarts were drawn (solved)."""
    monkeypatch.setattr(targets, "store_root", lambda: tmp_path)
    drawn = []
    own = book.own_starts
    monkeypatch.setattr(book, "own_starts", lambda env, *a: drawn.append(env.name) or own(env, *a))
    return tmp_path, drawn


def _same(a: book.Target, b: book.Target) -> None:
    for x, y in zip(a.plans, b.plans, strict=True):
        assert np.array_equal(x.trajectory, y.trajectory)
        assert np.array_equal(x.features, y.features)
        assert x.reward == y.reward and (x.status, x.iterations, x.starts) == (
            y.status,
            y.iterations,
            y.starts,
        )


def test_a_searched_persons_plans_are_kept_and_read_back_to_the_bit(counted):
    root, drawn = counted
    settings = study_file.parse_study(dict(BASE))
    envs = settings.envs()[:2]
    first = settings.person_target(envs)
    assert len(drawn) == 2 and len(list(root.glob("*.npz"))) == 2
    _TARGETS.clear()  # another process: the store only
    again = settings.person_target(envs)
    assert len(drawn) == 2  # nothing solved
    _same(first, again)
    planner = shared_planner(settings.user_planner_config())  # with the study's atlas
    alone = book.Target.solve(planner, [1.0, -1.0], envs, atlas=settings.atlas(), restarts=2)
    _same(first, alone)


def test_a_file_that_cannot_be_trusted_is_said_and_solved_again(counted):
    root, drawn = counted
    settings = study_file.parse_study(dict(BASE))
    envs = settings.envs()[:1]
    first = settings.person_target(envs)
    (path,) = root.glob("*.npz")
    path.write_bytes(path.read_bytes()[:100])  # truncated
    store = targets.TargetStore()
    key = path.stem
    assert store.load(key, 10, 2) is None and store.rejected[0][0] == key
    _TARGETS.clear()
    again = settings.person_target(envs)
    assert len(drawn) == 2
    _same(first, again)


def test_without_restarts_nothing_is_kept(counted):
    root, _ = counted
    settings = study_file.parse_study({**BASE, "person_restarts": 0})
    settings.person_target(settings.envs()[:1])
    assert not list(root.glob("*"))


def test_the_key_moves_with_the_person_the_search_the_environment_and_the_planner():
    settings = study_file.parse_study(dict(BASE))
    config = settings.user_planner_config()
    envs = settings.envs()[:2]

    def key(config=config, theta=(1.0, -1.0), restarts=2, atlas=None, env=0) -> str:
        return targets.answer_keys(config, envs, theta, restarts, atlas)[env]

    assert key() == key(theta=np.array([1.0, -1.0]))
    assert key() == targets.answer_keys(config, envs[:1], [1.0, -1.0], 2, None)[0]
    planner = study_file.parse_study({**BASE, "planner": {"n_starts": 2}}).user_planner_config()
    others = {
        key(theta=(1.0, -0.5)),
        key(restarts=3),
        key(env=1),
        key(atlas=settings.atlas()),
        key(config=planner),
    }
    assert key() not in others and len(others) == 5
