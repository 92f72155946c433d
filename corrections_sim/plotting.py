"""Figures with matplotlib (headless, Agg). Only the edges of the program import this."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import QuadMesh  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from corrections_sim.metrics import mean_sem  # noqa: E402


def save_atomically(fig: plt.Figure, path: Path, **kwargs) -> Path:
    """Save ``fig`` to ``path`` through a temporary file, so a crash leaves no half file.

    A PDF carries no creation date, so the same figure gives the same bytes."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    if path.suffix.lower() == ".pdf":
        kwargs.setdefault("metadata", {"CreationDate": None})
    fig.savefig(tmp, **kwargs)
    os.replace(tmp, path)
    return path


def _save_and_close(fig: plt.Figure, paths, dpi: int) -> None:
    """Lay out ``fig``, write it to every path (atomically) and free it, even on failure."""
    try:
        fig.tight_layout()
        for path in paths:
            save_atomically(fig, path, dpi=dpi)
    finally:
        plt.close(fig)


def save_scene_figure(
    path: Path,
    image: np.ndarray,
    title: str,
    legend: Sequence[tuple[tuple[float, float, float, float], str]],
) -> Path:
    """A render (H, W, 3) with a title and a legend of coloured paths, as a PNG."""
    h, w = image.shape[:2]
    fig, ax = plt.subplots(figsize=(w / 100, h / 100 + 0.9), dpi=100)
    ax.imshow(image)
    ax.set_axis_off()
    ax.set_title(title, fontsize=11)
    handles = [Line2D([0], [0], color=rgba[:3], lw=3, label=label) for rgba, label in legend]
    ax.legend(
        handles=handles, loc="lower center", bbox_to_anchor=(0.5, -0.1), fontsize=9, frameon=False
    )
    fig.tight_layout()
    try:
        return save_atomically(fig, path, dpi=100)
    finally:
        plt.close(fig)


#: Colour and line style per learner; the correction-aware variants share their paper
#: learner's colour, dashed. Names come from ``study.LEARNERS``.
LEARNER_STYLE = {
    "PP": ("#7f7f7f", "-"),
    "KF": ("#1f77b4", "-"),
    "EKF": ("#2ca02c", "-"),
    "AL": ("#d62728", "-"),
    "PP-C": ("#7f7f7f", "--"),
    "KF-C": ("#1f77b4", "--"),
    "AL-C": ("#d62728", "--"),
    "KF-A": ("#9467bd", "-."),
    "BP": ("#8c564b", ":"),
}
_EXTRA_COLOURS = ("#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22")


def learner_style(name: str) -> tuple[str, str]:
    """(colour, line style) of a learner; learners without a fixed style get the next free
    colour in a stable order of their names."""
    if name in LEARNER_STYLE:
        return LEARNER_STYLE[name]
    from corrections_sim.study import LEARNERS

    extra = [n for n in LEARNERS if n not in LEARNER_STYLE]
    i = extra.index(name) if name in extra else 0
    return _EXTRA_COLOURS[i % len(_EXTRA_COLOURS)], "-"


def learner_label(name: str) -> str:
    from corrections_sim.study import LEARNERS

    spec = LEARNERS.get(name)
    return spec.label if spec is not None and spec.label else name


