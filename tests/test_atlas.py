"""The plan atlas (``planning/atlas.py``): its grid, its build on a small grid in one paper
environment, warm starts from a cell, and the cache that never trusts a bad file."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from corrections_sim.plans import atlas as A
from corrections_sim.scene.environments import paper_environments


def test_a_grid_knows_its_nodes_and_their_neighbours():
    grid = A.AtlasGrid((-1.0, -2.0, 0.0), (1.0, 2.0, 1.0), (3, 4, 5))
    assert grid.size == 60 and grid.thetas().shape == (60, 3)
    thetas, neighbours = grid.thetas(), grid.neighbours()
    steps = np.array([1.0, 4.0 / 3.0, 0.25])
    for node, mine in enumerate(neighbours):
        assert 3 <= len(mine) <= 6  # a corner has 3, an inner node 6
        for other in mine:
            d = np.abs(thetas[other] - thetas[node])
            assert np.count_nonzero(d > 1e-12) == 1 and np.isclose(d[d > 1e-12], steps).any()
            assert node in neighbours[other]


def test_a_cell_is_its_corners_and_its_theta_is_inside_them():
    grid = A.AtlasGrid((-3.0, -3.0), (3.0, 3.0), (31, 31))
    thetas = grid.thetas()
    for theta in ([0.05, -1.93], [3.0, 3.0], [-3.0, 0.2]):
        corners = grid.cell(theta)
        assert len(corners) == 4
        box = thetas[corners]
        assert np.all(box.min(axis=0) <= np.add(theta, 1e-12))
        assert np.all(np.subtract(theta, 1e-12) <= box.max(axis=0))
        assert np.all(box.max(axis=0) - box.min(axis=0) == pytest.approx(0.2))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"lows": (0.0,), "highs": (1.0,), "counts": (2,)}, "integer >= 3"),
        ({"lows": (0.0,), "highs": (0.0,), "counts": (5,)}, "low < high"),
        ({"lows": (0.0, 1.0), "highs": (1.0,), "counts": (5,)}, "one entry per weight"),
        ({"lows": (float("nan"),), "highs": (1.0,), "counts": (5,)}, "finite"),
    ],
)
def test_a_bad_grid_is_one_line(kwargs, message):
    with pytest.raises(ValueError, match=message):
        A.AtlasGrid(**kwargs)


def test_a_box_that_misses_the_prior_mean_is_refused():
    grid = A.AtlasGrid.around([0.0, 0.0], [0.1, 1.0])
    grid.require([0.4, -4.9])
    with pytest.raises(ValueError, match=r"does not contain the prior mean \[0.6, 0.0\]"):
        grid.require([0.6, 0.0])


@pytest.fixture(scope="module")
def small(planner):
    """A 5 × 5 atlas over [−2, 2]² in one paper environment."""
    env = paper_environments()[7]
    grid = A.AtlasGrid((-2.0, -2.0), (2.0, 2.0), (5, 5))
    return env, grid, A.build(planner, env, grid, cold_stride=2)


def test_every_node_is_at_least_as_good_as_the_planners_own_answer(planner, small):
    """Global at its nodes as far as the planner can tell: no node is worse than the planner's
    cold starts there, and each node's reward is its plan's reward at its θ."""
    env, grid, atlas = small
    assert atlas.found.all() and atlas.solves >= grid.size
    for node, theta in enumerate(grid.thetas()):
        own = planner.solve(theta, env)
        assert atlas.rewards[node] >= own.reward - 1e-6 * abs(own.reward)
        again = planner.reward(theta, atlas.trajectories[node], env)
        assert again == pytest.approx(atlas.rewards[node], rel=1e-9, abs=1e-9)


def test_cell_starts_rank_the_corners_by_their_reward_at_theta(planner, small):
    env, _, atlas = small
    theta = np.array([0.3, -1.1])
    starts = A.cell_starts(atlas, theta, planner.config.smoothness)
    assert 1 <= len(starts) <= 4
    values = [planner.reward(theta, s, env) for s in starts]
    assert values == sorted(values, reverse=True)
    assert A.cell_starts(atlas, [2.5, 0.0], planner.config.smoothness) == []  # outside


def test_the_store_reads_back_what_it_wrote_and_rebuilds_a_bad_file(planner, small, tmp_path):
    env, grid, atlas = small
    store = A.AtlasStore(tmp_path)
    key = A.atlas_key(planner.config, env, grid, cold_stride=2)
    assert store.load(key, grid, 12) is None  # nothing yet
    store.save(key, atlas)
    back = store.load(key, grid, 12)
    assert np.array_equal(back.trajectories, atlas.trajectories)
    assert np.array_equal(back.rewards, atlas.rewards) and back.solves == atlas.solves
    assert not store.rejected
    # Truncated data: refused by its checksum, said, and not trusted.
    data = tmp_path / f"{key}.npy"
    data.write_bytes(data.read_bytes()[:-100])
    assert store.load(key, grid, 12) is None
    assert "checksum" in store.rejected[-1][1]
    # Another atlas's file under this key (a foreign grid): refused.
    store.save(key, atlas)
    meta = json.loads((tmp_path / f"{key}.json").read_text())
    meta["grid"]["counts"] = [7, 7]
    (tmp_path / f"{key}.json").write_text(json.dumps(meta))
    assert store.load(key, grid, 12) is None and "another atlas" in store.rejected[-1][1]
    # Another planner, environment, grid or build option: another key.
    other = A.AtlasGrid((-2.0, -2.0), (2.0, 2.0), (7, 7))
    assert len({
        key,
        A.atlas_key(planner.config, env, other, cold_stride=2),
        A.atlas_key(planner.config, paper_environments()[8], grid, cold_stride=2),
        A.atlas_key(planner.config, env, grid, cold_stride=3),
    }) == 4  # fmt: skip


def test_changed_newton_code_gives_another_atlas_key(planner, small, monkeypatch):
    """The build's warm solves take Newton's steps, so its code is part of an atlas's key (a
    changed newton.c must not read an atlas built before); with the solver's warm starts, not."""
    env, grid, _ = small
    solver_warm = replace(planner.config, warm="solver")
    before = A.atlas_key(planner.config, env, grid), A.atlas_key(solver_warm, env, grid)
    monkeypatch.setattr(A.newton, "library_key", lambda build: "changed newton.c")
    after = A.atlas_key(planner.config, env, grid), A.atlas_key(solver_warm, env, grid)
    assert after[0] != before[0]
    assert after[1] == before[1]


