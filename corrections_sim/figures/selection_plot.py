"""Figs. 1 and 2's plot (:mod:`corrections_sim.figures.selection`): heat maps of eq. (A1)
over the cup's start, the table and the laptop drawn on them."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.collections import QuadMesh
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle

from corrections_sim.figures.style import (
    FIGURE_FONTS,
    outline,
    plt,
    save_atomically,
)

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
    ax.plot(*outline(table).T, color="#8b5a2b", lw=1.5, ls="--", label="table top")
    if spec.get("laptop") is not None:
        keyboard = g.laptop_base_corners_xy(*spec["laptop"])[[0, 1, 3, 2]]
        ax.plot(*outline(keyboard).T, color="#1f4e9a", lw=2.2, label="laptop keyboard")
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