def plot_learning_curves(
    curves: dict[str, dict[str, np.ndarray]],
    title: str,
    paths,
    bands: dict[str, tuple[float, float]] | None = None,
) -> None:
    """Estimate error, regret and calibration against iteration.

    Bands are ± SEM over runs (none for a single run). The calibration panel shows the mean
    NEES of every learner with a covariance on a log scale, with the 95% χ² band of a
    calibrated mean for that learner's number of runs shaded (light grey: the most runs;
    hatched: a single run).

    Args:
        curves: learner -> {"estimate_error", "regret", "regret_paper", "nees"}: each
            (runs, T+1).
        paths: files to write (PNG, PDF, …).
        bands: learner -> (low, high) band of its mean NEES; learners without one have no
            covariance and are left out of the calibration panel.
    """
    bands = bands or {}
    fig, axes = plt.subplots(1, 4, figsize=(17, 4.4))
    panels = (
        ("estimate_error", "Estimate error ‖θ̂ − θ*‖₁", "error (L1, weight units)"),
        ("regret", "Regret (full objective), Σ over 48 envs", "regret (reward units)"),
        ("regret_paper", "Regret θ*·Φ only (paper's), Σ over 48 envs", "regret (reward units)"),
    )
    for ax, (key, label, ylabel) in zip(axes, panels, strict=False):
        for learner, data in curves.items():
            colour, style = learner_style(learner)
            values = data[key]
            mean, sem = mean_sem(values)
            t = np.arange(mean.size)
            n = values.shape[0]
            name = f"{learner_label(learner)}, N = {n}"
            ax.plot(t, mean, color=colour, ls=style, lw=2, label=name)
            if n > 1:
                ax.fill_between(t, mean - sem, mean + sem, color=colour, alpha=0.2, lw=0)
        ax.set_title(label, fontsize=10)
        ax.set_ylabel(ylabel)
    ax = axes[3]
    shown = set()
    for learner, band in sorted(bands.items(), key=lambda kv: kv[1][1] - kv[1][0]):
        if tuple(band) in shown:
            continue
        n = curves[learner]["nees"].shape[0]
        single = n == 1
        ax.axhspan(
            *band,
            facecolor="none" if single else "0.85",
            hatch="///" if single else None,
            edgecolor="0.7",
            lw=0,
            label=f"95% band, calibrated mean of {n} run{'s' if n > 1 else ''}",
        )
        shown.add(tuple(band))
    for learner in bands:
        colour, style = learner_style(learner)
        mean = np.nanmean(curves[learner]["nees"], axis=0)
        ax.plot(np.arange(mean.size), mean, color=colour, ls=style, lw=2)
    if bands:
        ax.set_yscale("log")
        ax.legend(fontsize=7, loc="upper left")
    ax.set_title("Calibration: mean NEES (θ̂−θ*)ᵀP⁻¹(θ̂−θ*)", fontsize=10)
    ax.set_ylabel("mean NEES (calibrated: k)")
    for ax in axes:
        ax.set_xlabel("iteration (corrections)")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(title + "; bands: ± SEM over runs", fontsize=11)
    _save_and_close(fig, paths, dpi=150)


# --- figs. 1-3: heat maps of the predicted covariance, risk-sensitive deployment ---------------

#: Hatching of grid cells without a value, by status (never drawn as a colour of the map).
MISSING_STYLE = {
    "unreachable": ("//", "start unreachable (no IK)"),
    "start_collides": ("xx", "start in collision"),
    "plan_failed": ("\\\\", "planner failed"),
}


def _edges(centres: np.ndarray) -> np.ndarray:
    """Cell edges (n + 1,) around equally spaced centres (n,)."""
    step = centres[1] - centres[0]
    return np.concatenate([centres - step / 2, [centres[-1] + step / 2]])


def _outline(corners: np.ndarray) -> np.ndarray:
    """Close a polygon (n, 2) for plotting in (y, x) axes: returns (n + 1, 2) as (y, x)."""
    closed = np.vstack([corners, corners[:1]])
    return closed[:, ::-1]


