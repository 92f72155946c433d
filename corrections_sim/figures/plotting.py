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


#: Colours for learners that name no ``style`` (see :class:`corrections_sim.learning.base.Learner`).
_EXTRA_COLOURS = ("#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22")


def learner_style(name: str) -> tuple[str, str]:
    """(colour, line style) of a learner: its own ``style``, or else the next free colour in
    the registry's order of the learners without one. The correction-aware variants share
    their paper learner's colour, dashed."""
    from corrections_sim.learning.base import LEARNERS

    cls = LEARNERS.get(name)
    if cls is not None and cls.style is not None:
        return cls.style
    extra = [n for n, c in LEARNERS.items() if c.style is None]
    i = extra.index(name) if name in extra else 0
    return _EXTRA_COLOURS[i % len(_EXTRA_COLOURS)], "-"


def learner_label(name: str) -> str:
    """A learner's label in figures (its registered name if it has none)."""
    from corrections_sim.learning.base import LEARNERS

    cls = LEARNERS.get(name)
    return cls.label if cls is not None and cls.label else name


def plot_learning_curves(
    curves: dict[str, dict[str, np.ndarray]],
    title: str,
    paths,
    bands: dict[str, tuple[float, float]] | None = None,
    n_environments: int = 48,
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
        (
            "regret",
            f"Regret (full objective), Σ over {n_environments} envs",
            "regret (reward units)",
        ),
        (
            "regret_paper",
            f"Regret θ*·Φ only (paper's), Σ over {n_environments} envs",
            "regret (reward units)",
        ),
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
    axes[0].legend(fontsize=7, loc="best")
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


#: Fonts of figs. 1-3, sized for the width the README and the docs show them at (~1000 px).
FIGURE_FONTS = {
    "font.size": 12,
    "axes.titlesize": 13,
    "axes.labelsize": 12,
    "xtick.labelsize": 11,
    "ytick.labelsize": 11,
    "legend.fontsize": 10.5,
    "figure.titlesize": 14,
}
#: The heat maps' shared colour bar.
RELATIVE_LABEL = (
    "uncertainty left after one correction, ‖Pᵗ⁺¹‖_F / ‖P + M‖_F "
    "(1 = learns nothing, lower = learns more)"
)


def relative_uncertainty(spec: dict) -> np.ndarray:
    """A map's predicted ‖Pᵗ⁺¹‖_F divided by ‖P + M‖_F (its value when nothing is learned),
    so maps with different P share one scale; NaN where the cell has no value."""
    return np.asarray(spec["values"], float) / float(spec["no_information"])


def plot_heat_map(ax: plt.Axes, spec: dict, vmin: float) -> QuadMesh:
    """One map of the relative uncertainty left over a grid, seen from above and beyond the table.

    Args:
        ax: the axes.
        spec: ``grid`` (xs, ys, vary), ``values`` (nx, ny) predicted ‖Pᵗ⁺¹‖_F with NaN where
            missing, ``status`` (nx, ny) strings, ``no_information`` (‖P + M‖_F),
            ``overlay`` cup path (N, 2) or None, ``laptop`` (x, y, yaw) or None, ``table``
            (x, y), ``start`` / ``goal`` cup positions or None, ``title``.
        vmin: bottom of the colour scale (shared by every map of the figure); the top is 1.
    """
    from corrections_sim.scene import geometry as g

    grid = spec["grid"]
    values = relative_uncertainty(spec)
    status = spec["status"]
    xe, ye = _edges(grid.xs), _edges(grid.ys)
    finite = values[np.isfinite(values)]
    mesh = ax.pcolormesh(ye, xe, np.ma.masked_invalid(values), cmap="magma_r", vmin=vmin, vmax=1.0)
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
            label="most informative cell",
        )
    # Seen from above and beyond the table, like the renders: the robot at the top.
    ax.set_xlim(min(ye[0], spec["goal"][1] - 0.05), max(ye[-1], spec["goal"][1] + 0.05))
    ax.set_ylim(max(xe[-1], spec["goal"][0] + 0.05), min(xe[0], spec["goal"][0] - 0.05))
    ax.set_aspect("equal")
    ax.set_xlabel("world y (m), robot's left →")
    ax.set_ylabel("world x (m), robot ↑")
    best = f"\nmost informative: {np.nanmin(values):.2f}" if finite.size else ""
    ax.set_title(spec["title"] + best)
    ax.legend()
    return mesh


