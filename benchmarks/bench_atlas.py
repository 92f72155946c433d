"""``python -m benchmarks.bench atlas``: what a plan atlas costs and what it buys.

Builds fig. 4's planner's atlas (:mod:`corrections_sim.plans.atlas`) over the study's prior
box (θ̂⁰ ± ``width`` sd, ``count`` points a weight) for the first ``envs`` paper environments on
a process pool, then draws off-grid problems (θ ~ U[−range, range]^k, a random environment of
those) and compares, against the best of ``restarts`` random restarts:

* the figure's planner from its cold starts (what a fresh plan book answers),
* the atlas's answer (:meth:`~corrections_sim.plans.atlas.Atlas.solve`: warm from the
  corner plan best at θ, what a study with ``atlas`` plans), and
* the atlas's every corner: warm from each distinct corner plan, the best kept.

Prints the build's wall and CPU time, solves, size on disk and in memory, and the fraction of
problems within 1% of the restarts' best; it never asserts.

With ``lazy``, the same problems are also answered by a coarse-to-fine construction (what a
lazily built atlas could be; docs/atlas.md, "Toward a lazy atlas"): a grid of every other
node, (count + 1) / 2 points a weight, built in full as today; each node of the full grid
between its nodes solved once, warm from its parent cell's corner best at its θ (the next if
that fails), only where a problem's cell asks for it; the problem then answered from those
nodes as ``Atlas.solve`` answers.

:func:`run_study` (``--study FILE``) makes the same comparison for a study's own
atlas (its planner, box and environments, k = 3 included), without building a full finer
grid: a coarse atlas of ``coarse`` points a weight, built in full by continuation; a finer
level of 2·coarse − 1 points whose nodes between the coarse ones are solved only where a
problem's cell asks, once from the parent cell's best corner and once from every corner of
it (the best kept); and the study's own atlas as it is stored. Each against the best of
``restarts`` random restarts, the planner's own answer and every answer here.
"""

from __future__ import annotations

import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.restarts import random_restarts, relative_gap
from corrections_sim.planning.planner import PlannerConfig, PlanningError, shared_planner
from corrections_sim.plans import atlas as A
from corrections_sim.scene.environments import paper_environments

#: Fig. 4's planner (experiments/fig4.toml: four cold starts).
CONFIG = PlannerConfig(n_starts=4)


def _build_one(args) -> tuple[int, A.EnvironmentAtlas, float]:
    index, grid, cold_stride = args
    planner = shared_planner(CONFIG)
    t0 = time.process_time()
    built = A.build(planner, paper_environments()[index], grid, cold_stride=cold_stride)
    return index, built, time.process_time() - t0


@dataclass(frozen=True)
class AtlasBench:
    grid: A.AtlasGrid
    envs: int
    build_wall: float
    build_cpu: float
    solves: int
    missing: int
    bytes_per_env: int
    gaps_planner: np.ndarray
    gaps_atlas: np.ndarray
    atlas_solves: float
    gaps_answer: np.ndarray
    answer_ms: float
    nodes_below: int
    nodes_sampled: int
    gaps_lazy: np.ndarray | None = None
    lazy_build_cpu: float = 0.0
    lazy_nodes: int = 0
    lazy_node_cpu: float = 0.0
    lazy_builds: int = 0


