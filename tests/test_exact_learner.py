"""Plans from a plan atlas, and the exact learners on its grid (issue 52): a study with
``atlas`` plans every (θ, E) from the atlas alone; EX-C and EX-CL *are* the exact reference on
the atlas's grid (the same posterior, to round-off), its cells cut finer where the posterior
is narrower than the grid; a study that asks for an exact learner
without an atlas, or for a bad atlas, is refused in one line."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from corrections_sim.cli import main as cli
from corrections_sim.learning.exact import bayes as ref
from corrections_sim.learning.exact.cells import Cells
from corrections_sim.planning.planner import PlannerConfig, shared_planner
from corrections_sim.plans import atlas as A
from corrections_sim.plans import spread
from corrections_sim.plans.book import PlanBook, Target
from corrections_sim.scene.environments import paper_environments
from corrections_sim.study import schema
from corrections_sim.study.runner import run_key

STUDY = """\
theta_star = [1.0, -1.0]
runs = 1
iterations = 2
seed = 3
environments = ["s0-t0-l1", "s1-t1-l2"]
atlas = { points = 9 }

# The reference tool's own refinement (twice the learners' default resolution, its core to
# 1e-6 of the peak), so that on the same cells the learners are the reference; EX-CL cuts
# its cells along the narrow axes only, and the reference cuts its own as EX-CL does.
[learners.KF-C]
[learners.EX-C]
resolution = 2.0
cut = 13.8
[learners.EX-CL]
resolution = 2.0
cut = 13.8
axes = "narrow"
"""


@pytest.fixture(scope="module")
def figure(tmp_path_factory):
    folder = tmp_path_factory.mktemp("exact")
    (folder / "tiny.toml").write_text(STUDY)
    argv = ["study", str(folder / "tiny.toml"), "--out", str(folder / "out"), "--workers", "1"]
    assert cli.main(argv) == 0
    return folder / "out" / "tiny"


def _rows(path, learner=None):
    with open(path, newline="") as fh:
        return [r for r in csv.DictReader(fh) if learner is None or r["learner"] == learner]


@pytest.mark.parametrize("learner", ["EX-C", "EX-CL"])
def test_the_exact_learner_is_its_reference_on_the_atlas_grid(figure, learner, capsys):
    """The reference tool, on a study with an atlas, reads the atlas's grid and plans: the
    exact learner's mean and covariance after every correction are the reference's."""
    assert cli.main(["reference", str(figure), "--learner", learner, "--runs", "1"]) == 0
    reference = _rows(figure / f"reference-{learner}" / "records.csv")
    curves = _rows(figure / "curves.csv", learner)
    assert [int(r["iteration"]) for r in reference] == [1, 2]
    for r in reference:
        mine = curves[int(r["iteration"])]
        for key in ("theta_0", "theta_1", "cov_00", "cov_01", "cov_11"):
            assert float(mine[key]) == pytest.approx(float(r[f"ref_{key}"]), rel=1e-9, abs=1e-12)
        assert float(r["ref_kl_gaussian"]) == pytest.approx(0.0, abs=1e-9)
    # It learns: the first correction moves the mean and shrinks the covariance.
    assert float(curves[1]["cov_00"]) < float(curves[0]["cov_00"])
    assert "ref NEES" in capsys.readouterr().out


def test_its_spread_over_the_cells_keeps_its_estimate_and_adds_what_cells_cannot_resolve(
    figure, tmp_path
):
    """``spread = "cells"``: the same θ̂, error and regret to the bit after every correction,
    and after the first a P wider than the nodes' in every direction (the density within the
    cells), so a lower NEES; the prior's P the same."""
    path = tmp_path / "tiny.toml"
    path.write_text(STUDY)
    argv = ["study", str(path), "--out", str(tmp_path / "out"), "--workers", "1"]
    assert cli.main([*argv, "--learners", "EX-C", "--set", 'learners.EX-C.spread="cells"']) == 0
    cells_rows = _rows(tmp_path / "out" / "tiny" / "curves.csv", "EX-C")
    nodes_rows = _rows(figure / "curves.csv", "EX-C")
    assert len(cells_rows) == len(nodes_rows) == 3
    for wide, narrow in zip(cells_rows, nodes_rows, strict=True):
        for key in ("theta_0", "theta_1", "regret", "estimate_error"):
            assert wide[key] == narrow[key]
        gap = np.linalg.eigvalsh(_cov(wide) - _cov(narrow))
        if wide["iteration"] == "0":  # the prior, before any cell
            assert np.array_equal(_cov(wide), _cov(narrow))
        else:
            assert gap.min() > 0.0
            assert float(wide["nees"]) < float(narrow["nees"])