def plot_selection_figure(
    image: np.ndarray,
    legend: Sequence[tuple[tuple[float, float, float, float], str]],
    maps: Sequence[dict],
    title: str,
    paths: Sequence[Path],
    legend_title: str | None = None,
) -> None:
    """Figs. 1–2: the scene render with its paths, then one heat map per ``maps`` entry, all
    on one colour scale (the relative uncertainty left, :func:`relative_uncertainty`) with
    one colour bar and one legend."""
    n = len(maps)
    lows = [np.nanmin(v) for v in map(relative_uncertainty, maps) if np.isfinite(v).any()]
    vmin = float(np.floor(min(lows, default=0.0) * 20) / 20)
    with plt.rc_context(FIGURE_FONTS):
        fig = plt.figure(figsize=(4.9 * n + 5.6, 6.6))
        grid = fig.add_gridspec(
            3,
            n + 1,
            width_ratios=[1.3] + [1.0] * n,
            height_ratios=[1.0, 0.045, 0.3],
            left=0.03,
            right=0.99,
            top=0.87,
            bottom=0.01,
            wspace=0.2,
            hspace=0.35,
        )
        ax = fig.add_subplot(grid[0:2, 0])
        ax.imshow(image)
        ax.set_axis_off()
        ax.set_title("the scene: the robot's optimal cup paths")
        handles = [Line2D([0], [0], color=rgba[:3], lw=3, label=text) for rgba, text in legend]
        box = fig.add_subplot(grid[2, 0])
        box.set_axis_off()
        box.legend(handles=handles, title=legend_title, loc="upper center", frameon=False)
        heat = [fig.add_subplot(grid[0, m + 1]) for m in range(n)]
        for ax, spec in zip(heat, maps, strict=True):
            mesh = plot_heat_map(ax, spec, vmin)
        labelled = {}
        for ax in heat:
            for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
                labelled.setdefault(label, handle)
            ax.get_legend().remove()
        cax = fig.add_subplot(grid[1, 1:])
        bar = fig.colorbar(mesh, cax=cax, orientation="horizontal")
        bar.set_label(RELATIVE_LABEL)
        box = fig.add_subplot(grid[2, 1:])
        box.set_axis_off()
        box.legend(
            list(labelled.values()),
            list(labelled),
            loc="upper center",
            bbox_to_anchor=(0.5, 0.8),
            ncol=3,
            frameon=False,
        )
        fig.suptitle(title)
        try:
            for path in paths:
                save_atomically(fig, path, dpi=100)
        finally:
            plt.close(fig)


#: Line styles of fig. 3's insets, so that coinciding paths stay distinguishable.
PATH_LINES = {
    "averse": {"ls": "-", "lw": 2.4},
    "neutral": {"ls": "--", "lw": 2.0},
    "seeking": {"ls": "-.", "lw": 2.0},
    "A3": {"ls": ":", "lw": 3.2},
}
_SAME_PATH_M = 0.005


