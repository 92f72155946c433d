"""``reference``: the exact posterior beside a learner's Gaussian, for the runs of a finished
learning figure (:mod:`corrections_sim.figures.reference`).

    python -m corrections_sim.run reference results/quick/fig4 --learner KF-C --runs 2
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from corrections_sim.cli.command import Command, wrote_nothing
from corrections_sim.cli.errors import UsageError
from corrections_sim.defaults import DEFAULTS


def run_reference(args: argparse.Namespace) -> list[Path]:
    """The reference of ``--runs`` runs of ``--learner`` in the figure folder FILE: its CSV and
    JSON beside the figure's files, and the table of its means over runs printed."""
    from corrections_sim.figures.output import write_records
    from corrections_sim.figures.reference import recorded_runs, reference_run, summary_at
    from corrections_sim.learning.exact import bayes as ref
    from corrections_sim.planning.planner import Planner
    from corrections_sim.plans import interpolation
    from corrections_sim.study import schema

    if not args.study_file:
        raise UsageError("reference: give a finished figure's folder, e.g. results/quick/fig4")
    folder = Path(args.study_file)
    learner = args.learner or DEFAULTS["reference"][0]
    count = 2 if args.runs is None else args.runs
    points = args.points or 61
    restart = args.restart or ""
    particles = args.particles or 0
    seed = args.seed or 0
    try:
        summary = json.loads((folder / "summary.json").read_text())
        settings = schema.parse_study(summary["settings"], name=summary.get("figure", ""))
        if learner not in settings.study.learners:
            known = ", ".join(settings.study.learners)
            raise ValueError(f"--learner {learner}: not in this figure ({known})")
        runs = recorded_runs(folder, learner)
        try:
            restarts = tuple(sorted({int(v) for v in restart.split(",") if v.strip()}))
        except ValueError:
            raise ValueError(f"--restart {restart}: expected iterations like 0,1,4") from None
        if any(s < 0 for s in restarts):
            raise ValueError(f"--restart {restart}: iterations are >= 0")
        if args.check_grid and settings.study.k != 2:
            raise ValueError(
                f"--check-grid: the grid exists only for k = 2, not {settings.study.k}"
            )
        k = settings.study.k
        spec = settings.atlas_spec()
        if spec is not None and k == 2:  # the atlas's box, at its spacing unless --points
            box = spec.grid
            grid = ref.Grid(box.lows, box.highs, args.points or box.counts[0])
        else:
            grid = ref.Grid((-3.0,) * k, (3.0,) * k, points) if k == 2 else None
        planner = Planner(settings.planner_config())
        records = []
        for run in sorted(runs)[:count]:
            records += reference_run(
                settings,
                learner,
                runs[run],
                grid,
                planner,
                one_step=args.one_step,
                restarts=restarts,
                particles=particles,
                seed=seed + run,
                resolution=args.resolution,
            )
            print(f"run {run}: done", file=sys.stderr, flush=True)
            if settings.atlas() is not None:  # the plans solved between nodes, kept
                settings.atlas().save()
                interpolation.save_kept()  # and the particles' checked cells
    except (OSError, KeyError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    path = write_records(folder / f"reference-{learner}.csv", records)
    n_runs = len({r["run"] for r in records})
    iterations = sorted({r["iteration"] for r in records})
    by_t = [summary_at(records, t) for t in iterations]
    print(f"(means over {n_runs} runs; 95% intervals over runs)")
    print(
        f"{'t':>3} {'ref NEES':>9} {'NEES':>7} {'NEES / ref NEES':>22} {'ref_kl':>22} "
        f"{'Gaussian part':>22}"
    )
    for row in by_t:
        ratio = f"{row['ratio']:.2f} [{row['ratio_ci95'][0]:.2f}, {row['ratio_ci95'][1]:.2f}]"
        kl = (
            f"{row['ref_kl']:.3f} [{row['ref_kl_ci95'][0]:.3f}, {row['ref_kl_ci95'][1]:.3f}]"
            if "ref_kl" in row
            else "-"
        )
        lo, hi = row["ref_kl_gaussian_ci95"]
        gauss = f"{row['ref_kl_gaussian']:.3f} [{lo:.3f}, {hi:.3f}]"
        print(
            f"{row['iteration']:>3} {row['ref_nees']:9.2f} {row['nees']:7.2f} {ratio:>22} "
            f"{kl:>22} {gauss:>22}"
        )
    final = by_t[-1]
    (folder / f"reference-{learner}.json").write_text(
        json.dumps({"learner": learner, **final, "by_iteration": by_t}, indent=1) + "\n"
    )
    kl_text = (
        f"ref_kl = {final['ref_kl']:.3f} [{final['ref_kl_ci95'][0]:.3f}, "
        f"{final['ref_kl_ci95'][1]:.3f}], of which Gaussian "
        if "ref_kl" in final
        else "the reference is the particles': ref_kl's Gaussian part "
    )
    print(
        f"t = {final['iteration']}: NEES / reference NEES = {final['ratio']:.2f} "
        f"[{final['ratio_ci95'][0]:.2f}, {final['ratio_ci95'][1]:.2f}], {kl_text}"
        f"{final['ref_kl_gaussian']:.3f} (95% intervals over {final['runs']} runs)"
    )
    if "particle_kl" in final:
        print(
            f"{particles} particles against the grid: KL (smoothed on the grid) "
            f"{final['particle_kl']:.3f}, mean within {final['particle_mean_gap']:.1%} of an "
            f"sd, variances within {final['particle_var_gap']:.1%}, ESS "
            f"{final['particle_ess']:.0f}"
        )
    if "one_step_ratio" in final:
        low, high = final["one_step_ratio_ci95"]
        print(
            f"one filter step from the reference: NEES / reference NEES = "
            f"{final['one_step_ratio']:.2f} [{low:.2f}, {high:.2f}], KL "
            f"{final['one_step_kl']:.3f}"
        )
    if "relevance_gap" in final:
        print(
            f"β̂ against the exact one: mean |gap| {final['relevance_gap']:.3f} (largest "
            f"{final['relevance_gap_max']:.3f}); the same side of 1/2 for "
            f"{final['relevance_agree']:.0%} of the corrections"
        )
    for key, value in final.items():
        if key.startswith("restart_"):
            at = key.split("_")[1]
            print(f"the filter from the reference at t = {at} on: NEES / ref NEES {value:.2f}")
    if args.check_grid:
        fine = grid.halved()
        first = sorted(runs)[0]
        coarse = [r for r in records if r["run"] == first]
        finer = reference_run(
            settings, learner, runs[first], fine, planner, resolution=args.resolution
        )
        pairs = list(zip(coarse, finer, strict=True))
        k = settings.study.k
        worst_mean = max(
            abs(a[f"ref_theta_{i}"] - b[f"ref_theta_{i}"]) / np.sqrt(b[f"ref_cov_{i}{i}"])
            for a, b in pairs
            for i in range(k)
        )
        worst_cov = max(
            abs(a[f"ref_cov_{i}{i}"] - b[f"ref_cov_{i}{i}"]) / b[f"ref_cov_{i}{i}"]
            for a, b in pairs
            for i in range(k)
        )
        print(
            f"grid {grid.points} -> {fine.points} points per axis: the mean moves by at most "
            f"{worst_mean:.2%} of its sd, the variances by {worst_cov:.2%}"
        )
    return [path]


COMMAND = Command(
    name="reference",
    run=run_reference,
    help="the exact posterior beside a learner's Gaussian, for a finished figure's runs",
    options=(
        "study_file",
        "learner",
        "runs",
        "points",
        "resolution",
        "one_step",
        "restart",
        "particles",
        "seed",
        "check_grid",
    ),
    file="DIR",
    option_help={
        "study_file": "a finished learning figure's folder (curves.csv, summary.json)",
        "learner": f"whose runs to judge (default {DEFAULTS['reference'][0]})",
        "runs": "how many runs (the first N; default 2)",
        "seed": "the particle reference's seed (default 0; run r uses seed + r)",
    },
    nothing_kept=wrote_nothing,
)
