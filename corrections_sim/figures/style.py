"""What every figure's plot shares: matplotlib headless (Agg), atomic saves, each learner's
colour and label, the fonts of figs. 1–3, the outline of a rectangle, and a rendered scene
with its legend. Only the figures' plots import it (lazily: a figure module itself does not
load matplotlib)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402


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


def save_and_close(fig: plt.Figure, paths, dpi: int, rect=None) -> None:
    """Lay out ``fig`` (its axes within ``rect``, (left, bottom, right, top) in figure
    fractions, if given: room for a figure legend), write it to every path (atomically) and
    free it, even on failure."""
    try:
        fig.tight_layout(rect=rect)
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
EXTRA_COLOURS = ("#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22")


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
    return EXTRA_COLOURS[i % len(EXTRA_COLOURS)], "-"


def learner_label(name: str) -> str:
    """A learner's label in figures (its registered name if it has none)."""
    from corrections_sim.learning.base import LEARNERS

    cls = LEARNERS.get(name)
    return cls.label if cls is not None and cls.label else name


def outline(corners: np.ndarray) -> np.ndarray:
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