def _deployment_table(ax: plt.Axes, rows: Sequence[dict], features, styles: dict) -> None:
    """Feature counts and rewards of a panel's trajectories as a table with colour keys."""
    header = ["", "γ", *[f"Φ {n}" for n in features], "θ̂·Φ − λS", "worst over Γ"]
    cells, colours = [], []
    for r in rows:
        gamma = (
            "—"
            if r["rule"] == "A3"
            else "(" + ", ".join(f"{r[f'gamma_{n}']:+.3g}" for n in features) + ")"
        )
        cells.append(
            [
                "max-min" if r["style"] == "A3" else r["style"],
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
    table.set_fontsize(10)
    table.auto_set_column_width(list(range(len(header))))
    table.scale(1.0, 1.5)


def _plot_cup_paths(
    top: plt.Axes, side: plt.Axes, paths: dict[str, np.ndarray], styles: dict, scene: dict
) -> None:
    """A panel's cup paths seen from above (world x over y, robot at the top) and as height
    above the table top over y, one line style per trajectory."""
    from corrections_sim.scene import geometry as g

    hx, hy = g.TABLE_HALF_SIZE
    tx, ty = scene["table"]
    table = np.array(
        [[tx - hx, ty - hy], [tx + hx, ty - hy], [tx + hx, ty + hy], [tx - hx, ty + hy]]
    )
    top.plot(*_outline(table).T, color="#8b5a2b", lw=1.2, ls="--")
    keyboard = g.laptop_base_corners_xy(*scene["laptop"])[[0, 1, 3, 2]]
    top.fill(*_outline(keyboard).T, color="#1f4e9a", alpha=0.25, lw=1.5, ec="#1f4e9a")
    laptop_corners = g.laptop_base_corners_xy(*scene["laptop"])
    side.axvspan(
        laptop_corners[:, 1].min(), laptop_corners[:, 1].max(), color="#1f4e9a", alpha=0.15, lw=0
    )
    side.axhline(0.0, color="#8b5a2b", lw=1.2, ls="--")
    for label, points in paths.items():
        rgba = styles[label][0]
        color = "#c89b00" if label == "A3" else rgba[:3]
        kw = {**PATH_LINES[label], "color": color}
        top.plot(points[:, 1], points[:, 0], **kw)
        side.plot(points[:, 1], points[:, 2] - g.TABLE_TOP_Z, **kw)
    points = np.vstack([table, *(p[:, :2] for p in paths.values())])
    (x0, y0), (x1, y1) = points.min(axis=0) - 0.03, points.max(axis=0) + 0.03
    top.set_xlim(y0, y1)
    # The robot at the top, as in the renders and figs. 1-2. No equal aspect, so that the
    # x axis stays aligned with the height plot below; the box is close to 1:1 anyway.
    top.set_ylim(x1, x0)
    top.set_ylabel("world x (m)")
    top.set_title("seen from above", fontsize=11)
    side.set_ylabel("height over\ntable top (m)")
    side.set_xlabel("world y (m), robot's left →")
    top.tick_params(labelbottom=False)
    for ax in (top, side):
        ax.grid(alpha=0.3)
    same = _same_as_averse(paths)
    if same:
        side.annotate(
            "exact max-min = averse (within 5 mm)",
            (0.02, 0.05),
            xycoords="axes fraction",
            va="bottom",
            fontsize=10,
        )


def _same_as_averse(paths: dict[str, np.ndarray]) -> bool:
    a, b = paths.get("A3"), paths.get("averse")
    if a is None or b is None or a.shape != b.shape:
        return False
    return bool(np.max(np.linalg.norm(a - b, axis=1)) < _SAME_PATH_M)


def _plot_comparison(ax: plt.Axes, comparison: Sequence[dict], labels: dict[str, str]) -> None:
    """Worst-case gain of the exact max-min over the paper's averse plan, per panel: against
    the paper's rule (grey) and against it with refined plans (black), one dot per study
    environment."""
    panels = list(dict.fromkeys(r["panel"] for r in comparison))
    for i, panel in enumerate(panels):
        rows = [r for r in comparison if r["panel"] == panel]
        lines = []
        for key, offset, color, label in (
            ("gain", -0.18, "#9a9a9a", "vs the paper's rule (the planner's usual starts)"),
            ("gain_refined", 0.18, "#111111", "vs the paper's rule, every plan re-solved from all"),
        ):
            gains = np.array([r[key] for r in rows], float)
            ok = np.isfinite(gains)
            jitter = (np.arange(gains.size) % 5 - 2) * 0.035
            ax.scatter(
                i + offset + jitter[ok],
                gains[ok],
                s=14,
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
            fontsize=10,
        )
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xticks(range(len(panels)), [labels.get(p, p) for p in panels], fontsize=10)
    ax.set_xlim(-0.6, len(panels) - 0.4)
    ax.set_ylabel("gain in the worst case over Γ (reward units)")
    n_env = len(comparison) // max(len(panels), 1)
    ax.set_title(
        f"exact max-min vs the paper's averse rule\nin {n_env} environments; on top: how many\n"
        "gain more than 1e-4 (grey | black)",
        pad=22,
    )
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), frameon=False, fontsize=10)
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
    *,
    cup_paths: Sequence[dict[str, np.ndarray]],
    scene: dict,
    panel_labels: dict[str, str],
) -> None:
    """Fig. 3: per panel a render with the deployed paths, the same paths seen from above and
    as heights (one line style each), and a table of their features; on the right, the
    worst-case gain of the exact max-min over the paper's averse plan.

    Args:
        cup_paths: per panel, the cup's points (N, 3) of each drawn trajectory by label.
        scene: ``table`` (x, y) and ``laptop`` (x, y, yaw) for the outlines.
        panel_labels: a short label of each panel by name, for the comparison's axis.
    """
    n = len(images)
    extra = 1 if comparison else 0
    with plt.rc_context(FIGURE_FONTS):
        fig = plt.figure(figsize=(5.6 * n + 5.0 * extra, 13.0))
        grid = fig.add_gridspec(
            4,
            n + extra,
            height_ratios=[3.0, 1.5, 1.3, 1.25],
            width_ratios=[1.0] * n + [0.85] * extra,
            left=0.04,
            right=0.99,
            top=0.85,
            bottom=0.02,
            wspace=0.3,
            hspace=0.25,
        )
        for i, (image, panel_title, rows) in enumerate(zip(images, titles, tables, strict=True)):
            ax = fig.add_subplot(grid[0, i])
            ax.imshow(image)
            ax.set_axis_off()
            ax.set_title(panel_title)
            top = fig.add_subplot(grid[1, i])
            side = fig.add_subplot(grid[2, i], sharex=top)
            _plot_cup_paths(top, side, cup_paths[i], styles, scene)
            _deployment_table(fig.add_subplot(grid[3, i]), rows, features, styles)
        handles = [
            Line2D(
                [0],
                [0],
                color="#c89b00" if label == "A3" else rgba[:3],
                label=text,
                **PATH_LINES[label],
            )
            for label, (rgba, text) in styles.items()
        ]
        handles += [
            Line2D([0], [0], color="#8b5a2b", lw=1.2, ls="--", label="table top"),
            Rectangle((0, 0), 1, 1, color="#1f4e9a", alpha=0.25, label="laptop"),
        ]
        left, right = grid[0, 0].get_position(fig).x0, grid[0, n - 1].get_position(fig).x1
        fig.legend(
            handles=handles,
            loc="upper center",
            bbox_to_anchor=((left + right) / 2, 0.93),
            ncol=3,
            frameon=False,
            handlelength=3.5,
        )
        if comparison:
            _plot_comparison(fig.add_subplot(grid[:3, n]), comparison, panel_labels)
        fig.suptitle(title)
        try:
            for path in paths:
                save_atomically(fig, path, dpi=100)
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
                value = r["nees_final"] if key == "nees" else r[f"{key}_mean"]
                values[i, j] = np.nan if value is None else value
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
                    if v is None:
                        text = "—"
                    else:
                        inside = r["nees_band_low"] <= v <= r["nees_band_high"]
                        text = f"{v:.3g}" + (" ✓" if inside else "")
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