def plot_heat_map(ax: plt.Axes, spec: dict) -> QuadMesh:
    """One map of predicted ‖Pᵗ⁺¹‖_F over a grid, seen from above and beyond the table.

    Args:
        ax: the axes.
        spec: ``grid`` (xs, ys, vary), ``values`` (nx, ny) with NaN where missing,
            ``status`` (nx, ny) strings, ``no_information`` (the colour scale's top),
            ``overlay`` cup path (N, 2) or None, ``laptop`` (x, y, yaw) or None, ``table``
            (x, y), ``start`` / ``goal`` cup positions or None, ``title``.
    """
    from corrections_sim import geometry as g

    grid = spec["grid"]
    values = np.asarray(spec["values"], float)
    status = spec["status"]
    xe, ye = _edges(grid.xs), _edges(grid.ys)
    finite = values[np.isfinite(values)]
    top = spec["no_information"]
    low = float(finite.min()) if finite.size else 0.0
    mesh = ax.pcolormesh(
        ye, xe, np.ma.masked_invalid(values), cmap="magma_r", vmin=min(low, top), vmax=top
    )
    dx, dy = xe[1] - xe[0], ye[1] - ye[0]
    seen = set()
    for (i, j), s in np.ndenumerate(status):
        if s == "ok":
            continue
        hatch, label = MISSING_STYLE[s]
        ax.add_patch(
            Rectangle(
                (ye[j], xe[i]),
                dy,
                dx,
                facecolor="0.88",
                edgecolor="0.55",
                hatch=hatch,
                lw=0.0,
                label=None if s in seen else label,
            )
        )
        seen.add(s)
    hx, hy = g.TABLE_HALF_SIZE
    tx, ty = spec["table"]
    table = np.array(
        [[tx - hx, ty - hy], [tx + hx, ty - hy], [tx + hx, ty + hy], [tx - hx, ty + hy]]
    )
    ax.plot(*_outline(table).T, color="#8b5a2b", lw=1.5, ls="--", label="table top")
    if spec.get("laptop") is not None:
        keyboard = g.laptop_base_corners_xy(*spec["laptop"])[[0, 1, 3, 2]]
        ax.plot(*_outline(keyboard).T, color="#1f4e9a", lw=2.2, label="laptop keyboard")
    if spec.get("overlay") is not None:
        path = spec["overlay"]
        ax.plot(path[:, 1], path[:, 0], color="#1fb4c9", lw=2.0, label=spec["overlay_label"])
    if spec.get("start") is not None:
        ax.plot(
            spec["start"][1], spec["start"][0], "^", color="#1fb4c9", ms=9, mec="k", label="start"
        )
    ax.plot(spec["goal"][1], spec["goal"][0], "o", color="#2ca02c", ms=9, mec="k", label="goal")
    if finite.size:
        i, j = np.unravel_index(np.nanargmin(values), values.shape)
        ax.plot(
            grid.ys[j],
            grid.xs[i],
            "*",
            color="#00e5ff",
            ms=17,
            mec="k",
            mew=1.2,
            label=f"argmin {values[i, j]:.3f}",
        )
    # Seen from above and beyond the table, like the renders: the robot at the top.
    ax.set_xlim(min(ye[0], spec["goal"][1] - 0.05), max(ye[-1], spec["goal"][1] + 0.05))
    ax.set_ylim(max(xe[-1], spec["goal"][0] + 0.05), min(xe[0], spec["goal"][0] - 0.05))
    ax.set_aspect("equal")
    ax.set_xlabel("world y (m), robot's left →")
    ax.set_ylabel("world x (m), robot ↑")
    ax.set_title(spec["title"], fontsize=10)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False)
    return mesh


def plot_selection_figure(
    image: np.ndarray,
    legend: Sequence[tuple[tuple[float, float, float, float], str]],
    maps: Sequence[dict],
    title: str,
    paths: Sequence[Path],
) -> None:
    """Figs. 1–2: the scene render with its paths, then one heat map per ``maps`` entry."""
    n = len(maps)
    fig = plt.figure(figsize=(5.6 * (n + 1), 6.6))
    grid = fig.add_gridspec(1, n + 1, width_ratios=[1.25] + [1.0] * n)
    ax = fig.add_subplot(grid[0])
    ax.imshow(image)
    ax.set_axis_off()
    ax.set_title("scene: optimal cup paths", fontsize=10)
    handles = [Line2D([0], [0], color=rgba[:3], lw=3, label=text) for rgba, text in legend]
    ax.legend(
        handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.01), fontsize=8, frameon=False
    )
    for m, spec in enumerate(maps):
        ax = fig.add_subplot(grid[m + 1])
        mesh = plot_heat_map(ax, spec)
        bar = fig.colorbar(mesh, ax=ax, shrink=0.8, pad=0.02)
        bar.set_label("predicted ‖Pᵗ⁺¹‖_F  (top: ‖P + M‖_F, no information)", fontsize=8)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    try:
        for path in paths:
            save_atomically(fig, path, dpi=110)
    finally:
        plt.close(fig)


