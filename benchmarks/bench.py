"""Benchmarks: ``python -m benchmarks.bench planner`` (the trajectory optimizer, here) and
``python -m benchmarks.bench fig4`` (a whole figure, :mod:`benchmarks.bench_batch`).

Solves a fixed, seeded set of (θ, E) problems in the ways the rest of the program does
(cold, default multi-start, warm from a nearby θ), compares the default solve with the best of
many random restarts, and a subset with SciPy's SLSQP on numeric features and finite
differences. It prints a table with targets beside the measured values; it never asserts.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from benchmarks.restarts import random_restarts, relative_gap
from benchmarks.sizes import set_options, study_overrides
from corrections_sim.planning.features import feature_counts
from corrections_sim.planning.planner import (
    SOLVERS,
    WARM_MODES,
    Plan,
    Planner,
    PlannerConfig,
    PlanningError,
    clearance,
    smoothness_cost,
)
from corrections_sim.scene.environments import Environment, paper_environments
from corrections_sim.scene.robot import N_ARM_JOINTS, joint_limits

#: Every benchmark, by the name the command line gives it.
SUBCOMMANDS = (
    "planner",
    "fig4",
    "interact",
    "warm",
    "physical",
    "relevance",
    "learnt",
    "confidence",
    "study",
    "questionnaire",
    "catch",
    "atlas",
    "particles",
    "exact",
    "split",
    "main",
)

#: A figure's study at a tiny size: its atlas at 3 points a weight (the paper's 31 would be
#: built first on a fresh machine), its first 2 paper environments.
SMALL = ("--grid", "3", "--study-envs", "2")

#: Each benchmark at its smallest size (``--tiny``): what the tests run, so that none rots
#: unnoticed; the numbers it prints mean nothing. A figure's plan atlas shrinks to 3 points a
#: weight, the first 2 of its environments (:data:`SMALL`).
TINY: dict[str, list[str]] = {
    "planner": ["--problems", "1", "--restarts", "1", "--solvers", "fatrop"],
    "fig4": ["--skip-full", "--slice-runs", "1", "--iterations", "1", *SMALL],
    "interact": ["--corrections", "1", "--learners", "KF-C", *SMALL],
    "warm": ["--problems", "2", "--iterations", "2"],
    "physical": ["--problems", "1"],
    "relevance": ["--problems", "1", "--learners", "KF-C", *SMALL],
    "learnt": ["--problems", "2"],
    "confidence": ["--problems", "1", "--learners", "KF-CI", "--iterations", "2", *SMALL],
    "study": ["--problems", "1", *SMALL],
    "questionnaire": ["--problems", "1"],
    "catch": ["--problems", "1"],
    "atlas": ["--envs", "1", "--grid", "5", "--problems", "1", "--restarts", "1", "--lazy"],
    "particles": ["--particles", "20", "--problems", "1", "--envs", "1", "--moves", "1", *SMALL],
    "exact": ["--problems", "1", "--iterations", "2", "--learners", "EX-C", *SMALL],
    "split": ["--slice-runs", "1", "--iterations", "1", "--learners", "KF,EX-C", *SMALL],
    "main": ["--quick", "--learners", "KF,EX-M", "--iterations", "1", *SMALL, "--keep-compiled"],
}

THETA_RANGE = (-1.5, 1.5)
WARM_THETA_STEP = 0.05  # std of the θ perturbation a warm start comes from


@dataclass(frozen=True)
class Problem:
    """One benchmark problem: weights θ (k,) and the index of a paper environment."""

    theta: np.ndarray
    env_index: int


@dataclass(frozen=True)
class Outcome:
    """One solve: wall time (s), IPOPT iterations of the kept start, reward; ``error`` is
    ``"planning"`` for a PlanningError, the exception's repr for anything else, else None."""

    time: float
    iterations: int = 0
    reward: float = float("nan")
    error: str | None = None


def make_problems(
    n: int, k: int, n_envs: int, rng: np.random.Generator, theta_range=THETA_RANGE
) -> list[Problem]:
    """``n`` problems: θ uniform in ``theta_range``^k, environment index uniform."""
    thetas = rng.uniform(*theta_range, size=(n, k))
    indices = rng.integers(0, n_envs, size=n)
    return [Problem(t, int(i)) for t, i in zip(thetas, indices, strict=True)]


def timed(solve: Callable[[], Plan]) -> tuple[Outcome, Plan | None]:
    """Run one solve, timing it and classifying its failure instead of raising."""
    t0 = time.perf_counter()
    try:
        plan = solve()
    except PlanningError:
        return Outcome(time.perf_counter() - t0, error="planning"), None
    except Exception as exc:  # noqa: BLE001 - the benchmark counts, it does not crash
        return Outcome(time.perf_counter() - t0, error=repr(exc)), None
    return Outcome(time.perf_counter() - t0, plan.iterations, plan.reward), plan


def percentiles(values: Sequence[float]) -> tuple[float, float]:
    """(median, 95th percentile) of the finite values; NaN when there are none."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan"), float("nan")
    return float(np.median(v)), float(np.percentile(v, 95))


@dataclass(frozen=True)
class SlsqpResult:
    """SLSQP's solve: wall time (s), iterations, reward, smallest constraint value, success."""

    time: float
    iterations: int
    reward: float
    min_clearance: float
    success: bool