def plot_physical(curves: dict, tasks: dict, k: int, title: str, paths) -> None:
    """The physical-corrections figure: estimate error and regret against corrections per
    learner (solid: the physical person, dashed: the other columns' users), the regret of
    the motion the person got with online replanning minus with the plan kept after the same
    push, per correction, and the mean NEES (log, calibrated band shaded).

    Args:
        curves: user label -> ``analysis.curves`` (learner -> metric -> (runs, T + 1)).
        tasks: user label -> learner -> per-task column -> (runs, T).
        k: θ's dimension (NEES's calibrated mean).
    """
    from corrections_sim.calibration import mean_band

    users = list(curves)
    physical = [
        u
        for u in users
        if any(
            np.isfinite(v["executed_regret"]).any()
            for v in tasks[u].values()
            if v["executed_regret"].size
        )
    ]
    learners = list(dict.fromkeys(n for u in users for n in curves[u]))
    # One colour per learner (learner_style gives KF-C KF's colour, dashed; here dashes mark
    # the user).
    palette = {n: plt.cm.tab10(i % 10) for i, n in enumerate(learners)}
    fig, axes = plt.subplots(2, 2, figsize=(13, 8.6))
    panels = (
        (axes[0, 0], "estimate_error", "estimate error ‖θ̂ − θ*‖₁"),
        (axes[0, 1], "regret", "regret of the next plans, Σ over environments"),
    )
    for ax, key, label in panels:
        for user in users:
            dashes = "-" if user in physical else "--"
            for learner, values in curves[user].items():
                colour = palette[learner]
                mean, sem = mean_sem(values[key])
                x = np.arange(mean.size)
                ax.plot(
                    x, mean, dashes, color=colour, lw=1.8, label=f"{learner_label(learner)}, {user}"
                )
                ax.fill_between(x, mean - sem, mean + sem, color=colour, alpha=0.15, lw=0)
        ax.set_xlabel("corrections")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, ncol=2, loc="upper right")
    ax = axes[1, 0]
    for user in physical:
        for learner, columns in tasks[user].items():
            online, kept = columns["executed_regret"], columns["executed_regret_kept"]
            if kept.size == 0 or not np.isfinite(kept).any():
                continue
            mean, sem = mean_sem(online - kept)
            x = np.arange(1, mean.size + 1)
            colour = palette[learner]
            ax.plot(x, mean, "-o", color=colour, lw=1.8, ms=3, label=learner_label(learner))
            ax.fill_between(x, mean - sem, mean + sem, color=colour, alpha=0.15, lw=0)
    ax.axhline(0.0, color="0.3", lw=1)
    ax.set_xlabel("correction (task)")
    ax.set_title(
        "regret of the executed motion: online replanning − plan kept (same push; < 0: "
        "online helps)",
        fontsize=10,
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax = axes[1, 1]
    for user in users:
        dashes = "-" if user in physical else "--"
        for learner, values in curves[user].items():
            nees = values["nees"]
            if not np.isfinite(nees).any():
                continue
            colour = palette[learner]
            mean = np.nanmean(nees, axis=0)
            ax.plot(np.arange(mean.size), mean, dashes, color=colour, lw=1.8)
        runs = next(iter(curves[user].values()))["nees"].shape[0]
    low, high = mean_band(k, runs)
    ax.axhspan(low, high, color="0.6", alpha=0.25, lw=0, label="calibrated band (95%)")
    ax.set_yscale("log")
    ax.set_xlabel("corrections")
    ax.set_title("mean NEES (solid: physical person, dashed: kinematic user)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.suptitle(title, fontsize=11)
    _save_and_close(fig, paths, dpi=110)


def plot_push(example: dict, paths) -> None:
    """One push seen from above and from the side: the robot's plan (blue), the person's
    (grey, dashed), the executed cup path (orange) with the person's force (red arrows, every
    0.1 s), the deformation ξ_H the robot learnt from (orange, dashed) and its new plan
    (green, dotted)."""
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    force = np.asarray(example["force"])
    executed = np.asarray(example["executed"])
    pushing = np.flatnonzero(np.linalg.norm(force, axis=1) > 0)[::10]
    for ax, (i, j), view in zip(
        axes, ((0, 1), (0, 2)), ("from above", "from the side"), strict=True
    ):
        ax.plot(
            *example["person"][:, [i, j]].T,
            "--",
            color="0.45",
            lw=1.6,
            label="the person's plan ξ*(θ*)",
        )
        ax.plot(*example["plan"][:, [i, j]].T, color="tab:blue", lw=2, label="the robot's plan ξ_R")
        ax.plot(
            *executed[:, [i, j]].T, color="tab:orange", lw=2.2, label="executed (with the push)"
        )
        ax.plot(
            *example["deformed"][:, [i, j]].T,
            "--",
            color="tab:orange",
            lw=1.4,
            label="deformation ξ_H (learnt)",
        )
        if example["new_plan"] is not None:
            ax.plot(
                *example["new_plan"][:, [i, j]].T,
                ":",
                color="tab:green",
                lw=2.2,
                label="new plan (online)",
            )
        if pushing.size:
            ax.quiver(
                executed[pushing, i],
                executed[pushing, j],
                force[pushing, i],
                force[pushing, j],
                color="tab:red",
                angles="xy",
                scale_units="xy",
                scale=150,
                width=0.004,
                label="the person's force",
            )
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)" if j == 1 else "z (m)")
        ax.set_title(view, fontsize=10)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="best")
    before, after = (None if t is None else np.round(t, 2).tolist() for t in example["theta"])
    learnt = f" → {after}" if after is not None else ""
    fig.suptitle(
        f"one push in {example['environment']}: {example['learner']} θ̂ {before}{learnt}; "
        f"effort {example['effort']:.1f} N·s, sensing error {100 * example['sense_error']:.1f}%",
        fontsize=10,
    )
    _save_and_close(fig, paths, dpi=110)


