"""Markdown tables from a figure's ``summary.json``: what the README quotes, computed, not typed.

    python -m corrections_sim.run report results/fig4   # learning figure: final, paired, NEES
    python -m corrections_sim.run report results/fig6            # robustness matrix

Reads only the summary a figure wrote; prints to stdout. Bad input (no such folder, not a
figure's summary) is one line on stderr and exit status 2.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

METRIC_NAMES = {
    "estimate_error": "estimate error ‖θ̂ − θ*‖₁",
    "regret": "regret, full objective",
    "regret_paper": "regret, paper's θ*·Φ",
}


def pm(stat: dict, digits: int = 3) -> str:
    if stat.get("sem") is None:
        return f"{stat['mean']:.{digits}f} (N = 1)"
    return f"{stat['mean']:.{digits}f} ± {stat['sem']:.{digits}f}"


def final_table(summary: dict, learners: Sequence[str] | None = None) -> list[str]:
    """Final mean ± SEM; area under the mean curve, per learner (all, or ``learners``) and
    metric."""
    learners = list(summary["final"]) if learners is None else _known(summary["final"], learners)
    lines = [
        "| after the last correction (mean ± SEM; AUC) | "
        + " | ".join(f"{n} (N = {summary['final'][n]['runs']})" for n in learners)
        + " |",
        "|---|" + "---|" * len(learners),
    ]
    for key, name in METRIC_NAMES.items():
        cells = [
            f"{pm(summary['final'][n][key])}; {summary['final'][n][key]['auc_mean']:.1f}"
            for n in learners
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def calibration_table(summary: dict, learners: Sequence[str] | None = None) -> list[str]:
    """Mean NEES per iteration, the band, and coverage, per learner with a covariance (all, or
    ``learners``)."""
    calib = summary["calibration"]
    if learners is not None:
        calib = {n: calib[n] for n in _known(calib, learners)}
    if not calib:
        return []
    n_iter = len(next(iter(calib.values()))["mean_nees"])
    lines = [
        "| learner (N) | mean NEES at t = 0 … "
        + str(n_iter - 1)
        + " | 95% band | inside | 68% / 95% coverage (mean over t) |",
        "|---|---|---|---|---|",
    ]
    for name, c in calib.items():
        nees = " ".join(f"{v:.3g}" for v in c["mean_nees"])
        band = f"[{c['band'][0]:.2f}, {c['band'][1]:.2f}]"
        cover = f"{c['coverage_1sigma_mean']:.2f} / {c['coverage_2sigma_mean']:.2f}"
        lines.append(
            f"| {name} ({c['runs']}) | {nees} | {band} | {c['inside_band']:.0%} | {cover} |"
        )
    return lines


def paired_table(
    summary: dict,
    pairs: Sequence[tuple[str, str]] | None = None,
    metrics: Sequence[str] | None = None,
) -> list[str]:
    """Paired differences a − b (final value and AUC) with their 95% intervals, for every pair
    or ``pairs`` (in their order), every metric or ``metrics``."""
    rows = summary.get("paired", [])
    if pairs is not None:
        found = {(r["a"], r["b"]) for r in rows}
        missing = [f"{a}/{b}" for a, b in pairs if (a, b) not in found]
        if missing:
            raise KeyError(f"no paired comparison {', '.join(missing)} in the summary")
        rows = [r for pair in pairs for r in rows if (r["a"], r["b"]) == tuple(pair)]
    if metrics is not None:
        rows = [r for r in rows if r["metric"] in metrics]
    if not rows:
        return []
    lines = [
        "| a − b (paired runs) | metric | final: mean [95% CI] | AUC: mean [95% CI] |",
        "|---|---|---|---|",
    ]
    for r in rows:
        cells = []
        for part in ("final", "auc"):
            s = r[part]
            cells.append(f"{s['mean']:+.3f} [{s['ci95'][0]:+.3f}, {s['ci95'][1]:+.3f}]")
        lines.append(f"| {r['a']} − {r['b']} | {r['metric']} | {cells[0]} | {cells[1]} |")
    return lines


def learner_table(summary: dict, learners: Sequence[str]) -> list[str]:
    """The paper's metrics after the last correction, mean ± SEM (a learner of one run: its
    value), for ``learners``."""
    final = summary["final"]
    learners = _known(final, learners)
    iterations = summary["settings"]["iterations"]
    head = [f"{n} (1 run)" if final[n]["runs"] == 1 else n for n in learners]
    lines = [
        f"| after {iterations} corrections (mean ± SEM) | " + " | ".join(head) + " |",
        "|---|" + "---|" * len(learners),
    ]
    for key, digits in (("estimate_error", 3), ("regret", 2), ("regret_paper", 1)):
        cells = [
            f"{final[n][key]['mean']:.{digits}f}"
            if final[n]["runs"] == 1
            else pm(final[n][key], digits)
            for n in learners
        ]
        lines.append(f"| {METRIC_NAMES[key]} | " + " | ".join(cells) + " |")
    return lines


def _known(table: dict, learners: Sequence[str]) -> list[str]:
    missing = [n for n in learners if n not in table]
    if missing:
        known = ", ".join(table)
        raise KeyError(f"no learner {', '.join(missing)} in the summary (it has {known})")
    return list(learners)


def matrix_table(summary: dict, key: str) -> list[str]:
    """Fig. 6: one metric as a learners × users table."""
    rows = summary["matrix"]
    users = list(dict.fromkeys(r["user"] for r in rows))
    learners = list(dict.fromkeys(r["learner"] for r in rows))
    cell = {(r["learner"], r["user"]): r for r in rows}
    lines = ["| learner | " + " | ".join(users) + " |", "|---|" + "---|" * len(users)]
    for learner in learners:
        cells = []
        for user in users:
            r = cell[(learner, user)]
            if key == "nees":
                v = r["nees_final"]
                if v is None or v != v:
                    cells.append("—")
                    continue
                inside = r["nees_band_low"] <= v <= r["nees_band_high"]
                cells.append(f"{v:.3g}{' ✓' if inside else ''}")
            else:
                sem = r[f"{key}_sem"]
                mean = r[f"{key}_mean"]
                cells.append(f"{mean:.3g} ± {sem:.2g}" if sem is not None else f"{mean:.3g}")
        lines.append(f"| {learner} | " + " | ".join(cells) + " |")
    return lines


def report(folder: Path) -> str:
    summary = json.loads((folder / "summary.json").read_text())
    parts = []
    if "matrix" in summary:
        for key, title in (
            ("estimate_error", "Final estimate error (mean ± SEM)"),
            ("regret", "Final regret, full objective (mean ± SEM)"),
            ("nees", "Final mean NEES (✓: inside the 95% band of a calibrated mean)"),
        ):
            parts += [f"**{title}**", "", *matrix_table(summary, key), ""]
        return "\n".join(parts)
    parts += final_table(summary) + [""]
    parts += calibration_table(summary) + [""]
    parts += paired_table(summary)
    return "\n".join(parts)
