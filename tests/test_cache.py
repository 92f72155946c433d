"""The machine's cache: every reader marks what it reads as used, ``cache`` lists it by kind,
and ``cache --prune DAYS`` removes only what no run used for that long (never a file it
does not know)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from corrections_sim.cli import main as cli
from corrections_sim.planning import cache
from corrections_sim.planning.compiled import build_once
from corrections_sim.plans import between
from corrections_sim.plans.atlas import AtlasGrid, AtlasStore, EnvironmentAtlas
from corrections_sim.plans.between import BetweenNodes, PlanShards

DAY = 86_400.0
LONG_AGO = time.time() - 100 * DAY


def _file(path: Path, size: int, mtime: float = LONG_AGO) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x" * size)
    os.utime(path, (mtime, mtime))
    return path


@pytest.fixture
def filled(tmp_path: Path) -> Path:
    """A cache of every kind, all last used 100 days ago but one atlas used now."""
    root = tmp_path / "cache"
    _file(root / "trajopt-abc.so", 100)
    _file(root / "trajopt-abc.so.lock", 0)
    _file(root / "newton-def.so", 50)
    _file(root / "atlas" / "0123.npy", 1000)
    _file(root / "atlas" / "0123.json", 10)
    _file(root / "atlas" / "4567.npy", 2000, time.time())
    _file(root / "atlas" / "4567.json", 20, time.time())
    _file(root / "atlas" / "0123-v1.extra-aaaa.npz", 300)
    _file(root / "atlas" / "0123-c1.cells-bbbb.npz", 200)
    _file(root / "atlas" / "tmpq1w2.npz.tmp", 7)
    _file(root / "reference" / "89ab.npy", 400)
    _file(root / "reference" / "89ab.npy.lock", 0)
    _file(root / "reference" / "89ab.123.tmp.npy", 5)
    _file(root / "person" / "cdef.npz", 70)
    _file(root / "person" / "tmpx9.npz.tmp", 4)
    _file(root / "tmpbuild" / "generated.c", 30)
    _file(root / "tmpbuild" / "trajopt-abc.so", 60)
    _file(root / "notes.txt", 3)
    return root


def test_entries_group_the_files_by_kind(filled):
    found = {(e.kind, e.name): e for e in cache.entries(filled)}
    assert set(found) == {
        ("compiled", "trajopt-abc.so"),
        ("compiled", "newton-def.so"),
        ("atlas", "0123"),
        ("atlas", "4567"),
        ("between", "0123-v1.extra-aaaa.npz"),
        ("cells", "0123-c1.cells-bbbb.npz"),
        ("reference", "89ab.npy"),
        ("person", "cdef"),
        ("unfinished", "atlas/tmpq1w2.npz.tmp"),
        ("unfinished", "person/tmpx9.npz.tmp"),
        ("unfinished", "reference/89ab.123.tmp.npy"),
        ("unfinished", "tmpbuild/"),
        ("other", "notes.txt"),
    }
    assert found["atlas", "0123"].size == 1010
    assert found["compiled", "trajopt-abc.so"].paths == (
        filled / "trajopt-abc.so",
        filled / "trajopt-abc.so.lock",
    )
    assert found["unfinished", "tmpbuild/"].paths == (filled / "tmpbuild",)
    assert found["unfinished", "tmpbuild/"].size == 90
    assert found["atlas", "4567"].last_used > time.time() - 60
    assert cache.entries(filled / "absent") == []


def test_prune_removes_only_what_went_unused_and_never_an_unknown_file(filled):
    removed = cache.prune(cache.entries(filled), 30 * DAY, time.time())
    assert {e.kind for e in removed} == set(cache.PRUNABLE)
    left = sorted(p.relative_to(filled).as_posix() for p in filled.rglob("*") if p.is_file())
    assert left == ["atlas/4567.json", "atlas/4567.npy", "notes.txt"]
    assert not (filled / "tmpbuild").exists()
    # Nothing is older than 200 days: nothing more goes.
    assert cache.prune(cache.entries(filled), 200 * DAY, time.time()) == []
    with pytest.raises(ValueError, match="unused_for"):
        cache.prune([], 0, time.time())


def test_readers_mark_what_they_read_as_used(tmp_path):
    grid = AtlasGrid((-1.0, -1.0), (1.0, 1.0), (3, 3))
    atlas = EnvironmentAtlas(
        grid,
        np.zeros((9, 3, 7)),
        np.zeros((9, 2)),
        np.zeros(9),
        np.zeros(9),
        solves=9,
    )
    store = AtlasStore(tmp_path)
    store.save("key", atlas)
    shard = store.shards.save("key", np.zeros((1, 2)), np.zeros((1, 3, 7)))
    library = _file(tmp_path / "trajopt-x.so", 10)
    for path in (tmp_path / "key.npy", tmp_path / "key.json", shard):
        os.utime(path, (LONG_AGO, LONG_AGO))
    assert store.load("key", grid, 3) is not None
    assert len(PlanShards(tmp_path).load("key", 3, 2)[0]) == 1
    build_once(library, lambda path: pytest.fail("built again"))
    recent = time.time() - 60
    for path in (tmp_path / "key.npy", tmp_path / "key.json", shard, library):
        assert path.stat().st_mtime > recent, path.name
    assert cache.prune(cache.entries(tmp_path), DAY, time.time()) == []


def test_the_command_lists_and_prunes(filled, monkeypatch, capsys):
    monkeypatch.setenv("CORRECTIONS_SIM_CACHE", str(filled))
    assert cli.main(["cache"]) == 0
    out = capsys.readouterr().out
    assert f"cache: {filled}" in out
    assert "atlas" in out and "unfinished" in out and "total" in out
    assert cli.main(["cache", "--prune", "30"]) == 0
    out = capsys.readouterr().out
    assert "removed 11 entries not used for 30 days" in out
    assert (filled / "atlas" / "4567.npy").exists() and (filled / "notes.txt").exists()


@pytest.mark.parametrize("days", ["0", "-1", "nan", "soon"])
def test_a_bad_prune_is_one_line_naming_it(days, capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["cache", "--prune", days])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--prune" in err[0]


def _shards(root: Path, n: int, T: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """``n`` shards of the atlas "key", the i-th with the plans at θ_i and θ_(i+1) (so every
    inner θ twice), the plan at θ_2 NaN (no start converged)."""
    rng = np.random.default_rng(65)
    thetas, plans = rng.normal(size=(n + 1, 2)), rng.normal(size=(n + 1, T, 7))
    plans[2] = np.nan
    for i in range(n):
        PlanShards(root).save("key", thetas[i : i + 2], plans[i : i + 2])
    return thetas, plans


def _assert_known(root: Path, thetas: np.ndarray, plans: np.ndarray) -> None:
    known = BetweenNodes(PlanShards(root), 3, 2).known(b"E", "key")
    assert set(known) == {theta.tobytes() for theta in thetas}
    for theta, plan in zip(thetas, plans, strict=True):
        if np.isnan(plan).all():
            assert known[theta.tobytes()] is None
        else:
            assert np.array_equal(known[theta.tobytes()], plan)


def test_many_shards_of_an_atlas_are_merged_into_one_and_no_plan_is_lost(tmp_path):
    thetas, plans = _shards(tmp_path, between.COMPACT_AT)
    assert len(list(tmp_path.glob("key.extra-*.npz"))) == between.COMPACT_AT
    read, _ = PlanShards(tmp_path).load("key", 3, 2)
    assert len(read) == len(thetas)  # each θ once, though inner ones were in two shards
    assert len(list(tmp_path.glob("key.extra-*.npz"))) == 1
    _assert_known(tmp_path, thetas, plans)
    assert len(list(tmp_path.glob("key.extra-*.npz"))) == 1  # one shard is not merged again


def test_a_few_shards_are_left_as_they_are(tmp_path):
    thetas, plans = _shards(tmp_path, between.COMPACT_AT - 1)
    _assert_known(tmp_path, thetas, plans)
    assert len(list(tmp_path.glob("key.extra-*.npz"))) == between.COMPACT_AT - 1


def test_a_store_that_cannot_be_written_is_read_as_it_is(tmp_path, monkeypatch):
    thetas, plans = _shards(tmp_path, between.COMPACT_AT)

    def refused(*args, **kwargs):
        raise PermissionError("read-only file system")

    monkeypatch.setattr(between, "write_shard", refused)
    _assert_known(tmp_path, thetas, plans)
    assert len(list(tmp_path.glob("key.extra-*.npz"))) == between.COMPACT_AT


def test_a_shard_merged_away_after_the_listing_is_found_in_the_merged_one(tmp_path):
    """The folder is listed; then another process writes a merged shard and removes one the
    listing named: the reader lists again and reads the merged one, without a word."""
    thetas, plans = _shards(tmp_path, 3)
    gone = sorted(tmp_path.glob("key.extra-*.npz"))[1]
    rejected: list[tuple[str, str]] = []
    listing = iter(between.read_shards(tmp_path, "key.extra", rejected, lambda a: None))
    first = next(listing)
    with np.load(gone) as data:  # merged with the one read: a shard of another name
        merged = {n: np.concatenate([first[n], data[n]]) for n in ("thetas", "plans")}
    between.write_shard(tmp_path, "key.extra", merged)
    gone.unlink()
    read = [first, *listing]
    assert len(read) == 3 and rejected == []
    found = {t.tobytes() for a in read for t in a["thetas"]}
    assert found == {t.tobytes() for t in thetas}


def test_distinct_tells_thetas_apart_by_their_bytes():
    thetas = np.array([[0.0, 1.0], [-0.0, 1.0], [0.0, 1.0], [2.0, 3.0]])
    plans = np.arange(4 * 3 * 7, dtype=float).reshape(4, 3, 7)
    kept, kept_plans = between.distinct(thetas, plans)
    assert kept.tobytes() == thetas[[0, 1, 3]].tobytes()
    assert np.array_equal(kept_plans, plans[[0, 1, 3]])


def _load_known(root: str, out) -> None:
    known = BetweenNodes(PlanShards(Path(root)), 3, 2).known(b"E", "key")
    out.put(len(known))


def test_processes_that_merge_the_same_shards_at_once_lose_no_plan(tmp_path):
    """Four processes read (and so merge) the same 3 × COMPACT_AT shards at once: each finds
    every plan, and so does a reader after them, from what is left on disk."""
    import multiprocessing

    thetas, plans = _shards(tmp_path, 3 * between.COMPACT_AT)
    context = multiprocessing.get_context("fork")
    out = context.Queue()
    workers = [context.Process(target=_load_known, args=(str(tmp_path), out)) for _ in range(4)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join(30)
        assert worker.exitcode == 0
    assert sorted(out.get() for _ in workers) == [len(thetas)] * 4
    _assert_known(tmp_path, thetas, plans)
    assert len(list(tmp_path.glob("key.extra-*.npz"))) < between.COMPACT_AT


@pytest.mark.parametrize("mapped", [0, 3])
def test_a_plan_table_answers_as_a_dictionary_of_first_plans_would(tmp_path, mapped, monkeypatch):
    """PlanTable (a few arrays and an index) against a plain dict θ's bytes -> the first plan
    kept there (None where it has a NaN), over a random mix of single plans and blocks (some θ
    repeated within and across them, blocks past MAX_BLOCKS compacted), after ``mapped``
    shards' blocks mapped from their files (rows with a NaN among numbers in them, as a shard
    written by other code could hold): the same keys, and every lookup — one at a time and
    many at once — the same bits."""
    rng = np.random.default_rng(65)
    T, table, reference = 3, between.PlanTable(3), {}
    for i in range(mapped):
        thetas = rng.integers(0, 300, size=(40 if i != 1 else 4, 2)).astype(float)
        n = len(thetas)
        plans = rng.normal(size=(n, T, 7))
        plans[rng.random(n) < 0.2] = np.nan
        plans[rng.random(n) < 0.1, 1, 3] = np.nan  # partial: no plan
        PlanShards(tmp_path).save("key", thetas, plans)
    # Shards of 40 plans mapped, the one of 4 copied, in the order found.
    monkeypatch.setattr(between, "MAP_AT", 40 * T * 7 * 8)
    for thetas, plans in PlanShards(tmp_path).blocks("key", T, 2):
        is_mapped = isinstance(plans, np.memmap)
        assert is_mapped == (len(thetas) == 40)
        memos = between.row_keys(thetas)
        table.add_many(memos, plans, mapped=is_mapped)
        for memo, plan in zip(memos, plans, strict=True):
            reference.setdefault(memo, None if np.isnan(plan).any() else np.array(plan))
    for _ in range(400):
        if rng.random() < 0.1:  # a block, as read from shards or taken from another worker
            n = int(rng.integers(0, 50))
            thetas = rng.integers(0, 300, size=(n, 2)).astype(float)
            plans = rng.normal(size=(n, T, 7))
            plans[rng.random(n) < 0.2] = np.nan
            memos = between.row_keys(thetas)
            new = table.add_many(memos, plans)
            expected_new = []
            for memo, plan in zip(memos, plans, strict=True):
                if memo not in reference:
                    reference[memo] = None if np.isnan(plan).all() else plan
                    expected_new.append(memo)
            assert new == expected_new
        else:  # one solved here
            memo = rng.integers(0, 300, size=2).astype(float).tobytes()
            plan = None if rng.random() < 0.2 else rng.normal(size=(T, 7))
            assert table.add(memo, plan) == (memo not in reference)
            reference.setdefault(memo, plan)
        asked = list(reference)
        asked = [asked[i] for i in rng.integers(0, len(asked), size=20)] if asked else []
        taken = table.take(table.rows(asked)) if asked else []
        for memo, plan in zip(asked, taken, strict=True):
            want = reference[memo]
            if want is None:
                assert np.isnan(plan).all() and table[memo] is None
            else:
                assert np.array_equal(plan, want) and np.array_equal(table[memo], want)
    assert set(table) == set(reference) and len(table) == len(reference)
    assert len(table._blocks) <= mapped + between.MAX_BLOCKS + 1
    assert table.rows([b"absent but sixteen"]).tolist() == [-1]
    with pytest.raises(ValueError, match="2 thetas for 1 plans"):
        table.add_many([b"a" * 16, b"b" * 16], np.zeros((1, T, 7)))


def test_a_store_larger_than_a_process_keeps_is_mapped_not_read_again(tmp_path, monkeypatch):
    """The shards' plans are mapped from their files and do not count against MAX_KEPT: a
    process that looks at more stored plans than it may keep in memory reads each
    environment's shards once (before, it dropped every environment's plans and read them
    again at the next look), and answers from them."""
    monkeypatch.setattr(between, "MAX_KEPT", 5)
    monkeypatch.setattr(between, "MAP_AT", 0)
    rng = np.random.default_rng(7)
    stored = {}
    for name in ("a", "b", "c"):
        thetas, plans = rng.normal(size=(8, 2)), rng.normal(size=(8, 3, 7))
        PlanShards(tmp_path).save(name, thetas, plans)
        stored[name] = (thetas, plans)
    loads = []
    shards = PlanShards(tmp_path)
    blocks = shards.blocks
    monkeypatch.setattr(shards, "blocks", lambda *a: loads.append(a[0]) or blocks(*a))
    process = BetweenNodes(shards, 3, 2)
    for name in ("a", "b", "c", "a", "b", "c"):
        known = process.known(name.encode(), name)
        thetas, plans = stored[name]
        taken = known.take(known.rows(between.row_keys(thetas)))
        assert np.array_equal(taken, plans)
    assert loads == ["a", "b", "c"]


def test_a_compressed_shard_is_read_as_a_copy(tmp_path, monkeypatch):
    """A shard whose members are compressed (not np.savez's way) cannot be mapped: its plans
    are read into memory, the same values."""
    import hashlib

    monkeypatch.setattr(between, "MAP_AT", 0)
    thetas, plans = np.arange(4.0).reshape(2, 2), np.linspace(0, 1, 42).reshape(2, 3, 7)
    tmp = tmp_path / "tmp.npz"
    np.savez_compressed(tmp, thetas=thetas, plans=plans)
    digest = hashlib.sha256(tmp.read_bytes()).hexdigest()[:16]
    tmp.rename(tmp_path / f"key.extra-{digest}.npz")
    [(read_thetas, read_plans)] = PlanShards(tmp_path).blocks("key", 3, 2)
    assert not isinstance(read_plans, np.memmap)
    assert np.array_equal(read_thetas, thetas) and np.array_equal(read_plans, plans)


def test_a_small_shard_is_copied_and_a_large_one_mapped(tmp_path):
    """A map holds a file open: shards under MAP_AT bytes (a run's few new plans) are copied,
    so a process holds a few maps an environment, not one a shard."""
    rng = np.random.default_rng(3)
    small = int(between.MAP_AT // (3 * 7 * 8)) // 2
    for n in (small, 4 * small):
        PlanShards(tmp_path).save("key", rng.normal(size=(n, 2)), rng.normal(size=(n, 3, 7)))
    blocks = PlanShards(tmp_path).blocks("key", 3, 2)
    found = sorted((len(t), isinstance(p, np.memmap)) for t, p in blocks)
    assert found == [(small, False), (4 * small, True)]