def plot_relevance(
    rows: Sequence[dict], seen: dict, title: str, paths, boundary: float | None = None
) -> None:
    """The relevance figure's second plot: (a) the distribution of ρ, the unexplained fraction
    of each correction KF-CR judged, relevant and irrelevant apart, per person; (b) how
    far θ̂ drifted from θ̂⁰ over the run, per learner and person (mean ± SEM).

    Args:
        rows: ``relevance.matrix`` rows (learner, user, drift_mean, drift_sem, …).
        seen: person -> learner -> {"rho", "beta", "relevant"} arrays per correction.
        paths: files to write.
        boundary: the ρ where β̂ = 1/2, drawn as a line.
    """
    users = list(dict.fromkeys(r["user"] for r in rows))
    learners = list(dict.fromkeys(r["learner"] for r in rows))
    cell = {(r["learner"], r["user"]): r for r in rows}
    fig, (left, right) = plt.subplots(1, 2, figsize=(15, 5.2))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for j, user in enumerate(users):
        data = seen.get(user, {}).get("KF-CR")
        if data is None or data["rho"].size == 0:
            continue
        for label, mask, style in (
            ("relevant", data["relevant"] == 1, "-"),
            ("irrelevant", data["relevant"] == 0, "--"),
        ):
            values = np.sort(data["rho"][mask & np.isfinite(data["rho"])])
            if values.size:
                left.step(
                    values,
                    np.arange(1, values.size + 1) / values.size,
                    where="post",
                    linestyle=style,
                    color=colours[j % len(colours)],
                    label=f"{user}: {label} ({values.size})",
                )
    if boundary is not None:
        left.axvline(boundary, color="0.4", lw=0.8, ls=":")
        left.text(boundary, 0.02, f" β̂ = 0.5 at ρ = {boundary:.2f}", fontsize=8, color="0.3")
    left.set_xlim(0.0, 1.0)
    left.set_ylim(0.0, 1.02)
    left.set_xlabel("ρ, the unexplained fraction of a correction (KF-CR's best θ)")
    left.set_ylabel("fraction of corrections with a smaller ρ")
    left.set_title("(a) what the robot's features cannot explain", fontsize=10)
    left.legend(fontsize=7)
    width = 0.8 / max(len(users), 1)
    x = np.arange(len(learners))
    for j, user in enumerate(users):
        means = [cell[(n, user)]["drift_mean"] for n in learners]
        sems = [cell[(n, user)]["drift_sem"] for n in learners]
        right.bar(x + (j - (len(users) - 1) / 2) * width, means, width, yerr=sems, label=user)
    right.set_xticks(x, learners, rotation=20, fontsize=9)
    right.set_ylabel("‖θ̂ᵀ − θ̂⁰‖₁")
    right.set_title("(b) how far θ̂ moved over the run", fontsize=10)
    right.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    _save_and_close(fig, paths, dpi=130)


