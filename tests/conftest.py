"""Shared pytest fixtures."""

from __future__ import annotations

import os
import sys
from pathlib import Path

if "PYTEST_XDIST_WORKER" in os.environ:
    # A worker keeps to one core (below): BLAS threads would only wait on each other there.
    # Set before numpy loads its BLAS, and inherited by every process a test starts.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from corrections_sim.learning import Belief


@pytest.fixture(autouse=True)
def _no_person_plans_from_another_test():
    """Each test solves its people's plans itself (a process keeps them,
    :meth:`FigureSettings.person_target`): what a test counts or patches is its own."""
    settings = sys.modules.get("corrections_sim.study.settings")
    if settings is not None:
        settings._TARGETS.clear()


@pytest.fixture
def rng() -> np.random.Generator:
    """A generator seeded with the paper's conference date, fresh for each test."""
    return np.random.default_rng(20181029)


@pytest.fixture
def random_belief():
    """A function (rng, k) -> a random Belief with a well-conditioned covariance (k, k)."""

    def make(rng: np.random.Generator, k: int) -> Belief:
        a = rng.normal(size=(k, k))
        return Belief(theta=rng.normal(size=k), cov=a @ a.T + 0.3 * np.eye(k))

    return make


@pytest.fixture
def refusing_gcc(tmp_path) -> tuple[Path, str]:
    """(a folder holding a ``gcc`` that refuses every source as a compiler does, the error
    line it prints on stderr before it exits 1); put the folder first on the PATH."""
    folder = tmp_path / "refusing-gcc"
    folder.mkdir()
    says = "x.c:1:1: error: unknown type name foo"
    (folder / "gcc").write_text(f'#!/bin/sh\necho "{says}" >&2\nexit 1\n')
    (folder / "gcc").chmod(0o755)
    return folder, says


@pytest.fixture(scope="module")
def planner():
    """Fig. 4's planner (laptop and table, four cold starts), for the tests that plan."""
    from corrections_sim.planning.planner import PlannerConfig, shared_planner

    return shared_planner(PlannerConfig(n_starts=4))


def pytest_collection_modifyitems(config, items):
    """The browser tests first (see :func:`pytest_xdist_make_scheduler`), then the longest
    modules, then the rest in the files' own order; a browser test outside a ``*_browser.py``
    module is refused (the scheduler groups the browser tests by their module's name)."""
    for item in items:
        if item.get_closest_marker("browser") and not item.path.name.endswith("_browser.py"):
            raise pytest.UsageError(f"{item.nodeid}: a browser test belongs in a *_browser.py")
    items.sort(key=_order)


#: The modules that take longest (a minute or more of one core, ``--durations``), scheduled
#: right after the browser tests so that the suite does not end waiting on one of them.
LONG = (
    "test_regression.py",
    "test_robustness.py",
    "test_bench.py",
    "test_cli.py",
    "test_video.py",
    "test_reference_run.py",
    "test_cli_input.py",
    "test_wheel.py",
    "test_interrupt.py",
    "test_user_study.py",
    "test_study_file.py",
)


def _order(item) -> tuple[int, int, str]:
    name = item.path.name
    if item.get_closest_marker("browser"):
        return (0, 0, name)  # module by module: each launches its chromium once
    return (1, LONG.index(name), "") if name in LONG else (2, 0, "")


def pytest_xdist_make_scheduler(config, log):
    """How the suite shares the machine's cores (pytest-xdist): each module's tests go to one
    worker (each class of a :data:`BY_CLASS` module to one), so a module fixture (a compiled
    planner, a quick run) is built once, and the
    browser tests of every ``*_browser.py`` module go to one worker together, first: they share
    a chromium, are the longest group and wait on pages that must not starve. (xdist's own
    ``loadgroup`` cannot do this under pytest 9, which ignores the group it writes into a
    test's id: every module fixture was built on both workers.)"""
    from xdist.scheduler import LoadScopeScheduling

    class ModulesAndBrowser(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            if module.endswith("_browser.py"):
                return "browser"
            parts = nodeid.split("::")
            if module.endswith(BY_CLASS) and len(parts) > 2:
                return "::".join(parts[:2])  # the class: its fixtures are the class's
            return module

    return ModulesAndBrowser(config, log)


#: Modules whose test classes go to workers of their own (each class's fixture is its own:
#: fig. 4's and fig. 5's quick runs side by side).
BY_CLASS = ("test_regression.py", "test_bench.py")

#: The cores this suite may use, read before any test narrows them.
CORES = sorted(os.sched_getaffinity(0))


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """Under pytest-xdist each worker keeps to a core of its own, and so does every process a
    test or its fixtures start (a figure's pool, a Dask cluster, gcc): a command left to choose
    its workers takes one, and a test that asks for a 2-worker pool (to check that 1 worker and
    2 give the same numbers) runs it on its own core, not on top of the other worker's. The
    browser tests keep every core: chromium, the page's server and the test share them. Set
    before the test's fixtures, module-scoped ones included, are made."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker is not None and len(CORES) > 1:
        browser = item.get_closest_marker("browser") is not None
        mine = CORES if browser else [CORES[int(worker.removeprefix("gw")) % len(CORES)]]
        os.sched_setaffinity(0, mine)