def test_plans_between_nodes_are_kept_for_the_next_process_and_a_bad_shard_is_skipped(
    planner, small, tmp_path, monkeypatch
):
    """Off-node plans an atlas solved, saved, are what a fresh atlas on the same store answers
    without solving (bit-identical); kept by code that answers differently (another
    :func:`answer_version`), they are not read; a shard whose bytes changed is refused by its
    checksum, said, and its plans solved again."""
    env, grid, built = small
    thetas = np.array([[0.3, -0.7], [1.1, 0.4], [-1.7, 1.9]])
    first = A.Atlas(planner, grid, store=A.AtlasStore(tmp_path), cold_stride=2)
    first.hold(env, built)
    solved = first.plans(thetas, env)
    assert first.save() == 3 and first.save() == 0  # nothing new the second time
    (shard,) = tmp_path.glob("*.extra-*.npz")
    second = A.Atlas(planner, grid, store=A.AtlasStore(tmp_path), cold_stride=2)
    second.hold(env, built)
    second.solve = lambda *args, **kwargs: pytest.fail("solved again")
    assert second.read(env) == 3  # read before any ask, as a page server does
    (shard,) = tmp_path.glob("*.extra-*.npz")  # and read once: the ask below reads no file
    shard.rename(shard.with_suffix(".moved"))
    assert np.array_equal(second.plans(thetas, env), solved, equal_nan=True)
    shard.with_suffix(".moved").rename(shard)
    with monkeypatch.context() as patch:
        patch.setattr(A, "answer_version", lambda: "another")
        stale = A.Atlas(planner, grid, store=A.AtlasStore(tmp_path), cold_stride=2)
        stale.hold(env, built)
        calls = []
        stale.solve = lambda theta, e: calls.append(theta) or first.solve(theta, e)
        stale.plans(thetas, env)
        assert len(calls) == 3  # every plan solved again, none read
    shard.write_bytes(shard.read_bytes()[:-10])
    third = A.Atlas(planner, grid, store=A.AtlasStore(tmp_path), cold_stride=2)
    third.hold(env, built)
    assert np.array_equal(third.plans(thetas, env), solved, equal_nan=True)
    assert "checksum" in third.store.rejected[-1][1]
