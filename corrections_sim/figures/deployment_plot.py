"""Fig. 3's plot (:mod:`corrections_sim.figures.deployment`): the cup's paths seen from above
and from the side for each deployment rule, and the table of what each costs."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle

from corrections_sim.figures.style import (
    FIGURE_FONTS,
    outline,
    plt,
    save_atomically,
)

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
    top.plot(*outline(table).T, color="#8b5a2b", lw=1.2, ls="--")
    keyboard = g.laptop_base_corners_xy(*scene["laptop"])[[0, 1, 3, 2]]
    top.fill(*outline(keyboard).T, color="#1f4e9a", alpha=0.25, lw=1.5, ec="#1f4e9a")
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