def _deployment_table(ax: plt.Axes, rows: Sequence[dict], features, styles: dict) -> None:
    """Feature counts and rewards of a panel's trajectories as a table with colour keys."""
    header = ["", "γ", *[f"Φ {n}" for n in features], "θ̂·Φ − λS", "worst over Γ"]
    cells, colours = [], []
    for r in rows:
        gamma = (
            "max-min"
            if r["rule"] == "A3"
            else "(" + ", ".join(f"{r[f'gamma_{n}']:+.3g}" for n in features) + ")"
        )
        cells.append(
            [
                r["style"],
                gamma,
                *[f"{r[f'phi_{n}']:.2f}" for n in features],
                f"{r['reward_theta_hat']:.2f}",
                f"{r['worst_case']:.3f}",
            ]
        )
        rgba = styles[r["style"]][0]
        colours.append([(*rgba[:3], 0.35)] + ["white"] * (len(header) - 1))
    ax.set_axis_off()
    table = ax.table(
        cellText=cells, colLabels=header, cellColours=colours, loc="upper center", cellLoc="center"
    )
    table.auto_set_font_size(False)
    table.set_fontsize(8)
    table.scale(1.0, 1.35)


def _plot_comparison(ax: plt.Axes, comparison: Sequence[dict]) -> None:
    """Worst-case gain of (A3) over (A4)'s averse plan per panel: against the paper's (A4)
    (grey) and against (A4) with refined plans (black), one dot per study environment."""
    panels = list(dict.fromkeys(r["panel"] for r in comparison))
    for i, panel in enumerate(panels):
        rows = [r for r in comparison if r["panel"] == panel]
        lines = []
        for key, offset, color, label in (
            ("gain", -0.18, "#9a9a9a", "vs A4 (paper: the planner's usual starts)"),
            ("gain_refined", 0.18, "#111111", "vs A4 refined (every plan re-solved from all)"),
        ):
            gains = np.array([r[key] for r in rows], float)
            ok = np.isfinite(gains)
            jitter = (np.arange(gains.size) % 5 - 2) * 0.035
            ax.scatter(
                i + offset + jitter[ok],
                gains[ok],
                s=12,
                color=color,
                alpha=0.8,
                label=label if i == 0 else None,
            )
            lines.append(f"{int(np.sum(gains[ok] > 1e-4))}/{int(ok.sum())}")
        ax.annotate(
            " | ".join(lines),
            (i, 1.0),
            xycoords=("data", "axes fraction"),
            ha="center",
            va="bottom",
            fontsize=8,
        )
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xticks(range(len(panels)), panels)
    ax.set_xlim(-0.6, len(panels) - 0.4)
    ax.set_ylabel("worst case over Γ: A3 − A4 (averse)")
    n_env = len(comparison) // max(len(panels), 1)
    ax.set_title(
        f"A3 gain over A4 in {n_env} study environments\n(count > 1e-4 above)",
        fontsize=10,
        pad=16,
    )
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.06), frameon=False)
    ax.grid(alpha=0.3, axis="y")


