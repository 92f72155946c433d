"""Plans read off a plan atlas between its nodes (``planning/interpolation.py``) and the
particle learner's likelihood through them (issue 53): within its tolerance of the solved
plans' features, the same at a θ whatever was asked before, the atlas's own answer outside
its box, and a bad bound refused in one line."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from corrections_sim.cli import main as cli
from corrections_sim.learning.base import make_learner
from corrections_sim.learning.observation import CorrectedPlanFeatures, PlanFeatures
from corrections_sim.learning.particles.cloud import smoothed_kl
from corrections_sim.learning.particles.state import Particles
from corrections_sim.people.corrections import (
    OptimalCorrection,
    WaypointCorrection,
    worst_waypoints,
)
from corrections_sim.plans import atlas as A
from corrections_sim.plans import interpolation
from corrections_sim.plans.interpolation import (
    CellInterpolant,
    CellStore,
    check_tolerance,
    waypoint_table,
)
from corrections_sim.scene.environments import paper_environments

NAMES = ("laptop", "table")
SD = np.array([0.5, 0.5])  # fig. 4's noise sd
T = 12


@pytest.fixture(scope="module")
def small(planner):
    """A 9 × 9 atlas over [−2, 2]² in one paper environment, in memory."""
    env = paper_environments()[7]
    grid = A.AtlasGrid((-2.0, -2.0), (2.0, 2.0), (9, 9))
    atlas = A.Atlas(planner, grid, cold_stride=4)
    atlas.environment(env)
    return atlas, env


def _split(values: np.ndarray):
    return values[:, : T * 7].reshape(-1, T, 7), values[:, T * 7 :].reshape(-1, T, len(NAMES))


@pytest.mark.parametrize(
    "observation",
    [PlanFeatures(), CorrectedPlanFeatures(WaypointCorrection())],
    ids=["own optimum", "worst waypoint"],
)
def test_what_the_particles_read_is_within_the_bound_of_solved_plans(small, observation):
    """h at 120 random θ from the interpolated waypoints against h from the atlas's solved
    plans there: within the tolerance (0.02 noise sd) on all but the rare θ where the
    interpolated plan changes which waypoint is the worst (a tie of two; measured on fig. 4's
    environments: 0.4% of θ), and the cells' own probes within it by construction."""
    atlas, env = small
    tolerance = 0.02
    table = waypoint_table(atlas, env, NAMES, SD, tolerance, 3)
    rng = np.random.default_rng(5)
    thetas = rng.uniform(-1.9, 1.9, (120, 2))
    robot = atlas.solve(np.array([0.3, -0.4]), env).trajectory
    plans, features = _split(table(thetas))
    got = observation.at_waypoints(plans, features, robot, env, NAMES)
    exact = observation.at_plans(atlas.plans(thetas, env), robot, env, NAMES)
    error = np.max(np.abs(got - exact) / SD, axis=1)
    assert np.mean(error <= tolerance) >= 0.97, np.sort(error)[-5:]
    assert np.median(error) < tolerance / 4
    assert table.checked > 0


def test_a_value_does_not_depend_on_what_was_asked_before(small):
    """Two interpolants asked the same θ in different orders, one of them after other θ
    first: bit-identical answers (which cells are trusted depends on the cells alone)."""
    atlas, env = small
    rng = np.random.default_rng(6)
    thetas = rng.uniform(-1.9, 1.9, (40, 2))

    def values(plans):
        return PlanFeatures().at_plans(plans, None, env, NAMES)

    def measure(d):
        return np.max(np.abs(d) / SD, axis=-1)

    first = CellInterpolant(atlas, env, values, measure, tolerance=0.02, max_level=2)
    second = CellInterpolant(atlas, env, values, measure, tolerance=0.02, max_level=2)
    second(rng.uniform(-1.9, 1.9, (30, 2)))
    a = first(thetas)
    b = second(thetas[::-1])[::-1]
    assert np.array_equal(a, b, equal_nan=True)


def _feature_values(env):
    def values(plans):
        return PlanFeatures().at_plans(plans, None, env, NAMES)

    def measure(d):
        return np.max(np.abs(d) / SD, axis=-1)

    return values, measure


