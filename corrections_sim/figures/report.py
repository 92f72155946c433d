"""Markdown tables from a figure's ``summary.json``: what the README quotes, computed, not typed.

    python -m corrections_sim.figures.report results/fig4   # learning figure: final, paired, NEES
    python -m corrections_sim.figures.report results/fig6            # robustness matrix

Reads only the summary a figure wrote; prints to stdout. Bad input (no such folder, not a
figure's summary) is one line on stderr and exit status 2.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path

METRIC_NAMES = {
    "estimate_error": "estimate error ‖θ̂ − θ*‖₁",
    "regret": "regret, full objective",
    "regret_paper": "regret, paper's θ*·Φ",
}


def _pm(stat: dict, digits: int = 3) -> str:
    if stat.get("sem") is None:
        return f"{stat['mean']:.{digits}f} (N = 1)"
    return f"{stat['mean']:.{digits}f} ± {stat['sem']:.{digits}f}"


def final_table(summary: dict) -> list[str]:
    """Final mean ± SEM; area under the mean curve, per learner and metric."""
    learners = list(summary["final"])
    lines = [
        "| after the last correction (mean ± SEM; AUC) | "
        + " | ".join(f"{n} (N = {summary['final'][n]['runs']})" for n in learners)
        + " |",
        "|---|" + "---|" * len(learners),
    ]
    for key, name in METRIC_NAMES.items():
        cells = [
            f"{_pm(summary['final'][n][key])}; {summary['final'][n][key]['auc_mean']:.1f}"
            for n in learners
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def calibration_table(summary: dict) -> list[str]:
    """Mean NEES per iteration, the band, and coverage, per learner with a covariance."""
    calib = summary["calibration"]
    if not calib:
        return []
    n_iter = len(next(iter(calib.values()))["mean_nees"])
    lines = [
        "| learner (N) | mean NEES at t = 0 … "
        + str(n_iter - 1)
        + " | 95% band | inside | 68% / 95% coverage |",
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


def paired_table(summary: dict, pairs: Sequence[tuple[str, str]] | None = None) -> list[str]:
    """Paired differences a − b (final value and AUC) with their 95% intervals."""
    rows = summary.get("paired", [])
    if pairs is not None:
        rows = [r for r in rows if (r["a"], r["b"]) in pairs or (r["b"], r["a"]) in pairs]
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


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 1:
        print(
            "error: usage: python -m corrections_sim.figures.report RESULTS/FIGURE", file=sys.stderr
        )
        return 2
    folder = Path(args[0])
    try:
        print(report(folder))
    except FileNotFoundError:
        print(f"error: {folder}: no summary.json (run the figure first)", file=sys.stderr)
        return 2
    except (KeyError, json.JSONDecodeError) as exc:
        print(
            f"error: {folder}/summary.json: not a learning figure's summary ({exc})",
            file=sys.stderr,
        )
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