def plot_deployment_figure(
    images: Sequence[np.ndarray],
    titles: Sequence[str],
    tables: Sequence[Sequence[dict]],
    features: Sequence[str],
    styles: dict,
    comparison: Sequence[dict],
    title: str,
    paths: Sequence[Path],
) -> None:
    """Fig. 3: per panel a render with the deployed paths and a table of their features;
    on the right, the worst-case gain of the exact max-min (A3) over (A4)'s averse plan."""
    n = len(images)
    extra = 1 if comparison else 0
    fig = plt.figure(figsize=(5.4 * n + 4.2 * extra, 6.6))
    grid = fig.add_gridspec(
        2, n + extra, height_ratios=[3.2, 1.3], width_ratios=[1.0] * n + [0.8] * extra
    )
    for i, (image, panel_title, rows) in enumerate(zip(images, titles, tables, strict=True)):
        ax = fig.add_subplot(grid[0, i])
        ax.imshow(image)
        ax.set_axis_off()
        ax.set_title(panel_title, fontsize=10)
        _deployment_table(fig.add_subplot(grid[1, i]), rows, features, styles)
    handles = [Line2D([0], [0], color=rgba[:3], lw=4, label=text) for rgba, text in styles.values()]
    fig.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, 0.93),
        ncol=len(handles),
        fontsize=9,
        frameon=False,
    )
    if comparison:
        _plot_comparison(fig.add_subplot(grid[:, n]), comparison)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.92))
    try:
        for path in paths:
            save_atomically(fig, path, dpi=110)
    finally:
        plt.close(fig)


def plot_robustness_matrix(rows: Sequence[dict], title: str, paths) -> None:
    """Fig. 6: learners (rows) × users (columns); final estimate error, final regret and
    final mean NEES as coloured tables with mean ± SEM in each cell.

    Args:
        rows: ``robustness.matrix`` rows (learner, user, *_mean, *_sem, nees_final, band).
        paths: files to write.
    """
    learners = list(dict.fromkeys(r["learner"] for r in rows))
    users = list(dict.fromkeys(r["user"] for r in rows))
    cell = {(r["learner"], r["user"]): r for r in rows}
    panels = (
        ("estimate_error", "Final estimate error ‖θ̂ − θ*‖₁ (lower is better)", "viridis_r"),
        ("regret", "Final regret, Σ over 48 envs (lower is better)", "viridis_r"),
        ("nees", "Final mean NEES (calibrated: k = 2; log colour)", "coolwarm"),
    )
    fig, axes = plt.subplots(1, 3, figsize=(6.2 * 3, 0.55 * len(learners) + 2.6))
    for ax, (key, label, cmap) in zip(axes, panels, strict=True):
        values = np.full((len(learners), len(users)), np.nan)
        for i, learner in enumerate(learners):
            for j, user in enumerate(users):
                r = cell[(learner, user)]
                values[i, j] = r["nees_final"] if key == "nees" else r[f"{key}_mean"]
        if key == "nees":
            # Diverging around k = 2 on a log scale: blue under-, red over-confident.
            shown = np.log10(values / 2.0)
            limit = max(1.0, float(np.nanmax(np.abs(shown))))
            image = ax.imshow(shown, cmap=cmap, vmin=-limit, vmax=limit, aspect="auto")
        else:
            image = ax.imshow(values, cmap=cmap, aspect="auto")
        colours = image.cmap(image.norm(shown if key == "nees" else values))
        for i, learner in enumerate(learners):
            for j, user in enumerate(users):
                r = cell[(learner, user)]
                if key == "nees":
                    v = r["nees_final"]
                    inside = r["nees_band_low"] <= v <= r["nees_band_high"]
                    text = "—" if not np.isfinite(v) else f"{v:.3g}" + (" ✓" if inside else "")
                else:
                    sem = r[f"{key}_sem"]
                    text = f"{r[f'{key}_mean']:.3g}" + (f"\n± {sem:.2g}" if sem else "\n(N = 1)")
                luminance = np.dot(colours[i, j, :3], (0.299, 0.587, 0.114))
                ax.text(
                    j,
                    i,
                    text,
                    ha="center",
                    va="center",
                    fontsize=8,
                    color="black" if luminance > 0.5 or not np.isfinite(values[i, j]) else "white",
                )
        ax.set_xticks(range(len(users)), users, rotation=20, ha="right", fontsize=9)
        ax.set_yticks(range(len(learners)), learners, fontsize=9)
        ax.set_title(label, fontsize=10)
    fig.text(
        0.99,
        0.01,
        "NEES: ✓ inside the 95% χ² band of a calibrated mean for its N; — no covariance (PP)",
        ha="right",
        fontsize=8,
    )
    fig.suptitle(title, fontsize=11)
    _save_and_close(fig, paths, dpi=150)