def plot_reliability(diagrams: dict, title: str, paths) -> None:
    """Reliability diagrams of β̂: per learner, the fraction of relevant corrections in each
    β̂ bin against the bin's mean β̂ (marker area ∝ the bin's corrections), the diagonal
    being perfect calibration; the expected calibration error in the legend.

    Args:
        diagrams: learner -> {"ece": float, "bins": [{count, probability, fraction}, …]}.
        paths: files to write.
    """
    fig, ax = plt.subplots(figsize=(6.2, 5.6))
    ax.plot([0, 1], [0, 1], color="0.6", lw=0.8, ls=":")
    total = max(sum(b["count"] for b in d["bins"]) for d in diagrams.values())
    for name, diagram in diagrams.items():
        bins = [b for b in diagram["bins"] if b["count"]]
        colour, style = learner_style(name)
        x = [b["probability"] for b in bins]
        y = [b["fraction"] for b in bins]
        ax.plot(x, y, color=colour, ls=style, lw=1.2, label=f"{name}: ECE {diagram['ece']:.3f}")
        ax.scatter(x, y, s=[8 + 600 * b["count"] / total for b in bins], color=colour, alpha=0.6)
    ax.set_xlim(-0.02, 1.02)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("β̂ (mean within the bin)")
    ax.set_ylabel("fraction of the bin's corrections that are relevant")
    ax.set_title("Is β̂ calibrated? (every person's corrections; area ∝ count)", fontsize=10)
    ax.legend(fontsize=8, loc="upper left")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    _save_and_close(fig, paths, dpi=130)