def _cov(row) -> np.ndarray:
    return np.array(
        [[float(row[f"cov_{min(i, j)}{max(i, j)}"]) for j in range(2)] for i in range(2)]
    )


def test_the_reference_cuts_its_cells_as_axes_says(figure, capsys):
    """``--axes``: a reference's cells cut otherwise than its learner cuts its own (what makes
    a filter's reference affordable at k = 3) hold the same posterior to within their
    integration error, but not the same bits; ``--axes all`` for EX-C, which cuts in 2^k, is
    its default to the bit."""
    argv = ["reference", str(figure), "--learner", "EX-C", "--runs", "1", "--force"]
    assert cli.main(argv) == 0
    own = _rows(figure / "reference-EX-C" / "records.csv")
    assert cli.main([*argv, "--axes", "all"]) == 0
    assert _rows(figure / "reference-EX-C" / "records.csv") == own
    assert cli.main([*argv, "--axes", "narrow"]) == 0
    narrow = _rows(figure / "reference-EX-C" / "records.csv")
    summary = json.loads((figure / "reference-EX-C" / "summary.json").read_text())
    assert summary["settings"]["axes"] == "narrow"
    keys = ("ref_cov_00", "ref_cov_01", "ref_cov_11")
    assert any(a[key] != b[key] for a, b in zip(own, narrow, strict=True) for key in keys)
    for a, b in zip(own, narrow, strict=True):
        sd = np.sqrt([float(a["ref_cov_00"]), float(a["ref_cov_11"])])
        for i in range(2):
            gap = abs(float(a[f"ref_theta_{i}"]) - float(b[f"ref_theta_{i}"]))
            assert gap < 0.05 * sd[i]
            var = float(a[f"ref_cov_{i}{i}"])
            assert float(b[f"ref_cov_{i}{i}"]) == pytest.approx(var, rel=0.05)