class CoarseToFine:
    """The coarse-to-fine construction of the module docstring, for one planner and grid: the
    coarse grid is an :class:`~corrections_sim.plans.atlas.Atlas` of its own (built in memory
    on first use); the full grid's nodes are filled in as problems ask for them, each the
    coarse atlas's answer there (:meth:`Atlas.solve`), and a problem is answered by
    :meth:`Atlas.solve` over those nodes.

    Raises:
        ValueError: a grid whose every other node is not a grid (an even count, or < 5).
    """

    def __init__(
        self,
        planner,
        grid: A.AtlasGrid,
        cold_stride: int,
        every_corner: bool = False,
        coarse: A.Atlas | None = None,
    ) -> None:
        if any(n % 2 == 0 or n < 5 for n in grid.counts):
            raise ValueError(
                f"--lazy: --grid must be odd and >= 5 (the coarse grid is every other node), "
                f"got {grid.counts[0]}"
            )
        counts = tuple((n + 1) // 2 for n in grid.counts)
        #: The coarse level (given: one already built, shared; else built on first use).
        self.coarse = (
            coarse
            if coarse is not None
            else A.Atlas(
                planner, A.AtlasGrid(grid.lows, grid.highs, counts), cold_stride=cold_stride
            )
        )
        self.fine = A.Atlas(planner, grid, cold_stride=cold_stride)
        self.thetas = grid.thetas()
        self.asked: dict[bytes, set[int]] = {}  # per environment, the full grid's nodes filled
        self.build_cpu = self.node_cpu = 0.0
        #: Fill a node from every distinct corner plan of its coarse cell, the best kept
        #: (else from the best corner at its θ, the next only if that fails).
        self.every_corner = every_corner

    def _fill(self, env, node: int) -> None:
        """The full grid's ``node`` in ``env``: a coarse node's own plan, else the coarse
        atlas's answer there (left NaN where no start converges)."""
        held = self.fine.environment(env)
        coarse = self.coarse.environment(env)
        at = np.unravel_index(node, self.fine.grid.counts)
        if all(i % 2 == 0 for i in at):
            c = int(np.ravel_multi_index(tuple(i // 2 for i in at), self.coarse.grid.counts))
            trajectory, phi, smooth = (
                coarse.trajectories[c],
                coarse.features[c],
                coarse.smoothness[c],
            )
            reward = coarse.rewards[c]
        else:
            try:
                plan = (self._every if self.every_corner else self.coarse.solve)(
                    self.thetas[node], env
                )
            except PlanningError:
                return
            trajectory, phi, reward = plan.trajectory, plan.features, plan.reward
            smooth = A.smoothness_cost(trajectory)
        held.trajectories[node], held.features[node] = trajectory, phi
        held.smoothness[node], held.rewards[node] = smooth, reward

    def _every(self, theta: np.ndarray, env):
        """θ's plan from each distinct corner plan of its coarse cell, the best kept (the
        planner's cold starts where none converges)."""
        planner, plans = self.fine.planner, []
        for start in A.cell_starts(self.coarse.environment(env), theta, planner.config.smoothness):
            try:
                plans.append(planner.solve(theta, env, inits=[start]))
            except PlanningError:
                continue
        if not plans:
            return planner.solve(theta, env)
        return max(plans, key=lambda p: p.reward)

    def solve(self, theta: np.ndarray, env) -> float:
        """The reward of θ's answer (−inf where nothing converges)."""
        asked = self.asked.get(env.key())
        if asked is None:
            t0 = time.process_time()
            self.coarse.environment(env)  # the coarse grid, built in full
            self.build_cpu += time.process_time() - t0
            n, k, T = self.fine.grid.size, self.fine.grid.k, self.fine.planner.config.n_waypoints
            empty = A.EnvironmentAtlas(
                self.fine.grid,
                np.full((n, T, 7), np.nan),
                np.full((n, k), np.nan),
                np.full(n, np.nan),
                np.full(n, -np.inf),
                0,
            )
            self.fine.hold(env, empty)
            asked = self.asked[env.key()] = set()
        if self.fine.grid.contains(theta):
            t0 = time.process_time()
            for node in self.fine.grid.cell(theta):
                if node not in asked:
                    asked.add(node)
                    self._fill(env, node)
            self.node_cpu += time.process_time() - t0
        try:
            return self.fine.solve(theta, env).reward
        except PlanningError:
            return -np.inf

    @property
    def nodes(self) -> int:
        """Full-grid nodes filled in, over every environment."""
        return sum(len(a) for a in self.asked.values())

    @property
    def builds(self) -> int:
        return len(self.asked)


def run(
    envs: int = 48,
    count: int = 31,
    width: float = 5.0,
    problems: int = 200,
    restarts: int = 30,
    theta_range: float = 2.0,
    cold_stride: int = 10,
    workers: int = 2,
    seed: int = 0,
    lazy: bool = False,
) -> AtlasBench:
    grid = A.AtlasGrid.around([0.0, 0.0], [1.0, 1.0], width=width, count=count)
    planner = shared_planner(CONFIG)
    fine = CoarseToFine(planner, grid, cold_stride) if lazy else None  # bad input before work
    indices = list(range(envs))
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=workers) as pool:
        built = sorted(pool.map(_build_one, [(i, grid, cold_stride) for i in indices]))
    wall = time.perf_counter() - t0
    atlases = {i: a for i, a, _ in built}
    all_envs = paper_environments()
    rng = np.random.default_rng(seed)
    gaps_planner, gaps_atlas, used, gaps_answer, answer_cpu = [], [], [], [], 0.0
    answering = A.Atlas(planner, grid, cold_stride=cold_stride)
    gaps_lazy = []
    for i, built_atlas in atlases.items():
        answering.hold(all_envs[i], built_atlas)
    for _ in range(problems):
        theta = rng.uniform(-theta_range, theta_range, 2)
        i = int(rng.choice(indices))
        env = all_envs[i]
        starts = random_restarts(env, CONFIG.n_waypoints, restarts, rng)
        try:
            best = planner.solve(theta, env, inits=starts).reward
        except PlanningError:
            continue
        try:
            own = planner.solve(theta, env).reward
        except PlanningError:
            own = -np.inf
        rewards, n = [], 0
        for start in A.cell_starts(atlases[i], theta, CONFIG.smoothness):
            n += 1
            try:
                rewards.append(planner.solve(theta, env, inits=[start]).reward)
            except PlanningError:
                continue
        used.append(n)
        t1 = time.process_time()
        try:
            answer = answering.solve(theta, env).reward
        except PlanningError:
            answer = -np.inf
        answer_cpu += time.process_time() - t1
        gaps_answer.append(relative_gap(best, answer))
        if fine is not None:
            gaps_lazy.append(relative_gap(best, fine.solve(theta, env)))
        gaps_planner.append(relative_gap(best, own))
        gaps_atlas.append(relative_gap(best, max(rewards, default=-np.inf)))
    # Global at its nodes? Sampled nodes against the planner's own cold starts there.
    nodes = grid.thetas()
    below, sampled = 0, 0
    for _ in range(problems):
        i = int(rng.choice(indices))
        node = int(rng.integers(grid.size))
        if not atlases[i].found[node]:
            continue
        try:
            own = planner.solve(nodes[node], all_envs[i]).reward
        except PlanningError:
            continue
        sampled += 1
        below += relative_gap(own, atlases[i].rewards[node]) > 1e-6
    return AtlasBench(
        grid,
        envs,
        wall,
        sum(c for _, _, c in built),
        sum(a.solves for a in atlases.values()),
        sum(int((~a.found).sum()) for a in atlases.values()),
        grid.size * CONFIG.n_waypoints * 7 * 8,
        np.array(gaps_planner),
        np.array(gaps_atlas),
        float(np.mean(used)) if used else 0.0,
        np.array(gaps_answer),
        1000 * answer_cpu / max(len(gaps_answer), 1),
        below,
        sampled,
        np.array(gaps_lazy) if fine is not None else None,
        fine.build_cpu if fine is not None else 0.0,
        fine.nodes if fine is not None else 0,
        fine.node_cpu if fine is not None else 0.0,
        fine.builds if fine is not None else 0,
    )


def run_study(
    study,
    coarse: int = 7,
    problems: int = 200,
    restarts: int = 30,
    seed: int = 65,
    workers: int = 2,
) -> list[str]:
    """The comparison of the module docstring for ``study``'s atlas (a path to a study file
    with ``atlas``): θ uniform over its whole box, environments uniform over its own; the
    report's lines.

    Raises:
        ValueError: a study without an atlas, or ``coarse`` < 3.
    """
    from dataclasses import replace

    from corrections_sim.plans import spread
    from corrections_sim.study.schema import load_study

    if isinstance(coarse, bool) or not isinstance(coarse, int) or coarse < 3:
        raise ValueError(f"--coarse {coarse!r}: a coarse grid needs >= 3 points a weight")
    settings = load_study(study, name=Path(study).stem, quick=False)
    spec = settings.atlas_spec()
    if spec is None:
        raise ValueError(f"--study {study}: the study has no plan atlas")
    k = spec.grid.k
    lows, highs = np.array(spec.grid.lows), np.array(spec.grid.highs)
    coarse_spec = replace(spec, grid=A.AtlasGrid(spec.grid.lows, spec.grid.highs, (coarse,) * k))
    envs = list({e.key(): e for e in settings.envs()}.values())
    t0, c0 = time.perf_counter(), _children_cpu()
    with ProcessPoolExecutor(max_workers=workers) as pool:
        built = spread.prepare(coarse_spec, envs, pool)
    build_wall, build_cpu = time.perf_counter() - t0, _children_cpu() - c0
    planner = shared_planner(spec.config)
    fine_grid = A.AtlasGrid(spec.grid.lows, spec.grid.highs, (2 * coarse - 1,) * k)
    answers = {
        f"the study's atlas ({spec.grid.counts[0]} points, built in full)": spec.atlas(),
        f"coarse ({coarse} points, built in full)": coarse_spec.atlas(),
    }
    lazy = {
        f"finer level ({2 * coarse - 1} points), lazily, {how}": CoarseToFine(
            planner, fine_grid, spec.cold_stride, every, coarse=coarse_spec.atlas()
        )
        for how, every in (("best corner", False), ("every corner", True))
    }
    rng = np.random.default_rng(seed)
    gaps: dict[str, list[float]] = {name: [] for name in [*answers, *lazy, "planner's own"]}
    for _ in range(problems):
        theta = lows + rng.uniform(size=k) * (highs - lows)
        env = envs[int(rng.integers(len(envs)))]
        rewards: dict[str, float] = {}
        for name, atlas in answers.items():
            try:
                rewards[name] = atlas.solve(theta, env).reward
            except PlanningError:
                rewards[name] = -np.inf
        for name, fine in lazy.items():
            rewards[name] = fine.solve(theta, env)
        try:
            rewards["planner's own"] = planner.solve(theta, env).reward
        except PlanningError:
            rewards["planner's own"] = -np.inf
        starts = random_restarts(env, spec.config.n_waypoints, restarts, rng)
        try:
            best = planner.solve(theta, env, inits=starts).reward
        except PlanningError:
            best = -np.inf
        best = max(best, *rewards.values())
        if not np.isfinite(best):
            continue
        for name, value in rewards.items():
            gaps[name].append(relative_gap(best, value))
    box = f"{[round(float(v), 2) for v in lows]} .. {[round(float(v), 2) for v in highs]}"
    lines = [
        f"atlas levels of {study}: {len(envs)} environments, k = {k}, box {box}; {problems} "
        f"problems (seed {seed}), theta uniform over the box, against the best of {restarts} "
        "random restarts and every answer here",
        f"  coarse level, {coarse} points a weight: {built} environments built in "
        f"{build_wall:.0f} s wall, {build_cpu:.0f} s CPU ({workers} workers; 0: on disk)",
    ]
    for name, values in gaps.items():
        g = np.array(values)
        found = g[np.isfinite(g)]
        lines.append(
            f"  {name}: within 1% on {100 * np.mean(g <= 0.01):.1f}% of {len(g)}, within "
            f"1e-6 on {100 * np.mean(g <= 1e-6):.1f}%, no plan on {int((~np.isfinite(g)).sum())}"
            f", worst gap where a plan {100 * found.max(initial=0.0):.1f}%"
        )
    for name, fine in lazy.items():
        lines.append(
            f"  {name}: {fine.nodes} nodes asked for, "
            f"{1000 * fine.node_cpu / max(fine.nodes, 1):.1f} ms CPU each"
        )
    return lines


def _children_cpu() -> float:
    """CPU seconds of this process's finished children (a process pool's workers)."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def report(b: AtlasBench) -> list[str]:
    g = b.grid
    box = " × ".join(f"[{lo:g}, {hi:g}]" for lo, hi in zip(g.lows, g.highs, strict=True))
    within = lambda gaps: f"{100 * np.mean(gaps <= 0.01):.1f}%"  # noqa: E731
    worst = lambda gaps: f"{100 * np.max(gaps):.1f}%"  # noqa: E731
    return [
        f"atlas of fig. 4's planner: {b.envs} environments, {' × '.join(map(str, g.counts))} "
        f"nodes over {box}",
        f"  build: {b.build_wall:.1f} s wall, {b.build_cpu:.1f} s CPU, {b.solves} solves "
        f"({b.solves / (b.envs * g.size):.1f} a node), {b.missing} nodes without a plan",
        f"  size: {b.bytes_per_env / 1e6:.2f} MB of trajectories an environment, "
        f"{b.envs * b.bytes_per_env / 1e6:.1f} MB in all (on disk and memory-mapped)",
        f"  {len(b.gaps_atlas)} off-grid problems against the best of the random restarts:",
        f"    planner's cold starts: within 1% on {within(b.gaps_planner)}, "
        f"worst gap {worst(b.gaps_planner)}",
        f"    atlas's answer (the best corner's plan, {b.answer_ms:.2f} ms CPU a problem): "
        f"within 1% on {within(b.gaps_answer)}, worst gap {worst(b.gaps_answer)}  "
        "(target: >= 99%)",
        f"    every corner of the cell ({b.atlas_solves:.2f} warm solves a problem): within 1% "
        f"on {within(b.gaps_atlas)}, worst gap {worst(b.gaps_atlas)}",
        f"  nodes below the planner's own cold starts there: {b.nodes_below} of "
        f"{b.nodes_sampled} sampled",
        *_lazy_lines(b, within, worst),
    ]


def _lazy_lines(b: AtlasBench, within, worst) -> list[str]:
    if b.gaps_lazy is None:
        return []
    coarse = " × ".join(str((n + 1) // 2) for n in b.grid.counts)
    return [
        f"  coarse to fine ({coarse} built in full, finer nodes from their parents): within 1% "
        f"on {within(b.gaps_lazy)}, worst gap {worst(b.gaps_lazy)}",
        f"    its coarse builds {b.lazy_build_cpu / max(b.lazy_builds, 1):.2f} s CPU an "
        f"environment ({b.lazy_builds}); {b.lazy_nodes} nodes of the full grid "
        f"asked for, {1000 * b.lazy_node_cpu / max(b.lazy_nodes, 1):.1f} ms CPU each",
    ]