def plot_ferl(curves: dict, people: list[str], bounds: dict, title: str, paths) -> None:
    """The FERL figure: per person (columns), the regret of their whole objective (top) and
    the error on the robot's own features (bottom) over corrections, mean ± SEM per learner,
    and the upper bound (KF-C of the column where the robot knows their feature) dashed grey.

    Args:
        curves: column label -> learner -> {"regret", "error"} arrays (runs, T + 1).
        people: the columns to draw, in order.
        bounds: column label -> the label of its upper bound's column.
        paths: files to write.
    """
    fig, axes = plt.subplots(2, len(people), figsize=(5.0 * len(people), 7.4), squeeze=False)
    for j, person in enumerate(people):
        lines = dict(curves[person])
        if person in bounds:
            lines["KF-C, knows human"] = curves[bounds[person]]["KF-C"]
        for i, metric in enumerate(("regret", "error")):
            ax = axes[i, j]
            for name, data in lines.items():
                values = data[metric]
                t = np.arange(values.shape[1])
                mean, sem = mean_sem(values)
                if name.endswith("knows human"):
                    colour, style = "0.45", "--"
                else:
                    colour, style = learner_style(name)
                ax.plot(t, mean, color=colour, ls=style, lw=1.4, label=name)
                ax.fill_between(t, mean - sem, mean + sem, color=colour, alpha=0.15, lw=0)
            ax.set_xlabel("corrections t")
            if i == 0:
                ax.set_title(person, fontsize=10)
                ax.set_ylabel("regret of the person's objective")
            else:
                ax.set_ylabel("error ‖θ̂ − θ*‖₁ on laptop, table")
            ax.grid(alpha=0.3)
        axes[0, j].legend(fontsize=8)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    _save_and_close(fig, paths, dpi=120)