def test_the_exact_learner_without_an_atlas_is_one_line(tmp_path, capsys):
    path = tmp_path / "bare.toml"
    path.write_text(STUDY.replace("atlas = { points = 9 }\n", "atlas = false\n"))
    assert cli.main(["study", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "learners.EX-C: its grid is the study's plan atlas" in err


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("atlas = { points = 2 }", "atlas.points: must be an integer >= 3, got 2"),
        ("atlas = { width = -1.0 }", "atlas.width: must be finite and > 0"),
        ("atlas = { box = 3 }", "atlas.box: unknown key"),
    ],
)
def test_a_bad_atlas_is_one_line(tmp_path, capsys, value, message):
    path = tmp_path / "bad.toml"
    path.write_text(STUDY.replace("atlas = { points = 9 }", value))
    assert cli.main(["study", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err


def test_the_run_key_names_the_atlas_only_when_there_is_one():
    values = {"theta_star": [1.0, -1.0], "environments": ["s0-t0-l1"], "learners": ["KF"]}
    bare = run_key(schema.parse_study(values))
    assert "atlas" not in bare and "atlas_identity" not in bare
    mine = run_key(schema.parse_study({**values, "atlas": {"points": 9}}))
    other = run_key(schema.parse_study({**values, "atlas": {"points": 11}}))
    assert mine["atlas"] == {"width": 5.0, "points": 9, "cold_stride": 10}
    assert mine["atlas_identity"] != other["atlas_identity"]


@pytest.fixture(scope="module")
def small_atlas(tmp_path_factory):
    config = PlannerConfig(n_starts=2)
    grid = A.AtlasGrid.around([0.0, 0.0], [1.0, 1.0], width=3.0, count=7)
    spec = spread.AtlasSpec(config, grid, cold_stride=3, root=str(tmp_path_factory.mktemp("atlas")))
    return spec


def test_a_plan_from_the_atlas_depends_on_theta_and_e_alone(small_atlas):
    """Two books asked the same problems in opposite orders give the same plans, bit for
    bit; outside the box the cold starts answer and are counted."""
    envs = paper_environments()[:2]
    problems = [
        (np.array([0.3, -1.1]), envs[0]),
        (np.array([-2.2, 0.7]), envs[1]),
        (np.array([0.31, -1.05]), envs[0]),
        (np.array([1.9, 2.4]), envs[1]),
    ]
    atlas = small_atlas.atlas()
    planner = shared_planner(small_atlas.config)
    forward, backward = PlanBook(planner, atlas=atlas), PlanBook(planner, atlas=atlas)
    ahead = [forward.plan(t, e).trajectory for t, e in problems]
    behind = [backward.plan(t, e).trajectory for t, e in reversed(problems)][::-1]
    for a, b in zip(ahead, behind, strict=True):
        assert np.array_equal(a, b)
    outside = atlas.outside
    forward.plan(np.array([3.5, 0.0]), envs[0])
    assert atlas.outside == outside + 1
    with pytest.raises(ValueError, match="another planner configuration"):
        PlanBook(shared_planner(PlannerConfig(n_starts=1)), atlas=atlas)


def test_plans_at_many_thetas_are_the_nodes_and_the_atlas_answers(small_atlas):
    """Atlas.plans: a node's stored plan at a node (to round-off in θ), Atlas.solve's answer
    between nodes, the same bits when asked again (kept) or by a fresh atlas (not kept)."""
    env = paper_environments()[0]
    atlas = small_atlas.atlas()
    nodes = small_atlas.grid.thetas()
    between = np.array([[0.3, -1.1], [-2.2, 0.7]])
    asked = np.concatenate([nodes[[3, 17]] + 1e-13, between])
    plans = atlas.plans(asked, env)
    stored = atlas.environment(env).trajectories
    assert np.array_equal(plans[:2], stored[[3, 17]])
    for theta, plan in zip(between, plans[2:], strict=True):
        assert np.array_equal(plan, atlas.solve(theta, env).trajectory)
    planner, spec = shared_planner(small_atlas.config), small_atlas
    fresh = A.Atlas(planner, spec.grid, store=spec.store(), cold_stride=spec.cold_stride)
    assert np.array_equal(atlas.plans(asked, env), plans)
    assert np.array_equal(fresh.plans(asked[::-1], env)[::-1], plans)


def test_the_person_plans_with_the_atlas_and_restarts_at_least_as_well(small_atlas):
    envs = paper_environments()[:2]
    planner = shared_planner(small_atlas.config)
    theta = np.array([1.0, -1.0])
    cold = Target.solve(planner, theta, envs)
    best = Target.solve(planner, theta, envs, atlas=small_atlas.atlas(), restarts=5)
    for c, b in zip(cold.plans, best.plans, strict=True):
        assert b.reward >= c.reward - 1e-12
    again = Target.solve(planner, theta, envs[::-1], atlas=small_atlas.atlas(), restarts=5)
    assert np.array_equal(again.plans[1].trajectory, best.plans[0].trajectory)
    with pytest.raises(ValueError, match="restarts = -1"):
        Target.solve(planner, theta, envs, restarts=-1)


def test_plans_between_nodes_reach_a_process_that_shares_no_files_through_an_exchange(
    small_atlas, tmp_path
):
    """What one process solved between the atlas's nodes, given to an exchange, is taken by
    a process with a store of its own: it answers the same θ with the same bits and solves
    none of them, and keeps them in its store; plans named for another atlas are refused,
    and nothing is given twice."""
    import dataclasses

    env = paper_environments()[1]
    one = small_atlas.atlas()
    two = dataclasses.replace(small_atlas, root=str(tmp_path / "elsewhere"))
    thetas = np.array([[0.37, -1.13], [-2.21, 0.71], [1.07, 0.43]])
    exchange = spread.PlanExchange()
    here, there = spread.Peer(exchange), spread.Peer(exchange)
    solved = one.solved_between
    here.give(one)  # what earlier tests solved here
    mine = one.plans(thetas, env)
    assert one.solved_between == solved + 3
    assert here.give(one) == 3 and here.give(one) == 0
    two.atlas().hold(env, one.environment(env))  # the atlas handed, as on a cluster
    assert there.take(two.atlas()) >= 3 and there.take(two.atlas()) == 0
    assert np.array_equal(two.atlas().plans(thetas, env), mine)
    assert two.atlas().solved_between == 0
    assert two.atlas().save() >= 3  # and kept on its machine
    with pytest.raises(ValueError, match="not this process's atlas"):
        two.atlas().merge(env, "another-atlas", thetas, mine)


def test_a_corrupt_atlas_file_is_built_again_and_says_so(small_atlas, tmp_path):
    """A stored atlas whose data was truncated is not read: preparing the study's atlases
    warns in one line naming why, and builds it again."""
    import dataclasses

    spec = dataclasses.replace(small_atlas, root=str(tmp_path / "store"))
    env = paper_environments()[3]
    assert spread.prepare(spec, [env]) == 1 and spread.prepare(spec, [env]) == 0
    data = tmp_path / "store" / f"{spec.key(env)}.npy"
    data.write_bytes(data.read_bytes()[:-64])
    with pytest.warns(UserWarning, match="not trusted, built again: its data does not match"):
        assert spread.prepare(spec, [env]) == 1
    assert spec.missing([env]) == []


def test_the_reference_builds_the_atlases_it_lacks_before_its_runs(figure, tmp_path, monkeypatch):
    """On a machine without the study's atlases, the reference command builds each
    environment's atlas once, one task an environment, before any run starts (each run built
    what it met before, so two workers built the same atlas at once); the records are those
    made with the atlases on disk."""
    from concurrent.futures import ThreadPoolExecutor
    from contextlib import contextmanager

    from corrections_sim.cli.commands import figure as command
    from corrections_sim.figures import reference_figure
    from corrections_sim.planning.planner import cache_dir
    from corrections_sim.study.schema import load_study

    argv = ["reference", str(figure), "--learner", "EX-C", "--runs", "1"]
    assert cli.main([*argv, "--out", str(tmp_path / "warm")]) == 0
    settings = load_study(figure.parent.parent / "tiny.toml", name="tiny", quick=False)
    envs = {e.key(): e for e in settings.envs()}
    keys = tuple(settings.atlas_spec().key(e) for e in envs.values())
    cache = tmp_path / "cache"
    (cache / "atlas").mkdir(parents=True)
    for library in cache_dir().glob("*.so"):  # the compiled solvers, no atlas
        (cache / library.name).symlink_to(library)
    for shard in (cache_dir() / "atlas").glob("*.extra-*.npz"):  # its plans between nodes
        if shard.name.startswith(keys):
            (cache / "atlas" / shard.name).symlink_to(shard)
    monkeypatch.setenv("CORRECTIONS_SIM_CACHE", str(cache))
    built, at_first_run = [], []
    build, judge_run = A.build, reference_figure.judge_run

    def counted(planner, env, *args, **kwargs):
        built.append(env.key())
        return build(planner, env, *args, **kwargs)

    def first_run(*args, **kwargs):
        at_first_run.append(len(built))
        return judge_run(*args, **kwargs)

    @contextmanager
    def here(workers):  # the command's pool as one thread of this process, to count builds
        with ThreadPoolExecutor(1) as pool:  # (one: a planner is not for two threads at once)
            yield pool

    monkeypatch.setattr(A, "build", counted)
    monkeypatch.setattr(reference_figure, "judge_run", first_run)
    monkeypatch.setattr(command, "process_pool", here)
    assert cli.main([*argv, "--workers", "1", "--out", str(tmp_path / "empty")]) == 0
    assert sorted(built) == sorted(envs) and at_first_run == [len(envs)]
    records = "reference-EX-C/records.csv"
    assert (tmp_path / "empty" / records).read_bytes() == (tmp_path / "warm" / records).read_bytes()


def test_an_atlas_study_gives_the_same_bytes_on_one_or_two_workers_and_on_dask(
    figure, tmp_path, monkeypatch
):
    """The study's curves (EX-C among them) with its atlas, made again on two worker
    processes and on a Dask cluster whose two workers and client each keep a cache of their
    own (as machines that share no files do): byte for byte those of the one-worker run, and
    on the cluster each environment's atlas built once in all (the client keeps what a worker
    built and hands it to every worker), every worker's cache holding every atlas after, and
    the client's the plans the workers solved between the nodes."""
    from distributed import Client, Nanny, Scheduler, SpecCluster

    from corrections_sim.planning.planner import cache_dir
    from corrections_sim.study.schema import load_study

    study = figure.parent.parent / "tiny.toml"
    made = (figure / "curves.csv").read_bytes()
    argv = ["study", str(study), "--workers", "2", "--out", str(tmp_path / "two")]
    assert cli.main(argv) == 0
    assert (tmp_path / "two" / "tiny" / "curves.csv").read_bytes() == made

    caches = {}
    for name in ("client", "a", "b"):  # the compiled solvers linked, no atlas
        caches[name] = tmp_path / f"cache-{name}"
        caches[name].mkdir()
        for library in cache_dir().glob("*.so"):
            (caches[name] / library.name).symlink_to(library)
    workers = {
        name: {
            "cls": Nanny,
            "options": {"nthreads": 1, "env": {"CORRECTIONS_SIM_CACHE": str(caches[name])}},
        }
        for name in ("a", "b")
    }
    scheduler = {"cls": Scheduler, "options": {"host": "127.0.0.1", "dashboard_address": None}}
    monkeypatch.setenv("CORRECTIONS_SIM_CACHE", str(caches["client"]))
    settings = load_study(study, name="tiny", quick=False)
    spec = settings.atlas_spec()

    def built() -> int:
        return spec.atlas().built

    before = built()  # this process may have built some for the fixture
    with SpecCluster(workers=workers, scheduler=scheduler) as cluster, Client(cluster) as client:
        argv = ["study", str(study), "--scheduler", cluster.scheduler_address]
        assert cli.main([*argv, "--out", str(tmp_path / "dask")]) == 0
        by_worker = client.run(built)
        _plans_between_nodes_are_solved_once_on_the_cluster(client, study)
    assert (tmp_path / "dask" / "tiny" / "curves.csv").read_bytes() == made
    envs = {e.key(): e for e in settings.envs()}.values()
    assert sum(by_worker.values()) == len(envs), by_worker
    assert built() == before  # the client kept what the workers built
    for name in ("client", "a", "b"):
        assert spec.missing(envs, A.AtlasStore(caches[name] / "atlas")) == []
    # ... and the plans the workers solved between the nodes, taken from the exchange
    assert list((caches["client"] / "atlas").glob("*.extra-*.npz"))


def _plans_between_nodes_are_solved_once_on_the_cluster(client, study) -> None:
    """On the cluster above (two workers, a cache each): a run of EX-C on cells of its own
    (a wider core than the study's, cut at 18 nats: nodes no worker has yet) on one worker,
    then the same run on the other: the second takes every plan between the atlas's nodes
    the first solved from the cluster's exchange and solves none of them again (only the few
    the first knew from the study run and so never solved), with the same records. (At
    resolution 3 the first solved 4,718 plans: 40 s of the suite for the same check as the
    144 here.)"""
    from corrections_sim.cli.executors import _exchange
    from corrections_sim.study import runner
    from corrections_sim.study.schema import load_study

    finer = {"learners": {"EX-C": {"resolution": 2.0, "cut": 18.0}}}
    settings = load_study(study, name="tiny", quick=False, overrides=finer)
    shared = runner.prepare(settings)
    held: list = []
    exchange = _exchange(client, held)
    a, b = sorted(client.scheduler_info(n_workers=-1)["workers"])

    def solved() -> int:
        return settings.atlas().solved_between

    def run_on(worker: str):
        before = client.run(solved, workers=[worker])[worker]
        future = client.submit(
            runner.run_one, settings, shared, "EX-C", 0, exchange=exchange, workers=[worker],
            pure=False,
        )  # fmt: skip
        result = future.result()
        return result, client.run(solved, workers=[worker])[worker] - before

    def given(since: int) -> tuple[set, int]:
        items, cursor = exchange.since(since).result()
        return {(env.key(), t.tobytes()) for env, _, thetas, _ in items for t in thetas}, cursor

    first, solved_first = run_on(a)
    by_a, cursor = given(0)
    second, solved_second = run_on(b)
    by_b, _ = given(cursor)
    # b solves only what a knew from the study run above and never had to solve here.
    assert len(by_a) == solved_first > 0 and len(by_b) == solved_second
    assert not by_a & by_b and solved_second < solved_first / 10, (solved_first, solved_second)
    assert second.records == first.records


def test_an_atlas_session_replays_from_its_atlas_and_says_so(tmp_path):
    """A page session planned from the study's atlas logs its identity; replayed from the
    same atlas, its own learner (EX-C) gives back the logged θ̂ exactly, and the replay says
    the atlas is the session's; a study whose atlas differs is told apart."""
    from corrections_sim.people.users import make_user
    from corrections_sim.session.log import StudyLog
    from corrections_sim.session.replay import replay, same_atlas
    from corrections_sim.session.session import Session
    from corrections_sim.session.simulate import simulate

    values = {
        "environments": ["s0-t0-l1", "s1-t1-l2"],
        "theta_star": [1.0, -1.0],
        "learners": ["KF-C", "EX-C"],
        "seed": 7,
        "iterations": 2,
        "atlas": {"points": 9},
    }
    settings = schema.parse_study(values, name="atlas")
    with StudyLog(tmp_path / "s.sqlite") as log:
        session = Session.start(settings, log, learner="EX-C", participant="sim-1")
        assert session.book.atlas is not None
        simulate(session, make_user("biased"), (1.0, -1.0), 2)
        _, _, facts = replay(log, session.id, ["KF-C", "EX-C"])
        assert facts["max_gap_to_log"] == 0.0 and facts["same_atlas"] is True
        other = schema.parse_study({**values, "atlas": {"points": 11}}, name="atlas")
        assert same_atlas(log, session.id, other) is False
        assert (
            same_atlas(
                log, session.id, schema.parse_study(values | {"atlas": False, "learners": ["KF-C"]})
            )
            is None
        )


def test_runs_made_on_another_atlas_are_not_reused(figure, tmp_path):
    """The run cache's key names the atlas: the same study on another grid computes every
    run again, and on the same grid resumes them all."""
    import json

    study = figure.parent.parent / "tiny.toml"
    out = tmp_path / "out"
    assert cli.main(["study", str(study), "--workers", "1", "--out", str(out)]) == 0
    again = ["study", str(study), "--workers", "1", "--out", str(out), "--force"]
    assert cli.main(again) == 0
    summary = json.loads((out / "tiny" / "summary.json").read_text())
    assert summary["resumed_runs"] == 3
    assert cli.main([*again, "--set", "atlas.points=7"]) == 0
    summary = json.loads((out / "tiny" / "summary.json").read_text())
    assert summary["resumed_runs"] == 0


def test_the_reference_without_refinement_is_another_posterior(figure):
    """The learners above refined their cells (else the reference's --resolution 0 would
    give the same numbers)."""
    argv = ["reference", str(figure), "--learner", "EX-C", "--runs", "1", "--resolution", "0"]
    assert cli.main([*argv, "--force"]) == 0  # the reference above had other settings
    coarse = _rows(figure / "reference-EX-C" / "records.csv")
    curves = _rows(figure / "curves.csv", "EX-C")
    gaps = [
        abs(float(curves[int(r["iteration"])]["cov_00"]) - float(r["ref_cov_00"]))
        / float(r["ref_cov_00"])
        for r in coarse
    ]
    assert max(gaps) > 1e-3


def _gaussian(cells: Cells, mean, cov) -> np.ndarray:
    d = cells.thetas() - mean
    return -0.5 * np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)


def test_cells_integrate_by_the_trapezoid_rule_and_keep_their_nodes_when_cut():
    cells = Cells.base((-1.0, 0.0), (1.0, 4.0), (5, 3), depth=3)
    assert cells.coefficients.sum() == pytest.approx(2.0 * 4.0)
    grid = A.AtlasGrid((-1.0, 0.0), (1.0, 4.0), (5, 3))
    assert np.allclose(cells.thetas()[:15], grid.thetas(), rtol=0.0, atol=1e-12)
    which = np.zeros(len(cells.leaves), bool)
    which[[0, 5]] = True
    finer = cells.cut(which)
    assert np.array_equal(finer.coords[: len(cells.coords)], cells.coords)
    assert len(finer.leaves) == len(cells.leaves) + 2 * 3
    assert finer.coefficients.sum() == pytest.approx(8.0)
    # Linear functions are integrated exactly on any cut.
    f = 1.0 + finer.thetas() @ np.array([0.3, -0.2])
    assert finer.coefficients @ f == pytest.approx(8.0 * (1.0 + 0.3 * 0.0 - 0.2 * 2.0))
    with pytest.raises(ValueError, match="finest level"):
        Cells.base((0.0,), (1.0,), (3,), depth=0).cut(np.ones(2, bool))


def test_refinement_resolves_a_posterior_narrower_than_the_grid():
    """A Gaussian of sd 0.1 on cells 1 wide: the base grid's moments are far off; cut
    where it lives until an sd has a node, they are right, and the cells stay few."""
    mean, cov = np.array([0.23, -0.41]), np.array([[0.01, 0.004], [0.004, 0.02]])
    cells = Cells.base((-5.0, -5.0), (5.0, 5.0), (11, 11), depth=6)
    refine = ref.Refinement(resolution=1.0)

    def moments(c):
        return ref.moments(c.thetas(), ref.posterior(_gaussian(c, mean, cov), c.coefficients))

    coarse = moments(cells)
    assert abs(coarse[1][0, 0] - cov[0, 0]) / cov[0, 0] > 0.5
    while (finer := refine.finer(cells, _gaussian(cells, mean, cov))) is not None:
        cells = finer
    got_mean, got_cov = moments(cells)
    assert np.abs(got_mean - mean).max() < 1e-3 * np.sqrt(cov[0, 0])
    assert np.abs(got_cov - cov).max() < 1e-3 * cov[0, 0]
    assert len(cells.coords) < 1000  # 121 coarse nodes; only the core is cut
    assert ref.Refinement(resolution=0.0).finer(cells, _gaussian(cells, mean, cov)) is None


def test_a_cell_halved_along_one_axis_keeps_the_trapezoid_rule():
    cells = Cells.base((0.0, 0.0, 0.0), (2.0, 2.0, 2.0), (3, 3, 3), depth=2)
    which = np.zeros(len(cells.leaves), bool)
    which[0] = True
    finer = cells.cut(which, np.array([False, True, False]))
    # Two children, each half as wide along axis 1 only; the new nodes are the midpoints of
    # the leaf's four edges along axis 1.
    assert len(finer.leaves) == len(cells.leaves) + 1
    assert len(finer.coords) == len(cells.coords) + 4
    assert sorted(finer.levels[-2:].tolist()) == [[0, 1, 0], [0, 1, 0]]
    assert finer.coefficients.sum() == pytest.approx(8.0)
    f = 2.0 + finer.thetas() @ np.array([0.5, -1.0, 0.25])
    assert finer.coefficients @ f == pytest.approx(8.0 * (2.0 + 0.5 - 1.0 + 0.25))
    with pytest.raises(ValueError, match="at least one"):
        cells.cut(which, np.zeros(3, bool))


def test_narrow_cuts_resolve_a_posterior_narrow_along_one_axis_with_few_nodes():
    """A Gaussian of sd 0.15 / 0.5 / 0.85 at k = 3 on cells 1.67 wide: cut along the axes
    that need it, its moments are as right as with every cell cut in eight, on a sixth of
    the nodes (measured: 1,873 against 32,107)."""
    mean, cov = np.array([1.0, -1.0, -1.0]), np.diag([0.15, 0.5, 0.85]) ** 2
    found = {}
    for axes in ref.REFINED_AXES:
        cells = Cells.base((-5.0,) * 3, (5.0,) * 3, (7, 7, 7), depth=4)
        refine = ref.Refinement(resolution=1.0, axes=axes)
        while (finer := refine.finer(cells, _gaussian(cells, mean, cov))) is not None:
            cells = finer
        w = ref.posterior(_gaussian(cells, mean, cov), cells.coefficients)
        got_mean, got_cov = ref.moments(cells.thetas(), w)
        assert np.abs(got_mean - mean).max() < 1e-3
        assert np.abs(np.diag(got_cov) / np.diag(cov) - 1).max() < 2e-3
        found[axes] = len(cells.coords)
    assert found["narrow"] * 6 < found["all"]


@pytest.mark.parametrize(
    ("param", "value", "message"),
    [
        ("resolution", -1.0, "learners.EX-C.resolution: must be a number >= 0"),
        ("cut", 0.0, "learners.EX-C.cut: must be a number > 0"),
        ("max_level", -1, "learners.EX-C.max_level"),
        ("axes", '"diagonal"', 'learners.EX-C.axes: must be "all" or "narrow"'),
        ("spread", '"wide"', 'learners.EX-C.spread: must be "nodes" or "cells"'),
    ],
)
def test_a_bad_refinement_is_one_line(tmp_path, capsys, param, value, message):
    path = tmp_path / "bad.toml"
    path.write_text(STUDY)
    argv = ["study", str(path), "--set", f"learners.EX-C.{param}={value}"]
    assert cli.main([*argv, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