def solve_slsqp(
    theta: np.ndarray, env: Environment, config: PlannerConfig, init: np.ndarray
) -> SlsqpResult:
    """The same problem with SciPy SLSQP: numeric features, finite-difference gradients.

    Objective −(θ·Φ − λS) over the T − 2 free waypoints, joint-limit bounds, and the planner's
    hard constraints (smallest table gap and laptop keep-out level per waypoint, via
    ``planner.clearance``) as inequalities ≥ 0.
    """
    from scipy.optimize import minimize

    T = config.n_waypoints
    params = env.params()

    def path(x: np.ndarray) -> np.ndarray:
        return np.vstack([env.q_start, x.reshape(T - 2, N_ARM_JOINTS), env.q_goal])

    def cost(x: np.ndarray) -> float:
        xi = path(x)
        phi = feature_counts(xi, params, config.features)
        return -(theta @ phi - config.smoothness * smoothness_cost(xi))

    def constraints(x: np.ndarray) -> np.ndarray:
        return np.concatenate([clearance(q, env) for q in x.reshape(T - 2, N_ARM_JOINTS)])

    lo, hi = joint_limits()
    bounds = list(zip(np.tile(lo, T - 2), np.tile(hi, T - 2), strict=True))
    t0 = time.perf_counter()
    res = minimize(
        cost,
        init[1:-1].ravel(),
        method="SLSQP",
        bounds=bounds,
        constraints=[{"type": "ineq", "fun": constraints}],
        options={"maxiter": 500, "ftol": 1e-9},
    )
    elapsed = time.perf_counter() - t0
    return SlsqpResult(
        elapsed, int(res.nit), float(-res.fun), float(constraints(res.x).min()), bool(res.success)
    )


# --- the planner benchmark -------------------------------------------------------------------

MODES = ("cold", "default", "warm")
MODE_TITLES = {
    "cold": "cold (straight line, 1 start)",
    "default": "default (config n_starts)",
    "warm": "warm (from nearby theta)",
}


@dataclass(frozen=True)
class PlannerBench:
    """Raw measurements over the problem set (one entry per problem, same order).

    ``runs[solver][mode]`` holds each solver's outcomes in each of :data:`MODES`, measured
    side by side (every problem is solved by every solver before the next problem).
    """

    runs: dict[str, dict[str, list[Outcome]]]
    best_restart: list[float]  # best reward over the random restarts, NaN if none converged
    restart_errors: int  # problems where no random restart converged
    slsqp: list[SlsqpResult]
    slsqp_default: list[Outcome]  # the first solver's default solves of the SLSQP subset
    problems: tuple[Problem, ...] = ()


def run_planner_bench(
    planners: dict[str, Planner],
    envs: Sequence[Environment],
    problems: Sequence[Problem],
    *,
    n_restarts: int,
    n_slsqp: int,
    rng: np.random.Generator,
    progress: Callable[[str], None] = lambda _: None,
) -> PlannerBench:
    """Measure every solver in every mode on every problem (SLSQP on the first ``n_slsqp``).

    The warm start of a problem comes from the same solver's solve of a nearby θ (one draw
    per problem, shared by the solvers). The random restarts run on the first planner.
    """
    first = next(iter(planners.values()))
    T = first.config.n_waypoints
    runs = {name: {mode: [] for mode in MODES} for name in planners}
    best_restart = []
    restart_errors = 0
    for n, prob in enumerate(problems):
        env, theta = envs[prob.env_index], prob.theta
        line = random_restarts(env, T, 1, rng)  # the straight joint-space line
        nearby = theta + rng.normal(0.0, WARM_THETA_STEP, theta.shape)
        for name, planner in planners.items():
            out = runs[name]
            out["cold"].append(timed(partial(planner.solve, theta, env, inits=line))[0])
            out["default"].append(timed(partial(planner.solve, theta, env))[0])
            _, previous = timed(partial(planner.solve, nearby, env))
            inits = [previous.trajectory] if previous is not None else line
            out["warm"].append(timed(partial(planner.solve, theta, env, inits=inits))[0])
        restarts = random_restarts(env, T, n_restarts, rng)
        outcome, _ = timed(partial(first.solve, theta, env, inits=restarts))
        restart_errors += outcome.error is not None
        best_restart.append(outcome.reward)
        if (n + 1) % 10 == 0:
            progress(f"  {n + 1}/{len(problems)} problems")
    slsqp, slsqp_default = [], []
    for n, prob in enumerate(problems[:n_slsqp]):
        env = envs[prob.env_index]
        # the planner timed again right beside SLSQP, so load from other processes hits both
        slsqp_default.append(timed(partial(first.solve, prob.theta, env))[0])
        slsqp.append(solve_slsqp(prob.theta, env, first.config, random_restarts(env, T, 1, rng)[0]))
        progress(f"  SLSQP {n + 1}/{n_slsqp}: {slsqp[-1].time:.2f} s")
    return PlannerBench(runs, best_restart, restart_errors, slsqp, slsqp_default, tuple(problems))