def plot_ferl_quality(rows: Sequence[dict], title: str, paths) -> None:
    """Spearman ρ of a learnt feature against the true one, against the number of traces,
    per teacher noise (mean ± SEM over seeds; FERL's measure), with the issue's targets."""
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    for noise in dict.fromkeys(r["noise"] for r in rows):
        mine = [r for r in rows if r["noise"] == noise]
        counts = sorted({r["traces"] for r in mine})
        values = [np.array([r["spearman"] for r in mine if r["traces"] == n]) for n in counts]
        mean = [v.mean() for v in values]
        sem = [v.std(ddof=1) / np.sqrt(v.size) if v.size > 1 else 0.0 for v in values]
        ax.errorbar(counts, mean, yerr=sem, marker="o", capsize=3, label=f"teacher: {noise}")
    for level in (0.9, 0.8):
        ax.axhline(level, color="0.6", lw=0.8, ls=":")
    ax.set_xscale("log")
    counts = sorted({r["traces"] for r in rows})
    ax.set_xticks(counts, [str(n) for n in counts])
    ax.minorticks_off()
    ax.set_xlabel("feature traces")
    ax.set_ylabel("Spearman ρ, learnt vs true (10,000 configurations)")
    ax.set_ylim(top=1.0)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    _save_and_close(fig, paths, dpi=130)


def plot_reference_calibration(panels: dict, title: str, paths) -> None:
    """Each learner against its exact reference over t, one column per figure (``panels``:
    figure label -> {learner: by-iteration summaries of ``figures.reference``}): NEES /
    reference NEES with its 95% interval (1 is exact Bayes' confidence; the band
    [0.8, 1.25] shaded) and the Gaussian part of ``ref_kl`` (nats; 0 is the reference's own
    moments) with its interval."""
    columns = list(panels)
    fig, axes = plt.subplots(
        2, len(columns), figsize=(4.2 * len(columns), 6.4), squeeze=False, sharex="col"
    )
    for c, figure in enumerate(columns):
        top, bottom = axes[0, c], axes[1, c]
        top.axhspan(0.8, 1.25, color="0.9")
        top.axhline(1.0, color="0.5", lw=0.8)
        for learner, rows in panels[figure].items():
            colour, style = learner_style(learner)
            t = [r["iteration"] for r in rows]
            ratio = [r["ratio"] for r in rows]
            low, high = zip(*(r["ratio_ci95"] for r in rows), strict=True)
            top.plot(t, ratio, color=colour, ls=style, marker="o", ms=3, label=learner)
            top.fill_between(t, low, high, color=colour, alpha=0.15)
            gauss = [r["ref_kl_gaussian"] for r in rows]
            low, high = zip(*(r["ref_kl_gaussian_ci95"] for r in rows), strict=True)
            bottom.plot(t, gauss, color=colour, ls=style, marker="o", ms=3, label=learner)
            bottom.fill_between(t, low, high, color=colour, alpha=0.15)
        top.set_yscale("log")
        top.set_title(figure, fontsize=9)
        top.set_ylabel("NEES / reference NEES")
        bottom.axhline(0.02, color="0.6", lw=0.8, ls=":")
        bottom.set_ylabel("ref_kl, Gaussian part (nats)")
        bottom.set_xlabel("corrections t")
        for ax in (top, bottom):
            ax.grid(alpha=0.3)
        top.legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    _save_and_close(fig, paths, dpi=130)
