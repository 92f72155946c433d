"""Figures with matplotlib (headless, Agg). Only the edges of the program import this."""

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
    """Save ``fig`` to ``path`` through a temporary file, so a crash leaves no half file."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    fig.savefig(tmp, **kwargs)
    os.replace(tmp, path)
    return path


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