def test_checked_cells_are_kept_for_the_next_process_and_a_bad_shard_is_checked_again(
    small, tmp_path
):
    """The cells one interpolant checked, saved, are what a fresh one on the same store reads:
    the same bits at every θ with no cell checked again and no plan asked but those of the θ
    solved one by one; a shard whose bytes changed is said, skipped and its cells checked
    again, to the same bits."""
    atlas, env = small
    values, measure = _feature_values(env)
    thetas = np.random.default_rng(8).uniform(-1.9, 1.9, (60, 2))
    first = CellInterpolant(
        atlas, env, values, measure, max_level=2, store=CellStore(tmp_path, "test")
    )
    a = first(thetas)
    assert first.checked > 0 and first.save() == first.checked
    assert first.save() == 0  # nothing new since

    asked = []

    def counted(plans):
        asked.append(len(plans))
        return values(plans)

    second = CellInterpolant(
        atlas, env, counted, measure, max_level=2, store=CellStore(tmp_path, "test")
    )
    assert np.array_equal(second(thetas), a, equal_nan=True)
    assert second.checked == 0 and sum(asked) == second.solved

    shard = next(tmp_path.glob("test.cells-*.npz"))
    shard.write_bytes(shard.read_bytes()[:-50])
    rejected = []
    third = CellInterpolant(
        atlas, env, values, measure, max_level=2, store=CellStore(tmp_path, "test", rejected)
    )
    assert np.array_equal(third(thetas), a, equal_nan=True)
    assert third.checked == first.checked
    assert rejected and "checksum" in rejected[0][1]


def test_cells_are_named_by_what_they_depend_on(small, monkeypatch):
    """Another tolerance, another function or changed code answering between nodes: another
    name, so no process reads cells checked for something else."""
    atlas, env = small
    name = interpolation.cell_name(atlas, env, "v", 0.02, 4)
    assert name == interpolation.cell_name(atlas, env, "v", 0.02, 4)
    assert name.startswith(atlas.key(env))
    assert len({
        name,
        interpolation.cell_name(atlas, env, "v", 0.05, 4),
        interpolation.cell_name(atlas, env, "v", 0.02, 3),
        interpolation.cell_name(atlas, env, "w", 0.02, 4),
    }) == 4  # fmt: skip
    monkeypatch.setattr(A, "answer_version", lambda: "changed")
    assert interpolation.cell_name(atlas, env, "v", 0.02, 4) != name


def test_outside_the_box_it_is_the_atlases_own_answer(small):
    atlas, env = small
    table = waypoint_table(atlas, env, NAMES, SD, 0.02, 3)
    outside = np.array([[2.5, 0.0], [0.0, -3.0]])
    plans, _ = _split(table(outside))
    assert np.array_equal(plans, atlas.plans(outside, env))
    assert table.solved >= 2


@pytest.mark.parametrize("bad", [0.0, -0.1, float("nan"), True, "0.1"])
def test_a_bound_that_is_not_positive_is_one_line(bad):
    with pytest.raises(ValueError, match=r"^interpolation tolerance .*: must be a number > 0$"):
        check_tolerance(bad)
    with pytest.raises(ValueError) as caught:
        make_learner("PF-C", {"interpolation": bad})
    message = str(caught.value)
    assert "\n" not in message and message.startswith("learners.PF-C.interpolation: an error")


def test_a_particle_count_below_two_is_one_line():
    with pytest.raises(ValueError) as caught:
        make_learner("PF-C", {"particles": 1})
    assert str(caught.value) == "learners.PF-C.particles: must be an integer >= 2, got 1"


@pytest.mark.parametrize("count", [1, 2])
def test_the_waypoints_a_correction_takes_are_the_worst_ones(count):
    """The batch :meth:`taken` of the waypoint model marks what :func:`worst_waypoints`
    picks, row by row; the whole-plan model takes every waypoint; a partial step none."""
    rng = np.random.default_rng(7)
    robot = rng.normal(size=(T, 7))
    intended = robot[None] + rng.normal(scale=0.1, size=(50, T, 7))
    intended[3, 4] = intended[3, 5] = robot[4] + 1.0  # a tie: the lower index first
    taken = WaypointCorrection(waypoints=count).taken(robot, intended)
    for row, mask in zip(intended, taken, strict=True):
        assert sorted(np.flatnonzero(mask)) == sorted(worst_waypoints(robot, row, count))
    assert OptimalCorrection().taken(robot, intended).all()
    assert WaypointCorrection(step=0.5).taken(robot, intended) is None