def _failures(outcomes: Sequence[Outcome]) -> tuple[int, int]:
    planning = sum(o.error == "planning" for o in outcomes)
    other = sum(o.error is not None and o.error != "planning" for o in outcomes)
    return planning, other


def _verdict(ok: bool) -> str:
    return "PASS" if ok else "MISS"


def optimality(bench: PlannerBench, outcomes: Sequence[Outcome]) -> tuple[np.ndarray, float]:
    """Relative gaps of ``outcomes`` to the best known reward of each problem (the best of the
    random restarts and of every solver's default and cold solves), and the fraction of
    problems within 1% (a failed solve counts as outside)."""
    best = np.array(bench.best_restart, float)
    for modes in bench.runs.values():
        for mode in ("cold", "default"):
            best = np.fmax(best, [o.reward for o in modes[mode]])
    gaps = np.array([relative_gap(b, o.reward) for b, o in zip(best, outcomes, strict=True)])
    known = np.isfinite(best)
    within = float(np.mean(np.nan_to_num(gaps[known], nan=np.inf) <= 0.01))
    return gaps[known & np.isfinite(gaps)], within


def by_quadrant(bench: PlannerBench, outcomes: Sequence[Outcome]) -> list[str]:
    """Table rows: per sign quadrant of (θ_0, θ_1), the share of problems within 1% of the
    best known reward (as :func:`optimality`) and the worst gap."""
    best = np.array(bench.best_restart, float)
    for modes in bench.runs.values():
        for mode in ("cold", "default"):
            best = np.fmax(best, [o.reward for o in modes[mode]])
    gaps = np.array([relative_gap(b, o.reward) for b, o in zip(best, outcomes, strict=True)])
    gaps = np.nan_to_num(gaps, nan=np.inf)
    signs = np.array([np.sign(p.theta[:2]) for p in bench.problems])
    rows = []
    for s0 in (1, -1):
        for s1 in (1, -1):
            mask = (signs[:, 0] == s0) & (signs[:, 1] == s1) & np.isfinite(best)
            if not mask.any():
                continue
            rows.append(
                f"| {'+' if s0 > 0 else '−'} | {'+' if s1 > 0 else '−'} | {mask.sum()} | "
                f"{100 * np.mean(gaps[mask] <= 0.01):.1f}% | {100 * gaps[mask].max():.2f}% |"
            )
    return rows