def test_the_particles_kl_weighs_refined_cells_by_their_volume():
    """A sample of the reference itself, smoothed: on a grid with a refined half (twice the
    nodes a side there, each weighing a quarter), the KL with the cells' volumes is the
    uniform grid's; without them the refined half would count four times."""
    rng = np.random.default_rng(8)
    sample = Particles(rng.normal(size=(3000, 2)), np.zeros(3000), np.zeros(3000))
    coarse = np.arange(-4.0, 4.0 + 1e-9, 0.25)
    fine = np.arange(-4.0, 4.0 + 1e-9, 0.125)
    left = np.array([(x, y) for x in coarse[coarse < 0] for y in coarse])
    right = np.array([(x, y) for x in fine[fine >= 0] for y in fine])
    points = np.concatenate([left, right])
    volume = np.concatenate([np.full(len(left), 0.25**2), np.full(len(right), 0.125**2)])
    density = np.exp(-0.5 * np.sum(points**2, axis=1))
    uniform_points = np.array([(x, y) for x in coarse for y in coarse])
    uniform = np.exp(-0.5 * np.sum(uniform_points**2, axis=1))
    expected = smoothed_kl(uniform_points, uniform / uniform.sum(), sample)
    weighed = density * volume
    got = smoothed_kl(points, weighed / weighed.sum(), sample, volume)
    assert got == pytest.approx(expected, abs=0.01)
    assert smoothed_kl(points, weighed / weighed.sum(), sample) > expected + 0.05


STUDY = """\
theta_star = [1.0, -1.0]
runs = 2
iterations = 3
seed = 3
environments = ["s0-t0-l1", "s1-t1-l2"]
atlas = { points = 9 }

[learners.PF-C]
particles = 300
interpolation = 0.05
max_level = 2
"""


def test_particles_through_the_atlas_learn_and_give_the_same_numbers_on_two_workers(tmp_path):
    """PF-C with its likelihood read off a 9-point atlas: it learns (the covariance shrinks),
    and one worker or two give byte-identical curves (the interpolants are per process, their
    values a function of θ alone)."""
    (tmp_path / "tiny.toml").write_text(STUDY)
    curves = []
    for workers in ("1", "2"):
        out = tmp_path / f"out{workers}"
        argv = ["study", str(tmp_path / "tiny.toml"), "--out", str(out), "--workers", workers]
        assert cli.main(argv) == 0
        curves.append((out / "tiny" / "curves.csv").read_bytes())
    assert curves[0] == curves[1]
    rows = [r for r in csv.DictReader(curves[0].decode().splitlines()) if r["learner"] == "PF-C"]
    first = [r for r in rows if r["run"] == "0"]
    assert float(first[-1]["cov_00"]) < 0.5 * float(first[0]["cov_00"])


def test_an_interpolant_dropped_from_the_process_keeps_its_cells(small, tmp_path, monkeypatch):
    """Past the per-process limit the least recently used interpolant goes, its cells saved
    first, so a process with many environments checks nothing twice on the machine."""
    atlas, env = small
    values, measure = _feature_values(env)
    monkeypatch.setattr(interpolation, "_KEPT", type(interpolation._KEPT)())
    monkeypatch.setattr(interpolation, "_MAX_INTERPOLANTS", 1)

    def make(name):
        store = CellStore(tmp_path, name)
        return lambda: CellInterpolant(atlas, env, values, measure, max_level=1, store=store)

    first = interpolation.interpolant("first", make("first"))
    first(np.array([[0.1, 0.2], [1.1, -0.7]]))
    assert first.checked > 0 and not list(tmp_path.glob("first.cells-*.npz"))
    interpolation.interpolant("second", make("second"))
    assert list(interpolation._KEPT) == ["second"]
    assert len(list(tmp_path.glob("first.cells-*.npz"))) == 1
    again = interpolation.interpolant("first", make("first"))
    assert again is not first and len(again._status) == first.checked