def report_planner_bench(bench: PlannerBench) -> list[str]:
    """The printed table, as lines."""
    names = list(bench.runs)
    lines = [
        f"{'solver':<8}{'mode':<32}{'median':>10}{'p95':>10}{'ratio*':>8}{'iters med':>10}"
        f"{'iters p95':>10}{'within 1%':>11}{'worst gap':>10}{'PlanningErr':>12}{'other':>7}"
    ]
    medians = {
        (name, mode): percentiles([1e3 * o.time for o in out if o.error is None])[0]
        for name, modes in bench.runs.items()
        for mode, out in modes.items()
    }
    within: dict[tuple[str, str], float] = {}
    for mode in MODES:
        for name in names:
            outcomes = bench.runs[name][mode]
            ok = [o for o in outcomes if o.error is None]
            t_p95 = percentiles([1e3 * o.time for o in ok])[1]
            i_med, i_p95 = percentiles([o.iterations for o in ok])
            planning, other = _failures(outcomes)
            gaps, within[name, mode] = optimality(bench, outcomes)
            ratio = medians.get(("ipopt", mode), float("nan")) / medians[name, mode]
            lines.append(
                f"{name:<8}{MODE_TITLES[mode]:<32}{medians[name, mode]:>8.2f}ms{t_p95:>8.2f}ms"
                f"{ratio:>7.2f}x{i_med:>10.0f}{i_p95:>10.0f}{100 * within[name, mode]:>10.1f}%"
                f"{100 * max(gaps, default=np.nan):>9.2f}%{planning:>12d}{other:>7d}"
            )
    lines += [
        "  times: wall time of planner.solve (solver + MuJoCo check of the result + features)",
        "  * ratio: IPOPT's median time / this solver's, same mode, timed side by side",
        "  iterations of the kept start (fatrop's, or IPOPT's where it was the fallback)",
        f"  within 1%: of the best known reward per problem (best of "
        f"{len(bench.best_restart)} problems' random restarts and every solver's own solves; "
        f"{bench.restart_errors} problems with no converged restart); failures count as outside",
        "",
    ]

    default = names[0]
    if bench.problems:
        lines += [
            f"{default} default solve by sign quadrant of (theta_0, theta_1):",
            "| theta_0 | theta_1 | problems | within 1% | worst gap |",
            "|---|---|---|---|---|",
            *by_quadrant(bench, bench.runs[default]["default"]),
            "",
        ]
    if bench.slsqp:
        slsqp_t = [r.time for r in bench.slsqp]
        planner_t = [o.time for o in bench.slsqp_default if o.error is None]
        s_med = percentiles(slsqp_t)[0]
        ratio = s_med / percentiles(planner_t)[0]
        rel = [
            relative_gap(o.reward, r.reward)
            for r, o in zip(bench.slsqp, bench.slsqp_default, strict=True)
            if o.error is None
        ]
        lines += [
            f"SciPy SLSQP (numeric FK/features, finite differences) on {len(bench.slsqp)} "
            "problems:",
            f"  median time {s_med:.2f} s (p95 {percentiles(slsqp_t)[1]:.2f} s), median "
            f"iterations {percentiles([r.iterations for r in bench.slsqp])[0]:.0f}, "
            f"converged {sum(r.success for r in bench.slsqp)}/{len(bench.slsqp)}, "
            f"min constraint {min((r.min_clearance for r in bench.slsqp), default=np.nan):+.4f}",
            f"  speed ratio SLSQP / {default} default (medians over the same problems, timed "
            f"side by side): {ratio:.0f}x",
            f"  SLSQP reward relative to {default} default, ({default} − slsqp)/|{default}| "
            "(> 0: SLSQP worse): " + ", ".join(f"{100 * v:+.2f}%" for v in rel),
            "",
        ]

    everything = [o for modes in bench.runs.values() for out in modes.values() for o in out]
    unhandled = sum(o.error is not None and o.error != "planning" for o in everything)
    targets = [
        (
            f"{default} warm median <= 4 ms",
            f"{medians[default, 'warm']:.2f} ms",
            medians[default, "warm"] <= 4.0,
        ),
        (
            f"{default} cold median <= 10 ms",
            f"{medians[default, 'cold']:.2f} ms",
            medians[default, "cold"] <= 10.0,
        ),
        (
            f"{default} default within 1% on >= 98%",
            f"{100 * within[default, 'default']:.1f}%",
            within[default, "default"] >= 0.98,
        ),
        ("0 unhandled failures", f"{unhandled}", unhandled == 0),
    ]
    if "ipopt" in names and default != "ipopt":
        for mode in ("warm", "default"):
            r = medians["ipopt", mode] / medians[default, mode]
            targets.append((f"{default} {mode} faster than ipopt", f"{r:.2f}x", r > 1.0))
    if bench.slsqp:
        targets.append((">= 100x faster than SLSQP", f"{ratio:.0f}x", ratio >= 100))
    lines.append(f"{'target':<40}{'measured':>12}  verdict")
    lines += [f"{name:<40}{value:>12}  {_verdict(ok)}" for name, value, ok in targets]
    lines += [
        f"  unhandled: {e}" for e in sorted({o.error for o in everything} - {None, "planning"})
    ]
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.bench",
        description="Benchmarks of corrections_sim. 'planner': solve times, iterations, "
        "failures and optimality of the trajectory optimizer over seeded (theta, E) problems. "
        "'fig4': wall time of paper-scale fig. 4, solves per second, 1 -> 2 worker speed-up, "
        "Dask against the process pool, peak memory per worker. 'interact': the page's "
        "latency from submit to the next plan, driven in chromium by Playwright. 'warm': "
        "warm re-solves captured from fig. 4 runs, in each warm mode (Newton, solver). "
        "'physical': the arm's real-time factor, sensing against the applied push, one "
        "physical correction end to end. 'relevance': the relevance study's learners' cost "
        "per correction (seconds, planner solves). 'learnt': training a learnt feature, "
        "planning with it against the hand-written feature it imitates, a new one's cost. "
        "'confidence': the iterated and particle learners' cost per correction against "
        "KF-C's in figs. 4 and 5 (CPU seconds, planner solves). 'study': several participants "
        "at once on one study server (scripted websocket clients submitting together): "
        "server submit -> next plan, and each one's isolation. 'questionnaire': the raw "
        "NASA-TLX answered in chromium as fast as the page takes input, and whether every value "
        "set reaches the log (--problems questionnaires, default 20). 'catch': how often a "
        "hand catches the moving handle on the physical page, against a binomial bar "
        "(--problems tries, default 62). 'atlas': the plan atlas of fig. 4's planner over "
        "its prior box (build time, size) and its plans' optimality against random restarts "
        "(--problems off-grid problems, default 200; --envs, --grid). 'particles': PF-C's "
        "likelihood read off fig. 4's atlas against solved plans (accuracy in --envs "
        "environments, default 4) and its CPU a correction (--problems runs, default 4; "
        "--particles, default 2000; --bound in noise sd, default 0.02). 'exact': an exact "
        "learner's update (EX-C, EX-CL, EX-M) on fig. 4's atlas (or --study FILE's), CPU s "
        "a correction (median, p90) in a fresh process with an empty store of plans "
        "between the atlas's nodes and then a full one (--problems runs, default 3; "
        "--iterations; --learners). 'split': where a study's CPU goes, learner by learner "
        "(fig. 4 or --study FILE at paper settings; --slice-runs runs of each, default 8): a "
        "run, its regret metric, the learner's update, solves, and the study's runs at that "
        "rate. 'main': the README's run fig4 in a fresh process from an empty cache (gcc "
        "builds, atlas), then with everything cached but the runs: wall, CPU, max RSS, the "
        "wall split around the runs, and whether the two curves are byte-identical.",
    )
    parser.add_argument(
        "what",
        choices=list(SUBCOMMANDS),
        help="which benchmark to run",
    )
    parser.add_argument(
        "--envs", type=int, default=48, help="atlas: the first N paper environments (default 48)"
    )
    parser.add_argument(
        "--grid",
        type=int,
        help="atlas: points a weight (default 31); confidence, exact, particles, fig4, interact, "
        "study, relevance: "
        "the study's plan atlas at N points a weight (default the study's own)",
    )
    parser.add_argument(
        "--study",
        help="exact: a study file with a plan atlas to time instead of fig. 4 (e.g. "
        "experiments/three_features.toml), its learners' parameters as it gives them; atlas: "
        "its atlas, a coarse level and a lazily solved finer one against random restarts",
    )
    parser.add_argument(
        "--coarse",
        type=int,
        default=7,
        help="atlas --study: points a weight of the coarse level built in full (default 7); "
        "the lazily solved finer level has twice as many cells a weight",
    )
    parser.add_argument(
        "--cluster",
        action="store_true",
        help="exact: the plans between the atlas's nodes two Dask workers with caches of their "
        "own solve, without and with the plan exchange, instead of the update's CPU time",
    )
    parser.add_argument(
        "--pool",
        action="store_true",
        help="exact: the same on a process pool of two workers sharing one store",
    )
    parser.add_argument(
        "--study-envs",
        type=int,
        help="confidence, exact, particles, fig4, interact, study, relevance: the study's "
        "first N paper environments (default: its own)",
    )
    parser.add_argument(
        "--lazy",
        action="store_true",
        help="atlas: the same problems also through a coarse-to-fine construction (every other "
        "node built in full, the others from their parents, where a problem asks; docs/atlas.md)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="main: the figure's quick preset (the tests' size) instead of the paper's",
    )
    parser.add_argument(
        "--tiny",
        action="store_true",
        help="the benchmark at its smallest size, every other option replaced by the tiny "
        "size's (TINY): a check that it still runs, not a measurement (the tests run every "
        "benchmark so)",
    )
    parser.add_argument(
        "--particles", type=int, default=2000, help="particles: PF-C's count (default 2000)"
    )
    parser.add_argument(
        "--moves", type=int, default=2, help="particles: PF-C's Metropolis moves (default 2)"
    )
    parser.add_argument(
        "--bound",
        type=float,
        default=0.02,
        help="particles: the interpolation's error bound in noise sd (default 0.02)",
    )
    parser.add_argument(
        "--learners",
        help="interact: the learners, one session each (default KF-CL,KF-C,BP); relevance: "
        "the learners costed (default KF-C,KF-CR,KF-CRP); confidence: (default "
        "KF-CI,PF-C,AL-C,AL-PF); exact: (default EX-C,EX-CL; EX-M on request)",
    )
    parser.add_argument(
        "--corrections", type=int, default=10, help="interact: corrections per session"
    )
    parser.add_argument(
        "--db",
        help="interact: the sessions' log (default results/interact/bench.sqlite); physical "
        "--page: the session's (default a temporary file)",
    )
    parser.add_argument(
        "--screenshot",
        help="interact: save the page after the first session's last update; physical --page: "
        "after the first push",
    )
    parser.add_argument(
        "--slice-runs",
        type=int,
        default=8,
        help="fig4: runs of PP and KF in the slice for the speed-up and Dask; split: runs of "
        "each learner (default 8)",
    )
    parser.add_argument(
        "--iterations",
        type=int,
        help="fig4, exact, confidence, warm (the captured runs): corrections per run (default: "
        "the paper's 12)",
    )
    parser.add_argument(
        "--skip-full", action="store_true", help="fig4: only the slice, not the paper-scale run"
    )
    parser.add_argument(
        "--local-optima",
        action="store_true",
        help="confidence: also how often PF-C's plans are local optima (best of 10 random "
        "starts, 150 of its plans)",
    )
    parser.add_argument(
        "--keep-compiled",
        action="store_true",
        help="main: the empty cache gets the machine's compiled solvers, so that only the "
        "atlas and plans are made again (the tiny size's: its gcc builds were most of it)",
    )
    parser.add_argument(
        "--build",
        action="store_true",
        help="learnt: also time the first build of a learnt shape's NLP in an empty cache",
    )
    parser.add_argument(
        "--problems",
        type=int,
        help="number of (theta, E) problems (default 60; warm: 300 of those captured); "
        "relevance, confidence: runs per person and learner (default 3)",
    )
    parser.add_argument(
        "--seed", type=int, help="seed of the problem set (default 0; warm: of fig. 4's runs, 7)"
    )
    parser.add_argument(
        "--theta-range",
        type=float,
        default=THETA_RANGE[1],
        help=f"planner: theta uniform in [-R, R]^k (default {THETA_RANGE[1]}; users' studies "
        "meet every sign quadrant, e.g. 2)",
    )
    parser.add_argument(
        "--restarts",
        type=int,
        default=30,
        help="random restarts per problem for the optimality gap (default 30)",
    )
    parser.add_argument(
        "--slsqp",
        type=int,
        default=0,
        help="problems also solved with SciPy SLSQP, the first N of the set (default 0)",
    )
    parser.add_argument(
        "--solvers",
        default=",".join(SOLVERS),
        help=f"planner: the solvers compared, the first one the default (default "
        f"{','.join(SOLVERS)})",
    )
    parser.add_argument(
        "--features",
        default="laptop,table",
        help="planner: the features θ weighs (default laptop,table, as figs. 4-5)",
    )
    parser.add_argument(
        "--n-starts",
        type=int,
        default=4,
        help="planner: initial guesses of a default solve (default 4, as figs. 4-5)",
    )
    parser.add_argument(
        "--solver",
        help="fig4: the solver of the paper-scale run (default: the planner's default)",
    )
    parser.add_argument(
        "--page",
        action="store_true",
        help="physical: also the page in chromium (poses/s, frames/s, let-go -> new path)",
    )
    parser.add_argument(
        "--browser",
        action="store_true",
        help="study: the fourth participant is a chromium tab driven with the mouse",
    )
    parser.add_argument(
        "--pushes", type=int, default=2, help="physical --page: pushes, one a plan (default 2)"
    )
    parser.add_argument(
        "--speed",
        type=float,
        default=0.25,
        help="physical --page: the page's simulated seconds per real second (default 0.25)",
    )
    parser.add_argument(
        "--breakdown",
        action="store_true",
        help="warm: where a fig. 4 run's time goes in each warm mode (--slice-runs runs of "
        "every learner at paper settings, one worker): solves by kind, the rest",
    )
    parser.add_argument(
        "--small-step",
        action="store_true",
        help="warm: time fatrop's small-step options (issue 22) against its defaults, gated "
        "by the start's stationarity residual, instead of the warm paths",
    )
    parser.add_argument(
        "--warm",
        choices=WARM_MODES,
        help="fig4: how warm starts are re-solved (default: the planner's, newton); newton "
        "also times the slice with solver (the reference path), side by side",
    )
    args = parser.parse_args(argv)
    if args.tiny:  # every other option the tiny size's; the flag itself kept
        args = parser.parse_args([args.what, *TINY[args.what], "--tiny"])
    if args.grid is not None and args.grid < 3:
        parser.error("--grid: an atlas needs >= 3 points a weight")
    if args.cluster and args.what != "exact":
        parser.error(f"--cluster: only exact runs on a cluster, not {args.what}")
    if args.pool and args.what != "exact":
        parser.error(f"--pool: only exact compares a pool's sharing, not {args.what}")
    if args.pool and args.cluster:
        parser.error("--pool and --cluster: one at a time")
    if args.study is not None and args.what not in ("exact", "atlas", "split"):
        parser.error(f"--study: only exact and atlas take a study file, not {args.what}")
    if args.study_envs is not None and not 1 <= args.study_envs <= 48:
        parser.error("--study-envs: 1 to 48 paper environments")
    points = None if args.what == "atlas" else args.grid
    smaller = study_overrides(points, args.study_envs)
    if args.what == "warm":
        from benchmarks.bench_warm import run_bench as run_warm
        from benchmarks.bench_warm import sample

        n = 300 if args.problems is None else args.problems
        if n < 1:
            parser.error("--problems must be >= 1")
        if args.breakdown and args.small_step:
            parser.error("--breakdown and --small-step are two benchmarks: give one")
        if args.breakdown:
            if args.slice_runs < 1:
                parser.error("--slice-runs must be >= 1")
            from benchmarks.bench_warm import run_breakdown

            print("\n".join(run_breakdown(args.slice_runs, 0 if args.seed is None else args.seed)))
            return
        if args.iterations is not None and args.iterations < 1:
            parser.error("warm: --iterations must be >= 1")
        problems = sample(
            n, seed=7 if args.seed is None else args.seed, iterations=args.iterations or 12
        )
        if args.small_step:
            from benchmarks.bench_warm import run_small_step

            print("\n".join(run_small_step(problems)))
        else:
            print("\n".join(run_warm(problems)))
        return
    if args.what == "learnt":
        from benchmarks.bench_learnt import run_bench as run_learnt

        n = 24 if args.problems is None else args.problems
        if n < 2:
            parser.error("--problems: learnt takes >= 2 problems (default 24)")
        print("\n".join(run_learnt(n, 0 if args.seed is None else args.seed, args.build)))
        return
    if args.what == "atlas":
        from benchmarks.bench_atlas import report as report_atlas
        from benchmarks.bench_atlas import run as run_atlas
        from benchmarks.bench_atlas import run_study

        n = 200 if args.problems is None else args.problems
        if args.study is not None:
            if n < 1 or args.restarts < 1:
                parser.error("atlas: --problems and --restarts must be >= 1")
            if not Path(args.study).is_file():
                parser.error(f"--study {args.study}: not a study file (a .toml that exists)")
            try:
                lines = run_study(
                    args.study,
                    coarse=args.coarse,
                    problems=n,
                    restarts=args.restarts,
                    seed=65 if args.seed is None else args.seed,
                )
            except ValueError as exc:
                parser.error(str(exc).splitlines()[0])
            print("\n".join(lines), flush=True)
            return
        if n < 1 or not 1 <= args.envs <= 48:
            parser.error("atlas: --problems >= 1, --envs in [1, 48]")
        try:
            bench = run_atlas(
                envs=args.envs,
                count=31 if args.grid is None else args.grid,
                problems=n,
                restarts=args.restarts,
                theta_range=args.theta_range if args.theta_range != THETA_RANGE[1] else 2.0,
                seed=0 if args.seed is None else args.seed,
                lazy=args.lazy,
            )
        except ValueError as exc:  # a grid --lazy cannot halve, refused before any build
            parser.error(str(exc).splitlines()[0])
        print("\n".join(report_atlas(bench)), flush=True)
        return
    if args.what == "particles":
        from benchmarks.bench_particles import run_bench as run_particles

        runs = 4 if args.problems is None else args.problems
        envs = 4 if args.envs == 48 else args.envs
        if runs < 1 or args.particles < 2 or not args.bound > 0 or not 1 <= envs <= 48:
            parser.error("particles: --problems >= 1, --particles >= 2, --bound > 0, --envs 1-48")
        if args.moves < 0:
            parser.error("particles: --moves >= 0")
        seed = 0 if args.seed is None else args.seed
        lines = run_particles(args.particles, runs, args.bound, envs, seed, args.moves, smaller)
        print("\n".join(lines), flush=True)
        return
    if args.what == "split":
        from benchmarks.bench_split import run_bench as run_split

        if args.slice_runs < 1 or (args.iterations is not None and args.iterations < 1):
            parser.error("split: --slice-runs and --iterations must be >= 1")
        figure = "fig4"
        if args.study is not None:
            if not args.study.endswith(".toml") or not Path(args.study).is_file():
                parser.error(f"--study {args.study}: not a study file (a .toml that exists)")
            figure = args.study
        overrides = dict(smaller)
        if args.iterations is not None:
            overrides["iterations"] = args.iterations
        names = [n.strip() for n in (args.learners or "").split(",") if n.strip()] or None
        print("\n".join(run_split(figure, args.slice_runs, overrides, names)), flush=True)
        return
    if args.what == "exact":
        from benchmarks.bench_exact import run_bench as run_exact

        runs = 3 if args.problems is None else args.problems
        if runs < 1 or (args.iterations is not None and args.iterations < 1):
            parser.error("exact: --problems (runs) and --iterations must be >= 1")
        names = tuple(n.strip() for n in (args.learners or "EX-C,EX-CL").split(",") if n.strip())
        figure = "fig4"
        if args.study is not None:
            if not args.study.endswith(".toml") or not Path(args.study).is_file():
                parser.error(f"--study {args.study}: not a study file (a .toml that exists)")
            if args.study_envs is not None:
                parser.error("--study-envs: fig. 4's paper environments; a study file has its own")
            figure = args.study
        if args.cluster:
            from benchmarks.bench_exact import run_cluster

            lines = run_cluster(names, runs, args.iterations, smaller, figure)
        elif args.pool:
            from benchmarks.bench_exact import run_pool

            lines = run_pool(names, runs, args.iterations, smaller, figure)
        else:
            lines = run_exact(names, runs, args.iterations, smaller, figure)
        print("\n".join(lines), flush=True)
        return
    if args.what == "main":
        from benchmarks.bench_main import report as report_main
        from benchmarks.bench_main import run as run_main

        extra = ["--quick"] if args.quick else []
        extra += set_options(args.grid, args.study_envs)
        if args.learners:
            extra += ["--learners", args.learners]
        if args.iterations is not None:
            extra += ["--iterations", str(args.iterations), "--runs", "1"]
        result = run_main("fig4", extra, compiled=args.keep_compiled)
        print("\n".join(report_main(result)), flush=True)
        return
    if args.what == "catch":
        from benchmarks.bench_catch import report as report_catch
        from benchmarks.bench_catch import run as run_catch

        tries = 62 if args.problems is None else args.problems
        if tries < 1:
            parser.error("--problems: catch takes the tries, >= 1")
        print("\n".join(report_catch(run_catch(tries))), flush=True)
        return
    if args.what == "questionnaire":
        from benchmarks.bench_questionnaire import report as report_questionnaire
        from benchmarks.bench_questionnaire import run as run_questionnaire

        count = 20 if args.problems is None else args.problems
        if count < 1:
            parser.error("--problems: questionnaire takes the questionnaires to answer, >= 1")
        seed = 0 if args.seed is None else args.seed
        print("\n".join(report_questionnaire(run_questionnaire(count, seed))), flush=True)
        return
    if args.what == "study":
        from benchmarks.bench_study import report, run

        learner = (args.learners or "KF-CL").split(",")[0]
        corrections = 6 if args.problems is None else args.problems
        if corrections < 1:
            parser.error("--problems: study takes the corrections per participant, >= 1")
        result = run(4, corrections, learner, chromium=args.browser, smaller=smaller)
        print("\n".join(report(result)), flush=True)
        return
    if args.what == "confidence":
        from benchmarks.bench_confidence import run_bench as run_confidence

        names = (args.learners or "KF-CI,PF-C,AL-C,AL-PF").split(",")
        runs = 3 if args.problems is None else args.problems
        if runs < 1 or (args.iterations is not None and args.iterations < 1):
            parser.error("confidence: --problems (runs per learner) and --iterations >= 1")
        lines = run_confidence(
            tuple(n for n in names if n), runs, iterations=args.iterations, smaller=smaller
        )
        print("\n".join(lines), flush=True)
        if args.local_optima:
            from benchmarks.bench_confidence import local_optima

            print("\n".join(local_optima(seed=0 if args.seed is None else args.seed)))
        return
    if args.what == "relevance":
        from benchmarks.bench_relevance import run_bench as run_relevance

        runs = 3 if args.problems is None else args.problems
        if runs < 1:
            parser.error("--problems: relevance takes the runs per person and learner, >= 1")
        names = tuple(n.strip() for n in (args.learners or "KF-C,KF-CR,KF-CRP").split(","))
        print("\n".join(run_relevance(tuple(n for n in names if n), runs, smaller)))
        return
    if args.what == "physical":
        from benchmarks.bench_physical import run_bench as run_physical

        n = 12 if args.problems is None else args.problems
        if not 1 <= n <= 48:
            parser.error("--problems: physical takes 1 to 48 environments (default 12)")
        print("\n".join(run_physical(n, 0 if args.seed is None else args.seed)))
        if args.page:
            from benchmarks.bench_physical import run_page_bench

            print()
            shot = Path(args.screenshot) if args.screenshot else None
            print("\n".join(run_page_bench(args.speed, args.pushes, shot, args.db)))
        return
    args.problems = 60 if args.problems is None else args.problems
    args.seed = 0 if args.seed is None else args.seed
    if args.what == "interact":
        from benchmarks.bench_interact import run_bench as run_interact

        if args.corrections < 1:
            parser.error("--corrections must be >= 1")
        shot = Path(args.screenshot) if args.screenshot else None
        learners = [n.strip() for n in (args.learners or "KF-CL,KF-C,BP").split(",") if n.strip()]
        if args.db:
            db = Path(args.db)
        elif args.tiny:  # a check, not a measurement: nothing of it is kept
            db = Path(tempfile.mkdtemp(prefix="bench-interact-")) / "bench.sqlite"
        else:
            db = Path("results/interact/bench.sqlite")
        print("\n".join(run_interact(learners, args.corrections, db, shot, smaller)))
        return
    if args.what == "fig4":
        from benchmarks.bench_batch import run_bench

        if args.slice_runs < 1 or (args.iterations is not None and args.iterations < 1):
            parser.error("--slice-runs and --iterations must be >= 1")
        t0 = time.perf_counter()
        lines = run_bench(
            full=not args.skip_full,
            slice_runs=args.slice_runs,
            iterations=args.iterations,
            smaller=set_options(args.grid, args.study_envs),
            solver=args.solver or PlannerConfig().solver,
            warm=args.warm or PlannerConfig().warm,
        )
        print()
        print("\n".join(lines))
        print(f"\ntotal {time.perf_counter() - t0:.0f} s")
        return
    if args.problems < 1 or args.restarts < 1 or args.slsqp < 0 or not args.theta_range > 0:
        parser.error("--problems and --restarts must be >= 1, --slsqp >= 0, --theta-range > 0")

    t0 = time.perf_counter()
    try:
        configs = {
            name: PlannerConfig(
                features=tuple(f.strip() for f in args.features.split(",")),
                n_starts=args.n_starts,
                solver=name,
            )
            for name in (s.strip() for s in args.solvers.split(","))
        }
    except ValueError as exc:
        parser.error(str(exc))
    planners = {name: Planner(cfg) for name, cfg in configs.items()}
    envs = paper_environments()
    rng = np.random.default_rng(args.seed)
    cfg = next(iter(configs.values()))
    theta_range = (-args.theta_range, args.theta_range)
    problems = make_problems(args.problems, cfg.k, len(envs), rng, theta_range)
    print(
        f"planner benchmark: {args.problems} problems (seed {args.seed}), theta uniform in "
        f"{list(theta_range)}^{cfg.k}, {len(envs)} environments; features {cfg.features}, "
        f"T={cfg.n_waypoints}, lambda={cfg.smoothness}, n_starts={cfg.n_starts}, jit={cfg.jit}"
        f", solvers {list(planners)}, {args.restarts} random restarts; planners ready in "
        f"{time.perf_counter() - t0:.2f} s",
        flush=True,
    )
    for planner in planners.values():  # first-call overheads
        planner.solve(problems[0].theta, envs[problems[0].env_index])
        planner._ipopt_solver()  # the fallback's library, so no build lands in a timing
    bench = run_planner_bench(
        planners,
        envs,
        problems,
        n_restarts=args.restarts,
        n_slsqp=min(args.slsqp, args.problems),
        rng=rng,
        progress=lambda line: print(line, flush=True),
    )
    print()
    print("\n".join(report_planner_bench(bench)))
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
